"""Which module provides each extra section of a scenario file, imported the first time its table appears, and the
check of a document's top-level keys against the registry (:mod:`.sections`)."""

from __future__ import annotations

from typing import Any

from ..params import echo
from .sections import _CORE_KEYS, _CORE_TABLES, _SECTIONS
from .tables import ScenarioError, _type_name

# Modules that register extra sections on import; imported on demand the first time their table
# appears (the loader's registry: it imports no section's code itself). A [ring] file is a scenario of its own:
# the platoon loader refuses it (STANDALONE_SECTIONS) before it looks here, and the ring loader imports its module.
SECTION_PROVIDERS: dict[str, str] = {
    "mpc": "aev_ocp.mpc.scenario",
    "mismatch": "aev_ocp.estimation.scenario",
    "sensors": "aev_ocp.estimation.scenario",
}


def _load_provider(key: str) -> None:
    """Import the package that registers section ``key`` (if one is known and it is not registered)."""
    mod = SECTION_PROVIDERS.get(key)
    if mod is not None and key not in _SECTIONS:
        import importlib

        importlib.import_module(mod)


def _check_top_level(doc: dict[str, Any], file: str) -> None:
    for key in doc:
        _load_provider(key)
    for key, value in doc.items():
        if key in _CORE_KEYS:
            continue
        if key in _CORE_TABLES or key in _SECTIONS:
            if not isinstance(value, dict):
                raise ScenarioError(
                    f"{file}: {key} = {echo(value)} is not allowed: expected a table [{key}], got a {_type_name(value)}"
                )
            continue
        raise ScenarioError(
            f"{file}: unknown top-level key or table {key!r}; allowed: "
            f"{sorted(_CORE_KEYS + _CORE_TABLES + tuple(_SECTIONS))}"
        )

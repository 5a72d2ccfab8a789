"""The registry of a scenario file's top-level tables: the core tables every platoon scenario may have, the extra
sections other modules register (:func:`register_section`; validated into ``Scenario.extra``), the modules that
provide them (imported the first time their table appears) and the sections that are scenario forms of their own."""

from __future__ import annotations

from typing import Any, Callable

from ..params import echo
from .tables import ScenarioError, TableReader, _type_name

SectionValidator = Callable[[TableReader], Any]
_SECTIONS: dict[str, SectionValidator] = {}
_CORE_TABLES = (
    "units",
    "leader",
    "platoon",
    "carfollowing",
    "simulation",
    "vehicle",
    "cell",
    "pack",
    "limits",
    "thermal",
)
_CORE_KEYS = ("name", "description", "compare")
# Modules that register extra sections on import; imported on demand the first time their table
# appears (the loader's registry: it imports no section's code itself).
SECTION_PROVIDERS: dict[str, str] = {
    "mpc": "aev_ocp.mpc.scenario",
    "ring": "aev_ocp.ring.scenario",
    "mismatch": "aev_ocp.estimation.scenario",
    "sensors": "aev_ocp.estimation.scenario",
}
#: Registered sections that describe a whole run of their own (no [leader], [platoon], [simulation]; their own
#: loader) -> the command that runs such a file. The platoon loader refuses them with that pointer, and
#: :func:`shipped_scenarios` lists them only when asked.
STANDALONE_SECTIONS: dict[str, str] = {"ring": "aev-ocp ring"}


def register_section(name: str, validator: SectionValidator) -> None:
    """Allow a top-level table ``[name]`` in scenario files.

    ``validator(reader)`` receives a :class:`TableReader` over the table, reads and checks its keys
    (raising through ``reader.error(...)``; ``reader.finish()`` rejects unknown keys) and returns the
    validated value, stored as ``Scenario.extra[name]``. It is called only when the table is present.
    """
    if name in _CORE_TABLES or name in _CORE_KEYS:
        raise ValueError(f"register_section: {name!r} is a core scenario key")
    _SECTIONS[name] = validator


def registered_sections() -> list[str]:
    """Names of the registered extra sections."""
    return sorted(_SECTIONS)


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

"""The registry of a scenario file's top-level tables: the core tables every platoon scenario may have, the extra
sections other modules register (:func:`register_section`; validated into ``Scenario.extra``) and the sections that
are scenario forms of their own. The modules that provide sections, and the check of a document's top level, are in
:mod:`.providers` (a provider imports this registry, so the list of providers stands above it)."""

from __future__ import annotations

from typing import Any, Callable

from .tables import TableReader

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

"""Finding scenario files: the folders shipped scenarios are looked for in, the list of them by form, and a name
or path resolved to a file (:func:`find_scenario`)."""

from __future__ import annotations

import errno
import os
import stat
import tomllib
from importlib import resources
from pathlib import Path
from typing import Iterator

from .sections import STANDALONE_SECTIONS
from .tables import ScenarioError

SCENARIO_DIR_NAME = "scenarios"  # the repository's folder of scenario files
PACKAGED_DIR_NAME = "scenario_files"  # inside the package: a link to the repository's folder


def packaged_scenario_dir() -> Path | None:
    """The scenario files installed with the package (``aev_ocp/scenario_files``), if present."""
    try:
        d = resources.files("aev_ocp") / PACKAGED_DIR_NAME
        path = Path(str(d))
    except (ModuleNotFoundError, TypeError):
        return None
    return path if path.is_dir() else None


def scenario_dirs() -> list[Path]:
    """Where shipped scenarios are looked for, in order: ./scenarios, then the packaged copy."""
    out = [Path.cwd() / SCENARIO_DIR_NAME]
    pkg = packaged_scenario_dir()
    if pkg is not None:
        out.append(pkg)
    return out


def shipped_scenarios(kind: str = "platoon") -> dict[str, Path]:
    """Shipped scenario names -> files (the first folder of :func:`scenario_dirs` that has each name) of one
    ``kind``: "platoon" (the default), a key of :data:`STANDALONE_SECTIONS` ("ring"), or "all"."""
    found: dict[str, Path] = {}
    for d in scenario_dirs():
        if d.is_dir():
            for f in sorted(d.glob("*.toml")):
                found.setdefault(f.stem, f)
    if kind != "all":
        found = {k: f for k, f in found.items() if _file_kind(f) == kind}
    return dict(sorted(found.items()))


def _file_kind(path: Path) -> str:
    """'platoon', or the standalone section a scenario file has (an unreadable file counts as a platoon: the
    platoon loader then reports what is wrong with it)."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        return "platoon"
    return next((k for k in STANDALONE_SECTIONS if isinstance(doc.get(k), dict)), "platoon")


def find_scenario(name_or_path: str | Path) -> Path:
    """Resolve a scenario: an existing path, else a shipped scenario name (with or without .toml).

    A path that exists but is not a readable file (a folder, a loop of symbolic links, a device) is
    reported as such, not as a missing scenario."""
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"scenario must be a path or a scenario name (str), got {type(name_or_path).__name__}")
    p = Path(name_or_path)
    try:
        st = p.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ScenarioError(f"{name_or_path}: cannot read the scenario file (a loop of symbolic links)") from None
        st = None
    if st is not None:
        if stat.S_ISREG(st.st_mode):
            return p
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise ScenarioError(f"{name_or_path}: cannot read the scenario file (it is {kind})")
    stem = p.name[:-5] if p.name.endswith(".toml") else p.name
    if p.parent == Path(".") or str(p.parent) == SCENARIO_DIR_NAME:
        for d in scenario_dirs():
            cand = d / f"{stem}.toml"
            if cand.is_file():
                return cand
    known = ", ".join(shipped_scenarios()) or "none found"
    raise ScenarioError(f"{name_or_path}: no such scenario file (shipped scenarios: {known})")


def iter_shipped() -> Iterator[tuple[str, Path]]:
    """(name, path) of every shipped scenario."""
    yield from shipped_scenarios().items()

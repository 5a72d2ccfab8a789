"""Where a result came from: package, git commit, library versions, platform, time, the scenario as
loaded (SHA-256 after overrides) and the random seeds (the provenance record).

:func:`provenance` builds the record; :func:`context` lets a command state its scenario and seeds
once, and every JSON written inside it (:func:`aev_ocp.results.write_json`) carries the record.
"""

from __future__ import annotations

import contextvars
import datetime as _dt
import hashlib
import json
import platform
import subprocess
import sys
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterator

from ._version import __version__

_CONTEXT: contextvars.ContextVar[dict[str, Any]] = contextvars.ContextVar("aev_ocp_provenance", default={})


BUILD_INFO = "_build_info.json"  # written into the built package by setup.py's build hook


def _built_commit(folder: Path | None = None) -> str | None:
    """The commit recorded when this copy was built (``pip install .`` from a clone), else None. folder: where
    ``_build_info.json`` is (default: beside this module)."""
    try:
        info = json.loads(((folder or Path(__file__).resolve().parent) / BUILD_INFO).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    commit = info.get("git_commit") if isinstance(info, dict) else None
    return commit if isinstance(commit, str) and commit else None


def _checkout_commit() -> str | None:
    """The commit of the source checkout the package runs from (None when not in an aev_ocp git tree).
    Only a tree whose pyproject.toml names aev_ocp counts (an installed copy inside another repository
    must not report that repository's commit)."""
    root = Path(__file__).resolve().parents[1]
    try:
        if 'name = "aev_ocp"' not in (root / "pyproject.toml").read_text(encoding="utf-8"):
            return None
        p = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if p.returncode != 0 or not p.stdout.strip():
        return None
    return p.stdout.strip() + ("+dirty" if dirty.returncode == 0 and dirty.stdout.strip() else "")


@lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit of the running code: its source checkout's (run from a clone or an editable install), else the
    one recorded when it was built (``pip install .`` from a clone; ``+dirty`` when built from changed files),
    else None (built without git)."""
    return _checkout_commit() or _built_commit()


@lru_cache(maxsize=1)
def versions() -> dict[str, Any]:
    """aev_ocp, CasADi, NumPy and Python versions, the platform and the git commit."""
    import casadi
    import numpy

    # CasADi 3.8's stubs omit __version__ (casadi/__init__.py sets it at import time)
    casadi_version: str = casadi.__version__  # type: ignore[attr-defined]
    return {
        "aev_ocp": __version__,
        "git_commit": git_commit(),
        "casadi": casadi_version,
        "numpy": numpy.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
    }


def scenario_sha256(scenario: Any) -> str | None:
    """SHA-256 of a scenario as loaded (its TOML document after overrides, canonical JSON), or of its
    file when no document is kept; None for objects without either."""
    doc = getattr(scenario, "document", None)
    blob: bytes | None
    if isinstance(doc, dict):
        blob = json.dumps(doc, sort_keys=True, separators=(",", ":"), default=str).encode()
    else:
        src = getattr(scenario, "source", None)
        try:
            blob = Path(src).read_bytes() if src else None
        except OSError:
            blob = None
    return hashlib.sha256(blob).hexdigest() if blob is not None else None


def provenance(scenario: Any = None, seeds: dict[str, int] | None = None) -> dict[str, Any]:
    """The provenance record: versions, UTC time, the scenario's name and SHA-256, and every seed
    (from the arguments and the enclosing :func:`context`)."""
    ctx = _CONTEXT.get()
    scn = scenario if scenario is not None else ctx.get("scenario")
    rec: dict[str, Any] = {**versions(), "utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    if scn is not None:
        rec["scenario"] = getattr(scn, "name", None)
        rec["scenario_sha256"] = scenario_sha256(scn)
    all_seeds = {**ctx.get("seeds", {}), **(seeds or {})}
    if all_seeds:
        rec["seeds"] = all_seeds
    return rec


def declare(scenario: Any = None, **seeds: int) -> None:
    """For a command-line process: from now on every provenance record names ``scenario`` and ``seeds``."""
    outer = _CONTEXT.get()
    _CONTEXT.set(
        {
            "scenario": scenario if scenario is not None else outer.get("scenario"),
            "seeds": {**outer.get("seeds", {}), **seeds},
        }
    )


@contextmanager
def context(scenario: Any = None, **seeds: int) -> Iterator[None]:
    """Within the block, every provenance record names ``scenario`` and the ``seeds`` given (nested
    contexts add to the outer one)."""
    outer = _CONTEXT.get()
    token = _CONTEXT.set(
        {
            "scenario": scenario if scenario is not None else outer.get("scenario"),
            "seeds": {**outer.get("seeds", {}), **seeds},
        }
    )
    try:
        yield
    finally:
        _CONTEXT.reset(token)

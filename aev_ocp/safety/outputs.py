"""Saving and loading a safety-suite run (manifest kind ``safety``).

The folder holds safety.json (settings, summary, cases and one row per case × actuator × controller, SI; the
document the manifest names with its SHA-256), the runs' trajectories when the suite kept them (one process:
``trajectories.npz``, one run per ``<case>:<actuator>:<controller>``) and safety.csv, safety.md and the figures
beside them (:func:`aev_ocp.safety.report.write_outputs`). :func:`load_suite_output` gives the
:class:`~aev_ocp.safety.run.SuiteOutput` back.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from ..saved import MANIFEST, LoadError, load_all, read_document, save_output
from .cases import SafetyCase
from .run import CaseRow, SuiteOutput

DOCUMENT = "safety.json"


def _label(case: str, key: str) -> str:
    return f"{case}:{key.replace('/', ':')}"  # key: "actuator/controller"


def save_suite_manifest(out: SuiteOutput, folder: str | Path) -> list[Path]:
    """The manifest (and trajectories.npz when the suite kept its runs) of a folder whose safety.json is written."""
    runs = {_label(case, key): r for case, by in out.runs.items() for key, r in by.items()}
    index = {_label(case, key): [case, key] for case, by in out.runs.items() for key in by}
    return save_output(folder, "safety", runs, document=DOCUMENT, extra={"safety_runs": index})


def load_suite_output(m: dict[str, Any], folder: Path) -> SuiteOutput:
    """The :class:`SuiteOutput` of a safety folder from its manifest (used by :func:`aev_ocp.load`)."""
    doc = read_document(m, folder)
    where = folder / DOCUMENT
    for key in ("settings", "cases", "rows"):
        if not isinstance(doc, dict) or key not in doc:
            raise LoadError(f"{where}: field {key!r} is missing (a safety document has it)")
    names = {f.name for f in dataclasses.fields(CaseRow)}
    try:
        rows = [CaseRow(**{k: v for k, v in r.items() if k in names}) for r in doc["rows"]]
        cases = [SafetyCase(**c) for c in doc["cases"]]
    except (TypeError, ValueError) as exc:
        raise LoadError(
            f"{where}: field 'rows' or 'cases' is damaged ({type(exc).__name__}: {str(exc)[:200]})"
        ) from None
    index = m.get("safety_runs") or {}
    if not isinstance(index, dict):
        raise LoadError(f"{folder / MANIFEST}: field 'safety_runs' = {str(index)[:60]!r} is not a table of runs")
    runs: dict[str, dict[str, Any]] = {}
    for label, r in (load_all(folder) if index else {}).items():
        case, key = index[label]
        runs.setdefault(case, {})[key] = r
    out = SuiteOutput(rows, dict(doc["settings"]), runs, cases)
    return out

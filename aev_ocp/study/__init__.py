"""Studies: sweeps, Pareto fronts and batches declared in one TOML file, run on all cores or on Dask.

>>> from aev_ocp.study import read_study, run_study, load_table
>>> study = read_study("studies/kappa_alpha_table1.toml")   # validates every point; nothing runs
>>> out = run_study(study, "results/study/kappa_alpha_table1", workers=2)
>>> rows = load_table(out.folder)                          # one dict per point × controller × vehicle

See :mod:`aev_ocp.study.spec` for the file format, :mod:`aev_ocp.study.runner` for executors and the
store, :mod:`aev_ocp.study.table` for the table, :mod:`aev_ocp.study.report` for figures and report.md and
:mod:`aev_ocp.study.cli` for the ``aev-ocp study`` command.
"""

from __future__ import annotations

from ..lazy import lazy_exports

#: name -> module that defines it (imported on first use: aev_ocp.lazy)
_EXPORTS = {
    "TRAJECTORIES": "aev_ocp.saved",
    "StudyOutput": "aev_ocp.saved",
    "load_study_output": "aev_ocp.saved",
    "EXECUTORS": "runner",
    "Store": "runner",
    "TimeLimitStop": "runner",
    "execute": "runner",
    "run_task": "runner",
    "Study": "spec",
    "StudyError": "spec",
    "parse_study": "spec",
    "read_study": "spec",
    "build_rows": "table",
    "load_table": "table",
    "write_table": "table",
    "run_study": "run",
    "STUDY_FILES": "run",
}
__all__ = [
    "EXECUTORS",
    "TRAJECTORIES",
    "Store",
    "Study",
    "StudyError",
    "StudyOutput",
    "TimeLimitStop",
    "build_rows",
    "execute",
    "load_study_output",
    "load_table",
    "parse_study",
    "read_study",
    "run_study",
    "run_task",
    "write_table",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

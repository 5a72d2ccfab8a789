"""Studies: sweeps, Pareto fronts and batches declared in one TOML file, run on all cores or on Dask.

>>> from aev_ocp.study import read_study, run_study, load_table
>>> study = read_study("studies/kappa_alpha_table1.toml")   # validates every point; nothing runs
>>> out = run_study(study, "results/study/kappa_alpha_table1", workers=2)
>>> rows = load_table(out.folder)                          # one dict per point × controller × vehicle

See :mod:`aev_ocp.study.spec` for the file format, :mod:`aev_ocp.study.runner` for executors and the
store, :mod:`aev_ocp.study.table` for the table and :mod:`aev_ocp.study.report` for figures and report.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .runner import EXECUTORS, Store, execute, run_task
from .spec import Study, StudyError, parse_study, read_study
from .table import build_rows, load_table, write_table


@dataclass
class StudyOutput:
    """What :func:`run_study` produced: folder, rows, files written, counts."""

    folder: Path
    rows: list[dict[str, Any]]
    files: list[Path]
    n_tasks: int
    n_failed: int


def run_study(study: Study | str | Path, out: str | Path | None = None, *, executor: str = "pool",
              workers: int | None = None, scheduler: str | None = None, report: bool = True,
              progress_stream: Any = None) -> StudyOutput:
    """Run (or resume) a study and write its table, figures and report.md into ``out``
    (default ``results/study/<name>``). executor: 'inprocess', 'pool' or 'dask' (see
    :func:`aev_ocp.study.runner.execute`)."""
    if not isinstance(study, Study):
        study = read_study(study)
    folder = Path(out) if out is not None else Path("results") / "study" / study.name
    tasks = study.tasks()
    results = execute(tasks, Store(folder), executor=executor, workers=workers, scheduler=scheduler,
                      name=study.name, progress_stream=progress_stream)
    rows = build_rows(study, results)
    files = list(write_table(rows, folder, study.axis_keys))
    if report:
        from .report import write_report

        files += write_report(study, rows, folder)
    failed = sum(1 for r in results.values() if r["status"] == "error")
    return StudyOutput(folder, rows, files, len(results), failed)


def cli_study(argv: list[str]) -> int:
    """``aev-ocp study STUDY.toml [...]`` (see :mod:`aev_ocp.study.cli`)."""
    from .cli import cli_study as _cli

    return _cli(argv)


__all__ = ["EXECUTORS", "Store", "Study", "StudyError", "StudyOutput", "build_rows", "cli_study", "execute",
           "load_table", "parse_study", "read_study", "run_study", "run_task", "write_table"]

"""Studies: sweeps, Pareto fronts and batches declared in one TOML file, run on all cores or on Dask.

>>> from aev_ocp.study import read_study, run_study, load_table
>>> study = read_study("studies/kappa_alpha_table1.toml")   # validates every point; nothing runs
>>> out = run_study(study, "results/study/kappa_alpha_table1", workers=2)
>>> rows = load_table(out.folder)                          # one dict per point × controller × vehicle

See :mod:`aev_ocp.study.spec` for the file format, :mod:`aev_ocp.study.runner` for executors and the
store, :mod:`aev_ocp.study.table` for the table and :mod:`aev_ocp.study.report` for figures and report.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .runner import EXECUTORS, Store, TimeLimitStop, execute, run_task
from .spec import Study, StudyError, parse_study, read_study
from .table import build_rows, load_table, write_table

TRAJECTORIES = "trajectories"  # sub-folder of a study's output: one loadable folder per task hash


@dataclass
class StudyOutput:
    """What :func:`run_study` produced (or :func:`aev_ocp.load` read back): folder, rows (one per point ×
    controller × vehicle, see :mod:`aev_ocp.study.table`), files written, counts; meta: the manifest's
    settings (the study file's document and path) and provenance, and ``output`` when loaded."""

    folder: Path
    rows: list[dict[str, Any]]
    files: list[Path]
    n_tasks: int
    n_failed: int
    meta: dict[str, Any] = field(default_factory=dict)

    def metrics(self) -> list[dict[str, Any]]:
        """The table rows (every §10 metric per point × controller × vehicle)."""
        return self.rows

    def trajectory(self, point: int, controller: str) -> Any:
        """The SimulationResult of one point under one controller, saved by ``run_study(...,
        trajectories=True)`` (``aev-ocp study --trajectories``); LoadError if it was not saved."""
        from ..saved import LoadError, load

        keys = {r["task_hash"] for r in self.rows if r["point"] == point and r["controller"] == controller}
        if not keys:
            raise LoadError(f"{self.folder}: no row for point {point} and controller {controller!r}")
        path = self.folder / TRAJECTORIES / keys.pop()
        if not path.is_dir():
            raise LoadError(f"{self.folder}: no trajectories saved for point {point}, controller {controller!r}; "
                            "rerun the study with --trajectories (trajectories=True)")
        return load(path)


def run_study(study: Study | str | Path, out: str | Path | None = None, *, executor: str = "pool",
              workers: int | None = None, scheduler: str | None = None, report: bool = True,
              progress_stream: Any = None, time_limit_s: float | None = None,
              trajectories: bool = False) -> StudyOutput:
    """Run (or resume) a study and write its table, figures, report.md and manifest.json (so that
    :func:`aev_ocp.load` reads it back) into ``out`` (default ``results/study/<name>``). executor:
    'inprocess', 'pool' or 'dask' (see :func:`aev_ocp.study.runner.execute`); time_limit_s [s]: stop
    (raising :class:`TimeLimitStop`) once passed, the finished tasks stored for a rerun to resume;
    trajectories: also save every task's trajectories (``trajectories/<hash>/``, see
    :meth:`StudyOutput.trajectory`)."""
    if not isinstance(study, Study):
        study = read_study(study)
    folder = Path(out) if out is not None else Path("results") / "study" / study.name
    tasks = study.tasks()
    results = execute(tasks, Store(folder), executor=executor, workers=workers, scheduler=scheduler,
                      name=study.name, progress_stream=progress_stream, time_limit_s=time_limit_s,
                      trajectories_dir=folder / TRAJECTORIES if trajectories else None)
    rows = build_rows(study, results)
    files = list(write_table(rows, folder, study.axis_keys))
    if report:
        from .report import write_report

        files += write_report(study, rows, folder)
    failed = sum(1 for r in results.values() if r["status"] == "error")
    from ..results import to_jsonable
    from ..saved import save_output

    settings = {"study": study.name, "file": study.file, "description": study.description, "axes": study.axes,
                "controllers": study.controllers, "reference": study.reference, "bases": study.bases,
                "n_points": len(study.points)}
    files += save_output(folder, "study", {}, settings=settings,
                         extra={"table": "table.jsonl", "n_tasks": len(results), "n_failed": failed,
                                "trajectories": TRAJECTORIES if trajectories else None})
    return StudyOutput(folder, rows, files, len(results), failed, {"settings": to_jsonable(settings)})


def load_study_output(manifest: dict[str, Any], folder: Path) -> StudyOutput:
    """The :class:`StudyOutput` of a study folder from its manifest (used by :func:`aev_ocp.load`)."""
    from ..saved import LoadError

    table = folder / Path(str(manifest.get("table") or "table.jsonl")).name
    if not table.is_file():
        raise LoadError(f"{folder}: the study's table {table.name} is missing")
    rows = load_table(table)
    files = sorted(p for p in folder.iterdir() if p.is_file())
    meta = {"settings": manifest.get("settings", {}),
            "output": {"path": str(folder), "kind": "study", "settings": manifest.get("settings", {}),
                       "provenance": manifest.get("provenance")}}
    return StudyOutput(folder, rows, files, int(manifest.get("n_tasks", 0)), int(manifest.get("n_failed", 0)), meta)


def cli_study(argv: list[str]) -> int:
    """``aev-ocp study STUDY.toml [...]`` (see :mod:`aev_ocp.study.cli`)."""
    from .cli import cli_study as _cli

    return _cli(argv)


__all__ = ["EXECUTORS", "Store", "Study", "StudyError", "StudyOutput", "TimeLimitStop", "build_rows", "cli_study",
           "execute", "load_study_output", "load_table", "parse_study", "read_study", "run_study", "run_task",
           "write_table"]

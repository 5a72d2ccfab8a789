"""``run_study``: run a study into its folder (the table, report and manifest); the package :mod:`aev_ocp.study`
exports it with the rest of the study API."""

from __future__ import annotations

import hashlib

from pathlib import Path
from typing import Any

from ..saved import TRAJECTORIES, StudyOutput
from .runner import Store, check_executor, execute
from .spec import Study, read_study
from .table import build_rows, write_table


def run_study(
    study: Study | str | Path,
    out: str | Path | None = None,
    *,
    executor: str = "pool",
    workers: int | None = None,
    scheduler: str | None = None,
    report: bool = True,
    progress_stream: Any = None,
    time_limit_s: float | None = None,
    trajectories: bool = False,
) -> StudyOutput:
    """Run (or resume) a study and write its table, figures, report.md and manifest.json (so that
    :func:`aev_ocp.load` reads it back) into ``out`` (default ``results/study/<name>``). executor:
    'inprocess', 'pool' or 'dask' (see :func:`aev_ocp.study.runner.execute`); time_limit_s [s]: stop
    (raising :class:`TimeLimitStop`) once passed, the finished tasks stored for a rerun to resume;
    trajectories: also save every task's trajectories (``trajectories/<hash>/``, see
    :meth:`StudyOutput.trajectory`)."""
    check_executor(executor, workers, scheduler)  # before the folder is claimed
    if not isinstance(study, Study):
        study = read_study(study)
    from ..results import claim_output_dir, default_output_dir, output_lock

    folder = Path(out) if out is not None else default_output_dir("study", study.name)
    with output_lock(folder):  # one study at a time per folder
        # a folder of another study or of the user's own files is refused; the same study resumes
        claim_output_dir(
            folder, "study", study.name, study.file if Path(study.file).is_file() else None, list(STUDY_FILES)
        )
        return _run_study(
            study,
            folder,
            executor=executor,
            workers=workers,
            scheduler=scheduler,
            report=report,
            progress_stream=progress_stream,
            time_limit_s=time_limit_s,
            trajectories=trajectories,
        )


#: Files of a study folder that a foreign folder must not already hold (besides figures).
STUDY_FILES = ("table.csv", "table.jsonl", "report.md", "manifest.json", "seeds.json")


def _run_study(
    study: Study,
    folder: Path,
    *,
    executor: str,
    workers: int | None,
    scheduler: str | None,
    report: bool,
    progress_stream: Any,
    time_limit_s: float | None,
    trajectories: bool,
) -> StudyOutput:
    tasks = study.tasks()
    results = execute(
        tasks,
        Store(folder),
        executor=executor,
        workers=workers,
        scheduler=scheduler,
        name=study.name,
        progress_stream=progress_stream,
        time_limit_s=time_limit_s,
        trajectories_dir=folder / TRAJECTORIES if trajectories else None,
    )
    rows = build_rows(study, results)
    files = list(write_table(rows, folder, study.axis_keys))
    from .seeds import study_seeds, write_seeds

    seeds = study_seeds(study, rows)  # a seed axis: the metrics over the seeds with intervals (issue 33.5)
    if seeds is not None:
        files.append(write_seeds(folder, seeds))
    if report:
        from .report import write_report

        files += write_report(study, rows, folder)
    failed = sum(1 for r in results.values() if r["status"] == "error")
    from ..results import to_jsonable
    from ..saved import save_output

    settings = {
        "study": study.name,
        "file": study.file,
        "description": study.description,
        "axes": study.axes,
        "controllers": study.controllers,
        "reference": study.reference,
        "bases": study.bases,
        "n_points": len(study.points),
    }
    files += save_output(
        folder,
        "study",
        {},
        settings=settings,
        extra={
            "table": "table.jsonl",
            # the table this manifest describes: load() refuses another study's table put in its place
            "table_sha256": hashlib.sha256(files[1].read_bytes()).hexdigest(),
            "n_tasks": len(results),
            "n_failed": failed,
            "trajectories": TRAJECTORIES if trajectories else None,
        },
    )
    return StudyOutput(folder, rows, files, len(results), failed, {"settings": to_jsonable(settings)})

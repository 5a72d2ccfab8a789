"""``aev-ocp study STUDY.toml [--out DIR] [--workers N | --dask-local N | --scheduler ADDRESS | --in-process]
[--set KEY=VALUE ...] [--time-limit S]``: run or resume a study; writes table.csv, table.jsonl, figures,
report.md and manifest.json (``aev_ocp.load(OUT)`` returns the table)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

# the command line's one error format, exit codes and parser (aev_ocp/cli.py)
from ..console import (
    EXIT_BAD_INPUT,
    EXIT_FAILED_RUN,
    EXIT_OK,
    add_executor_options,
    add_set_option,
    bad_input,
    executor_options,
)
from ..console import OneLineParser as _Parser
from ..console import error_line as _err
from ..console import warning_line


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp study``."""
    p = _Parser(
        prog="aev-ocp study",
        description="Run or resume a study (points x controllers) on a local process "
        "pool or on Dask; writes table.csv, table.jsonl, figures and report.md. Rerun the same command "
        "to resume: stored points are not recomputed.",
    )
    p.add_argument("study", help="a study .toml file (e.g. studies/kappa_alpha_table1.toml)")
    p.add_argument("--out", default=None, help="output folder (default results/study/<name>); rerun to resume")
    add_executor_options(p)
    add_set_option(
        p,
        "override a scenario key at every point, e.g. --set simulation.t_end_s=60 (repeatable). "
        "Precedence: command line over study file over scenario file; a key that an axis "
        "sweeps or a [[controllers.mpc]] entry sets is refused",
    )
    p.add_argument("--no-report", action="store_true", help="write the table only (no figures, no report.md)")
    p.add_argument(
        "--trajectories",
        action="store_true",
        help="also save every task's trajectories (trajectories/<hash>/, loadable with aev_ocp.load or "
        "StudyOutput.trajectory(point, controller)); stored tasks without them are run again",
    )
    p.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="S",
        help="wall-clock limit [s]: past it, pending tasks are cancelled; finished ones are stored and "
        "a rerun resumes (default: none)",
    )
    return p


def cli_study(argv: list[str]) -> int:
    """Entry point; exit 0 when every task ran (events are results), 1 if a task failed, 2 for bad input."""
    from ..overrides import OverrideError, parse_assignments
    from ..scenarios import ScenarioError
    from . import StudyError, TimeLimitStop, read_study, run_study

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    if a.time_limit is not None and not (math.isfinite(a.time_limit) and a.time_limit > 0):
        _err(f"--time-limit {a.time_limit:g}: must be a number of seconds > 0")
        return EXIT_BAD_INPUT
    from ..params import ParameterError

    try:
        kw = executor_options(a)
    except ParameterError as exc:
        _err(str(exc))
        return EXIT_BAD_INPUT
    try:
        study = read_study(a.study, sets=parse_assignments(a.sets))
    except (StudyError, ScenarioError, OverrideError) as exc:
        _err(str(exc))
        return EXIT_BAD_INPUT
    for w in study.warnings:
        warning_line(w)
    if kw["executor"] == "dask":
        try:
            import dask.distributed  # noqa: F401
        except ImportError:
            from .runner import dask_missing_message

            _err(dask_missing_message())
            return EXIT_BAD_INPUT
        if a.scheduler is not None:
            from .runner import check_scheduler_address

            check_scheduler_address(a.scheduler)  # before the folder is claimed
    print(
        f"[study {study.name}] {len(study.points)} points × {len(study.controllers)} controllers "
        f"({', '.join(c.label for c in study.controllers)}), executor {kw['executor']}",
        file=sys.stderr,
        flush=True,
    )
    try:
        out = run_study(
            study, a.out, report=not a.no_report, time_limit_s=a.time_limit, trajectories=a.trajectories, **kw
        )
    except TimeLimitStop as exc:
        _err(f"stopped by --time-limit {a.time_limit:g} s: {exc}; rerun the same command to resume")
        return EXIT_FAILED_RUN
    except KeyboardInterrupt:
        _err("interrupted: finished tasks are stored; rerun the same command to resume")
        return 130
    except OSError as exc:
        return bad_input(exc)
    except RuntimeError as exc:  # the executor failed (a broken pool, a cluster that cannot import aev_ocp)
        _err(f"{exc}; finished tasks are stored, rerun to resume")
        return EXIT_FAILED_RUN
    bad = [r for r in out.rows if r["status"] != "ok"]
    print(
        f"{out.n_tasks} tasks, {out.n_failed} failed, {len({(r['point'], r['controller']) for r in bad})} "
        f"ended by an event or error"
    )
    print(f"wrote {out.folder}/table.csv, table.jsonl" + ("" if a.no_report else ", report.md and figures"))
    return EXIT_FAILED_RUN if out.n_failed else EXIT_OK


def _with_sets(path: str, sets: dict, parse_study=None):  # noqa: ANN001, ANN202
    """The study with ``--set`` overrides applied over the study file's (see :data:`aev_ocp.study.spec.PRECEDENCE`)."""
    from . import read_study

    return read_study(path, sets=sets)


def cli_sumo_seeds(argv: list[str]) -> int:
    """``aev-ocp sumo SCENARIO --seeds N [...]`` (the top-level CLI sends a SUMO command with ``--seeds`` here: it
    runs through the study layer, which the SUMO folder does not import)."""
    from ..sumo.cli import prepare

    args, sc, out = prepare(argv)
    return run_sumo_seeds(sc, args, out)


def run_sumo_seeds(sc: Any, args: Any, out: Path) -> int:
    """``--seeds N``: every point on N seeds as study tasks (resumable store under ``out``), the table of means and
    95 % intervals printed and written (seeds.md, traffic.json, seeds.csv)."""
    from ..sumo.cli import seed_points, seeds_csv, seeds_markdown
    from ..sumo.run import FAILED_STATUSES
    from ..results import write_atomic
    from .traffic import sumo_tasks
    from .traffic_study import run_traffic_study

    shares, ctrls, seeds = seed_points(sc, args.sweep, args.seeds)
    path = sc.source if sc.source is not None else args.scenario
    tasks = sumo_tasks(path, shares, ctrls, seeds, sc.spec.t_end_s)
    kw: dict[str, Any] = {"executor": "inprocess"} if args.in_process else {"workers": args.workers}
    results, rows = run_traffic_study(tasks, out, name=f"sumo {sc.name} over {len(seeds)} seeds", **kw)
    md = seeds_markdown(sc.name, rows, seeds, sc.spec.t_end_s)
    write_atomic(out / "seeds.md", md)
    write_atomic(out / "seeds.csv", seeds_csv(tasks, results))
    print(md)
    print(f"wrote {out}/seeds.md, seeds.csv, traffic.json ({len(tasks)} runs)")
    return 1 if any(r["status"] in (*FAILED_STATUSES, "error") for r in results.values()) else 0

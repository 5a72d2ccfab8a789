"""``aev-ocp sumo SCENARIO.toml``: one SUMO run, ``--sweep`` over share × controller in worker processes, or
``--seeds N`` over N seeds through the study layer (:func:`aev_ocp.study.traffic.sumo_tasks`): each point's metrics
as the mean with a 95 % t interval over the seeds and, against the all-SUMO run (share 0) on the same seeds, paired
verdicts."""

from __future__ import annotations

import argparse
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from .. import interrupts
from ..console import OneLineParser
from ..limits import check_local_workers
from ..results import claim_output_dir, default_output_dir
from . import SumoError, require_sumo
from .scenario import SumoScenario, load_sumo_scenario


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``aev-ocp sumo``."""
    p = OneLineParser(
        prog="aev-ocp sumo",
        description="Drive the toolkit's controllers inside SUMO: a "
        "scenario file with a [sumo] table (shipped: sumo_ring, sumo_merge).",
        epilog="Exit status: 0 when the run (every sweep point) went to its end, events such as emergency braking "
        "counted; 1 after a collision, a teleport, a battery event, a failed point or an interruption (results up to "
        "then are written); 2 for bad input.",
    )
    p.add_argument("scenario", help="a SUMO scenario .toml file, or the name of a shipped one (sumo_ring, sumo_merge)")
    p.add_argument("--out", default=None, help="output folder (default: results/<scenario name>/)")
    p.add_argument("--t-end-s", type=float, default=None, metavar="S", help="simulated time [s] (over sumo.t_end_s)")
    p.add_argument(
        "--share", type=float, default=None, help="share of vehicles the toolkit drives, 0-1 (over sumo.share)"
    )
    p.add_argument("--controller", default=None, help="law name, 'mpc' or 'module:function' (over sumo.controller)")
    p.add_argument(
        "--sweep",
        action="store_true",
        help="run every share × controller of [sumo.sweep] (one SUMO per worker process)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=None,
        metavar="N",
        help="run every point on N seeds (sumo.seed, sumo.seed + 1, …) and the all-SUMO run on the same seeds, "
        "through the study layer; print and write each metric's mean and 95 %% interval (seeds.md, traffic.json, "
        "seeds.csv)",
    )
    p.add_argument("--in-process", action="store_true", help="--seeds: run every point in this process")
    p.add_argument(
        "--workers", type=int, default=None, help="worker processes of --sweep and --seeds (default: the cores)"
    )
    p.add_argument("--no-plots", action="store_true", help="skip the space-time diagrams")
    return p


def _with_options(sc: SumoScenario, args: argparse.Namespace) -> SumoScenario:
    """The scenario with the command line's --t-end-s, --share and --controller over its [sumo] keys, checked as the
    file's keys are (the [mpc] a "mpc" controller needs, the size budget); an option a sweep would ignore is refused."""
    import dataclasses

    from .scenario import _controller, check_sumo_spec, mpc_for
    from ..scenarios import TableReader

    spec = sc.spec
    if args.sweep:
        given = [o for o, v in (("--share", args.share), ("--controller", args.controller)) if v is not None]
        if given:
            raise SumoError(
                f"{' and '.join(given)} cannot be combined with --sweep: a sweep runs every share x controller of "
                "[sumo.sweep] (drop --sweep to run one point)"
            )
    seeds, in_process = getattr(args, "seeds", None), getattr(args, "in_process", False)
    if not args.sweep and args.workers is not None and seeds is None:
        raise SumoError("--workers applies to --sweep only (and to --seeds; one run is one SUMO process)")
    if seeds is not None and (isinstance(seeds, bool) or seeds < 2):
        raise SumoError(f"--seeds = {seeds!r} is not allowed: must be an integer >= 2 (an interval needs 2 seeds)")
    if in_process and (seeds is None or args.workers is not None):
        raise SumoError("--in-process applies to --seeds only, without --workers")
    if args.workers is not None:
        check_local_workers(args.workers)
    if args.t_end_s is not None:
        if not (math.isfinite(args.t_end_s) and args.t_end_s >= spec.step_s):
            raise SumoError(
                f"--t-end-s = {args.t_end_s!r} is not allowed: must be a finite number >= sumo.step_s = {spec.step_s:g}"
            )
        spec = dataclasses.replace(spec, t_end_s=args.t_end_s)
    if args.share is not None:
        if not (0 <= args.share <= 1):
            raise SumoError(f"--share = {args.share!r} is not allowed: must be in [0, 1]")
        spec = dataclasses.replace(spec, share=args.share)
    if args.controller is not None:
        spec = dataclasses.replace(
            spec, controller=_controller(TableReader({}, "", "--controller"), "controller", args.controller)
        )
    keys = {"t_end_s": "--t-end-s" if args.t_end_s is not None else None}
    check_sumo_spec(spec, str(sc.source or sc.name), keys)
    return dataclasses.replace(sc, spec=spec, mpc=mpc_for(spec, sc.ev, sc.mpc, str(sc.source or sc.name)))


def run_one(sc: SumoScenario, out: Path, plots: bool = True, progress: Any = None) -> Any:
    """Run one scenario and write its folder; returns the SumoRun."""
    from .outputs import save_space_time, save_sumo, write_report
    from .run import run_sumo

    run = run_sumo(sc, out / "network", progress=progress)
    save_sumo(run, out)
    figs = save_space_time(run, out) if plots else []
    write_report(run, out, figs)
    return run


def _point(sc: SumoScenario, share: float, controller: str, out: str, plots: bool) -> dict[str, Any]:
    """One sweep point in a worker process (one SUMO per process)."""
    from .outputs import sweep_row

    label = f"share{share:g}_{controller.replace(':', '_')}"
    try:
        run = run_one(sc.with_point(share, controller), Path(out) / "points" / label, plots)
        return sweep_row(share, controller, run)
    except SumoError as exc:
        return sweep_row(share, controller, None, str(exc))


def prepare(argv: list[str]) -> tuple[argparse.Namespace, SumoScenario, Path]:
    """The parsed options, the scenario with them and the claimed output folder of ``aev-ocp sumo`` (errors raised
    for the CLI's one-line handler)."""
    args = build_parser().parse_args(argv)
    require_sumo()
    sc = _with_options(load_sumo_scenario(args.scenario), args)
    out = Path(args.out) if args.out else default_output_dir(sc.name)
    claim_output_dir(out, "sumo", sc.name, str(sc.source) if sc.source else None)
    return args, sc, out


def cli_sumo(argv: list[str]) -> int:
    """Entry of ``aev-ocp sumo``; returns the exit code (errors are raised for the CLI's one-line handler)."""
    from .run import FAILED_STATUSES

    args, sc, out = prepare(argv)
    if args.seeds is not None:  # aev-ocp sumo --seeds runs in aev_ocp.study.cli (the study layer)
        raise SumoError(
            "--seeds runs through the study layer: aev_ocp.study.cli.cli_sumo_seeds (aev-ocp sumo ... --seeds N)"
        )
    if not args.sweep:

        def progress(t: float, t_end: float) -> None:
            if sys.stderr.isatty():
                print(f"\r{t:.0f}/{t_end:.0f} s simulated", end="", file=sys.stderr, flush=True)

        run = run_one(sc, out, not args.no_plots, progress)
        if sys.stderr.isatty():
            print(file=sys.stderr)
        ft = run.fleet_totals()
        print(
            f"{run!r}: status {run.status}\n  battery energy {ft['all']['battery_energy_kWh_per_100km']:.4g} kWh/100 km (toolkit's "
            f"vehicles {ft['controlled']['battery_energy_kWh_per_100km']:.4g}, SUMO's "
            f"{ft['sumo']['battery_energy_kWh_per_100km']:.4g}), pack heat {ft['all']['heat_pack_J_per_km']:.4g} J/km, "
            f"charge throughput {ft['all']['charge_throughput_Ah_per_km']:.4g} Ah/km, mean speed "
            f"{ft['all']['mean_speed_mps']:.4g} m/s, collisions {ft['all']['collisions']}, teleports "
            f"{ft['all']['teleports']}, emergency stops {ft['all']['emergency_braking_events']}, lane-end stops "
            f"{ft['all']['lane_end_stop_events']}, currents beyond the cell's limit {ft['all']['current_limit_events']}"
            f"\n  wrote {out}/ (report.md, metrics.csv, fleet.json, manifest.json)"
        )
        return 1 if run.status in FAILED_STATUSES else 0
    from .outputs import write_sweep

    s = sc.spec
    shares = list(s.sweep_share) or [s.share]
    ctrls = list(s.sweep_controller) or [s.controller]
    points = [(sh, c) for c in ctrls for sh in shares]
    rows: list[dict[str, Any]] = []
    workers = args.workers if args.workers is not None else min(len(points), os.cpu_count() or 1)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        # the workers start with SIGINT blocked (as a study's): a Ctrl-C reaches the whole process group, and this
        # process stops them; a Ctrl-C while one is half started is honoured once all can be stopped
        with interrupts.deferred(), interrupts.sigint_blocked():
            futs = {pool.submit(_point, sc, sh, c, str(out), not args.no_plots): (sh, c) for sh, c in points}
        try:
            for f in as_completed(futs):
                rows.append(f.result())
                r = rows[-1]
                print(
                    f"share {r['share']:g}, {r['controller']}: {r['status']}"
                    + (
                        f", battery energy {r['battery_energy_kWh_per_100km']:.4g} kWh/100 km, "
                        f"{r['mean_speed_mps']:.4g} m/s"
                        if r["status"] == "ok"
                        else f" ({r.get('message', '')})"
                    ),
                    flush=True,
                )
        except KeyboardInterrupt:  # end the running SUMO workers now (a wait lets each finish its run: ~35 s)
            interrupts.stop_pool(pool)
            raise
    order = {p: i for i, p in enumerate(points)}
    rows.sort(key=lambda r: order[(r["share"], r["controller"])])
    write_sweep(rows, out, sc.name)
    print(f"wrote {out}/sweep.md, sweep.csv ({len(rows)} points)")
    return 1 if any(r["status"] in FAILED_STATUSES for r in rows) else 0


def seed_points(sc: SumoScenario, sweep: bool, n: int) -> tuple[list[float], list[str], list[int]]:
    """(shares, controllers, seeds) of ``--seeds n``: the scenario's point (``sweep``: every share × controller of
    [sumo.sweep]) and share 0, the all-SUMO reference of the paired verdicts; seeds sumo.seed … sumo.seed + n − 1."""
    s = sc.spec
    shares = (list(s.sweep_share) or [s.share]) if sweep else [s.share]
    ctrls = (list(s.sweep_controller) or [s.controller]) if sweep else [s.controller]
    shares = [0.0] + [x for x in shares if x != 0]
    return shares, ctrls, list(range(s.seed, s.seed + n))


#: The columns of seeds.md (the field's metrics a SUMO run reports; SI).
SEED_METRICS = (
    "battery_energy_kWh_per_100km",
    "mean_speed_mps",
    "speed_std_mps",
    "throughput_veh_per_h",
    "braking_events_per_veh_km",
)


def seeds_markdown(name: str, rows: list[dict[str, Any]], seeds: list[int], t_end_s: float) -> str:
    """seeds.md: each point's metrics over the seeds (mean [95 % t interval], the verdict against share 0)."""
    from ..ring.field import table_markdown

    metrics = [m for m in SEED_METRICS if rows and m in rows[0]]
    return "\n".join(
        [
            f"# {name} over {len(seeds)} seeds ({seeds[0]}–{seeds[-1]}), {t_end_s:g} s",
            "",
            "Run: share of the cars the toolkit drives and its controller (0.0 sumo: SUMO's drivers alone). Each "
            "metric: the mean over the seeds [95 % t interval]; after it the paired verdict against the all-SUMO "
            "run on the same seeds (better/worse only when the interval of the difference excludes 0, else tie). "
            "failed: runs with an event (an emergency stop, a lane-end stop, a collision, a teleport: its status in "
            "seeds.csv), left out of the means.",
            "",
            table_markdown(rows, metrics),
            "",
        ]
    )


def seeds_csv(tasks: list[Any], results: dict[str, dict[str, Any]]) -> str:
    """seeds.csv: one line per run (share, controller, seed, status and the metrics of :data:`SEED_METRICS`)."""
    import csv
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["share", "controller", "seed", "status", *SEED_METRICS])
    for t in tasks:
        r = results.get(t.key) or {"status": "missing", "metrics": []}
        m = r["metrics"][0] if r.get("metrics") else {}
        v = t.spec["values"]
        w.writerow([v["share"], t.controller, v["seed"], r["status"], *(m.get(k, "") for k in SEED_METRICS)])
    return buf.getvalue()


__all__ = ["build_parser", "cli_sumo", "prepare", "run_one", "seed_points", "seeds_csv", "seeds_markdown"]

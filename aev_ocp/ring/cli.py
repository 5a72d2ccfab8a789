"""``aev-ocp ring sugiyama | stern | sweep | SCENARIO.toml [--t-end-s S] [--seed K] [--out DIR] [--no-plots]``.

The ring experiments (see :mod:`aev_ocp.ring.run`): ``sugiyama`` (22 human drivers on 230 m: the jam
emerges; and on 600 m, where uniform flow is linearly stable: it does not), ``stern`` (the same ring all-human
and with one AEV under each AEV controller, with a space-time diagram of each run), ``sweep`` (penetration
0–5 AEVs of 22, spread evenly, × ring lengths; ``--aev`` the controller). Writes ring.json (fleet metrics, SI),
the runs' trajectories with a manifest (``aev_ocp.load(out)`` reads them back, :mod:`aev_ocp.ring.outputs`)
and the PNGs to ``--out``; prints the fleet table. A ring scenario file (:mod:`aev_ocp.ring.scenario`; shipped:
``ring_sugiyama``, ``ring_stern``) runs its own runs (``--t-end-s`` overrides its horizon; ``--seed`` is the file's). Exit codes: 0 ok, 1 a run stopped on an event, 2 bad input.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from ..console import EXIT_FAILED_RUN, EXIT_OK, bad_input
from ..console import OneLineParser as _Parser
from ..limits import check_ring_size, memory_limit_bytes
from ..params import ParameterError
from ..progress import Progress, TimeLimitReached, check_time_limit, time_limited
from ..results import claim_output_dir, default_output_dir
from ..scenarios import ScenarioError

COLUMNS = (
    "speed_std_mps",
    "mean_speed_mps",
    "vehicles_stopped",
    "braking_events",
    "braking_events_per_veh_km",
    "throughput_veh_per_h",
    "battery_energy_kWh_per_100km",
    "heat_pack_J_per_km",
    "soc_used_mean",
    "min_gap_m",
    "wave_speed_mps",
    "status",
)


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp ring``."""
    p = _Parser(prog="aev-ocp ring", description="mixed traffic on a ring road: the Sugiyama and Stern experiments")
    p.add_argument(
        "experiment",
        metavar="EXPERIMENT|SCENARIO",
        help="sugiyama, stern, sweep, or a ring scenario file / shipped name (ring_sugiyama, ring_stern)",
    )
    p.add_argument("--t-end-s", type=float, default=None, help="simulated time [s] (default 600, or the scenario's)")
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="seed of the human drivers' acceleration noise (default 0; a scenario file has its own ring.seed)",
    )
    p.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="S",
        help="stop after S seconds of wall-clock time (exit 1, nothing written); default none",
    )
    p.add_argument(
        "--aev",
        default="followerstopper",
        help="sweep: the AEV controller (followerstopper, pi-saturation, proposed, ovfl, mpc; default followerstopper)",
    )
    p.add_argument(
        "--penetration",
        type=int,
        action="append",
        default=None,
        metavar="K",
        help="sweep: number of AEVs among the 22 (repeatable; default 0 1 2 3 4 5)",
    )
    p.add_argument(
        "--length-m",
        type=float,
        action="append",
        default=None,
        metavar="L",
        help="sweep: ring length [m] (repeatable; default 230 260 300)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=None,
        metavar="N",
        help="a scenario file: run every run with seeds 0 … N−1 (N >= 2; 10 for the tables) and write the field's "
        "metrics with 95 %% intervals and verdicts against the all-human ring (ring_seeds.json, ring_seeds.md)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the space-time diagrams")
    p.add_argument("--out", default=None, help="output folder (default results/ring/<experiment>)")
    return p


def _width(key: str) -> int:
    """A column as wide as its full header (the key with its unit), at least 10 characters."""
    return max(10, len(key))


def _header() -> str:
    """The table's header: every column's full key, unit included (never cut)."""
    return f"{'run':<24}" + "  ".join(f"{k:>{_width(k)}}" for k in COLUMNS)


def _row(label: str, fleet: dict[str, Any]) -> str:
    cells = []
    for k in COLUMNS:
        v = fleet[k]
        cells.append(f"{v:.4g}" if isinstance(v, float) else str(v))
    return f"{label:<24}" + "  ".join(f"{c:>{_width(k)}}" for c, k in zip(cells, COLUMNS))


def cli_ring(argv: list[str]) -> int:
    """Entry point of ``aev-ocp ring``; returns the exit code."""
    from .run import SUGIYAMA_N
    from .simulate import RingOptions

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        memory_limit_bytes()  # a bad $AEV_OCP_MAX_MEMORY_GB is refused before anything else, as simulate and mpc do
        if a.t_end_s is not None and not (math.isfinite(a.t_end_s) and 0 < a.t_end_s <= 36_000):
            raise ParameterError(f"--t-end-s {a.t_end_s!r}: must be in (0, 36000] s")
        if a.seed is not None and a.seed < 0:  # NumPy's generators take seeds >= 0 only
            raise ParameterError(f"--seed {a.seed}: must be an integer >= 0")
        time_limit = check_time_limit(a.time_limit)
        sc = None
        if a.experiment not in ("sugiyama", "stern", "sweep"):
            from .scenario import load_ring_scenario

            if a.seed is not None:  # never ignored silently: the file's runs are reproducible from the file alone
                raise ParameterError(
                    f"--seed {a.seed}: a ring scenario file sets its seed with ring.seed; --seed applies to the "
                    "sugiyama, stern and sweep experiments"
                )
            sc = load_ring_scenario(a.experiment)
            if a.seeds is not None:
                return _cli_seeds(a, sc, time_limit)
        else:
            if a.seeds is not None:
                raise ParameterError("--seeds applies to a ring scenario file (ring_calibrated, ring_stern, ...)")
            a.t_end_s = 600.0 if a.t_end_s is None else a.t_end_s
            a.seed = 0 if a.seed is None else a.seed
        for opt, given in (
            ("--aev", a.aev != "followerstopper"),
            ("--penetration", a.penetration),
            ("--length-m", a.length_m),
        ):
            if given and a.experiment != "sweep":
                raise ParameterError(f"{opt} applies to the sweep experiment only (it would be ignored here)")
        # the budget before any work (RingSimulator.run checks each run again)
        if sc is not None:
            t_key = "--t-end-s" if a.t_end_s is not None else "ring.t_end_s"
            t_end = a.t_end_s if a.t_end_s is not None else sc.spec.t_end_s
            check_ring_size(sc.spec.vehicles, t_end, sc.spec.dt_out_s, ("ring.vehicles", t_key, "ring.dt_out_s"))
        else:
            check_ring_size(
                SUGIYAMA_N,
                a.t_end_s,
                RingOptions().dt_out_s,
                (f"the experiment has {SUGIYAMA_N}", "--t-end-s", "dt_out_s"),
            )
        out = Path(a.out) if a.out else default_output_dir("ring", sc.name if sc is not None else a.experiment)
        claim_output_dir(
            out,
            "ring",
            sc.name if sc is not None else a.experiment,  # before any work
            str(sc.source) if sc is not None and sc.source else None,
            ["ring.json", "manifest.json", "trajectories.npz", "space_time_*.png"],
        )
        clock = Progress("", time_limit_s=time_limit)
        with time_limited(clock):  # the compiled ring polls the clock while it integrates
            runs, doc = _runs(a, sc)
        out.mkdir(parents=True, exist_ok=True)
        from .outputs import save_ring_output

        files = save_ring_output(out, runs, doc)  # ring.json, trajectories.npz, manifest.json (aev_ocp.load)
        if not a.no_plots and a.experiment != "sweep" and not (sc is not None and sc.spec.sweep_aevs):
            from .plots import space_time

            for r in runs:
                name = "space_time_" + "".join(c if c.isalnum() else "_" for c in r.label) + ".png"
                space_time(r.result, out / name, r.label)
                files.append(out / name)
    except TimeLimitReached:
        print(
            f"aev-ocp ring: stopped by --time-limit {a.time_limit:g} s before the runs finished; nothing written",
            file=sys.stderr,
        )
        return EXIT_FAILED_RUN
    except (ParameterError, ScenarioError, OSError) as exc:
        return bad_input(exc)
    print(_header())
    for r in runs:
        print(_row(r.label, r.fleet))
    print(f"wrote {len(files)} files to {out}/")
    bad = [r for r in runs if r.fleet["status"] != "ok"]
    for r in bad:
        print(f"aev-ocp ring: {r.label}: run stopped ({r.fleet['status']})", file=sys.stderr)
    return EXIT_FAILED_RUN if bad else EXIT_OK


def _cli_seeds(a: argparse.Namespace, sc: Any, time_limit: float | None) -> int:
    """``aev-ocp ring SCENARIO --seeds N``: the field's metrics over seeds (aev_ocp.ring.field)."""
    from ..results import write_atomic, write_json
    from .field import scenario_over_seeds, scenario_seed_rows, table_markdown

    if not 2 <= a.seeds <= 1000:
        raise ParameterError(f"--seeds {a.seeds}: must be an integer in [2, 1000]")
    t_end = a.t_end_s if a.t_end_s is not None else sc.spec.t_end_s
    check_ring_size(sc.spec.vehicles, t_end, sc.spec.dt_out_s, ("ring.vehicles", "--t-end-s", "ring.dt_out_s"))
    out = Path(a.out) if a.out else default_output_dir("ring", sc.name + "_seeds")
    claim_output_dir(out, "ring", sc.name, str(sc.source) if sc.source else None, ["ring_seeds.json", "ring_seeds.md"])
    clock = Progress("", time_limit_s=time_limit)
    try:
        with time_limited(clock):
            runs = scenario_over_seeds(sc, range(a.seeds), a.t_end_s)
    except TimeLimitReached:
        print(f"aev-ocp ring: stopped by --time-limit {a.time_limit:g} s; nothing written", file=sys.stderr)
        return EXIT_FAILED_RUN
    rows = scenario_seed_rows(runs, sc)
    md = table_markdown(rows)
    out.mkdir(parents=True, exist_ok=True)
    write_json(
        out / "ring_seeds.json", {"scenario": sc.name, "seeds": list(range(a.seeds)), "rows": rows, "runs": runs}
    )
    write_atomic(out / "ring_seeds.md", md + "\n")
    print(md)
    print(f"wrote 2 files to {out}/")
    failed = sum(r["failed"] for r in rows)
    if failed:
        print(f"aev-ocp ring: {failed} runs stopped at an event (see ring_seeds.json)", file=sys.stderr)
    return EXIT_FAILED_RUN if failed else EXIT_OK


def _runs(a: argparse.Namespace, sc: Any) -> tuple[list[Any], dict[str, Any]]:
    """The runs of ``aev-ocp ring`` (a scenario file's, or an experiment's) and the document of ring.json."""
    from .run import STABLE_LENGTH_M, human_ring, make_aev, relative_to, run_ring, stern, sugiyama
    from .simulate import uniform_speed_mps

    runs: list[Any]
    doc: dict[str, Any] = {"experiment": a.experiment, "t_end_s": a.t_end_s, "seed": a.seed}
    if sc is not None:
        from .run import run_ring_scenario

        runs = run_ring_scenario(sc, t_end_s=a.t_end_s)
        doc.update(
            {
                "experiment": sc.name,
                "scenario": str(sc.source),
                "t_end_s": runs[0].result.t_s[-1] if a.t_end_s is None else a.t_end_s,
                "seed": sc.spec.seed,
                "initial": runs[0].result.initial.perturbation,
            }
        )
        if runs[0].label == "all human" and len(runs) > 1:
            doc["relative_to_all_human"] = {r.label: relative_to(runs[0].fleet, r.fleet) for r in runs[1:]}
    elif a.experiment == "sugiyama":
        runs = sugiyama(a.t_end_s, seed=a.seed)
        doc["stable_length_m"] = STABLE_LENGTH_M
    elif a.experiment == "stern":
        runs = stern(t_end_s=a.t_end_s, seed=a.seed)
        doc["relative_to_all_human"] = {r.label: relative_to(runs[0].fleet, r.fleet) for r in runs[1:]}
    else:
        pens = a.penetration if a.penetration is not None else [0, 1, 2, 3, 4, 5]
        lengths = a.length_m if a.length_m is not None else [230.0, 260.0, 300.0]
        for k in pens:
            if not 0 <= k <= 22:
                raise ParameterError(f"--penetration {k}: must be an integer in [0, 22]")
        for L in lengths:
            if not (math.isfinite(L) and L > 22 * 5.0):
                raise ParameterError(f"--length-m {L!r}: must exceed 110 m (22 vehicles of 5 m)")
        runs = []
        for L in lengths:
            base = human_ring(L, seed=a.seed)
            r_mps = 0.85 * uniform_speed_mps(base)
            for k in pens:
                idx = sorted({int(round(j * 22 / k)) for j in range(k)}) if k else []
                ring = human_ring(L, aevs={i: make_aev(a.aev, base.ev, r_mps) for i in idx}, seed=a.seed)
                runs.append(run_ring(ring, a.t_end_s, label=f"L={L:g} m, {k} AEV"))
                runs[-1].fleet.update({"length_m": L, "density_per_km": ring.density_per_km, "aevs": k})
    return runs, doc

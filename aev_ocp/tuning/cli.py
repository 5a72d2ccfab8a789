"""``aev-ocp tune``: the drive-cycle tuning (default), ``--ring`` the ring's, ``--safety-suite`` the drive-cycle
tuned sets through the whole safety suite afterwards."""

from __future__ import annotations

import argparse
import sys
from typing import Any, Sequence

from ..params import ParameterError
from .core import TUNING_TABLE, _fmt


def _bounds_arg(items: Sequence[str]) -> dict[str, dict[str, tuple[float, float]]]:
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for it in items:
        try:
            key, rng = it.split("=", 1)
            ctrl, name = key.strip().split(".", 1)
            lo, hi = (float(x) for x in rng.split(":"))
        except ValueError:
            raise ParameterError(
                f"--bounds {it!r} is not allowed: must be CONTROLLER.PARAMETER=LO:HI, e.g. idm.T_s=0.8:2.5"
            ) from None
        out.setdefault(ctrl, {})[name] = (lo, hi)
    return out


def seeds_arg(text: str, option: str) -> list[int]:
    """Seeds from 'A,B,C' and/or ranges 'A-B' (inclusive), e.g. '1,2' or '11-20'; ParameterError naming the
    option otherwise."""
    out: list[int] = []
    try:
        for part in (p.strip() for p in text.split(",")):
            lo, sep, hi = part.partition("-")
            out += list(range(int(lo), int(hi) + 1)) if sep else [int(part)]
    except ValueError:
        raise ParameterError(f"{option} {text!r} is not allowed: must be seeds like 1,2 or 11-20") from None
    return out


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp tune``."""
    from ..console import OneLineParser, add_executor_options
    from .ring import HELDOUT_SEEDS, RING_TABLE, TRAIN_SEEDS, UNTUNED

    p = OneLineParser(
        prog="aev-ocp tune",
        description="Tune every controller with the same budget of closed-loop evaluations (optuna TPE, fixed "
        "seed) on training drive-cycle segments; report default and tuned side by side on training and held-out "
        "scenarios (tuning.md, tuning.csv, runs.csv, trials.csv, tuning.json). --ring: the ring controllers on ring "
        "seeds instead (ring.md, ring.json, ring_runs.csv, ring_trials.csv). Rerun to resume.",
    )
    p.add_argument(
        "--controllers",
        default=None,
        help=f"comma-separated (default {','.join(TUNING_TABLE)}; with --ring {','.join([*RING_TABLE, *UNTUNED])})",
    )
    p.add_argument("--budget", type=int, default=16, help="trials per controller (default 16)")
    p.add_argument("--batch", type=int, default=4, help="trials per controller per study execution (default 4)")
    p.add_argument("--seed", type=int, default=1, help="the sampler's seed (default 1)")
    p.add_argument(
        "--bounds",
        action="append",
        default=[],
        metavar="CTRL.PARAM=LO:HI",
        help="replace a parameter's bounds (repeatable), e.g. idm.T_s=0.8:2.5 (drive cycles)",
    )
    p.add_argument("--out", default=None, help="output folder (default results/tune, with --ring results/tune_ring)")
    p.add_argument("--ring", action="store_true", help="tune the ring controllers on the calibrated ring")
    p.add_argument(
        "--train-seeds", default=None, help=f"--ring: training seeds (default {','.join(map(str, TRAIN_SEEDS))})"
    )
    p.add_argument(
        "--heldout-seeds",
        default=None,
        help=f"--ring: held-out seeds (default {HELDOUT_SEEDS[0]}-{HELDOUT_SEEDS[-1]})",
    )
    p.add_argument("--t-end-s", type=float, default=None, help="--ring: simulated time [s] (default the scenario's)")
    p.add_argument(
        "--safety-suite",
        action="store_true",
        help="then run the default and the tuned sets through every case of the safety suite (safety.md, safety.json)",
    )
    add_executor_options(p)  # --workers, --dask-local, --scheduler, --in-process: as aev-ocp study
    return p


def _executor(a: argparse.Namespace) -> dict[str, Any]:
    from ..console import executor_options

    return executor_options(a)


def _ring(a: argparse.Namespace, controllers: list[str] | None, command: str) -> int:
    from .ring import HELDOUT_SEEDS, RING_TABLE, TRAIN_SEEDS, UNTUNED, run_ring_tuning

    for opt, given in (("--bounds", a.bounds), ("--safety-suite", a.safety_suite)):
        if given:
            raise ParameterError(f"{opt} applies to the drive-cycle tuning, not to --ring")
    res = run_ring_tuning(
        controllers if controllers is not None else [*RING_TABLE, *UNTUNED],
        a.budget,
        a.out,
        train_seeds=seeds_arg(a.train_seeds, "--train-seeds") if a.train_seeds else TRAIN_SEEDS,
        heldout_seeds=seeds_arg(a.heldout_seeds, "--heldout-seeds") if a.heldout_seeds else HELDOUT_SEEDS,
        t_end_s=a.t_end_s,
        seed=a.seed,
        batch=a.batch,
        command=command,
        **_executor(a),
    )
    for r in res.rows:
        e = r["battery_energy_kWh_per_100km"]
        mean = _fmt(e["mean"], 4) if e["mean"] is not None else "–"
        print(f"{r['controller']:>15} {r['set']:>9}: {mean} kWh/100 km over {r['seeds'] - r['failed']} seeds")
    print(f"wrote {len(res.files)} files to {res.folder}/")
    return 0


def _cycles(a: argparse.Namespace, controllers: list[str] | None, command: str) -> int:
    from .cycles import run_tuning

    for opt, given in (
        ("--train-seeds", a.train_seeds),
        ("--heldout-seeds", a.heldout_seeds),
        ("--t-end-s", a.t_end_s),
    ):
        if given is not None:
            raise ParameterError(f"{opt} applies to --ring only")
    res = run_tuning(
        controllers if controllers is not None else list(TUNING_TABLE),
        a.budget,
        a.out,
        seed=a.seed,
        batch=a.batch,
        bounds=_bounds_arg(a.bounds),
        command=command,
        **_executor(a),
    )
    for r in res.summary:
        print(
            f"{r['controller']:>9} {r['set']:>7} {r['split']:>8}: {_fmt(r['battery_energy_kWh_per_100km'], 4)} "
            f"kWh/100 km, {r['feasible_runs']}/{r['runs']} feasible"
        )
    print(f"wrote {len(res.files)} files to {res.folder}/")
    if a.safety_suite:
        from .safety import event_rows, run_safety

        out = run_safety(res.folder, workers=a.workers if a.workers is not None else None)
        for row in event_rows(out):
            print("safety suite " + " | ".join(row))
        print(f"wrote {res.folder}/safety.md, safety.json")
    return 0


def cli_tune(argv: list[str]) -> int:
    """Entry point of ``aev-ocp tune``: 0 done, 2 bad input."""
    from ..console import EXIT_BAD_INPUT, EXIT_OK
    from ..console import error_line as _err

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    controllers = [c.strip() for c in a.controllers.split(",") if c.strip()] if a.controllers is not None else None
    command = ("aev-ocp tune " + " ".join(argv)).strip()
    try:
        (_ring if a.ring else _cycles)(a, controllers, command)
    except ParameterError as exc:
        _err(str(exc))
        return EXIT_BAD_INPUT
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(cli_tune(sys.argv[1:]))

"""``aev-ocp safety [--out DIR] [--quick] [--controllers LIST] [--actuators LIST] [--workers N] [--no-plots]``.

The safety suite: every case (Euro NCAP CCRs, CCRm, CCRb extended to 130 km/h, lane ends, cut-ins) at the ideal
and the declared actuator, for the MPC (as shipped and with its soft margin), the proposed law, OVFL and IDM, bare
and under the braking-distance safety layer, each case labelled by the kinematic avoidability bound; writes
safety.csv, safety.json, safety.md and one figure per family. Exit codes: 0 the shipped MPC and every controller
under the layer passed every avoidable case (no collision, gap never below its floor), 1 one of them failed one
(every row is still written), 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..console import EXIT_BAD_INPUT, EXIT_FAILED_RUN, EXIT_OK
from ..console import OneLineParser as _Parser
from ..console import error_line as _err


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp safety``."""
    p = _Parser(prog="aev-ocp safety", description=__doc__.splitlines()[2].strip())
    p.add_argument("--out", default=None, help="output folder (default results/safety)")
    p.add_argument("--quick", action="store_true", help="a smoke run: 8 cases, 3 s each")
    p.add_argument(
        "--controllers",
        default=None,
        help="comma-separated controllers (default: mpc, proposed, ovfl, idm, each also with +layer, and "
        "mpc-margin+layer, wave-mpc+layer)",
    )
    p.add_argument("--actuators", default="ideal,declared", help="comma-separated: ideal, declared (default both)")
    p.add_argument("--workers", type=int, default=None, help="processes (default one per core; 1: in this process)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    return p


def gate_controllers(controllers: list[str]) -> list[str]:
    """The controllers whose failure in an avoidable case fails the run: the shipped MPC and every one under the
    layer (the bare laws' collisions are reported, not failed: the paper's laws as published)."""
    return [c for c in controllers if c == "mpc" or c.endswith("+layer")]


def cli_safety(argv: list[str]) -> int:
    """Entry point of ``aev-ocp safety``; returns the exit code."""
    from ..limits import memory_limit_bytes
    from ..params import ParameterError
    from ..results import claim_output_dir
    from .report import FILES, summary, write_outputs
    from .run import DEFAULT_CONTROLLERS, run_suite

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    ctrls = [c.strip() for c in a.controllers.split(",") if c.strip()] if a.controllers else list(DEFAULT_CONTROLLERS)
    acts = [c.strip() for c in a.actuators.split(",") if c.strip()]
    out = Path(a.out) if a.out else Path("results") / "safety"
    say = lambda m: print(f"[safety] {m}", file=sys.stderr, flush=True)  # noqa: E731
    try:
        memory_limit_bytes()  # a bad $AEV_OCP_MAX_MEMORY_GB is refused before the output folder is claimed
        if a.workers is not None and a.workers < 1:
            raise ParameterError(f"--workers = {a.workers} is not allowed: must be >= 1")
        claim_output_dir(out, "safety", "quick" if a.quick else "suite", None, list(FILES))
        res = run_suite(controllers=ctrls, actuators=acts, quick=a.quick, workers=a.workers, progress=say)
    except ParameterError as exc:
        _err(str(exc))
        return EXIT_BAD_INPUT
    files = write_outputs(res, out, plots=not a.no_plots)
    for key, s in summary(res).items():
        imp = ", ".join(f"{c} {v:.1f} m/s" for c, v in s["impact_speeds_mps"].items() if c in s["failures"])
        print(
            f"{key:>26}: {s['cases']['avoidable']} avoidable cases, {s['collisions']['avoidable']} collisions"
            + (f" ({imp})" if imp else "")
            + f" and {s['floor_violations']['avoidable']} floor violations there; "
            f"{sum(s['collisions'].values())} collisions in all {sum(s['cases'].values())} cases"
        )
    print(f"wrote {len(files)} files to {out}/")
    fails = [r for c in gate_controllers(ctrls) for r in res.failures(c)]
    for r in fails:
        _err(
            f"safety case {r.case} ({r.actuator} actuator): {r.controller} "
            + (
                f"collided at t = {r.collision_time_s:.3f} s at {r.impact_speed_mps:.2f} m/s"
                if r.collision
                else f"fell below its {res.settings['floor_m']:g} m floor (min gap {r.min_gap_m:.3f} m)"
            )
            + " in an avoidable case"
        )
    return EXIT_FAILED_RUN if fails else EXIT_OK

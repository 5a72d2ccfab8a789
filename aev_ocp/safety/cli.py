"""``aev-ocp safety [--out DIR] [--quick] [--idm] [--no-plots]``: the safety suite.

Every case (Euro NCAP-style CCRb, CCRs, CCRm, cut-ins) for the MPC on its shipped defaults, the proposed law
and OVFL (``--idm``: also IDM), each case labelled by the kinematic avoidability bound; writes safety.csv,
safety.json, safety.md and one figure per family. Exit codes: 0 every avoidable case passed by the MPC (no
collision, gap never below its floor), 1 the MPC failed an avoidable case (its rows are still written), 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..console import EXIT_FAILED_RUN, EXIT_OK
from ..console import OneLineParser as _Parser
from ..console import error_line as _err


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp safety``."""
    p = _Parser(prog="aev-ocp safety", description=__doc__.splitlines()[0].strip("`"))
    p.add_argument("--out", default=None, help="output folder (default results/safety)")
    p.add_argument("--quick", action="store_true", help="a smoke run: two cases per family, 3 s each")
    p.add_argument("--idm", action="store_true", help="also run IDM (saturated like the other laws)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    return p


def cli_safety(argv: list[str]) -> int:
    """Entry point of ``aev-ocp safety``; returns the exit code."""
    from ..results import claim_output_dir
    from .report import FILES, summary, write_outputs
    from .suite import DEFAULT_CONTROLLERS, run_suite

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    out = Path(a.out) if a.out else Path("results") / "safety"
    claim_output_dir(out, "safety", "quick" if a.quick else "suite", None, list(FILES))
    say = lambda m: print(f"[safety] {m}", file=sys.stderr, flush=True)  # noqa: E731
    controllers = DEFAULT_CONTROLLERS + (("idm",) if a.idm else ())
    res = run_suite(controllers=controllers, quick=a.quick, progress=say)
    files = write_outputs(res, out, plots=not a.no_plots)
    for ctrl, s in summary(res).items():
        print(
            f"{ctrl:>9}: {s['cases']['avoidable']} avoidable cases, {s['collisions']['avoidable']} collisions and "
            f"{s['floor_violations']['avoidable']} floor violations there; "
            f"{sum(s['collisions'].values())} collisions in all {sum(s['cases'].values())} cases"
        )
    print(f"wrote {len(files)} files to {out}/")
    fails = res.failures("mpc")
    for r in fails:
        _err(
            f"safety case {r.case}: the MPC "
            + (
                f"collided at t = {r.collision_time_s:.3f} s at {r.impact_speed_mps:.2f} m/s"
                if r.collision
                else f"fell below its {res.settings['floor_m']:g} m floor (min gap {r.min_gap_m:.3f} m)"
            )
            + " in an avoidable case"
        )
    return EXIT_FAILED_RUN if fails else EXIT_OK

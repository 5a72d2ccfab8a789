"""``aev-ocp ocp {prop31,current-profile,eco-trip,oracle} [SCENARIO.toml] [--method ms|collocation] [--out DIR]
[--N N] [--no-refine] [--multistart]``.

The project's main CLI (owned elsewhere) can dispatch to :func:`cli_ocp`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..params import ParameterError

COMMANDS = ("prop31", "current-profile", "eco-trip", "oracle")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="aev-ocp ocp", description="Optimal-control problems OCP-A..D (PROBLEM.md §8).")
    ap.add_argument("problem", choices=COMMANDS)
    ap.add_argument("scenario", nargs="?", default=None, help="scenario TOML (oracle: default canonical scenario)")
    ap.add_argument("--method", choices=("ms", "collocation"), default="ms", help="transcription (default ms)")
    ap.add_argument("--out", default=None, help="output folder (JSON, CSV, PNG)")
    ap.add_argument("--N", type=int, default=None, help="number of intervals (problem default if omitted)")
    ap.add_argument("--no-refine", action="store_true",
                    help="skip the extra solve with 2N intervals that reports how the objective changes")
    ap.add_argument("--multistart", action="store_true",
                    help="eco-trip, oracle: solve from several initial guesses, keep the best, report the spread")
    return ap


def cli_ocp(argv: list[str]) -> int:
    """Run one OCP from the command line; returns the exit code (0 ok, 1 solver failure, 2 bad input)."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    from . import api

    if args.N is not None and args.N < 1:
        print(f"aev-ocp ocp {args.problem}: error: --N = {args.N} is not allowed: must be an integer >= 1",
              file=sys.stderr)
        return 2
    if args.problem in ("prop31",) and args.scenario is not None:
        print("aev-ocp ocp prop31: error: prop31 takes no scenario (OCP-A is the single cell of PROBLEM.md §8)",
              file=sys.stderr)
        return 2
    if args.multistart and args.problem not in ("eco-trip", "oracle"):
        print(f"aev-ocp ocp {args.problem}: error: --multistart applies to eco-trip and oracle only", file=sys.stderr)
        return 2
    if args.problem == "oracle" and args.N is not None:
        print("aev-ocp ocp oracle: error: --N does not apply (N = t_end/dt of the scenario, dt = 0.1)",
              file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else None
    try:
        if args.problem == "prop31":
            from .prop31 import prop31_table

            cases = api.run_prop31(args.method, out_dir=out, refine=not args.no_refine,
                                   **({"N": args.N} if args.N is not None else {}))
            print(prop31_table(cases))
            ok = all(e["status"] in ("optimal", "acceptable") for e in cases.values())
        elif args.problem == "current-profile":
            rep = api.run_current_profile(method=args.method, out_dir=out, scenario=args.scenario,
                                          refine=not args.no_refine, **({"N": args.N} if args.N is not None else {}))
            print(rep["table"])
            ok = rep["ok"]
        elif args.problem == "eco-trip":
            rep = api.run_eco_trip(method=args.method, out_dir=out, scenario=args.scenario,
                                   refine=not args.no_refine, multistart=args.multistart,
                                   **({"N": args.N} if args.N is not None else {}))
            print(rep["table"])
            ok = rep["ok"]
        else:
            rep = api.run_oracle(method=args.method, out_dir=out, scenario=args.scenario, multistart=args.multistart)
            print(rep["table"])
            ok = rep["ok"]
    except (ParameterError, FileNotFoundError, ValueError) as exc:
        print(f"aev-ocp ocp {args.problem}: error: {exc}", file=sys.stderr)
        return 2
    if out is not None:
        print(f"wrote results to {out}")
    return 0 if ok else 1

"""``aev-ocp ocp {prop31,current-profile,eco-trip,oracle} [SCENARIO.toml] [--method ms|collocation] [--out DIR]
[--N N] [--no-refine] [--multistart] [--time-limit S]``.

The project's main CLI (owned elsewhere) can dispatch to :func:`cli_ocp`.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

COMMANDS = ("prop31", "current-profile", "eco-trip", "oracle")


def _parser() -> argparse.ArgumentParser:
    from ..cli import OneLineParser

    ap = OneLineParser(prog="aev-ocp ocp", description="Optimal-control problems OCP-A..D (PROBLEM.md §8).")
    ap.add_argument("problem", choices=COMMANDS)
    ap.add_argument("scenario", nargs="?", default=None, help="scenario TOML (oracle: default canonical scenario)")
    ap.add_argument("--method", choices=("ms", "collocation"), default="ms", help="transcription (default ms)")
    ap.add_argument("--out", default=None, help="output folder (JSON, CSV, PNG)")
    ap.add_argument("--N", type=int, default=None, help="number of intervals (problem default if omitted)")
    ap.add_argument("--no-refine", action="store_true",
                    help="skip the extra solve with 2N intervals that reports how the objective changes")
    ap.add_argument("--multistart", action="store_true",
                    help="eco-trip, oracle: solve from several initial guesses, keep the best, report the spread")
    ap.add_argument("--time-limit", type=float, default=None, metavar="S",
                    help="oracle: wall-time limit of each IPOPT solve [s] (default 600); a solve stopped there "
                         "is reported as not optimal")
    return ap


def _check_size(args: argparse.Namespace) -> None:
    """Refuse, before building it, an NLP too large for the memory budget (:mod:`aev_ocp.limits`:
    measured bytes per interval per problem and transcription)."""
    from ..limits import check_ocp_size

    if args.problem == "oracle":
        if args.scenario is not None:  # the canonical scenario has N = 700
            from ..scenarios import find_scenario
            from .api import oracle_scenario_from_file

            scn = oracle_scenario_from_file(find_scenario(args.scenario))
            check_ocp_size("oracle", scn.N, args.method, f"{args.scenario}: simulation.t_end (N = t_end/dt)")
    else:
        check_ocp_size(args.problem, args.N or 200, args.method)


def cli_ocp(argv: list[str]) -> int:
    """Run one OCP from the command line; returns the exit code (0 ok, 1 solver failure, 2 bad input,
    130 interrupted). Errors are one line ``aev-ocp: error: ...`` as for every subcommand."""
    from ..cli import guarded

    return guarded(lambda: _cli_ocp(argv))


def _cli_ocp(argv: list[str]) -> int:
    from ..params import ParameterError
    from ..results import claim_output_dir

    args = _parser().parse_args(argv)
    from . import api

    if args.N is not None and args.N < 1:
        raise ParameterError(f"ocp {args.problem}: --N = {args.N} is not allowed: must be an integer >= 1")
    if args.problem in ("prop31",) and args.scenario is not None:
        raise ParameterError("ocp prop31: prop31 takes no scenario (OCP-A is the single cell of PROBLEM.md §8)")
    if args.multistart and args.problem not in ("eco-trip", "oracle"):
        raise ParameterError(f"ocp {args.problem}: --multistart applies to eco-trip and oracle only")
    if args.problem == "oracle" and args.N is not None:
        raise ParameterError("ocp oracle: --N does not apply (N = t_end/dt of the scenario: dt = 0.1, "
                             "1 s on a drive cycle)")
    if args.time_limit is not None:
        if args.problem != "oracle":
            raise ParameterError(f"ocp {args.problem}: --time-limit applies to oracle only")
        if not (math.isfinite(args.time_limit) and args.time_limit > 0):
            raise ParameterError(f"ocp oracle: --time-limit = {args.time_limit!r} is not allowed: must be a finite "
                                 "number of seconds > 0")
    _check_size(args)
    if args.scenario is not None:  # every JSON this command writes names the scenario and its SHA-256
        from ..provenance import declare
        from ..scenarios import find_scenario, load_scenario

        declare(load_scenario(find_scenario(args.scenario)))
    out = Path(args.out) if args.out else None
    if out is not None:
        claim_output_dir(out, f"ocp {args.problem}", str(args.scenario or args.problem), args.scenario)
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
        from .oracle import DEFAULT_TIME_LIMIT_S

        rep = api.run_oracle(method=args.method, out_dir=out, scenario=args.scenario, multistart=args.multistart,
                             time_limit_s=args.time_limit or DEFAULT_TIME_LIMIT_S, progress=True)
        print(rep["table"])
        ok = rep["ok"]
    if out is not None:
        print(f"wrote results to {out}")
    if not ok:
        from ..cli import error_line

        error_line(f"ocp {args.problem}: the solver did not converge (see the table above)")
    return 0 if ok else 1

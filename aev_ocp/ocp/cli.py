"""``aev-ocp ocp {prop31,current-profile,eco-trip,oracle} [SCENARIO.toml] [--method ms|collocation] [--out DIR]
[--N N] [--no-refine] [--multistart] [--grid NAME=V1,V2,...] [--grid-file FILE] [--time-limit S] [--no-plots]``.

Every problem writes into ``--out`` (default ``results/ocp/<problem>[/<scenario>]``), including
manifest.json + trajectories.npz that :func:`aev_ocp.load` reads back.

The project's main CLI (owned elsewhere) can dispatch to :func:`cli_ocp`.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

COMMANDS = ("prop31", "current-profile", "eco-trip", "oracle")


def _parser() -> argparse.ArgumentParser:
    from ..console import OneLineParser

    ap = OneLineParser(prog="aev-ocp ocp", description="Optimal-control problems OCP-A..D (model guide §8).")
    ap.add_argument("problem", choices=COMMANDS)
    ap.add_argument("scenario", nargs="?", default=None, help="scenario TOML (oracle: default canonical scenario)")
    ap.add_argument("--method", choices=("ms", "collocation"), default="ms", help="transcription (default ms)")
    ap.add_argument(
        "--out",
        default=None,
        help="output folder (JSON, CSV, PNG, manifest.json; default results/ocp/<problem>[/<scenario>])",
    )
    ap.add_argument("--N", type=int, default=None, help="number of intervals (problem default if omitted)")
    ap.add_argument(
        "--no-refine",
        action="store_true",
        help="skip the extra solve with 2N intervals that reports how the objective changes",
    )
    ap.add_argument(
        "--multistart",
        action="store_true",
        help="eco-trip, oracle: solve from several initial guesses, keep the best, report the spread",
    )
    ap.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="NAME=V1,V2,...",
        help="sweep grid (repeatable): current-profile E_req [J] (default 1000,2000,3000,4000,6000) and "
        "t_f [s] (default 30,60,120); eco-trip D [m] and t_f [s] (default: no sweep; one list "
        "given, the other is the trip's value)",
    )
    ap.add_argument(
        "--grid-file",
        default=None,
        metavar="FILE",
        help="the grids from a TOML or JSON file: E_req = [...], t_f = [...], D = [...] (--grid entries override it)",
    )
    ap.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="S",
        help="current-profile, eco-trip: wall-clock limit [s]; the sweep stops cleanly after the solve "
        "that passes it, the output is flagged partial (default: none). oracle: IPOPT's wall-time "
        "limit (default 600 s); a solve stopped there is reported as not optimal, with no bound",
    )
    ap.add_argument(
        "--cell",
        default=None,
        metavar="NAME|FILE",
        help="prop31: the cell (a shipped cell name, e.g. a123_anr26650, or a cell file; default the A123)",
    )
    ap.add_argument("--soc0", type=float, default=None, metavar="S", help="prop31: initial SOC S(0) (default 0.5)")
    ap.add_argument(
        "--v-relax-V",
        default=None,
        metavar="V1,V2",
        help="prop31: the relaxing cases' initial polarisation V1(0),V2(0) [V] (default 0.02,0.03)",
    )
    ap.add_argument(
        "--no-plots", action="store_true", help="skip the PNG plots (default: write them; JSON and CSV are the same)"
    )
    ap.add_argument(
        "--progress-every",
        type=float,
        default=2.0,
        metavar="S",
        help="seconds between progress lines (solve k/n, elapsed, ETA; oracle: IPOPT iteration, "
        "objective, infeasibility) on stderr (default: 2)",
    )
    return ap


def parse_grids(problem: str, items: list[str], file: str | None) -> dict[str, list[float]]:
    """The sweep grids of ``--grid NAME=v1,v2,...`` and ``--grid-file`` (TOML or JSON) as {name: values};
    ParameterError naming the grid for an unknown name, one that ``problem`` does not sweep, or a value
    that is not a finite number > 0."""
    import json
    import math
    import tomllib

    from ..params import ParameterError
    from .run import GRIDS

    raw: dict[str, object] = {}
    from_file: set[str] = set()
    if file is not None:
        from ..limits import read_input_file

        data = read_input_file(file, "grid file (--grid-file)", ParameterError)  # a FIFO or device: refused
        try:
            text = data.decode("utf-8")
            raw.update(json.loads(text) if file.endswith(".json") else tomllib.loads(text))
        except (ValueError, TypeError, tomllib.TOMLDecodeError, RecursionError) as exc:  # TypeError: JSON not a table
            raise ParameterError(
                f"--grid-file {file}: not valid {'JSON' if file.endswith('.json') else 'TOML'}: {exc}"
            ) from None
        from_file = set(raw)
    for item in items:
        name, sep, spec = item.partition("=")
        if not sep or not spec.strip():
            raise ParameterError(f"--grid {item!r} is not NAME=V1,V2,... (e.g. --grid E_req=1000,2000)")
        raw[name.strip()] = [v.strip() for v in spec.split(",")]
        from_file.discard(name.strip())  # the command line over the file
    out: dict[str, list[float]] = {}
    for name, vals in raw.items():
        where = f"--grid-file {file}: grid {name}" if name in from_file else f"grid {name}"
        if name not in GRIDS:
            raise ParameterError(
                f"{where}: unknown grid; known grids are {sorted(GRIDS)} "
                f"({', '.join(f'{k} [{u}]' for k, (u, _) in GRIDS.items())})"
            )
        unit, problems = GRIDS[name]
        if problem not in problems:
            raise ParameterError(f"{where} does not apply to ocp {problem} (it sweeps {', '.join(problems)})")
        if not isinstance(vals, list) or not vals:
            raise ParameterError(f"{where} = {vals!r} is not allowed: must be a non-empty list of numbers [{unit}]")
        xs = []
        for k, v in enumerate(vals):
            try:
                x = float(v) if not isinstance(v, bool) else math.nan
            except (TypeError, ValueError):
                x = math.nan
            if not (math.isfinite(x) and x > 0):
                raise ParameterError(
                    f"{where}: value {k + 1} = {v!r} is not allowed: must be a finite number > 0 [{unit}]"
                )
            xs.append(x)
        out[name] = xs
    return out


def _check_size(args: argparse.Namespace) -> None:
    """Refuse, before building it, an NLP too large for the memory budget (:mod:`aev_ocp.limits`:
    measured bytes per interval per problem and transcription)."""
    from ..limits import check_ocp_size

    if args.problem == "oracle":
        if args.scenario is not None:  # the canonical scenario has N = 700
            from ..scenarios import find_scenario
            from .run import oracle_scenario_from_file

            scn = oracle_scenario_from_file(find_scenario(args.scenario))
            check_ocp_size("oracle", scn.N, args.method, f"{args.scenario}: simulation.t_end (N = t_end/dt)")
    else:
        check_ocp_size(args.problem, args.N or 200, args.method)


def cli_ocp(argv: list[str]) -> int:
    """Run one OCP from the command line; returns the exit code (0 ok, 1 solver failure, 2 bad input,
    130 interrupted). Errors are one line ``aev-ocp: error: ...`` as for every subcommand."""
    from ..console import guarded

    return guarded(lambda: _cli_ocp(argv))


def _check_options(args: argparse.Namespace) -> None:
    """Refuse options that do not apply to the problem (ParameterError naming the option)."""
    from ..params import ParameterError

    if args.N is not None and args.N < 1:
        raise ParameterError(f"ocp {args.problem}: --N = {args.N} is not allowed: must be an integer >= 1")
    if args.problem in ("prop31",) and args.scenario is not None:
        raise ParameterError("ocp prop31: prop31 takes no scenario (OCP-A is the single cell of model guide §8)")
    for flag, value in (("--cell", args.cell), ("--soc0", args.soc0), ("--v-relax-V", args.v_relax_V)):
        if value is not None and args.problem != "prop31":
            raise ParameterError(
                f"ocp {args.problem}: {flag} applies to prop31 only (the scenario's [cell] sets the "
                "cell of the other problems)"
            )
    if args.multistart and args.problem not in ("eco-trip", "oracle"):
        raise ParameterError(f"ocp {args.problem}: --multistart applies to eco-trip and oracle only")
    if args.problem == "oracle" and args.N is not None:
        raise ParameterError(
            "ocp oracle: --N does not apply (N = t_end/dt of the scenario: dt = 0.1, 1 s on a drive cycle)"
        )
    _check_size(args)


def _prop31_options(args: argparse.Namespace) -> dict[str, Any]:
    """run_prop31's keywords from --N, --cell, --soc0 and --v-relax-V (two finite voltages V1,V2 [V])."""
    from ..params import ParameterError

    kw: dict[str, Any] = {"N": args.N} if args.N is not None else {}
    if args.cell is not None:
        from ..cells import load_cell

        kw["cell"] = load_cell(args.cell)
    if args.soc0 is not None:
        kw["soc0"] = args.soc0
    if args.v_relax_V is not None:
        try:
            kw["v_relax_V"] = tuple(float(v) for v in args.v_relax_V.split(","))
        except ValueError:
            kw["v_relax_V"] = ()
        if len(kw["v_relax_V"]) != 2 or not all(map(math.isfinite, kw["v_relax_V"])):  # named as the option
            raise ParameterError(
                f"ocp prop31: --v-relax-V = {args.v_relax_V!r} is not allowed: two finite voltages V1,V2 [V]"
            )
    return kw


def _solve(
    args: argparse.Namespace, out: Path, grids: dict[str, list[float]], prog: Any
) -> tuple[bool, dict[str, Any], dict[str, Any]]:
    """Solve the problem (its table printed): (converged, {run name: result} to save, the report)."""
    from . import run as runs

    # what current-profile and eco-trip both take from the command line (N only when given: else the problem's)
    common: dict[str, Any] = dict(
        method=args.method,
        out_dir=out,
        scenario=args.scenario,
        refine=not args.no_refine,
        progress=prog,
        plots=not args.no_plots,
    )
    common.update({"N": args.N} if args.N is not None else {})
    if args.problem == "prop31":
        from .plots import write_prop31_outputs
        from .prop31 import prop31_table

        kw = _prop31_options(args)
        cases = runs.run_prop31(args.method, refine=not args.no_refine, **kw)
        write_prop31_outputs(cases, out, plots=not args.no_plots)
        print(prop31_table(cases))
        ok = all(e["status"] in ("optimal", "acceptable") for e in cases.values())
        return ok, {case: e["result"] for case, e in cases.items() if "result" in e}, {}
    if args.problem == "current-profile":
        # a grid not given keeps run_current_profile's default sweep
        rep = runs.run_current_profile(
            **common, sweep_E_J=grids.get("E_req") or runs.SWEEP_E_J, sweep_t_f_s=grids.get("t_f") or runs.SWEEP_T_F_S
        )
        print(rep["table"])
        return (
            rep["ok"],
            {"main": rep["result"], **{f"sweep{k:03d}": r for k, r in enumerate(rep["sweep_results"])}},
            rep,
        )
    if args.problem == "eco-trip":
        rep = runs.run_eco_trip(
            **common, multistart=args.multistart, sweep_D_m=grids.get("D", ()), sweep_t_f_s=grids.get("t_f", ())
        )
        print(rep["table"])
        return rep["ok"], {**rep["results"], **{f"sweep{k:03d}": r for k, r in enumerate(rep["sweep_results"])}}, rep
    from .oracle import DEFAULT_TIME_LIMIT_S

    # IPOPT stops itself at the limit (max_wall_time); its iterations are reported every --progress-every s
    rep = runs.run_oracle(
        method=args.method,
        out_dir=out,
        scenario=args.scenario,
        multistart=args.multistart,
        time_limit_s=args.time_limit or DEFAULT_TIME_LIMIT_S,
        progress=prog.say,
        progress_every_s=args.progress_every,
        plots=not args.no_plots,
    )
    print(rep["table"])
    return rep["ok"], {"main": rep["result"]}, rep


def _exit_code(args: argparse.Namespace, out: Path, ok: bool, stopped: bool, rep: dict[str, Any]) -> int:
    """1 (with the one-line error) when stopped by --time-limit or not converged, else 0."""
    if stopped:
        from ..console import error_line

        error_line(f"ocp {args.problem}: stopped by --time-limit {args.time_limit:g} s: partial sweep written to {out}")
        return 1
    if not ok:
        from ..console import error_line

        if args.problem == "oracle" and rep["time_limit"]:
            error_line(f"ocp oracle: {rep['result'].message} (no lower bound; raise --time-limit)")
        else:
            error_line(f"ocp {args.problem}: the solver did not converge (see the table above)")
    return 0 if ok else 1


def _cli_ocp(argv: list[str]) -> int:
    from ..params import ParameterError
    from ..results import claim_output_dir, default_output_dir
    from ..saved import save_output

    args = _parser().parse_args(argv)
    _check_options(args)
    from ..scenarios import find_scenario, load_scenario

    if args.scenario is not None:  # every JSON this command writes names the scenario and its SHA-256
        from ..provenance import declare

        declare(load_scenario(find_scenario(args.scenario)))
    from ..progress import Progress, check_time_limit

    grids = parse_grids(args.problem, args.grid, args.grid_file)
    check_time_limit(args.time_limit, "--time-limit")
    if args.time_limit is not None and args.problem not in ("current-profile", "eco-trip", "oracle"):
        raise ParameterError(f"ocp {args.problem}: --time-limit applies to current-profile, eco-trip and oracle")
    prog = Progress(f"ocp {args.problem}", unit="solves", time_limit_s=args.time_limit, every_s=args.progress_every)
    scenario_name = load_scenario(find_scenario(args.scenario)).name if args.scenario is not None else None
    out = (
        Path(args.out)
        if args.out
        else default_output_dir("ocp", args.problem, *([scenario_name] if scenario_name else []))
    )
    claim_output_dir(out, f"ocp {args.problem}", str(args.scenario or args.problem), args.scenario)
    ok, runs, rep = _solve(args, out, grids, prog)
    stopped = args.problem in ("current-profile", "eco-trip") and rep["time_limit"]
    save_output(
        out,
        "ocp",
        runs,
        settings={
            "problem": args.problem,
            "method": args.method,
            "N": args.N,
            "refine": not args.no_refine,
            "multistart": args.multistart,
            "grids": grids,
            "time_limit_s": args.time_limit,
            "scenario": args.scenario,
        },
        extra={"time_limit": stopped, "sweep": rep.get("sweep") if args.problem != "prop31" else None},
    )
    print(f"wrote results to {out} (aev_ocp.load('{out}'))")
    return _exit_code(args, out, ok, stopped, rep)

"""``aev-ocp mpc SCENARIO.toml [--out DIR] [--set KEY=VALUE] [--solver ...] [--time-limit S]``: the MPC closed loop of a scenario beside the
closed-form laws (and OCP-D for a single follower); writes results.json, a trajectories CSV, plots, manifest.json and trajectories.npz."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .settings import QP_SOLVERS, SOLVER_PATHS, MPCSettings

_D = MPCSettings()  # the defaults an [mpc] table falls back to (the traffic formulation)

OUTPUT_FILES = ("results.json", "trajectories_mpc.csv", "mpc_trajectories.png", "mpc_solve_times.png")


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp mpc`` (every option with its unit and default)."""
    from ..console import OneLineParser, add_set_option

    p = OneLineParser(
        prog="aev-ocp mpc",
        description="The MPC closed loop of a scenario beside the closed-form laws (and the "
        "OCP-D lower bound for a single follower); writes results.json, trajectories_mpc.csv, plots, "
        "manifest.json and trajectories.npz into the output folder.",
        epilog="Exit codes: 0 ok; 1 the MPC run stopped on an event (collision, infeasible current, "
        "time limit, ...; results up to then are written) or a solver failed; 2 bad input; "
        "130 interrupted. Load the results with aev_ocp.load(OUT).",
    )
    p.add_argument(
        "scenario",
        help="scenario TOML file or shipped scenario name (e.g. mpc_paper_single); its [mpc] "
        "table holds the controller settings (defaults: MPCSettings(), the traffic formulation "
        'aev_ocp/ocp/traffic.py; formulation = "s9" for model guide §9)',
    )
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (default: results/mpc/<scenario name>/)")
    add_set_option(
        p,
        "override a scenario key, e.g. --set mpc.N=20 --set simulation.t_end_s=10 (repeatable; "
        "checked like the file; the command line over the file; a key that an option below "
        "also sets is refused; default: none)",
    )
    p.add_argument(
        "--solver",
        choices=SOLVER_PATHS,
        default=None,
        help=f"solver path (default: the scenario's mpc.solver, else {_D.solver})",
    )
    p.add_argument(
        "--qp-solver",
        choices=QP_SOLVERS,
        default=None,
        help=f"QP solver of the sqp and rti paths (default: the scenario's mpc.qp_solver, else {_D.qp_solver}; "
        "'auto': 'riccati', aev_ocp's own, on the rti path, 'hpipm' on the sqp path)",
    )
    cg = p.add_mutually_exclusive_group()
    cg.add_argument(
        "--codegen",
        action="store_true",
        default=None,
        help="compile the NLP functions to C with gcc (default: the scenario's mpc.codegen, else "
        f"{'on' if _D.codegen else 'off'})",
    )
    cg.add_argument(
        "--no-codegen",
        dest="codegen",
        action="store_false",
        help="interpreted CasADi functions (overrides the scenario's mpc.codegen)",
    )
    te = p.add_mutually_exclusive_group()
    te.add_argument(
        "--t-end",
        type=_positive_float,
        default=None,
        metavar="S",
        help="simulated horizon [s], e.g. --t-end 120 for a quick run (default: the scenario's "
        "simulation.t_end_s or t_end)",
    )
    te.add_argument(
        "--t-end-model",
        type=_positive_float,
        default=None,
        metavar="T",
        help="the horizon in model time instead (1 = L/U s with the scenario's [units])",
    )
    p.add_argument(
        "--laws",
        nargs="*",
        default=None,
        metavar="LAW",
        help="closed-form laws to compare (default: the scenario's compare list, else proposed ovfl)",
    )
    p.add_argument(
        "--no-ocpd", action="store_true", help="skip the OCP-D lower bound (default: solved for a single follower)"
    )
    p.add_argument(
        "--time-limit",
        type=_positive_float,
        default=None,
        metavar="S",
        help="wall-clock limit of the MPC closed loop [s]: the loop stops cleanly at the first step "
        "past it, with status time_limit and a partial result (default: none)",
    )
    p.add_argument(
        "--progress-every",
        type=_positive_float,
        default=2.0,
        metavar="S",
        help="seconds between progress lines (step k/N, elapsed, ETA) on stderr (default: 2)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots (default: write them)")
    return p


def _positive_float(text: str) -> float:
    x = float(text)
    if not (x > 0 and x < float("inf")):
        raise ValueError(text)
    return x


_positive_float.__name__ = "positive number"  # argparse: "invalid positive number value: '-1'"


#: Options that set a scenario key: (option dest, option text, the keys it sets). Giving the option and a
#: --set of the same key is refused: one of them would be dropped.
OPTION_KEYS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("t_end", "--t-end", ("simulation.t_end", "simulation.t_end_s")),
    ("t_end_model", "--t-end-model", ("simulation.t_end", "simulation.t_end_s")),
    ("solver", "--solver", ("mpc.solver",)),
    ("qp_solver", "--qp-solver", ("mpc.qp_solver",)),
    ("codegen", "--codegen/--no-codegen", ("mpc.codegen",)),
)


def _refuse_doubled(a: argparse.Namespace) -> None:
    from ..overrides import OverrideError, parse_assignments

    sets = parse_assignments(a.sets)
    for dest, opt, keys in OPTION_KEYS:
        if getattr(a, dest) is None:
            continue
        hit = next((k for k in keys if k in sets), None)
        if hit is not None:
            raise OverrideError(f"{opt} and --set {hit} both set the same thing; give one of them")


def cli_mpc(argv: list[str]) -> int:
    """Entry point; returns the exit code: 0 ok, 1 the MPC run stopped on an event (collision,
    infeasible current, ...; results up to then are written) or a solver failed, 2 bad input,
    130 interrupted. Errors are one line ``aev-ocp: error: ...`` as for every subcommand."""
    from ..console import guarded

    return guarded(lambda: _cli_mpc(argv))


def _cli_mpc(argv: list[str]) -> int:
    from ..console import error_line, warning_line
    from ..results import claim_output_dir, default_output_dir
    from ..scenarios import load_with_sets
    from ..progress import TIME_LIMIT, Progress
    from ..saved import OUTPUT_FILES as SAVED_FILES, settings_of
    from ..scenarios import find_scenario
    from .report import check_mpc_scenario, comparison_table, write_comparison
    from .run import run_comparison
    from .scenario import MPCConfig
    from .settings import MPCSettings

    a = build_parser().parse_args(argv)
    _refuse_doubled(a)
    sc = load_with_sets(str(find_scenario(a.scenario)), a.sets)
    from ..provenance import declare

    declare(sc)  # every JSON this command writes names the scenario and its SHA-256
    cfg: MPCConfig = sc.extra.get("mpc") or MPCConfig(MPCSettings())
    changes = {k: v for k, v in (("solver", a.solver), ("qp_solver", a.qp_solver)) if v is not None}
    if a.codegen is not None:
        changes["codegen"] = a.codegen
    s = cfg.settings.with_(**changes)
    if a.t_end is not None:
        sc = sc.replace(t_end=float(sc.units.time_from_si(a.t_end)))
    elif a.t_end_model is not None:
        sc = sc.replace(t_end=a.t_end_model)
    laws = tuple(a.laws) if a.laws is not None else (tuple(sc.compare) or ("proposed", "ovfl"))
    option = "--t-end" if a.t_end is not None else "--t-end-model" if a.t_end_model is not None else None
    check_mpc_scenario(sc, s, laws, option)  # bad input is refused before anything runs or is written
    out = Path(a.out) if a.out else default_output_dir("mpc", sc.name)
    overlays = tuple(f"overlay_vehicle{i + 1}.png" for i in range(sc.n_followers))
    claim_output_dir(out, "mpc", sc.name, str(sc.source) if sc.source else None, OUTPUT_FILES + SAVED_FILES + overlays)
    say = lambda m: print(f"[mpc] {m}", file=sys.stderr, flush=True)  # noqa: E731
    prog = Progress("", unit="steps", time_limit_s=a.time_limit, every_s=a.progress_every, say=say)
    c = run_comparison(sc, s, laws=laws, with_ocpd=not a.no_ocpd, log=say, progress=prog)
    say(f"writing tables, figures and the saved runs into {out} …")
    write_comparison(
        c,
        out,
        settings_of(
            sc,
            solver=s.solver,
            qp_solver=s.qp,
            codegen=s.codegen,
            t_end=sc.t_end,
            laws=list(laws),
            ocpd=not a.no_ocpd,
            sets=list(a.sets),
            time_limit_s=a.time_limit,
        ),
        plots=not a.no_plots,
    )
    r = c.results["mpc"]
    for i in range(r.n_vehicles):
        print(f"\nfollower {i + 1}:")
        print(comparison_table(c, i))
    print(
        f"\nwrote {out}/results.json, trajectories_mpc.csv, {'' if a.no_plots else 'plots, '}manifest.json + trajectories.npz "
        f"(aev_ocp.load('{out}'))"
    )
    for lab, res in c.results.items():
        if lab != "mpc" and res.events:
            warning_line(f"run {lab} stopped: {res.events[0]}")
    if r.status == TIME_LIMIT:
        u = sc.units
        error_line(
            f"scenario {sc.name}, run mpc stopped by --time-limit {a.time_limit:g} s at t = "
            f"{u.time_to_si(r.events[0].time):.4g} s of {u.time_to_si(sc.t_end):.4g} s (model time "
            f"{r.events[0].time:.4g} of {sc.t_end:g}): partial result (status time_limit) written to {out}/"
        )
        return 1
    if r.events:
        error_line(f"scenario {sc.name}, run mpc: {r.events[0]} (results up to that time written to {out}/)")
        return 1
    return 0

"""``aev-ocp mpc SCENARIO.toml [--out DIR] [--solver ...]``: the MPC closed loop of a scenario beside the
closed-form laws (and OCP-D for a single follower); writes results.json, a trajectories CSV and plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .settings import QP_SOLVERS, SOLVER_PATHS

OUTPUT_FILES = ("results.json", "trajectories_mpc.csv", "mpc_trajectories.png", "mpc_solve_times.png")


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp mpc``."""
    from ..cli import OneLineParser

    p = OneLineParser(prog="aev-ocp mpc", description=__doc__.splitlines()[0])
    p.add_argument("scenario", help="scenario TOML file or shipped scenario name (e.g. mpc_paper_single)")
    p.add_argument("--out", default=None, help="output folder (default results/mpc/<scenario name>)")
    p.add_argument("--solver", choices=SOLVER_PATHS, default=None, help="solver path (default: the scenario's)")
    p.add_argument("--qp-solver", choices=QP_SOLVERS, default=None, help="QP solver of the sqp path")
    cg = p.add_mutually_exclusive_group()
    cg.add_argument("--codegen", action="store_true", default=None, help="compile the NLP functions to C (gcc)")
    cg.add_argument("--no-codegen", dest="codegen", action="store_false", help="interpreted CasADi functions")
    p.add_argument("--t-end", type=_positive_float, default=None, help="shorter horizon [model time] for a quick run")
    p.add_argument("--laws", nargs="*", default=None, help="closed-form laws to compare (default proposed ovfl)")
    p.add_argument("--no-ocpd", action="store_true", help="skip the OCP-D lower bound")
    return p


def _positive_float(text: str) -> float:
    x = float(text)
    if not (x > 0 and x < float("inf")):
        raise ValueError(text)
    return x


_positive_float.__name__ = "positive number"  # argparse: "invalid positive number value: '-1'"


def cli_mpc(argv: list[str]) -> int:
    """Entry point; returns the exit code: 0 ok, 1 the MPC run stopped on an event (collision,
    infeasible current, ...; results up to then are written) or a solver failed, 2 bad input,
    130 interrupted. Errors are one line ``aev-ocp: error: ...`` as for every subcommand."""
    from ..cli import guarded

    return guarded(lambda: _cli_mpc(argv))


def _cli_mpc(argv: list[str]) -> int:
    from ..cli import error_line
    from ..results import claim_output_dir, default_output_dir
    from ..scenarios import find_scenario, load_scenario
    from .report import check_mpc_scenario, comparison_table, run_comparison, write_outputs
    from .scenario import MPCConfig
    from .settings import MPCSettings

    a = build_parser().parse_args(argv)
    sc = load_scenario(find_scenario(a.scenario))
    from ..provenance import declare

    declare(sc)  # every JSON this command writes names the scenario and its SHA-256
    cfg: MPCConfig = sc.extra.get("mpc") or MPCConfig(MPCSettings())
    changes = {k: v for k, v in (("solver", a.solver), ("qp_solver", a.qp_solver)) if v is not None}
    if a.codegen is not None:
        changes["codegen"] = a.codegen
    s = cfg.settings.with_(**changes)
    if a.t_end is not None:
        sc = sc.replace(t_end=a.t_end)
    laws = tuple(a.laws) if a.laws is not None else (tuple(sc.compare) or ("proposed", "ovfl"))
    check_mpc_scenario(sc, s, laws)  # bad input is refused before anything runs or is written
    out = Path(a.out) if a.out else default_output_dir("mpc", sc.name)
    overlays = tuple(f"overlay_vehicle{i + 1}.png" for i in range(sc.n_followers))
    claim_output_dir(out, "mpc", sc.name, str(sc.source) if sc.source else None, OUTPUT_FILES + overlays)
    c = run_comparison(sc, s, laws=laws, with_ocpd=not a.no_ocpd,
                       log=lambda m: print(f"[mpc] {m}", file=sys.stderr, flush=True))
    write_outputs(c, out)
    r = c.results["mpc"]
    for i in range(r.n_vehicles):
        print(f"\nfollower {i + 1}:")
        print(comparison_table(c, i))
    print(f"\nwrote {out}/results.json, trajectories_mpc.csv and plots")
    for lab, res in c.results.items():
        if lab != "mpc" and res.events:
            print(f"aev-ocp: warning: run {lab} stopped: {res.events[0]}", file=sys.stderr, flush=True)
    if r.events:
        error_line(f"scenario {sc.name}, run mpc: {r.events[0]} (results up to that time written to {out}/)")
        return 1
    return 0

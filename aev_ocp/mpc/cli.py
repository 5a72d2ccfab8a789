"""``aev-ocp mpc SCENARIO.toml [--out DIR] [--solver ...]``: the MPC closed loop of a scenario beside the
closed-form laws (and OCP-D for a single follower); writes results.json, a trajectories CSV and plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..params import ParameterError
from .settings import QP_SOLVERS, SOLVER_PATHS


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp mpc``."""
    p = argparse.ArgumentParser(prog="aev-ocp mpc", description=__doc__.splitlines()[0])
    p.add_argument("scenario", help="scenario TOML file or shipped scenario name (e.g. mpc_paper_single)")
    p.add_argument("--out", default=None, help="output folder (default results/mpc/<scenario name>)")
    p.add_argument("--solver", choices=SOLVER_PATHS, default=None, help="solver path (default: the scenario's)")
    p.add_argument("--qp-solver", choices=QP_SOLVERS, default=None, help="QP solver of the sqp path")
    cg = p.add_mutually_exclusive_group()
    cg.add_argument("--codegen", action="store_true", default=None, help="compile the NLP functions to C (gcc)")
    cg.add_argument("--no-codegen", dest="codegen", action="store_false", help="interpreted CasADi functions")
    p.add_argument("--t-end", type=float, default=None, help="shorter horizon [model time] for a quick run")
    p.add_argument("--laws", nargs="*", default=None, help="closed-form laws to compare (default proposed ovfl)")
    p.add_argument("--no-ocpd", action="store_true", help="skip the OCP-D lower bound")
    return p


def cli_mpc(argv: list[str]) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input, 3 run ended with an event)."""
    from ..scenarios import ScenarioError, find_scenario, load_scenario
    from .report import comparison_table, run_comparison, write_outputs
    from .scenario import MPCConfig
    from .settings import MPCSettings

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        sc = load_scenario(find_scenario(a.scenario))
        cfg: MPCConfig = sc.extra.get("mpc") or MPCConfig(MPCSettings())
        changes = {k: v for k, v in (("solver", a.solver), ("qp_solver", a.qp_solver)) if v is not None}
        if a.codegen is not None:
            changes["codegen"] = a.codegen
        s = cfg.settings.with_(**changes)
        if a.t_end is not None:
            sc = sc.replace(t_end=a.t_end)
        laws = tuple(a.laws) if a.laws is not None else (tuple(sc.compare) or ("proposed", "ovfl"))
        c = run_comparison(sc, s, laws=laws, with_ocpd=not a.no_ocpd,
                           log=lambda m: print(f"[mpc] {m}", file=sys.stderr, flush=True))
    except (ScenarioError, ParameterError) as exc:
        print(f"aev-ocp mpc: error: {exc}", file=sys.stderr)
        return 2
    out = Path(a.out) if a.out else Path("results") / "mpc" / sc.name
    write_outputs(c, out)
    r = c.results["mpc"]
    for i in range(r.n_vehicles):
        print(f"\nfollower {i + 1}:")
        print(comparison_table(c, i))
    for e in r.events:
        print(f"event: {e}")
    print(f"\nwrote {out}/results.json, trajectories_mpc.csv and plots")
    return 0 if r.status == "ok" else 3

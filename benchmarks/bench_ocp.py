"""Benchmark of the OCP layer: build and solve time of OCP-A…D versus N for both transcriptions.

Run: /work/venv/bin/python benchmarks/bench_ocp.py [--repeats 3] [--quick]
Prints a table and the fitted log-log slope of solve time vs N (≈ 1 means linear growth), and
writes benchmarks/bench_ocp.json atomically. Targets (issue 3): OCP-A at N = 200 solves in < 0.3 s;
OCP-D (Table 1 leader) at N = 700 in < 3 s.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aev_ocp.ocp.cell import cell_problem
from aev_ocp.ocp.current_profile import CurrentProfileSolver
from aev_ocp.ocp.eco_trip import EcoTrip, EcoTripSolver
from aev_ocp.ocp.oracle import OracleSolver, canonical_scenario
from aev_ocp.ocp.prop31 import SOC0, T_F_S, V_RELAX
from aev_ocp.ocp.result import write_json_atomic
from aev_ocp.ocp.transcription import OCPSolver, TranscriptionOptions
from aev_ocp.params import CellParams

NS = (100, 200, 400, 800, 1600)
METHODS = ("ms", "collocation")
BUDGET_S = 15.0  # skip larger N for a problem/method once one N took longer than this (build + solves)


def _make(problem: str, method: str, N: int) -> tuple[float, Callable[[], Any]]:
    """(build time [s], solve callable returning an OCPResult)."""
    if problem == "A":
        s = OCPSolver(cell_problem(CellParams(), False), TranscriptionOptions(method=method, N=N))
        return s.build_time_s, lambda: s.solve([V_RELAX[0], V_RELAX[1], SOC0], T_F_S)
    if problem == "B":
        b = CurrentProfileSolver(method, N)
        return b.solver.build_time_s, lambda: b.solve(3000.0, 60.0)
    if problem == "C":
        c = EcoTripSolver(EcoTrip(), method, N)
        return c.solver.build_time_s, c.solve
    scn = canonical_scenario()
    scn = dataclasses.replace(scn, dt=scn.t_end / N)
    d = OracleSolver(scn, method=method)
    return d.build_time_s, d.solve


def slope(ns: list[int], ts: list[float]) -> float:
    """Least-squares slope of log t vs log N."""
    if len(ns) < 2:
        return float("nan")
    return float(np.polyfit(np.log(ns), np.log(ts), 1)[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="N up to 400 only")
    ap.add_argument("--out", default=str(Path(__file__).with_name("bench_ocp.json")))
    args = ap.parse_args(argv)
    ns = NS[:3] if args.quick else NS
    rows: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    print(f"{'OCP':<4}{'method':<12}{'N':>6}{'build [s]':>11}{'solve [s]':>11}{'iter':>6}  status")
    for problem in ("A", "B", "C", "D"):
        for method in METHODS:
            for N in ns:
                t0 = time.perf_counter()
                build, solve = _make(problem, method, N)
                times, res = [], None
                for _ in range(args.repeats):
                    res = solve()
                    times.append(res.wall_time_s)
                row = {"ocp": problem, "method": method, "N": N, "build_s": build,
                       "solve_median_s": statistics.median(times), "solve_times_s": times,
                       "iterations": res.iterations, "status": res.status, "objective": res.objective}
                rows.append(row)
                print(f"{problem:<4}{method:<12}{N:>6}{build:>11.3f}{row['solve_median_s']:>11.3f}"
                      f"{res.iterations:>6}  {res.status}", flush=True)
                if time.perf_counter() - t0 > BUDGET_S:
                    print(f"     (skipping larger N for OCP-{problem} {method}: over {BUDGET_S:g} s)")
                    break
    # extra: the exact target cases
    targets: dict[str, Any] = {}
    build, solve = _make("A", "ms", 200)
    ta = statistics.median(solve().wall_time_s for _ in range(args.repeats))
    targets["ocp_a_ms_N200_solve_s"] = {"value": ta, "target": 0.3, "met": ta < 0.3}
    for method in METHODS:
        d = OracleSolver(canonical_scenario(), method=method)
        td = statistics.median(d.solve().wall_time_s for _ in range(args.repeats))
        targets[f"ocp_d_{method}_N700_solve_s"] = {"value": td, "build_s": d.build_time_s, "target": 3.0,
                                                   "met": td < 3.0}
    slopes: dict[str, dict[str, float]] = {}
    print("\nlog-log slope of time vs N (1 = linear):")
    for problem in ("A", "B", "C", "D"):
        for method in METHODS:
            sel = [r for r in rows if r["ocp"] == problem and r["method"] == method and r["status"] == "optimal"]
            s_solve = slope([r["N"] for r in sel], [r["solve_median_s"] for r in sel])
            s_build = slope([r["N"] for r in sel], [r["build_s"] for r in sel])
            per_it = slope([r["N"] for r in sel], [r["solve_median_s"] / max(r["iterations"], 1) for r in sel])
            slopes[f"{problem}_{method}"] = {"solve": s_solve, "build": s_build, "solve_per_iteration": per_it}
            print(f"  OCP-{problem} {method:<12} solve {s_solve:5.2f}   per iteration {per_it:5.2f}   build {s_build:5.2f}")
    print("\ntargets:")
    for k, v in targets.items():
        print(f"  {k}: {v['value']:.3f} s (target < {v['target']} s): {'met' if v['met'] else 'NOT met'}")
    total = time.perf_counter() - t_start
    print(f"\ntotal benchmark time {total:.1f} s")
    write_json_atomic(args.out, {"rows": rows, "slopes": slopes, "targets": targets, "repeats": args.repeats,
                                 "total_time_s": total, "python": sys.version.split()[0]})
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

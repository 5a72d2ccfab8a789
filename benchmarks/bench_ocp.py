"""Benchmark of the OCP layer: build and solve time of OCP-A…D versus N for both transcriptions.

Run: /work/venv/bin/python benchmarks/bench_ocp.py [--repeats 3] [--quick] [--udds-only]
Prints a table and the fitted log-log slope of solve time vs N (≈ 1 means linear growth), and
writes benchmarks/bench_ocp.json atomically. Targets (issue 3): OCP-A at N = 200 solves in < 0.3 s;
OCP-D (Table 1 leader) at N = 700 in < 3 s. Issue 8 item 5: OCP-D on the whole UDDS (udds_platoon,
1369 s on the 1 s grid, N = 1369) in < 60 s and < 2 GB peak RSS, each variant (the mapped MX NLP, the
default, and the SX expansion; then HWFET and US06) in its own process so that its peak RSS is its own.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
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
from aev_ocp.ocp_result import write_json_atomic
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


UDDS_TARGET_S, UDDS_TARGET_GB = 60.0, 2.0  # issue 8 item 5


#: (variant, scenario) of the whole-cycle lines: UDDS both ways, then HWFET and US06 with the default.
WHOLE_CYCLES = (("mx", "udds_platoon"), ("sx", "udds_platoon"), ("mx", "hwfet_platoon"), ("mx", "us06_platoon"))


def whole_udds_child(variant: str, scenario: str = "udds_platoon") -> dict[str, Any]:
    """In this process: build and solve OCP-D on a whole cycle (variant 'mx': mapped MX NLP, 'sx':
    expanded); wall times [s], peak RSS [GB] of this process, status, iterations, objective."""
    from aev_ocp.ocp.run import oracle_scenario_from_file
    from aev_ocp.scenarios import find_scenario

    t0 = time.perf_counter()
    scn = oracle_scenario_from_file(find_scenario(scenario))
    d = OracleSolver(scn, mx_map=(variant == "mx"))
    res = d.solve()
    return {
        "variant": variant,
        "scenario": scenario,
        "N": scn.N,
        "dt_s": scn.dt * scn.ev.units.time_s,
        "build_s": d.build_time_s,
        "solve_s": res.wall_time_s,
        "total_s": time.perf_counter() - t0,
        "iterations": res.iterations,
        "status": res.status,
        "objective": res.objective,
        "peak_rss_GB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9,
    }


def whole_udds(cases: tuple[tuple[str, str], ...] = WHOLE_CYCLES) -> list[dict[str, Any]]:
    """Each (variant, scenario) of :func:`whole_udds_child` in a fresh Python process (its own peak RSS)."""
    out = []
    for v, sc in cases:
        p = subprocess.run(
            [sys.executable, __file__, "--child-udds", v, sc], capture_output=True, text=True, check=True
        )
        out.append(json.loads(p.stdout.strip().splitlines()[-1]))
    return out


def print_udds(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Print the whole-cycle lines; returns the target record of the default (mx) variant on UDDS."""
    print(f"\nOCP-D, whole cycles on the 1 s grid (dt = {rows[0]['dt_s']:.3g} s):")
    print(
        f"{'scenario':<15}{'variant':<9}{'N':>6}{'build [s]':>10}{'solve [s]':>10}{'total [s]':>10}{'iter':>6}"
        f"{'peak RSS [GB]':>15}  status"
    )
    for r in rows:
        print(
            f"{r['scenario']:<15}{r['variant']:<9}{r['N']:>6}{r['build_s']:>10.2f}{r['solve_s']:>10.2f}{r['total_s']:>10.2f}{r['iterations']:>6}"
            f"{r['peak_rss_GB']:>15.3f}  {r['status']}"
        )
    mx = rows[0]
    return {
        "value": mx["total_s"],
        "peak_rss_GB": mx["peak_rss_GB"],
        "target": UDDS_TARGET_S,
        "target_GB": UDDS_TARGET_GB,
        "met": mx["total_s"] < UDDS_TARGET_S and mx["peak_rss_GB"] < UDDS_TARGET_GB and mx["status"] == "optimal",
    }


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
    ap.add_argument(
        "--udds-only",
        action="store_true",
        help="only OCP-D on the whole cycles (UDDS mapped and expanded, HWFET, US06)",
    )
    ap.add_argument("--child-udds", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child_udds:
        print(json.dumps(whole_udds_child(*args.child_udds)))
        return 0
    if args.udds_only:
        udds = whole_udds()
        target = print_udds(udds)
        print(
            f"  ocp_d_whole_udds: {target['value']:.1f} s, {target['peak_rss_GB']:.3f} GB (target < 60 s, "
            f"< 2 GB): {'met' if target['met'] else 'NOT met'}"
        )
        out = Path(args.out).with_name("bench_ocp_udds.json")
        write_json_atomic(out, {"whole_udds": udds, "target": target, "python": sys.version.split()[0]})
        print(f"wrote {out}")
        return 0
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
                row = {
                    "ocp": problem,
                    "method": method,
                    "N": N,
                    "build_s": build,
                    "solve_median_s": statistics.median(times),
                    "solve_times_s": times,
                    "iterations": res.iterations,
                    "status": res.status,
                    "objective": res.objective,
                }
                rows.append(row)
                print(
                    f"{problem:<4}{method:<12}{N:>6}{build:>11.3f}{row['solve_median_s']:>11.3f}"
                    f"{res.iterations:>6}  {res.status}",
                    flush=True,
                )
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
        targets[f"ocp_d_{method}_N700_solve_s"] = {
            "value": td,
            "build_s": d.build_time_s,
            "target": 3.0,
            "met": td < 3.0,
        }
    udds = whole_udds()
    targets["ocp_d_whole_udds_total_s"] = print_udds(udds)
    slopes: dict[str, dict[str, float]] = {}
    print("\nlog-log slope of time vs N (1 = linear):")
    for problem in ("A", "B", "C", "D"):
        for method in METHODS:
            sel = [r for r in rows if r["ocp"] == problem and r["method"] == method and r["status"] == "optimal"]
            s_solve = slope([r["N"] for r in sel], [r["solve_median_s"] for r in sel])
            s_build = slope([r["N"] for r in sel], [r["build_s"] for r in sel])
            per_it = slope([r["N"] for r in sel], [r["solve_median_s"] / max(r["iterations"], 1) for r in sel])
            slopes[f"{problem}_{method}"] = {"solve": s_solve, "build": s_build, "solve_per_iteration": per_it}
            print(
                f"  OCP-{problem} {method:<12} solve {s_solve:5.2f}   per iteration {per_it:5.2f}   build {s_build:5.2f}"
            )
    print("\ntargets:")
    for k, v in targets.items():
        gb = f", peak RSS {v['peak_rss_GB']:.3f} GB (target < {v['target_GB']} GB)" if "peak_rss_GB" in v else ""
        print(f"  {k}: {v['value']:.3f} s (target < {v['target']} s){gb}: {'met' if v['met'] else 'NOT met'}")
    total = time.perf_counter() - t_start
    print(f"\ntotal benchmark time {total:.1f} s")
    write_json_atomic(
        args.out,
        {
            "rows": rows,
            "slopes": slopes,
            "targets": targets,
            "whole_udds": udds,
            "repeats": args.repeats,
            "total_time_s": total,
            "python": sys.version.split()[0],
        },
    )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

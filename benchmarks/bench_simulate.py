"""Benchmark of :mod:`aev_ocp.simulate` against the independent SciPy reference (GitHub issue 2).

Two parts, both timed per run *after* the CasADi Functions are built (build time reported apart):

1. Table 1 scenario (paper leader, 5 proposed-law followers, gaps [0.3, 3.5×4], speeds 1.87,
   t ∈ [0, 70], battery on). Every run's final ω [model units] is compared with a tight reference
   (SciPy DOP853 at rtol = atol = 1e-12, cross-checked against CasADi at 1e-12). The SciPy baseline
   runs at a few tolerances; for each, the *cheapest* CasADi tolerance whose ω error is no larger is
   the "matching accuracy" run, and the speed-up is baseline time / CasADi time.
2. Scale: 10, 100 and 1000 proposed-law followers behind the paper leader over 70 time units,
   dt_out = 0.1, rtol = atol = 1e-8 (gaps 3.5 except 0.3 for the first, speeds 1.87).

Times are medians over repeats (the machine is shared, so single timings are noisy). Results go to
``benchmarks/bench_simulate.json`` (atomic write). Run: ``python benchmarks/bench_simulate.py``
(``--quick`` for fewer repeats). Not part of the test suite; about 2–4 minutes.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aev_ocp.models import PaperLeader, Proposed
from aev_ocp.reference import simulate_reference
from aev_ocp.results import write_json
from aev_ocp.simulate import PlatoonSimulator, SimOptions

OUT = Path(__file__).with_name("bench_simulate.json")
T_END = 70.0  # model time
GAPS = np.array([0.3, 3.5, 3.5, 3.5, 3.5])  # model length
SPEEDS = np.full(5, 1.87)  # model speed


def _median_time(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """Median wall time [s] of ``repeats`` calls of fn, and the last call's result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _sim(n: int, rtol: float, dt_out: float, method: str = "auto") -> tuple[PlatoonSimulator, float]:
    """A built simulator for n proposed-law followers, and its build time [s] (C compile cached on disk)."""
    t0 = time.perf_counter()
    sim = PlatoonSimulator(
        PaperLeader(),
        [Proposed()] * n,
        options=SimOptions(dt_out=dt_out, rtol=rtol, atol=rtol, max_num_steps=10**7, method=method),
    )
    return sim, time.perf_counter() - t0


def table1(repeats: int) -> dict[str, Any]:
    """Part 1: time and ω error of CasADi and SciPy runs of the Table 1 scenario."""
    t0 = time.perf_counter()
    ref = simulate_reference("proposed", GAPS, SPEEDS, T_END, rtol=1e-12, atol=1e-12)
    ref_time = time.perf_counter() - t0
    omega_ref = np.asarray(ref["omega"])
    sim, _ = _sim(5, 1e-12, 0.01, "cvodes")
    omega_cv12 = sim.run(GAPS, SPEEDS, T_END).omega[-1]
    cross = float(np.max(np.abs(omega_cv12 - omega_ref)))
    print(f"reference: SciPy DOP853 rtol=atol=1e-12, {ref_time:.2f} s; |ω_CasADi(1e-12) − ω_ref| = {cross:.1e}")

    rows: list[dict[str, Any]] = []
    for rtol in (1e-8, 1e-10):
        med, out = _median_time(
            lambda: simulate_reference("proposed", GAPS, SPEEDS, T_END, rtol=rtol, atol=rtol), max(1, repeats // 2)
        )
        rows.append(
            {
                "impl": "scipy_dop853",
                "rtol": rtol,
                "time_s": med,
                "nfev": int(out["nfev"]),
                "omega_err": float(np.max(np.abs(out["omega"] - omega_ref))),
            }
        )
    configs = [("cvodes", r) for r in (1e-8, 1e-10)] + [("auto", r) for r in (1e-7, 1e-8, 1e-9, 1e-10, 1e-11)]
    for method, rtol in configs:
        sim, build = _sim(5, rtol, 0.01, method)
        med, out = _median_time(lambda: sim.run(GAPS, SPEEDS, T_END), repeats if method == "auto" else 3)
        rows.append(
            {
                "impl": f"casadi_{sim.method}",
                "rtol": rtol,
                "time_s": med,
                "build_s": build,
                "status": out.status,
                "omega_err": float(np.max(np.abs(out.omega[-1] - omega_ref))),
                "heat_rel_err_vs_scipy_ref": float(np.max(np.abs(out.heat_J[-1] / ref["heat_J"] - 1))),
                "S_err": float(np.max(np.abs(out.S[-1] - ref["S"]))),
            }
        )
    matches = []
    for base in (r for r in rows if r["impl"] == "scipy_dop853"):
        cands = [r for r in rows if r["impl"].startswith("casadi") and r["omega_err"] <= base["omega_err"]]
        pick = (
            min(cands, key=lambda r: r["time_s"])
            if cands
            else min((r for r in rows if r["impl"].startswith("casadi")), key=lambda r: r["omega_err"])
        )
        matches.append(
            {
                "scipy_rtol": base["rtol"],
                "scipy_time_s": base["time_s"],
                "scipy_omega_err": base["omega_err"],
                "casadi_impl": pick["impl"],
                "casadi_rtol": pick["rtol"],
                "casadi_time_s": pick["time_s"],
                "casadi_omega_err": pick["omega_err"],
                "speedup": base["time_s"] / pick["time_s"],
                "accuracy_matched": pick["omega_err"] <= base["omega_err"],
            }
        )
    return {
        "reference": {
            "method": "DOP853",
            "rtol": 1e-12,
            "time_s": ref_time,
            "omega": omega_ref,
            "casadi_1e-12_max_abs_diff": cross,
        },
        "runs": rows,
        "matches": matches,
        "target_speedup": 20.0,
        "target_met": all(m["speedup"] >= 20.0 and m["accuracy_matched"] for m in matches),
    }


def scale(sizes: tuple[int, ...], repeats: int) -> dict[str, Any]:
    """Part 2: time per run for n followers (dt_out = 0.1, rtol = 1e-8); ω error against the same
    simulator at rtol = 1e-11, and for n = 10 also against SciPy DOP853 at 1e-11."""
    rows = []
    for n in sizes:
        gaps, speeds = np.full(n, 3.5), np.full(n, 1.87)
        gaps[0] = 0.3
        sim, build = _sim(n, 1e-8, 0.1)
        med, out = _median_time(lambda: sim.run(gaps, speeds, T_END), repeats if n <= 100 else max(1, repeats // 2))
        tight, _ = _sim(n, 1e-11, 0.1)
        err = float(np.max(np.abs(out.omega[-1] - tight.run(gaps, speeds, T_END).omega[-1])))
        row = {
            "n": n,
            "impl": f"casadi_{sim.method}",
            "time_s": med,
            "build_s": build,
            "status": out.status,
            "omega_err_vs_rtol_1e-11": err,
            "omega_first": float(out.omega[-1, 0]),
            "omega_last": float(out.omega[-1, -1]),
            "steps": int(sum(s["nsteps"] for s in out.solver_stats)) if out.solver_stats[0] else None,
        }
        if n == 10:
            ref = simulate_reference("proposed", gaps, speeds, T_END, rtol=1e-11, atol=1e-11)
            row["omega_err_vs_scipy_1e-11"] = float(np.max(np.abs(out.omega[-1] - ref["omega"])))
        rows.append(row)
        print(
            f"n = {n:5d}: {med:8.3f} s per run (build {build:.2f} s), status {out.status}, "
            f"ω err vs 1e-11 {err:.1e}"
            + (f", vs SciPy 1e-11 {row['omega_err_vs_scipy_1e-11']:.1e}" if n == 10 else ""),
            flush=True,
        )
    t1000 = next((r["time_s"] for r in rows if r["n"] == 1000), None)
    return {
        "dt_out": 0.1,
        "rtol": 1e-8,
        "runs": rows,
        "target_s_1000": 2.0,
        "target_met": t1000 is not None and t1000 < 2.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    ap.add_argument("--out", type=Path, default=OUT, help="JSON output path")
    args = ap.parse_args()
    repeats = 3 if args.quick else 7
    res: dict[str, Any] = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}
    }
    res["table1"] = t1 = table1(repeats)
    base = {r["rtol"]: r["time_s"] for r in t1["runs"] if r["impl"] == "scipy_dop853"}
    print(f"\n{'impl':15s} {'rtol':>7s} {'time/run':>11s} {'ω err':>9s} {'vs SciPy 1e-8':>14s}")
    for r in t1["runs"]:
        print(
            f"{r['impl']:15s} {r['rtol']:7.0e} {r['time_s'] * 1e3:8.1f} ms {r['omega_err']:9.1e} "
            f"{base[1e-8] / r['time_s']:13.1f}×"
        )
    print("\nmatching accuracy (cheapest CasADi run with ω error ≤ SciPy's):")
    for m in t1["matches"]:
        print(
            f"  SciPy {m['scipy_rtol']:.0e} {m['scipy_time_s'] * 1e3:7.1f} ms (err {m['scipy_omega_err']:.1e})  vs  "
            f"{m['casadi_impl']} {m['casadi_rtol']:.0e} {m['casadi_time_s'] * 1e3:6.1f} ms (err {m['casadi_omega_err']:.1e}): "
            f"{m['speedup']:.1f}×"
        )
    print(f"target ≥ 20× at matching accuracy: {'met' if t1['target_met'] else 'NOT met'}\n")
    res["scale"] = sc = scale((10, 100, 1000), 3 if args.quick else 5)
    print(f"target 1000 followers < 2 s: {'met' if sc['target_met'] else 'NOT met'}")
    write_json(args.out, res)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

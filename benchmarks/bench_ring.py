"""Benchmark of the compiled ring (aev_ocp.ring): Sugiyama-density rings of human IDM drivers (22 vehicles per
230 m, acceleration noise 0.1 m/s²: the stop-and-go wave forms and runs for the whole time) over 600 s.

Targets (issue 22): 22 vehicles ≤ 1 s, 1 000 ≤ 10 s, 10 000 ≤ 120 s and ≤ 4 GB, on 2 cores. Prints a table and
writes JSON (``--out``, default results/bench_ring.json): wall time, steps, rejected steps, right-hand-side
evaluations, peak resident memory, and the fleet's speed std; beside the wall time the process CPU time and the
1-minute load average when the run started (on a shared machine the wall time is the CPU time the scheduler gave). The big rings use rtol = atol = 1e-5 with
RingOptions.local_factor = 30 (the step is set by the ring's RMS error, a single vehicle may reach 30× the
tolerance at a kink: a stop, a saturation) and thinned output (5 s): on 1 000 vehicles × 600 s their fleet speed
std and energy per km agree with the strict per-vehicle norm (local_factor 1) to 2e-5 and 1e-4 relative.

    python benchmarks/bench_ring.py [--sizes 22 1000 10000] [--threads 2] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

from aev_ocp.ring.experiments import fleet_metrics, human_ring
from aev_ocp.ring.simulate import RingOptions, RingSimulator, uniform_flow

TARGET_S = {22: 1.0, 1000: 10.0, 10000: 120.0}


def run(n: int, t_end_s: float, threads: int, tol: float, lf: float = 1.0) -> dict:
    ring = human_ring(230.0 / 22 * n, n, seed=1)
    opts = RingOptions(rtol=tol, atol=tol, dt_out_s=0.5 if n <= 100 else 5.0, threads=threads, local_factor=lf)
    t0 = time.perf_counter()
    sim = RingSimulator(ring, opts)
    build = time.perf_counter() - t0
    c0, load = time.process_time(), os.getloadavg()[0]
    t1 = time.perf_counter()
    res = sim.run(uniform_flow(ring, shift_m=2.0), t_end_s)
    wall = time.perf_counter() - t1
    cpu = time.process_time() - c0
    f = fleet_metrics(res)
    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    return {
        "vehicles": n,
        "t_end_s": t_end_s,
        "rtol": tol,
        "threads": threads,
        "build_s": build,
        "run_s": wall,
        "cpu_s": cpu,
        "load_1min": load,
        "target_s": TARGET_S.get(n),
        "peak_rss_GB": rss_gb,
        "status": res.status,
        **res.stats,
        "speed_std_mps": f["speed_std_mps"],
        "battery_energy_J_per_km": f["battery_energy_J_per_km"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[22, 1000, 10000])
    p.add_argument("--t-end-s", type=float, default=600.0)
    p.add_argument(
        "--threads", type=int, default=1
    )  # 2 only on an idle machine: OpenMP barriers stall when the cores are shared
    p.add_argument("--out", default="results/bench_ring.json")
    a = p.parse_args()
    rows = []
    print(
        f"{'vehicles':>9} {'tol':>7} {'run [s]':>9} {'cpu [s]':>8} {'load':>5} {'target':>7} {'steps':>8} {'rejected':>8} {'RSS [GB]':>9} "
        f"{'speed std':>9} {'Eb [J/km]':>10} status"
    )
    for n in a.sizes:
        tol = 1e-8 if n <= 100 else 1e-5
        r = run(n, a.t_end_s, a.threads, tol, 1.0 if n <= 100 else 30.0)
        rows.append(r)
        print(
            f"{n:>9} {tol:>7.0e} {r['run_s']:>9.3f} {r['cpu_s']:>8.3f} {r['load_1min']:>5.2f} {r['target_s'] or float('nan'):>7g} {r['steps']:>8} "
            f"{r['rejected']:>8} {r['peak_rss_GB']:>9.3f} {r['speed_std_mps']:>9.4f} {r['battery_energy_J_per_km']:>10.5g} "
            f"{r['status']}",
            flush=True,
        )
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

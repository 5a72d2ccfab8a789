"""Benchmark of the compiled ring (aev_ocp.ring): Sugiyama-density rings of human IDM drivers (22 vehicles per
230 m, acceleration noise 0.1 m/s²: the stop-and-go wave forms and runs for the whole time) over 600 s.

Targets (issue 22): 22 vehicles ≤ 1 s, 1 000 ≤ 10 s, 10 000 ≤ 120 s and ≤ 4 GB, on 2 cores. Prints a table and
writes JSON (``--out``, default results/bench_ring.json): wall time, steps, rejected steps, right-hand-side
evaluations, peak resident memory, and the fleet's speed std; beside the wall time the process CPU time and the
1-minute load average when the run started (on a shared machine the wall time is the CPU time the scheduler gave). The big rings use rtol = atol = 1e-5 with
RingOptions.local_factor = 30 (the step is set by the ring's RMS error, a single vehicle may reach 30× the
tolerance at a kink: a stop, a saturation) and thinned output (5 s): on 1 000 vehicles × 600 s their fleet speed
std and energy per km agree with the strict per-vehicle norm (local_factor 1) to 2e-5 and 1e-4 relative.

Issue 36/40 target: 10 000 vehicles × 600 s in ≤ 60 s on one core (``--threads 1``, the default). ns per
vehicle-step is the run's CPU time over n × (accepted + rejected steps). Issue 36's last step (the OCV looked up in a
table instead of 40 masked comparisons, the laws' coefficient-only parts evaluated once per advance, fmax/fmin inline):
CPU ratio to the main before it 0.50 at 10 000 and 0.61 at 1 000 vehicles (--baseline, load 3 on 2 cores), the
same bits. ``--baseline DIR`` measures the same in a child
process with another checkout's toolkit (e.g. ``git worktree add /tmp/main main``), alternating with this one, and
prints the CPU ratio and whether the trajectories are the same to the bit (hash of gap, speed, accel, ω, S, I, energy).

    python benchmarks/bench_ring.py [--sizes 22 1000 10000] [--threads 2] [--baseline DIR] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

from _baseline import load_1min, run_baseline, trajectory_hash

from aev_ocp.results import write_json
from aev_ocp.ring.run import fleet_metrics, human_ring
from aev_ocp.ring.simulate import RingOptions, RingSimulator, uniform_flow

TARGET_S = {22: 1.0, 1000: 10.0, 10000: 60.0}


def run(n: int, t_end_s: float, threads: int, tol: float, lf: float = 1.0) -> dict:
    ring = human_ring(230.0 / 22 * n, n, seed=1)
    opts = RingOptions(rtol=tol, atol=tol, dt_out_s=0.5 if n <= 100 else 5.0, threads=threads, local_factor=lf)
    t0 = time.perf_counter()
    sim = RingSimulator(ring, opts)
    build = time.perf_counter() - t0
    c0, load = time.process_time(), load_1min()
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
        "ns_per_vehicle_step": 1e9 * cpu / max(n * (res.stats["steps"] + res.stats["rejected"]), 1),
        "hash": trajectory_hash(
            res.sim.gap, res.sim.speed, res.sim.accel, res.sim.omega, res.sim.S, res.sim.current_A, res.energy_J
        ),
    }


def _row(label: str, r: dict) -> str:
    return (
        f"{label:>8} {r['vehicles']:>9} {r['t_end_s']:>6g} {r['rtol']:>7.0e} {r['run_s']:>9.3f} {r['cpu_s']:>8.3f} "
        f"{r['load_1min']:>5.2f} {r['target_s'] or float('nan'):>7g} {r['steps']:>8} {r['rejected']:>8} "
        f"{r['ns_per_vehicle_step']:>9.0f} {r['peak_rss_GB']:>9.3f} {r['speed_std_mps']:>9.4f} "
        f"{r['battery_energy_J_per_km']:>10.5g} {r['status']} {r['hash']}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[22, 1000, 10000])
    p.add_argument("--t-end-s", type=float, default=600.0)
    p.add_argument(
        "--threads", type=int, default=1
    )  # 2 only on an idle machine: OpenMP barriers stall when the cores are shared
    p.add_argument("--baseline", default=None, help="another checkout of the toolkit, measured alongside")
    p.add_argument("--out", default="results/bench_ring.json")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args()

    def one(n: int) -> dict:
        tol = 1e-8 if n <= 100 else 1e-5
        return run(n, a.t_end_s, a.threads, tol, 1.0 if n <= 100 else 30.0)

    if a.child:  # one measurement for a parent's --baseline: its JSON row on the last line
        print(json.dumps(one(a.sizes[0])))
        return
    rows = []
    print(
        f"{'version':>8} {'vehicles':>9} {'t_end':>6} {'tol':>7} {'wall [s]':>9} {'cpu [s]':>8} {'load':>5} {'target':>7} "
        f"{'steps':>8} {'rejected':>8} {'ns/v-step':>9} {'RSS [GB]':>9} {'speed std':>9} {'Eb [J/km]':>10} status hash"
    )
    for n in a.sizes:
        r = one(n)
        rows.append(r)
        print(_row("this", r), flush=True)
        if a.baseline:
            args = ["--sizes", str(n), "--t-end-s", str(a.t_end_s), "--threads", str(a.threads)]
            b = run_baseline(__file__, a.baseline, args)
            r |= {"baseline": b, "cpu_ratio": r["cpu_s"] / b["cpu_s"], "same_bits": r["hash"] == b["hash"]}
            print(_row("baseline", b), flush=True)
            print(f"{'':>8} CPU ratio this/baseline {r['cpu_ratio']:.3f}, same bits: {r['same_bits']}", flush=True)
    out = write_json(Path(a.out), rows)  # atomic
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

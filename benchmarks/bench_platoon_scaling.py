"""Scaling of the compiled platoon simulator (the cascade, aev_ocp/c/cascade.c): N proposed-law followers behind the
paper leader over 70 model time, sampled every 0.1, rtol = atol = 1e-8 (as bench_simulate.py's scale part).

Target (issue 40, item 6): 10 000 followers × 70 model time in ≤ 10 s. Prints a table (N, model time, build [s], CPU
[s], wall [s], steps, ns per vehicle-step, load) and writes JSON (``--out``, default
results/bench_platoon_scaling.json). Steps are every follower's attempts (accepted + rejected) summed; ns per
vehicle-step is the run's CPU time over them (the whole run: integration, samples, the result's arrays). CPU and
wall are medians over ``--repeats``; beside them the 1-minute load average. ``--baseline DIR`` measures the same in a
child process with another checkout's toolkit (e.g. ``git worktree add /tmp/main main``), alternating with this one,
and prints the CPU ratio and whether the trajectories are the same to the bit (hash of gap, speed, accel, ω, S, I).

    python benchmarks/bench_platoon_scaling.py [--sizes 100 1000 10000] [--repeats 3] [--baseline DIR] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
from _baseline import load_1min, run_baseline, trajectory_hash

from aev_ocp.models import PaperLeader, Proposed
from aev_ocp.results import write_json
from aev_ocp.simulate import PlatoonSimulator, SimOptions

T_END = 70.0  # model time (the paper's runs)
TARGET_S = {10000: 10.0}


def measure(n: int, repeats: int, t_end: float = T_END) -> dict[str, Any]:
    """Build once, run ``repeats`` times: medians of CPU and wall [s], steps, hash of the last run."""
    t0 = time.perf_counter()
    opts = SimOptions(dt_out=0.1, rtol=1e-8, atol=1e-8, max_num_steps=10**7)
    sim = PlatoonSimulator(PaperLeader(), [Proposed()] * n, options=opts)
    build = time.perf_counter() - t0
    gaps, speeds = np.full(n, 3.5), np.full(n, 1.87)
    gaps[0] = 0.3
    cpu, wall, load = [], [], load_1min()
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        r = sim.run(gaps, speeds, t_end)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    steps = sum(int(s["nsteps"]) + int(s["nrejected"]) for s in r.solver_stats)
    return {
        "n": n,
        "t_end_model": t_end,
        "method": sim.method,
        "build_s": build,
        "cpu_s": statistics.median(cpu),
        "wall_s": statistics.median(wall),
        "vehicle_steps": steps,
        "ns_per_vehicle_step": 1e9 * statistics.median(cpu) / max(steps, 1),
        "load_1min": load,
        "hash": trajectory_hash(r.gap, r.speed, r.accel, r.omega, r.S, r.current_A),
        "status": r.status,
    }


def _row(label: str, r: dict[str, Any]) -> str:
    return (
        f"{label:>8} {r['n']:>7} {r['t_end_model']:>6g} {r['build_s']:>8.2f} {r['cpu_s']:>8.2f} {r['wall_s']:>8.2f} "
        f"{r['vehicle_steps']:>10} {r['ns_per_vehicle_step']:>9.0f} {r['load_1min']:>5.2f} {r['hash']}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--baseline", default=None, help="another checkout of the toolkit, measured alongside")
    p.add_argument("--out", default="results/bench_platoon_scaling.json")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.child:  # one measurement for a parent's --baseline: its JSON row on the last line
        print(json.dumps(measure(a.sizes[0], a.repeats)))
        return
    print(
        f"{'version':>8} {'N':>7} {'t_end':>6} {'build s':>8} {'CPU s':>8} {'wall s':>8} {'veh-steps':>10} "
        f"{'ns/v-step':>9} {'load':>5} hash"
    )
    rows: list[dict[str, Any]] = []
    for n in a.sizes:
        new = measure(n, a.repeats)
        print(_row("this", new), flush=True)
        row: dict[str, Any] = {"this": new, "target_s": TARGET_S.get(n)}
        if a.baseline:
            base = run_baseline(__file__, a.baseline, ["--sizes", str(n), "--repeats", str(a.repeats)])
            print(_row("baseline", base), flush=True)
            row |= {
                "baseline": base,
                "cpu_ratio": new["cpu_s"] / base["cpu_s"],
                "same_bits": new["hash"] == base["hash"],
            }
            print(f"{'':>8} CPU ratio this/baseline {row['cpu_ratio']:.3f}, same bits: {row['same_bits']}")
        rows.append(row)
    out = write_json(Path(a.out), {"t_end_model": T_END, "dt_out": 0.1, "rtol": 1e-8, "runs": rows})
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

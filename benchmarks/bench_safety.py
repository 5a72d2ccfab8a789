"""Benchmark of the safety suite (``aev-ocp safety`` / ``aev_ocp.safety.run_suite``, issues 34 and 40).

Targets: the whole suite (49 cases × 2 actuators × 10 controllers = 980 runs) in ≤ 2 minutes on 2 cores (issue 34),
≤ 30 s (issue 40). Runs, in this process:

1. ``laws``: the bare laws' path, a few cases — the compiled cascade as before (``method='auto'``: the case's
   leader is a constant of the generated C, so each case compiled a library of its own the first time, 2–3 s;
   cached on disk after) against CVODES (``method='cvodes'``, what the suite uses now: nothing to compile); the
   ratio is per run, medians over the cases;
2. ``serial``: the suite in this process (``workers=1``);
3. ``pool``: the suite on the process pool (``workers``, default 2).

Every run's table (every row and number but the timing column ``wall_s``) is hashed (:func:`table_sha256`): the
serial and the pool runs must give the same table, and ``--expect-table-sha256 HEX`` (the hash a run of the code
before a change printed, same options) checks that the change left every result as it was; the run exits 1 when a
check fails.

Prints a table and writes JSON (``--out``, default results/bench_safety.json): wall time, CPU time (this process
and its finished children), the 1-minute load average at each start and the machine's cores (on a shared machine
the wall time is the CPU time the scheduler gave). The MPC libraries are compiled once per machine
(~/.cache/aev_ocp); run the suite once before timing it, or pass ``--cold`` to time it as it comes.

    python benchmarks/bench_safety.py [--quick] [--workers 2] [--skip-serial] [--expect-table-sha256 HEX] [--out FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import resource
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable

from aev_ocp.models.carfollowing import Proposed
from aev_ocp.models.leader import BrakingLeader
from aev_ocp.params import EVParams
from aev_ocp.results import write_atomic
from aev_ocp.safety.cases import CASE_UNITS, DECLARED, suite_cases
from aev_ocp.safety.run import run_suite
from aev_ocp.simulate import simulate_platoon

TARGETS_S = {"issue 34 (2 cores)": 120.0, "issue 40": 30.0}


def table_sha256(rows: list[Any]) -> str:
    """SHA-256 of the suite's table: every row's every field as its repr (floats to the last bit), but ``wall_s``."""
    d = [{k: repr(v) for k, v in dataclasses.asdict(r).items() if k != "wall_s"} for r in rows]
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def timed(fn: Callable[[], Any]) -> tuple[Any, dict[str, float]]:
    load, c0, t0 = os.getloadavg()[0], _cpu(), time.perf_counter()
    out = fn()
    return out, {"wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0, "load_1min_at_start": load}


def law_paths(n_cases: int = 4) -> dict[str, Any]:
    """The bare proposed law on n_cases cases through the compiled cascade and through CVODES (per-run medians)."""
    u = CASE_UNITS
    ev = EVParams(units=u, limits=DECLARED.limits())
    rows = []
    for c in [c for c in suite_cases() if c.family in ("CCRb", "cut-in")][:n_cases]:
        lead = BrakingLeader.from_si(c.v_lead_mps, c.a_lead_mps2, c.t_brake_s, u)
        args = (lead, [Proposed()], [float(u.length_from_si(c.gap_m))], [float(u.speed_from_si(c.v_ego_mps))])
        t_end = float(u.time_from_si(c.t_end_s))
        row: dict[str, Any] = {"case": c.name}
        for method in ("auto", "cvodes"):
            _, tm = timed(lambda m=method: simulate_platoon(*args, t_end, ev=ev, dt_out=0.01, method=m))  # type: ignore[misc]
            row[method] = tm
        rows.append(row)
    med = {m: statistics.median(r[m]["wall_s"] for r in rows) for m in ("auto", "cvodes")}
    return {"cases": rows, "median_wall_s": med, "ratio_auto_over_cvodes": med["auto"] / med["cvodes"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the quick subset (8 cases, 3 s each)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-serial", action="store_true", help="time the pool only")
    ap.add_argument("--cold", action="store_true", help="no warm-up run (MPC libraries compiled as they come)")
    ap.add_argument("--expect-table-sha256", default=None, help="the table hash every run must give")
    ap.add_argument("--out", default="results/bench_safety.json")
    a = ap.parse_args()
    res: dict[str, Any] = {"cores": os.cpu_count(), "quick": a.quick, "workers": a.workers, "targets_s": TARGETS_S}
    if not a.cold:  # compiles the MPC libraries of both actuators, with and without the margin, if not cached
        run_suite(suite_cases(True)[:1], ("mpc+layer", "mpc-margin+layer"), workers=1)
    res["laws"] = law_paths()
    runs = {}
    if not a.skip_serial:
        out, runs["serial"] = timed(lambda: run_suite(quick=a.quick, workers=1))
        runs["serial"]["runs"] = len(out.rows)
        runs["serial"]["table_sha256"] = table_sha256(out.rows)
    out, runs["pool"] = timed(lambda: run_suite(quick=a.quick, workers=a.workers))
    runs["pool"]["runs"] = len(out.rows)
    runs["pool"]["table_sha256"] = table_sha256(out.rows)
    hashes = {k: v["table_sha256"] for k, v in runs.items()}
    bad = [k for k, h in hashes.items() if h != (a.expect_table_sha256 or hashes["pool"])]
    res["table_check"] = {"expected": a.expect_table_sha256, "hashes": hashes, "failed": bad}
    if "serial" in runs:
        runs["pool"]["speedup_vs_serial"] = runs["serial"]["wall_s"] / runs["pool"]["wall_s"]
        # the pool's ideal on an otherwise idle machine: the serial run's CPU shared evenly by the workers
        runs["pool"]["ideal_wall_s"] = runs["serial"]["cpu_s"] / a.workers
    res["suite"] = runs
    res["layer_collisions_in_avoidable_cases"] = sum(
        1 for r in out.rows if r.layer and r.collision and r.label == "avoidable"
    )
    print(f"machine: {os.cpu_count()} cores; load (1 min) at start of each run below")
    print(f"{'run':<10} {'runs':>5} {'wall [s]':>9} {'CPU [s]':>8} {'load':>5}")
    for k, v in runs.items():
        print(f"{k:<10} {v['runs']:>5} {v['wall_s']:>9.1f} {v['cpu_s']:>8.1f} {v['load_1min_at_start']:>5.2f}")
    if "ideal_wall_s" in runs["pool"]:
        print(f"pool's ideal wall (serial CPU / {a.workers} workers): {runs['pool']['ideal_wall_s']:.1f} s")
    lw = res["laws"]
    print(
        f"bare law, one run (median of {len(lw['cases'])} cases): compiled cascade {lw['median_wall_s']['auto']:.3f} s, "
        f"CVODES {lw['median_wall_s']['cvodes']:.3f} s (ratio {lw['ratio_auto_over_cvodes']:.1f})"
    )
    print(f"layered controllers' collisions in avoidable cases: {res['layer_collisions_in_avoidable_cases']}")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_atomic(Path(a.out), json.dumps(res, indent=1, default=str))
    print(f"wrote {a.out}")
    print(f"table sha256: {hashes}" + (f", expected {a.expect_table_sha256}" if a.expect_table_sha256 else ""))
    if bad:
        print(f"table check FAILED for {bad}")
        sys.exit(1)


if __name__ == "__main__":
    main()

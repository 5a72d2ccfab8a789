"""MPC vs the laws in a closed loop as real as a car's (issue 25's measuring stick).

For each cycle (UDDS, US06: the shipped single-follower scenarios, first ``--segment-s`` seconds, ending at the
leader's next stop so every run covers the same distance) one follower runs the MPC (the default traffic
formulation with the scenario's forecast), the proposed law and OVFL, under two conditions:
  * ideal: the plant's exact parameters and exact, instantaneous states (laws continuous: today's comparison);
  * real: the model differs from the plant (seeded uniform ±``--mass`` on the mass, ±``--resistance`` on drag,
    rolling resistance and the cell's R0, R1, R2), every channel noisy, quantised and late by ``--delay-s``
    (Sensors() defaults: production sensors, sources in aev_ocp/estimation/sensors.py), V1, V2, SOC not
    measured, the estimator (EKF or MHE) in the loop from a SOC guess off by ``--soc-error``; the laws run as
    sampled laws at the MPC's rate on the same measurements; ``--capacitance``, ``--capacity`` and
    ``--ocv-offset-mV`` add seeded uniform errors of C1/C2, the capacity and the OCV (the rest of the declared set).
Prints a table (status, min gap, pack ∫Q/km, the MPC's margin against each law, SOC/V2/speed estimation errors,
median per-step cost of estimator + MPC) and writes benchmarks/bench_estimation.json.
Usage: python benchmarks/bench_estimation.py [--segment-s 300] [--cycles udds us06] [--seeds 1 2]
       [--estimator ekf|mhe] [--delay-s 0.1] [--mass 0.1] [--resistance 0.2] [--soc-error 0.1]
       [--capacitance 0] [--capacity 0] [--ocv-offset-mV 0]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

from aev_ocp.estimation import Mismatch
from aev_ocp.results import write_json
from aev_ocp.robustness import LAWS, margins, run_robustness, targets


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segment-s", type=float, default=300.0)
    ap.add_argument("--cycles", nargs="+", default=["udds", "us06"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--estimator", choices=("ekf", "mhe"), default="ekf")
    ap.add_argument("--delay-s", type=float, default=0.1)
    ap.add_argument("--mass", type=float, default=0.1)
    ap.add_argument("--resistance", type=float, default=0.2)
    ap.add_argument("--soc-error", type=float, default=0.1)
    ap.add_argument("--capacitance", type=float, default=0.0, help="± relative error of C1 and C2")
    ap.add_argument("--capacity", type=float, default=0.0, help="± relative error of the capacity")
    ap.add_argument("--ocv-offset-mV", type=float, default=0.0, help="± OCV offset per cell [mV]")
    ap.add_argument("--out", default=str(Path(__file__).with_name("bench_estimation.json")))
    a = ap.parse_args(argv)
    rows: list[dict[str, Any]] = []
    for cyc in a.cycles:
        rows += run_robustness(
            cyc,
            a.segment_s,
            a.seeds,
            a.estimator,
            a.delay_s,
            a.mass,
            a.resistance,
            a.soc_error,
            log=lambda m: print(m, file=sys.stderr, flush=True),
            mismatch=lambda seed: Mismatch.spread(
                a.mass, a.resistance, seed, "uniform", a.capacitance, a.capacity, 1e-3 * a.ocv_offset_mV
            ),
        )
    hdr = (
        f"{'cycle':6} {'cond':5} {'seed':>4} {'ctrl':9} {'status':8} {'min gap m':>9} {'Q J/km':>8} "
        f"{'SOC>60s %':>9} {'V2 mV':>6} {'vl m/s':>6} {'est+mpc ms':>10}"
    )
    print(hdr)

    def f(x: Any, fmt: str) -> str:
        return format(x, fmt) if isinstance(x, (int, float)) and x is not None and np.isfinite(x) else "-"

    for r in rows:
        print(
            f"{r['cycle']:6} {r['condition']:5} {r['seed'] if r['seed'] is not None else '-':>4} {r['controller']:9} "
            f"{r['status']:8} {f(r['min_gap_m'], '9.2f')} {f(r['heat_pack_J_per_km'], '8.0f')} "
            f"{f(r['soc_err_max_after_60s_pct'], '9.2f')} {f(r['V2_err_rms_mV'], '6.2f')} "
            f"{f(r['lead_speed_err_rms_mps'], '6.3f')} {f(r['estimator_plus_call_ms_median'], '10.3f')}"
        )
    mg = margins(rows)
    print("\nMPC pack heat per km below the laws [%]:")
    for m in mg:
        print(
            f"  {m['cycle']:6} {m['condition']:5} seed {m['seed'] if m['seed'] is not None else '-':>4}: "
            + ", ".join(f"{law} {m[f'margin_vs_{law}_pct']:+.1f} %" for law in LAWS)
        )
    tg = targets(rows, mg)
    tg["cost_target_1ms_met"] = (
        tg["estimator_plus_mpc_ms_median_max"] is not None and tg["estimator_plus_mpc_ms_median_max"] <= 1.0
    )
    print("\ntargets:", tg)
    write_json(
        a.out,
        {
            "rows": rows,
            "margins": mg,
            "targets": tg,
            "args": vars(a),
            "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count()},
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""MPC vs the laws in a closed loop as real as a car's (issue 25's measuring stick).

For each cycle (UDDS, US06: the shipped single-follower scenarios, first ``--segment-s`` seconds, ending at the
leader's next stop so every run covers the same distance) one follower runs the MPC (the default traffic
formulation with the scenario's forecast), the proposed law and OVFL, under two conditions:
  * ideal: the plant's exact parameters and exact, instantaneous states (laws continuous: today's comparison);
  * real: the model differs from the plant (seeded uniform ±``--mass`` on the mass, ±``--resistance`` on drag,
    rolling resistance and the cell's R0, R1, R2), every channel noisy, quantised and late by ``--delay-s``
    (Sensors() defaults: production sensors, sources in aev_ocp/estimation/sensors.py), V1, V2, SOC not
    measured, the estimator (EKF or MHE) in the loop from a SOC guess off by ``--soc-error``; the laws run as
    sampled laws at the MPC's rate on the same measurements.
Prints a table (status, min gap, pack ∫Q/km, the MPC's margin against each law, SOC/V2/speed estimation errors,
median per-step cost of estimator + MPC) and writes benchmarks/bench_estimation.json.
Usage: python benchmarks/bench_estimation.py [--segment-s 300] [--cycles udds us06] [--seeds 1 2]
       [--estimator ekf|mhe] [--delay-s 0.1] [--mass 0.1] [--resistance 0.2] [--soc-error 0.1]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from aev_ocp.control import ClosedLoop
from aev_ocp.estimation import EKF, MHE, Mismatch, Sensors
from aev_ocp.mpc import MPCVehicle
from aev_ocp.mpc.cycles import cycle_scenario
from aev_ocp.results import write_json
from aev_ocp.simulate import simulate_platoon

LAWS = ("proposed", "ovfl")


def _row(cycle: str, cond: str, seed: int | None, ctrl: str, r: Any, wall: float) -> dict[str, Any]:
    m = r.metrics()[0]
    st = (r.solver_stats or [None])[0] or {}
    est = st.get("estimation", {})
    return {"cycle": cycle, "condition": cond, "seed": seed, "controller": ctrl, "status": r.status,
            "collisions": m.get("collisions"), "min_gap_m": m.get("min_gap_m"), "distance_m": m.get("distance_m"),
            "heat_pack_J_per_km": m.get("heat_pack_J_per_km"), "fallbacks": st.get("fallbacks"),
            "soc_err_max_after_60s_pct": est.get("soc_err_max_after_60s_pct"),
            "soc_err_rms_pct": est.get("soc_err_rms_pct"), "V2_err_rms_mV": est.get("V2_err_rms_mV"),
            "lead_speed_err_rms_mps": est.get("lead_speed_err_rms_mps"), "gap_err_rms_m": est.get("gap_err_rms_m"),
            "call_ms_median": st.get("call_ms_median"), "estimator_ms_median": st.get("estimator_ms_median"),
            "estimator_plus_call_ms_median": st.get("estimator_plus_call_ms_median"), "wall_s": wall}


def run(cycle: str, segment_s: float, seeds: list[int], estimator: str, delay_s: float, mass: float,
        resistance: float, soc_error: float) -> list[dict[str, Any]]:
    sc = cycle_scenario(cycle, segment_s, end_at_rest=True)
    cfg = sc.extra["mpc"]
    dt = cfg.settings.dt
    rows: list[dict[str, Any]] = []
    mpc = MPCVehicle(cfg.settings, formulation=cfg.formulation)
    t0 = time.perf_counter()
    r = ClosedLoop(sc.leader, [mpc], sc.ev, fallback_law=sc.law("proposed")).run(sc.gaps0, sc.speeds0, sc.t_end)
    rows.append(_row(cycle, "ideal", None, "mpc", r, time.perf_counter() - t0))
    for law in LAWS:
        t0 = time.perf_counter()
        r = simulate_platoon(sc.leader, [sc.law(law)], list(sc.gaps0), list(sc.speeds0), sc.t_end, ev=sc.ev,
                             dt_out=dt)
        rows.append(_row(cycle, "ideal", None, law, r, time.perf_counter() - t0))
    soc_true = sc.ev.cell.soc0
    cls = EKF if estimator == "ekf" else MHE
    for seed in seeds:
        mm = Mismatch.spread(mass, resistance, seed=seed)
        sen = Sensors(seed=seed).scaled(1.0, delay_s)

        def factory(ev: Any, s: Sensors, off: float, i: int) -> Any:
            return cls(ev, s, soc0=soc_true - soc_error, ocv_offset_V=off)

        for ctrl in ("mpc", *LAWS):
            c = mpc if ctrl == "mpc" else sc.law(ctrl)
            t0 = time.perf_counter()
            r = ClosedLoop(sc.leader, [c], sc.ev, fallback_law=sc.law("proposed"), mismatch=mm, sensors=sen,
                           estimator=factory, law_dt=dt).run(sc.gaps0, sc.speeds0, sc.t_end)
            rows.append(_row(cycle, "real", seed, ctrl, r, time.perf_counter() - t0))
    return rows


def margins(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The MPC's pack ∫Q/km below each law [%] per (cycle, condition, seed): (law − MPC)/law·100."""
    out = []
    keys = sorted({(r["cycle"], r["condition"], r["seed"] if r["seed"] is not None else -1) for r in rows})
    for cyc, cond, seed in keys:
        grp = {r["controller"]: r for r in rows if r["cycle"] == cyc and r["condition"] == cond
               and (r["seed"] if r["seed"] is not None else -1) == seed}
        q = grp["mpc"]["heat_pack_J_per_km"]
        out.append({"cycle": cyc, "condition": cond, "seed": None if seed < 0 else seed,
                    **{f"margin_vs_{law}_pct": 100.0 * (grp[law]["heat_pack_J_per_km"] - q) / grp[law]["heat_pack_J_per_km"]
                       for law in LAWS}})
    return out


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
    ap.add_argument("--out", default=str(Path(__file__).with_name("bench_estimation.json")))
    a = ap.parse_args(argv)
    rows: list[dict[str, Any]] = []
    for cyc in a.cycles:
        rows += run(cyc, a.segment_s, a.seeds, a.estimator, a.delay_s, a.mass, a.resistance, a.soc_error)
    hdr = (f"{'cycle':6} {'cond':5} {'seed':>4} {'ctrl':9} {'status':8} {'min gap m':>9} {'Q J/km':>8} "
           f"{'SOC>60s %':>9} {'V2 mV':>6} {'vl m/s':>6} {'est+mpc ms':>10}")
    print(hdr)

    def f(x: Any, fmt: str) -> str:
        return format(x, fmt) if isinstance(x, (int, float)) and x is not None and np.isfinite(x) else "-"
    for r in rows:
        print(f"{r['cycle']:6} {r['condition']:5} {r['seed'] if r['seed'] is not None else '-':>4} {r['controller']:9} "
              f"{r['status']:8} {f(r['min_gap_m'], '9.2f')} {f(r['heat_pack_J_per_km'], '8.0f')} "
              f"{f(r['soc_err_max_after_60s_pct'], '9.2f')} {f(r['V2_err_rms_mV'], '6.2f')} "
              f"{f(r['lead_speed_err_rms_mps'], '6.3f')} {f(r['estimator_plus_call_ms_median'], '10.3f')}")
    mg = margins(rows)
    print("\nMPC pack heat per km below the laws [%]:")
    for m in mg:
        print(f"  {m['cycle']:6} {m['condition']:5} seed {m['seed'] if m['seed'] is not None else '-':>4}: "
              + ", ".join(f"{law} {m[f'margin_vs_{law}_pct']:+.1f} %" for law in LAWS))
    real = [r for r in rows if r["condition"] == "real"]
    cost = [r["estimator_plus_call_ms_median"] for r in real if r["controller"] == "mpc"]
    targets = {"no_collision_real": all(not r["collisions"] and r["status"] in ("ok",) for r in real),
               "mpc_below_both_laws_real": all(m[f"margin_vs_{law}_pct"] > 0 for m in mg if m["condition"] == "real"
                                               for law in LAWS),
               "estimator_plus_mpc_ms_median_max": max(cost) if cost else None,
               "cost_target_1ms_met": bool(cost) and max(cost) <= 1.0}
    print("\ntargets:", targets)
    write_json(a.out, {"rows": rows, "margins": mg, "targets": targets, "args": vars(a),
                       "machine": {"platform": platform.platform(), "python": sys.version.split()[0],
                                   "cpus": os.cpu_count()}})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

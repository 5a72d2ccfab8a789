"""MPC behind drive cycles with forecasts a car can make (issue 8's measuring stick).

For each cycle (UDDS, HWFET, US06 with the shipped scenarios' units, and the paper's leader) and each
non-oracle predictor, one follower from the scenario's initial state runs:
  * the proposed law and OVFL (closed-form, continuous),
  * the MPC with the §9 problem (the current default formulation),
  * the MPC with a candidate traffic formulation built with the ProblemBuilder (``candidate_problem``):
    the exact-energy objective (epigraph of v g(a)), a soft time-headway constraint h ≥ h_min + T_h v
    (T_h in seconds, converted with the scenario's units), the gap bound made soft, and a Δa penalty.
Prints the table predictor × cycle × controller — pack ∫Q/km, ω/km, distance, min gap, min TTC, RMS
jerk, fallbacks, solve p50/p99 — with the comparability flag against the proposed law (distance or
duration off by > 1 %, or ended by an event), and writes benchmarks/bench_mpc_cycles.json.
Usage: python benchmarks/bench_mpc_cycles.py [--t-end-s 300] [--solver ipopt|rti] [--cycles udds hwfet]
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

from aev_ocp.metrics import comparability
from aev_ocp.models import OVFL, PaperLeader, Proposed, drive_cycle
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.ocp import following_problem
from aev_ocp.ocp.problem import ProblemBuilder
from aev_ocp.params import EVParams, Units
from aev_ocp.results import write_json
from aev_ocp.simulate import simulate_platoon

# the shipped drive-cycle scenarios' units and start (scenarios/*_platoon.toml): from rest, 0.8 L apart
CYCLES = {"udds": (Units(15.0, 17.0), 0.8, 0.0), "hwfet": (Units(15.0, 17.0), 0.8, 0.0),
          "us06": (Units(20.0, 22.0), 0.8, 0.0), "paper": (Units(10.0, 5.0), 0.3, 1.87)}
TIME_HEADWAY_S = 1.0  # [s] candidate's minimum time gap (ACC practice: about 1 to 2 s; our choice)
HEADWAY_PENALTY = 100.0  # L1 penalty per model length of headway violation per model time (exact if > multiplier)
JERK_WEIGHT = 0.01  # weight of ((a_k − a_{k−1})/dt)² in model units (our choice)
ENERGY_WEIGHT = 3.0  # w_Q on v g(a) (the exact-energy objective)


def candidate_problem(ev: EVParams, s: MPCSettings, h_min: float) -> ProblemBuilder:
    """The candidate traffic formulation (see the module docstring): h_min [model length] is the soft
    headway constraint's gap at standstill."""
    pb = following_problem(ev, s.bounds, s.smooth, "energy", name="traffic_candidate")
    h, v, a = pb.x["h"], pb.x["v"], pb.u["a"]
    pb.subject_to(h - (TIME_HEADWAY_S / ev.units.time_s) * v, lb=h_min, soft=HEADWAY_PENALTY, name="headway")
    a_prev = pb.state("a_prev")
    pb.set_next(a_prev, a)
    pb.add_stage_cost(JERK_WEIGHT * ((a - a_prev) / s.dt) ** 2, name="jerk")
    return pb


def _row(cycle: str, predictor: str, ctrl: str, r: Any, ref: dict | None, wall: float) -> dict:
    m = r.metrics()[0]
    st = r.solver_stats[0] or {}
    steps = np.asarray((r.meta.get("mpc_steps") or [None])[0]["solve_ms"] if r.meta.get("mpc_steps") else [])
    row = {"cycle": cycle, "predictor": predictor, "controller": ctrl, "status": r.status, "wall_s": wall,
           **{k: m.get(k) for k in ("distance_m", "duration_s", "heat_pack_J_per_km", "omega_model_per_km",
                                    "min_gap_m", "min_ttc_s", "rms_jerk_model")},
           "fallbacks": st.get("fallbacks"), "forecast_rms": st.get("forecast_rms"),
           "solve_ms_p50": float(np.median(steps)) if steps.size else None,
           "solve_ms_p99": float(np.percentile(steps, 99)) if steps.size else None}
    row["comparable"] = comparability(m, ref)["comparable"] if ref is not None else True
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end-s", type=float, default=300.0, help="seconds of each cycle (default 300)")
    ap.add_argument("--cycles", nargs="+", default=list(CYCLES), choices=list(CYCLES))
    ap.add_argument("--predictors", nargs="+", default=["constant-velocity", "decaying-acceleration"])
    ap.add_argument("--solver", default="ipopt", choices=["ipopt", "rti", "sqp"])
    ap.add_argument("--out", default=str(Path(__file__).with_name("bench_mpc_cycles.json")))
    a = ap.parse_args(argv)
    rows: list[dict] = []
    print(f"{'cycle':6s} {'predictor':22s} {'controller':10s} {'status':>8s} {'km':>6s} {'Q J/km':>8s} "
          f"{'ω/km':>7s} {'gap m':>6s} {'TTC s':>6s} {'jerk':>6s} {'fb':>4s} {'p50':>6s} {'p99':>7s} cmp")
    for cyc in a.cycles:
        units, h0, v0 = CYCLES[cyc]
        ev = EVParams(units=units)
        leader = PaperLeader() if cyc == "paper" else drive_cycle(cyc, units)
        dt = 0.1
        t_end = round(units.time_from_si(a.t_end_s) / dt) * dt if cyc != "paper" else 70.0
        laws = {}
        for law in (Proposed(), OVFL()):
            t0 = time.perf_counter()
            laws[law.name] = (simulate_platoon(leader, [law], [h0], [v0], t_end, ev=ev, dt_out=dt),
                              time.perf_counter() - t0)
        ref_m = laws["proposed"][0].metrics()[0]
        for pred in a.predictors:
            runs = dict(laws)
            base = {"predictor": pred, "solver": a.solver, "codegen": True, "dt": dt}
            s9 = MPCSettings.from_dict(base)
            # the candidate: energy objective weighted ENERGY_WEIGHT; the hard gap bound is replaced by the
            # soft headway constraint (whose lower bound is §9's h_min)
            cand = MPCSettings.from_dict({**base, "objective": "energy", "w_Q": ENERGY_WEIGHT, "h_min": -10.0})
            for name, s, prob in (("mpc-s9", s9, None), ("mpc-cand", cand, candidate_problem(ev, cand, s9.bounds.h_min))):
                t0 = time.perf_counter()
                r = run_closed_loop(leader, [MPCVehicle(s, problem=prob)], [h0], [v0], t_end, ev=ev)
                runs[name] = (r, time.perf_counter() - t0)
            for name, (r, wall) in runs.items():
                row = _row(cyc, pred, name, r, ref_m if name != "proposed" else None, wall)
                rows.append(row)
                f = lambda x, p=1: "—" if x is None or not np.isfinite(x) else f"{x:.{p}f}"  # noqa: E731
                print(f"{cyc:6s} {pred:22s} {name:10s} {row['status']:>8s} {f(row['distance_m'] / 1000, 3):>6s} "
                      f"{f(row['heat_pack_J_per_km'], 0):>8s} {f(row['omega_model_per_km'], 3):>7s} "
                      f"{f(row['min_gap_m'], 2):>6s} {f(row['min_ttc_s'], 1):>6s} {f(row['rms_jerk_model'], 3):>6s} "
                      f"{str(row['fallbacks'] if row['fallbacks'] is not None else '—'):>4s} "
                      f"{f(row['solve_ms_p50'], 2):>6s} {f(row['solve_ms_p99'], 1):>7s} "
                      f"{'' if row['comparable'] else 'NOT COMPARABLE'}", flush=True)
    write_json(a.out, {"t_end_s": a.t_end_s, "solver": a.solver, "rows": rows,
                       "candidate": {"time_headway_s": TIME_HEADWAY_S, "headway_penalty": HEADWAY_PENALTY,
                                     "jerk_weight": JERK_WEIGHT, "energy_weight": ENERGY_WEIGHT},
                       "machine": {"platform": platform.platform(), "python": sys.version.split()[0],
                                   "cpus": os.cpu_count()}})
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""MPC behind drive cycles with forecasts a car can make (issue 8's measuring stick).

For each cycle (UDDS, HWFET, US06 with the shipped scenarios' units, and the paper's leader) and each
non-oracle predictor, one follower from the scenario's initial state runs:
  * the proposed law and OVFL (closed-form, continuous),
  * the MPC with the default traffic formulation (``MPCSettings()``: aev_ocp.ocp.traffic, RTI + codegen),
  * the MPC with the §9 formulation (``s9_formulation()``, N = 40, same solver path) for reference.
One parameter set for every cycle (the defaults): no per-cycle tuning. With ``--platoon`` also the
UDDS platoon (5 followers, MPC on all, cooperative forecasts behind the first) against the proposed law.
Prints the table predictor × cycle × controller — pack ∫Q/km, ω/km, distance, min gap, min TTC, RMS
jerk, fallbacks, solve p50/p99/max, forecast RMS — with the comparability flag against the proposed law
(distance or duration off by > 1 %, or ended by an event: such rows are never ranked), the targets
check, and writes benchmarks/bench_mpc_cycles.json.
Usage: python benchmarks/bench_mpc_cycles.py [--t-end-s 300] [--cycles udds hwfet] [--full] [--platoon]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from aev_ocp.metrics import comparability
from aev_ocp.models import OVFL, PaperLeader, Proposed, drive_cycle
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.ocp.formulation import s9_formulation, traffic_formulation
from aev_ocp.params import EVParams, Units
from aev_ocp.results import write_json
from aev_ocp.simulate import simulate_platoon

# the shipped drive-cycle scenarios' units and start (scenarios/*_platoon.toml): from rest, 0.8 L apart
CYCLES = {
    "udds": (Units(15.0, 17.0), 0.8, 0.0),
    "hwfet": (Units(15.0, 17.0), 0.8, 0.0),
    "us06": (Units(20.0, 22.0), 0.8, 0.0),
    "paper": (Units(10.0, 5.0), 0.3, 1.87),
}


def _row(cycle: str, predictor: str, ctrl: str, r: Any, i: int, ref: dict | None, wall: float) -> dict:
    m = r.metrics()[i]
    st = (r.solver_stats or [None] * (i + 1))[i] or {}
    steps = (r.meta.get("mpc_steps") or [None] * (i + 1))[i]
    ms = np.asarray(steps["solve_ms"], float) if steps else np.zeros(0)
    causes = Counter(str(sv).split(":")[0] for sv, ok in zip(steps["status"], steps["ok"]) if not ok) if steps else {}
    row = {
        "cycle": cycle,
        "predictor": predictor,
        "controller": ctrl,
        "vehicle": i + 1,
        "status": r.status,
        "wall_s": wall,
        **{
            k: m.get(k)
            for k in (
                "distance_m",
                "duration_s",
                "heat_pack_J_per_km",
                "omega_model_per_km",
                "min_gap_m",
                "min_speed_model",
                "min_ttc_s",
                "rms_jerk_model",
                "collisions",
            )
        },
        "fallbacks": st.get("fallbacks"),
        "fallback_causes": dict(causes),
        "forecast_rms": st.get("forecast_rms"),
        "solve_ms_p50": float(np.median(ms)) if ms.size else None,
        "solve_ms_p99": float(np.percentile(ms, 99)) if ms.size else None,
        "solve_ms_max": float(ms.max()) if ms.size else None,
    }
    row["comparable"] = (
        comparability({**m, "status": r.status}, ref)["comparable"] if ref is not None else r.status == "ok"
    )
    return row


def _fmt(x: Any, p: int = 1) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.{p}f}"


def _print(row: dict) -> None:
    print(
        f"{row['cycle']:6s} {row['predictor']:22s} {row['controller']:11s} {row['vehicle']:2d} {row['status']:>8s} "
        f"{_fmt(row['distance_m'] / 1000, 3):>6s} {_fmt(row['heat_pack_J_per_km'], 0):>8s} "
        f"{_fmt(row['omega_model_per_km'], 4):>7s} {_fmt(row['min_gap_m'], 2):>6s} {_fmt(row['min_ttc_s'], 1):>6s} "
        f"{_fmt(row['rms_jerk_model'], 4):>7s} {str(row['fallbacks'] if row['fallbacks'] is not None else '—'):>4s} "
        f"{_fmt(row['solve_ms_p50'], 2):>6s} {_fmt(row['solve_ms_p99'], 1):>6s} {_fmt(row['solve_ms_max'], 1):>6s} "
        f"{_fmt(row['forecast_rms'], 4):>7s} {'' if row['comparable'] else 'NOT COMPARABLE'}",
        flush=True,
    )


def targets(rows: list[dict], h_min_m: dict[str, float]) -> list[str]:
    """Issue 8's targets per (cycle, predictor) for the traffic MPC: a list of misses (empty: all met)."""
    miss = []
    by = {(r["cycle"], r["predictor"], r["controller"], r["vehicle"]): r for r in rows}
    for (cyc, pred, ctrl, veh), r in by.items():
        if ctrl != "mpc-traffic":
            continue
        tag = f"{cyc}/{pred}/vehicle {veh}"
        law, ovfl = by.get((cyc, pred, "proposed", veh)), by.get((cyc, pred, "ovfl", veh))
        if not r["comparable"]:
            miss.append(f"{tag}: not comparable (distance/duration > 1 % off, or ended by an event)")
        for ref in (law, ovfl):
            if ref is None:
                continue
            for k in ("heat_pack_J_per_km",) + (("omega_model_per_km",) if cyc != "platoon" else ()):
                if not r[k] < ref[k]:
                    miss.append(f"{tag}: {k} {r[k]:.5g} not below {ref['controller']}'s {ref[k]:.5g}")
        if law is not None and cyc != "platoon" and r["rms_jerk_model"] > law["rms_jerk_model"]:
            miss.append(f"{tag}: RMS jerk {r['rms_jerk_model']:.4g} above the law's {law['rms_jerk_model']:.4g}")
        if r["min_gap_m"] < h_min_m[cyc] - 1e-9:
            miss.append(f"{tag}: min gap {r['min_gap_m']:.3g} m below h_min {h_min_m[cyc]:.3g} m")
        if r["fallbacks"]:
            miss.append(f"{tag}: {r['fallbacks']} fallbacks {r['fallback_causes']}")
        for k, lim in (("solve_ms_p50", 2.0), ("solve_ms_p99", 10.0), ("solve_ms_max", 50.0)):
            if r[k] is not None and r[k] > lim:
                miss.append(f"{tag}: {k} = {r[k]:.3g} ms > {lim:g}")
    return miss


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end-s", type=float, default=300.0, help="seconds of each cycle (default 300)")
    ap.add_argument("--full", action="store_true", help="the whole cycles (overrides --t-end-s)")
    ap.add_argument("--cycles", nargs="+", default=list(CYCLES), choices=list(CYCLES))
    ap.add_argument("--predictors", nargs="+", default=["constant-velocity", "decaying-acceleration"])
    ap.add_argument("--no-s9", action="store_true", help="skip the §9 reference MPC")
    ap.add_argument("--platoon", action="store_true", help="also the UDDS platoon (5 MPC followers)")
    ap.add_argument("--out", default=str(Path(__file__).with_name("bench_mpc_cycles.json")))
    a = ap.parse_args(argv)
    rows: list[dict] = []
    h_min_m: dict[str, float] = {}
    print(
        f"{'cycle':6s} {'predictor':22s} {'controller':11s} {'#':>2s} {'status':>8s} {'km':>6s} {'Q J/km':>8s} "
        f"{'ω/km':>7s} {'gap m':>6s} {'TTC s':>6s} {'jerk':>7s} {'fb':>4s} {'p50':>6s} {'p99':>6s} {'max':>6s} "
        f"{'fc RMS':>7s} cmp"
    )
    traffic = MPCSettings()
    tform = traffic_formulation()  # the default formulation's SI parameters (its standstill floor)
    for cyc in a.cycles:
        units, h0, v0 = CYCLES[cyc]
        ev = EVParams(units=units)
        h_min_m[cyc] = tform.traffic.standstill_gap_m
        leader = PaperLeader() if cyc == "paper" else drive_cycle(cyc, units)
        dt = traffic.dt
        if cyc == "paper":
            t_end = 70.0
        else:
            t_s = leader.times[-1] * units.time_s if a.full else a.t_end_s
            t_end = round(units.time_from_si(t_s) / dt) * dt
        laws = {}
        for law in (Proposed(), OVFL()):
            t0 = time.perf_counter()
            laws[law.name] = (
                simulate_platoon(leader, [law], [h0], [v0], t_end, ev=ev, dt_out=dt),
                time.perf_counter() - t0,
            )
        ref_m = {**laws["proposed"][0].metrics()[0], "status": laws["proposed"][0].status}
        for pred in a.predictors:
            runs = dict(laws)
            ctrls = [("mpc-traffic", MPCVehicle(traffic.with_(predictor=pred)))]
            if not a.no_s9:
                # §9's problem and horizon (N = 40) on the same real-time path (RTI + codegen, projected Hessian)
                ctrls.append(("mpc-s9", MPCVehicle(traffic.with_(predictor=pred, N=40), formulation=s9_formulation())))
            for name, veh in ctrls:
                t0 = time.perf_counter()
                r = run_closed_loop(leader, [veh], [h0], [v0], t_end, ev=ev)
                runs[name] = (r, time.perf_counter() - t0)
            for name, (r, wall) in runs.items():
                row = _row(cyc, pred, name, r, 0, ref_m if name != "proposed" else None, wall)
                rows.append(row)
                _print(row)
    if a.platoon:
        from aev_ocp.scenarios import find_scenario, load_scenario
        from aev_ocp.mpc.scenario import MPCConfig, closed_loop_from_scenario

        sc = load_scenario(find_scenario("udds_platoon"))
        h_min_m["platoon"] = tform.traffic.standstill_gap_m
        dt = traffic.dt
        t_s = sc.leader.times[-1] * sc.ev.units.time_s if a.full else a.t_end_s
        t_end = round(sc.ev.units.time_from_si(t_s) / dt) * dt
        t0 = time.perf_counter()
        law = simulate_platoon(
            sc.leader,
            [sc.law("proposed")] * sc.n_followers,
            list(sc.gaps0),
            list(sc.speeds0),
            t_end,
            ev=sc.ev,
            dt_out=dt,
        )
        wl = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = closed_loop_from_scenario(sc, MPCConfig(traffic.with_(predictor="constant-velocity"))).run(
            list(sc.gaps0), list(sc.speeds0), t_end
        )
        wm = time.perf_counter() - t0
        for i in range(sc.n_followers):
            ref = {**law.metrics()[i], "status": law.status}
            for name, res, w in (("proposed", law, wl), ("mpc-traffic", r, wm)):
                row = _row(
                    "platoon",
                    "cooperative" if i else "constant-velocity",
                    name,
                    res,
                    i,
                    ref if name != "proposed" else None,
                    w,
                )
                rows.append(row)
                _print(row)
    miss = targets(rows, h_min_m)
    print("targets: all met" if not miss else "targets missed:\n  " + "\n  ".join(miss))
    write_json(
        a.out,
        {
            "t_end_s": "full" if a.full else a.t_end_s,
            "rows": rows,
            "targets_missed": miss,
            "settings": {
                "traffic": vars(tform.traffic),
                "N": traffic.N,
                "dt": traffic.dt,
                "solver": traffic.solver,
                "codegen": traffic.codegen,
                "budget": traffic.budget,
                "max_step_ms": traffic.max_step_ms,
            },
            "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count()},
        },
    )
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

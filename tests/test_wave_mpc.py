"""The wave-damping MPC (aev_ocp.mpc.wave) against independent results: its first move on a linear-quadratic instance
equals the Riccati recursion written out here; its linearised gains equal that recursion's gain; its commands stay
within the bounds; behind a constant-speed leader it keeps the leader's speed on average and its gap in the band;
v_ref is the mean of its own measured speeds plus the saturated gap catch-up, written out here; it runs the ring under
the safety layer without a collision."""

from __future__ import annotations

import json
from dataclasses import replace
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.control import run_closed_loop
from aev_ocp.loop import Observation
from aev_ocp.models.carfollowing import Proposed
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.mpc.settings import MPCSettings
from aev_ocp.mpc.wave import SpeedAverage, WaveMPC, WaveParams, linear_gains, spread, wave_problem
from aev_ocp.ocp.traffic import TrafficParams
from aev_ocp.params import EVParams, ParameterError

ROOT = Path(__file__).parents[1]  # the checkout (scenarios/, docs/, tests/data/)
EV = EVParams()
U = EV.units
#: settings of the tests' own parameter sets: interpreted (no C compiled for a problem built once here)
S = MPCSettings(codegen=False)
#: an LQ instance: only w_v (v − v_ref)² and w_a a² (and the terminal w_vT (v_N − v_ref)²); energy, heat, jerk and
#: the gap centring off, the gap well inside its band, so the problem is v_{k+1} = v_k + h a_k with a quadratic cost
W_V, W_A, W_VT = 1.7, 2.3, 3.1
LQ = WaveParams(
    speed_weight=W_V,
    gap_weight=0.0,
    terminal_speed_weight=W_VT,
    terminal_gap_weight=0.0,
    traffic=TrafficParams(omega_weight=0.0, heat_weight=0.0, accel_weight=W_A, jerk_weight=0.0, time_headway_s=0.8),
)


def riccati_gain(N: int, h: float) -> float:
    """K of the first move a_0 = K (v_0 − v_ref) of min Σ_{k<N} h (w_v e_k² + w_a a_k²) + w_vT e_N², e_{k+1} = e_k + h a_k
    (backward Riccati recursion, written out by hand)."""
    P, c = W_VT, h * W_A
    for _ in range(N - 1):
        P = h * W_V + P * c / (c + P * h * h)
    return -P * h / (c + P * h * h)


def z0(h_m: float, v_mps: float) -> np.ndarray:
    return np.array([float(U.length_from_si(h_m)), float(U.speed_from_si(v_mps)), 0.0, 0.0, EV.cell.soc0])


def obs(h_m: float, v_mps: float, vl_mps: float, t: float = 0.0) -> Observation:
    vl = float(U.speed_from_si(vl_mps))
    return Observation(t, 0.1, 0, z0(h_m, v_mps), np.array([t - 0.2, t - 0.1, t]), np.full(3, vl), None, 0.0)


@pytest.mark.parametrize("solver", ["ipopt", "rti"])
def test_first_move_equals_the_riccati_solution_of_the_lq_instance(solver):
    from aev_ocp.mpc.controller import MPCController
    from aev_ocp.ocp.formulation import problem_formulation

    s = MPCSettings(N=17, solver=solver, tol=1e-10, codegen=False)
    ctl = MPCController(s, EV, formulation=problem_formulation(wave_problem(EV, LQ, s.dt)))
    h_s = float(U.time_to_si(s.dt))
    vl = np.full(s.N, float(U.speed_from_si(5.0)))
    for v0, vref in ((5.0, 6.3), (6.1, 4.4)):
        ctl.reset()
        sol = ctl.solve(z0(20.0, v0), vl, vl, own={"a_prev": 0.0, "v_ref": float(U.speed_from_si(vref))})
        assert sol.success, sol.status
        a0 = float(U.accel_to_si(sol.a[0]))
        assert a0 == pytest.approx(riccati_gain(s.N, h_s) * (v0 - vref), rel=1e-6, abs=1e-8)


def test_linear_gains_equal_the_riccati_gain():
    s = MPCSettings(N=17)
    g = linear_gains(EV, LQ, s, h_m=20.0, v_mps=5.0)
    assert g["f_v_per_s"] == pytest.approx(riccati_gain(s.N, float(U.time_to_si(s.dt))), rel=1e-5)
    assert abs(g["f_h_per_s2"]) < 1e-6 and abs(g["f_dv_per_s"]) < 1e-6 and abs(g["a0_mps2"]) < 1e-7
    with pytest.raises(ParameterError, match="dh_m"):
        linear_gains(EV, LQ, s, h_m=0.3, v_mps=5.0)


def test_the_gap_ceiling_pulls_the_car_forward():
    """Beyond the soft ceiling h ≤ s_max + T_max v the L1 penalty makes the car accelerate harder than without it
    (s_max = 12 m: 60 m at 5 m/s is 33 m beyond it; the catch-up off, so v_ref is the own speed)."""
    moves = []
    band = {"max_gap_m": 12.0, "catch_gain_per_s": 0.0}
    for rho in (8.0, 1e-6):
        wp = WaveParams(band_penalty=rho, gap_weight=0.0, terminal_gap_weight=0.0, **band)
        c = WaveMPC(EV, Proposed(), wp, S)
        c.average.update(float(U.speed_from_si(5.0)))
        moves.append(float(U.accel_to_si(c.command(obs(60.0, 5.0, 5.0)).a)))
    assert moves[0] > moves[1] + 0.05 and abs(moves[1]) < 0.05
    # inside the band the ceiling changes nothing
    inside = []
    for rho in (8.0, 1e-6):
        c = WaveMPC(EV, Proposed(), WaveParams(band_penalty=rho, **band), S)
        inside.append(float(U.accel_to_si(c.command(obs(12.0, 5.0, 5.0)).a)))
    assert inside[0] == pytest.approx(inside[1], abs=1e-6)


def test_commands_stay_within_the_bounds():
    c = WaveMPC(EV, Proposed())
    lo, hi = c.formulation.accel_bounds(EV)
    assert float(U.accel_to_si(lo)) == EV.limits.a_min_mps2 and float(U.accel_to_si(hi)) == EV.limits.a_max_mps2
    seen = []
    for h in (0.4, 3.0, 9.0, 45.0, 400.0):
        for v in (0.0, 2.5, 17.0, 40.0):
            for vl in (0.0, 6.0, 35.0):
                c.reset()
                c.average.update(float(U.speed_from_si(v)) * 1.7 + 1.0)  # a v_ref far from the speed
                a = c.command(obs(h, v, vl)).a
                assert np.isfinite(a) and lo - 1e-9 <= a <= hi + 1e-9, (h, v, vl, a)
                seen.append(a)
    assert min(seen) < 0.9 * lo and max(seen) > 0.5 * hi  # the bounds are reached, not merely respected


def test_v_ref_is_the_mean_of_the_own_measured_speeds():
    # 5 samples of 0.2 s, no catch-up; the follower term off (no follower here: its twin would solve, tests/test_wave_follower.py)
    c = WaveMPC(EV, Proposed(), WaveParams(window_s=1.0, catch_gain_per_s=0.0, follower_speed_weight=0.0), S)
    speeds = [3.1, 4.7, 2.2, 5.9, 3.3, 6.4, 1.8, 4.1]
    for k, v in enumerate(speeds):
        cmd = c.command(obs(10.0, v, 4.0, t=0.1 * k))
        mean = np.mean(speeds[max(0, k - 4) : k + 1])
        assert cmd.info["v_ref_mps"] == pytest.approx(mean, rel=1e-12)
        # ... and it is the v_ref the problem was solved with (the plan's own state at node 1: constant over the horizon)
        x1 = c.controller.warm["X1"]
        assert cmd.ok and float(U.speed_to_si(x1[c.controller.problem.state_names.index("v_ref")])) == (
            pytest.approx(mean, rel=1e-9)
        )
    c.reset()
    assert np.isnan(c.average.value)
    with pytest.raises(ParameterError, match="SpeedAverage.n"):
        SpeedAverage(0)
    with pytest.raises(ParameterError, match="predictor"):
        WaveMPC(EV, Proposed(), settings=S, predictor="oracle")


def test_v_ref_adds_the_saturated_gap_catch_up():
    """v_ref = U + clip(k (h̄ − s_t − T_t U), −v_c, v_c) with U, h̄ the means of the last 5 speeds and gaps: inside
    the saturation, on both of its sides and exactly at it."""
    wp = WaveParams(window_s=1.0, catch_gain_per_s=0.37, target_gap_m=6.5, target_time_gap_s=1.3, catch_max_mps=0.8)
    c = WaveMPC(EV, Proposed(), replace(wp, follower_speed_weight=0.0), S)  # (the plan read below is its own)
    speeds = [3.1, 4.7, 2.2, 5.9, 3.3, 6.4, 1.8, 4.1, 4.4]
    gaps = [11.0, 14.5, 9.0, 30.0, 16.0, 2.5, 4.0, 8.0, 12.2]
    seen = set()
    for k, (v, h) in enumerate(zip(speeds, gaps)):
        cmd = c.command(obs(h, v, 4.0, t=0.1 * k))
        U_ = np.mean(speeds[max(0, k - 4) : k + 1])
        raw = 0.37 * (np.mean(gaps[max(0, k - 4) : k + 1]) - 6.5 - 1.3 * U_)
        seen.add("above" if raw > 0.8 else "below" if raw < -0.8 else "inside")
        assert cmd.info["v_ref_mps"] == pytest.approx(U_ + min(max(raw, -0.8), 0.8), rel=1e-12)
        x1 = c.controller.warm["X1"]
        assert float(U.speed_to_si(x1[c.controller.problem.state_names.index("v_ref")])) == pytest.approx(
            cmd.info["v_ref_mps"], rel=1e-9
        )
    assert seen == {"above", "below", "inside"}
    # at the saturation exactly: h̄ − s_t − T_t U = v_c / k
    c.reset()
    h_sat = 6.5 + 1.3 * 5.0 + 0.8 / 0.37
    assert c.reference(float(U.length_from_si(h_sat)), float(U.speed_from_si(5.0))) == pytest.approx(
        float(U.speed_from_si(5.8)), rel=1e-12
    )
    # never a negative reference
    c.reset()
    assert c.reference(float(U.length_from_si(0.5)), float(U.speed_from_si(0.3))) == 0.0


def test_the_catch_ups_upper_saturation_can_be_set_alone():
    """With ``catch_rise_max_mps`` = v_c⁺ the catch-up is clip(k (h̄ − h_t), −v_c, v_c⁺): a large gap raises v_ref by
    v_c⁺ only, a small one still lowers it by v_c, and inside the saturation nothing changes; 0 (the default) is
    the symmetric clip."""
    base = dict(window_s=1.0, catch_gain_per_s=0.37, target_gap_m=6.5, target_time_gap_s=1.3, buffer_time_s=0.0)
    assert WaveParams().catch_rise_max_mps == 0.0
    for rise in (0.0, 0.35, 1.6):
        c = WaveMPC(EV, Proposed(), WaveParams(**base, catch_max_mps=0.8, catch_rise_max_mps=rise), S)
        for h, v in ((20.0, 5.0), (14.0, 5.0), (13.35, 5.0), (3.0, 5.0)):
            c.reset()
            raw = 0.37 * (h - 6.5 - 1.3 * v)  # 2.59, 0.37, 0.1295, −3.7 m/s
            up = rise if rise > 0 else 0.8
            got = float(U.speed_to_si(c.reference(float(U.length_from_si(h)), float(U.speed_from_si(v)))))
            assert got == pytest.approx(v + min(max(raw, -0.8), up), rel=1e-12), (rise, h)
    c.reset()  # exactly at the upper saturation v_c⁺ = 1.6 m/s
    h_sat = 6.5 + 1.3 * 5.0 + 1.6 / 0.37
    assert float(U.speed_to_si(c.reference(float(U.length_from_si(h_sat)), float(U.speed_from_si(5.0))))) == (
        pytest.approx(6.6, rel=1e-12)
    )


def test_the_wave_buffer_raises_the_target_gap_by_c_times_the_predecessor_speed_std():
    """h_t = s_t + T_t U + c σ_l, σ_l the (population) std of the last 5 measured predecessor speeds."""
    wp = WaveParams(window_s=1.0, catch_gain_per_s=0.21, target_gap_m=15.0, target_time_gap_s=1.1, buffer_time_s=1.3)
    c = WaveMPC(EV, Proposed(), wp, S)
    speeds = [4.1, 3.7, 5.2, 4.4, 3.9, 4.8]
    gaps = [21.0, 19.5, 24.0, 22.5, 20.0, 23.5]
    leads = [2.0, 6.5, 1.2, 7.7, 3.3, 5.9]
    for k, (v, h, vl) in enumerate(zip(speeds, gaps, leads)):
        cmd = c.command(obs(h, v, vl, t=0.1 * k))
        w = slice(max(0, k - 4), k + 1)
        U_ = np.mean(speeds[w])
        raw = 0.21 * (np.mean(gaps[w]) - 15.0 - 1.1 * U_ - 1.3 * np.std(leads[w]))
        assert abs(raw) < 1.0  # inside the saturation: the buffer term is seen whole
        assert cmd.info["v_ref_mps"] == pytest.approx(U_ + raw, rel=1e-9)
    c.reset()
    assert np.isnan(c.predecessor_speeds.value)


def reference_params(k: float, s_t: float, T_t: float, c: float, **fields: float) -> WaveParams:
    """WaveParams of the reference tests: a 1 s window (5 samples), catch-up gain k [1/s], target s_t [m] + T_t [s] U,
    buffer c [s] σ_l, and ``fields``."""
    return WaveParams(
        window_s=1.0, catch_gain_per_s=k, target_gap_m=s_t, target_time_gap_s=T_t, buffer_time_s=c, **fields
    )


@pytest.mark.parametrize("beta", [1.0, 0.35])
def test_the_reference_base_is_the_blend_of_own_and_predecessor_mean_speeds(beta):
    """``base_predecessor_share`` = β: v_ref = B + clip(k (h̄ − s_t − T_t B − c σ_l), −v_c, v_c), B = (1 − β) U + β U_l,
    U and U_l the means of the last 5 own and predecessor speeds (hand computation; the predecessor's speeds are not
    the car's, so B is not U)."""
    wp = reference_params(0.23, 7.5, 1.7, 0.6, base_predecessor_share=beta)
    c = WaveMPC(EV, Proposed(), wp, S)
    speeds = [2.3, 3.1, 2.7, 3.6, 2.9, 3.3, 2.6]
    gaps = [16.0, 14.5, 17.5, 15.0, 16.5, 13.5, 18.0]
    leads = [4.7, 3.8, 5.3, 4.1, 4.9, 3.6, 5.6]
    for k, (v, h, vl) in enumerate(zip(speeds, gaps, leads)):
        cmd = c.command(obs(h, v, vl, t=0.1 * k))
        w = slice(max(0, k - 4), k + 1)
        base = (1.0 - beta) * np.mean(speeds[w]) + beta * np.mean(leads[w])
        raw = 0.23 * (np.mean(gaps[w]) - 7.5 - 1.7 * base - 0.6 * np.std(leads[w]))
        assert abs(raw) < 1.0  # inside the saturation
        assert abs(base - np.mean(speeds[w])) > 0.4  # the predecessor's mean is not the own one
        assert cmd.info["v_ref_mps"] == pytest.approx(base + raw, rel=1e-9), k
    assert WaveParams().base_predecessor_share == 0.0  # the default: the own mean, as before
    with pytest.raises(ParameterError, match="base_predecessor_share"):
        WaveParams(base_predecessor_share=1.2)


def test_the_speed_band_clips_v_ref_after_the_catch_up():
    """v_ref = clip(U + clip(k (h̄ − s_t − T_t U), −v_c, v_c), v_lo, v_hi): below, inside and above the band, and each
    side alone; an empty band is refused."""
    base = dict(window_s=1.0, catch_gain_per_s=0.37, target_gap_m=6.5, target_time_gap_s=1.3, buffer_time_s=0.0)
    for lo, hi in ((3.35, 4.15), (3.35, 0.0), (0.0, 4.15)):
        c = WaveMPC(EV, Proposed(), WaveParams(**base, min_ref_mps=lo, max_ref_mps=hi), S)
        for h, v in ((9.0, 3.0), (12.0, 3.6)):
            c.reset()
            free = v + 0.37 * (h - 6.5 - 1.3 * v)  # 2.482 and 3.903 m/s, both inside the saturation (±1 m/s)
            assert 2.0 < free < 3.35 or 3.35 < free < 4.15  # one reference below the band, one inside it
            got = float(U.speed_to_si(c.reference(float(U.length_from_si(h)), float(U.speed_from_si(v)))))
            assert got == pytest.approx(max(free, lo), rel=1e-12)
        c.reset()
        free = 5.0 + 0.37 * (20.0 - 6.5 - 6.5)  # 7.59, saturated at U + v_c = 6.0 m/s: above the band
        got = float(U.speed_to_si(c.reference(float(U.length_from_si(20.0)), float(U.speed_from_si(5.0)))))
        assert got == pytest.approx(min(6.0, hi) if hi else 6.0, rel=1e-12)
    with pytest.raises(ParameterError, match="min_ref_mps = 3.7 m/s is above max_ref_mps = 3.6"):
        WaveParams(min_ref_mps=3.7, max_ref_mps=3.6)
    assert WaveParams(min_ref_mps=3.6, max_ref_mps=3.6).max_ref_mps == 3.6  # on the limit: a point band


@pytest.mark.slow  # 600 s of closed loop: about 5 s of one core
def test_behind_a_constant_speed_leader_it_keeps_its_speed_on_average_and_its_gap_in_the_band():
    """Behind a constant-speed leader the catch-up's slow loop (an integral through the 38 s mean) does not settle:
    the car swings about the leader's speed (period about 90 s, within ±v_c + the MPC's own move) with its gap
    between the soft floor s_min + T_min v and the ceiling; on average it drives at the leader's speed."""
    wp = WaveParams()
    vl = 8.0
    r = run_closed_loop(
        ConstantSpeed(float(U.speed_from_si(vl))),
        [WaveMPC(EV, Proposed(), wp)],
        [float(U.length_from_si(14.0))],
        [float(U.speed_from_si(6.5))],
        float(U.time_from_si(600.0)),
        ev=EV,
    )
    assert r.status == "ok"
    v, h = U.speed_to_si(r.speed[:, 0]), U.length_to_si(r.gap[:, 0])
    t = U.time_to_si(r.t)
    late = t >= 300.0
    assert abs(np.trapezoid(v[late], t[late]) / (t[late][-1] - t[late][0]) - vl) < 0.15  # the leader's mean speed
    floor = wp.traffic.standstill_gap_m + wp.traffic.time_headway_s * vl  # 8.4 m
    assert np.min(h[late]) > floor - 0.05 and np.max(h[late]) < wp.max_gap_m + wp.max_time_gap_s * vl
    assert np.max(np.abs(v[late] - vl)) < 2.0


def test_one_wave_mpc_car_on_the_ring_under_the_safety_layer():
    from aev_ocp.ring.run import fleet_metrics
    from aev_ocp.ring.scenario import build_ring, load_ring_scenario
    from aev_ocp.ring.simulate import RingSimulator

    sc = load_ring_scenario(ROOT / "scenarios" / "ring_wave.toml")
    assert sc.ev.limits.safety_layer and "wave-mpc" in sc.spec.controllers
    ring, init = build_ring(sc, "wave-mpc")
    assert isinstance(ring.vehicles[0], WaveMPC) and not ring.human[0] and all(ring.human[1:])
    res = RingSimulator(ring).run(init, 90.0)
    f = fleet_metrics(res)
    assert res.status == "ok" and f["collisions"] == 0 and float(res.gap_m[:, 0].min()) > 2.0  # the car's own gap
    st = res.sim.solver_stats[0]
    assert st["steps"] == 450 and st["fallbacks"] == 0 and "safety layer" in st["conditioning"]


def _cell(x: dict[str, float]) -> str:
    """An interval as the guide prints it: mean [lo, hi], 3 significant digits."""
    return f"{x['mean']:.3g} [{x['lo']:.3g}, {x['hi']:.3g}]"


@pytest.mark.parametrize("scenario", ["ring_wave", "ring_wave_idm"])
def test_the_guide_quotes_the_benchmark_and_its_intervals_are_the_per_seed_values(scenario):
    """docs/guide/studies.md quotes what benchmarks/bench_wave_mpc.py measured (the JSON its --record writes to
    tests/data/), and each target's interval is Student's t over the recorded per-seed values, recomputed here with
    SciPy (the package computes its own quantile)."""
    from scipy import stats

    doc = json.loads((ROOT / "tests" / "data" / f"bench_wave_mpc_{scenario}.json").read_text(encoding="utf-8"))
    seeds = [str(k) for k in doc["seeds"]]
    assert len(seeds) >= 10 and not {int(k) for k in seeds} & {*range(10), *range(40, 50)}  # not the tuning seeds
    ps = doc["per_seed"]
    per = {
        "speed_std_ratio_to_human": [
            ps[k]["wave-mpc"]["speed_std_mps"] / ps[k]["human"]["speed_std_mps"] for k in seeds
        ],
        "mean_speed_minus_followerstopper_mps": [
            ps[k]["wave-mpc"]["mean_speed_mps"] - ps[k]["followerstopper"]["mean_speed_mps"] for k in seeds
        ],
        "battery_energy_ratio_to_human": [
            ps[k]["wave-mpc"]["battery_energy_J_per_km"] / ps[k]["human"]["battery_energy_J_per_km"] for k in seeds
        ],
    }
    text = (ROOT / "docs" / "guide" / "studies.md").read_text(encoding="utf-8")
    start = text.index(f"<!-- bench_wave_mpc {scenario} -->")
    section = text[start : text.index("<!-- end -->", start)]
    for name, x in per.items():
        iv = doc["targets"][name]
        n = len(x)
        half = stats.t.ppf(0.975, n - 1) * np.std(x, ddof=1) / np.sqrt(n)
        assert iv["mean"] == pytest.approx(np.mean(x), rel=1e-12)
        assert (iv["lo"], iv["hi"]) == pytest.approx((np.mean(x) - half, np.mean(x) + half), rel=1e-9, abs=1e-12)
        line = next(r for r in section.splitlines() if r.startswith(f"| {name} "))
        assert f"| {_cell(iv)} | {iv['verdict']} |" in line, (line, iv)
    for metric in ("throughput_veh_per_h", "mean_speed_mps", "speed_std_mps", "braking_events_per_veh_km"):
        row = (
            "| "
            + metric
            + " | "
            + " | ".join(_cell(doc["table"][c][metric]) for c in ("human", "followerstopper", "wave-mpc"))
        )
        assert row + " |" in section, row
    e = [doc["table"][c]["battery_energy_J_per_km"] for c in ("human", "followerstopper", "wave-mpc")]
    row = "| battery_energy_kJ_per_km | " + " | ".join(_cell({k: x[k] / 1e3 for k in ("mean", "lo", "hi")}) for x in e)
    assert row + " |" in section, row


def _wave_doc(**wave: object) -> dict[str, object]:
    """A small IDM ring whose vehicle 2 runs the wave MPC, with ``[ring.wave]`` = ``wave`` (none if empty)."""
    ring: dict[str, object] = {
        "length_m": 123.0,
        "vehicles": 7,
        "t_end_s": 17.0,
        "aev": {"vehicles": [2], "controllers": ["followerstopper", "wave-mpc"]},
    }
    if wave:
        ring["wave"] = dict(wave)
    return {"name": "w", "ring": ring}


def test_a_ring_scenario_sets_its_wave_mpc_parameters_and_only_its_own():
    """``[ring.wave]`` reaches the ring's wave-MPC car (the fields given, every other at WaveParams' default); without
    the table the car keeps the defaults (those the drive cycles and the safety suite run)."""
    from dataclasses import replace

    from aev_ocp.ring.scenario import build_ring, parse_ring_scenario

    sc = parse_ring_scenario(_wave_doc(target_gap_m=13.5, target_time_gap_s=2.75, buffer_time_s=0), "w.toml")
    assert sc.spec.wave == {"target_gap_m": 13.5, "target_time_gap_s": 2.75, "buffer_time_s": 0.0}
    car = build_ring(sc, "wave-mpc")[0].vehicles[1]
    assert isinstance(car, WaveMPC)
    assert car.params == replace(WaveParams(), target_gap_m=13.5, target_time_gap_s=2.75, buffer_time_s=0.0)
    assert car.params != WaveParams() and car.describe()["wave"]["target_gap_m"] == 13.5
    plain = build_ring(parse_ring_scenario(_wave_doc(), "w.toml"), "wave-mpc")[0].vehicles[1]
    assert plain.params == WaveParams()


@pytest.mark.parametrize(
    "wave, controllers, message",
    [
        ({"target_gap": 12.0}, None, "unknown key 'ring.wave.target_gap'"),
        ({"traffic": {"jerk_weight": 1.0}}, None, "unknown key 'ring.wave.traffic'"),
        ({"target_gap_m": -0.5}, None, "ring.wave.target_gap_m = -0.5 is not allowed"),
        ({"window_s": 0.0}, None, "ring.wave.window_s = 0.0 is not allowed: must be a finite number > 0"),
        ({"catch_max_mps": "1"}, None, "ring.wave.catch_max_mps"),
        ({"target_gap_m": 12.0}, ["followerstopper"], "no AEV runs 'wave-mpc'"),
    ],
)
def test_a_ring_scenarios_wave_table_refuses_nonsense_naming_the_key(wave, controllers, message):
    from aev_ocp.ring.scenario import parse_ring_scenario
    from aev_ocp.scenarios import ScenarioError

    doc = _wave_doc(**wave)
    if controllers is not None:
        doc["ring"]["aev"]["controllers"] = controllers  # type: ignore[index]
    with pytest.raises(ScenarioError, match=re.escape(message)) as e:
        parse_ring_scenario(doc, "w.toml")
    assert str(e.value).startswith("w.toml: ")
    assert parse_ring_scenario(_wave_doc(window_s=0.5), "w.toml").spec.wave == {"window_s": 0.5}  # inside: taken


def test_the_guide_quotes_the_sumo_wave_study_and_its_intervals_are_the_per_seed_values():
    """docs/guide/studies.md quotes what ``benchmarks/bench_sumo.py --wave`` measured in SUMO's ring and merge (the
    JSON its --record writes to tests/data/): the tables between the markers are the recorded ones, and each run's
    mean and 95 % interval of the speed std and the battery energy is Student's t over the recorded per-seed values
    of its completed runs, recomputed here with SciPy."""
    from scipy import stats

    doc = json.loads((ROOT / "tests" / "data" / "bench_sumo_wave.json").read_text(encoding="utf-8"))
    text = (ROOT / "docs" / "guide" / "studies.md").read_text(encoding="utf-8")
    for name in ("sumo_ring", "sumo_merge"):
        d = doc[name]
        assert len(d["seeds"]) >= 10
        start = text.index(f"<!-- bench_sumo_wave {name} -->")
        section = text[start : text.index("<!-- end -->", start)]
        assert d["markdown"].strip() in section
        for row in d["rows"]:
            share, ctrl = row["run"].split(" ", 1)
            runs = [
                p
                for p in d["per_seed"]
                if p["share"] == float(share) and (p["controller"] == ctrl or float(share) == 0) and p["status"] == "ok"
            ]
            assert row["seeds"] - row["failed"] == len(runs)
            for m in ("speed_std_mps", "battery_energy_kWh_per_100km"):
                x = np.array([p[m] for p in runs], float)
                if len(x) < 2:
                    assert row[m] is None
                    continue
                half = stats.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x))
                assert row[m]["mean"] == pytest.approx(np.mean(x), rel=1e-12)
                assert (row[m]["lo"], row[m]["hi"]) == pytest.approx(
                    (x.mean() - half, x.mean() + half), rel=1e-9, abs=1e-12
                )


@pytest.mark.parametrize(
    "suffix, first, marker",
    [
        ("_seeds80-99", 80, "**The fresh seeds 80–99"),
        ("_seeds100-119", 100, "**The fresh seeds 100–119"),
        ("_hold_seeds100-119", 100, "**The speed hold on the fresh seeds 100–119"),
        ("_hold_seeds20-39", 20, "**The hold on the earlier seeds 20–39"),
        ("_hold_seeds80-99", 80, "**The hold on the earlier seeds 80–99"),
    ],
)
def test_the_guide_quotes_the_evaluations_on_fresh_seeds(suffix, first, marker):
    """The guide's paragraphs on the evaluations (the fresh seeds 80–99 and 100–119 with the defaults, 100–119 with
    the speed hold, and the hold on 20–39 and 80–99) quote the runs recorded in tests/data (the three targets' means
    and 95 % t intervals, recomputed here with SciPy from the per-seed values, and every seed's speed-std ratio)."""
    from scipy import stats

    doc = json.loads((ROOT / "tests" / "data" / f"bench_wave_mpc_ring_wave{suffix}.json").read_text(encoding="utf-8"))
    assert doc["seeds"] == list(range(first, first + 20))
    # the speed hold's runs ran with it (the guide's setting), the others with the defaults
    hold = {"hold_min_mps": 3.5, "hold_max_mps": 3.5, "hold_sigma_mps": 1.5}
    ran = all(f"{k}={v!r}" in doc["wave_params"] for k, v in hold.items())
    assert ran == suffix.startswith("_hold"), doc["wave_params"]
    ps = doc["per_seed"]
    ratio = [ps[str(k)]["wave-mpc"]["speed_std_mps"] / ps[str(k)]["human"]["speed_std_mps"] for k in doc["seeds"]]
    half = stats.t.ppf(0.975, len(ratio) - 1) * np.std(ratio, ddof=1) / np.sqrt(len(ratio))
    iv = doc["targets"]["speed_std_ratio_to_human"]
    assert (iv["mean"], iv["lo"], iv["hi"]) == pytest.approx(
        (np.mean(ratio), np.mean(ratio) - half, np.mean(ratio) + half)
    )
    text = (ROOT / "docs" / "guide" / "studies.md").read_text(encoding="utf-8")
    start = text.index(marker)
    para = " ".join(text[start : text.index("\n\n", start)].split())  # the words, whatever the line breaks
    assert f"{iv['mean']:.3f} [{iv['lo']:.3f}, {iv['hi']:.3f}]" in para
    for name in ("mean_speed_minus_followerstopper_mps", "battery_energy_ratio_to_human"):
        x = doc["targets"][name]
        assert f"{x['mean']:.2f} [{x['lo']:.2f}, {x['hi']:.2f}]" in para, name
    assert ", ".join(f"{r:.3f}" for r in ratio) in para


def test_the_latched_hold_engages_at_hold_min_and_then_clips_v_ref_to_its_band():
    """Before the car's mean speed U first reaches v_lo = hold_min_mps, v_ref is the catch-up's (gain k, buffer c);
    from that step on (and after U falls below v_lo again) v_ref = clip(U + clip(k_h (h̄ − s_t − T_t U − c_h σ_l),
    −v_c, v_c), v_lo, v_hi), the reference written out here over a 5-sample window; reset() forgets the latch."""
    wp = WaveParams(
        window_s=1.0,
        catch_gain_per_s=0.37,
        target_gap_m=6.5,
        target_time_gap_s=1.3,
        catch_max_mps=0.8,
        buffer_time_s=1.1,
        hold_min_mps=3.45,
        hold_max_mps=3.95,
        hold_gain_per_s=0.13,
        hold_buffer_time_s=0.6,
    )
    c = WaveMPC(EV, Proposed(), wp, S)
    speeds = [2.1, 2.6, 3.0, 3.4, 4.6, 4.9, 2.3, 1.9, 2.2, 4.8, 5.6, 5.1, 3.7]
    gaps = [11.0, 14.5, 9.0, 30.0, 16.0, 12.5, 4.0, 8.0, 12.2, 21.0, 25.0, 19.0, 17.5]
    leads = [2.0, 6.5, 1.2, 7.7, 3.3, 5.9, 0.4, 2.8, 4.4, 6.1, 5.0, 3.9, 4.2]
    latched, seen = False, set()
    for k, (v, h, vl) in enumerate(zip(speeds, gaps, leads)):
        cmd = c.command(obs(h, v, vl, t=0.1 * k))
        w = slice(max(0, k - 4), k + 1)
        U_, h_bar, sig = np.mean(speeds[w]), np.mean(gaps[w]), np.std(leads[w])
        latched = latched or U_ >= 3.45
        k_, c_ = (0.13, 0.6) if latched else (0.37, 1.1)
        ref = U_ + min(max(k_ * (h_bar - 6.5 - 1.3 * U_ - c_ * sig), -0.8), 0.8)
        if latched:
            seen.add("below" if ref < 3.45 else "above" if ref > 3.95 else "inside")
            ref = min(max(ref, 3.45), 3.95)
        else:
            seen.add("free")
        assert c.held == latched
        assert cmd.info["v_ref_mps"] == pytest.approx(ref, rel=1e-9), k
    assert seen == {"free", "below", "inside", "above"}  # every branch of the reference taken
    c.reset()
    assert not c.held and not c.armed
    # it latches only once U has been below v_lo: a car that starts above the band (a ring's uniform flow, before its
    # jam) runs the catch-up until it has fallen below v_lo and come back (window 5 samples)
    states = []
    for v in (5.2, 5.0, 4.8, 1.0, 1.0, 1.0, 1.0, 6.0, 6.0, 6.0, 6.0, 6.0):
        c.reference(float(U.length_from_si(15.0)), float(U.speed_from_si(v)))
        states.append((c.armed, c.held))
    # U: 5.2, 5.1, 5.0, 4.0, 3.4 (armed), 2.56, 1.76, 2.0, 3.0, 3.6 (held), ...
    assert states == [(False, False)] * 4 + [(True, False)] * 5 + [(True, True)] * 3
    # the upper side alone is refused (nothing latches it); an empty band too; on the limit a point band
    with pytest.raises(ParameterError, match="hold_max_mps = 3.9 m/s needs hold_min_mps > 0"):
        WaveParams(hold_max_mps=3.9)
    with pytest.raises(ParameterError, match="hold_min_mps = 3.7 m/s is above hold_max_mps = 3.6"):
        WaveParams(hold_min_mps=3.7, hold_max_mps=3.6)
    assert WaveParams(hold_min_mps=3.6, hold_max_mps=3.6).hold_max_mps == 3.6
    assert WaveParams(hold_min_mps=3.6).hold_max_mps == 0.0  # no upper side


def test_the_hold_latches_only_while_the_ring_is_calm_and_releases_when_a_wave_grows():
    """With ``hold_sigma_mps`` = σ* the hold latches only with σ_l ≤ σ* (σ_l the std of the predecessor's last 5 measured
    speeds) and releases, back to the catch-up, at the first step with σ_l > σ*; it latches again when σ_l ≤ σ* with
    U ≥ v_lo (already armed). Each step's state is written out here from the window's std."""
    wp = WaveParams(window_s=1.0, buffer_time_s=0.0, hold_min_mps=3.5, hold_max_mps=3.5, hold_sigma_mps=0.45)
    c = WaveMPC(EV, Proposed(), wp, S)
    speeds = [2.0, 3.8, 4.0, 4.1, 4.2, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0]
    leads = [3.0, 3.1, 3.0, 3.2, 3.1, 3.0, 4.3, 3.1, 3.0, 3.0, 3.1, 3.0, 3.2]
    got, want = [], []
    held = False
    for k, (v, vl) in enumerate(zip(speeds, leads)):
        c.predecessor_speeds.update(float(U.speed_from_si(vl)))
        ref = float(U.speed_to_si(c.reference(float(U.length_from_si(18.0)), float(U.speed_from_si(v)))))
        w = slice(max(0, k - 4), k + 1)
        calm = np.std(leads[w]) <= 0.45
        held = calm and (held or np.mean(speeds[w]) >= 3.5)  # armed at step 0 (U = 2 m/s)
        got.append(c.held)
        want.append(held)
        if held:
            assert ref == pytest.approx(3.5, rel=1e-12)
    assert got == want
    # latched at step 4 (U 3.62), released at step 6 (the 4.3 m/s sample: σ_l 0.50), latched again at step 11
    assert want == [False] * 4 + [True] * 2 + [False] * 5 + [True] * 2


def test_the_hold_releases_below_hold_release_and_latches_again_at_hold_min():
    """With ``hold_release_mps`` = v_r < v_lo the held car returns to the catch-up at the first step with U < v_r and
    latches again at U ≥ v_lo (5-sample window); v_r ≥ v_lo is refused."""
    wp = WaveParams(window_s=1.0, buffer_time_s=0.0, hold_min_mps=3.5, hold_release_mps=3.1)
    c = WaveMPC(EV, Proposed(), wp, S)
    speeds = [2.0, 4.0, 4.0, 4.0, 4.0, 2.9, 2.9, 2.9, 3.0, 3.5, 4.6, 4.6, 4.6]
    # U: 2.0, 3.0, 3.33, 3.5 (held: on the limit), 3.6, 3.78, 3.56, 3.34, 3.14, 3.04 (released), 3.38, 3.72 (held), 4.06
    want = [False] * 3 + [True] * 6 + [False] * 2 + [True] * 2
    got = []
    for v in speeds:
        c.reference(float(U.length_from_si(18.0)), float(U.speed_from_si(v)))
        got.append(c.held)
    assert got == want
    with pytest.raises(ParameterError, match="hold_release_mps = 3.5 m/s must be below hold_min_mps = 3.5"):
        WaveParams(hold_min_mps=3.5, hold_release_mps=3.5)


def test_the_adaptive_buffer_integrates_the_wave_and_hands_the_base_back_to_the_own_mean():
    """``buffer_rate`` = g: b_k = clip(b_(k−1) + Δt g (σ_l − σ*), 0, b_max), h_t = s_t + T_t B + c σ_l + b and the
    base B = (1 − β') U + β' U_l with β' = β (1 − b/b_max) (hand computation over a wave and a calm that drive b to
    both of its limits; the catch-up unsaturated)."""
    g, sig_star, b_max, beta = 7.3, 0.45, 2.9, 0.8
    wp = reference_params(
        0.19,
        3.5,
        0.9,
        0.7,
        catch_max_mps=50.0,
        base_predecessor_share=beta,
        buffer_rate=g,
        buffer_sigma_mps=sig_star,
        buffer_max_m=b_max,
    )
    c = WaveMPC(EV, Proposed(), wp, S)
    dt_s = float(U.time_to_si(S.dt))
    speeds = [3.1, 3.4, 2.8, 3.3, 3.0, 3.2, 3.5, 2.9, 3.1, 3.3, 3.0, 3.2, 3.4, 2.7, 3.6]
    gaps = [12.0, 13.5, 11.0, 12.5, 14.0, 12.8, 13.1, 11.9, 12.2, 13.4, 12.6, 13.0, 12.4, 11.6, 13.7]
    leads = [
        1.2,
        5.1,
        0.9,
        5.6,
        1.5,
        3.3,
        3.3,
        3.3,
        3.3,
        3.3,
        3.3,
        3.3,
        3.3,
        3.3,
        3.3,
    ]  # a wave, then a steady predecessor
    b, seen = 0.0, []
    for k, (v, h, vl) in enumerate(zip(speeds, gaps, leads)):
        cmd = c.command(obs(h, v, vl, t=0.1 * k))
        w = slice(max(0, k - 4), k + 1)
        sig = np.std(leads[w])
        b = min(max(b + dt_s * g * (sig - sig_star), 0.0), b_max)
        beta_k = beta * (1.0 - b / b_max)
        base = (1.0 - beta_k) * np.mean(speeds[w]) + beta_k * np.mean(leads[w])
        ref = base + 0.19 * (np.mean(gaps[w]) - 3.5 - 0.9 * base - 0.7 * sig - b)
        assert cmd.info["buffer_m"] == pytest.approx(b, rel=1e-12, abs=1e-12), k
        assert cmd.info["v_ref_mps"] == pytest.approx(ref, rel=1e-9), k
        seen.append(b)
    assert b_max in seen and seen[-1] == 0.0 and any(0.0 < x < b_max for x in seen)  # both limits and inside
    c.reset()
    assert c.buffer_m == 0.0
    assert WaveParams().buffer_rate == 0.0  # off by default
    with pytest.raises(ParameterError, match="buffer_sigma_mps"):
        WaveParams(buffer_sigma_mps=0.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-40.0, 40.0, allow_nan=False), min_size=2, max_size=40), st.floats(-3.0, 3.0))
def test_the_detrended_spread_is_the_std_of_the_least_squares_residuals(ys, slope):
    """``spread(detrend=True)`` equals the population std of the residuals of numpy's degree-1 least-squares fit
    over the sample index; a linear trend added to the samples changes it by nothing; without detrending it is
    numpy's std."""
    y = np.asarray(ys) + slope * np.arange(len(ys))
    x = np.arange(len(ys), dtype=float)
    resid = y - np.polyval(np.polyfit(x, y, 1), x)
    assert spread(y, detrend=True) == pytest.approx(np.std(resid), rel=1e-7, abs=1e-9)
    assert spread(y, detrend=True) == pytest.approx(spread(np.asarray(ys), detrend=True), rel=1e-7, abs=1e-9)
    assert spread(y) == pytest.approx(np.std(y), rel=1e-12, abs=1e-12)


def test_the_detrended_wave_buffer_ignores_a_ramp_and_sees_an_oscillation():
    """With ``detrend_sigma`` the σ_l of c σ_l and of the adaptive buffer is the std of the last 5 predecessor speeds
    about their least-squares line (hand computation with numpy's polyfit): a predecessor leaving at a steady
    acceleration opens no buffer, an oscillating one opens the same buffer as the plain std's minus its trend."""
    g, sig_star, c_s = 3.7, 0.25, 1.9
    wp = reference_params(0.17, 4.5, 1.1, c_s, catch_max_mps=50.0, buffer_rate=g, buffer_sigma_mps=sig_star)
    dt_s = float(U.time_to_si(S.dt))
    speeds = [0.4, 1.1, 1.9, 2.6, 3.2, 3.9, 4.3, 4.6, 4.4, 4.7]
    gaps = [6.0, 6.8, 7.9, 8.6, 9.4, 9.9, 10.3, 10.1, 9.8, 10.4]
    for leads, ramp in (
        ([0.7, 1.4, 2.1, 2.8, 3.5, 4.2, 4.9, 5.6, 6.3, 7.0], True),
        ([2.1, 4.8, 1.6, 5.3, 2.4, 4.9, 1.8, 5.5, 2.2, 4.6], False),
    ):
        plain = WaveMPC(EV, Proposed(), wp, S)
        det = WaveMPC(EV, Proposed(), replace(wp, detrend_sigma=True), S)
        b = 0.0
        for k, (v, h, vl) in enumerate(zip(speeds, gaps, leads)):
            o = obs(h, v, vl, t=0.1 * k)
            cmd = det.command(o)
            plain.command(o)
            w = slice(max(0, k - 4), k + 1)
            x = np.arange(len(leads[w]), dtype=float)
            sig = float(np.std(leads[w] - np.polyval(np.polyfit(x, leads[w], 1), x))) if k else 0.0
            b = min(max(b + dt_s * g * (sig - sig_star), 0.0), 20.0)
            U_ = np.mean(speeds[w])
            ref = U_ + 0.17 * (np.mean(gaps[w]) - 4.5 - 1.1 * U_ - c_s * sig - b)
            assert cmd.info["buffer_m"] == pytest.approx(b, rel=1e-9, abs=1e-9), (ramp, k)
            assert cmd.info["v_ref_mps"] == pytest.approx(ref, rel=1e-9), (ramp, k)
        if ramp:  # a steady acceleration: no buffer detrended, a growing one plain
            assert det.buffer_m == 0.0 and plain.buffer_m > 0.5
        else:
            assert det.buffer_m > 0.5
    assert WaveParams().detrend_sigma is False  # off by default: the plain std, as before


def test_at_the_end_of_its_lane_it_targets_the_lanes_limit_and_keeps_the_lane_end_out_of_its_averages():
    """With ``Observation.lane_end`` (the gap measures the distance to the end of its lane, the "predecessor speed"
    is 0) v_ref is ``Observation.speed_limit``; the predecessor-speed and gap windows stay as they were (the own
    speed is still averaged); a merge assistant's advised speed (``Observation.merge_speed``) replaces the limit;
    without either v_ref is the reference of those windows (hand computation); the next ordinary step averages as
    before."""
    wp = WaveParams(window_s=1.0, catch_gain_per_s=0.27, target_gap_m=9.5, target_time_gap_s=1.4, buffer_time_s=0.5)
    wp = replace(wp, base_predecessor_share=0.6)
    c = WaveMPC(EV, Proposed(), wp, S)
    speeds, gaps, leads = [22.4, 22.9, 23.3], [41.0, 44.5, 39.5], [22.8, 23.6, 21.9]
    for k, (v, h, vl) in enumerate(zip(speeds, gaps, leads)):
        c.command(obs(h, v, vl, t=0.1 * k))
    lead_buf, gap_buf = list(c.predecessor_speeds._buf), list(c.gap_average._buf)
    limit = 31.7
    for k, v in enumerate([23.8, 24.6]):
        o = replace(
            obs(180.0 - 2.5 * k, v, 0.0, t=0.3 + 0.1 * k), lane_end=True, speed_limit=float(U.speed_from_si(limit))
        )
        cmd = c.command(o)
        assert cmd.info["v_ref_mps"] == pytest.approx(limit, rel=1e-12)
        assert list(c.predecessor_speeds._buf) == lead_buf and list(c.gap_average._buf) == gap_buf
    # a merge assistant's advice (Observation.merge_speed) wins over the limit, and it too leaves the windows alone
    o = replace(o, t=0.5, merge_speed=float(U.speed_from_si(27.3)))
    assert c.command(o).info["v_ref_mps"] == pytest.approx(27.3, rel=1e-12)
    assert list(c.predecessor_speeds._buf) == lead_buf and list(c.gap_average._buf) == gap_buf
    own = speeds + [23.8, 24.6, 24.6]
    cmd = c.command(replace(obs(175.0, 25.1, 0.0, t=0.6), lane_end=True))  # the limit and the advice unknown
    U_ = np.mean((own + [25.1])[-5:])
    base = 0.4 * U_ + 0.6 * np.mean(leads)
    ref = base + min(max(0.27 * (np.mean(gaps) - 9.5 - 1.4 * base - 0.5 * np.std(leads)), -1.0), 1.0)
    assert cmd.info["v_ref_mps"] == pytest.approx(ref, rel=1e-9)
    c.command(obs(35.5, 25.3, 24.9, t=0.7))  # an ordinary step: both windows take its samples again
    assert list(c.predecessor_speeds._buf)[-1] == pytest.approx(float(U.speed_from_si(24.9)), rel=1e-12)
    assert list(c.gap_average._buf)[-1] == pytest.approx(float(U.length_from_si(35.5)), rel=1e-12)


def test_the_reference_with_the_adaptive_buffer_and_a_lane_end_is_the_same_in_si_whatever_the_units():
    """[units] changes no SI behaviour of the reference: the same SI measurements (a wave, a calm, a lane end with its
    limit) give the same v_ref [m/s] and buffer b [m] under two unit systems (the MPC's dt set so both sample every
    0.2 s)."""
    from aev_ocp.params import Units

    wp = reference_params(
        0.23, 4.5, 1.2, 0.8, base_predecessor_share=0.7, buffer_rate=3.1, buffer_sigma_mps=0.35, buffer_max_m=6.5
    )
    leads = [2.1, 6.3, 1.4, 5.9, 3.8, 4.0, 4.1, 4.0, 3.9, 4.0]
    runs = []
    for units in (Units(7.0, 3.0), Units(23.0, 11.0)):
        ev = EVParams(units=units)
        s = MPCSettings(codegen=False, dt=float(units.time_from_si(0.2)))
        c = WaveMPC(ev, Proposed(), wp, s)
        out = []
        for k, vl in enumerate(leads):
            h, v, end = 14.0 + 0.7 * k, 3.6 + 0.05 * k, k >= 8
            z = np.array([float(units.length_from_si(h)), float(units.speed_from_si(v)), 0.0, 0.0, ev.cell.soc0])
            t = float(units.time_from_si(0.2 * k))
            o = Observation(t, s.dt, 0, z, np.array([t]), np.array([float(units.speed_from_si(0.0 if end else vl))]))
            o = replace(o, lane_end=end, speed_limit=float(units.speed_from_si(13.9)))
            own = c.own_states(o)
            out.append((float(units.speed_to_si(own["v_ref"])), c.buffer_m))
        runs.append(out)
    assert max(b for _, b in runs[0]) > 0.0  # the buffer acts
    for (r0, b0), (r1, b1) in zip(*runs):
        assert r0 == pytest.approx(r1, rel=1e-12) and b0 == pytest.approx(b1, rel=1e-12, abs=1e-12)
    assert runs[0][-1][0] == pytest.approx(13.9, rel=1e-12)

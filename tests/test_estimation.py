"""A closed loop as real as a car's (issue 25): plant ≠ model, noisy/quantised/late measurements, EKF and MHE.

Checks against something independent: sample statistics and closed forms for the sensors, the declared errors for
the mismatch, a hand-written linear Kalman filter (exact discretisation by scipy's expm) for the EKF's
predecessor part, the plant's true states for the SOC target, and the plain closed loop for an exact sensor path.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.linalg import expm

from aev_ocp.control import ClosedLoop, Command, Observation, SampledLaw, estimation_errors
from aev_ocp.estimation import EKF, MHE, Estimate, Measurement, Mismatch, SensorModel, Sensors
from aev_ocp.estimation.base import LEAD_ACCEL_SIGMA_MPS2, LEAD_ACCEL_TAU_S, OWN_NOISE_RATES, OWN_SPEED_NOISE_RATE
from aev_ocp.models import ConstantSpeed, Proposed
from aev_ocp.mpc.cycles import cycle_scenario
from aev_ocp.params import EVParams, ParameterError, Units

UNITS = Units(length_m=12.0, speed_mps=6.0)  # time unit 2 s, no unit equal to 1
LAW = Proposed(alpha=1.7, beta=2.6, kappa=0.04)


# ----------------------------------------------------------------------------- sensors
def _constant_model(s: Sensors, value: float, n_nodes: int = 4000, dt: float = 0.07) -> SensorModel:
    sm = SensorModel(s, 1)
    for k in range(n_nodes):
        sm.record(k * dt, np.full((1, 5), value), np.zeros((1, 3)))
    return sm


def test_sensor_noise_statistics_and_quantum() -> None:
    """Noisy channel: mean ≈ truth, standard deviation ≈ declared (4σ sampling bounds over 4000 draws); a
    quantised channel returns multiples of its quantum only."""
    s = Sensors(gap_noise_m=0.37, gap_quantum_m=0.0, speed_noise_mps=0.0, speed_quantum_mps=0.25, seed=5)
    sm = _constant_model(s, 13.4)
    ms = [sm.measure(0, 0.07 * k) for k in range(2, 4000)]
    g = np.array([m.gap_m for m in ms])
    n = g.size
    assert abs(g.mean() - 13.4) < 4 * 0.37 / math.sqrt(n)
    assert abs(g.std() / 0.37 - 1.0) < 4 / math.sqrt(2 * n)
    v = np.array([m.speed_mps for m in ms])
    assert np.allclose(v / 0.25, np.round(v / 0.25), atol=1e-9) and np.all(v == 13.5)  # 13.4 rounds to 13.5
    assert all(m.battery is None for m in ms)  # not observed by default


def test_sensor_delay_and_sample_period_on_a_ramp() -> None:
    """Zero noise, a linear true signal x(t) = 2.3 + 0.9 t: a delay d reads x(t − d) exactly (between nodes too);
    with a sample period T_s the value is x at the latest sample ⌊(t − d)/T_s⌋·T_s, held in between."""
    zero = Sensors.ideal()
    s = dataclasses.replace(zero, gap_delay_s=0.13, speed_delay_s=0.3, sample_period_s=0.0)
    sm = SensorModel(s, 1)
    for k in range(50):
        t = 0.1 * k
        sm.record(t, np.full((1, 5), 2.3 + 0.9 * t), np.zeros((1, 3)))
    for t in (1.0, 2.37, 4.9):
        m = sm.measure(0, t)
        assert m.gap_m == pytest.approx(2.3 + 0.9 * (t - 0.13), abs=1e-12)
        assert m.speed_mps == pytest.approx(2.3 + 0.9 * (t - 0.3), abs=1e-12)
        assert m.voltage_V == pytest.approx(2.3 + 0.9 * t, abs=1e-12)
    held = dataclasses.replace(s, sample_period_s=0.25)
    sm2 = SensorModel(held, 1)
    sm2.t, sm2.true, sm2.battery = sm.t, sm.true, sm.battery
    for t in (1.0, 1.1, 1.2, 2.37):
        tm = math.floor((t - 0.13) / 0.25) * 0.25
        assert sm2.measure(0, t).gap_m == pytest.approx(2.3 + 0.9 * tm, abs=1e-12)


def test_sensors_refuse_bad_values_and_scale() -> None:
    with pytest.raises(ParameterError, match="gap_noise_m"):
        Sensors(gap_noise_m=-0.1)
    with pytest.raises(ParameterError, match="voltage_delay_s"):
        Sensors(voltage_delay_s=float("nan"))
    s = Sensors().scaled(2.5, 0.17)
    assert s.gap_noise_m == pytest.approx(2.5 * Sensors().gap_noise_m)
    assert s.current_delay_s == 0.17 and s.gap_quantum_m == pytest.approx(2.5 * Sensors().gap_quantum_m)
    assert not Sensors.ideal().degraded and Sensors().degraded


def test_exact_sensor_path_reproduces_the_plain_closed_loop() -> None:
    """Sensors that sample exactly at the controller rate with no noise, no delay and the battery observed go
    through the measurement path yet give the very trajectory of the plain closed loop (two followers: the second
    measures the first)."""
    ev = EVParams(units=UNITS)
    exact = dataclasses.replace(Sensors.ideal(), sample_period_s=UNITS.time_to_si(0.1))
    runs = [
        ClosedLoop(ConstantSpeed(1.3), [SampledLaw(LAW, 0.1), SampledLaw(LAW, 0.1)], ev, sensors=s, estimator=None).run(
            [1.1, 0.9], [1.6, 1.2], 4.0
        )
        for s in (None, exact)
    ]
    assert runs[1].meta["sensors"]["sample_period_s"] > 0
    np.testing.assert_allclose(runs[1].gap, runs[0].gap, rtol=0, atol=1e-9)  # SI round trips
    np.testing.assert_allclose(runs[1].S, runs[0].S, rtol=0, atol=1e-9)


# ----------------------------------------------------------------------------- mismatch
def test_mismatch_fixed_scales_the_model_and_results_state_both() -> None:
    ev = EVParams(units=UNITS)
    mm = Mismatch(mass_rel=0.13, R1_rel=-0.17, capacity_rel=0.07, ocv_offset_V=0.003)
    m = mm.model_ev(ev, 2)
    assert m.vehicle.mass_kg == pytest.approx(1.13 * ev.vehicle.mass_kg)
    assert m.cell.R1_ohm == pytest.approx(0.83 * ev.cell.R1_ohm)
    assert m.cell.capacity_Ah == pytest.approx(1.07 * ev.cell.capacity_Ah)
    assert m.cell.R2_ohm == ev.cell.R2_ohm and m.units == ev.units
    d = mm.describe(ev, 2)
    assert d["plant"]["vehicle"]["mass_kg"] == ev.vehicle.mass_kg
    assert d["models"][1]["ev"]["vehicle"]["mass_kg"] == pytest.approx(1.13 * ev.vehicle.mass_kg)
    with pytest.raises(ParameterError, match="efficiency"):
        Mismatch(efficiency_rel=0.3).model_ev(ev, 0)  # 0.8 × 1.3 > 1
    with pytest.raises(ParameterError, match="distribution"):
        Mismatch(distribution="gauss")


@settings(max_examples=40, deadline=None)
@given(e=st.floats(0.01, 0.6), seed=st.integers(0, 10_000), vehicle=st.integers(0, 7))
def test_mismatch_uniform_draws_stay_within_the_declared_spread(e: float, seed: int, vehicle: int) -> None:
    mm = Mismatch.spread(e, 0.5 * e, seed=seed)
    d = mm.draws(vehicle)
    assert abs(d["mass_rel"]) <= e and abs(d["R0_rel"]) <= 0.5 * e and d["C2_rel"] == 0.0
    assert d == mm.draws(vehicle)  # seeded
    assert d["mass_rel"] != mm.draws(vehicle + 1)["mass_rel"]  # vehicles differ


def test_the_mpc_is_built_on_its_vehicles_model() -> None:
    from aev_ocp.mpc import MPCSettings

    sc = cycle_scenario("udds", 10.0)
    mm = Mismatch(mass_rel=0.09, R0_rel=-0.19)
    loop = ClosedLoop(sc.leader, [MPCSettings(N=8, codegen=False)], sc.ev, mismatch=mm)
    ctrl = loop.ctrl[0]
    assert ctrl.controller.ev.vehicle.mass_kg == pytest.approx(1.09 * sc.ev.vehicle.mass_kg)  # type: ignore[union-attr]
    assert loop.plant.ev.vehicle.mass_kg == sc.ev.vehicle.mass_kg


# ----------------------------------------------------------------------------- estimators
def _linear_lead_kf(ys: list[Measurement], s: Sensors) -> np.ndarray:
    """A hand-written linear Kalman filter of (h, v_l, a_l, v) with ḣ = v_l − v, v̇_l = a_l, ȧ_l = −a_l/τ, v̇ = a
    (a the mean applied acceleration of the interval): exact discretisation by expm; the EKF's noise model."""
    Ac = np.array([[0, 1, 0, -1], [0, 0, 1, 0], [0, 0, -1 / LEAD_ACCEL_TAU_S, 0], [0, 0, 0, 0]], float)
    Bc = np.array([[0.0], [0], [0], [1]])
    R = np.diag([s.variance("gap") + 1e-6, s.variance("lead_speed") + 1e-6, s.variance("speed") + 1e-6])
    C = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
    x = np.array([ys[0].gap_m, ys[0].lead_speed_mps, 0.0, ys[0].speed_mps])
    P = np.diag([R[0, 0] + 0.01, R[1, 1] + 0.01, 1.0, R[2, 2] + 0.01])
    out = []
    for k, y in enumerate(ys):
        if k:
            dt = y.t_s - ys[k - 1].t_s
            M = expm(np.block([[Ac, Bc], [np.zeros((1, 5))]]) * dt)
            A, b = M[:4, :4], M[:4, 4]
            x = A @ x + b * 0.5 * (ys[k - 1].accel_cmd_mps2 + y.accel_cmd_mps2)
            q_acc = LEAD_ACCEL_SIGMA_MPS2**2 * (1 - math.exp(-2 * dt / LEAD_ACCEL_TAU_S))
            Q = np.diag([OWN_NOISE_RATES[3] * dt, OWN_NOISE_RATES[4] * dt, q_acc, OWN_SPEED_NOISE_RATE * dt])
            P = A @ P @ A.T + Q
        K = np.linalg.solve(C @ P @ C.T + R, C @ P).T
        x = x + K @ (np.array([y.gap_m, y.lead_speed_mps, y.speed_mps]) - C @ x)
        P = (np.eye(4) - K @ C) @ P @ (np.eye(4) - K @ C).T + K @ R @ K.T
        out.append(x.copy())
    return np.array(out)


def test_ekf_lead_part_equals_a_linear_kalman_filter() -> None:
    """The EKF's motion states (gap, predecessor speed and acceleration, own speed) decouple from the battery's and
    are linear: they equal a hand-written linear KF with exact (expm) discretisation up to the RK4 step error."""
    s = Sensors(seed=3, gap_delay_s=0.0, lead_speed_delay_s=0.0, speed_delay_s=0.0)
    rng = np.random.default_rng(11)
    t = 0.2 * np.arange(120)
    vl = 9.0 + 2.0 * np.sin(0.3 * t)
    v = 8.5 + 1.5 * np.sin(0.3 * t - 0.4)
    a = 0.45 * np.cos(0.3 * t - 0.4)
    ys = [
        Measurement(
            float(tk),
            14.0 + 0.5 * math.sin(0.2 * tk) + 0.2 * rng.standard_normal(),
            float(v[k]) + 0.05 * rng.standard_normal(),
            float(vl[k]) + 0.1 * rng.standard_normal(),
            350.0,
            21.0,
            accel_cmd_mps2=float(a[k]),
        )
        for k, tk in enumerate(t)
    ]
    ekf = EKF(EVParams(units=UNITS), s, soc0=0.63)
    est = [ekf.reset(ys[0])] + [ekf.update(y) for y in ys[1:]]
    ref = _linear_lead_kf(ys, s)
    np.testing.assert_allclose([e.gap_m for e in est], ref[:, 0], atol=2e-5)
    np.testing.assert_allclose([e.lead_speed_mps for e in est], ref[:, 1], atol=2e-5)
    np.testing.assert_allclose([e.lead_accel_mps2 for e in est], ref[:, 2], atol=2e-5)
    np.testing.assert_allclose([e.speed_mps for e in est], ref[:, 3], atol=2e-5)


@pytest.mark.parametrize("cycle, soc_guess", [("us06", 0.7), ("udds", 0.9)])
def test_ekf_soc_error_below_one_percent_after_60_s(cycle: str, soc_guess: float) -> None:
    """From a 10 % SOC error (true 0.8, on the flat LFP plateau) with production sensor noise and 0.1 s delays,
    the EKF's SOC stays within 1 % of the plant's true SOC from 60 s on (the proposed law drives the cycle). The
    car starts at rest, so the first voltage is the OCV and the first update already removes most of the error."""
    sc = cycle_scenario(cycle, 90.0)
    loop = ClosedLoop(
        sc.leader,
        [sc.law("proposed")],
        sc.ev,
        sensors=Sensors(seed=7),
        estimator=lambda ev, s, off, i: EKF(ev, s, soc0=soc_guess),
        law_dt=0.2,
    )
    r = loop.run(sc.gaps0, sc.speeds0, sc.t_end)
    est = r.solver_stats[0]["estimation"]
    assert r.status == "ok" and r.controllers[0].startswith("proposed@")  # the law ran sampled on the measurements
    assert r.meta["estimators"][0]["soc0"] == soc_guess  # it did start 10 % off
    assert est["soc_err_max_after_60s_pct"] < 1.0
    assert est["lead_speed_err_rms_mps"] < 0.2 and est["gap_err_rms_m"] < 0.2


def test_mhe_tracks_like_the_ekf_and_refuses_a_bad_window() -> None:
    sc = cycle_scenario("udds", 40.0)
    r = ClosedLoop(sc.leader, [sc.law("ovfl")], sc.ev, sensors=Sensors(seed=2), estimator="mhe", law_dt=0.2).run(
        sc.gaps0, sc.speeds0, sc.t_end
    )
    est = r.solver_stats[0]["estimation"]
    assert r.meta["estimators"][0]["estimator"] == "mhe" and r.meta["estimators"][0]["failed_solves"] == 0
    assert est["lead_speed_err_rms_mps"] < 0.2 and est["V1_err_rms_mV"] < 1.0
    with pytest.raises(ParameterError, match="window"):
        MHE(sc.ev, Sensors(), window=1)


# ----------------------------------------------------------------------------- the protocol, the closed loop
class _Fixed:
    """A user's estimator: always SOC 0.437, V1 = V2 = 0, and the measured gap/speed minus 0.5 m / 0.3 m/s."""

    name = "fixed"

    def reset(self, first: Measurement) -> Estimate:
        return self.update(first)

    def update(self, y: Measurement) -> Estimate:
        return Estimate(0.437, 0.0, 0.0, y.gap_m - 0.5, y.lead_speed_mps - 0.3, 0.0)

    def describe(self) -> dict[str, Any]:
        return {"estimator": self.name}


class _Recorder:
    name, dt = "recorder", 0.1

    def __init__(self) -> None:
        self.seen: list[Observation] = []

    def reset(self) -> None:
        self.seen.clear()

    def command(self, obs: Observation) -> Command:
        self.seen.append(obs)
        return Command(0.0)

    def describe(self) -> dict[str, Any]:
        return {"controller": self.name}


def test_a_users_estimator_feeds_the_controller() -> None:
    ev = EVParams(units=UNITS)
    rec = _Recorder()
    s = Sensors.ideal().scaled(0.0, 0.0)
    s = dataclasses.replace(s, battery_states_observed=False)
    r = ClosedLoop(ConstantSpeed(1.3), [rec], ev, sensors=s, estimator=lambda *a: _Fixed()).run([1.1], [1.3], 1.0)
    assert r.meta["estimators"] == [{"estimator": "fixed"}]
    z = rec.seen[-1].z
    assert z[4] == 0.437 and z[2] == 0.0
    gap_true = float(np.interp(rec.seen[-1].t, r.t, r.gap[:, 0]))
    assert UNITS.length_to_si(z[0]) == pytest.approx(UNITS.length_to_si(gap_true) - 0.5, abs=1e-9)
    assert UNITS.speed_to_si(rec.seen[-1].meas_v[-1]) == pytest.approx(UNITS.speed_to_si(1.3) - 0.3, abs=1e-9)


def test_closed_loop_refuses_bad_realism_arguments() -> None:
    ev = EVParams(units=UNITS)
    with pytest.raises(ParameterError, match="estimator"):
        ClosedLoop(ConstantSpeed(1.3), [SampledLaw(LAW, 0.1)], ev, sensors=Sensors(), estimator="kalman")
    loop = ClosedLoop(ConstantSpeed(1.3), [SampledLaw(LAW, 0.1)], ev, sensors=Sensors(), estimator=None)
    with pytest.raises(ParameterError, match="battery_states_observed"):
        loop.run([1.1], [1.3], 0.5)
    with pytest.raises(TypeError, match="sensors"):
        ClosedLoop(ConstantSpeed(1.3), [SampledLaw(LAW, 0.1)], ev, sensors={"gap_noise_m": 0.1})  # type: ignore[arg-type]


def test_estimation_errors_summary() -> None:
    err = np.zeros((400, 5))
    err[:, 0] = np.where(np.arange(400) * 0.2 < 60.0, 0.1, 0.004)
    err[-1, 0] = -0.006
    err[:, 2] = 0.0013
    out = estimation_errors(err, 0.2)
    assert out["soc_err_max_after_60s_pct"] == pytest.approx(0.6)
    assert out["soc_err_final_pct"] == pytest.approx(-0.6)
    assert out["V2_err_rms_mV"] == pytest.approx(1.3)


# ----------------------------------------------------------------------------- scenario tables (study axes)
def _doc(**tables: Any) -> dict[str, Any]:
    import tomllib

    from aev_ocp.scenarios import find_scenario

    doc = tomllib.loads(find_scenario("mpc_udds_single").read_text())
    doc.update(tables)
    return doc


def test_scenario_tables_build_the_realism_arguments() -> None:
    from aev_ocp.estimation.scenario import measurements_degraded, realism_kwargs
    from aev_ocp.scenarios import parse_scenario

    sc = parse_scenario(
        _doc(
            mismatch={"mass_rel": 0.11, "distribution": "fixed"},
            sensors={"noise_scale": 1.7, "delay_s": 0.23, "estimator": "mhe", "soc0_error": 0.13},
        )
    )
    kw = realism_kwargs(sc)
    assert kw["mismatch"].model_ev(sc.ev, 0).vehicle.mass_kg == pytest.approx(1.11 * sc.ev.vehicle.mass_kg)
    assert kw["sensors"].gap_noise_m == pytest.approx(1.7 * Sensors().gap_noise_m)
    assert kw["sensors"].voltage_delay_s == 0.23 and measurements_degraded(sc)
    est = kw["estimator"](sc.ev, kw["sensors"], 0.0, 0)
    assert isinstance(est, MHE) and est.ekf.soc0 == pytest.approx(sc.ev.cell.soc0 - 0.13)
    exact = parse_scenario(
        _doc(sensors={"noise_scale": 0.0, "delay_s": 0.0, "battery_states_observed": True, "estimator": "none"})
    )
    assert not measurements_degraded(exact) and realism_kwargs(exact)["estimator"] is None


@pytest.mark.parametrize(
    "tables, key",
    [
        ({"mismatch": {"mass_rel": -1.5}}, "mismatch.mass_rel"),
        ({"mismatch": {"mass": 0.1}}, "mass"),
        ({"sensors": {"gap_noise_m": -0.2}}, "sensors.gap_noise_m"),
        ({"sensors": {"estimator": "ukf"}}, "sensors.estimator"),
        ({"sensors": {"estimator": "none"}}, "sensors.estimator"),
    ],
)
def test_scenario_tables_refuse_bad_values(tables: dict[str, Any], key: str) -> None:
    from aev_ocp.scenarios import ScenarioError, parse_scenario

    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        parse_scenario(_doc(**tables))


def test_robustness_margins_and_targets() -> None:
    from aev_ocp.robustness import margins, targets

    def row(cond: str, ctrl: str, q: float, ms: float | None = None) -> dict[str, Any]:
        return {
            "cycle": "udds",
            "condition": cond,
            "seed": None if cond == "ideal" else 3,
            "controller": ctrl,
            "heat_pack_J_per_km": q,
            "status": "ok",
            "collisions": 0,
            "estimator_plus_call_ms_median": ms,
        }

    rows = [
        row("ideal", "mpc", 1800.0),
        row("ideal", "proposed", 2400.0),
        row("ideal", "ovfl", 2250.0),
        row("real", "mpc", 2000.0, 0.83),
        row("real", "proposed", 1900.0, 0.2),
        row("real", "ovfl", 2500.0, 0.2),
    ]
    mg = {m["condition"]: m for m in margins(rows)}
    assert mg["ideal"]["margin_vs_proposed_pct"] == pytest.approx(25.0)
    assert mg["ideal"]["margin_vs_ovfl_pct"] == pytest.approx(20.0)
    assert mg["real"]["margin_vs_proposed_pct"] == pytest.approx(-100 / 19)
    tg = targets(rows, list(mg.values()))
    assert tg["no_collision_or_event_real"] and not tg["mpc_below_both_laws_real"]
    assert tg["estimator_plus_mpc_ms_median_max"] == 0.83


def test_ekf_learns_the_plants_ohmic_resistance() -> None:
    """The model's R0 is 17 % too high (a fixed mismatch): the EKF's R0 scale ρ converges to the plant's ratio
    1/1.17 on 90 s of US06, and the SOC stays within 1 %."""
    sc = cycle_scenario("us06", 90.0)
    made: list[EKF] = []

    def factory(ev: EVParams, s: Sensors, off: float, i: int) -> EKF:
        made.append(EKF(ev, s, soc0=sc.ev.cell.soc0, ocv_offset_V=off))
        return made[-1]

    r = ClosedLoop(
        sc.leader,
        [sc.law("ovfl")],
        sc.ev,
        sensors=Sensors(seed=4),
        mismatch=Mismatch(R0_rel=0.17),
        estimator=factory,
        law_dt=0.2,
    ).run(sc.gaps0, sc.speeds0, sc.t_end)
    assert made[0].model.ev.cell.R_s_ohm == pytest.approx(1.17 * sc.ev.cell.R_s_ohm)
    assert made[0].x[7] == pytest.approx(1 / 1.17, abs=0.02)
    assert r.solver_stats[0]["estimation"]["soc_err_max_after_60s_pct"] < 1.0


def test_the_ekf_on_bound_buffers_steps_like_its_plain_call() -> None:
    """The EKF's step on bound buffers (aev_ocp.fastcall.BufferedCall) gives the numbers of the plain CasADi call of
    the same step Function (x and P carried as DM), bit for bit over 80 noisy steps with a varying step length."""
    rng = np.random.default_rng(29)
    t = np.cumsum(rng.uniform(0.05, 0.2, 80))
    ys = [
        Measurement(
            float(tk),
            17.0 + 0.3 * math.sin(0.4 * tk) + 0.2 * rng.standard_normal(),
            11.3 + 0.05 * rng.standard_normal(),
            11.6 + 0.1 * rng.standard_normal(),
            352.0 + 0.5 * rng.standard_normal(),
            23.0 + 9.0 * math.sin(0.7 * tk),
            accel_cmd_mps2=0.31 * math.cos(0.5 * tk),
        )
        for tk in t
    ]
    ekf = EKF(EVParams(units=UNITS), Sensors(seed=5), soc0=0.71)
    ekf.reset(ys[0])
    x, P, u = ca.DM(ekf.x), ca.DM(ekf.P), ekf.u
    for k, y in enumerate(ys[1:], start=1):
        held = ekf.x  # a state read before the step stays what it was (the buffers are the filter's own)
        before = held.copy()
        ekf.update(y)
        np.testing.assert_array_equal(held, before)
        u1 = ekf.model.inputs(y)
        x, P = ekf._fn(x, P, u, u1, ekf.model.outputs(y), y.t_s - ys[k - 1].t_s)
        u = u1
        np.testing.assert_array_equal(ekf.x, np.asarray(x).ravel())
        np.testing.assert_array_equal(ekf.P, np.asarray(P.full()))

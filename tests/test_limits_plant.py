"""Vehicle limits enforced by the plant (issue 21 items 1 and 4): saturation, actuator lag, jerk limit, top
speed, the paper's unbounded laws unchanged, events located in time, status 'violated', the [limits] table,
saved runs, and the traffic MPC's prediction model with the lag. Each check is against something independent:
a hand-written SciPy integration, a closed form, or the other integrator."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aev_ocp.control import ClosedLoop, Command, ControlSequence, Observation
from aev_ocp.models import ConstantSpeed, PaperLeader, Proposed
from aev_ocp.params import UNLIMITED, EVParams, ParameterError, Units, VehicleLimits
from aev_ocp.simulate import simulate_platoon

UNITS = Units(length_m=12.0, speed_mps=6.0)  # accel unit 3 m/s², time unit 2 s (no unit equal to 1)
LAW = Proposed(alpha=1.7, beta=2.6, kappa=0.04)


def _ev(**limits: Any) -> EVParams:
    return EVParams(units=UNITS, limits=VehicleLimits(**limits))


# ----------------------------------------------------------------------------- saturation
@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_saturated_law_matches_scipy(method: str) -> None:
    """A follower closing fast on a slower leader: the law asks < a_min, the plant applies a_min; the gap and speed
    follow the hand-written saturated ODE integrated by SciPy (and the law really saturated for a while)."""
    ev = _ev(a_min_mps2=-6.3, a_max_mps2=2.7)
    lo, hi = -6.3 / 3.0, 2.7 / 3.0
    vl, h0, v0, T = 1.3, 1.1, 3.4, 6.0
    r = simulate_platoon(ConstantSpeed(vl), [LAW], [h0], [v0], T, ev=ev, battery=False, method=method, dt_out=0.05)
    assert r.status == "ok"

    def law(h: float, v: float) -> float:
        return float(LAW.accel(h, v, vl))

    def f(t: float, y: np.ndarray) -> list[float]:
        return [vl - y[1], min(max(law(y[0], y[1]), lo), hi)]

    sol = solve_ivp(f, (0, T), [h0, v0], t_eval=r.t, rtol=1e-11, atol=1e-12, method="DOP853")
    np.testing.assert_allclose(r.gap[:, 0], sol.y[0], atol=2e-7)
    np.testing.assert_allclose(r.speed[:, 0], sol.y[1], atol=2e-7)
    raw = np.array([law(h, v) for h, v in zip(sol.y[0], sol.y[1])])
    assert np.sum(raw < lo) > 10  # the law asked for more than the brakes give...
    assert r.accel.min() == pytest.approx(lo, abs=1e-9)  # ...and the plant applied a_min, never less
    assert np.all(r.accel >= lo - 1e-12) and np.all(r.accel <= hi + 1e-12)


def test_cascade_and_cvodes_agree_with_saturation_active() -> None:
    """The two integrators (no shared stepping code) agree on a platoon whose laws saturate (Table 1's start)."""
    ev = EVParams(limits=VehicleLimits(a_min_mps2=-5.5))
    res = {
        m: simulate_platoon(
            PaperLeader(), [Proposed()] * 3, [0.3, 3.5, 3.5], [1.87] * 3, 12.0, ev=ev, dt_out=0.05, method=m
        )
        for m in ("cascade", "cvodes")
    }
    a, b = res["cascade"], res["cvodes"]
    assert a.status == b.status == "ok"
    assert a.accel.min() == pytest.approx(-5.5 / 2.5, abs=1e-9)  # saturated (the unbounded law: −3.9 model)
    for name in ("gap", "speed", "S", "omega", "heat_J"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=2e-6, atol=2e-6, err_msg=name)


# ----------------------------------------------------------------------------- collisions located in time
@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_collision_time_and_impact_speed_of_a_saturated_brake(method: str) -> None:
    """Issue 21's cut-in: a follower 8 m behind a stopped car at 20 m/s. The law asks −67 m/s², the plant gives
    −8: contact at t = (v0 − √(v0² − 2·8·d))/8 with impact speed √(v0² − 2·8·d), located on the integrator."""
    ev = EVParams(limits=VehicleLimits())  # L = 10 m, U = 5 m/s: 8 m = 0.8, 20 m/s = 4
    r = simulate_platoon(ConstantSpeed(0.0), [Proposed()], [0.8], [4.0], 5.0, ev=ev, method=method)
    v0, d, b = 20.0, 8.0, 8.0
    t_c, v_c = (v0 - math.sqrt(v0**2 - 2 * b * d)) / b, math.sqrt(v0**2 - 2 * b * d)
    assert r.status == "collision"
    e = r.events[0]
    assert e.time_s == pytest.approx(t_c, abs=1e-8)
    assert e.time == pytest.approx(t_c / ev.units.time_s, abs=1e-8)
    assert e.impact_speed_mps == pytest.approx(v_c, abs=1e-7)
    assert r.t[-1] == e.time and r.gap[-1, 0] <= 0 and r.metrics()[0]["min_gap_m"] <= 0
    assert str(e).startswith(f"collision at t = {t_c:.4g} s (") and "impact speed 16.5 m/s" in str(e)


# ----------------------------------------------------------------------------- actuator lag and jerk
class _Step:
    """A sampled controller that commands a constant acceleration [model]."""

    def __init__(self, a: float, dt: float, h_min: float | None = None) -> None:
        self.a, self.dt, self.name, self.h_min = a, dt, "step", h_min

    def reset(self) -> None:
        pass

    def command(self, obs: Observation) -> Command:
        return Command(self.a)

    def describe(self) -> dict[str, Any]:
        return (
            {"controller": self.name}
            if self.h_min is None
            else {"controller": self.name, "bounds_model": {"h_min": self.h_min, "v_max": 9.0}}
        )


def test_lag_step_response_matches_the_closed_form() -> None:
    """A step command a_c through a first-order lag τ: a(t) = a_c (1 − e^{−t/τ}) and
    v(t) = v0 + a_c (t − τ (1 − e^{−t/τ})) (SI), at every sample of the CVODES plant."""
    tau, a_c, v0 = 0.37, 1.9, 7.3  # s, m/s², m/s
    ev = _ev(lag_s=tau)
    r = ClosedLoop(ConstantSpeed(2.5), [_Step(a_c / 3.0, 0.05)], ev).run([4.4], [v0 / 6.0], 1.5)
    t = r.t * 2.0
    a = r.accel[:, 0] * 3.0
    v = r.speed[:, 0] * 6.0
    np.testing.assert_allclose(a, a_c * (1 - np.exp(-t / tau)), atol=1e-7)
    np.testing.assert_allclose(v, v0 + a_c * (t - tau * (1 - np.exp(-t / tau))), atol=1e-7)


def test_jerk_limit_ramps_then_follows_the_stated_small_lag() -> None:
    """Jerk limit j without a lag: the actuator has τ = JERK_ONLY_LAG_S; from a = 0 it ramps at j while
    (a_c − a)/τ > j, i.e. until t1 = (a_c − j τ)/j, then a = a_c − j τ e^{−(t − t1)/τ} (closed form)."""
    j, a_c = 2.3, 3.1
    ev = _ev(jerk_max_mps3=j)
    tau = ev.limits.actuator_tau_s
    r = ClosedLoop(ConstantSpeed(2.5), [_Step(a_c / 3.0, 0.05)], ev).run([6.4], [1.2], 1.5)
    t, a = r.t * 2.0, r.accel[:, 0] * 3.0
    t1 = (a_c - j * tau) / j
    ref = np.where(t <= t1, j * t, a_c - j * tau * np.exp(-(t - t1) / tau))
    np.testing.assert_allclose(a, ref, atol=1e-6)
    jerk = np.diff(a) / np.diff(t)
    assert jerk.max() <= j * (1 + 1e-6)


def test_lag_cascade_equals_cvodes() -> None:
    """A law through a lag (an actuator state in the compiled cascade too) against the CVODES plant."""
    ev = _ev(lag_s=0.45, a_min_mps2=-6.0)
    res = {
        m: simulate_platoon(ConstantSpeed(1.3), [LAW, LAW], [1.1, 2.2], [3.0, 2.6], 8.0, ev=ev, dt_out=0.05, method=m)
        for m in ("cascade", "cvodes")
    }
    a, b = res["cascade"], res["cvodes"]
    assert a.status == b.status == "ok"
    for name in ("gap", "speed", "accel", "omega", "heat_J"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=2e-6, atol=2e-6, err_msg=name)
    # the lag is real: the realised acceleration at t = 0 is 0, not the law's
    assert a.accel[0, 0] == 0.0 and abs(float(LAW.accel(1.1, 3.0, 1.3))) > 0.5


def test_top_speed_is_held() -> None:
    """a = 2.2 m/s² from 20 m/s with v_max = 23.5 m/s: v = min(v0 + a t, v_max), position exact."""
    a_c, v0, vmax = 2.2, 20.0, 23.5
    ev = _ev(v_max_mps=vmax)
    r = ClosedLoop(ConstantSpeed(4.5), [_Step(a_c / 3.0, 0.05)], ev).run([20.0], [v0 / 6.0], 2.5)
    t, v = r.t * 2.0, r.speed[:, 0] * 6.0
    np.testing.assert_allclose(v, np.minimum(v0 + a_c * t, vmax), atol=1e-6)
    t1 = (vmax - v0) / a_c
    x = np.where(t <= t1, v0 * t + a_c * t**2 / 2, v0 * t1 + a_c * t1**2 / 2 + vmax * (t - t1))
    np.testing.assert_allclose(4.5 * 6.0 * t - (r.gap[:, 0] - 20.0) * 12.0, x, atol=1e-5)
    assert np.all(r.accel[t > t1 + 0.1, 0] == 0.0)  # what was really applied is recorded


def test_commanded_acceleration_is_saturated_and_recorded() -> None:
    """A controller asking for 9 m/s² gets a_max = 4: the recorded acceleration and the speed say so."""
    r = ClosedLoop(ConstantSpeed(4.0), [_Step(9.0 / 3.0, 0.05)], _ev()).run([20.0], [2.0], 1.0)
    assert np.all(r.accel[:, 0] == pytest.approx(4.0 / 3.0))
    np.testing.assert_allclose(r.speed[:, 0], 2.0 + 4.0 / 3.0 * r.t, atol=1e-8)


# ----------------------------------------------------------------------------- the paper's laws unchanged
#: ω of Table 1's proposed-law platoon before vehicles had limits (main at 94e3a16, cascade, rtol = atol = 1e-10)
TABLE1_OMEGA = [1.7642799527992934, 0.9759431121925576, 0.562046570337038, 0.41310370426343745, 0.3409005445119292]


def test_unlimited_reproduces_table1_exactly() -> None:
    from aev_ocp.scenarios import load_scenario

    s = load_scenario("table1")
    assert s.ev.limits == UNLIMITED  # the paper's scenario states it
    r = simulate_platoon(s.leader, [Proposed()] * 5, list(s.gaps0), list(s.speeds0), s.t_end, ev=s.ev, method="cascade")
    assert r.omega[-1].tolist() == TABLE1_OMEGA
    # limits that never bind give the same numbers to the integration tolerance (the limits' expressions change
    # nothing where inactive; the cascade's steps differ: with limits, ∫jerk² is not in its error test)
    wide = EVParams(limits=VehicleLimits(a_min_mps2=-1e3, a_max_mps2=1e3, v_max_mps=1e3))
    w = simulate_platoon(s.leader, [Proposed()] * 5, list(s.gaps0), list(s.speeds0), s.t_end, ev=wide, method="cascade")
    np.testing.assert_allclose(w.omega[-1], TABLE1_OMEGA, rtol=2e-7)


# ----------------------------------------------------------------------------- status 'violated'
def test_floor_violation_gives_status_violated_and_one_warning() -> None:
    """A controller that publishes a hard floor h_min and goes below it: status 'violated', one warning, the
    vehicle's metrics say so, the run is still comparable (it ran to the end)."""
    from aev_ocp.metrics import comparability

    h_min = 1.35
    loop = ClosedLoop(ConstantSpeed(1.0), [_Step(0.2, 0.1, h_min=h_min)], _ev())
    with pytest.warns(RuntimeWarning, match="violated its gap floor") as rec:
        r = loop.run([2.0], [1.0], 4.0)
    assert len([w for w in rec if "gap floor" in str(w.message)]) == 1
    assert r.status == "violated" and not r.events
    # gap: 2 − 0.1 t², below 1.35 from t = √6.5 = 2.55: the first sample below it
    e = r.violations[0]
    assert e.time == pytest.approx(2.6, abs=1e-9) and e.time_s == pytest.approx(5.2, abs=1e-8)
    m = r.metrics()[0]
    assert m["status"] == "violated" and m["gap_violations"] == int(np.sum(r.gap[1:, 0] < h_min - 1e-9)) > 0
    assert comparability(m, m)["comparable"]
    ok = ClosedLoop(ConstantSpeed(1.0), [_Step(0.2, 0.1, h_min=0.3)], _ev()).run([2.0], [1.0], 4.0)
    assert ok.status == "ok" and not ok.violations


# ----------------------------------------------------------------------------- [limits] table and saved runs
def test_limits_table_validated_and_round_tripped(tmp_path: Any) -> None:
    from aev_ocp.saved import load, save_output
    from aev_ocp.scenarios import ScenarioError, load_scenario

    text = tmp_path / "s.toml"
    base = (
        'name = "lim"\n[leader]\nkind = "constant"\nv = 1.2\n[platoon]\nfollowers = 1\nlaw = "proposed"\n'
        "gap0_first = 2.3\nspeed0 = 1.2\n[simulation]\nt_end = 2.0\n"
    )
    text.write_text(base + "[limits]\na_min_mps2 = -6.5\nlag_s = 0.3\njerk_max_mps3 = 3.5\n")
    s = load_scenario(text)
    assert s.ev.limits == VehicleLimits(a_min_mps2=-6.5, lag_s=0.3, jerk_max_mps3=3.5)
    for bad, where in (
        ("a_min_mps2 = 1.5", "limits.a_min_mps2"),
        ("lag_s = -0.1", "limits.lag_s"),
        ("enabled = 0", "limits.enabled"),
        ("vmax = 3.0", "limits.vmax"),
    ):
        text.write_text(base + f"[limits]\n{bad}\n")
        with pytest.raises(ScenarioError, match=where.replace(".", r"\.")):
            load_scenario(text)
    r = s.run()["proposed"]
    save_output(tmp_path / "out", "simulate", {"proposed": r})
    back = load(tmp_path / "out")
    assert back.ev.limits == s.ev.limits


def test_collision_round_trips_with_its_si_fields(tmp_path: Any) -> None:
    from aev_ocp.saved import load, save_output

    r = simulate_platoon(ConstantSpeed(0.0), [Proposed()], [0.8], [4.0], 5.0, method="cvodes")
    save_output(tmp_path / "o", "simulate", {"p": r})
    e = load(tmp_path / "o").events[0]
    assert (e.time_s, e.impact_speed_mps) == (r.events[0].time_s, r.events[0].impact_speed_mps)


# ----------------------------------------------------------------------------- the MPC's prediction model
def test_traffic_a_bounds_default_to_the_vehicle_limits() -> None:
    from aev_ocp.ocp.traffic import TrafficParams, traffic_bounds

    ev = _ev(a_min_mps2=-6.9, a_max_mps2=3.3)
    b = traffic_bounds(ev, TrafficParams())
    assert (b.a_min, b.a_max) == (pytest.approx(-6.9 / 3.0), pytest.approx(3.3 / 3.0))
    b = traffic_bounds(ev, TrafficParams(a_min_mps2=-5.1))
    assert b.a_min == pytest.approx(-5.1 / 3.0)
    with pytest.raises(ParameterError, match=r"a_min_mps2 = -7\.2 .*VehicleLimits\.a_min_mps2 = -6\.9"):
        traffic_bounds(ev, TrafficParams(a_min_mps2=-7.2))
    with pytest.raises(ParameterError, match=r"a_max_mps2 = 3\.8 .*VehicleLimits\.a_max_mps2 = 3\.3"):
        traffic_bounds(ev, TrafficParams(a_max_mps2=3.8))
    old = traffic_bounds(dataclasses.replace(ev, limits=UNLIMITED), TrafficParams())  # no limits: as before
    assert (old.a_min, old.a_max) == (pytest.approx(-7.5 / 3.0), pytest.approx(5.0 / 3.0))


def test_traffic_prediction_knows_the_lag() -> None:
    """The MPC's predicted speeds under its planned commands match the plant's (CVODES, the same commands
    replayed through the lag) when the prediction has the actuator state, and miss them without it."""
    from aev_ocp.mpc import MPCSettings
    from aev_ocp.mpc.controller import MPCController

    lagged = _ev(lag_s=0.6)
    s = MPCSettings(solver="ipopt", N=12)
    z0 = np.array([1.4, 1.9, 0.0, 0.0, 0.8])
    vl = np.full(12, 1.3)
    errs = {}
    for tag, ev_model in (("with", lagged), ("without", _ev())):
        ctl = MPCController(s, ev_model)
        assert ("a_act" in ctl.problem.state_names) == (tag == "with")
        sol = ctl.solve(z0, vl, vl, own={"a_prev": 0.0, "a_act": 0.0})
        assert sol.success
        seq = ControlSequence(tuple(float(a) for a in sol.a), s.dt)
        r = ClosedLoop(ConstantSpeed(1.3), [seq], lagged).run([z0[0]], [z0[1]], 12 * s.dt)
        errs[tag] = float(np.max(np.abs(r.speed[:, 0] - sol.X[1])))
    assert errs["with"] < 2e-4 < 0.02 < errs["without"]


def test_braking_to_a_stop_with_a_never_reversing_command_is_held_at_a_crawl() -> None:
    """A controller that brakes to a stop with a = -v/dt (never reversing over its step) leaves v decaying
    geometrically over its steps (1e-86, 1e-144, ...): CVODES failed (CV_TOO_MUCH_WORK) at such speeds in the safety
    suite. At or below V_STOP the brakes hold the car: every step integrates, the speed stops decaying there."""
    from aev_ocp.models.actuator import V_STOP
    from aev_ocp.models.leader import BrakingLeader
    from aev_ocp.plant import Plant

    plant = Plant(BrakingLeader.from_si(0.0, -3.0, 0.0, UNITS), [None], _ev())
    x = np.array([0.0435, 0.37, -0.0166, -0.00164, 0.802])
    dt, speeds = 0.1, []
    for k in range(40):
        res = plant.integrator(x0=x, p=np.array([4.8 + k * dt, dt, -x[1] / dt]))
        x = np.asarray(res["xf"]).ravel()
        speeds.append(x[1])
    assert 0.0 <= speeds[-1] <= V_STOP and speeds[-1] > 1e-30  # held at a crawl, not decayed to round-off
    assert speeds[-1] == speeds[-2]

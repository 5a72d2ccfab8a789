"""The closed-loop step core (aev_ocp.loop): one check, one conditioning, one safety layer, one saturation for every
simulator (platoon, ring, SUMO), and the events every simulator reports.

Independent references: the first-order filter's closed-form step response, the jerk limit's bound on, inside and
outside it, the braking-distance condition evaluated on a fine grid over the step (not the bound's own peak
formula), and the three loops against each other and against the stages computed by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.control import ClosedLoop, SampledLaw
from aev_ocp.loop import (
    NO_STAGES,
    PRODUCTION_ACC,
    Command,
    CommandStages,
    Observation,
    VehicleStep,
    check_command,
    stages_for,
)
from aev_ocp.models.carfollowing import OVM, Proposed
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.params import CellParams, EVParams, ParameterError, Units, VehicleLimits
from aev_ocp.models.safety_bound import SafetyParams, effective_reaction_s, safe_acceleration_mps2
from aev_ocp.sumo import sumo_available

needs_sumo = pytest.mark.skipif(not sumo_available(), reason="SUMO is not installed (pip install 'aev_ocp[sumo]')")

UNITS = Units(length_m=12.0, speed_mps=6.0)  # 2 s per model time unit, 3 m/s² per model acceleration unit
WIDE = VehicleLimits(a_min_mps2=-9.0, a_max_mps2=7.0)


def _step(stages: CommandStages, dt_s: float = 0.13, limits: VehicleLimits = WIDE) -> VehicleStep:
    return VehicleStep("test", "vehicle 1", UNITS, limits, stages, UNITS.time_from_si(dt_s))


# ----------------------------------------------------------------------------- conditioning
@pytest.mark.parametrize("tau_s, dt_s, u_mps2", [(0.37, 0.13, 2.19), (0.5, 0.1, -3.7), (1.3, 0.088, 0.61)])
def test_filter_follows_its_closed_form_step_response(tau_s: float, dt_s: float, u_mps2: float) -> None:
    """A step of u from rest: the applied command after k + 1 instants is u (1 − e^(−(k+1) dt/τ)) (the exact
    first-order lag sampled at the ends of the steps); a filter that forgets its state fails this."""
    s = _step(CommandStages(filter_s=tau_s), dt_s)
    u = UNITS.accel_from_si(u_mps2)
    got = np.array([UNITS.accel_to_si(s.apply(u, 5.0, 1.0, 1.0)) for _ in range(25)])
    k = np.arange(25)
    np.testing.assert_allclose(got, u_mps2 * (1 - np.exp(-(k + 1) * dt_s / tau_s)), rtol=1e-12, atol=1e-12)
    assert s.counts()["filtered_steps"] == 25 and s.counts()["saturated_steps"] == 0


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_jerk_limit_on_inside_and_outside_its_bound(sign: float) -> None:
    """j = 1.7 m/s³, dt = 0.13 s: a change of 0.4 j dt passes as it is, exactly j dt passes as it is (on the bound),
    3 j dt is cut to j dt in its own direction (a limit with the wrong sign fails one of the two directions)."""
    j, dt_s = 1.7, 0.13
    step = j * dt_s
    for factor, expect, limited in ((0.4, 0.4, 0), (1.0, 1.0, 0), (3.0, 1.0, 1)):
        s = _step(CommandStages(jerk_max_mps3=j), dt_s)
        a0 = UNITS.accel_from_si(0.9)
        s.apply(a0, 5.0, 1.0, 1.0)  # from rest: 0.9 m/s² is > j dt, so the first step is cut to j dt
        assert UNITS.accel_to_si(s.a_prev) == pytest.approx(step, rel=1e-12)
        got = s.apply(UNITS.accel_from_si(step + sign * factor * step), 5.0, 1.0, 1.0)
        assert UNITS.accel_to_si(got) == pytest.approx(step + sign * expect * step, rel=1e-12)
        assert s.counts()["jerk_limited_steps"] == 1 + limited


def test_limits_saturate_after_the_stages_and_are_counted() -> None:
    """Saturation to [a_min, a_max] on, inside and outside: −9 (on) and 6.99 (inside) pass, ±20 are cut."""
    s = _step(NO_STAGES)
    for a_si, out in ((-9.0, -9.0), (6.99, 6.99), (20.0, 7.0), (-20.0, -9.0)):
        assert UNITS.accel_to_si(s.apply(UNITS.accel_from_si(a_si), 5.0, 1.0, 1.0)) == pytest.approx(out, rel=1e-12)
    assert s.counts()["saturated_steps"] == 2


def test_unconditioned_commands_pass_bit_for_bit() -> None:
    """Without stages and inside the limits the applied command is the controller's, the same float (what keeps
    the paper's runs bit-identical)."""
    s = VehicleStep("x", "vehicle 1", Units(), VehicleLimits(enabled=False), NO_STAGES, 0.1)
    for a in (0.1234567891234, -3.3e-7, 17.25):
        assert s.apply(a, 1.0, 1.0, 1.0) == a


def test_default_conditioning_is_for_laws_under_realistic_sensors_only() -> None:
    lim = VehicleLimits()
    assert stages_for(lim, law=True, sensed=True) == PRODUCTION_ACC
    assert PRODUCTION_ACC.filter_s == 0.5 and PRODUCTION_ACC.jerk_max_mps3 == 5.0
    for law, sensed in ((True, False), (False, True), (False, False)):
        assert stages_for(lim, law=law, sensed=sensed) == NO_STAGES
    off = VehicleLimits(command_filter_s=0.0, command_jerk_max_mps3=0.0)
    assert stages_for(off, law=True, sensed=True) == NO_STAGES
    mine = stages_for(VehicleLimits(command_filter_s=0.8, safety_layer=True), law=False, sensed=False)
    assert mine.filter_s == 0.8 and mine.jerk_max_mps3 == 0.0 and mine.safety == SafetyParams.from_limits(lim)
    assert mine.label() == "filter 0.8 s, safety layer" and NO_STAGES.label() == "none"
    with pytest.raises(ParameterError, match="command_filter_s"):
        VehicleLimits(command_filter_s=-0.1)
    with pytest.raises(ParameterError, match="CommandStages.jerk_max_mps3"):
        CommandStages(jerk_max_mps3=math.nan)


# ----------------------------------------------------------------------------- the safety stage
def _condition_holds_over_step(
    h: float, v: float, vl: float, a: float, dt: float, p: SafetyParams, b_lead: float
) -> bool:
    """The braking-distance condition at 401 times over the step (the ego holds a, stopping at 0; the lead brakes
    at b_lead from now on), checked on the grid, not with the bound's peak formula."""
    t = np.linspace(0.0, dt, 401)
    t_stop = v / -a if a < 0 and v > 0 else math.inf
    te = np.minimum(t, t_stop) if a < 0 else t
    x_e, v_e = v * te + 0.5 * a * te**2, np.maximum(v + a * te, 0.0)
    tl = np.minimum(t, vl / b_lead)
    x_l, v_l = h + vl * tl - 0.5 * b_lead * tl**2, np.maximum(vl - b_lead * tl, 0.0)
    t_r, b = effective_reaction_s(p), p.ego_brake_mps2
    P_e = x_e + v_e * t_r + v_e**2 / (2 * b)
    P_l = x_l + v_l**2 / (2 * b_lead)
    return bool(np.all(P_e <= P_l - p.standstill_gap_m + 1e-7))


@settings(max_examples=150, deadline=None)
@given(
    h=st.floats(2.5, 90.0),
    v=st.floats(0.0, 36.0),
    vl=st.floats(0.0, 36.0),
    a_cmd=st.floats(-9.0, 7.0),
    dt=st.sampled_from([0.05, 0.1, 0.2]),
)
def test_safety_stage_never_lets_the_condition_fail_over_a_step(
    h: float, v: float, vl: float, a_cmd: float, dt: float
) -> None:
    """Wherever the braking-distance condition holds now, the command the safety stage lets through keeps it over
    the whole step, whatever the controller asked (a stage skipped lets a_cmd = a_max through and fails)."""
    p = SafetyParams.from_limits(WIDE)
    assume_ok = _condition_holds_over_step(h, v, vl, p.a_min_mps2, 1e-9, p, p.lead_brake_mps2)
    if not assume_ok:
        return
    s = VehicleStep("x", "vehicle 1", UNITS, WIDE, CommandStages(safety=p), UNITS.time_from_si(dt))
    U = UNITS
    a = U.accel_to_si(s.apply(U.accel_from_si(a_cmd), U.length_from_si(h), U.speed_from_si(v), U.speed_from_si(vl)))
    assert a <= a_cmd + 1e-12
    assert _condition_holds_over_step(h, v, vl, a, dt, p, p.lead_brake_mps2)
    safe = safe_acceleration_mps2(h, v, vl, dt, p)
    assert s.counts()["safety_limited_steps"] == int(safe < a_cmd)


def test_safety_stage_in_the_closed_loop_keeps_a_reckless_controller_off_a_standing_car() -> None:
    """A controller commanding a_max at a standing leader 60 m ahead collides bare and stops short of it with the
    safety layer declared in the limits (its steps counted); the layer off changes nothing else."""
    ev = EVParams(units=UNITS)
    h0 = UNITS.length_from_si(60.0)
    bare = ClosedLoop(ConstantSpeed(0.0), [Reckless(4.0, dt_s=0.1)], ev).run([h0], [UNITS.speed_from_si(20.0)], 10.0)
    assert bare.status == "collision"
    safe_ev = dataclasses.replace(ev, limits=VehicleLimits(safety_layer=True))
    r = ClosedLoop(ConstantSpeed(0.0), [Reckless(4.0, dt_s=0.1)], safe_ev).run([h0], [UNITS.speed_from_si(20.0)], 10.0)
    assert r.status == "ok" and float(np.min(r.gap)) * UNITS.length_m >= SafetyParams().standstill_gap_m - 1e-6
    st_ = r.meta["command_stages"][0]
    assert st_["safety_limited_steps"] > 0 and st_["conditioning"] == "safety layer"
    assert r.solver_stats[0]["safety_limited_steps"] == st_["safety_limited_steps"]


# ----------------------------------------------------------------------------- bad commands, every loop
class Reckless:
    """A user controller: a [m/s²] (or ``bad``, returned as given) every dt_s, recording what it saw (obs.a_prev:
    the command the loop applied last)."""

    name = "reckless"

    def __init__(self, a_mps2: float = 3.0, dt_s: float = 0.1, units: Units = UNITS, bad: object = None) -> None:
        self.a, self.units, self.bad = a_mps2, units, bad
        self.dt = float(units.time_from_si(dt_s))
        self.seen: list[float] = []

    def reset(self) -> None:
        self.seen = []

    def command(self, obs: Observation) -> object:
        self.seen.append(float(self.units.accel_to_si(obs.a_prev)))
        if self.bad is not None:
            return self.bad
        return Command(float(self.units.accel_from_si(self.a)))

    def describe(self) -> dict:
        return {"controller": self.name}


BAD = [Command(math.nan), Command(math.inf), Command(-math.inf), Command(None), 0.3, "fast"]  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", BAD, ids=["nan", "inf", "-inf", "None", "float", "str"])
def test_every_loop_refuses_a_bad_command_naming_controller_vehicle_time_and_field(bad: object) -> None:
    with pytest.raises(
        ParameterError, match=r"closed loop: controller 'reckless' of vehicle 1 returned .* at t = 0: .*Command\.a"
    ):
        ClosedLoop(ConstantSpeed(1.3), [Reckless(bad=bad)], EVParams(units=UNITS)).run([4.5], [1.3], 1.0)
    from aev_ocp.ring.simulate import RingRoad, RingSimulator, uniform_flow

    ring = RingRoad(200.0, (Reckless(bad=bad), OVM(), OVM()), ev=EVParams(units=UNITS))
    with pytest.raises(
        ParameterError, match=r"ring: controller 'reckless' of vehicle 1 returned .* at t = 0: .*Command\.a"
    ):
        RingSimulator(ring, None).run(uniform_flow(ring, speed_mps=5.0), 2.0)


def test_check_command_takes_numpy_scalars_and_refuses_bools() -> None:
    assert check_command(Command(np.float32(0.25)), "c", "vehicle 1", 0.0, UNITS, "x").a == np.float32(0.25)
    assert check_command(Command(np.array([-0.5])), "c", "vehicle 1", 0.0, UNITS, "x").a == -0.5  # type: ignore[arg-type]
    with pytest.raises(
        ParameterError, match=r"x: controller 'c' of vehicle 'v.2' returned Command\(a = True\) at t = 1.5"
    ):
        check_command(Command(True), "c", "vehicle 'v.2'", 1.5, UNITS, "x")


# ----------------------------------------------------------------------------- one core, three loops
SEQ_MPS2 = (3.0, 6.0, 6.0, 6.0, -2.0, -9.0, -9.0, 1.0, 0.5, 0.0, 2.0, -1.0)


class Sequence_:
    """Commands SEQ_MPS2 in turn (independent of what it sees), recording obs.a_prev [m/s²]."""

    name = "sequence"

    def __init__(self, units: Units, dt_s: float = 0.1) -> None:
        self.units, self.dt = units, float(units.time_from_si(dt_s))
        self.seen: list[float] = []

    def reset(self) -> None:
        self.seen = []

    def command(self, obs: Observation) -> Command:
        self.seen.append(float(self.units.accel_to_si(obs.a_prev)))
        return Command(float(self.units.accel_from_si(SEQ_MPS2[min(len(self.seen) - 1, len(SEQ_MPS2) - 1)])))

    def describe(self) -> dict:
        return {"controller": self.name}


LOOP_LIMITS = VehicleLimits(command_filter_s=0.3, command_jerk_max_mps3=40.0)


def _expected_applied() -> list[float]:
    """The applied commands by hand: filter (τ = 0.3 s, dt = 0.1 s), jerk (4 m/s² per step), then [−8, 4]."""
    alpha, out, prev = 1 - math.exp(-0.1 / 0.3), [], 0.0
    for u in SEQ_MPS2:
        a = prev + alpha * (u - prev)
        a = min(max(a, prev - 4.0), prev + 4.0)
        prev = min(max(a, -8.0), 4.0)
        out.append(prev)
    return out


def _platoon_applied() -> list[float]:
    ev = EVParams(limits=LOOP_LIMITS)
    c = Sequence_(ev.units)
    ClosedLoop(ConstantSpeed(3.0), [c], ev).run([8.0], [3.0], 0.65)  # 13 steps of 0.1 s (2 s per model time)
    return c.seen[1:]


def _ring_applied() -> list[float]:
    from aev_ocp.ring.simulate import RingRoad, RingSimulator, uniform_flow

    ev = EVParams(limits=LOOP_LIMITS)
    c = Sequence_(ev.units)
    ring = RingRoad(600.0, (c, OVM(), OVM()), ev=ev)
    RingSimulator(ring, None).run(uniform_flow(ring, speed_mps=15.0), 1.3)
    return c.seen[1:]


def test_the_platoon_and_the_ring_apply_the_same_commands_as_the_core_by_hand() -> None:
    """The same controller (an open-loop sequence past both limits) through the platoon's and the ring's loops: the
    commands each applied (as the controller saw them next) are the hand-computed stages, to round-off."""
    want = _expected_applied()
    for got in (_platoon_applied(), _ring_applied()):
        assert len(got) == len(want) == 12
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def sequence_controller(ev: EVParams) -> Sequence_:
    """The SUMO 'module:function' form of Sequence_ (the run's units)."""
    SUMO_SEEN.append(Sequence_(ev.units))
    return SUMO_SEEN[-1]


def nan_controller(ev: EVParams) -> Reckless:
    return Reckless(units=ev.units, bad=Command(math.nan))


def float_controller(ev: EVParams) -> Reckless:
    return Reckless(units=ev.units, bad=0.3)


SUMO_SEEN: list[Sequence_] = []


def _sumo_doc(controller: str, t_end_s: float = 1.4, **limits: object) -> dict:
    return {
        "limits": limits,
        "sumo": {
            "network": "ring",
            "t_end_s": t_end_s,
            "step_s": 0.1,
            "controller": controller,
            "share": 0.0,
            "ids": ["ring.3"],
        },
    }


@needs_sumo
def test_sumo_applies_the_same_commands_as_the_other_loops() -> None:
    from aev_ocp.sumo.run import run_sumo
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    SUMO_SEEN.clear()
    lim = {"command_filter_s": 0.3, "command_jerk_max_mps3": 40.0}
    run = run_sumo(parse_sumo_scenario(_sumo_doc(f"{__name__}:sequence_controller", **lim)))
    got = SUMO_SEEN[-1].seen[1:13]
    assert len(got) == 12
    np.testing.assert_allclose(got, _expected_applied()[: len(got)], rtol=1e-9, atol=1e-9)  # SI round trips
    np.testing.assert_allclose(got, _platoon_applied()[: len(got)], rtol=1e-9, atol=1e-9)
    meta = run.vehicles["ring.3"].meta["command_stages"][0]
    assert meta["conditioning"] == "filter 0.3 s, jerk <= 40 m/s^3" and meta["saturated_steps"] >= 1


@needs_sumo
@pytest.mark.parametrize("fn, got", [("nan_controller", r"Command\(a = nan\)"), ("float_controller", "float 0.3")])
def test_sumo_refuses_a_bad_command(fn: str, got: str) -> None:
    from aev_ocp.sumo.run import run_sumo
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    with pytest.raises(
        ParameterError, match=rf"sumo: controller 'reckless' of vehicle 'ring.3' returned {got} at t = .*Command\.a"
    ):
        run_sumo(parse_sumo_scenario(_sumo_doc(f"{__name__}:{fn}")))


# ----------------------------------------------------------------------------- conditioned laws, realistic sensors
def test_laws_under_realistic_sensors_are_conditioned_by_default_and_can_be_switched_off() -> None:
    from aev_ocp.estimation.sensors import Sensors

    ev = EVParams()
    run = lambda e: ClosedLoop(ConstantSpeed(1.5), [Proposed()], e, sensors=Sensors(seed=4)).run([1.4], [1.2], 3.0)  # noqa: E731
    on = run(ev)
    assert on.meta["command_stages"][0]["conditioning"] == "filter 0.5 s, jerk <= 5 m/s^3"
    assert on.meta["command_stages"][0]["filtered_steps"] == 30
    off = run(dataclasses.replace(ev, limits=VehicleLimits(command_filter_s=0.0, command_jerk_max_mps3=0.0)))
    assert off.meta["command_stages"][0]["conditioning"] == "none"
    assert not np.array_equal(on.accel, off.accel)
    explicit = ClosedLoop(ConstantSpeed(1.5), [SampledLaw(Proposed(), 0.1)], ev, stages=NO_STAGES).run(
        [1.4], [1.2], 3.0
    )
    assert explicit.meta["command_stages"][0]["conditioning"] == "none"


# ----------------------------------------------------------------------------- events in every simulator
def test_a_current_beyond_the_cell_limit_is_an_event_in_the_platoon_and_the_ring() -> None:
    """A cell whose limit (2.1 A; the runs reach 3.2 A and, on the ring, 2.4 A for the AEV and 1.9 A for the humans) is exceeded: one event per vehicle at the first sample beyond it, with the
    largest |I|; the run goes on and its status is not ok. Without vehicle limits (the paper's model): none."""
    from aev_ocp.ring.simulate import RingRoad, RingSimulator, uniform_flow

    ev = EVParams(cell=CellParams(max_current_A=2.1))
    r = ClosedLoop(ConstantSpeed(2.0), [Reckless(2.0, units=ev.units)], ev).run([3.0], [1.0], 3.0)
    I = np.abs(r.current_A[:, 0])
    (e,) = [e for e in r.violations if e.kind == "current_limit"]
    k = int(np.flatnonzero(I > 2.1)[0])
    assert e.vehicle == 0 and e.time == r.t[k] and f"{I.max():.4g} A" in e.message
    assert r.status == "violated" and r.t[-1] == pytest.approx(3.0)
    ring = RingRoad(300.0, (Reckless(2.5, units=ev.units), OVM(), OVM()), ev=ev)
    rr = RingSimulator(ring, None).run(uniform_flow(ring, speed_mps=3.0), 3.0)
    ev_ring = [e for e in rr.sim.violations if e.kind == "current_limit"]
    assert [e.vehicle for e in ev_ring] == [0] and rr.status == "violated" and ev_ring[0].time_s is not None
    unlimited = dataclasses.replace(ev, limits=VehicleLimits(enabled=False))
    r0 = ClosedLoop(ConstantSpeed(2.0), [Reckless(2.0, units=ev.units)], unlimited).run([3.0], [1.0], 3.0)
    assert r0.status == "ok" and np.abs(r0.current_A).max() > 2.1


@needs_sumo
def test_sumo_merge_reports_its_lane_end_stop_emergency_stop_and_current_breach() -> None:
    """The shipped merge at share 0.5 (issue 34): a controlled car reaches the end of the acceleration lane and
    SUMO stops it from 11.6 m/s to 0 in one 0.1 s step; each is an event with time, vehicle and value, the run's
    status is not ok and the fleet table counts them."""
    from aev_ocp.sumo.run import run_sumo
    from aev_ocp.sumo.scenario import load_sumo_scenario

    sc = load_sumo_scenario("sumo_merge")
    run = run_sumo(dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, share=0.5, t_end_s=176.0)))
    ev = {(e["kind"], e["vehicle"]): e for e in run.events if e["kind"] != "left_network"}
    brake = ev[("emergency_braking", "ramp.21")]
    assert brake["t_s"] == pytest.approx(174.7) and brake["value"] < -100.0 and brake["controlled"]
    stop = ev[("lane_end_stop", "ramp.21")]
    assert stop["t_s"] == pytest.approx(174.7) and stop["value"] == pytest.approx(-brake["value"] * 0.1, rel=1e-9)
    cur = ev[("current_limit", "ramp.21")]
    assert cur["value"] > 46.0 and cur["t_s"] < 174.7
    assert run.status == "emergency_braking"
    ft = run.fleet_totals()["controlled"]
    assert ft["emergency_braking_events"] >= 1 and ft["lane_end_stop_events"] >= 1 and ft["current_limit_events"] >= 1
    assert run.vehicles["ramp.21"].status == "violated"


def zero_dt_controller(ev: EVParams) -> Reckless:
    c = Reckless(units=ev.units)
    c.dt = 0.0
    return c


@needs_sumo
def test_sumo_refuses_a_user_controller_with_a_bad_dt_or_a_broken_module(tmp_path, monkeypatch) -> None:  # noqa: ANN001
    """Checked as the platoon's loop checks a controller: dt = 0 is refused naming the key and dt; a module with a
    syntax error is bad input naming the key, not an internal error."""
    from aev_ocp.sumo import SumoError
    from aev_ocp.sumo.run import make_controller_factory
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    _, factory = make_controller_factory(parse_sumo_scenario(_sumo_doc(f"{__name__}:zero_dt_controller")))
    assert factory is not None
    with pytest.raises(SumoError, match=r"sumo.controller = '.*:zero_dt_controller': its controller's dt = 0.0 is not"):
        factory()
    (tmp_path / "broken_ctrl_mod.py").write_text("def make(ev):\n    return (\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(SumoError, match=r"sumo.controller = 'broken_ctrl_mod:make': cannot import it \(SyntaxError"):
        make_controller_factory(parse_sumo_scenario(_sumo_doc("broken_ctrl_mod:make")))


def test_safety_layer_declared_in_the_limits_keeps_a_ring_car_off_its_leader() -> None:
    """The same stage on the ring: a controller commanding 3 m/s² behind humans hits its leader bare, and with
    ``safety_layer`` in the ring's limits keeps at least the layer's standstill gap (its steps counted)."""
    from aev_ocp.ring.simulate import RingRoad, RingSimulator, uniform_flow

    out = {}
    for on in (False, True):
        ev = EVParams(limits=VehicleLimits(safety_layer=on))
        ring = RingRoad(120.0, (Reckless(3.0, units=ev.units), OVM(), OVM(), OVM()), ev=ev)
        out[on] = RingSimulator(ring, None).run(uniform_flow(ring, speed_mps=4.0), 20.0)
    assert out[False].status == "collision"
    r = out[True]
    assert r.status == "ok" and float(r.gap_m[:, 0].min()) >= SafetyParams().standstill_gap_m - 1e-6
    assert r.sim.meta["command_stages"][0]["safety_limited_steps"] > 0 and r.sim.meta["command_stages"][1] is None


@needs_sumo
def test_sumo_laws_count_their_saturated_steps_without_stages() -> None:
    """A law in SUMO without stages is saturated by the loop's limits alone; its steps and saturations are still
    counted (the proposed law at a_max = 0.2 m/s² from a standing start saturates at the start)."""
    from aev_ocp.sumo.run import run_sumo
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    doc = _sumo_doc("proposed", 2.0, a_max_mps2=0.2)
    run = run_sumo(parse_sumo_scenario(doc))
    st_ = run.vehicles["ring.3"].meta["command_stages"][0]
    assert st_["conditioning"] == "none" and st_["steps"] == 20 and st_["saturated_steps"] >= 1
    a = np.diff(run.vehicles["ring.3"].speed[:, 0]) * run.vehicles["ring.3"].units.speed_mps / 0.1
    assert a.max() <= 0.2 + 1e-9


@pytest.mark.parametrize(
    ("kw", "ok"),
    [
        ({"command_filter_s": 4.97}, True),
        ({"command_filter_s": 5.0}, True),  # on the bound
        ({"command_filter_s": 5.03}, False),
        ({"command_filter_s": 1e300}, False),  # ran with status ok before: the controller silently ignored
        ({"command_jerk_max_mps3": 0.0}, True),  # off
        ({"command_jerk_max_mps3": 0.1}, True),  # on the bound
        ({"command_jerk_max_mps3": 0.0997}, False),
        ({"command_jerk_max_mps3": 1e-300}, False),  # ran with status ok before
    ],
)
def test_command_stages_refuse_a_filter_or_jerk_limit_that_ignores_the_controller(kw: dict, ok: bool) -> None:
    if ok:
        lim = VehicleLimits(**kw)
        assert getattr(lim, next(iter(kw))) == next(iter(kw.values()))
    else:
        with pytest.raises(ParameterError, match=next(iter(kw))):
            VehicleLimits(**kw)

"""Where the plant locates an event whose threshold has a nonzero offset (the state-of-charge bounds), against
SciPy's ``solve_ivp`` event location on the same model equations written out here (model guide §2, §6)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import aev_ocp.plant as plant_mod
from aev_ocp.models.ego import battery_side
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.params import EVParams
from aev_ocp.plant import EVENT_RULES, EventRule, Plant
from aev_ocp.results import Event

EV = EVParams()
V_LEAD = 1.3  # leader speed [model]
SOC_MIN = 0.137  # a lower SOC bound that is neither 0 nor 1
LOW = EventRule(4, "soc_out_of_range", "S", 1.0, SOC_MIN, False, "state of charge fell below 0.137")
HIGH = next(r for r in EVENT_RULES if r.code == 5)  # the table's own upper bound: −S − (−1) < 0


def _reference_time(S0: float, a_cmd: float, rule: EventRule, t_end: float) -> float:
    """The first time the rule's margin crosses 0, by solve_ivp (DOP853, rtol 1e-10) with an event
    function, on (h, v, V1, V2, S)' = (v_l − v, a, T·dV1, T·dV2, T·dS) from battery_side (T: the time unit [s])."""
    v, V1, V2, S = ca.SX.sym("v"), ca.SX.sym("V1"), ca.SX.sym("V2"), ca.SX.sym("S")
    b = battery_side(v, ca.SX(a_cmd), V1, V2, S, EV)
    T = EV.units.time_s
    f = ca.Function("f", [v, V1, V2, S], [T * b["dV1"], T * b["dV2"], T * b["dS"]])

    def rhs(_t: float, y: np.ndarray) -> list[float]:
        d = f(y[1], y[2], y[3], y[4])
        return [V_LEAD - y[1], a_cmd, float(d[0]), float(d[1]), float(d[2])]

    def crossing(_t: float, y: np.ndarray) -> float:
        return float(rule.margin(y[4]))

    crossing.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(rhs, (0.0, t_end), [2.3, 1.1, 0.0, 0.0, S0], "DOP853", events=crossing, rtol=1e-10, atol=1e-13)
    assert sol.t_events[0].size == 1
    return float(sol.t_events[0][0])


@pytest.mark.parametrize(
    "rule,S0,a_cmd",
    [
        (LOW, SOC_MIN + 3.1e-5, 0.47),  # driving: S falls through 0.137
        (HIGH, 1.0 - 2.9e-5, -0.43),  # regenerative braking: S rises through 1
    ],
    ids=["soc_min_0.137", "soc_max_1"],
)
def test_soc_bound_event_is_located_where_scipy_finds_it(
    monkeypatch: pytest.MonkeyPatch, rule: EventRule, S0: float, a_cmd: float
) -> None:
    """One commanded follower (a_cmd held) crosses a SOC bound inside a 1.7-long interval (one sample at its
    end): the event time agrees with SciPy's to 1e-8 (model time), and the state returned at the event is on
    the side where the rule fires (the run stops there, so the last sample must show the violation)."""
    monkeypatch.setattr(plant_mod, "EVENT_RULES", (*[r for r in EVENT_RULES if r.quantity != "S"], rule))
    t_end = 1.7
    p = Plant(ConstantSpeed(V_LEAD), [None], EV)
    x0 = p.initial_state([2.3], [1.1], S0)
    q0 = np.zeros(p.nq)
    out: tuple[list, list, list, list] = (
        [np.array([0.0])],
        [x0[:, None]],
        [q0[:, None]],
        [p.samples([0.0], x0[:, None])],
    )
    events: list[Event] = []
    assert not p.advance(0.0, t_end, x0, q0, np.array([a_cmd]), out, events)
    assert [(e.kind, e.vehicle) for e in events] == [("soc_out_of_range", 0)]
    t_ref = _reference_time(S0, a_cmd, rule, t_end)
    assert 0.05 < t_ref < 0.95 * t_end  # well inside the interval: the locator, not the sampling, sets the time
    assert events[0].time == pytest.approx(t_ref, abs=1e-8)
    assert out[0][-1][-1] == events[0].time
    S_event = float(out[1][-1][4, -1])
    assert rule.violated(S_event)  # on the firing side ...
    assert abs(float(rule.margin(S_event))) < 1e-13  # ... and at the threshold


@pytest.mark.parametrize(
    ("h_model", "shown"),
    [
        (-3.9e-16, "gap at contact 0 m (0 model)"),
        (-2.99e-13, "gap at contact 0 m (0 model)"),
        (-0.0371, "gap at contact -0.556 m (-0.0371 model)"),
    ],
)
def test_collision_message_shows_the_gap_at_contact_without_round_off(h_model, shown):
    """A located contact's gap is 0 up to the locator's round-off, which the message does not print (it used to
    read 'gap at contact -3.9e-16 m'); a collision found already past contact (a state that starts overlapped)
    shows its real overlap, in m and model units (here 15 m per model length unit)."""
    from aev_ocp.plant import event_at
    from aev_ocp.params import Units

    units = Units(length_m=15.0, speed_mps=13.3)
    ev = event_at(EVENT_RULES[0], 0.81, 1, units, h_model, 0.42, 0.11, h_model)
    assert shown in ev.message and ev.kind == "collision"
    assert ev.impact_speed_mps == pytest.approx((0.42 - 0.11) * 13.3)


# ----------------------------------------------------------------------------- the plant's calls on bound buffers
def test_buffered_calls_equal_the_function_calls_and_fail_like_them() -> None:
    """The plant calls its integrator and output map on bound buffers (plant.BufferedCall): the results equal the
    ordinary Function calls bit for bit (integrator outputs at 3 samples, two commanded followers, the map at 4
    times); a failing integration (too few steps allowed) reports False there, and the ordinary call raises."""
    from aev_ocp.models.carfollowing import Proposed
    from aev_ocp.models.leader import BrakingLeader

    lead = BrakingLeader(1.1, -0.35, 0.4)
    p = Plant(lead, [None, Proposed(), None], EVParams(), samples=3)
    x = p.initial_state([0.9, 1.3, 0.7], [1.05, 0.95, 1.2], 0.8)
    bc = plant_mod.BufferedCall(p.integrator)
    pv = np.array([0.25, 0.6, -0.13, 0.07])  # (t0, L, a_cmd of followers 1 and 3)
    bc.args[p.integrator.index_in("x0")][:] = x
    bc.args[p.integrator.index_in("p")][:] = pv
    assert bc()
    ref = p.integrator(x0=x, p=pv)
    for name in ("xf", "qf"):
        got = bc.res[p.integrator.index_out(name)].reshape(ref[name].shape, order="F")
        assert np.array_equal(got, np.asarray(ref[name])) and np.ptp(got) > 0, name
    q0 = np.zeros(p.nq)
    out: tuple[list, list, list, list] = (
        [np.array([0.25])],
        [x[:, None]],
        [q0[:, None]],
        [p.samples(0.25, x[:, None])],
    )
    assert p.advance(0.25, 0.85, x, q0, pv[2:], out, [])  # the plant's own step, on its buffers
    assert np.array_equal(out[1][-1], np.asarray(ref["xf"])) and np.array_equal(out[2][-1], np.asarray(ref["qf"]))
    t, X = np.array([0.3, 0.45, 0.7, 0.85]), np.asarray(ref["xf"])[:, [0, 1, 2, 2]]
    ac = np.array([-0.13, 0.07])
    want = np.asarray(p._samples.map(4)(t.reshape(1, -1), X, np.repeat(ac[:, None], 4, axis=1)))
    assert np.array_equal(p.samples(t, X, ac), want) and want.shape == (3 * 3 + 1, 4)
    stiff = Plant(lead, [None], EVParams(), max_num_steps=3)
    sb = plant_mod.BufferedCall(stiff.integrator)
    x1 = stiff.initial_state([0.9], [1.05], 0.8)
    sb.args[stiff.integrator.index_in("x0")][:] = x1
    sb.args[stiff.integrator.index_in("p")][:] = [0.0, 5.0, -0.2]
    assert sb() is False
    with pytest.raises(RuntimeError):
        stiff.integrator(x0=x1, p=[0.0, 5.0, -0.2])

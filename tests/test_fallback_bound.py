"""The safe fallback's bound (aev_ocp/mpc/safe_fallback.py) against its closed form: the largest acceleration that
keeps the ego's stopping point s_min behind the lead's over the whole step, with the lead braking at the larger of
the assumed and the measured deceleration; every limit (a_max, a_min, the assumed lead braking) on, inside and
outside it; the bound tightest mid-step; the lag's reaction time; the measured deceleration from an Observation.

The closed forms are written here from the rule's statement (module docstring), not from the code:
the lead's stopping point P_l = x_l + v_l²/(2 b_l) is fixed while it brakes at b_l, so the condition over a step is
max_t P_e(t) ≤ P_l − s_min with P_e = x_e + v t_r + v²/(2 b), x_e and v with a held over the step (stopping at 0).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aev_ocp.control import Observation
from aev_ocp.params import EVParams, ParameterError
from aev_ocp.safety import SafeFallback, SafetyParams, safe_acceleration_mps2
from aev_ocp.mpc.safe_fallback import effective_reaction_s

B_EGO, B_LEAD, S_MIN, T_R, A_MAX, A_MIN = 7.3, 6.1, 2.7, 0.37, 2.9, -7.3
P = SafetyParams(
    standstill_gap_m=S_MIN,
    reaction_time_s=T_R,
    ego_brake_mps2=B_EGO,
    lead_brake_mps2=B_LEAD,
    a_min_mps2=A_MIN,
    a_max_mps2=A_MAX,
)


def _room(gap: float, vl: float, b_l: float, s_min: float = S_MIN) -> float:
    """P_l − s_min − x_e(0) [m]."""
    return gap - s_min + vl * vl / (2.0 * b_l)


def _accelerating_a(room: float, v: float, dt: float, t_r: float, b: float) -> float:
    """The a ≥ 0 whose stopping point at the step's end (its maximum: P_e rises while a ≥ 0) equals the room:
    with w = v + a dt, (v + w) dt/2 + w t_r + w²/(2b) = room, a quadratic in w."""
    c1 = dt / 2.0 + t_r
    w = b * (-c1 + math.sqrt(c1 * c1 - 2.0 * (v * dt / 2.0 - room) / b))
    return (w - v) / dt


def _gap_for(a: float, v: float, vl: float, dt: float, t_r: float = T_R, b_l: float = B_LEAD) -> float:
    """The gap [m] at which a ≥ 0 held over dt is exactly safe (its end-of-step stopping point = the room)."""
    w = v + a * dt
    return (v + w) * dt / 2.0 + w * t_r + w * w / (2.0 * B_EGO) + S_MIN - vl * vl / (2.0 * b_l)


def _peak_by_hand(v: float, a: float, dt: float, t_r: float, b: float) -> float:
    """max over the step of P_e(t) − x_e(0), on a 200 001-point grid (the stop included)."""
    t = np.linspace(0.0, dt, 200_001)
    if a < 0 and v > 0:
        t = np.minimum(t, v / -a)
    vt = v + a * t
    return float(np.max(v * t + 0.5 * a * t * t + vt * t_r + vt * vt / (2.0 * b)))


# ------------------------------------------------------------------------------- accelerating: closed form
@pytest.mark.parametrize(
    "a, v, vl, dt", [(1.3, 13.7, 11.3, 0.1), (0.37, 4.3, 9.7, 0.23), (2.71, 22.9, 19.1, 0.05), (0.93, 0.0, 3.3, 0.17)]
)
def test_bound_equals_the_closed_form_when_accelerating(a: float, v: float, vl: float, dt: float) -> None:
    gap = _gap_for(a, v, vl, dt)
    assert _accelerating_a(_room(gap, vl, B_LEAD), v, dt, T_R, B_EGO) == pytest.approx(a, abs=1e-9)  # inverted
    assert safe_acceleration_mps2(gap, v, vl, dt, P) == pytest.approx(a, abs=1e-9)
    for d in (-0.01, 0.01):  # nearby gaps: the closed form, not a constant
        a_cf = _accelerating_a(_room(gap + d, vl, B_LEAD), v, dt, T_R, B_EGO)
        assert safe_acceleration_mps2(gap + d, v, vl, dt, P) == pytest.approx(a_cf, abs=1e-9)


def test_a_lead_braking_harder_than_assumed_lowers_the_bound_softer_leaves_it() -> None:
    """b_l = max(b_lead, −a_lead): the measured deceleration enters P_l = v_l²/(2 b_l) only when it exceeds the
    assumed one (on: equal; inside: softer; outside: harder)."""
    v, vl, dt = 13.7, 4.1, 0.1
    gap = _gap_for(2.1, v, vl, dt)
    assumed = safe_acceleration_mps2(gap, v, vl, dt, P, 0.0)
    assert assumed == pytest.approx(2.1, abs=1e-9)
    for a_lead in (-3.1, -B_LEAD, 1.7):  # softer, exactly the assumed, accelerating: the assumed b_lead
        assert safe_acceleration_mps2(gap, v, vl, dt, P, a_lead) == assumed
    for a_lead in (-6.9, -B_LEAD - 0.2):  # harder: b_l = −a_lead
        a_cf = _accelerating_a(_room(gap, vl, -a_lead), v, dt, T_R, B_EGO)
        got = safe_acceleration_mps2(gap, v, vl, dt, P, a_lead)
        assert 0.0 < a_cf and got == pytest.approx(a_cf, abs=1e-9)
        assert got < assumed - 0.05  # it raises the bound on the ego's stopping point: less acceleration


def test_a_max_limit_on_inside_and_outside() -> None:
    """The room that makes a_max exactly the largest safe acceleration: on it a_max, a little less room: the closed
    form below a_max, a little more: still a_max (clipped)."""
    v, vl, dt = 9.1, 8.3, 0.2
    w = v + A_MAX * dt
    room_on = (v + w) * dt / 2.0 + w * T_R + w * w / (2.0 * B_EGO)
    gap_on = room_on + S_MIN - vl * vl / (2.0 * B_LEAD)
    assert safe_acceleration_mps2(gap_on, v, vl, dt, P) == A_MAX
    assert safe_acceleration_mps2(gap_on + 0.3, v, vl, dt, P) == A_MAX
    inside = safe_acceleration_mps2(gap_on - 0.3, v, vl, dt, P)
    assert inside == pytest.approx(_accelerating_a(room_on - 0.3, v, dt, T_R, B_EGO), abs=1e-9)
    assert 0.0 < inside < A_MAX


def test_a_min_limit_when_the_condition_already_fails() -> None:
    """Condition broken at t = 0 (gap below what braking at b_ego needs): maximal braking a_min; a gap exactly at
    what braking from now needs: a ≥ a_min (braking at b_ego keeps P_e from rising, t_r = 0 here)."""
    p = SafetyParams(**{**vars(P), "reaction_time_s": 0.0})
    v, vl, dt = 17.3, 6.1, 0.1
    need = v * v / (2 * B_EGO) - vl * vl / (2 * B_LEAD) + S_MIN  # the gap where the condition holds with equality
    assert safe_acceleration_mps2(need - 0.05, v, vl, dt, p) == A_MIN
    on = safe_acceleration_mps2(need, v, vl, dt, p)
    assert A_MIN <= on <= A_MIN + 1e-6
    inside = safe_acceleration_mps2(need + 0.4, v, vl, dt, p)
    assert inside > A_MIN + 0.1


# ------------------------------------------------------------------------------- braking: tightest mid-step
@pytest.mark.parametrize("frac", [0.21, 0.5, 0.83])
def test_bound_holds_where_the_stopping_point_peaks_mid_step(frac: float) -> None:
    """Braking gently (−b < a < 0) with a reaction time, P_e rises until the speed falls to v* = −a t_r/(1 + a/b)
    and falls after: its peak is inside the step. The gap that makes a given a exactly safe over the whole step
    (its peak by hand) must give back that a, not the larger one an end-of-step check would allow."""
    a, dt, t_r = -2.3, 0.4, 0.9
    v_star = -a * t_r / (1 + a / B_EGO)
    v = v_star + frac * dt * -a  # the peak at t* = frac dt
    p = SafetyParams(**{**vars(P), "reaction_time_s": t_r})
    peak = _peak_by_hand(v, a, dt, t_r, B_EGO)
    end = v * dt + 0.5 * a * dt * dt + (v + a * dt) * t_r + (v + a * dt) ** 2 / (2 * B_EGO)
    assert peak > end + 1e-4 and peak > v * t_r + v * v / (2 * B_EGO) + 1e-4  # inside the step
    vl = 5.3
    gap = peak + S_MIN - vl * vl / (2 * B_LEAD)
    assert safe_acceleration_mps2(gap, v, vl, dt, p) == pytest.approx(a, abs=2e-4)


def test_the_actuator_lag_raises_the_reaction_time_by_its_worst_delay() -> None:
    """t_r + τ (a_max + b)/b: the bound with lag τ equals the bound without lag at that reaction time."""
    tau = 0.31
    p = SafetyParams(**{**vars(P), "lag_s": tau})
    t_eff = T_R + tau * (A_MAX + B_EGO) / B_EGO
    assert effective_reaction_s(p) == pytest.approx(t_eff, rel=1e-15)
    v, vl, dt = 11.9, 12.7, 0.1
    gap = _gap_for(1.7, v, vl, dt, t_r=t_eff)
    assert safe_acceleration_mps2(gap, v, vl, dt, p) == pytest.approx(1.7, abs=1e-9)
    assert safe_acceleration_mps2(gap, v, vl, dt, P) == A_MAX  # without the lag the same gap allows more


def test_standstill_gap_and_reaction_time_enter_once() -> None:
    """A larger floor moves the room by exactly its difference; the reaction time weighs the end speed."""
    v, vl, dt = 13.7, 11.3, 0.1
    gap = _gap_for(0.9, v, vl, dt) + 1.3
    p2 = SafetyParams(**{**vars(P), "standstill_gap_m": S_MIN + 1.3})
    assert safe_acceleration_mps2(gap, v, vl, dt, p2) == pytest.approx(0.9, abs=1e-9)
    assert safe_acceleration_mps2(gap - 1.3, v, vl, dt, P) == pytest.approx(0.9, abs=1e-9)
    p3 = SafetyParams(**{**vars(P), "reaction_time_s": T_R + 0.2})
    assert safe_acceleration_mps2(_gap_for(0.9, v, vl, dt, t_r=T_R + 0.2), v, vl, dt, p3) == pytest.approx(
        0.9, abs=1e-9
    )


def test_the_controller_measures_the_leads_deceleration_from_its_last_two_speeds() -> None:
    """SafeFallback.safe_mps2: a_lead = Δv_l/Δt of the last two measured speeds (model units in, SI out)."""
    ev = EVParams()
    u = ev.units
    dt = float(u.time_from_si(0.1))
    v, vl = 13.7, 4.1
    gap = _gap_for(2.1, v, vl, 0.1)
    sf = SafeFallback(None, u, dt, P)
    for a_lead in (-6.9, -3.1):
        vl_prev = vl - a_lead * 0.1
        obs = Observation(
            t=1.0,
            dt=dt,
            vehicle=0,
            z=np.array([u.length_from_si(gap), u.speed_from_si(v), 0.0, 0.0, 0.8]),
            meas_t=np.array([1.0 - dt, 1.0]),
            meas_v=np.array([u.speed_from_si(vl_prev), u.speed_from_si(vl)]),
        )
        b_l = max(B_LEAD, -a_lead)
        a_cf = _accelerating_a(_room(gap, vl, b_l), v, 0.1, T_R, B_EGO)
        assert sf.safe_mps2(obs) == pytest.approx(a_cf, abs=1e-8)


@pytest.mark.parametrize("bad", [{"dt_s": 0.0}, {"dt_s": -0.1}, {"gap_m": math.nan}, {"a_lead_mps2": math.inf}])
def test_bad_input_is_refused_naming_the_field(bad: dict[str, float]) -> None:
    kw = {"gap_m": 31.0, "v_mps": 13.7, "v_lead_mps": 11.3, "dt_s": 0.1, "a_lead_mps2": 0.0, **bad}
    with pytest.raises(ParameterError, match=next(iter(bad))):
        safe_acceleration_mps2(p=P, **kw)

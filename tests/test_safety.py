"""The safety package: the kinematic avoidability bound (against SciPy and closed forms), the safe fallback
(hypothesis properties), the BrakingLeader profile, one closed-loop case per family, and ``aev-ocp safety --quick``."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from braking_oracle import scipy_min_gap
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from aev_ocp.cli import main
from aev_ocp.control import ClosedLoop, Observation
from aev_ocp.models import BrakingLeader, Proposed
from aev_ocp.params import EVParams, ParameterError, Units
from aev_ocp.safety import (
    AVOIDABLE,
    COLLISION_AVOIDABLE_ONLY,
    UNAVOIDABLE,
    SafeFallback,
    SafetyParams,
    braking_bound,
    label_of,
    safe_acceleration_mps2,
)
from aev_ocp.safety.cases import CASE_UNITS, SafetyCase, suite_cases
from aev_ocp.mpc.safe_fallback import effective_reaction_s


# ----------------------------------------------------------------------------- the bound
def _scipy_min_gap(v0: float, g0: float, vl0: float, al: float, tb: float, am: float, tau: float) -> float:
    """The same motion integrated by SciPy, piece by piece between the right-hand side's switches
    (tests/braking_oracle.py): h, v_e, a_e (lagged), v_l; no reverse."""
    return scipy_min_gap(
        v0, g0, vl0, al, tb, am, tau, max(v0 / -am + 3 * tau, tb + (vl0 / -al if al < 0 else 0.0)) + 1.0
    )


@pytest.mark.parametrize(
    "case",
    [
        (24.3, 8.7, 24.3, -9.2, 0.0, -7.7, 0.0),  # cut-in, the lead brakes harder than the ego can
        (24.3, 8.7, 24.3, -9.2, 0.0, -7.7, 0.35),  # the same with an actuator lag
        (13.9, 12.0, 13.9, -6.0, 0.0, -8.0, 0.2),  # CCRb, ego brakes harder
        (19.4, 21.3, 5.6, 0.0, 0.0, -7.3, 0.45),  # slower moving target
        (16.7, 18.2, 16.7, -5.3, 1.35, -6.9, 0.25),  # the lead brakes late
        (11.1, 3.7, 0.0, 0.0, 0.0, -8.0, 0.15),  # stationary target, contact
    ],
)
def test_bound_matches_scipy(case: tuple[float, ...]) -> None:
    v0, g0, vl0, al, tb, am, tau = case
    b = braking_bound(v0, g0, vl0, al, t_brake_s=tb, a_min_mps2=am, lag_s=tau)
    # to 1e-9 (observed 5e-12; the single solve with 0.5 ms steps of before agreed to 9.5e-7, hence its 2e-5)
    assert b.min_gap_m == pytest.approx(_scipy_min_gap(*case), abs=1e-9)


def test_bound_closed_forms() -> None:
    # stationary target, no lag: h0 − v²/(2b)
    b = braking_bound(17.3, 31.7, 0.0, 0.0, a_min_mps2=-7.3)
    assert b.min_gap_m == pytest.approx(31.7 - 17.3**2 / (2 * 7.3), abs=1e-12)
    assert b.t_min_s == pytest.approx(17.3 / 7.3, abs=1e-12) and b.label == AVOIDABLE
    # same speeds, the lead brakes harder (9.1 > 7.7): the gap shrinks until the ego stands
    b = braking_bound(22.4, 13.3, 22.4, -9.1, a_min_mps2=-7.7)
    assert b.min_gap_m == pytest.approx(13.3 + 22.4**2 / 18.2 - 22.4**2 / 15.4, abs=1e-12)
    # slower lead at constant speed: the minimum where the speeds meet, h0 − Δv²/(2b)
    b = braking_bound(21.0, 9.5, 13.0, 0.0, a_min_mps2=-6.4)
    assert b.min_gap_m == pytest.approx(9.5 - 8.0**2 / (2 * 6.4), abs=1e-12)
    assert b.t_min_s == pytest.approx(8.0 / 6.4, abs=1e-12)
    # the lead brakes only at t_b = 1.7 s: the ego (faster braking) keeps its initial gap, the minimum is at t = 0
    b = braking_bound(15.0, 10.0, 15.0, -3.0, t_brake_s=1.7, a_min_mps2=-8.0)
    assert b.min_gap_m == pytest.approx(10.0, abs=1e-12) and b.t_min_s == 0.0
    # a contact: the first time the gap reaches 0 (stationary target 3.7 m ahead at 11.1 m/s, b = 8)
    b = braking_bound(11.1, 3.7, 0.0, 0.0, a_min_mps2=-8.0)
    assert b.label == UNAVOIDABLE and b.min_gap_m < 0
    t = b.t_min_s
    assert 11.1 * t - 4.0 * t * t == pytest.approx(3.7, abs=1e-9)


def test_lag_only_shrinks_the_bound() -> None:
    g = [braking_bound(24.3, 14.2, 24.3, -9.2, a_min_mps2=-7.7, lag_s=tau).min_gap_m for tau in (0.0, 0.15, 0.3, 0.6)]
    assert all(a > b for a, b in zip(g, g[1:]))


def test_labels_on_inside_outside_the_floor() -> None:
    assert label_of(2.0, 2.0) == AVOIDABLE  # on the floor
    assert label_of(2.0 + 1e-9, 2.0) == AVOIDABLE
    assert label_of(1.3, 2.0) == COLLISION_AVOIDABLE_ONLY  # inside (0, floor)
    assert label_of(1e-9, 2.0) == COLLISION_AVOIDABLE_ONLY
    assert label_of(0.0, 2.0) == UNAVOIDABLE  # contact
    assert label_of(-0.7, 2.0) == UNAVOIDABLE


@pytest.mark.parametrize(
    "kw, name",
    [
        ({"gap_m": 0.0}, "gap_m"),
        ({"a_lead_mps2": 1.5}, "a_lead_mps2"),
        ({"a_min_mps2": 0.0}, "a_min_mps2"),
        ({"lag_s": -0.1}, "lag_s"),
        ({"v_ego_mps": math.nan}, "v_ego_mps"),
    ],
)
def test_bound_bad_input_names_the_field(kw: dict, name: str) -> None:
    args = {"v_ego_mps": 12.0, "gap_m": 9.0, "v_lead_mps": 10.0, "a_lead_mps2": -2.0, **kw}
    with pytest.raises(ParameterError, match=name):
        braking_bound(args.pop("v_ego_mps"), args.pop("gap_m"), args.pop("v_lead_mps"), args.pop("a_lead_mps2"), **args)


# ----------------------------------------------------------------------------- the leader profile
def test_braking_leader_speed_position_accel() -> None:
    u = Units(15.0, 17.0)
    lead = BrakingLeader.from_si(22.0, -6.5, 1.3, u)
    t_stop = float(u.time_from_si(1.3 + 22.0 / 6.5))
    assert lead.breakpoints == pytest.approx((float(u.time_from_si(1.3)), t_stop))
    ts = np.array([0.0, 0.5, 1.1, 2.0, 3.7, t_stop, t_stop + 2.0])
    v = lead.speed_np(ts)
    v_si = 22.0 - 6.5 * np.clip(u.time_to_si(ts) - 1.3, 0, None)
    assert u.speed_to_si(v) == pytest.approx(np.maximum(v_si, 0.0), abs=1e-12)
    for t in ts[1:]:  # position = ∫ speed
        assert float(lead.position(t)) == pytest.approx(
            quad(lambda s: float(lead.speed_np(s)[0]), 0, t, points=lead.breakpoints, limit=200)[0], abs=1e-9
        )
    assert float(lead.accel(float(u.time_from_si(2.0)))) == pytest.approx(float(u.accel_from_si(-6.5)))
    assert float(lead.accel(float(u.time_from_si(0.7)))) == 0.0 and float(lead.accel(t_stop + 1)) == 0.0
    with pytest.raises(ParameterError, match="decel"):
        BrakingLeader(1.2, 0.4)


# ----------------------------------------------------------------------------- the safe controller
def _step(h: float, v: float, vl: float, a: float, dt: float, b_l: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gap, v, v_l) on a fine grid of one step of dt with the ego at a (stopping at 0) and the lead braking at b_l."""
    ts = np.linspace(0.0, dt, 2001)
    te = ts if a >= 0 or v <= 0 else np.minimum(ts, v / -a)
    tl = np.minimum(ts, vl / b_l)
    g = h + (vl * tl - 0.5 * b_l * tl**2) - (v * te + 0.5 * a * te**2)
    return g, v + a * te, vl - b_l * tl


def _end_of_step(h: float, v: float, vl: float, a: float, dt: float, b_l: float) -> tuple[float, float, float, float]:
    """(min gap over the step, gap, v, v_l) after the step (see _step)."""
    g, ve, vle = _step(h, v, vl, a, dt, b_l)
    return float(g.min()), float(g[-1]), float(ve[-1]), float(vle[-1])


PARAMS = SafetyParams(
    standstill_gap_m=2.3, reaction_time_s=0.0, ego_brake_mps2=7.7, lead_brake_mps2=8.4, a_min_mps2=-7.7, a_max_mps2=3.6
)


@settings(max_examples=150, deadline=None)
@given(
    v=st.floats(0.0, 35.0),
    vl=st.floats(0.0, 35.0),
    h=st.floats(2.4, 80.0),
    dt=st.floats(0.04, 0.3),
    t_r=st.sampled_from([0.0, 0.45]),
    a_l=st.floats(-11.0, 2.0),
)
# braking gently with a reaction time: the stopping point peaks mid-step (at t* = 0.15 s), so a + 0.02 breaks the
# condition inside the step while it still holds at the step's end (an end-of-step check fails here without a bug)
@example(v=1.821, vl=4.0, h=2.4006, dt=0.3, t_r=0.45, a_l=0.0)
def test_safe_never_accelerates_into_a_gap_it_cannot_stop_in(
    v: float, vl: float, h: float, dt: float, t_r: float, a_l: float
) -> None:
    p = SafetyParams(**{**vars(PARAMS), "reaction_time_s": t_r})
    b_l = max(p.lead_brake_mps2, -a_l)
    holds = h - p.standstill_gap_m >= v * t_r + v * v / (2 * p.ego_brake_mps2) - vl * vl / (2 * b_l)
    a = safe_acceleration_mps2(h, v, vl, dt, p, a_l)
    assert p.a_min_mps2 <= a <= p.a_max_mps2
    if not holds:
        assert a == p.a_min_mps2  # the condition already fails: maximal braking
        return
    g_min, g1, v1, vl1 = _end_of_step(h, v, vl, a, dt, b_l)
    assert g_min >= p.standstill_gap_m - 1e-6  # never below the floor during the step
    g, ve, vle = _step(h, v, vl, a, dt, b_l)  # the condition itself holds at every instant of the step
    cond = g - p.standstill_gap_m - (ve * t_r + ve**2 / (2 * p.ego_brake_mps2) - vle**2 / (2 * b_l))
    assert cond.min() >= -1e-6
    # from the state after the step, braking at b_ego behind a lead braking at b_l keeps the floor (the bound)
    if v1 > 0 or vl1 > 0:
        rest = braking_bound(max(v1, 0.0), g1, max(vl1, 0.0), -b_l, a_min_mps2=-p.ego_brake_mps2)
        assert rest.min_gap_m >= p.standstill_gap_m - 1e-6
    if a < p.a_max_mps2 and a > p.a_min_mps2:  # the largest such a: a little more breaks the condition somewhere
        # in the step (not necessarily at its end: braking gently with a reaction time, the ego's stopping point
        # peaks mid-step), by the closed form of that peak against the lead's fixed stopping point
        room = h - p.standstill_gap_m + vl * vl / (2 * b_l)
        assert _stopping_point_peak_closed_form(v, a + 0.02, dt, t_r, p.ego_brake_mps2) > room - 1e-9


def _stopping_point_peak_closed_form(v: float, a: float, dt: float, t_r: float, b: float) -> float:
    """max over the step of x_e(t) + v(t) t_r + v(t)²/(2b) − x_e(0) with a held (speed stopping at 0): P_e is a
    quadratic in t up to the stop and constant after, so its maximum is at t = 0, at the step's (or the stop's)
    end or where dP_e/dt = v(t)(1 + a/b) + a t_r vanishes."""
    t_end = min(dt, v / -a) if a < 0 else dt
    cands = [0.0, t_end]
    if a != 0 and 1 + a / b != 0:
        t_star = (-a * t_r / (1 + a / b) - v) / a
        if 0 < t_star < t_end:
            cands.append(t_star)
    return max(v * t + 0.5 * a * t * t + (v + a * t) * t_r + (v + a * t) ** 2 / (2 * b) for t in cands)


@settings(max_examples=200, deadline=None)
@given(v=st.floats(0.0, 12.0), a=st.floats(-7.7, 3.6), dt=st.floats(0.05, 0.6), t_r=st.floats(0.0, 1.2))
def test_stopping_point_peak_over_the_step(v: float, a: float, dt: float, t_r: float) -> None:
    # the largest ego stopping point x + v t_r + v²/(2b) over a step with a held, against a fine grid
    from aev_ocp.mpc.safe_fallback import _stopping_point_peak

    b = 7.7
    ts = np.linspace(0.0, dt, 20001)
    te = ts if a >= 0 or v <= 0 else np.minimum(ts, v / -a)
    ve = v + a * te
    grid = np.max(v * te + 0.5 * a * te**2 + ve * t_r + ve**2 / (2 * b))
    assert _stopping_point_peak(v, a, dt, t_r, b) == pytest.approx(grid, abs=1e-7)
    # an interior peak: v = v* + 0.1 s × |a| with v* = −a t_r / (1 + a/b) (the braking ego's stopping point rises first)
    a2, t_r2 = -3.1, 0.7
    v2 = -a2 * t_r2 / (1 + a2 / b) + 0.1 * 3.1
    ts = np.linspace(0.0, 0.3, 20001)
    ve2 = v2 + a2 * ts
    peak = np.max(v2 * ts + 0.5 * a2 * ts**2 + ve2 * t_r2 + ve2**2 / (2 * b))
    assert (
        peak
        > max(v2 * t_r2 + v2**2 / (2 * b), float((v2 * ts + 0.5 * a2 * ts**2 + ve2 * t_r2 + ve2**2 / (2 * b))[-1]))
        + 1e-4
    )
    assert _stopping_point_peak(v2, a2, 0.3, t_r2, b) == pytest.approx(peak, abs=1e-9)


def test_safe_equals_the_law_when_far_and_brakes_when_close() -> None:
    u = Units(15.0, 17.0)
    fb = SafeFallback(Proposed(), u, 0.1, SafetyParams(a_min_mps2=-7.9, ego_brake_mps2=7.9, a_max_mps2=3.3))
    lo, hi = float(u.accel_from_si(-7.9)), float(u.accel_from_si(3.3))
    for h, v, vl in ((9.0, 1.1, 1.3), (14.0, 0.6, 0.7), (12.0, 1.2, 1.25)):  # 135-210 m ahead: far
        obs = Observation(0.0, 0.1, 0, np.array([h, v, 0, 0, 0.8]), np.array([0.0]), np.array([vl]))
        law = float(Proposed().function(h, v, vl))
        assert fb.command(obs).a == pytest.approx(min(max(law, lo), hi), abs=1e-12)
    assert fb.limited_steps == 0 and fb.braking_steps == 0
    # 4 m behind a car at the same 23 m/s: any command (here +2 m/s², as a solver might ask) becomes full braking
    obs = Observation(0.0, 0.1, 0, np.array([4.0 / 15, 23.0 / 17, 0, 0, 0.8]), np.array([0.0]), np.array([23.0 / 17]))
    assert fb.limit(obs, float(u.accel_from_si(2.0))) == pytest.approx(lo)
    assert fb.command(obs).a == pytest.approx(lo)
    assert fb.limited_steps == 1 and fb.braking_steps == 2


def test_lag_lengthens_the_reaction_time() -> None:
    p = SafetyParams(lag_s=0.4, a_max_mps2=3.5, ego_brake_mps2=7.0, a_min_mps2=-7.0, reaction_time_s=0.25)
    assert effective_reaction_s(p) == pytest.approx(0.25 + 0.4 * 10.5 / 7.0)
    with pytest.raises(ParameterError, match="ego_brake_mps2"):
        SafetyParams(ego_brake_mps2=9.0, a_min_mps2=-8.0)


# ----------------------------------------------------------------------------- closed loop
def _run(case: SafetyCase, controller: object, ev: EVParams) -> tuple[float, bool]:
    u = ev.units
    lead = BrakingLeader.from_si(case.v_lead_mps, case.a_lead_mps2, case.t_brake_s, u)
    dt = 0.1
    t_end = dt * round(float(u.time_from_si(case.t_end_s)) / dt)
    r = ClosedLoop(lead, [controller], ev).run(
        [float(u.length_from_si(case.gap_m))], [float(u.speed_from_si(case.v_ego_mps))], t_end
    )
    return float(u.length_to_si(r.gap[:, 0].min())), r.status == "collision"


def test_safe_fallback_alone_in_a_hard_cut_in() -> None:
    # 8 m ahead at 25 m/s braking at 9 m/s² (harder than the assumed 8): avoidable; the law alone, clipped, is not safe
    ev = EVParams(units=CASE_UNITS)
    case = SafetyCase("cut-in", "c", 25.0, 8.0, 25.0, -9.0, 0.0, 4.5)
    bound = braking_bound(25.0, 8.0, 25.0, -9.0)
    gap, coll = _run(case, SafeFallback.for_vehicle(Proposed(), ev, 0.1), ev)
    assert not coll and 2.0 <= gap <= bound.min_gap_m + 1e-6


@pytest.mark.parametrize(
    "name", ["CCRb_100kmh_12m_-6mps2", "CCRs_130kmh", "CCRm_120kmh", "cutin_100kmh_lead100kmh_15m_-6mps2"]
)
def test_mpc_one_case_per_family(name: str) -> None:
    from aev_ocp.safety.run import run_suite

    case = next(c for c in suite_cases() if c.name == name)
    short = SafetyCase(
        case.family,
        case.name,
        case.v_ego_mps,
        case.gap_m,
        case.v_lead_mps,
        case.a_lead_mps2,
        case.t_brake_s,
        4.0 if case.family == "cut-in" else 6.0,
    )
    out = run_suite([short], controllers=("mpc", "proposed"), actuators=("declared",))
    for row in out.rows:
        assert row.label == AVOIDABLE and row.actuator == "declared"
        # no controller bounded by a_min keeps a larger gap than the bound (pointwise, so also its minimum), up to the
        # samples missing the exact minimum (≤ 88 ms apart, relative acceleration ≤ 8 m/s²: ½ · 8 · 0.088² = 0.031 m)
        assert row.min_gap_m <= row.bound_min_gap_m + 0.031
    mpc = next(r for r in out.rows if r.controller == "mpc")
    assert not mpc.collision and mpc.floor_violation_samples == 0 and mpc.min_gap_m >= 2.0
    assert mpc.peak_decel_mps2 <= 8.0 + 1e-9 and mpc.fallbacks == 0


def test_suite_cases_as_specified() -> None:
    from aev_ocp.safety.cases import NCAP

    cases = suite_cases()
    assert len({c.name for c in cases}) == len(cases) == 11 + 9 + 8 + 3 + 18
    kmh = {f: [round(c.v_ego_mps * 3.6) for c in cases if c.family == f] for f in ("CCRs", "CCRm", "CCRb", "cut-in")}
    assert kmh["CCRs"] == [10, 20, 30, 40, 50, 60, 70, 80, 100, 120, 130]  # Euro NCAP's 10-80, then motorway
    assert kmh["CCRm"] == [30, 40, 50, 60, 70, 80, 100, 120, 130]
    assert set(kmh["CCRb"]) == {50, 100} and max(kmh["cut-in"]) == 130
    ccrs = [c for c in cases if c.family == "CCRs"]
    assert all(c.gap_m == pytest.approx(4.0 * c.v_ego_mps) and c.v_lead_mps == 0 for c in ccrs)
    ccrb = [c for c in cases if c.family == "CCRb"]
    assert {c.gap_m for c in ccrb} == {12.0, 40.0} and {c.a_lead_mps2 for c in ccrb} == {-2.0, -6.0}
    # every case states its source: Euro NCAP's own speeds cite the protocol, the extensions say they are ours
    assert all(
        (c.source == NCAP) == (c.family in ("CCRs", "CCRm", "CCRb") and c.v_ego_mps <= 80 / 3.6 + 1e-9) for c in cases
    )
    assert all(c.source.startswith("ours") for c in cases if c.source != NCAP)
    lane = [c for c in cases if c.family == "lane-end"]
    assert {round(c.v_ego_mps * 3.6) for c in lane} == {100, 130} and all(c.v_lead_mps == 0 for c in lane)


def test_cli_quick(tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "s"
    argv = ["safety", "--quick", "--no-plots", "--out", str(out), "--workers", "1", "--actuators", "declared"]
    assert main(argv + ["--controllers", "mpc,proposed,ovfl+layer"]) == 0
    rows = list(csv.DictReader(open(out / "safety.csv", encoding="utf-8")))
    assert len(rows) == 8 * 3 and {r["controller"] for r in rows} == {"mpc", "proposed", "ovfl+layer"}
    assert all(r["failed"] == "False" for r in rows if r["controller"] != "proposed")
    # the bare proposed law closes below the floor on the standing obstacle 60 m ahead at 100 km/h (avoidable) within
    # the quick run's 3 s: a failed row, reported, and the exit code still 0 (the paper's law as published)
    lane = next(r for r in rows if r["controller"] == "proposed" and r["case"] == "laneend_100kmh_60m")
    assert lane["failed"] == "True" and float(lane["min_gap_m"]) < 2.0
    md = (out / "safety.md").read_text(encoding="utf-8")
    assert "Safety suite" in md and "Euro NCAP AEB Car-to-Car test protocol" in md
    assert main(["safety", "--quick", "--bogus"]) == 2
    assert main(argv + ["--controllers", "mpc,lqr"]) == 2  # an unknown controller: refused, named


# ----------------------------------------------------------------------------- the suite's shared runs and warnings
_ARRAYS = ("t", "gap", "speed", "accel", "V1", "V2", "S", "current_A", "omega", "heat_J", "int_jerk2", "leader_speed")
_TIMINGS = ("solve_ms_median", "solve_ms_p95", "solve_ms_max", "call_ms_median", "call_ms_p95")


def test_bare_mpc_is_its_layered_run_only_when_the_layer_changed_no_command() -> None:
    """With 'mpc' and 'mpc+layer' both asked for, the suite runs the MPC under the layer first and takes the bare run
    from it when the layer changed no command: that run must equal the MPC run alone (every sample bit for bit, its
    name, settings and statistics); where the layer did change commands the bare MPC must run on its own."""
    from aev_ocp.safety.run import run_suite

    quick = {c.name: c for c in suite_cases(quick=True)}
    # at the declared actuator the layer never acts in CCRs 50 km/h and lowers commands at the lane end 60 m ahead
    cases = [quick["CCRs_50kmh"], quick["laneend_100kmh_60m"]]
    both = run_suite(cases, ("mpc", "mpc+layer"), actuators=("declared",))
    alone = run_suite(cases, ("mpc",), actuators=("declared",))
    for c, taken in (("CCRs_50kmh", True), ("laneend_100kmh_60m", False)):
        r, ref, lay = both.runs[c]["declared/mpc"], alone.runs[c]["declared/mpc"], both.runs[c]["declared/mpc+layer"]
        assert (r.gap is lay.gap) == taken  # taken from the layered run (the same arrays), or run on its own
        for f in _ARRAYS:
            assert np.array_equal(getattr(r, f), getattr(ref, f)), (c, f)
        assert r.controllers == ref.controllers and r.status == ref.status and r.events == ref.events
        assert r.meta["controllers"] == ref.meta["controllers"] and "layer" in lay.meta["controllers"][0]
        mine, theirs = (
            {k: v for k, v in (s or {}).items() if k not in _TIMINGS} for s in (r.solver_stats[0], ref.solver_stats[0])
        )
        assert mine == theirs and mine["n_steps"] > 0
    lane = {x.controller: x for x in both.rows if x.case == "laneend_100kmh_60m"}
    assert lane["mpc+layer"].safety_limited_steps > 0 and lane["mpc+layer"].min_gap_m != lane["mpc"].min_gap_m
    strip = lambda rows: [{**vars(x), "wall_s": 0.0} for x in rows]  # noqa: E731
    assert strip(x for x in both.rows if x.controller == "mpc") == strip(alone.rows)


#: a cut-in the MPC cannot keep 2 m in (below its floor, no contact, ideal actuator), between two it can
_TIGHT = [
    SafetyCase("CCRs", "wide_before", 10.3, 37.0, 0.0, 0.0, 0.0, 2.5),
    SafetyCase("cut-in", "tight_cut_in", 20.0, 3.0, 20.0, -9.0, 0.0, 2.5),
    SafetyCase("CCRs", "wide_after", 11.7, 41.0, 0.0, 0.0, 0.0, 2.5),
]


# on the pool: two spawned workers, over 5 s of one core (measured under load)
@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_a_cases_warning_comes_under_its_own_progress_line(workers: int) -> None:
    """The floor warning a run raises is said after its case's progress line ('case k/3 name'), never under another
    case's, in this process and on the pool (where the worker's own stderr would put it anywhere)."""
    import warnings

    from aev_ocp.safety.run import run_suite

    said: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda m, *a, **k: said.append(f"warning: {m}")
        out = run_suite(_TIGHT, ("mpc", "mpc+layer"), actuators=("ideal",), workers=workers, progress=said.append)
    lines = [s for s in said if s.startswith("case ")]  # one per case as it ends, counted out of 3
    assert [s.split()[1] for s in lines] == ["1/3", "2/3", "3/3"]
    assert sorted(s.split()[2] for s in lines) == sorted(c.name for c in _TIGHT)
    warned = [k for k, s in enumerate(said) if s.startswith("warning")]
    tight = {r.controller: r for r in out.rows if r.case == "tight_cut_in"}
    assert all(r.status == "violated" and not r.collision for r in tight.values())
    assert len(warned) == 2  # the bare MPC's (taken from the layered run) and the layered one's
    for k in warned:
        heading = next(s for s in reversed(said[:k]) if s.startswith("case "))
        assert heading.endswith(" tight_cut_in") and "safety case tight_cut_in: mpc(traffic)" in said[k]
        assert "violated its gap floor" in said[k]


# ----------------------------------------------------------------------------- reuse: plants and controllers
def _same_runs(a, b) -> None:  # type: ignore[no-untyped-def]
    """Two SimulationResults equal bit for bit: every array, the events, status, names and settings."""
    for f in _ARRAYS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert a.events == b.events and a.status == b.status and a.controllers == b.controllers
    assert a.meta["controllers"] == b.meta["controllers"]


def test_a_reused_plant_runs_bit_for_bit_like_a_fresh_one() -> None:
    """A plant run by one closed loop and handed to another (the suite builds one per case and actuator) gives the
    second loop's run bit for bit as on a plant of its own (a run leaves nothing in the plant); a plant built for
    another vehicle is refused, naming the field."""
    from aev_ocp.safety.cases import DECLARED

    ev = EVParams(units=CASE_UNITS, limits=DECLARED.limits())
    lead = BrakingLeader.from_si(23.0, -6.0, 0.0, CASE_UNITS)
    h0, v0 = float(CASE_UNITS.length_from_si(17.0)), float(CASE_UNITS.speed_from_si(26.0))
    first = ClosedLoop(lead, [SafeFallback.for_vehicle(Proposed(), ev, 0.1)], ev)
    first.run([h0], [v0], 2.0)  # the plant has run once (another controller, another start)
    law = Proposed(h_scale_m=15.0, v_scale_mps=17.0).in_units(CASE_UNITS)
    reused = ClosedLoop(lead, [SafeFallback.for_vehicle(law, ev, 0.1)], ev, plant=first.plant)
    fresh = ClosedLoop(lead, [SafeFallback.for_vehicle(law, ev, 0.1)], ev)
    assert reused.plant is first.plant and fresh.plant is not first.plant
    r, ref = reused.run([h0 * 0.7], [v0], 3.0), fresh.run([h0 * 0.7], [v0], 3.0)
    _same_runs(r, ref)
    assert r.gap.size > 30 and float(CASE_UNITS.accel_to_si(np.ptp(r.accel))) > 5.0  # it braked hard
    other = EVParams(units=CASE_UNITS)  # the ideal actuator: another plant
    with pytest.raises(ParameterError, match=r"plant\.ev"):
        ClosedLoop(lead, [SafeFallback.for_vehicle(law, other, 0.1)], other, plant=first.plant)
    with pytest.raises(ParameterError, match=r"plant\.rtol"):
        ClosedLoop(lead, [SafeFallback.for_vehicle(law, ev, 0.1)], ev, rtol=1e-8, plant=first.plant)


def test_a_case_runs_the_same_fresh_and_after_another_case(monkeypatch: pytest.MonkeyPatch) -> None:
    """The suite builds each MPC once per process and resets it before every run, and builds one plant per case and
    actuator: a case run after another case (MPCs used, warm starts and forecasts filled) equals, bit for bit, the
    same case run first on newly built MPCs."""
    import aev_ocp.safety.run as sr

    quick = {c.name: c for c in suite_cases(quick=True)}
    ctrls = ("mpc", "mpc+layer", "wave-mpc+layer", "proposed+layer")
    target = quick["CCRb_50kmh_12m_-6mps2"]
    monkeypatch.setattr(sr, "_POLICIES", {})
    monkeypatch.setattr(sr, "_WAVE", {})
    fresh = sr.run_suite([target], ctrls, actuators=("declared",))
    after = sr.run_suite([quick["laneend_100kmh_60m"], target], ctrls, actuators=("declared",))
    for c in ctrls:
        _same_runs(after.runs[target.name][f"declared/{c}"], fresh.runs[target.name][f"declared/{c}"])
    strip = lambda rows: [{**vars(x), "wall_s": 0.0} for x in rows if x.case == target.name]  # noqa: E731
    assert strip(after.rows) == strip(fresh.rows) and len(strip(fresh.rows)) == len(ctrls)

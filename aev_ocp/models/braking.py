"""The kinematic avoidability bound of a rear-end case: pure physics, SI units, no solver.

A case: the ego drives at ``v_ego_mps`` a gap ``gap_m`` behind a lead at ``v_lead_mps``; the lead keeps its
speed until ``t_brake_s`` and then brakes at ``a_lead_mps2`` (≤ 0) until it stops. The bound is the smallest
gap over time when the ego commands its maximal braking ``a_min`` from t = 0 on, realised through a first-order
actuator lag τ from a realised acceleration of 0 at t = 0 (a_e(t) = a_min (1 − e^(−t/τ)); τ = 0: a_e = a_min
at once; with a jerk limit J the rate of a_e is clipped to ±J as in the plant, :class:`_Ego`). Both cars stop at
v = 0 and never reverse. Between the breakpoints (the lead's braking start and stop, the end of the ego's
jerk-limited ramp, the ego's stop) the relative speed v_l − v_e is linear, quadratic (the ramp) or linear plus one
exponential, convex on each piece, so its zeros are found exactly (closed form / a bracketed root of a monotone piece) and the gap, in closed
form, is evaluated there: the minimum is exact to round-off.

No controller whose acceleration is bounded below by a_min (realised through the same lag) can keep a
larger gap than this bound at all times (it travels at least as far at every time), so:

* *avoidable*: the bound keeps the gap ≥ ``floor_m`` (the controller's standstill floor);
* *collision-avoidable only*: 0 < bound < floor_m;
* *unavoidable*: the bound reaches 0 (a collision whatever the controller does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..numerics import bracketed_root
from ..params import ParameterError, VehicleLimits

AVOIDABLE = "avoidable"
COLLISION_AVOIDABLE_ONLY = "collision-avoidable only"
UNAVOIDABLE = "unavoidable"
LABELS = (AVOIDABLE, COLLISION_AVOIDABLE_ONLY, UNAVOIDABLE)


@dataclass(frozen=True)
class BrakingBound:
    """The result of :func:`braking_bound`: min_gap_m [m] (≤ 0: contact), t_min_s [s] when it is reached
    (the first contact time when min_gap_m ≤ 0), stop_ego_s / stop_lead_s [s] when each car stops
    (inf: never), label (LABELS) against floor_m [m]."""

    min_gap_m: float
    t_min_s: float
    stop_ego_s: float
    stop_lead_s: float
    floor_m: float
    label: str


def _check(name: str, value: float, lo: float | None = None, hi: float | None = None, strict: bool = False) -> float:
    x = float(value)
    bad = not math.isfinite(x) or (lo is not None and (x <= lo if strict else x < lo)) or (hi is not None and x > hi)
    if bad:
        rng = f"{'>' if strict else '>='} {lo:g}" if lo is not None else ""
        rng += (" and " if rng and hi is not None else "") + (f"<= {hi:g}" if hi is not None else "")
        raise ParameterError(
            f"braking_bound: {name} = {value!r} is not allowed: must be a finite number {rng}".rstrip()
        )
    return x


class _Lead:
    """The lead: v0 until t_b, then decelerating at d = −a_l until it stops (closed-form speed and position)."""

    def __init__(self, v0: float, a_l: float, t_b: float) -> None:
        self.v0, self.a, self.tb = v0, a_l, t_b
        self.t_stop = t_b + v0 / -a_l if a_l < 0 else (0.0 if v0 == 0 else math.inf)

    def v(self, t: float) -> float:
        if t <= self.tb:
            return self.v0
        return max(self.v0 + self.a * (t - self.tb), 0.0)

    def a_at(self, t: float) -> float:
        return self.a if self.tb < t < self.t_stop else 0.0

    def x(self, t: float) -> float:
        if t <= self.tb:
            return self.v0 * t
        s = min(t, self.t_stop) - self.tb
        return self.v0 * self.tb + self.v0 * s + 0.5 * self.a * s * s


class _Ego:
    """The ego braking at a_min from t = 0 from a realised acceleration of 0, stopping at v = 0: the plant's actuator
    da/dt = (a_min − a)/τ with its rate clipped to ±J (:func:`aev_ocp.models.actuator.actuator_rate`).

    With J·τ < |a_min| the rate limit binds first: a = −J t up to t1 = (|a_min| − J τ)/J, then the lag
    a = a_min + J τ e^(−(t−t1)/τ); else (or J = None) the lag alone from t1 = 0, a = a_min (1 − e^(−t/τ)); τ = 0:
    the ramp (if any) then a_min at once. So a(t) = −J t on [0, t1], a_min + D e^(−(t−t1)/τ) after, D = a(t1) − a_min."""

    def __init__(self, v0: float, a_min: float, tau: float, jerk: float | None = None) -> None:
        self.v0, self.am, self.tau = v0, a_min, tau
        self.J = jerk
        if jerk is not None and jerk * tau < -a_min:  # the rate limit binds from t = 0 to t1
            self.t1 = (-a_min - jerk * tau) / jerk
            self.D = jerk * tau
        else:
            self.t1 = 0.0
            self.D = -a_min if tau > 0 else 0.0
        self.v1 = v0 - 0.5 * (jerk or 0.0) * self.t1**2
        self.x1 = v0 * self.t1 - (jerk or 0.0) * self.t1**3 / 6.0
        if v0 == 0.0:
            self.t_stop = 0.0
        elif self.v1 <= 0.0:  # stops during the ramp: v0 − J t²/2 = 0
            assert jerk is not None
            self.t_stop = math.sqrt(2.0 * v0 / jerk)
        elif tau == 0.0:
            self.t_stop = self.t1 + self.v1 / -a_min
        else:  # v decreases (a ≤ 0): one root, bracketed (v(t1 + τ + v0/|a_min|) ≤ 0, class docstring)
            self.t_stop = bracketed_root(self._v_raw, self.t1, self.t1 + tau + v0 / -a_min, 1e-15)

    def _exp(self, s: float) -> float:
        """τ (1 − e^(−s/τ)) (0 when τ = 0)."""
        return self.tau * -math.expm1(-s / self.tau) if self.tau > 0 else 0.0

    def _v_raw(self, t: float) -> float:
        if t <= self.t1:
            return self.v0 - 0.5 * (self.J or 0.0) * t * t
        s = t - self.t1
        return self.v1 + self.am * s + self.D * self._exp(s)

    def v(self, t: float) -> float:
        return 0.0 if t >= self.t_stop else max(self._v_raw(t), 0.0)

    def a_at(self, t: float) -> float:
        if t >= self.t_stop:
            return 0.0
        if t <= self.t1:
            return -(self.J or 0.0) * t
        s = t - self.t1
        return self.am + (self.D * math.exp(-s / self.tau) if self.tau > 0 else 0.0)

    def t_of_accel(self, target: float) -> float:
        """The time [s] at which the ego's acceleration (decreasing from 0 to a_min) equals ``target`` (≤ 0); inf when
        it never does before a_min (the lag only approaches a_min)."""
        if target >= 0.0:
            return 0.0
        if self.J is not None and self.t1 > 0.0 and target >= -self.J * self.t1:
            return -target / self.J
        if target > self.am and self.tau > 0 and self.D > 0:
            return self.t1 + self.tau * math.log(self.D / (target - self.am))
        return self.t1 if target <= self.am and self.tau == 0.0 and target == self.am else math.inf

    def x(self, t: float) -> float:
        s_all = min(t, self.t_stop)
        if s_all <= self.t1:
            return self.v0 * s_all - (self.J or 0.0) * s_all**3 / 6.0
        s = s_all - self.t1  # ∫ D τ (1 − e^(−s'/τ)) ds' = D τ (s − τ (1 − e^(−s/τ)))
        return self.x1 + self.v1 * s + 0.5 * self.am * s * s + self.D * self.tau * (s - self._exp(s))


def label_of(min_gap_m: float, floor_m: float) -> str:
    """The avoidability label of a bound min_gap_m [m] against a floor floor_m [m] (module docstring)."""
    if min_gap_m <= 0.0:
        return UNAVOIDABLE
    return AVOIDABLE if min_gap_m >= floor_m else COLLISION_AVOIDABLE_ONLY


def braking_bound(
    v_ego_mps: float,
    gap_m: float,
    v_lead_mps: float,
    a_lead_mps2: float,
    *,
    t_brake_s: float = 0.0,
    a_min_mps2: float = VehicleLimits().a_min_mps2,  # the default vehicle's (dry-road friction)
    lag_s: float = 0.0,
    floor_m: float = 2.0,
    jerk_max_mps3: float | None = None,
) -> BrakingBound:
    """The smallest gap [m] when the ego brakes at a_min_mps2 from t = 0 (through lag_s, its rate clipped to
    ±jerk_max_mps3 when given) behind a lead that keeps v_lead_mps until t_brake_s [s], then brakes at a_lead_mps2
    (≤ 0) until it stops (module docstring).

    Defaults: a_min −8 m/s², lag 0 and no jerk limit are :class:`aev_ocp.params.VehicleLimits`' defaults; floor 2 m
    is the traffic MPC's standstill gap (TrafficParams.standstill_gap_m). A plant with a jerk limit and no lag runs
    its actuator through VehicleLimits.actuator_tau_s: pass that as lag_s to match it."""
    v0 = _check("v_ego_mps", v_ego_mps, 0.0)
    g0 = _check("gap_m", gap_m, 0.0, strict=True)
    vl0 = _check("v_lead_mps", v_lead_mps, 0.0)
    al = _check("a_lead_mps2", a_lead_mps2, hi=0.0)
    tb = _check("t_brake_s", t_brake_s, 0.0)
    am = _check("a_min_mps2", a_min_mps2, hi=0.0)
    if am >= 0.0:
        raise ParameterError(f"braking_bound: a_min_mps2 = {a_min_mps2!r} is not allowed: must be < 0")
    tau = _check("lag_s", lag_s, 0.0)
    fl = _check("floor_m", floor_m, 0.0)
    jm = None if jerk_max_mps3 is None else _check("jerk_max_mps3", jerk_max_mps3, 0.0, strict=True)
    lead, ego = _Lead(vl0, al, tb), _Ego(v0, am, tau, jm)
    t_end = max(ego.t_stop, lead.t_stop if math.isfinite(lead.t_stop) else 0.0)
    brk = (tb, lead.t_stop, ego.t1)  # the lead's braking start and stop, the end of the ego's jerk-limited ramp
    cuts = sorted({0.0, ego.t_stop, *(b for b in brk if math.isfinite(b) and 0.0 < b < t_end), t_end})

    def rel(t: float) -> float:  # v_l − v_e: the gap's derivative
        return lead.v(t) - ego.v(t)

    def gap(t: float) -> float:
        return g0 + lead.x(t) - ego.x(t)

    cands = list(cuts)
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        if hi <= lo:
            continue
        # on (lo, hi) rel is smooth and convex (rel'' = −da_e/dt ≥ 0; linear when the ego's a is constant): split
        # at its minimiser, where the ego's decreasing acceleration equals the lead's (rel' = a_l − a_e = 0)
        pieces = [lo, hi]
        if lo < ego.t_stop:
            ts = ego.t_of_accel(lead.a_at(0.5 * (lo + hi)))
            if lo < ts < hi:
                pieces = [lo, ts, hi]
        for a, b in zip(pieces[:-1], pieces[1:]):
            ra, rb = rel(a + 0.0), rel(b)
            # one-sided values inside the piece (rel is continuous: the cars' speeds are)
            if ra == 0.0:
                cands.append(a)
            elif ra * rb < 0.0:
                cands.append(bracketed_root(rel, a, b, 1e-15))
    if not math.isfinite(lead.t_stop) and ego.t_stop < math.inf:
        pass  # after both cut points the lead drives on and the ego stands: the gap only grows
    cands = sorted(set(cands))
    gaps = [gap(t) for t in cands]
    k = int(np.argmin(gaps))
    g_min, t_min = float(gaps[k]), float(cands[k])
    if g_min <= 0.0:  # the first contact: the gap is decreasing before t_min, so bracket its first zero
        prev = [t for t in cands if t < t_min and gap(t) > 0.0]
        t_lo = prev[-1] if prev else 0.0
        t_min = bracketed_root(gap, t_lo, t_min, 1e-13) if gap(t_lo) > 0.0 else t_lo
    return BrakingBound(g_min, t_min, ego.t_stop, lead.t_stop, fl, label_of(g_min, fl))


def stopping_point_m(v_mps: float, b_mps2: float, reaction_s: float = 0.0) -> float:
    """How far [m] a car at v_mps travels before it stands when it brakes at b_mps2 (> 0) after reaction_s [s]:
    v t_r + v²/(2 b)."""
    return v_mps * reaction_s + v_mps * v_mps / (2.0 * b_mps2)

"""The braking-distance bound: the largest acceleration that keeps the braking-distance condition over one step.

Pure physics, SI units, no controller (the physics layer, beside :mod:`.kinematics`): the closed loop's safety stage
(:mod:`aev_ocp.loop`) and the safe fallback controller (:mod:`.fallback`, which re-exports these names) both use it.

The condition (a responsibility-sensitive-safety style stopping-distance rule): with the lead assumed to brake at
b_lead from now on and the ego at b_ego after a reaction time t_r, the ego can still stop s_min behind it,

    h − s_min ≥ v t_r + v²/(2 b_ego) − v_l²/(2 b_lead).

Equivalently the ego's stopping point P_e = x_e + v t_r + v²/(2 b_ego) stays s_min behind the lead's,
P_l = x_l + v_l²/(2 b_lead). P_l never moves back while the lead brakes at most at b_lead, and P_e never moves
forward while the ego brakes at b_ego (dP_e/dt = −b_ego t_r ≤ 0), so once the condition holds, maximal braking
keeps it and the gap stays ≥ s_min: it is invariant. :func:`safe_acceleration_mps2` returns the largest a in
[a_min, a_max] that, held over the next step of dt (the speed stopping at 0), keeps P_e(t) ≤ P_l − s_min at every
t of the step (exactly: P_e is piecewise polynomial in t, its maximum over the step is at an end, at the stop or
at its one stationary point); if none does (the condition already fails), maximal braking a_min. b_lead is raised
to the lead's measured deceleration when that is larger (a lead braking harder than assumed).

With an actuator lag τ the realised acceleration trails the command: starting from at most a_max it reaches
−b_ego later, which moves the stopping point by at most v τ (a_max + b_ego)/b_ego, so t_r is raised by
τ (a_max + b_ego)/b_ego (:func:`effective_reaction_s`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..params import ParameterError, VehicleLimits, spec, validate_fields

_DEFAULT_LIMITS = VehicleLimits()


@dataclass(frozen=True)
class SafetyParams:
    """The safe controller's parameters, SI. Sources beside each default."""

    standstill_gap_m: float = spec(2.0, ge=0.0)  # s_min: the traffic MPC's standstill floor (TrafficParams)
    reaction_time_s: float = spec(
        0.3, ge=0.0
    )  # t_r: the traffic MPC's braking-constraint reaction time (TrafficParams)
    ego_brake_mps2: float = spec(-_DEFAULT_LIMITS.a_min_mps2, gt=0.0)  # b_ego: VehicleLimits.a_min (dry-road friction)
    lead_brake_mps2: float = spec(-_DEFAULT_LIMITS.a_min_mps2, gt=0.0)  # b_lead: the same friction limit for the lead
    a_min_mps2: float = spec(_DEFAULT_LIMITS.a_min_mps2, lt=0.0)  # most braking the ego commands (VehicleLimits)
    a_max_mps2: float = spec(_DEFAULT_LIMITS.a_max_mps2, gt=0.0)  # most acceleration (VehicleLimits, ISO 22179)
    lag_s: float = spec(0.0, ge=0.0)  # actuator lag τ (VehicleLimits.lag_s)

    def __post_init__(self) -> None:
        validate_fields(self)
        if self.ego_brake_mps2 > -self.a_min_mps2 + 1e-12:
            raise ParameterError(
                f"SafetyParams.ego_brake_mps2 = {self.ego_brake_mps2} is not allowed: the ego cannot "
                f"brake harder than a_min_mps2 = {self.a_min_mps2} lets it"
            )

    @classmethod
    def from_limits(cls, limits: VehicleLimits, **changes: Any) -> "SafetyParams":
        """Braking, bounds and lag from a vehicle's limits (the defaults when the limits are off)."""
        lim = limits if limits.enabled else _DEFAULT_LIMITS
        kw: dict[str, Any] = {
            "ego_brake_mps2": -lim.a_min_mps2,
            "a_min_mps2": lim.a_min_mps2,
            "a_max_mps2": lim.a_max_mps2,
            "lag_s": lim.lag_s if limits.enabled else 0.0,
        }
        kw.update(changes)
        return cls(**kw)


def effective_reaction_s(p: SafetyParams) -> float:
    """t_r plus the lag's worst delay τ (a_max + b_ego)/b_ego [s] (module docstring)."""
    return p.reaction_time_s + p.lag_s * (p.a_max_mps2 + p.ego_brake_mps2) / p.ego_brake_mps2


def _stopping_point_peak(v: float, a: float, dt: float, t_r: float, b: float) -> float:
    """max over t ∈ [0, dt] of P_e(t) − x_e(0) = x_e(t) + v(t) t_r + v(t)²/(2 b) with a held (speed stops at 0)."""

    def P(t: float) -> float:
        if a < 0.0:
            t = min(t, v / -a) if v > 0 else 0.0
        vt = v + a * t
        return v * t + 0.5 * a * t * t + vt * t_r + vt * vt / (2.0 * b)

    cands = [0.0, dt]
    if -b < a < 0.0 and t_r > 0.0:  # dP/dt = v(t)(1 + a/b) + a t_r = 0 at one speed v*
        v_star = -a * t_r / (1.0 + a / b)
        t_star = (v_star - v) / a
        if 0.0 < t_star < dt:
            cands.append(t_star)
    return max(P(t) for t in cands)


def safe_acceleration_mps2(
    gap_m: float, v_mps: float, v_lead_mps: float, dt_s: float, p: SafetyParams | None = None, a_lead_mps2: float = 0.0
) -> float:
    """The largest acceleration [m/s²] in [a_min, a_max] that keeps the braking-distance condition over the next
    dt_s [s]; a_min if none does (module docstring). gap_m [m], speeds [m/s]; a_lead_mps2: the lead's measured
    acceleration (a deceleration beyond p.lead_brake_mps2 replaces it)."""
    p = p or SafetyParams()
    for nm, x in (
        ("gap_m", gap_m),
        ("v_mps", v_mps),
        ("v_lead_mps", v_lead_mps),
        ("dt_s", dt_s),
        ("a_lead_mps2", a_lead_mps2),
    ):
        if not math.isfinite(x):
            raise ParameterError(f"safe_acceleration_mps2: {nm} = {x!r} is not allowed: must be finite")
    if dt_s <= 0:
        raise ParameterError(f"safe_acceleration_mps2: dt_s = {dt_s!r} is not allowed: must be > 0")
    v, vl = max(v_mps, 0.0), max(v_lead_mps, 0.0)
    b_l = max(p.lead_brake_mps2, -a_lead_mps2)
    room = gap_m - p.standstill_gap_m + vl * vl / (2.0 * b_l)  # P_l − s_min − x_e(0)
    t_r, b = effective_reaction_s(p), p.ego_brake_mps2

    def ok(a: float) -> bool:
        return _stopping_point_peak(v, a, dt_s, t_r, b) <= room

    lo, hi = p.a_min_mps2, p.a_max_mps2
    if ok(hi):
        return hi
    if not ok(lo):
        return lo
    for _ in range(60):  # the peak grows with a: bisection on [lo ok, hi not ok]
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo

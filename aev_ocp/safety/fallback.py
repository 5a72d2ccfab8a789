"""A safe fallback: the largest acceleration that keeps the braking-distance condition after one step.

The condition (SI; a responsibility-sensitive-safety style stopping-distance rule): with the lead assumed to
brake at b_lead from now on and the ego at b_ego after a reaction time t_r, the ego can still stop s_min behind it,

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

:class:`SafeFallback` is this controller as a :class:`~aev_ocp.control.Controller`, combined with a
car-following law as min(law clipped to [a_min, a_max], safe): it equals the law wherever the law is safe,
and never accelerates into a gap it could not stop in. The MPC policy applies it as its fallback and, for the
traffic formulation, as a safety filter on every step (min(MPC, safe)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..control import Command, Observation
from ..models.carfollowing import CarFollowingLaw
from ..params import EVParams, ParameterError, Units, VehicleLimits, spec, validate_fields

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


@dataclass
class SafeFallback:
    """min(law, safe) as a Controller (model units in the Observation and the Command; SI inside).

    law: the car-following law (None: the safe controller alone, i.e. a_max where safe); units: the scenario's;
    params: the safe controller's; dt [model time]. :meth:`limit` applies the safe bound to any command (the MPC's
    safety filter); ``limited_steps`` counts the commands it lowered since :meth:`reset`."""

    law: CarFollowingLaw | None
    units: Units
    dt: float
    params: SafetyParams = field(default_factory=SafetyParams)
    name: str = "safe"
    limited_steps: int = 0
    braking_steps: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"SafeFallback.dt = {self.dt!r} is not allowed: must be > 0 (model time)")
        if self.law is not None:
            self.name = f"{self.law.name}+safe"

    @classmethod
    def for_vehicle(cls, law: CarFollowingLaw | None, ev: EVParams, dt: float, **changes: Any) -> "SafeFallback":
        """The fallback of a vehicle with ``ev``'s limits and units (``changes``: SafetyParams fields)."""
        return cls(law, ev.units, dt, SafetyParams.from_limits(ev.limits, **changes))

    @classmethod
    def for_mpc(cls, law: CarFollowingLaw, formulation: Any, dt: float, ev: EVParams) -> "SafeFallback":
        """The MPC's fallback and safety filter: the formulation's a bounds (within the vehicle's limits) and floor
        (its h_min; 0 when a problem sets none), the traffic formulation's reaction time (its default for the other
        formulations); ``formulation`` an :class:`aev_ocp.ocp.formulation.Formulation`, dt [model time]."""
        from ..ocp.traffic import TrafficParams  # noqa: PLC0415 - the default reaction time only

        u, b = ev.units, formulation.bounds_model(ev)
        lim = ev.limits if ev.limits.enabled else _DEFAULT_LIMITS
        # the formulation's a bounds, within the vehicle's limits when it has them (the plant enforces those anyway)
        a_min = float(u.accel_to_si(b.a_min)) if b.a_min is not None else lim.a_min_mps2
        a_max = float(u.accel_to_si(b.a_max)) if b.a_max is not None else lim.a_max_mps2
        if ev.limits.enabled:
            a_min, a_max = max(a_min, lim.a_min_mps2), min(a_max, lim.a_max_mps2)
        h_min = max(float(u.length_to_si(b.h_min)), 0.0) if b.h_min is not None else 0.0
        t_r = (formulation.traffic if formulation.kind == "traffic" else TrafficParams()).reaction_time_s
        return cls(
            law,
            u,
            dt,
            SafetyParams.from_limits(
                ev.limits,
                standstill_gap_m=h_min,
                a_min_mps2=a_min,
                a_max_mps2=a_max,
                ego_brake_mps2=-a_min,
                reaction_time_s=t_r,
            ),
        )

    @property
    def a_min(self) -> float:
        """The most braking it commands [model acceleration]."""
        return float(self.units.accel_from_si(self.params.a_min_mps2))

    @property
    def a_max(self) -> float:
        """The most acceleration it commands [model acceleration]."""
        return float(self.units.accel_from_si(self.params.a_max_mps2))

    def reset(self) -> None:
        """Zero the counters."""
        self.limited_steps = self.braking_steps = 0

    def safe_mps2(self, obs: Observation) -> float:
        """The safe bound [m/s²] at this observation (the lead's acceleration measured from its last two speeds)."""
        u = self.units
        h, v, vl = float(u.length_to_si(obs.z[0])), float(u.speed_to_si(obs.z[1])), float(u.speed_to_si(obs.meas_v[-1]))
        a_l = 0.0
        if len(obs.meas_v) >= 2 and obs.meas_t[-1] > obs.meas_t[-2]:
            a_l = float(u.accel_to_si((obs.meas_v[-1] - obs.meas_v[-2]) / (obs.meas_t[-1] - obs.meas_t[-2])))
        return safe_acceleration_mps2(h, v, vl, float(u.time_to_si(obs.dt)), self.params, a_l)

    def limit(self, obs: Observation, a: float) -> float:
        """min(a, safe) [model acceleration], never reversing over the step (a ≥ −v/dt); counts lowered commands."""
        u = self.units
        a_safe = float(u.accel_from_si(self.safe_mps2(obs)))
        if a_safe < a:
            self.limited_steps += 1
            a = a_safe
        if a <= float(u.accel_from_si(self.params.a_min_mps2)) + 1e-12:
            self.braking_steps += 1
        return max(a, min(0.0, -float(obs.z[1]) / obs.dt))

    def command(self, obs: Observation) -> Command:
        """The law (clipped to [a_min, a_max]) limited by the safe bound."""
        u = self.units
        lo, hi = float(u.accel_from_si(self.params.a_min_mps2)), float(u.accel_from_si(self.params.a_max_mps2))
        if self.law is None:
            a = hi
        else:
            a = float(self.law.function(max(float(obs.z[0]), 1e-6), float(obs.z[1]), float(obs.meas_v[-1])))
            a = min(max(a if math.isfinite(a) else lo, lo), hi)
        return Command(self.limit(obs, a))

    def describe(self) -> dict[str, Any]:
        """Settings and counters, for reports."""
        from ..params import as_dict

        return {
            "controller": self.name,
            "law": self.law.describe() if self.law is not None else None,
            "dt": self.dt,
            "safety": as_dict(self.params),
            "limited_steps": self.limited_steps,
            "max_braking_steps": self.braking_steps,
        }

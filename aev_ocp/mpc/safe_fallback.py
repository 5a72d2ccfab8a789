"""A safe fallback: the largest acceleration that keeps the braking-distance condition after one step.

The bound itself (:class:`SafetyParams`, :func:`safe_acceleration_mps2`, :func:`effective_reaction_s`) is pure
physics and lives in :mod:`.bound` (re-exported here): the closed loop's safety stage (:mod:`aev_ocp.loop`) applies
the same bound to any controller when a run declares it (``VehicleLimits.safety_layer``).

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
from ..fastcall import column_call
from ..models.carfollowing import CarFollowingLaw
from ..params import EVParams, ParameterError, Units
from ..models.safety_bound import (  # noqa: F401 - re-exported: the bound's names stay importable from here
    _DEFAULT_LIMITS,
    SafetyParams,
    _stopping_point_peak,
    effective_reaction_s,
    safe_acceleration_mps2,
)

__all__ = ["SafeFallback"]  # (the bound's names are documented in .bound)


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
            a = column_call(self.law.function).scalar(
                max(float(obs.z[0]), 1e-6), float(obs.z[1]), float(obs.meas_v[-1])
            )
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

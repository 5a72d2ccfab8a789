"""A vehicle's physical limits on its longitudinal motion (:class:`aev_ocp.params.VehicleLimits`), in model units.

The plant applies them to every controller's command, in this order:

1. saturation: a_sat = min(max(a_cmd, a_min), a_max);
2. actuator (when ``limits.has_actuator_state``): the realised acceleration a_act is a state,
   da_act/dt = (a_sat − a_act)/τ, the rate clipped to ±jerk_max when a jerk limit is set; else a_act = a_sat;
3. speed range: the realised acceleration is cut to ≤ 0 at v ≥ v_max (top speed) and to ≥ 0 at v ≤ V_STOP
   (the brakes hold a stopped car, they never reverse it; V_STOP is a speed far below any sensor's resolution,
   so a controller that brakes to a stop with a ≥ −v/dt, which leaves v decaying geometrically over its steps,
   is held there instead of driving the integrator through speeds of 1e-140 where CVODES fails). Both are one-sided switches of the right-hand side
   (an ``if_else`` on v): a trajectory reaching v_max or 0 stays there (dv/dt = 0), so adaptive integrators
   cross each switch once, with one rejected step, and never chatter.

Every function works on floats, NumPy arrays and CasADi SX/MX alike (the plant, the compiled cascade and
any CasADi user see the same model). With ``limits.enabled`` False nothing here is applied (the plant does
not even build these expressions: the paper's unbounded laws, bit for bit).
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from ..params import Units, VehicleLimits

#: The speed [model] at or below which a car with limits is stopped: the brakes hold it (see module docstring).
#: 1e-9 model speed is 5e-9 m/s at the default units (a metre in 6 years); below it v only matters to round-off.
V_STOP = 1e-9


def saturate(a_cmd: Any, limits: VehicleLimits, units: Units) -> Any:
    """a_cmd [model acceleration] clipped to [a_min, a_max] of ``limits`` (unchanged when the limits are off)."""
    if not limits.enabled:
        return a_cmd
    lo, hi = limits.accel_bounds_model(units)
    return ca.fmin(ca.fmax(a_cmd, lo), hi)


def actuator_rate(a_sat: Any, a_act: Any, limits: VehicleLimits, units: Units) -> Any:
    """da_act/dt [model acceleration per model time] = (a_sat − a_act)/τ, clipped to ±jerk_max when set."""
    tau = units.time_from_si(limits.actuator_tau_s)
    rate = (a_sat - a_act) / tau
    if limits.jerk_max_mps3 is not None:
        j = float(units.accel_from_si(limits.jerk_max_mps3) * units.time_s)  # m/s³ -> model accel / model time
        rate = ca.fmin(ca.fmax(rate, -j), j)
    return rate


def speed_cut(a: Any, v: Any, limits: VehicleLimits, units: Units) -> Any:
    """The acceleration the car realises at speed v [model]: a cut to ≤ 0 at v ≥ v_max and to ≥ 0 at v ≤ V_STOP."""
    if not limits.enabled:
        return a
    v_max = float(units.speed_from_si(limits.v_max_mps))
    return ca.if_else(v >= v_max, ca.fmin(a, 0), ca.if_else(v <= V_STOP, ca.fmax(a, 0), a))

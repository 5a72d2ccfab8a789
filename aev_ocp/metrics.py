"""Per-vehicle metrics of model guide §10, computed from a :class:`SimulationResult`.

Integrals (ω, pack ∫Q, ∫Q_irr, RMS errors, RMS jerk of smooth laws) come from the plant's own
quadratures, so they are exact across control jumps. Battery energy ∫P_b dt [J] — *the* energy of every table
(``battery_energy_kWh_per_100km``) — comes from the plant's quadrature (``SimulationResult.battery_energy_J``:
a platoon of closed-form laws in the compiled cascade or the CVODES plant, the ring, SUMO) and, for a closed loop
with commanded vehicles (held over each sample interval) or an output saved before the plants integrated it, from
the trapezoid of the exact P_b(v, a) over the samples (:func:`battery_energy_J`). ω is the paper's measure (``omega_*`` keys), not an energy of the battery. The minimum gap is taken over the continuous
trajectory: the smallest sample is refined by the cubic Hermite interpolant of h with ḣ = v_l − v
on its two neighbouring intervals.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np

from .models.carfollowing import optimal_velocity
from .models.powertrain import battery_power_W
from .models.vehicle import wheel_power_W
from .params import VehicleParams
from .numerics import BOUND_TOLERANCE
from .models.thermal import temperature_metrics

#: A :class:`aev_ocp.results.SimulationResult`. Not imported: ``SimulationResult.metrics()`` imports this module,
#: and the layer table allows no cycle (tests/contracts/test_layers.py); the functions read its attributes only.
SimulationResult = Any

MPC_GAP_MIN = 0.2  # model guide §9: h ≥ 0.2 (2 m)
MPC_SPEED_MAX = 2.0  # model guide §9: 0 ≤ v ≤ 2


def _hermite_min(t0: float, t1: float, y0: float, y1: float, d0: float, d1: float) -> float:
    """Minimum of the cubic Hermite interpolant on [t0, t1] (values y, slopes d)."""
    dt = t1 - t0
    if dt <= 0:
        return min(y0, y1)
    # p(s) = h00 y0 + h10 dt d0 + h01 y1 + h11 dt d1, s ∈ [0,1]; p'(s) = a s² + b s + c
    a = 6 * y0 + 3 * dt * d0 - 6 * y1 + 3 * dt * d1
    b = -6 * y0 - 4 * dt * d0 + 6 * y1 - 2 * dt * d1
    c = dt * d0
    cands = [0.0, 1.0]
    if abs(a) > 1e-15:
        disc = b * b - 4 * a * c
        if disc >= 0:
            r = math.sqrt(disc)
            cands += [(-b + r) / (2 * a), (-b - r) / (2 * a)]
    elif abs(b) > 1e-15:
        cands.append(-c / b)
    best = min(y0, y1)
    for s in cands:
        if 0.0 <= s <= 1.0:
            h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
            best = min(best, h00 * y0 + h10 * dt * d0 + h01 * y1 + h11 * dt * d1)
    return best


def min_gap_continuous(t: np.ndarray, h: np.ndarray, hdot: np.ndarray) -> float:
    """Minimum of h(t) over the continuous trajectory [model length] (Hermite refinement near the smallest sample)."""
    k = int(np.argmin(h))
    best = float(h[k])
    for j in (k - 1, k):
        if 0 <= j < t.size - 1:
            best = min(best, _hermite_min(t[j], t[j + 1], h[j], h[j + 1], hdot[j], hdot[j + 1]))
    return best


J_PER_KWH = 3.6e6


@lru_cache(maxsize=16)
def _battery_power(p: VehicleParams) -> ca.Function:
    """P_b(v [m/s], a [m/s²]) [W] of the vehicle's exact powertrain, mapped over samples."""
    v, a = ca.SX.sym("v"), ca.SX.sym("a")
    return ca.Function("battery_power", [v, a], [battery_power_W(wheel_power_W(v, a, p), p)])


def battery_energy_J(r: SimulationResult, i: int) -> float:
    """Battery energy ∫P_b dt of follower i over the run [J]: the plant's quadrature when it has one, else the
    trapezoid of the exact P_b(v, a) on the samples (a command held over a sample interval: P_b at both ends with
    the held acceleration)."""
    if getattr(r, "battery_energy_J", None) is not None:
        e = r.battery_energy_J[:, i]
        return float(e[-1] - e[0])
    u = r.units
    t = np.asarray(r.t, float)
    if t.size < 2:
        return 0.0
    v = u.speed_to_si(np.asarray(r.speed[:, i], float))
    a = u.accel_to_si(np.asarray(r.accel[:, i], float))
    f = _battery_power(r.ev.vehicle).map(t.size - 1)
    P0 = np.asarray(f(v[None, :-1], a[None, :-1])).ravel()
    P1 = np.asarray(f(v[None, 1:], a[None, :-1] if r.jerk_sampled else a[None, 1:])).ravel()
    return float(np.sum(np.diff(t) * u.time_s * (P0 + P1) / 2))


def charge_throughput_Ah(r: SimulationResult, i: int) -> float:
    """The pack's charge throughput ∫|I_pack| dt of follower i [Ah] (trapezoid of the sampled cell current × N_p)."""
    I = np.abs(np.asarray(r.current_A[:, i], float))
    t_s = np.asarray(r.t, float) * r.units.time_s
    if t_s.size < 2 or not np.all(np.isfinite(I)):
        return math.nan
    return float(np.sum(np.diff(t_s) * (I[1:] + I[:-1]) / 2)) * r.ev.pack.n_parallel / 3600.0


def violation_bounds(r: SimulationResult, i: int) -> tuple[float, float]:
    """(h_min, v_max) [model units] that follower i's gap and speed violations count against: its controller's
    own declared bounds (``describe()['bounds_model']``, an MPC's formulation; a missing side: no bound, ∓inf),
    else model guide §9's (MPC_GAP_MIN, MPC_SPEED_MAX)."""
    ctrls = r.meta.get("controllers") or []
    own = ctrls[i].get("bounds_model") if i < len(ctrls) and isinstance(ctrls[i], dict) else None
    if not own:
        return MPC_GAP_MIN, MPC_SPEED_MAX
    h, v = own.get("h_min"), own.get("v_max")
    return (float(h) if h is not None else -math.inf), (float(v) if v is not None else math.inf)


def bound_violations(h: np.ndarray, v: np.ndarray, h_min: float, v_max: float) -> tuple[int, int]:
    """(gap, speed) samples beyond their bounds [model units]: h below h_min, v below 0 or above v_max, each by more
    than the tolerance plans are accepted with (:data:`aev_ocp.numerics.BOUND_TOLERANCE`); h_min = −inf, v_max = inf:
    no such bound."""
    tol = BOUND_TOLERANCE
    return int(np.sum(h < h_min - tol)), int(np.sum((v < -tol) | (v > v_max + tol)))


def vehicle_metrics(r: SimulationResult, i: int) -> dict[str, Any]:
    """All §10 metrics of follower i (0-based) as a flat dict; units in the key names."""
    u = r.units
    t = r.t
    duration = float(t[-1] - t[0]) if t.size > 1 else 0.0
    v_lead = r.leader_speed if i == 0 else r.speed[:, i - 1]
    h, v = r.gap[:, i], r.speed[:, i]
    hdot = v_lead - v
    # violations count against the vehicle's controller's own bounds (an MPC states its formulation's: the
    # traffic formulation's 2 m floor and 45 m/s, in model units; None = no such bound), else model guide §9's
    h_min, v_max = violation_bounds(r, i)
    n_gap, n_speed = bound_violations(h[1:], v[1:], h_min, v_max)

    def rms(c: np.ndarray) -> float:
        return math.sqrt(max(float(c[-1, i]), 0.0) / duration) if duration > 0 else float("nan")

    if r.jerk_sampled and t.size > 1:
        da = np.diff(r.accel[:, i]) / np.diff(t)
        rms_jerk = float(math.sqrt(np.sum(da**2 * np.diff(t)) / duration))
    else:
        rms_jerk = rms(r.int_jerk2)
    min_gap = min_gap_continuous(t, h, hdot)
    omega = float(r.omega[-1, i])
    kinds = [e.kind for e in r.events if e.vehicle == i]
    out: dict[str, Any] = {
        "vehicle": i + 1,
        "controller": r.controllers[i],
        # the event that stopped this vehicle, else 'violated' (below its controller's own hard floor), else 'ok'
        "status": kinds[0] if kinds else ("violated" if any(e.vehicle == i for e in r.violations) else "ok"),
        "run_status": r.status,  # 'ok' or the event that stopped the whole run (possibly another vehicle's)
        "duration_model": duration,
        "battery_energy_J": battery_energy_J(r, i),
        "omega_model": omega,
        "omega_J_per_kg": float(u.energy_per_mass_to_si(omega)),
        "heat_pack_J": float(r.heat_J[-1, i]),
        "heat_irr_pack_J": float(r.heat_irr_J[-1, i]),
        "delta_soc": float(r.S[-1, i] - r.S[0, i]),
        "min_gap_model": min_gap,
        "min_gap_m": float(u.length_to_si(min_gap)),
        "min_speed_model": float(np.min(v)),
        "max_speed_model": float(np.max(v)),
        "rms_ovm_error_model": rms(r.int_ovm_err2),
        "rms_rel_speed_model": rms(r.int_rel_speed2),
        "rms_jerk_model": rms_jerk,
        "max_abs_current_A": float(np.nanmax(np.abs(r.current_A[:, i])))
        if np.isfinite(r.current_A[:, i]).any()
        else float("nan"),
        "gap_violations": n_gap,
        "speed_violations": n_speed,
        "collisions": kinds.count("collision"),
        "infeasible_current": kinds.count("infeasible_current"),
        "final_ovm_error_model": float(optimal_velocity(h[-1]) - v[-1]),
    }
    if r.temperature_K is not None:  # the lumped pack temperature: peak, time-mean, time above the limit
        tm = temperature_metrics(u.time_to_si(t), r.temperature_K[:, i], r.ev.thermal.T_max_K)
        out.update(
            {
                "peak_temperature_K": tm["peak_K"],
                "mean_temperature_K": tm["mean_K"],
                "time_above_T_max_s": tm["time_above_s"],
            }
        )
    out.update(distance_metrics(r, i, duration))
    out.update(si_twins(out, u))
    stats = r.solver_stats[i] if i < len(r.solver_stats) else None
    if stats:
        out.update(stats)
    return out


#: SI twins of the model-unit metrics: model key -> (SI key, dimension). Distance, duration, gap, TTC and ω
#: have their SI keys beside them already (distance_m, duration_s, min_gap_m, min_ttc_s, omega_J_per_kg).
SI_METRICS: dict[str, tuple[str, str]] = {
    "min_speed_model": ("min_speed_mps", "speed"),
    "max_speed_model": ("max_speed_mps", "speed"),
    "rms_ovm_error_model": ("rms_ovm_error_mps", "speed"),
    "rms_rel_speed_model": ("rms_rel_speed_mps", "speed"),
    "final_ovm_error_model": ("final_ovm_error_mps", "speed"),
    "rms_jerk_model": ("rms_jerk_mps3", "jerk"),
}


def si_twins(m: dict[str, Any], u: Any) -> dict[str, float]:
    """The SI values of the model-unit metrics in ``m`` that have no SI key yet (:data:`SI_METRICS`), converted
    with the units ``u`` (speed U [m/s], jerk U³/L² [m/s³])."""
    factor = {"speed": u.speed_mps, "jerk": u.accel_mps2 / u.time_s}
    return {si: float(m[k]) * factor[dim] for k, (si, dim) in SI_METRICS.items() if k in m and si not in m}


def si_first(columns: list[str]) -> list[str]:
    """Metric columns in a stable order with the model-unit ones (``*_model``, ``*_model_*``) after the others,
    so that tables lead with SI."""
    is_model = lambda c: c.endswith("_model") or "_model_" in c  # noqa: E731
    return [c for c in columns if not is_model(c)] + [c for c in columns if is_model(c)]


def metrics_table(r: SimulationResult) -> list[dict[str, Any]]:
    """Metrics of every follower."""
    return [vehicle_metrics(r, i) for i in range(r.n_vehicles)]


# ----------------------------------------------------------------------------- comparable results
#: Runs whose distance or duration differ from the reference's by more than this fraction are flagged.
COMPARABLE_REL_TOL = 0.01


def min_time_to_collision(t: np.ndarray, h: np.ndarray, closing_speed: np.ndarray) -> float:
    """Smallest time-to-collision h / (v − v_l) over the samples where the follower closes in
    (v > v_l) [model time]; inf if it never closes in. Samples only: TTC is a sampled safety indicator."""
    closing = closing_speed > 1e-12
    if not np.any(closing):
        return math.inf
    return float(np.min(h[closing] / closing_speed[closing]))


def distance_metrics(r: SimulationResult, i: int, duration: float | None = None) -> dict[str, Any]:
    """Distance travelled, duration, ω and pack heat per km and the minimum time-to-collision of follower i.

    Keys: distance_model [model length], distance_m [m], duration_s [s], battery_energy_J_per_km [J/km] and
    battery_energy_kWh_per_100km (∫P_b, :func:`battery_energy_J`), charge_throughput_Ah_per_km [Ah/km] (the pack's),
    omega_model_per_km [the paper's ω per km, model units], omega_J_per_kg_per_km [J/kg/km], heat_pack_J_per_km [J/km],
    heat_irr_pack_J_per_km [J/km], min_ttc_model [model time], min_ttc_s [s] (inf: never closing in).
    The distance is x_i(t_end) − x_i(0) from the sampled positions (exact at the samples); per-km
    values are nan when the follower did not move."""
    u = r.units
    t = r.t
    if duration is None:
        duration = float(t[-1] - t[0]) if t.size > 1 else 0.0
    x = r.positions()[:, i]
    dist = float(x[-1] - x[0]) if t.size > 1 else 0.0
    dist_m = float(u.length_to_si(dist))
    km = dist_m / 1000.0

    def per_km(q: float) -> float:
        return q / km if km > 1e-12 else float("nan")

    omega = float(r.omega[-1, i])
    e_b = battery_energy_J(r, i)
    v_lead = r.leader_speed if i == 0 else r.speed[:, i - 1]
    ttc = min_time_to_collision(t, r.gap[:, i], r.speed[:, i] - v_lead)
    return {
        "distance_model": dist,
        "distance_m": dist_m,
        "duration_s": duration * u.time_s,
        "battery_energy_J_per_km": per_km(e_b),
        "battery_energy_kWh_per_100km": per_km(e_b) * 100.0 / J_PER_KWH,
        "charge_throughput_Ah_per_km": per_km(charge_throughput_Ah(r, i)),
        "omega_model_per_km": per_km(omega),
        "omega_J_per_kg_per_km": per_km(float(u.energy_per_mass_to_si(omega))),
        "heat_pack_J_per_km": per_km(float(r.heat_J[-1, i])),
        "heat_irr_pack_J_per_km": per_km(float(r.heat_irr_J[-1, i])),
        "min_ttc_model": ttc,
        "min_ttc_s": ttc * u.time_s,
    }


def _rel_diff(a: Any, b: Any) -> float:
    try:
        a, b = float(a), float(b)
    except (TypeError, ValueError):
        return float("nan")
    if not (math.isfinite(a) and math.isfinite(b)):
        return float("nan")
    if b == 0.0:
        return 0.0 if a == 0.0 else math.inf
    return (a - b) / abs(b)


def comparability(m: dict[str, Any], ref: dict[str, Any] | None, rel_tol: float = COMPARABLE_REL_TOL) -> dict[str, Any]:
    """Whether the metrics ``m`` of one vehicle can be ranked beside those of the same vehicle under the
    reference controller (``ref``; None when the reference run is missing or failed).

    Returns distance_diff_pct and duration_diff_pct [%] (m relative to ref), and the flags
    flag_distance / flag_duration (differs by more than ``rel_tol``, or cannot be compared),
    flag_event (m's run ended by an event: a collision, negative speed, ...; a run that only went below its
    controller's floor, status 'violated', ran to the end: its status column says so) and comparable (no
    flag set). A run is comparable with itself."""
    ended = str(m.get("run_status", m.get("status", "ok"))) not in ("ok", "violated")  # violated: ran to the end
    if ref is None:
        dd = du = float("nan")
    else:
        dd = _rel_diff(m.get("distance_m"), ref.get("distance_m"))
        du = _rel_diff(m.get("duration_s"), ref.get("duration_s"))
    flag_d = not (math.isfinite(dd) and abs(dd) <= rel_tol)
    flag_t = not (math.isfinite(du) and abs(du) <= rel_tol)
    return {
        "distance_diff_pct": 100 * dd,
        "duration_diff_pct": 100 * du,
        "flag_distance": flag_d,
        "flag_duration": flag_t,
        "flag_event": ended,
        "comparable": not (flag_d or flag_t or ended),
    }

"""Runs cut at a time or a distance, so runs of different length get a verdict.

Runs that end at different distances (an MPC that drops back 25 m in a braking test) are not comparable
over their whole length. :func:`truncate_at_time` and :func:`truncate_at_distance` cut a
:class:`~aev_ocp.results.SimulationResult` exactly at a time or at a travelled distance of one follower (the
state is interpolated at the cut, not taken from the nearest sample), and :func:`equal_views` evaluates
every run up to the shortest common distance and up to the common time, where every run is comparable by
construction, and ranks them.

Interpolation inside the sample interval [t_k, t_k+1] that holds the cut: positions and gaps by the cubic
Hermite interpolant with their exact derivatives (ẋ = v, ḣ = v_ahead − v), speeds by the Hermite interpolant with
v̇ = a (a held over the interval when the controller is sampled: exact), the held command itself, and the cell
states and the plant's cumulative quadratures (ω, pack ∫Q, ∫Q_irr, ∫ errors²) by the quadratic through the
interval's ends and a third sample on the same smooth piece (the same held command), error O(Δt³); linearly
when there is none. Model units unless named.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Mapping

import numpy as np

from .params import ParameterError
from .results import SIM_ARRAYS, SimulationResult

#: interpolated like the smooth pieces they are: the cell states, current and integrals (every array after accel)
#: and the leader's speed
_LINEAR = (*SIM_ARRAYS[SIM_ARRAYS.index("V1") :], "leader_speed")


def _hermite(y0: Any, y1: Any, d0: Any, d1: Any, dt: float, s: float) -> Any:
    """Cubic Hermite interpolant at s ∈ [0, 1] of an interval of length dt (values y, slopes d)."""
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * dt * d0 + h01 * y1 + h11 * dt * d1


def _ahead_speed(r: SimulationResult) -> np.ndarray:
    """(K, n) speed of each follower's predecessor (the leader for follower 1)."""
    return np.hstack([r.leader_speed[:, None], r.speed[:, :-1]])


def truncate_at_time(r: SimulationResult, t_cut: float) -> SimulationResult:
    """``r`` up to ``t_cut`` [model time] (t_0 < t_cut ≤ t_end): its samples before the cut and the state at the
    cut (module docstring). Events after the cut are dropped; whole-run solver statistics are not carried."""
    t = r.t
    if not (math.isfinite(t_cut) and t[0] < t_cut <= t[-1] + 1e-12 * max(1.0, abs(t[-1]))):
        raise ParameterError(f"truncate: t_cut = {t_cut!r} must lie in ({t[0]:g}, {t[-1]:g}] (the run's time span)")
    t_cut = min(float(t_cut), float(t[-1]))
    k = int(np.searchsorted(t, t_cut, side="right")) - 1  # t[k] <= t_cut < t[k+1]
    tol = 1e-12 * max(1.0, abs(t_cut))
    fields: dict[str, Any] = {}
    lin = _LINEAR + tuple(nm for nm in ("temperature_K", "battery_energy_J") if getattr(r, nm) is not None)
    names = ("leader_position", "gap", "speed", "accel") + lin
    if abs(t[k] - t_cut) <= tol or k == t.size - 1:
        for nm in names:
            fields[nm] = getattr(r, nm)[: k + 1].copy()
        fields["t"] = t[: k + 1].copy()
    else:
        dt = float(t[k + 1] - t[k])
        s = (t_cut - float(t[k])) / dt
        cut: dict[str, Any] = {}
        j = _third_node(r, k)
        for nm in lin:
            y = getattr(r, nm)
            if j is None:
                cut[nm] = y[k] + s * (y[k + 1] - y[k])
            else:  # the quadratic through t_k, t_k+1 and a third node of the same smooth piece
                n = (k, k + 1, j)
                cut[nm] = sum(y[a] * math.prod((t_cut - t[b]) / (t[a] - t[b]) for b in n if b != a) for a in n)
        cut["leader_position"] = _hermite(
            r.leader_position[k], r.leader_position[k + 1], r.leader_speed[k], r.leader_speed[k + 1], dt, s
        )
        a0 = r.accel[k]
        a1 = r.accel[k] if r.jerk_sampled else r.accel[k + 1]  # a held over the interval: v is linear in it
        cut["speed"] = _hermite(r.speed[k], r.speed[k + 1], a0, a1, dt, s)
        cut["accel"] = r.accel[k].copy() if r.jerk_sampled else r.accel[k] + s * (r.accel[k + 1] - r.accel[k])
        va = _ahead_speed(r)
        cut["gap"] = _hermite(r.gap[k], r.gap[k + 1], va[k] - r.speed[k], va[k + 1] - r.speed[k + 1], dt, s)
        for nm in names:
            y = getattr(r, nm)
            fields[nm] = np.concatenate([y[: k + 1], np.asarray(cut[nm])[None, ...]], axis=0)
        fields["t"] = np.concatenate([t[: k + 1], [t_cut]])
    meta = {**r.meta, "truncated_at_model": t_cut}
    return replace(r, **fields, events=[e for e in r.events if e.time <= t_cut + tol], solver_stats=[], meta=meta)


def _third_node(r: SimulationResult, k: int) -> int | None:
    """A third sample beside t_k, t_k+1 on the same smooth piece of the run (a sampled controller's command held
    unchanged; a continuous law everywhere), for the quadratic interpolant; None if there is none."""
    K = r.t.size
    for j in (k - 1, k + 2):
        if 0 <= j < K and (not r.jerk_sampled or np.array_equal(r.accel[j], r.accel[k])):
            if r.jerk_sampled and j == k + 2 and not np.array_equal(r.accel[k + 1], r.accel[k]):
                continue
            return j
    return None


def distance_travelled(r: SimulationResult, i: int) -> np.ndarray:
    """x_i(t) − x_i(t_0) of follower i at the samples [model length]."""
    x = r.positions()[:, i]
    return x - x[0]


def time_at_distance(r: SimulationResult, i: int, distance: float) -> float:
    """The first time [model time] at which follower i has travelled ``distance`` [model length] (the Hermite
    interpolant of its position with ẋ = v, solved by bisection); ParameterError if it never does."""
    d = distance_travelled(r, i)
    if not (math.isfinite(distance) and 0.0 < distance <= d[-1] * (1 + 1e-12)):
        raise ParameterError(
            f"truncate: distance {distance!r} must lie in (0, {d[-1]:g}] (follower {i + 1}'s "
            "distance travelled, model length)"
        )
    distance = min(distance, float(d[-1]))
    k = int(np.searchsorted(d, distance, side="left"))  # d[k-1] < distance <= d[k]
    if k == 0 or d[k] == distance:
        return float(r.t[k])
    t0, t1 = float(r.t[k - 1]), float(r.t[k])
    v0, v1 = r.speed[k - 1, i], r.speed[k, i]  # exact slopes: a quadratic x (a held) is reproduced exactly
    lo, hi = 0.0, 1.0
    for _ in range(80):  # x is non-decreasing (v ≥ 0): bisection to machine precision
        mid = 0.5 * (lo + hi)
        if _hermite(d[k - 1], d[k], v0, v1, t1 - t0, mid) < distance:
            lo = mid
        else:
            hi = mid
    return t0 + 0.5 * (lo + hi) * (t1 - t0)


def truncate_at_distance(r: SimulationResult, i: int, distance_m: float) -> SimulationResult:
    """``r`` up to the time follower i has travelled ``distance_m`` [m]."""
    return truncate_at_time(r, time_at_distance(r, i, float(r.units.length_from_si(distance_m))))


#: The metrics each view reports (and ranks by the first), per run.
VIEW_KEYS = ("heat_pack_J_per_km", "heat_pack_J", "omega_J_per_kg_per_km", "distance_m", "duration_s", "min_gap_m")


def equal_views(results: Mapping[Any, SimulationResult], vehicle: int = 0) -> dict[str, Any]:
    """Every run of follower ``vehicle`` evaluated up to the shortest common distance ('distance') and up to the
    common time ('time'), ranked by pack ∫Q/km (1 = lowest). Runs ended by an event are left out of the cut and
    not ranked. Returns {'distance': {'cut_m', 'runs': {label: metrics}}, 'time': {'cut_s', 'runs': …}}."""
    from .metrics import vehicle_metrics

    ok = {lab: r for lab, r in results.items() if not r.events and r.t.size > 1}
    out: dict[str, Any] = {"distance": {"cut_m": math.nan, "runs": {}}, "time": {"cut_s": math.nan, "runs": {}}}
    if not ok:
        return out
    first = next(iter(ok.values()))
    d_cut = min(float(distance_travelled(r, vehicle)[-1]) for r in ok.values())
    t_cut = min(float(r.t[-1]) for r in ok.values())
    views = {}
    if d_cut > 0:
        out["distance"]["cut_m"] = float(first.units.length_to_si(d_cut))
        views["distance"] = {lab: truncate_at_time(r, time_at_distance(r, vehicle, d_cut)) for lab, r in ok.items()}
    if t_cut > max(float(r.t[0]) for r in ok.values()):
        out["time"]["cut_s"] = float(first.units.time_to_si(t_cut))
        views["time"] = {lab: truncate_at_time(r, t_cut) for lab, r in ok.items()}
    for view, runs in views.items():
        rows = {}
        for lab, tr in runs.items():
            m = vehicle_metrics(tr, vehicle)
            rows[lab] = {k: m[k] for k in VIEW_KEYS}
        order = sorted(
            (lab for lab in rows if math.isfinite(rows[lab][VIEW_KEYS[0]])), key=lambda x: rows[x][VIEW_KEYS[0]]
        )
        for lab in rows:
            rows[lab]["rank"] = order.index(lab) + 1 if lab in order else None
        out[view]["runs"] = rows
    return out


# ----------------------------------------------------------------------------- compact profiles (studies)
#: Samples a study keeps of each run (every k-th output sample and the last) to evaluate it later at a cut.
PROFILE_POINTS = 1001
PROFILE_VIEW_KEY = "heat_pack_J_per_km"


def cumulative_profile(r: SimulationResult, i: int, points: int = PROFILE_POINTS) -> dict[str, list[float]]:
    """Follower i's distance travelled [m], time [s] and cumulative pack ∫Q [J] at no more than ``points``
    samples of the run (every k-th and the last): what a study task keeps so that the runs of one point, made in
    different processes, can be cut at their common distance or time afterwards (:func:`equal_profile_views`)."""
    if points < 2:
        raise ParameterError(f"cumulative_profile: points = {points!r} must be >= 2")
    u = r.units
    d = np.asarray(u.length_to_si(distance_travelled(r, i)), float)
    t = np.asarray(u.time_to_si(r.t - r.t[0]), float)
    q = np.asarray(r.heat_J[:, i] - r.heat_J[0, i], float)
    step = max(1, -(-(t.size - 1) // (points - 1)))
    idx = np.unique(np.append(np.arange(0, t.size, step), t.size - 1))
    return {"distance_m": d[idx].tolist(), "t_s": t[idx].tolist(), "heat_pack_J": q[idx].tolist()}


def _heat_at(profile: Mapping[str, Any], key: str, cut: float) -> float:
    """Cumulative pack ∫Q [J] of a profile at distance or time ``cut`` (linear between its samples; the first time
    the distance is reached)."""
    x = np.asarray(profile[key], float)
    q = np.asarray(profile["heat_pack_J"], float)
    if key == "distance_m":  # standing still repeats a distance: keep the first sample of each
        x, first = np.unique(x, return_index=True)
        q = q[first]
    return float(np.interp(cut, x, q))


def equal_profile_views(profiles: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The study twin of :func:`equal_views` on compact profiles ({label: :func:`cumulative_profile`}) of the runs of
    one point: pack ∫Q per km up to the shortest common distance ('distance', cut_m) and up to the common time
    ('time', cut_s), each ranked (1 = lowest). The cut value is interpolated linearly between the kept samples
    (≤ PROFILE_POINTS per run), so it is a table's evaluation, not :func:`truncate_at_time`'s exact one."""
    out: dict[str, Any] = {"distance": {"cut_m": math.nan, "runs": {}}, "time": {"cut_s": math.nan, "runs": {}}}
    ok = {lab: p for lab, p in profiles.items() if p and len(p.get("t_s", [])) > 1}
    if not ok:
        return out
    d_cut = min(float(p["distance_m"][-1]) for p in ok.values())
    t_cut = min(float(p["t_s"][-1]) for p in ok.values())
    for view, key, cut, cut_key in (("distance", "distance_m", d_cut, "cut_m"), ("time", "t_s", t_cut, "cut_s")):
        if not cut > 0:
            continue
        out[view][cut_key] = cut
        rows: dict[str, dict[str, Any]] = {}
        for lab, p in ok.items():
            dist = (
                cut if view == "distance" else float(np.interp(cut, np.asarray(p["t_s"]), np.asarray(p["distance_m"])))
            )
            heat = _heat_at(p, key, cut)
            rows[lab] = {PROFILE_VIEW_KEY: heat / (dist / 1000.0) if dist > 0 else math.nan, "heat_pack_J": heat}
        order = sorted(
            (lab for lab in rows if math.isfinite(rows[lab][PROFILE_VIEW_KEY])), key=lambda x: rows[x][PROFILE_VIEW_KEY]
        )
        for lab in rows:
            rows[lab]["rank"] = order.index(lab) + 1 if lab in order else None
        out[view]["runs"] = rows
    return out

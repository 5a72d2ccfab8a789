"""The ring experiments: Sugiyama et al. 2008 (a jam with no bottleneck) and Stern et al. 2018 (one AEV dissolves it).

Human drivers: the IDM with Treiber et al. 2000's city parameters (:data:`aev_ocp.ring.laws.IDM_SI`), vehicles
5 m long, seeded acceleration noise of 0.1 m/s² held over 0.5 s (our choice: enough to seed waves the way real
drivers do, small against the IDM's 1 m/s²). Why the IDM and not the paper's OVM: with the paper's V(h) and
α = 2 the OVM is string stable at every gap (2 V'(h) ≤ 2 = α), so no ring of it jams; the IDM at the Sugiyama
density (22 vehicles on 230 m, gap 5.45 m, uniform speed 3.45 m/s) is linearly unstable (growth 0.023 1/s, the
k = 1 mode, :func:`aev_ocp.stability.ring.ring_stability`), and at 600 m (36.7 veh/km) stable (−0.020 1/s).

Fleet metrics over a window (default the second half of the run, after the wave has formed): speed standard
deviation over all vehicles and samples, vehicles that stopped (speed < 0.1 m/s at some sample), braking events
(entries into a < −1 m/s²), battery energy and pack heat per km of the whole fleet [J/km], SOC used, the
smallest gap [m] and the wave speed [m/s] (the slope of the slowest vehicle's unwrapped position in time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..models.carfollowing import CarFollowingLaw
from ..numerics import least_squares_slope
from ..params import EVParams, ParameterError
from .laws import AEV_CONTROLLERS, RING_PREDICTORS, idm_si, make_aev, ring_mpc  # noqa: F401 (re-exported)
from .simulate import RingOptions, RingResult, RingRoad, RingSimulator, uniform_flow

SUGIYAMA_LENGTH_M = 230.0  # Sugiyama et al. 2008 (New J. Phys. 10:033001): 22 cars on a 230 m circuit
SUGIYAMA_N = 22
STABLE_LENGTH_M = 600.0  # the same 22 vehicles on 600 m: uniform flow linearly stable (see module doc)
NOISE_MPS2 = 0.1  # human acceleration noise (our choice, module doc)
NOISE_DT_S = 0.5
STOP_SPEED_MPS = 0.1  # a vehicle below this speed counts as stopped
BRAKING_MPS2 = -1.0  # a braking event: the acceleration drops below this (harder than IDM's comfortable b = 1.5 m/s²
# at most moments of a calm ring, reached in every stop-and-go wave)


def human_ring(
    length_m: float = SUGIYAMA_LENGTH_M,
    n: int = SUGIYAMA_N,
    *,
    aevs: dict[int, Any] | None = None,
    ev: EVParams | None = None,
    noise_mps2: float = NOISE_MPS2,
    heterogeneity: float = 0.0,
    seed: int = 0,
) -> RingRoad:
    """n IDM drivers on a ring (vehicles in ``aevs`` {index: controller} replaced); ``heterogeneity`` h scales
    each human's a, b, v0, s0 and T by independent factors uniform in [1 − h, 1 + h] (seeded)."""
    ev = ev or EVParams()
    if not (0 <= heterogeneity < 1):
        raise ParameterError(f"ring: heterogeneity = {heterogeneity!r} is not allowed: must be in [0, 1)")
    rng = np.random.default_rng(seed + 7919)
    vehicles: list[Any] = []
    human: list[bool] = []
    from .laws import IDM_SI

    for i in range(n):
        if aevs and i in aevs:
            vehicles.append(aevs[i])
            human.append(False)
            continue
        f = 1 + heterogeneity * rng.uniform(-1, 1, 5) if heterogeneity > 0 else np.ones(5)
        vals = [v * fk for v, fk in zip(IDM_SI.values(), f)]
        vehicles.append(idm_si(ev.units, *vals))
        human.append(True)
    return RingRoad(
        length_m, tuple(vehicles), ev=ev, human=tuple(human), noise_mps2=noise_mps2, noise_dt_s=NOISE_DT_S, seed=seed
    )


def _wave_speed(res: RingResult, sel: np.ndarray) -> float:
    """Slope [m/s] of the position of the slowest vehicle (unwrapped, following the wave from vehicle to vehicle)."""
    t = res.t_s[sel]
    if t.size < 3:
        return math.nan
    x = res.positions_m(wrap=True)[sel]
    j = np.argmin(res.speed_mps[sel], axis=1)
    pos = x[np.arange(t.size), j]
    L = res.ring.length_m
    unwrapped = np.unwrap(pos * 2 * math.pi / L) * L / (2 * math.pi)
    return least_squares_slope(t, unwrapped)


def fleet_metrics(res: RingResult, t_from_s: float | None = None) -> dict[str, Any]:
    """Fleet metrics over [t_from_s, end] (default: the second half): see the module doc."""
    t = res.t_s
    t0 = 0.5 * float(t[-1]) if t_from_s is None else float(t_from_s)
    sel = t >= t0 - 1e-9
    i0 = int(np.flatnonzero(sel)[0])
    v, a = res.speed_mps[sel], res.accel_mps2[sel]
    u = res.ring.ev.units
    dist_m = float(np.sum(res.distance[-1] - res.distance[i0]) * u.length_m)
    energy = float(np.sum(res.energy_J[-1] - res.energy_J[i0]))
    heat = float(np.sum(res.sim.heat_J[-1] - res.sim.heat_J[i0]))
    brake = a < BRAKING_MPS2
    events = int(np.sum(brake[1:] & ~brake[:-1]) + np.sum(brake[0]))
    # the field's braking count (below −1 m/s² held 0.5 s, on the integrator's steps: independent of the
    # sampling) when the run counted from this window's start; else NaN
    b_from = res.stats.get("braking_from_s")
    on_steps = b_from is not None and abs(float(b_from) - float(t[i0])) <= 1e-6 * (1 + abs(float(t[i0])))
    brakes_held = int(np.sum(res.stats["braking_events_window"])) if on_steps else None
    v_space = dist_m / (res.ring.n * float(t[-1] - t[i0])) if t[-1] > t[i0] else math.nan
    return {
        "status": res.status,
        "collisions": sum(1 for e in res.sim.events if e.kind == "collision"),
        "window_s": [t0, float(t[-1])],
        "mean_speed_mps": float(np.mean(v)),
        "speed_std_mps": float(np.std(v)),
        "vehicles_stopped": int(np.sum(np.min(v, axis=0) < STOP_SPEED_MPS)),
        "braking_events": events,  # entries into a < −1 m/s² on the output samples (sampling-dependent)
        "braking_events_per_veh_km": (
            brakes_held / (dist_m / 1000.0) if brakes_held is not None and dist_m > 0 else math.nan
        ),
        "throughput_veh_per_h": res.ring.density_per_km * v_space * 3.6,  # density × space-mean speed
        "distance_km": dist_m / 1000.0,
        "battery_energy_J_per_km": energy / (dist_m / 1000.0) if dist_m > 0 else math.nan,
        "battery_energy_kWh_per_100km": energy / (dist_m / 1000.0) / 3.6e4 if dist_m > 0 else math.nan,
        "heat_pack_J_per_km": heat / (dist_m / 1000.0) if dist_m > 0 else math.nan,
        "soc_used_mean": float(np.mean(res.sim.S[i0] - res.sim.S[-1])),
        "min_gap_m": float(np.min(res.gap_m[sel])),
        "wave_speed_mps": _wave_speed(res, sel),
    }


@dataclass
class RingExperiment:
    """One run of an experiment: label, the ring, its result and fleet metrics."""

    label: str
    result: RingResult
    fleet: dict[str, Any] = field(default_factory=dict)


def run_ring(
    ring: RingRoad, t_end_s: float, *, shift_m: float = 2.0, options: RingOptions | None = None, label: str = ""
) -> RingExperiment:
    """Uniform flow perturbed by moving vehicle 1 back ``shift_m`` [m]; fleet metrics over the second half."""
    res = RingSimulator(ring, options).run(uniform_flow(ring, shift_m=shift_m), t_end_s)
    fleet = fleet_metrics(res)
    _add_controller_stats(res, fleet)
    return RingExperiment(label, res, fleet)


def sugiyama(t_end_s: float = 600.0, *, seed: int = 0, options: RingOptions | None = None) -> list[RingExperiment]:
    """All-human ring at the Sugiyama density (jams) and at :data:`STABLE_LENGTH_M` (does not)."""
    return [
        run_ring(human_ring(SUGIYAMA_LENGTH_M, seed=seed), t_end_s, options=options, label="sugiyama 230 m"),
        run_ring(human_ring(STABLE_LENGTH_M, seed=seed), t_end_s, options=options, label="22 vehicles, 600 m"),
    ]


def stern(
    controllers: Sequence[str] = AEV_CONTROLLERS,
    t_end_s: float = 600.0,
    *,
    seed: int = 0,
    r_fraction: float = 0.85,
    options: RingOptions | None = None,
    length_m: float = SUGIYAMA_LENGTH_M,
) -> list[RingExperiment]:
    """The Sugiyama ring all-human, then with vehicle 1 an AEV under each controller (FollowerStopper's desired
    speed r = ``r_fraction`` × the ring's uniform-flow speed)."""
    base = human_ring(length_m, seed=seed)
    from .simulate import uniform_speed_mps

    r = r_fraction * uniform_speed_mps(base)
    runs = [run_ring(base, t_end_s, options=options, label="all human")]
    for name in controllers:
        ring = human_ring(length_m, aevs={0: make_aev(name, base.ev, r)}, seed=seed)
        runs.append(run_ring(ring, t_end_s, options=options, label=name))
    return runs


def relative_to(base: dict[str, Any], other: dict[str, Any]) -> dict[str, float]:
    """Relative changes of the fleet metrics against a baseline (−0.5 = 50 % lower)."""
    out = {}
    for k in ("speed_std_mps", "battery_energy_J_per_km", "heat_pack_J_per_km", "braking_events"):
        b = float(base[k])
        out[k] = (float(other[k]) - b) / b if b else math.nan
    return out


_ = CarFollowingLaw


def run_ring_scenario(
    sc: Any, options: RingOptions | None = None, t_end_s: float | None = None
) -> list[RingExperiment]:
    """Every run of a ring scenario (:class:`aev_ocp.ring.scenario.RingScenario`): all human first when it asks
    for it, then one run per AEV controller; fleet metrics from ``metrics_from_s`` (default the second half).
    ``t_end_s`` overrides the scenario's horizon [s]."""
    from .scenario import build_ring, scenario_runs

    s = sc.spec
    t_end = s.t_end_s if t_end_s is None else float(t_end_s)
    t_from = s.metrics_from_s if s.metrics_from_s is not None and s.metrics_from_s < t_end else None
    opts = options or RingOptions(dt_out_s=min(s.dt_out_s, t_end), braking_from_s=t_from)
    out = []
    for run in scenario_runs(sc):
        ring, init = build_ring(sc, run.controller, run.length_m, run.aevs)
        res = RingSimulator(ring, opts).run(init, t_end)
        fleet = fleet_metrics(res, t_from)
        fleet.update(
            {
                "length_m": ring.length_m,
                "density_per_km": ring.density_per_km,
                "aevs": len(run.aevs) if run.controller is not None else 0,
                "controller": run.controller or "human",
            }
        )
        _add_controller_stats(res, fleet)
        out.append(RingExperiment(run.label, res, fleet))
    for e in out:  # relative changes against the all-human run on the same ring (−0.5 = 50 % lower)
        human = next((h for h in out if h.fleet["aevs"] == 0 and h.fleet["length_m"] == e.fleet["length_m"]), None)
        if human is not None and e is not human:
            e.fleet.update({f"change_{k}": v for k, v in relative_to(human.fleet, e.fleet).items()})
    return out


def _add_controller_stats(res: RingResult, fleet: dict[str, Any]) -> None:
    """Fallbacks and call times [ms] of the sampled controllers (the MPC's solve times) into the fleet metrics."""
    st = [s for s in res.sim.solver_stats if s]
    if st:
        fleet["fallbacks"] = int(sum(s["fallbacks"] for s in st))
        fleet["call_ms_median"] = float(np.median([s["call_ms_median"] for s in st]))
        fleet["call_ms_max"] = float(max(s["call_ms_max"] for s in st))

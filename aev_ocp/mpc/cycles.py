"""MPC on drive cycles: one follower behind each EPA cycle (and the paper's leader) under the MPC with each
forecast, beside the closed-form laws; the rows of the report section "MPC on drive cycles" and of
``benchmarks/bench_mpc_cycles.py``.

API (shared by the report section :mod:`aev_ocp.mpc.cycles_section` and benchmarks):

* :func:`cycle_scenario` — the shipped scenario of a cycle, optionally cut to its first ``segment_s`` seconds;
* :func:`run_cycle` — MPC runs (one per forecast) and closed-form law runs on that scenario:
  ``{(controller, predictor): SimulationResult}`` (predictor None for a law);
* :func:`cycle_rows` — one row per run and follower: the §10 metrics per km, min gap, min TTC, RMS jerk,
  fallbacks, solve-time p50/p99, forecast RMS and the comparability flags against the proposed law
  (:func:`aev_ocp.metrics.comparability`); :func:`rank_rows` ranks only comparable rows.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from ..metrics import comparability
from ..params import ParameterError
from ..results import SimulationResult
from ..truncation import equal_views

#: The cycles of the section and their shipped single-follower MPC scenarios (``paper``: model guide §9's
#: Table 1 leader, mpc_paper_single, whose own [mpc] table is replaced by the defaults below).
CYCLE_SCENARIOS: dict[str, str] = {
    "udds": "mpc_udds_single",
    "hwfet": "mpc_hwfet_single",
    "us06": "mpc_us06_single",
    "paper": "mpc_paper_single",
}
#: The 5-follower UDDS platoon with every follower on MPC.
PLATOON_SCENARIO = "mpc_udds_platoon"
#: Forecasts compared: the simplest measured one and the best non-oracle one of aev_ocp/mpc/predictors.py.
PREDICTORS: tuple[str, ...] = ("constant-velocity", "decaying-acceleration")
#: Closed-form laws beside the MPC; the first is the comparability reference.
LAWS: tuple[str, ...] = ("proposed", "ovfl")
REFERENCE = "proposed"

#: Columns of a row (keys of :func:`cycle_rows`' dicts), in table order.
COLUMNS: tuple[str, ...] = (
    "cycle",
    "vehicle",
    "controller",
    "predictor",
    "status",
    "battery_energy_kWh_per_100km",
    "heat_pack_J_per_km",
    "charge_throughput_Ah_per_km",
    "omega_J_per_kg_per_km",
    "distance_m",
    "duration_s",
    "min_gap_m",
    "min_ttc_s",
    "rms_jerk_model",
    "fallbacks",
    "solve_ms_p50",
    "solve_ms_p99",
    "forecast_rms",
    "distance_diff_pct",
    "duration_diff_pct",
    "comparable",
    "flags",
    "rank",
    "eq_distance_m",
    "heat_pack_J_per_km_eq_distance",
    "rank_eq_distance",
    "eq_time_s",
    "heat_pack_J_per_km_eq_time",
    "rank_eq_time",
)


#: A segment ends once the leader has stood still this long [s] (our choice: every follower of a 5-car
#: platoon has stopped by then), so runs of different controllers end at rest with comparable distances.
STOP_HOLD_S = 20.0


def leader_rest_end(sc: Any, t_from: float, hold_s: float = STOP_HOLD_S, step_s: float = 0.5) -> float | None:
    """The first time t ≥ ``t_from`` [model time] at which the leader of ``sc`` has been at rest for
    ``hold_s`` seconds (sampled every ``step_s`` s), or None if that does not happen before ``sc.t_end``."""
    u = sc.units
    t = np.arange(0.0, sc.t_end, u.time_from_si(step_s))
    rest = np.asarray(sc.leader.speed_np(t), float).ravel() <= 1e-9
    hold = u.time_from_si(hold_s)
    start = None
    for ti, r in zip(t, rest):
        if not r:
            start = None
            continue
        start = ti if start is None else start
        if ti - start >= hold - 1e-12 and ti >= t_from:
            return float(ti)
    return None


def cycle_scenario(cycle: str, segment_s: float | None = None, platoon: bool = False, end_at_rest: bool = False) -> Any:
    """The shipped scenario of ``cycle`` ('udds', 'hwfet', 'us06', 'paper'; platoon: the UDDS 5-follower
    scenario), cut to its first ``segment_s`` seconds [s] (rounded up to whole MPC steps) when given and
    shorter than the scenario. ``end_at_rest``: the cut moves on to the first time after ``segment_s`` at
    which the leader has stood still for :data:`STOP_HOLD_S` (the whole scenario if it never does), so
    every controller's run ends at rest and their distances are comparable (an MPC that keeps a longer
    time gap than a law is otherwise metres behind it at an arbitrary cut)."""
    from ..scenarios import find_scenario, load_scenario

    if platoon:
        if cycle != "udds":
            raise ParameterError(f"cycle_scenario: platoon = True exists for 'udds' only, not {cycle!r}")
        name = PLATOON_SCENARIO
    else:
        try:
            name = CYCLE_SCENARIOS[cycle]
        except KeyError:
            raise ParameterError(
                f"cycle = {cycle!r} is not allowed: must be one of {sorted(CYCLE_SCENARIOS)}"
            ) from None
    sc = load_scenario(find_scenario(name))
    if segment_s is not None:
        if not (isinstance(segment_s, (int, float)) and math.isfinite(segment_s) and segment_s > 0):
            raise ParameterError(
                f"cycle_scenario: segment_s = {segment_s!r} is not allowed: must be a number of seconds > 0"
            )
        t_seg = sc.units.time_from_si(float(segment_s))
        if end_at_rest:
            t_rest = leader_rest_end(sc, t_seg)
            t_seg = sc.t_end if t_rest is None else t_rest
        cfg = sc.extra.get("mpc")
        if cfg is not None:  # whole MPC steps (the closed loop needs them): round up to a multiple of mpc.dt
            t_seg = math.ceil(t_seg / cfg.settings.dt - 1e-9) * cfg.settings.dt
        if t_seg < sc.t_end:
            sc = sc.replace(t_end=t_seg)
    return sc


def run_cycle(
    sc: Any,
    predictors: Iterable[str] = PREDICTORS,
    laws: Iterable[str] = LAWS,
    settings: Any = None,
    log: Callable[[str], None] | None = None,
) -> tuple[dict[tuple[str, str | None], SimulationResult], dict[str, float]]:
    """Run scenario ``sc`` with every MPC follower on ``settings`` (default: MPCSettings(), the project's
    default formulation) under each forecast in ``predictors``, and the whole platoon on each law of
    ``laws`` (same leader and start). Returns ({(controller, predictor): result}, wall time per run [s]);
    laws have predictor None. ``log`` gets the runs' progress lines (the MPC at every 25 %)."""
    from .run import run_comparison
    from .settings import MPCSettings

    base = settings if settings is not None else MPCSettings()
    runs: dict[tuple[str, str | None], SimulationResult] = {}
    wall: dict[str, float] = {}
    laws, predictors = tuple(laws), tuple(predictors)
    if not predictors:
        raise ParameterError("run_cycle: predictors is empty: give at least one forecast for the MPC runs")
    for k, p in enumerate(predictors):
        s = base.with_(predictor=p)
        c = run_comparison(sc, s, laws=laws if k == 0 else (), with_ocpd=False, log=log)
        runs[("mpc", p)] = c.results["mpc"]
        wall[f"mpc/{p}"] = c.timings_s.get("mpc", math.nan)
        for name in laws if k == 0 else ():
            runs[(name, None)] = c.results[name]
            wall[name] = c.timings_s.get(name, math.nan)
    return runs, wall


def _solve_percentiles(r: SimulationResult, i: int) -> tuple[float, float]:
    """p50, p99 of the MPC solve times of follower i [ms] (nan for a law)."""
    steps = (r.meta.get("mpc_steps") or [None] * r.n_vehicles)[i] if r.meta else None
    ms = np.asarray(steps["solve_ms"], float) if steps else np.zeros(0)
    ms = ms[np.isfinite(ms)]
    if ms.size == 0:
        return math.nan, math.nan
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def cycle_rows(
    cycle: str,
    runs: Mapping[tuple[str, str | None], SimulationResult],
    reference: str = REFERENCE,
    vehicles: Iterable[int] | None = None,
) -> list[dict[str, Any]]:
    """One row per run and follower (0-based ``vehicles``, default all) with the columns of
    :data:`COLUMNS`; comparability (distance or duration > 1 % apart, or a run ended by an event) is
    judged against the same follower under the ``reference`` law (flagged 'no reference' if absent);
    'flags' names what is off. Ranks are set by :func:`rank_rows`. Every row also has the equal-distance and
    equal-time views (:func:`aev_ocp.truncation.equal_views`: each run up to the shortest common distance and
    the common time of the cycle's runs, where all are comparable): the cut, pack ∫Q/km up to it and its rank."""
    ref_run = runs.get((reference, None))
    rows = []
    first = next(iter(runs.values()), None)
    n = first.n_vehicles if first is not None else 0
    views = {i: equal_views(runs, i) for i in (range(n) if vehicles is None else vehicles)}
    for (ctrl, pred), r in runs.items():
        ms = r.metrics()
        for i in range(r.n_vehicles) if vehicles is None else vehicles:
            eq = {}
            for view, cut, unit in (("distance", "cut_m", "eq_distance_m"), ("time", "cut_s", "eq_time_s")):
                vr = views[i][view]["runs"].get((ctrl, pred)) or {}
                eq.update(
                    {
                        unit: views[i][view][cut],
                        f"heat_pack_J_per_km_eq_{view}": vr.get("heat_pack_J_per_km", math.nan),
                        f"rank_eq_{view}": vr.get("rank"),
                    }
                )
            m = ms[i]
            ref = ref_run.metrics()[i] if ref_run is not None else None
            c = comparability(m, ref)
            flags = [
                f
                for f, on in (
                    ("event: " + str(m.get("run_status")), c["flag_event"]),
                    ("distance", c["flag_distance"]),
                    ("duration", c["flag_duration"]),
                )
                if on
            ]
            if ref is None:
                flags.append("no reference")
            p50, p99 = _solve_percentiles(r, i)
            rows.append(
                {
                    "cycle": cycle,
                    "vehicle": i + 1,
                    "controller": ctrl,
                    "predictor": pred or "—",
                    "status": m.get("run_status", "ok"),
                    "battery_energy_kWh_per_100km": m["battery_energy_kWh_per_100km"],
                    "heat_pack_J_per_km": m["heat_pack_J_per_km"],
                    "charge_throughput_Ah_per_km": m["charge_throughput_Ah_per_km"],
                    "omega_J_per_kg_per_km": m["omega_J_per_kg_per_km"],
                    "distance_m": m["distance_m"],
                    "duration_s": m["duration_s"],
                    "min_gap_m": m["min_gap_m"],
                    "min_ttc_s": m["min_ttc_s"],
                    "rms_jerk_model": m["rms_jerk_model"],
                    "fallbacks": m.get("fallbacks") if ctrl == "mpc" else None,
                    "solve_ms_p50": p50,
                    "solve_ms_p99": p99,
                    "forecast_rms": m.get("forecast_rms", math.nan) if ctrl == "mpc" else math.nan,
                    "distance_diff_pct": c["distance_diff_pct"],
                    "duration_diff_pct": c["duration_diff_pct"],
                    "comparable": bool(c["comparable"]) and ref is not None,
                    "flags": ", ".join(flags),
                    "rank": None,
                    **eq,
                }
            )
    return rows


def rank_rows(rows: list[dict[str, Any]], key: str = "heat_pack_J_per_km") -> list[dict[str, Any]]:
    """Set 'rank' (1 = lowest ``key``) among the comparable rows of each (cycle, vehicle); a row that
    is not comparable is never ranked (rank None). Returns ``rows``."""
    groups: dict[tuple[Any, Any], list[dict[str, Any]]] = {}
    for r in rows:
        r["rank"] = None
        if r["comparable"] and math.isfinite(float(r[key])):
            groups.setdefault((r["cycle"], r["vehicle"]), []).append(r)
    for g in groups.values():
        for k, r in enumerate(sorted(g, key=lambda x: float(x[key])), start=1):
            r["rank"] = k
    return rows


def platoon_rows(
    runs: Mapping[tuple[str, str | None], SimulationResult], mpc_key: tuple[str, str | None], reference: str = REFERENCE
) -> list[dict[str, Any]]:
    """Per follower of a platoon: pack ∫Q [J] and per km under the MPC run ``mpc_key`` and under the
    ``reference`` law, the MPC's change [%] and whether the two are comparable (ranked otherwise never)."""
    mpc, ref = runs[mpc_key], runs[(reference, None)]
    out = []
    for m, q in zip(mpc.metrics(), ref.metrics()):
        c = comparability(m, q)
        out.append(
            {
                "vehicle": m["vehicle"],
                "heat_pack_J_mpc": m["heat_pack_J"],
                "heat_pack_J_ref": q["heat_pack_J"],
                "heat_pack_J_per_km_mpc": m["heat_pack_J_per_km"],
                "heat_pack_J_per_km_ref": q["heat_pack_J_per_km"],
                "change_pct": 100.0 * (m["heat_pack_J_per_km"] / q["heat_pack_J_per_km"] - 1.0)
                if q["heat_pack_J_per_km"]
                else math.nan,
                "fallbacks": m.get("fallbacks"),
                "min_gap_m": m["min_gap_m"],
                "distance_diff_pct": c["distance_diff_pct"],
                "comparable": bool(c["comparable"]),
                "status": m.get("run_status", "ok"),
            }
        )
    return out

"""The field's metrics of a ring run, and their tables over seeds with 95 % intervals.

:func:`field_metrics` of one run over the window [t_from_s, end] (SI):

* ``mean_speed_mps``: the fleet's distance over the window (the ring's distance quadrature, not the samples)
  divided by n × the window's duration (Edie's space-mean speed of the whole ring);
* ``throughput_veh_per_h``: the flow q = k v̄ (k = n/L the density), in vehicles per hour — from density × mean
  speed, not counted at a detector (on a ring, the time-mean count at any point equals k v̄ over a long window);
* ``travel_time_per_lap_s``: L / v̄, the mean time to go once around the ring;
* ``speed_std_mps``: the standard deviation of every vehicle's speed over the output samples of the window;
* ``braking_events_per_veh_km``: events (acceleration below −1 m/s² held at least 0.5 s,
  :class:`aev_ocp.ring.simulate.RingOptions` ``braking_*``) beginning in the window, counted on the integrator's
  own steps (so the count does not depend on the output sampling), per vehicle-km driven in the window;
* ``battery_energy_kWh_per_100km`` (∫P_b dt of the whole fleet per fleet distance) and ``heat_pack_J_per_km``.

:func:`seed_table` gives each metric's mean over seeds with its 95 % interval (:func:`aev_ocp.intervals.summarize`)
and, against a baseline run (the all-human ring), the paired difference's interval and a verdict
(:func:`aev_ocp.intervals.compare`: 'better' / 'worse' only when the interval excludes zero, else 'tie').
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..intervals import compare, summarize
from ..params import ParameterError
from .simulate import RingOptions, RingResult, RingSimulator

#: the metrics of a table, and whether lower is better (for the verdicts)
FIELD_METRICS: dict[str, bool] = {
    "throughput_veh_per_h": False,
    "mean_speed_mps": False,
    "travel_time_per_lap_s": True,
    "speed_std_mps": True,
    "braking_events_per_veh_km": True,
    "battery_energy_kWh_per_100km": True,
    "heat_pack_J_per_km": True,
}


BRAKING_MPS2 = -1.0  # a braking event: below this acceleration (aev_ocp.ring.run.BRAKING_MPS2) ...
BRAKING_HOLD_S = 0.5  # ... held at least this long (RingOptions.braking_hold_s)


def count_braking(
    t_s: np.ndarray, a_mps2: np.ndarray, threshold_mps2: float = BRAKING_MPS2, hold_s: float = BRAKING_HOLD_S
) -> int:
    """Braking events in one vehicle's accelerations on a simulator's own steps (times t_s [s], a [m/s²]): a run of
    steps with a < threshold lasting at least hold_s from its first step (the rule ring.c applies on its steps)."""
    t = np.asarray(t_s, float)
    on = np.asarray(a_mps2, float) < threshold_mps2
    count, since, counted = 0, -1.0, False
    for tk, b in zip(t, on):
        if not b:
            since = -1.0
            continue
        if since < 0:
            since, counted = float(tk), False
        if not counted and tk - since >= hold_s * (1 - 1e-12):
            count, counted = count + 1, True
    return count


def window_metrics(
    t_s: np.ndarray,
    distance_m: np.ndarray,
    speed_mps: np.ndarray,
    energy_J: np.ndarray,
    heat_J: np.ndarray,
    braking_events: int,
    length_m: float,
) -> dict[str, Any]:
    """The field's metrics (module doc) from one window's samples: times [s] (K,), each vehicle's cumulative
    distance [m], speed [m/s], battery energy and pack heat [J] (K, n), the braking events begun in the window
    and the ring's length [m]."""
    t = np.asarray(t_s, float)
    n = np.asarray(speed_mps).shape[1]
    duration = float(t[-1] - t[0])
    if not duration > 0:
        raise ParameterError("field_metrics: the window must span more than one sample")
    total_m = float(np.sum(np.asarray(distance_m)[-1] - np.asarray(distance_m)[0]))
    v_mean = total_m / (n * duration)
    km = total_m / 1000.0
    energy = float(np.sum(np.asarray(energy_J)[-1] - np.asarray(energy_J)[0]))
    heat = float(np.sum(np.asarray(heat_J)[-1] - np.asarray(heat_J)[0]))
    density = 1000.0 * n / length_m
    return {
        "window_s": [float(t[0]), float(t[-1])],
        "density_per_km": density,
        "mean_speed_mps": v_mean,
        "throughput_veh_per_h": density * v_mean * 3.6,
        "travel_time_per_lap_s": length_m / v_mean if v_mean > 0 else math.inf,
        "speed_std_mps": float(np.std(speed_mps)),
        "braking_events": int(braking_events),
        "braking_events_per_veh_km": braking_events / km if km > 0 else math.nan,
        "battery_energy_kWh_per_100km": energy / km / 3.6e4 if km > 0 else math.nan,
        "heat_pack_J_per_km": heat / km if km > 0 else math.nan,
    }


def field_metrics(res: RingResult, t_from_s: float | None = None) -> dict[str, Any]:
    """The field's metrics of ``res`` over [t_from_s, end] (default: the second half; module doc). The braking
    events are those the simulator counted from its ``RingOptions.braking_from_s``, which must be this window's
    start (ParameterError otherwise)."""
    t = res.t_s
    t0 = 0.5 * float(t[-1]) if t_from_s is None else float(t_from_s)
    sel = np.flatnonzero(t >= t0 - 1e-9)
    if sel.size < 2 and res.status != "ok":  # the run stopped at an event before the window: no metrics
        nan = dict.fromkeys(FIELD_METRICS, math.nan)
        return {"status": res.status, "window_s": [t0, float(t[-1])], "braking_events": 0, **nan}
    if sel.size < 2:
        raise ParameterError(f"field_metrics: t_from_s = {t0:g} s leaves fewer than 2 samples of the run")
    i0 = int(sel[0])
    b_from = res.stats.get("braking_from_s")
    if b_from is None or abs(float(b_from) - float(t[i0])) > 1e-6 * (1 + abs(float(t[i0]))):
        raise ParameterError(
            f"field_metrics: the run counted braking events from {b_from} s, the window starts at {float(t[i0]):g} s: "
            "run it with RingOptions(braking_from_s=...) equal to the window's start"
        )
    u = res.ring.ev.units
    out = {"status": res.status}
    out.update(
        window_metrics(
            t[i0:],
            res.distance[i0:] * u.length_m,
            res.speed_mps[i0:],
            res.energy_J[i0:],
            res.sim.heat_J[i0:],
            int(np.sum(res.stats["braking_events_window"])),
            res.ring.length_m,
        )
    )
    return out


def _ok(r: dict[str, Any]) -> bool:
    return r.get("status", "ok") == "ok"


def seed_table(
    runs: Mapping[str, Sequence[dict[str, Any]]],
    baseline: str | None = None,
    metrics: Sequence[str] = tuple(FIELD_METRICS),
) -> list[dict[str, Any]]:
    """One row per run label: for each metric its mean with a 95 % interval over the seeds (the rows of
    ``runs[label]``, one per seed) and, for every label but the ``baseline``, the paired difference to the
    baseline's with its interval and verdict. Runs that stopped at an event (``status`` not 'ok') are counted
    ('failed') and left out; the pairs are the seeds both runs completed (by the rows' ``seed``, else by position).
    A metric with fewer than 2 completed seeds gets None."""
    if baseline is not None and baseline not in runs:
        raise ParameterError(f"seed_table: baseline {baseline!r} is not one of the runs {sorted(runs)}")

    def keyed(rows: Sequence[dict[str, Any]]) -> dict[Any, dict[str, Any]]:
        return {r.get("seed", j): r for j, r in enumerate(rows) if _ok(r)}

    base = keyed(runs[baseline]) if baseline is not None else {}
    out = []
    for label, rows in runs.items():
        good = keyed(rows)
        row: dict[str, Any] = {
            "run": label,
            "seeds": len(rows),
            "failed": len(rows) - len(good),  # runs that stopped at an event
        }
        common = [k for k in good if k in base]
        for m in metrics:
            x = [float(r[m]) for r in good.values()]
            row[m] = summarize(x).as_dict() if len(x) >= 2 else None
            if baseline is not None and label != baseline:
                if len(common) >= 2:
                    c = compare(
                        [float(good[k][m]) for k in common],
                        [float(base[k][m]) for k in common],
                        lower_is_better=FIELD_METRICS.get(m, True),
                    )
                    row[f"{m}_vs_{baseline}"] = {
                        "difference": c["difference"],
                        "verdict": c["verdict"],
                        "pairs": len(common),
                    }
                else:
                    row[f"{m}_vs_{baseline}"] = None
        out.append(row)
    return out


def table_markdown(rows: list[dict[str, Any]], metrics: Sequence[str] = tuple(FIELD_METRICS)) -> str:
    """The table as Markdown: mean [lo, hi] per metric, and the verdict against the baseline where there is one."""
    head = "| run | seeds | failed | " + " | ".join(metrics) + " |"
    lines = [head, "|" + "---|" * (len(metrics) + 3)]
    for r in rows:
        cells = []
        for m in metrics:
            s = r[m]
            cell = "–" if s is None else f"{s['mean']:.4g} [{s['lo']:.4g}, {s['hi']:.4g}]"
            vs = next((v for k, v in r.items() if k.startswith(f"{m}_vs_")), None)
            if vs is not None:
                cell += f" {vs['verdict']}"
            cells.append(cell)
        run = f"{r['density_per_km']:.4g}/km, {r['run']}" if "density_per_km" in r else r["run"]
        lines.append(f"| {run} | {r['seeds']} | {r['failed']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def scenario_over_seeds(
    sc: Any,
    seeds: Sequence[int],
    t_end_s: float | None = None,
    options: RingOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, list[dict[str, Any]]]:
    """Every run of a ring scenario (:func:`aev_ocp.ring.scenario.scenario_runs`) once per seed (the scenario's
    ``ring.seed`` replaced): {run label: [field metrics per seed]}, the metrics over ``metrics_from_s``'s window."""
    from .scenario import build_ring, scenario_runs

    s = sc.spec
    t_end = s.t_end_s if t_end_s is None else float(t_end_s)
    t_from = s.metrics_from_s if s.metrics_from_s is not None and s.metrics_from_s < t_end else 0.5 * t_end
    base = options or RingOptions(dt_out_s=min(s.dt_out_s, t_end))
    opts = dataclasses.replace(base, braking_from_s=t_from)
    out: dict[str, list[dict[str, Any]]] = {}
    for run in scenario_runs(sc):
        for seed in seeds:
            sc_k = dataclasses.replace(sc, spec=dataclasses.replace(s, seed=int(seed)))
            ring, init = build_ring(sc_k, run.controller, run.length_m, run.aevs)
            res = RingSimulator(ring, opts).run(init, t_end)
            m = field_metrics(res, t_from)
            m["seed"] = int(seed)
            out.setdefault(run.label, []).append(m)
            if progress is not None:
                progress(f"{run.label}, seed {seed}: {m['status']}")
    return out


def scenario_seed_rows(runs: dict[str, list[dict[str, Any]]], sc: Any) -> list[dict[str, Any]]:
    """:func:`seed_table` of a scenario's runs over seeds, each ring's runs against its own all-human run (a
    sweep has one per ring length), with the ring's length [m] and density on every row."""
    from .scenario import scenario_runs

    by_length: dict[float, list[Any]] = {}
    for run in scenario_runs(sc):
        by_length.setdefault(run.length_m, []).append(run)
    rows: list[dict[str, Any]] = []
    for L, group in by_length.items():
        human = next((r.label for r in group if r.controller is None), None)
        part = seed_table({r.label: runs[r.label] for r in group}, human)
        for row, r in zip(part, group):
            row.update(
                {
                    "length_m": L,
                    "density_per_km": 1000.0 * sc.spec.vehicles / L,
                    "controller": r.controller or "human",
                    "aevs": len(r.aevs) if r.controller else 0,
                }
            )
        rows += part
    return rows

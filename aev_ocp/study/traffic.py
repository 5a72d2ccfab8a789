"""Ring and SUMO sweeps as study points: penetration × controller × density × seed, each point a
:class:`~aev_ocp.study.model.Task` run by the study's executors (in process, the process pool, Dask) into its
hash-keyed :class:`~aev_ocp.study.runner.Store` (a rerun computes only what is missing), then tabled over seeds with
95 % intervals and paired verdicts against the all-human point of the same density and seed
(:func:`aev_ocp.ring.field.seed_table`).

A point's task specification holds ``kind`` ("ring" or "sumo"), the scenario's TOML document and file, the
point's values and the controller; :func:`aev_ocp.study.runner.run_task` hands such a task to :func:`run_point`,
which returns the study's result form ({key, controller, status, message, metrics: [one row of the field's
metrics with the point's values], wall_s}).

* ring: :func:`ring_tasks` over a ring scenario file (:mod:`aev_ocp.ring.scenario`): ``aevs`` AEVs spread evenly
  (0: all human), ``controllers`` (:data:`aev_ocp.ring.laws.AEV_CONTROLLERS`), ``density_per_km`` (the ring's
  length set to n / density), ``seeds`` (``ring.seed``: the drivers' draws and noise);
* SUMO: :func:`sumo_tasks` over a SUMO scenario file: ``shares`` (of vehicles the toolkit drives), ``controllers``
  and ``seeds`` (``sumo.seed``: the selection of controlled vehicles and SUMO's own randomness); density is the
  scenario's.
"""

from __future__ import annotations

import hashlib
import json
import time
import traceback
from pathlib import Path
from typing import Any, Sequence

from .._version import __version__
from ..params import ParameterError
from ..results import to_jsonable
from .model import Task
from .tasks import canonical_json

KINDS = ("ring", "sumo")


def _task(kind: str, index: int, doc: dict[str, Any], file: str, values: dict[str, Any], controller: str) -> Task:
    identity = {"kind": kind, "document": doc, "values": values, "controller": controller, "version": __version__}
    key = hashlib.sha256(canonical_json(identity).encode()).hexdigest()
    spec = {
        "kind": kind,
        "document": doc,
        "file": file,
        "values": values,
        "controller": {"label": controller, "kind": kind, "name": controller, "settings": {}},
        "key": key,
    }
    return Task(index, controller, spec, key)


def ring_tasks(
    scenario: str | Path,
    aevs: Sequence[int],
    controllers: Sequence[str],
    density_per_km: Sequence[float] | None = None,
    seeds: Sequence[int] = tuple(range(10)),
    t_end_s: float | None = None,
) -> list[Task]:
    """The ring sweep's tasks: every density × AEV count × controller × seed (the count 0, all human, once per
    density and seed); ``density_per_km`` None: the scenario's ring; ``t_end_s`` None: the scenario's."""
    from ..ring.laws import AEV_CONTROLLERS
    from ..ring.scenario import load_ring_scenario

    sc = load_ring_scenario(scenario)
    n = sc.spec.vehicles
    for c in controllers:
        if c not in AEV_CONTROLLERS:
            raise ParameterError(f"ring_tasks: controller {c!r} is not one of {AEV_CONTROLLERS}")
    for k in aevs:
        if not (isinstance(k, int) and 0 <= k <= n):
            raise ParameterError(f"ring_tasks: aevs {k!r} must be whole numbers of AEVs in 0 … {n}")
    dens = list(density_per_km) if density_per_km is not None else [sc.density_per_km]
    for d in dens:
        if not (d > 0 and n * sc.spec.vehicle_length_m < 1000.0 * n / d):
            raise ParameterError(f"ring_tasks: density_per_km {d!r}: {n} vehicles do not fit on that ring")
    if t_end_s is not None and not (0 < t_end_s <= 36_000):
        raise ParameterError(f"ring_tasks: t_end_s = {t_end_s!r} must be in (0, 36000] s")
    doc = sc.document or {}
    file = str(sc.source or scenario)
    tasks: list[Task] = []
    for d in dens:
        for k in aevs:
            for c in controllers[:1] if k == 0 else controllers:
                for s in seeds:
                    v = {"density_per_km": float(d), "aevs": int(k), "seed": int(s), "t_end_s": t_end_s}
                    tasks.append(_task("ring", len(tasks), doc, file, v, "human" if k == 0 else c))
    return tasks


def sumo_tasks(
    scenario: str | Path,
    shares: Sequence[float],
    controllers: Sequence[str],
    seeds: Sequence[int] = tuple(range(10)),
    t_end_s: float | None = None,
) -> list[Task]:
    """The SUMO sweep's tasks: every share × controller × seed (share 0, all SUMO's drivers, once per seed);
    ``t_end_s`` None: the scenario's."""
    from ..sumo.scenario import load_sumo_scenario

    sc = load_sumo_scenario(scenario)
    for x in shares:
        if not 0.0 <= x <= 1.0:
            raise ParameterError(f"sumo_tasks: share {x!r} must be in [0, 1]")
    file = str(sc.source or scenario)
    tasks: list[Task] = []
    for x in shares:
        for c in controllers[:1] if x == 0 else controllers:
            for s in seeds:
                v = {"share": float(x), "seed": int(s), "t_end_s": t_end_s}
                tasks.append(_task("sumo", len(tasks), sc.document, file, v, "sumo" if x == 0 else c))
    return tasks


def run_point(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one ring or SUMO point (the study's result form, module doc); an exception is recorded as 'error'."""
    t0 = time.perf_counter()
    out: dict[str, Any] = {"key": spec["key"], "controller": spec["controller"]["label"]}
    try:
        row = _ring(spec) if spec["kind"] == "ring" else _sumo(spec)
        out.update(status=row["status"], message=row.pop("message", ""), metrics=[row])
    except Exception as exc:  # noqa: BLE001 - a failed point is recorded, the others go on
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" ({Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
        out.update(status="error", message=f"{type(exc).__name__}: {exc}{where}", metrics=[])
    out["wall_s"] = time.perf_counter() - t0
    return json.loads(json.dumps(to_jsonable(out)))


def _ring(spec: dict[str, Any]) -> dict[str, Any]:
    import dataclasses

    from ..ring.field import field_metrics
    from ..ring.scenario import build_ring, parse_ring_scenario, spread
    from ..ring.simulate import RingOptions, RingSimulator

    v = spec["values"]
    sc = parse_ring_scenario(
        spec["document"], spec["file"], Path(spec["file"]) if Path(spec["file"]).is_file() else None
    )
    sc = dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, seed=int(v["seed"])))
    s = sc.spec
    t_end = s.t_end_s if v.get("t_end_s") is None else float(v["t_end_s"])
    t_from = s.metrics_from_s if s.metrics_from_s is not None and s.metrics_from_s < t_end else 0.5 * t_end
    length = 1000.0 * s.vehicles / float(v["density_per_km"])
    k = int(v["aevs"])
    ring, init = build_ring(sc, None if k == 0 else spec["controller"]["name"], length, spread(k, s.vehicles))
    opts = RingOptions(dt_out_s=min(s.dt_out_s, t_end), braking_from_s=t_from)
    res = RingSimulator(ring, opts).run(init, t_end)
    row = field_metrics(res, t_from)
    row["message"] = "; ".join(str(e) for e in res.sim.events)
    return {**v, "controller": spec["controller"]["label"], **row}


def _sumo(spec: dict[str, Any]) -> dict[str, Any]:
    import dataclasses

    from ..sumo.outputs import sweep_row
    from ..sumo.run import run_sumo
    from ..sumo.scenario import parse_sumo_scenario

    v = spec["values"]
    sc = parse_sumo_scenario(
        spec["document"], spec["file"], Path(spec["file"]) if Path(spec["file"]).is_file() else None
    )
    ctrl = spec["controller"]["name"]
    sc = sc.with_point(share=float(v["share"]), controller=None if v["share"] == 0 else ctrl)
    kw: dict[str, Any] = {"seed": int(v["seed"])}
    if v.get("t_end_s") is not None:
        kw["t_end_s"] = float(v["t_end_s"])
    sc = dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, **kw))
    run = run_sumo(sc)
    row = sweep_row(float(v["share"]), spec["controller"]["label"], run)
    row["message"] = "; ".join(e["kind"] for e in run.events if e["kind"] != "left_network")[:500]
    return {**v, **row}


def traffic_table(tasks: list[Task], results: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (density or share, AEVs, controller) over its seeds: the field's metrics' means with 95 %
    intervals and, against the all-human (all-SUMO) point of the same density and seeds, paired verdicts."""
    from ..ring.field import FIELD_METRICS, seed_table

    groups: dict[tuple[Any, ...], dict[str, list[dict[str, Any]]]] = {}
    for t in tasks:
        r = results.get(t.key)
        if r is None or r["status"] == "error" or not r["metrics"]:
            continue
        v = t.spec["values"]
        where = ("density_per_km", v["density_per_km"]) if t.spec["kind"] == "ring" else ("scenario", t.spec["file"])
        what = v.get("aevs", v.get("share"))
        label = f"{what} {t.controller}"
        groups.setdefault(where, {}).setdefault(label, []).append({**r["metrics"][0], "seed": v["seed"]})
    rows = []
    for where, runs in groups.items():
        for label in runs:
            runs[label].sort(key=lambda m: m["seed"])
        base = next((lab for lab in runs if lab.split(" ", 1)[0] in ("0", "0.0")), None)
        metrics = [  # a metric every completed run has a number for (a merge has no lap: no travel time per lap)
            m
            for m in FIELD_METRICS
            if all(isinstance(r.get(m), (int, float)) for ms in runs.values() for r in ms if r.get("status") == "ok")
        ]
        part = seed_table(runs, base, metrics)
        for row in part:
            row[where[0]] = where[1]
        rows += part
    return rows

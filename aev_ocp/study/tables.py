"""The tables of a study file: [[axes]] (grid, zipped or seeded random), [controllers], [report] and the base
``scenarios``, each read with the scenario loader's :class:`~aev_ocp.scenarios.TableReader`."""

from __future__ import annotations

import difflib
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..limits import check_study_size
from ..models.carfollowing import LAW_REGISTRY
from ..overrides import OverrideError, check_key
from ..params import echo
from ..scenarios import TableReader, find_scenario
from .model import CHANGE_METRICS, TABLE_AFTER, TABLE_EXTRA, TABLE_LEAD, TABLE_TAIL, Axis, Controller, StudyError


def _axis(r: TableReader, i: int) -> Axis:
    where = f"axes[{i}]"
    if r.has("key") == r.has("keys"):
        raise StudyError(f"{r.file}: {where}: give either key (one dotted key) or keys (an array), not both or neither")
    keys = [r.string("key")] if r.has("key") else r.strings("keys")
    for k in keys:
        try:
            check_key(k)
        except OverrideError as exc:
            raise StudyError(f"{r.file}: {where}: {exc}") from None
    if len(set(keys)) != len(keys):
        raise r.error("keys", keys, "keys must be distinct")
    if r.has("values") == r.has("random"):
        raise StudyError(
            f"{r.file}: {where} ({', '.join(keys)}): give either values or random = {{n, seed, low, high}}"
        )
    if r.has("values"):
        vals = r.table["values"]
        r._get("values", None)
        if not isinstance(vals, list) or not vals:
            raise r.error("values", vals, "expected a non-empty array")
        rows: tuple[tuple[Any, ...], ...]
        if len(keys) == 1 and r.has("key"):
            rows = tuple((v,) for v in vals)
            kind = "grid"
        else:
            if len(vals) != len(keys) or not all(isinstance(v, list) for v in vals):
                raise r.error("values", vals, f"expected {len(keys)} arrays, one per key of {keys}")
            lengths = {len(v) for v in vals}
            if len(lengths) != 1 or 0 in lengths:
                raise r.error("values", vals, "the arrays of a zipped axis must have the same, non-zero length")
            rows = tuple(zip(*vals))
            kind = "zip"
        r.finish()
        return Axis(tuple(keys), rows, kind)
    rnd = r.sub("random", required=True)
    n = rnd.integer("n", ge=1)
    check_study_size(n, 1, f"{r.file}: {where} ({', '.join(keys)}): random.n = {n}")  # before drawing n samples
    seed = rnd.integer("seed", ge=0)
    log = rnd.boolean("log", False)
    lows = _bounds(rnd, "low", len(keys))
    highs = _bounds(rnd, "high", len(keys))
    for j, (lo, hi) in enumerate(zip(lows, highs)):
        if not hi > lo or (log and lo <= 0):
            raise rnd.error("high", highs, f"needs high > low{' > 0 (log)' if log else ''} for {keys[j]}")
    rnd.finish()
    r.finish()
    rng = np.random.default_rng(seed)
    u = rng.random((n, len(keys)))
    lo_a, hi_a = np.array(lows), np.array(highs)
    x = np.exp(np.log(lo_a) + u * (np.log(hi_a) - np.log(lo_a))) if log else lo_a + u * (hi_a - lo_a)
    return Axis(tuple(keys), tuple(tuple(float(v) for v in row) for row in x), "random", seed)


def _bounds(r: TableReader, key: str, n: int) -> list[float]:
    if isinstance(r.table.get(key), list):
        vals = r.numbers(key)
        if len(vals) != n:
            raise r.error(key, vals, f"needs {n} values, one per key")
        return vals
    return [r.number(key)] * n


def _controllers(r: TableReader) -> list[Controller]:
    out: list[Controller] = []
    for name in r.strings("laws", [], choices=sorted(LAW_REGISTRY)):
        out.append(Controller(name, "law", name))
    mpcs = r.table.get("mpc", [])
    r._get("mpc", None)
    if isinstance(mpcs, dict):
        mpcs = [mpcs]
    if not isinstance(mpcs, list) or not all(isinstance(m, dict) for m in mpcs):
        raise r.error("mpc", mpcs, "expected [[controllers.mpc]] tables")
    for j, m in enumerate(mpcs):
        m = dict(m)
        label = m.pop("label", "mpc" if len(mpcs) == 1 else f"mpc{j + 1}")
        if not isinstance(label, str) or not label:
            raise StudyError(f"{r.file}: controllers.mpc[{j}].label = {echo(label)} is not allowed: expected a string")
        out.append(Controller(label, "mpc", "mpc", tuple(sorted(m.items()))))
    if r.boolean("ocpd", False):
        out.append(Controller("ocp-d", "ocpd", "ocpd"))
    r.finish()
    labels = [c.label for c in out]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise StudyError(f"{r.file}: controllers: labels {dup} are used twice; give each [[controllers.mpc]] a label")
    if not out:
        raise StudyError(f"{r.file}: controllers: none given (laws = [...], [[controllers.mpc]] or ocpd = true)")
    return out


def _report(r: TableReader, file: str) -> dict[str, Any]:
    veh = r.table.get("vehicle", 1)
    r._get("vehicle", None)
    vehicles = veh if isinstance(veh, list) else [veh]
    if not vehicles or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in vehicles):
        raise r.error("vehicle", veh, "expected a follower number (1, 2, ...) or an array of them")
    rep: dict[str, Any] = {
        "vehicle": vehicles[0],
        "vehicles": vehicles,
        "metrics": r.strings("metrics", ["battery_energy_kWh_per_100km", "heat_pack_J_per_km", "omega_model"]),
        "change_metric": r.string("change_metric", "omega_model"),
    }
    pareto = r.table.get("pareto", [])
    r._get("pareto", None)
    if not isinstance(pareto, list) or not all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p) for p in pareto
    ):
        raise r.error("pareto", pareto, "expected an array of [metric_x, metric_y] pairs (both minimised)")
    rep["pareto"] = [tuple(p) for p in pareto]
    rep["pareto_by"] = r.strings("pareto_by", [])
    diffs = r.table.get("differences", [])
    r._get("differences", None)
    if not isinstance(diffs, list) or not all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p) and p[0] != p[1] for p in diffs
    ):
        raise r.error("differences", diffs, 'expected an array of ["a", "b"] controller label pairs (a − b per seed)')
    rep["differences"] = [tuple(p) for p in diffs]
    r.finish()
    return rep


@lru_cache(maxsize=1)
def _metric_columns() -> frozenset[str]:
    """Every metric key a task can give a follower: the §10 metrics (:func:`aev_ocp.metrics.vehicle_metrics` on a
    two-sample run with the thermal model, so the temperature metrics are in), the compiled integrator's and a
    sampled controller's statistics, an MPC's own cost and OCP-D's optimum, grid step and grid kind."""
    from ..control import sampled_stat_names
    from ..metrics import vehicle_metrics
    from ..ocp.formulation import COST_KEYS
    from ..params import EVParams
    from ..results import SimulationResult
    from ..simulate import INTEGRATOR_STATS

    t, o = np.array([0.0, 1.0]), np.ones((2, 1))
    r = SimulationResult(
        t=t,
        leader_speed=t + 1.0,
        leader_position=t,
        gap=o,
        speed=o,
        accel=o,
        V1=o,
        V2=o,
        S=o,
        current_A=o,
        omega=o,
        heat_J=o,
        heat_irr_J=o,
        int_ovm_err2=o,
        int_rel_speed2=o,
        int_jerk2=o,
        controllers=["law"],
        ev=EVParams(),
        temperature_K=o,
    )
    own_cost = [*COST_KEYS.values(), *(f"{k}_optimum" for k in COST_KEYS.values())]
    return frozenset([*vehicle_metrics(r, 0), *INTEGRATOR_STATS, *sampled_stat_names(), *own_cost, "grid_dt", "coarse"])


def report_columns(axes: list[Axis]) -> frozenset[str]:
    """Every column a study's table can have (:mod:`aev_ocp.study.table`): the fixed ones, the axis keys and
    every metric key: what a [report] may name."""
    keys = [k for a in axes for k in a.keys]
    return frozenset([*TABLE_LEAD, *TABLE_AFTER, *TABLE_TAIL, *TABLE_EXTRA, *keys]) | _metric_columns()


def check_report(file: str, report: dict[str, Any], axes: list[Axis], followers: set[int] | None = None) -> None:
    """Refuse, before anything runs, a [report] that names no column of the table (``report.metrics``,
    ``report.pareto``, ``report.pareto_by``), a ``report.change_metric`` without a % change column, or a follower
    (``report.vehicle``) that no scenario of the study has (``followers``: the follower counts of its points); a
    follower only some scenarios lack is the report's warning after the run. Without ``followers`` only the names
    are checked."""
    known = report_columns(axes)
    for key, names in (
        ("metrics", report.get("metrics", [])),
        ("pareto", [m for pair in report.get("pareto", []) for m in pair]),
        ("pareto_by", report.get("pareto_by", [])),
    ):
        unknown = [m for m in names if m not in known]
        if unknown:
            near = difflib.get_close_matches(str(unknown[0]), sorted(known), n=3)
            metrics = sorted(k for k in _metric_columns() if not k.endswith("_model"))[:6]
            hint = (
                f"did you mean {', '.join(near)}?"
                if near
                else f"axis keys {[k for a in axes for k in a.keys]}, controller, scenario, vehicle, or a metric "
                f"({', '.join(metrics)}, …)"
            )
            raise StudyError(
                f"{file}: report.{key} names {', '.join(map(echo, unknown))}, no column of the table ({hint})"
            )
    change = report.get("change_metric", "omega_model")
    if change not in CHANGE_METRICS:  # the metrics with a % change column
        raise StudyError(
            f"{file}: report.change_metric = {echo(change)} is not allowed: must be one of {list(CHANGE_METRICS)}"
        )
    if not followers:
        return
    most = max(followers)
    beyond = [v for v in report.get("vehicles", [report.get("vehicle", 1)]) if v > most]
    if beyond:
        raise StudyError(
            f"{file}: report.vehicle = {beyond[0]} is not allowed: must be a follower 1-{most} (the study's "
            f"scenarios have {', '.join(map(str, sorted(followers)))} follower(s))"
        )


def _bases(top: TableReader) -> tuple[list[str], dict[str, tuple[str, dict[str, Any]]]]:
    """``scenarios``: names/paths, or inline tables {scenario, label, overrides} (overrides for that base only).
    Returns the labels and {label: (scenario, overrides)}."""
    raw = top.table.get("scenarios")
    top._get("scenarios", None)
    if not isinstance(raw, list) or not raw:
        raise top.error(
            "scenarios",
            raw,
            "expected a non-empty array of scenario names/paths or "
            "{ scenario = ..., label = ..., overrides = { ... } } tables",
        )
    labels: list[str] = []
    out: dict[str, tuple[str, dict[str, Any]]] = {}
    for j, item in enumerate(raw):
        if isinstance(item, str):
            label, scen, ov = Path(item).stem, item, {}
        elif isinstance(item, dict):
            r = TableReader(item, f"scenarios[{j}]", top.file)
            scen = r.string("scenario")
            label = r.string("label", Path(scen).stem)
            ov_r = r.sub("overrides")
            ov = dict(ov_r.table)
            ov_r._seen.update(ov)
            r.finish()
        else:
            raise top.error(f"scenarios[{j}]", item, "expected a scenario name/path or an inline table")
        if label in out:
            raise top.error(f"scenarios[{j}]", item, f"label {echo(label)} is used twice; give each a distinct label")
        labels.append(label)
        out[label] = (scen, ov)
    return labels, out


def _base(name: str, study_path: Path | None) -> Path:
    p = Path(name)
    if study_path is not None and not p.is_absolute():
        cand = study_path.parent / p
        if cand.is_file():
            return cand
    return find_scenario(name)

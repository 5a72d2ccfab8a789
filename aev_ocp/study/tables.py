"""The tables of a study file: [[axes]] (grid, zipped or seeded random), [controllers], [report] and the base
``scenarios``, each read with the scenario loader's :class:`~aev_ocp.scenarios.TableReader`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..limits import check_study_size
from ..models.carfollowing import LAW_REGISTRY
from ..overrides import OverrideError, check_key
from ..params import echo
from ..scenarios import TableReader, find_scenario
from .model import Axis, Controller, StudyError


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
        "metrics": r.strings("metrics", ["omega_model", "heat_pack_J_per_km"]),
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
    r.finish()
    return rep


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

"""The study's tidy table: one row per point × controller × vehicle; CSV and JSON Lines; loading back.

Columns: study, point, scenario, the axis keys, controller, vehicle, status, message, the
comparability check against the reference controller (comparable, flag_distance, flag_duration,
flag_event, distance_diff_pct, duration_diff_pct), % change of ω, pack ∫Q and pack ∫Q per km against
the reference (``*_change_pct``), every §10 metric of :mod:`aev_ocp.metrics` (with solver statistics
for MPC rows), the task's wall time and hash, and provenance (package and CasADi versions, git
commit when available).
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

from ..provenance import versions
from ..metrics import comparability, si_first
from ..results import write_atomic
from ..truncation import equal_profile_views
from .model import (  # the fixed columns live with the study's data: a [report] is checked against them
    CHANGE_METRICS as CHANGE_METRICS,
    EQUAL_METRIC as EQUAL_METRIC,
    EQUAL_VIEWS as EQUAL_VIEWS,
    TABLE_AFTER as _AFTER,
    TABLE_LEAD as _LEAD,
    TABLE_TAIL as _TAIL,
)
from .spec import Study

TABLE_JSONL = "table.jsonl"
TABLE_CSV = "table.csv"


def provenance() -> dict[str, Any]:
    """Package and CasADi versions and the git commit (:mod:`aev_ocp.provenance`), the study table's columns."""
    v = versions()
    return {"aev_ocp_version": v["aev_ocp"], "casadi_version": v["casadi"], "git_commit": v["git_commit"]}


def _pct(a: Any, b: Any) -> float | None:
    if not isinstance(a, (int, float)) or not isinstance(b, (int, float)) or isinstance(a, bool) or b == 0:
        return None
    x = 100.0 * (a / b - 1.0)
    return x if math.isfinite(x) else None


def _equal_views(results: dict[str, Any], labels: dict[str, str]) -> dict[Any, dict[str, Any]]:
    """{vehicle: equal_profile_views} of one point's runs ({label: task key}); runs that failed or ended by an
    event are left out of the cut (as in the whole-run comparability check)."""
    by_vehicle: dict[Any, dict[str, Any]] = {}
    for lab, key in labels.items():
        res = results.get(key) or {}
        if res.get("status") not in ("ok", "violated"):
            continue
        for m, prof in zip(res.get("metrics") or [], res.get("profiles") or []):
            by_vehicle.setdefault(m.get("vehicle"), {})[lab] = prof
    return {v: equal_profile_views(p) for v, p in by_vehicle.items()}


def build_rows(study: Study, results: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """The tidy rows of a study from its task results ({hash: result})."""
    prov = provenance()
    tasks = {(t.point, t.controller): t for t in study.tasks()}
    rows: list[dict[str, Any]] = []
    for p in study.points:
        ref = results.get(tasks[(p.index, study.reference)].key)
        ref_by_vehicle = {m["vehicle"]: m for m in (ref or {}).get("metrics", [])} if ref else {}
        views = _equal_views(results, {c.label: tasks[(p.index, c.label)].key for c in study.controllers})
        for c in study.controllers:
            t = tasks[(p.index, c.label)]
            res = results.get(t.key)
            if res is None:
                continue
            head: dict[str, Any] = {"study": study.name, "point": p.index, "scenario": p.base}
            head.update({k: p.values[k] for k in p.values})
            ms = res.get("metrics") or [{"vehicle": None}]
            for m in ms:
                row = dict(head)
                row.update(
                    controller=c.label, vehicle=m.get("vehicle"), status=res["status"], message=res.get("message", "")
                )
                r = ref_by_vehicle.get(m.get("vehicle"))
                if res["status"] == "error":
                    flags = {
                        "distance_diff_pct": None,
                        "duration_diff_pct": None,
                        "flag_distance": True,
                        "flag_duration": True,
                        "flag_event": True,
                        "comparable": False,
                    }
                else:
                    flags = comparability({**m, "run_status": res["status"]}, r)
                    flags = {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in flags.items()}
                row.update(flags)
                for k in CHANGE_METRICS:
                    row[f"{k}_change_pct"] = _pct(m.get(k), r.get(k)) if r else None
                for prefix, view, cut in EQUAL_VIEWS:
                    vw = views.get(m.get("vehicle"), {}).get(view, {})
                    mine, ref_v = vw.get("runs", {}).get(c.label), vw.get("runs", {}).get(study.reference)
                    cut_value = vw.get(cut) if mine else None
                    row[f"{prefix}_{cut}"] = cut_value if cut_value is not None and math.isfinite(cut_value) else None
                    row[f"{prefix}_{EQUAL_METRIC}"] = mine[EQUAL_METRIC] if mine else None
                    row[f"{prefix}_rank"] = mine["rank"] if mine else None
                    row[f"{prefix}_{EQUAL_METRIC}_change_pct"] = (
                        _pct(mine[EQUAL_METRIC], ref_v[EQUAL_METRIC]) if mine and ref_v else None
                    )
                row.update({k: v for k, v in m.items() if k not in ("vehicle", "controller", "status")})
                row["vehicle_status"] = m.get("status")
                row["wall_s"] = res.get("wall_s")
                row["task_hash"] = t.key
                row.update(prov)
                rows.append(row)
    _ocpd_roles(study, rows)
    return rows


def _ocpd_roles(study: Study, rows: list[dict[str, Any]]) -> None:
    """The OCP-D rows' bound check, as ``aev-ocp mpc``'s (:func:`aev_ocp.ocp.oracle.bound_role`): 'ocpd_role'
    'bound' only when OCP-D was solved on the MPC's grid and its optimum is at most the own cost of every MPC run
    of the same point and vehicle (within BOUND_RTOL), else 'reference' with 'ocpd_role_reason'. The laws' rows
    carry no cost on the MPC's grid (their task does not read the [mpc] table) and are not part of the check."""
    from ..ocp.oracle import bound_role

    kind = {c.label: c.kind for c in study.controllers}
    for r in rows:
        if kind.get(r["controller"]) != "ocpd" or r["status"] == "error":
            continue
        key = next((k[: -len("_optimum")] for k in r if k.endswith("_optimum")), None)
        if key is None:
            continue
        if r.get("coarse"):
            r["ocpd_role"], r["ocpd_role_reason"] = (
                "reference",
                (f"OCP-D was solved on a coarser grid (dt = {r.get('grid_dt')}): it bounds nothing on the MPC's grid"),
            )
            continue
        runs = {
            x["controller"]: [x]
            for x in rows
            if x["point"] == r["point"]
            and x.get("vehicle") == r.get("vehicle")
            and kind.get(x["controller"]) == "mpc"
            and x["status"] != "error"
        }
        r["ocpd_role"], r["ocpd_role_reason"] = bound_role(float(r[f"{key}_optimum"]), runs, key)


def columns(rows: list[dict[str, Any]], axis_keys: list[str]) -> list[str]:
    """Column order: leading, axes, controller/flags, metrics (first-seen order, SI before ``_model``), tail."""
    fixed = set(_LEAD) | set(axis_keys) | set(_AFTER) | set(_TAIL)
    metrics: dict[str, None] = {}
    for r in rows:
        for k in r:
            if k not in fixed:
                metrics.setdefault(k, None)
    return (
        list(_LEAD) + [k for k in axis_keys if k != "scenario"] + list(_AFTER) + si_first(list(metrics)) + list(_TAIL)
    )


def write_table(rows: list[dict[str, Any]], out: str | Path, axis_keys: list[str]) -> tuple[Path, Path]:
    """Write ``table.csv`` and ``table.jsonl`` atomically into ``out``; returns both paths."""
    out = Path(out)
    cols = columns(rows, axis_keys)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow(["" if r.get(c) is None else (repr(r[c]) if isinstance(r[c], float) else r[c]) for c in cols])
    csv_path = write_atomic(out / TABLE_CSV, buf.getvalue())
    lines = "".join(json.dumps({c: r.get(c) for c in cols}) + "\n" for r in rows)
    jsonl_path = write_atomic(out / TABLE_JSONL, lines)
    return csv_path, jsonl_path


def _convert(x: str) -> Any:
    if x == "":
        return None
    if x in ("True", "False"):
        return x == "True"
    try:
        return int(x)
    except ValueError:
        pass
    try:
        return float(x)
    except ValueError:
        return x


def load_table(path: str | Path, as_dataframe: bool = False) -> Any:
    """Load a study table: a study output folder, its ``table.jsonl`` or its ``table.csv``.

    Returns a list of row dicts, or a pandas DataFrame with ``as_dataframe=True`` (needs pandas). A file that is
    missing, not a regular file, larger than the memory limit, not UTF-8 or not a table of rows raises
    :class:`aev_ocp.LoadError` naming it (before: UnicodeDecodeError, JSONDecodeError, or a hang on a FIFO)."""
    from ..limits import FileRefused, memory_limit_bytes, read_regular_file
    from ..saved import LoadError

    p = Path(path)
    if p.is_dir():
        p = p / TABLE_JSONL
    try:
        text = read_regular_file(p, int(memory_limit_bytes())).decode("utf-8")
        if p.suffix == ".csv":
            rows = [{k: _convert(v) for k, v in r.items()} for r in csv.DictReader(io.StringIO(text, newline=""))]
        else:
            rows = [json.loads(line) for line in text.splitlines() if line.strip()]
    except FileRefused as exc:
        raise LoadError(f"{p}: cannot read the study table ({exc})") from None
    except (UnicodeDecodeError, ValueError, csv.Error, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise LoadError(f"{p}: not a study table written by aev-ocp study ({type(exc).__name__}: {exc})") from None
    if not all(isinstance(r, dict) for r in rows):
        raise LoadError(f"{p}: not a study table written by aev-ocp study (a line is not a JSON object)")
    if as_dataframe:
        from ..results import require_pandas

        return require_pandas("load_table(as_dataframe=True)").DataFrame(rows)
    return rows

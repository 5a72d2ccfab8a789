"""A study's runs over its seeds: every metric's mean, 95 % interval and n per point of the other axes,
and the paired difference between two controllers on the same seeds with its interval and a better/worse/tie verdict.

A study has a *seed axis* when all keys of one of its axes are seeds (a key whose last part is ``seed`` or ends in
``_seed``: ``sensors.seed``, ``mismatch.seed``, ``ring.seed``; a zipped axis moves them together). Its summary groups
the table's rows over the seed axes' values (by scenario, the other axes' values, controller and follower); runs that
failed or ended by an event are left out (``n`` counts the others). A difference a − b pairs the runs of a and b on
the same seeds (:func:`aev_ocp.intervals.difference`, Student's t on the per-seed differences); the verdict is
'better' or 'worse' for a only when its interval excludes zero, 'tie' otherwise (:func:`aev_ocp.intervals.verdict`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..intervals import LEVEL, difference, summarize, verdict
from ..results import write_json
from .model import Axis

SEEDS_JSON = "seeds.json"

#: metrics where a larger value is the better one (a safety margin); every other metric: smaller is better
HIGHER_IS_BETTER = frozenset(
    {"min_gap_m", "min_gap_model", "min_ttc_s", "min_ttc_model", "min_speed_mps", "min_speed_model"}
)
#: statuses of runs kept over the seeds: ran to the end (a run that only went below its floor ran to the end)
KEPT_STATUSES = ("ok", "violated")


def is_seed_key(key: str) -> bool:
    """Whether the dotted scenario key ``key`` is a seed (its last part ``seed`` or ``*_seed``)."""
    leaf = key.rsplit(".", 1)[-1]
    return leaf == "seed" or leaf.endswith("_seed")


def seed_keys(axes: Sequence[Axis]) -> list[str]:
    """The keys of the axes whose keys are all seeds (empty: the study has no seed axis)."""
    return [k for a in axes if a.keys and all(is_seed_key(k) for k in a.keys) for k in a.keys]


def _finite(x: Any) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def _runs(
    rows: Iterable[dict[str, Any]], group_keys: Sequence[str], seeds: Sequence[str], vehicles: Sequence[Any] | None
) -> dict[tuple[Any, ...], dict[str, dict[tuple[Any, ...], dict[str, Any]]]]:
    """{(group values..., vehicle): {controller: {seed values: row}}} of the kept rows."""
    out: dict[tuple[Any, ...], dict[str, dict[tuple[Any, ...], dict[str, Any]]]] = {}
    for r in rows:
        if r.get("status") not in KEPT_STATUSES or (vehicles is not None and r.get("vehicle") not in vehicles):
            continue
        g = tuple(r.get(k) for k in group_keys) + (r.get("vehicle"),)
        out.setdefault(g, {}).setdefault(r["controller"], {})[tuple(r.get(k) for k in seeds)] = r
    return out


def _interval(prefix: str, values: list[float], level: float) -> dict[str, Any]:
    if len(values) < 2:  # one seed: a mean, no interval
        mean = values[0] if values else None
        return {f"{prefix}_mean": mean, f"{prefix}_lo": None, f"{prefix}_hi": None, f"{prefix}_n": len(values)}
    iv = summarize(values, level)
    return {f"{prefix}_mean": iv.mean, f"{prefix}_lo": iv.lo, f"{prefix}_hi": iv.hi, f"{prefix}_n": iv.n}


def seed_summary(
    rows: Sequence[dict[str, Any]],
    group_keys: Sequence[str],
    seeds: Sequence[str],
    metrics: Sequence[str],
    vehicles: Sequence[Any] | None = None,
    level: float = LEVEL,
) -> list[dict[str, Any]]:
    """One row per group (``group_keys`` values, follower) and controller: n_seeds (runs kept), n_dropped (runs
    that failed or ended by an event), each controller's conditioning as its runs name it, and for each metric
    ``<metric>_mean``, ``_lo``, ``_hi`` (the ``level`` t interval of the mean over the seeds) and ``_n``."""
    kept = _runs(rows, group_keys, seeds, vehicles)
    dropped: dict[tuple[Any, ...], int] = {}
    for r in rows:
        if r.get("status") not in KEPT_STATUSES and (vehicles is None or r.get("vehicle") in vehicles):
            g = tuple(r.get(k) for k in group_keys) + (r.get("vehicle"), r.get("controller"))
            dropped[g] = dropped.get(g, 0) + 1
    out: list[dict[str, Any]] = []
    for g, by_ctrl in kept.items():
        for ctrl, runs in by_ctrl.items():
            row: dict[str, Any] = dict(zip(group_keys, g[:-1]))
            conditioning = sorted({str(r.get("conditioning") or "none") for r in runs.values()})
            row.update(
                controller=ctrl,
                vehicle=g[-1],
                conditioning=", ".join(conditioning),
                n_seeds=len(runs),
                n_dropped=dropped.get(g + (ctrl,), 0),
            )
            for m in metrics:
                vals = [v for v in (_finite(r.get(m)) for r in runs.values()) if v is not None]
                row.update(_interval(m, vals, level))
            out.append(row)
    return out


def seed_differences(
    rows: Sequence[dict[str, Any]],
    group_keys: Sequence[str],
    seeds: Sequence[str],
    metrics: Sequence[str],
    pairs: Sequence[tuple[str, str]],
    vehicles: Sequence[Any] | None = None,
    level: float = LEVEL,
) -> list[dict[str, Any]]:
    """One row per group and pair (a, b): the paired difference a − b over the seeds both ran to the end,
    ``<metric>_diff_mean``, ``_diff_lo``, ``_diff_hi``, ``_diff_n``, its share of b's mean over the same seeds
    ``<metric>_diff_pct`` (100 (a − b)/b; the interval's ends ``_diff_lo_pct``, ``_diff_hi_pct`` on the same scale)
    and ``<metric>_verdict`` ('better'/'worse' for a when the interval excludes 0, else 'tie'; smaller is better but
    for :data:`HIGHER_IS_BETTER`); with fewer than 2 common seeds the verdict is None."""
    kept = _runs(rows, group_keys, seeds, vehicles)
    out: list[dict[str, Any]] = []
    for g, by_ctrl in kept.items():
        for a, b in pairs:
            ra, rb = by_ctrl.get(a, {}), by_ctrl.get(b, {})
            row: dict[str, Any] = dict(zip(group_keys, g[:-1]))
            row.update(a=a, b=b, vehicle=g[-1])
            for m in metrics:
                pa, pb = [], []
                for s in sorted(set(ra) & set(rb), key=repr):
                    x, y = _finite(ra[s].get(m)), _finite(rb[s].get(m))
                    if x is not None and y is not None:
                        pa.append(x)
                        pb.append(y)
                d = difference(pa, pb, paired=True, level=level) if len(pa) >= 2 else None
                mb = sum(pb) / len(pb) if pb else None
                scale = 100.0 / mb if mb else None
                row.update(
                    {
                        f"{m}_diff_mean": d.mean if d else None,
                        f"{m}_diff_lo": d.lo if d else None,
                        f"{m}_diff_hi": d.hi if d else None,
                        f"{m}_diff_n": len(pa),
                        f"{m}_diff_pct": d.mean * scale if d and scale else None,
                        f"{m}_diff_lo_pct": d.lo * scale if d and scale else None,
                        f"{m}_diff_hi_pct": d.hi * scale if d and scale else None,
                        f"{m}_verdict": verdict(d, lower_is_better=m not in HIGHER_IS_BETTER) if d else None,
                    }
                )
            out.append(row)
    return out


def study_pairs(study: Any) -> list[tuple[str, str]]:
    """The pairs a study compares: its ``[report] differences`` or every controller against the reference."""
    given = study.report.get("differences")
    if given:
        return [(str(a), str(b)) for a, b in given]
    return [(c.label, study.reference) for c in study.controllers if c.label != study.reference]


def study_seeds(study: Any, rows: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The seed summary and differences of a study's table rows (None without a seed axis): grouped by the other
    axes (and the base scenario when several), for the ``[report]`` metrics and followers."""
    seeds = seed_keys(study.axes)
    if not seeds:
        return None
    groups = ["scenario"] + [k for k in study.axis_keys if k not in seeds and k != "scenario"]
    metrics = list(study.report.get("metrics", []))
    vehicles = list(study.report.get("vehicles") or [study.report.get("vehicle", 1)])
    pairs = study_pairs(study)
    return {
        "seed_keys": seeds,
        "group_keys": groups,
        "metrics": metrics,
        "level": LEVEL,
        "pairs": [list(p) for p in pairs],
        "summary": seed_summary(rows, groups, seeds, metrics, vehicles),
        "differences": seed_differences(rows, groups, seeds, metrics, pairs, vehicles),
    }


def write_seeds(folder: str | Path, seeds: dict[str, Any]) -> Path:
    """``seeds.json`` (the summary and the differences) atomically into ``folder``."""
    return write_json(Path(folder) / SEEDS_JSON, seeds)


def _num(x: Any, fmt: str) -> str:
    return "–" if x is None else format(x, fmt)


def interval_text(mean: Any, lo: Any, hi: Any, fmt: str = ".4g") -> str:
    """'mean [lo, hi]' ('mean' alone without an interval, '–' without a value)."""
    if mean is None:
        return "–"
    if lo is None or hi is None:
        return format(mean, fmt)
    return f"{mean:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def markdown_lines(seeds: dict[str, Any], fmt: str = ".4g") -> list[str]:
    """The summary and the differences as Markdown tables (report.md's "Over the seeds")."""
    from ..report import markdown_table

    groups, metrics = seeds["group_keys"], seeds["metrics"]
    level = f"{100 * seeds['level']:g} %"
    lines = [
        f"Mean over the seeds ({', '.join(seeds['seed_keys'])}) and its {level} t interval [lo, hi]; n: runs kept "
        "(runs that failed or ended by an event are left out: 'dropped').",
        "",
        markdown_table(
            [*groups, "controller", "follower", "conditioning", "n", "dropped", *metrics],
            [
                [*(str(r.get(k)) for k in groups), r["controller"], str(r["vehicle"]), r["conditioning"]]
                + [str(r["n_seeds"]), str(r["n_dropped"])]
                + [interval_text(r[f"{m}_mean"], r[f"{m}_lo"], r[f"{m}_hi"], fmt) for m in metrics]
                for r in seeds["summary"]
            ],
        ),
        "",
    ]
    if seeds["differences"]:
        lines += [
            f"Paired difference a − b on the same seeds, mean [{level} interval], and the verdict for a (better/worse "
            "only when the interval excludes 0, else tie; smaller is better except for "
            + ", ".join(sorted(m for m in HIGHER_IS_BETTER if m in metrics) or ["none of these"])
            + "):",
            "",
            markdown_table(
                [*groups, "a − b", "follower", *metrics],
                [
                    [*(str(r.get(k)) for k in groups), f"{r['a']} − {r['b']}", str(r["vehicle"])]
                    + [
                        interval_text(r[f"{m}_diff_mean"], r[f"{m}_diff_lo"], r[f"{m}_diff_hi"], "+" + fmt)
                        + f" (n {r[f'{m}_diff_n']}) {r[f'{m}_verdict'] or ''}".rstrip()
                        for m in metrics
                    ]
                    for r in seeds["differences"]
                ],
            ),
            "",
        ]
    return lines

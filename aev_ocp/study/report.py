"""Figures and report.md of a study: metric-vs-axis plots (a line per controller), Pareto fronts with
the non-dominated points marked, and the % change against the reference controller over the axes.

Only rows of the report's vehicle (``[report] vehicle``, default follower 1) are shown. Rows that are
not comparable with the reference (distance or duration > 1 % apart, ended by an event, failed) are
drawn hollow in the figures, starred in tables and never on a Pareto front.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .. import plots  # noqa: E402
from ..plots import comparable_dots  # noqa: E402
from ..results import save_figure_atomic, write_atomic  # noqa: E402
from .table import EQUAL_METRIC
from .spec import Study  # noqa: E402


def _num(x: Any) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def pareto_mask(points: list[tuple[float, float]]) -> list[bool]:
    """Non-dominated points when both coordinates are minimised (ties: both kept)."""
    out = []
    for i, (x, y) in enumerate(points):
        dominated = any((a <= x and b <= y) and (a < x or b < y) for j, (a, b) in enumerate(points) if j != i)
        out.append(not dominated)
    return out


def _primary_axes(study: Study) -> list[str]:
    """The first key of each axis (a zipped axis moves its keys together), 'scenario' first if several."""
    keys = [a.keys[0] for a in study.axes]
    return (["scenario"] if len(study.bases) > 1 else []) + keys


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    try:  # a unique temporary name beside path, removed on any failure (Ctrl-C included)
        save_figure_atomic(fig, path, dpi=plots.DPI)  # the package's figure resolution (120 dpi)
    finally:
        plt.close(fig)
    return path


def _slug(s: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in s).strip("_")


def _label(row: dict[str, Any], keys: list[str]) -> str:
    return ", ".join(f"{k.split('.')[-1]}={row.get(k)!r}" for k in keys)


def plot_metric_vs_axis(study: Study, rows: list[dict[str, Any]], metric: str, axis: str, out: Path) -> Path | None:
    """metric against one numeric axis: a line per controller (and per value of the other axes, up to 6)."""
    others = [k for k in _primary_axes(study) if k != axis]
    cats = sorted({str(r.get(axis)) for r in rows if r.get(axis) is not None and _num(r.get(axis)) is None})
    series: dict[tuple, list[tuple[float, float, bool]]] = {}
    for r in rows:
        x = float(cats.index(str(r.get(axis)))) if cats and r.get(axis) is not None else _num(r.get(axis))
        y = _num(r.get(metric))
        if x is None or y is None:
            continue
        key = (r["controller"],) + tuple(repr(r.get(k)) for k in others)
        series.setdefault(key, []).append((x, y, bool(r.get("comparable"))))
    if not series:
        return None
    combos = sorted({k[1:] for k in series})
    if len(combos) > 6:  # too many lines: keep the first 6 combinations of the other axes
        keep = set(combos[:6])
        series = {k: v for k, v in series.items() if k[1:] in keep}
    ctrls = [c.label for c in study.controllers]
    styles = ["-", "--", ":", "-.", (0, (5, 1)), (0, (1, 1))]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for key, pts in sorted(series.items(), key=lambda kv: (ctrls.index(kv[0][0]) if kv[0][0] in ctrls else 99, kv[0])):
        pts.sort()
        color = f"C{ctrls.index(key[0]) % 10}" if key[0] in ctrls else "k"
        ls = styles[sorted({k[1:] for k in series}).index(key[1:]) % len(styles)]
        lab = key[0] + (
            "" if not others else " (" + ", ".join(f"{o.split('.')[-1]}={v}" for o, v in zip(others, key[1:])) + ")"
        )
        ax.plot([p[0] for p in pts], [p[1] for p in pts], color=color, linestyle=ls, label=lab)
        comparable_dots(ax, pts, color)
    if cats:
        ax.set_xticks(range(len(cats)), cats)
    ax.set_xlabel(axis)
    ax.set_ylabel(metric)
    ax.set_title(
        f"{study.name}: {metric}, follower {study.report.get('vehicle', 1)} (hollow: not comparable)", fontsize=9
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, out / f"fig_{_slug(metric)}_vs_{_slug(axis)}.png")


def pareto_front(study: Study, rows: list[dict[str, Any]], mx: str, my: str) -> tuple[list[dict[str, Any]], list[bool]]:
    """Comparable, successful rows with both metrics, and whether each is non-dominated (both minimised)."""
    cand = [
        r
        for r in rows
        if r.get("comparable")
        and r.get("status") == "ok"
        and _num(r.get(mx)) is not None
        and _num(r.get(my)) is not None
    ]
    mask = pareto_mask([(float(r[mx]), float(r[my])) for r in cand])
    return cand, mask


def plot_pareto(study: Study, rows: list[dict[str, Any]], mx: str, my: str, out: Path, base: str = "") -> Path | None:
    """Every comparable point by controller; the non-dominated ones circled and joined."""
    cand, mask = pareto_front(study, rows, mx, my)
    if not cand:
        return None
    ctrls = [c.label for c in study.controllers]
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for j, c in enumerate(ctrls):
        pts = [(r[mx], r[my]) for r in cand if r["controller"] == c]
        if pts:
            px, py = zip(*pts)
            ax.scatter(px, py, color=f"C{j % 10}", s=18, label=c)
    # never empty: a finite, non-empty set of points has a non-dominated one
    fx, fy = zip(*sorted((r[mx], r[my]) for r, m in zip(cand, mask) if m))
    ax.plot(fx, fy, color="k", linewidth=1.0, drawstyle="steps-post", label="Pareto front")
    ax.scatter(fx, fy, facecolors="none", edgecolors="k", s=70, linewidths=1.2, label="non-dominated")
    ax.set_xlabel(f"{mx} (lower is better)")
    ax.set_ylabel(f"{my} (lower is better)")
    ax.set_title(f"{study.name}{' / ' + base if base else ''}: follower {study.report.get('vehicle', 1)}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, out / f"pareto_{_slug(mx)}_vs_{_slug(my)}{'_' + _slug(base) if base else ''}.png")


def _fmt(x: Any) -> str:
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.5g}"
    return str(x)


def change_table(
    study: Study, rows: list[dict[str, Any]], metric: str, vehicle: int = 1, mark_comparable: bool = True
) -> list[str]:
    """% change of ``metric`` against the reference over the first two numeric axes (one table per
    other controller; with ``mark_comparable`` '*' marks a point whose whole runs are not comparable), and where the
    sign changes."""
    col = f"{metric}_change_pct"
    axes = _primary_axes(study)
    lines: list[str] = []
    if not axes or not any(r.get(col) is not None for r in rows):
        return lines
    numeric = [a for a in axes if any(_num(r.get(a)) is not None for r in rows)]
    axes = numeric[:1] + [a for a in axes if a not in numeric[:1]]  # rows along a numeric axis if any
    ax1 = axes[0]
    ax2 = axes[1] if len(axes) > 1 else None
    signs = bool(numeric)  # a sign change is only meaningful along a numeric axis
    for c in (c.label for c in study.controllers if c.label != study.reference):
        sub = [r for r in rows if r["controller"] == c]
        if not sub:
            continue
        xs = sorted({r[ax1] for r in sub if r.get(ax1) is not None}, key=lambda v: (str(type(v)), v))
        ys = sorted({r[ax2] for r in sub if r.get(ax2) is not None}, key=lambda v: (str(type(v)), v)) if ax2 else [None]
        if len(xs) * len(ys) > 400:
            lines.append(f"({c}: {len(xs)} × {len(ys)} points; the % change is in table.csv, column {col})")
            lines += _sign_changes(sub, col, ax1, ax2, xs, ys, c) if signs else []
            continue
        cell = {(r[ax1], r.get(ax2) if ax2 else None): r for r in sub}
        lines += [
            f"% change of {metric} of **{c}** against **{study.reference}** (follower "
            f"{vehicle}" + ("; * = not comparable):" if mark_comparable else "):"),
            "",
        ]
        lines.append(
            f"| {ax1} \\ {ax2} | " + " | ".join(_fmt(y) for y in ys) + " |" if ax2 else f"| {ax1} | % change |"
        )
        lines.append("|---" * (len(ys) + 1) + "|")
        for x in xs:
            vals = []
            for y in ys:
                r = cell.get((x, y))
                v = None if r is None else r.get(col)
                if r is None or v is None:
                    vals.append("—")
                else:
                    vals.append(f"{v:+.2f}%" + ("" if r.get("comparable") or not mark_comparable else "*"))
            lines.append(f"| {_fmt(x)} | " + " | ".join(vals) + " |")
        lines.append("")
        lines += _sign_changes(sub, col, ax1, ax2, xs, ys, c) if signs else []
    return lines


ZERO_PCT = 1e-9  # % changes smaller than this count as zero (e.g. kappa = 0: the laws coincide)


def _sign(v: float) -> int:
    return 0 if abs(v) <= ZERO_PCT else (1 if v > 0 else -1)


def _nonzero_pairs(seq: list[tuple[Any, float, bool]]) -> list[tuple[tuple[Any, float, bool], tuple[Any, float, bool]]]:
    """Consecutive pairs of the entries whose change is non-zero (a zero in between is skipped)."""
    nz = [s for s in seq if _sign(s[1]) != 0]
    return list(zip(nz, nz[1:]))


def _sign_changes(
    sub: list[dict[str, Any]], col: str, ax1: str, ax2: str | None, xs: list, ys: list, c: str
) -> list[str]:
    """Where, along the first axis, the % change changes sign (per value of the second axis)."""
    cell = {(r[ax1], r.get(ax2) if ax2 else None): r for r in sub}
    out = []
    for y in ys:
        cells = [(x, cell.get((x, y))) for x in xs]
        seq = [(x, r[col], bool(r.get("comparable"))) for x, r in cells if r is not None and r.get(col) is not None]
        flips = [
            f"between {ax1} = {_fmt(a[0])} ({a[1]:+.2f}%) and {_fmt(b[0])} ({b[1]:+.2f}%)"
            + ("" if a[2] and b[2] else " [not comparable]")
            for a, b in _nonzero_pairs(seq)
            if _sign(a[1]) * _sign(b[1]) < 0
        ]
        where = f"at {ax2} = {_fmt(y)}" if ax2 else ""
        if flips:
            out.append(f"- {c}: sign changes {where}: " + "; ".join(flips))
        elif any(_sign(v) for _, v, _ in seq):
            sign = "a saving (< 0)" if any(_sign(v) < 0 for _, v, _ in seq) else "an increase (> 0)"
            out.append(
                f"- {c}: {where} no sign change: {sign} wherever the change is non-zero "
                f"(|change| > {ZERO_PCT:g} %), {ax1} in [{_fmt(seq[0][0])}, {_fmt(seq[-1][0])}]"
            )
    return out + [""]


def _pareto_groups(study: Study, rows: list[dict[str, Any]]) -> list[tuple[str, list[dict[str, Any]]]]:
    """Rows split into the sets a Pareto front compares within: per base scenario (when several) and per
    value of each ``[report] pareto_by`` key (e.g. leader.cycle: runs on different cycles never compete)."""
    by = (["scenario"] if len(study.bases) > 1 else []) + list(study.report.get("pareto_by", []))
    if not by:
        return [("", rows)]
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in by), []).append(r)
    return [
        (", ".join(f"{k.split('.')[-1] if k != 'scenario' else 'scenario'} {v}" for k, v in zip(by, key)), g)
        for key, g in groups.items()
    ]


def _warn_unknown_metrics(study: Study, rows: list[dict[str, Any]]) -> None:
    """A [report] metric that is no column of the table (one the study's controllers do not produce), or a
    [report] vehicle no row is of, gives no figure, and one that some scenarios lack shows the others only: say
    so, once, instead of nothing (names no study can have are refused by read_study)."""
    columns = {k for r in rows for k in r}
    rep = study.report
    asked = [
        *rep.get("metrics", []),
        *(m for pair in rep.get("pareto", []) for m in pair),
        rep.get("change_metric", "omega_model"),
        *rep.get("pareto_by", []),
    ]
    unknown = sorted({m for m in asked if m not in columns})
    if rows and unknown:
        import warnings

        metrics = sorted(k for k in columns if isinstance(rows[0].get(k), float))[:12]
        warnings.warn(
            f"study {study.name}: [report] names {unknown}, not columns of the table: no figure or table for "
            f"them (metric columns include {metrics}; see table.csv)",
            stacklevel=2,
        )
    asked_v = list(rep.get("vehicles") or [rep.get("vehicle", 1)])  # vehicle = [..] is read as 'vehicles'
    present = {r["vehicle"] for r in rows if isinstance(r.get("vehicle"), int)}
    missing = [v for v in asked_v if v not in present]
    if present and missing:  # report.vehicle = [99] on a 1-follower platoon gave an empty report ("0 of 0")
        import warnings

        warnings.warn(
            f"study {study.name}: [report] vehicle names follower(s) {missing}, of which the table has no row: no "
            f"figure or change table for them (the table's followers: {sorted(present)})",
            stacklevel=2,
        )
    by_scenario: dict[Any, set[int]] = {}
    for r in rows:
        if isinstance(r.get("vehicle"), int):
            by_scenario.setdefault(r.get("scenario"), set()).add(r["vehicle"])
    for v in (v for v in asked_v if v in present):  # a follower that only some scenarios have (read_study refuses
        lacking = sorted(str(b) for b, vs in by_scenario.items() if v not in vs)  # one that none has)
        if lacking:
            import warnings

            warnings.warn(
                f"study {study.name}: [report] vehicle {v}: scenario(s) {lacking} have no follower {v}: its figures "
                "and change table show the other scenarios only",
                stacklevel=2,
            )


Front = tuple[str, str, str, "Path | None", list[dict[str, Any]]]


def _fronts(study: Study, rows: list[dict[str, Any]], out: Path) -> list[Front]:
    """Per Pareto pair and group: (mx, my, base, figure or None, the front: one row per distinct run)."""
    fronts: list[Front] = []
    groups = _pareto_groups(study, rows)
    for (mx, my), (base, grows) in ((pair, g) for pair in study.report.get("pareto", []) for g in groups):
        f = plot_pareto(study, grows, mx, my, out, base)
        cand, mask = pareto_front(study, grows, mx, my)
        front, seen = [], set()
        for r, k in sorted(zip(cand, mask), key=lambda rk: (rk[0][mx], rk[0][my])):
            if k and r.get("task_hash") not in seen:  # one row per distinct run (equal tasks share a hash)
                seen.add(r.get("task_hash"))
                front.append(r)
        fronts.append((mx, my, base, f, front))
    return fronts


def _head_lines(study: Study, rows_all: list[dict[str, Any]], rows: list[dict[str, Any]], veh: int) -> list[str]:
    """The report's title, what was run (points, controllers, axes), the counts of events, failures and
    non-comparable rows, and the failed tasks."""
    n_err = sum(1 for r in rows_all if r["status"] == "error")
    n_evt = sum(1 for r in rows_all if r["status"] not in ("ok", "error"))
    n_nc = sum(1 for r in rows if not r.get("comparable"))
    lines = (
        [f"# Study {study.name}", ""]
        + ([study.description, ""] if study.description else [])
        + [
            f"{len(study.points)} points × {len(study.controllers)} controllers "
            f"({', '.join(c.label for c in study.controllers)}), reference **{study.reference}**; "
            f"base scenario(s): {', '.join(study.bases)}; axes: "
            + (
                "; ".join(
                    f"{a.label} ({a.kind}, {len(a.rows)} values"
                    + (f", seed {a.seed}" if a.seed is not None else "")
                    + ")"
                    for a in study.axes
                )
                or "none"
            )
            + ".",
            "",
            f"Rows ended by an event: {n_evt}; failed: {n_err}; follower {veh} rows not comparable with "
            f"the reference (distance or duration > 1 % apart, event, failure): {n_nc} of {len(rows)}.",
            "Table: `table.csv` / `table.jsonl` (one row per point × controller × vehicle; "
            "`aev_ocp.study.load_table(folder)`).",
            "",
        ]
    )
    if n_err:
        lines += ["Failed tasks:", ""]
        seen = set()
        for r in rows_all:
            if r["status"] == "error" and (r["point"], r["controller"]) not in seen:
                seen.add((r["point"], r["controller"]))
                lines.append(f"- point {r['point']} {r['controller']}: {r['message']}")
        lines.append("")
    return lines


def _change_lines(study: Study, rows_all: list[dict[str, Any]], veh: int) -> list[str]:
    """Per reported follower: the change against the reference and the equal-distance view."""
    lines: list[str] = []
    for v in study.report.get("vehicles", [veh]):
        ch = change_table(
            study, [r for r in rows_all if r.get("vehicle") == v], study.report.get("change_metric", "omega_model"), v
        )
        if ch:
            lines += [f"## Change against the reference, follower {v}", ""] + ch
        eq = change_table(
            study,
            [r for r in rows_all if r.get("vehicle") == v],
            f"eq_distance_{EQUAL_METRIC}",
            v,
            mark_comparable=False,
        )
        if eq:
            lines += [
                f"## Equal-distance view, follower {v}",
                "",
                "Pack ∫Q per km of every run of a point up to the shortest distance all its runs covered "
                "(columns `eq_distance_*` of the table; runs ended by an event or a failure are left out), so "
                "runs of different length compare like with like; the same up to the common time: `eq_time_*`.",
                "",
            ] + eq
    return lines


def _front_lines(study: Study, fronts: list[Front], veh: int) -> list[str]:
    """Per Pareto front its figure and its rows (laws show '(any)' for the MPC's axes)."""
    lines: list[str] = []
    for mx, my, base, f, front in fronts:
        lines += [
            f"## Pareto front: {mx} vs {my}{', ' + base if base else ''} (both minimised, "
            f"follower {veh}; comparable rows only)",
            "",
        ]
        if f:
            lines += [f"![Pareto front]({f.name})", ""]
        keys = study.axis_keys
        lines.append("| controller | " + " | ".join(keys) + f" | {mx} | {my} |")
        lines.append("|---" * (len(keys) + 3) + "|")
        for r in front:
            law = next((c.kind == "law" for c in study.controllers if c.label == r["controller"]), False)
            lines.append(
                f"| {r['controller']} | "
                + " | ".join("(any)" if law and k.startswith("mpc.") else _fmt(r.get(k)) for k in keys)
                + f" | {_fmt(r[mx])} | {_fmt(r[my])} |"
            )
        lines.append("")
    return lines


def write_report(study: Study, rows_all: list[dict[str, Any]], out: str | Path) -> list[Path]:
    """Figures and report.md into ``out``; returns the files written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    veh = study.report.get("vehicle", 1)
    rows = [r for r in rows_all if r.get("vehicle") in (veh, None)]
    _warn_unknown_metrics(study, rows_all)
    files: list[Path] = []
    figs: list[Path] = []
    for m in study.report.get("metrics", []):
        for a in (k for k in _primary_axes(study) if k != "scenario"):
            f = plot_metric_vs_axis(study, rows, m, a, out)
            if f:
                figs.append(f)
    fronts = _fronts(study, rows, out)
    figs += [fr[3] for fr in fronts if fr[3]]
    lines = _head_lines(study, rows_all, rows, veh) + _change_lines(study, rows_all, veh)
    from .seeds import markdown_lines, study_seeds

    seeds = study_seeds(study, rows_all)
    if seeds is not None:
        lines += ["## Over the seeds", ""] + markdown_lines(seeds)
    lines += _front_lines(study, fronts, veh)
    if figs:
        lines += ["## Figures", ""] + [f"![{f.stem}]({f.name})" for f in figs if not f.name.startswith("pareto")] + [""]
    files.append(write_atomic(out / "report.md", "\n".join(lines) + "\n"))
    return files + figs

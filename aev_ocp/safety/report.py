"""Outputs of the safety suite: safety.csv, safety.json, safety.md and one figure per family (Agg), all written
atomically (:func:`aev_ocp.results.write_atomic`, :func:`aev_ocp.results.save_figure_atomic`)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..plots import LAW_STYLE  # noqa: E402
from ..report import csv_text, markdown_table, write_text  # noqa: E402
from ..results import save_figure_atomic, write_json  # noqa: E402
from .cases import FAMILIES  # noqa: E402
from .kinematics import AVOIDABLE, LABELS, UNAVOIDABLE  # noqa: E402
from .suite import CaseRow, SuiteOutput  # noqa: E402

FILES = ("safety.csv", "safety.json", "safety.md") + tuple(f"safety_{f.replace('-', '')}.png" for f in FAMILIES)
BOUND_TEXT = (
    "the ego brakes at its maximum a_min from t = 0 (through the actuator lag τ, from a = 0), the lead "
    "follows its profile, both stop at v = 0 and never reverse; the smallest gap of that motion (exact "
    "piecewise solution) labels the case *avoidable* (≥ the 2 m floor of the MPC's traffic formulation), "
    "*collision-avoidable only* (0 < gap < floor) or *unavoidable* (contact whatever the controller does)"
)


def _f(x: float, d: int = 2) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    if isinstance(x, float) and math.isinf(x):
        return "∞"
    return f"{x:.{d}f}"


def summary(out: SuiteOutput) -> dict[str, dict[str, Any]]:
    """Per controller: cases by label, collisions and floor violations by label, failures (avoidable cases with a
    collision or a floor violation)."""
    res: dict[str, dict[str, Any]] = {}
    for r in out.rows:
        s = res.setdefault(
            r.controller,
            {
                "cases": {lb: 0 for lb in LABELS},
                "collisions": {lb: 0 for lb in LABELS},
                "floor_violations": {lb: 0 for lb in LABELS},
                "failures": [],
            },
        )
        s["cases"][r.label] += 1
        s["collisions"][r.label] += int(r.collision)
        s["floor_violations"][r.label] += int(r.floor_violation_samples > 0)
        if r.failed:
            s["failures"].append(r.case)
    return res


def markdown(out: SuiteOutput, heading: str = "##") -> str:
    """The suite as Markdown: how cases are labelled, a summary per controller, and every avoidable-case failure,
    collision and floor violation (all SI)."""
    st = out.settings
    u = st["units"]
    lines = [
        f"{heading} Safety suite: rear-end braking, stationary and slower targets, cut-ins\n",
        f"{len(out.cases)} cases × {len(st['controllers'])} controllers ({', '.join(st['controllers'])}); units "
        f"L = {u['length_m']:g} m, U = {u['speed_mps']:g} m/s for every case (the drive-cycle scenarios'). The MPC "
        "runs on its shipped defaults (MPCSettings(): traffic formulation, decaying-acceleration forecast, the "
        "safe fallback and safety filter); the laws run continuously, saturated to the vehicle's "
        f"[a_min, a_max]. A cut-in is the new predecessor appearing at t = 0 at the given gap. Label: {BOUND_TEXT} "
        f"(a_min = {st['bound_a_min_mps2']:g} m/s², τ = {st['bound_lag_s']:g} s, floor = {st['floor_m']:g} m).\n",
    ]
    if st.get("quick"):
        lines.append("**Quick run** (a few cases, 3 s each): a smoke test, not the suite.\n")
    summ = summary(out)
    rows = []
    for c, s in summ.items():
        rows.append(
            [
                c,
                s["cases"][AVOIDABLE],
                s["collisions"][AVOIDABLE],
                s["floor_violations"][AVOIDABLE],
                sum(s["cases"][lb] for lb in LABELS if lb != AVOIDABLE),
                sum(s["collisions"][lb] for lb in LABELS if lb != AVOIDABLE),
                s["cases"][UNAVOIDABLE],
                s["collisions"][UNAVOIDABLE],
            ]
        )
    lines.append(
        markdown_table(
            [
                "controller",
                "avoidable cases",
                "collisions there",
                "floor violations there",
                "other cases",
                "collisions there",
                "of them unavoidable",
                "collisions there",
            ],
            rows,
        )
    )
    bad = [r for r in out.rows if r.collision or r.floor_violation_samples > 0]
    if bad:
        lines.append(
            "\nRuns with a collision or a floor violation (an avoidable case among them is a failure, **bold**):\n"
        )
        lines.append(
            markdown_table(
                [
                    "case",
                    "controller",
                    "label",
                    "bound min gap [m]",
                    "collision t [s]",
                    "impact speed [m/s]",
                    "min gap [m]",
                    "below floor [s]",
                    "peak decel [m/s²]",
                ],
                [
                    [
                        f"**{r.case}**" if r.failed else r.case,
                        r.controller,
                        r.label,
                        _f(r.bound_min_gap_m),
                        _f(r.collision_time_s),
                        _f(r.impact_speed_mps),
                        _f(r.min_gap_m),
                        _f(r.floor_violation_s),
                        _f(r.peak_decel_mps2),
                    ]
                    for r in bad
                ],
            )
        )
    lines.append("\nPer family (worst over the family's cases; min TTC over all cases):\n")
    fam_rows = []
    for fam in FAMILIES:
        for c in st["controllers"]:
            rs = [r for r in out.rows if r.family == fam and r.controller == c]
            if not rs:
                continue
            fam_rows.append(
                [
                    fam,
                    c,
                    len(rs),
                    sum(r.collision for r in rs),
                    _f(min(r.min_gap_m for r in rs)),
                    _f(min(r.min_ttc_s for r in rs)),
                    _f(max(r.peak_decel_mps2 for r in rs)),
                    _f(max(r.peak_jerk_mps3 for r in rs), 0),
                ]
            )
    lines.append(
        markdown_table(
            [
                "family",
                "controller",
                "cases",
                "collisions",
                "min gap [m]",
                "min TTC [s]",
                "peak decel [m/s²]",
                "peak jerk [m/s³]",
            ],
            fam_rows,
        )
    )
    lines.append(
        "\nEvery row of every case: `safety.csv` / `safety.json`. Peak jerk is sampled (Δa/Δt between "
        "samples: the laws' 8.8 ms output spacing, the MPC's 88 ms steps).\n"
    )
    return "\n".join(lines)


def plot_family(out: SuiteOutput, family: str, path: Path) -> Path | None:
    """One figure per family: min gap [m] per case and controller against the bound, the 2 m floor dashed."""
    cases = [c for c in out.cases if c.family == family]
    if not cases:
        return None
    fig, ax = plt.subplots(figsize=(max(6.0, 0.12 * len(cases) + 4), 3.8))
    x = np.arange(len(cases))
    bound = [next(r.bound_min_gap_m for r in out.rows if r.case == c.name) for c in cases]
    ax.plot(x, bound, "k_", ms=10, mew=2, label="bound (max braking from t = 0)")
    ctrls = out.settings["controllers"]
    for j, ctrl in enumerate(ctrls):
        ys = [
            next((r.min_gap_m for r in out.rows if r.case == c.name and r.controller == ctrl), math.nan) for c in cases
        ]
        coll = [
            next((r.collision for r in out.rows if r.case == c.name and r.controller == ctrl), False) for c in cases
        ]
        style = LAW_STYLE.get(ctrl, {})
        off = (j - (len(ctrls) - 1) / 2) * 0.18
        ax.scatter(x + off, ys, s=14, color=style.get("color"), label=ctrl, zorder=3)
        cx = [xi + off for xi, cc in zip(x, coll) if cc]
        if cx:
            ax.scatter(cx, [0.0] * len(cx), marker="x", s=40, color=style.get("color"), zorder=4)
    ax.axhline(out.settings["floor_m"], color="gray", ls="--", lw=1, label="floor")
    ax.axhline(0.0, color="black", lw=0.8)
    ax.set_ylabel("min gap [m] (× collision)")
    ax.set_xticks(x)
    ax.set_xticklabels([c.name.replace(f"{family}_", "").replace("cutin_", "") for c in cases], rotation=90, fontsize=6)
    ax.set_title(f"{family}: minimum gap per case")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)
    return path


def write_outputs(out: SuiteOutput, folder: str | Path, plots: bool = True) -> list[Path]:
    """safety.csv, safety.json, safety.md and the family figures into ``folder``; returns the paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names = [f.name for f in dataclasses.fields(CaseRow)]
    rows = [[getattr(r, n) for n in names] for r in out.rows]
    files = [
        write_text(
            folder / "safety.csv", csv_text(names + ["failed"], [row + [r.failed] for row, r in zip(rows, out.rows)])
        ),
        write_json(
            folder / "safety.json",
            {
                "settings": out.settings,
                "summary": summary(out),
                "cases": [dataclasses.asdict(c) for c in out.cases],
                "rows": [{**dataclasses.asdict(r), "failed": r.failed} for r in out.rows],
            },
        ),
        write_text(folder / "safety.md", markdown(out, "#")),
    ]
    if plots:
        for fam in FAMILIES:
            p = plot_family(out, fam, folder / f"safety_{fam.replace('-', '')}.png")
            if p is not None:
                files.append(p)
    return files

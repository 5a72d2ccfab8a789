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

from ..report import csv_text, markdown_table, write_text  # noqa: E402
from ..results import save_figure_atomic, write_json  # noqa: E402
from .cases import FAMILIES  # noqa: E402
from ..models.braking import AVOIDABLE, COLLISION_AVOIDABLE_ONLY, LABELS, UNAVOIDABLE  # noqa: E402
from .plots import family_figure  # noqa: E402
from .run import CaseRow, SuiteOutput  # noqa: E402

FILES = ("safety.csv", "safety.json", "safety.md", "manifest.json", "trajectories.npz") + tuple(
    f"safety_{f.replace('-', '')}.png" for f in FAMILIES
)
BOUND_TEXT = (
    "the ego brakes at its maximum a_min from t = 0 (through the actuator: its jerk limit and lag, from a = 0), "
    "the lead follows its profile, both stop at v = 0 and never reverse; the smallest gap of that motion (exact "
    "piecewise solution) labels the case *avoidable* (≥ the 2 m floor of the MPC's traffic formulation), "
    "*collision-avoidable only* (0 < gap < floor) or *unavoidable* (contact whatever the controller does)"
)
SHORT_LABEL = {AVOIDABLE: "A", COLLISION_AVOIDABLE_ONLY: "C", UNAVOIDABLE: "U"}


def _f(x: float, d: int = 2) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    if isinstance(x, float) and math.isinf(x):
        return "∞"
    return f"{x:.{d}f}"


def summary(out: SuiteOutput) -> dict[str, dict[str, Any]]:
    """Per controller (key ``controller`` or ``controller@actuator`` when the suite ran several actuators): cases by
    label, collisions and floor violations by label, failures (avoidable cases with a collision or a floor
    violation) with their impact speeds [m/s]."""
    acts = list(dict.fromkeys(r.actuator for r in out.rows))
    res: dict[str, dict[str, Any]] = {}
    for r in out.rows:
        key = r.controller if len(acts) == 1 else f"{r.controller}@{r.actuator}"
        s = res.setdefault(
            key,
            {
                "controller": r.controller,
                "actuator": r.actuator,
                "cases": {lb: 0 for lb in LABELS},
                "collisions": {lb: 0 for lb in LABELS},
                "floor_violations": {lb: 0 for lb in LABELS},
                "failures": [],
                "impact_speeds_mps": {},
            },
        )
        s["cases"][r.label] += 1
        s["collisions"][r.label] += int(r.collision)
        s["floor_violations"][r.label] += int(r.floor_violation_samples > 0)
        if r.failed:
            s["failures"].append(r.case)
        if r.collision:
            s["impact_speeds_mps"][r.case] = r.impact_speed_mps
    return res


def _cell(r: CaseRow | None) -> str:
    """A run in the case table: '·' no collision and never below the floor, 'f' below the floor, else the impact
    speed [m/s]; bold in an avoidable case."""
    if r is None:
        return ""
    txt = f"{r.impact_speed_mps:.1f}" if r.collision else ("f" if r.floor_violation_samples > 0 else "·")
    return f"**{txt}**" if r.failed else txt


def _median(xs: list[float]) -> float:
    ys = [x for x in xs if not math.isnan(x)]  # inf (a TTC that never closes) is a value: it sorts last
    return float(np.median(ys)) if ys else math.nan


def _intro(out: SuiteOutput, heading: str, acts: list[str]) -> list[str]:
    """The heading, what the suite runs (units, controllers, the layer, the label) and the actuators."""
    st = out.settings
    u = st["units"]
    ctrls: list[str] = st["controllers"]
    act_info = st.get("actuators", {})
    lines = [
        f"{heading} Safety suite: stationary, slower and braking targets, lane ends and cut-ins to 130 km/h\n",
        f"{len(out.cases)} cases × {len(acts)} actuators × {len(ctrls)} controllers; units L = {u['length_m']:g} m, "
        f"U = {u['speed_mps']:g} m/s for every case (the drive-cycle scenarios'). `mpc` is the MPC as shipped "
        "(MPCSettings(): traffic formulation, decaying-acceleration forecast; it already limits its commands by its "
        "own braking-distance filter); `mpc-margin` adds the soft time-gap / TTC margin (TrafficParams.margin_weight "
        f"= {st['margin']['weight']:g} W/kg per m², T_m = {st['margin']['time_gap_s']:g} s, TTC_m = "
        f"{st['margin']['ttc_s']:g} s); `wave-mpc` is the ring's wave-damping MPC (aev_ocp.mpc.wave, default "
        "WaveParams, the same settings and forecast); the proposed law and OVFL run as published (continuous, saturated to the "
        "vehicle's [a_min, a_max]); IDM with Treiber & Kesting's SI parameters (Traffic Flow Dynamics, 2013, Table "
        "11.2: a = 1 m/s², b = 1.5 m/s², T = 1.5 s, s0 = 2 m, δ = 4, v0 = the case's speed). `+layer`: under the "
        "braking-distance safety layer (SafeFallback.for_vehicle: min(controller, safe), sampled every "
        f"{st['layer_dt_s'] * 1e3:.0f} ms, its reaction time covering the actuator's lag and jerk limit). A cut-in "
        f"is the new predecessor appearing at t = 0 at the given gap. Label: {BOUND_TEXT} (a_min = "
        f"{st['bound_a_min_mps2']:g} m/s², floor = {st['floor_m']:g} m).\n",
        "Actuators: "
        + "; ".join(
            f"**{a}** (τ = {act_info[a]['tau_s']:g} s, jerk limit "
            f"{_f(act_info[a]['jerk_max_mps3'], 0) if act_info[a]['jerk_max_mps3'] else 'none'}"
            f"{' m/s³' if act_info[a]['jerk_max_mps3'] else ''}: {act_info[a]['source']})"
            for a in acts
            if a in act_info
        )
        + ".\n",
    ]
    return lines


def _summary_table(out: SuiteOutput) -> str:
    """Per actuator and controller: the avoidable cases, their collisions and the other cases."""
    summ = summary(out)
    rows = []
    for key, s in summ.items():
        imp = [v for c, v in s["impact_speeds_mps"].items() if c in s["failures"]]
        rows.append(
            [
                s["actuator"],
                s["controller"],
                s["cases"][AVOIDABLE],
                s["collisions"][AVOIDABLE],
                _f(max(imp)) if imp else "—",
                s["floor_violations"][AVOIDABLE],
                sum(s["cases"][lb] for lb in LABELS if lb != AVOIDABLE),
                sum(s["collisions"][lb] for lb in LABELS if lb != AVOIDABLE),
            ]
        )
    return markdown_table(
        [
            "actuator",
            "controller",
            "avoidable cases",
            "collisions there",
            "worst impact there [m/s]",
            "below the floor there",
            "other cases",
            "collisions there",
        ],
        rows,
    )


def _case_tables(out: SuiteOutput, acts: list[str], ctrls: list[str]) -> list[str]:
    """Per actuator, every case × controller (label, the bound's min gap, impact speeds)."""
    by = {(r.case, r.actuator, r.controller): r for r in out.rows}
    lines = []
    for act in acts:
        lines.append(
            f"\nEvery case at the **{act}** actuator: label (A avoidable, C collision-avoidable only, U unavoidable) "
            "and the bound's min gap [m]; per controller · (no collision, never below the floor), f (below the "
            "floor, no collision) or the impact speed [m/s]; **bold**: in an avoidable case.\n"
        )
        trows = []
        for c in out.cases:
            r0 = next((by[(c.name, act, k)] for k in ctrls if (c.name, act, k) in by), None)
            if r0 is None:
                continue
            trows.append(
                [c.name, SHORT_LABEL.get(r0.label, r0.label), _f(r0.bound_min_gap_m, 1)]
                + [_cell(by.get((c.name, act, k))) for k in ctrls]
            )
        lines.append(markdown_table(["case", "label", "bound [m]"] + ctrls, trows))
    return lines


def _margins(out: SuiteOutput, acts: list[str], ctrls: list[str]) -> list[str]:
    """The margins per actuator and controller: min gap, min TTC, time-gap quantiles, peak deceleration and jerk."""
    lines = []
    lines.append(
        "\nMargins per controller (over all cases of the actuator): the smallest gap [m] and time-to-collision [s]; "
        "the time gap h/v [s] while following (v ≥ 2 m/s), each case's 5/50/95 % quantiles, median over the cases; "
        "the peak deceleration [m/s²] and peak jerk [m/s³] (sampled Δa/Δt, without the intervals that touch a "
        "standstill: the plant's step to a = 0 when a car stops is not a commanded jerk); runs that collided are "
        "left out of the gap, TTC and time-gap columns (their minimum is 0).\n"
    )
    mrows = []
    for act in acts:
        for k in ctrls:
            rs = [r for r in out.rows if r.actuator == act and r.controller == k]
            if not rs:
                continue
            ok = [r for r in rs if not r.collision] or rs
            mrows.append(
                [
                    act,
                    k,
                    sum(r.collision for r in rs),
                    _f(min(r.min_gap_m for r in ok)),
                    _f(min(r.min_ttc_s for r in ok)),
                    _f(_median([r.time_gap_p05_s for r in ok])),
                    _f(_median([r.time_gap_p50_s for r in ok])),
                    _f(_median([r.time_gap_p95_s for r in ok])),
                    _f(max(r.peak_decel_mps2 for r in rs)),
                    _f(max(r.peak_jerk_mps3 for r in rs), 0),
                ]
            )
    lines.append(
        markdown_table(
            [
                "actuator",
                "controller",
                "collisions",
                "min gap [m]",
                "min TTC [s]",
                "time gap 5 % [s]",
                "time gap 50 % [s]",
                "time gap 95 % [s]",
                "peak decel [m/s²]",
                "peak jerk [m/s³]",
            ],
            mrows,
        )
    )
    return lines


def _sources(out: SuiteOutput) -> list[str]:
    """The cases and their sources, and where every row is written."""
    lines = []
    lines.append("\nThe cases and their sources:\n")
    lines.append(
        markdown_table(
            ["case", "family", "ego [km/h]", "gap [m]", "lead [km/h]", "lead a [m/s²]", "run [s]", "source"],
            [
                [
                    c.name,
                    c.family,
                    _f(c.v_ego_mps * 3.6, 0),
                    _f(c.gap_m, 1),
                    _f(c.v_lead_mps * 3.6, 0),
                    _f(c.a_lead_mps2, 1),
                    _f(c.t_end_s, 1),
                    c.source,
                ]
                for c in out.cases
            ],
        )
    )
    lines.append(
        "\nEvery row of every run: `safety.csv` / `safety.json`. Peak jerk is sampled (Δa/Δt between samples: the "
        "laws' 8.8 ms output spacing, the sampled controllers' 88 ms steps).\n"
    )
    return lines


def markdown(out: SuiteOutput, heading: str = "##") -> str:
    """The suite as Markdown (SI): how cases are labelled; per actuator and controller the avoidable cases and the
    collisions; every case × controller (impact speeds); the margins (TTC, time gaps, jerk); the cases' sources."""
    st = out.settings
    ctrls: list[str] = st["controllers"]
    acts = list(dict.fromkeys(r.actuator for r in out.rows))
    lines = _intro(out, heading, acts)
    if st.get("quick"):
        lines.append("**Quick run** (a few cases, 3 s each): a smoke test, not the suite.\n")
    lines.append(_summary_table(out))
    lines += _case_tables(out, acts, ctrls)
    lines += _margins(out, acts, ctrls)
    if "mpc+layer" in ctrls and "mpc-margin+layer" in ctrls:
        lines.append(margin_table(out))
    lines += _sources(out)
    return "\n".join(lines)


def margin_table(out: SuiteOutput, free_m: float = 5.0) -> str:
    """The MPC's soft margin on vs off (both under the layer): per actuator, the cases where the bound leaves at
    least ``free_m`` [m] above the floor, min gap [m] and min TTC [s] of each, and the medians."""
    by = {(r.case, r.actuator, r.controller): r for r in out.rows}
    floor = out.settings["floor_m"]
    lines = [
        f"\nThe MPC's soft margin, off (`mpc+layer`) vs on (`mpc-margin+layer`), in the cases where braking at a_min "
        f"from t = 0 leaves ≥ {free_m:g} m above the {floor:g} m floor (the room a margin can use): the median over "
        "those cases of the smallest gap [m], the smallest TTC [s] and the 5 % time gap [s], and the worst case.\n"
    ]
    rows = []
    for act in dict.fromkeys(r.actuator for r in out.rows):
        pairs = [
            (by[(c.name, act, "mpc+layer")], by[(c.name, act, "mpc-margin+layer")])
            for c in out.cases
            if (c.name, act, "mpc+layer") in by
            and (c.name, act, "mpc-margin+layer") in by
            and by[(c.name, act, "mpc+layer")].bound_min_gap_m >= floor + free_m
        ]
        if not pairs:
            continue
        for j, nm in ((0, "off"), (1, "on")):
            rs = [p[j] for p in pairs]
            rows.append(
                [
                    act,
                    nm,
                    len(rs),
                    _f(_median([r.min_gap_m for r in rs])),
                    _f(min(r.min_gap_m for r in rs)),
                    _f(_median([r.min_ttc_s for r in rs])),
                    _f(min(r.min_ttc_s for r in rs)),
                    _f(_median([r.time_gap_p05_s for r in rs])),
                    sum(r.collision for r in rs),
                ]
            )
    return "\n".join(
        lines
        + [
            markdown_table(
                [
                    "actuator",
                    "margin",
                    "cases",
                    "min gap, median [m]",
                    "min gap, worst [m]",
                    "min TTC, median [s]",
                    "min TTC, worst [s]",
                    "time gap 5 %, median [s]",
                    "collisions",
                ],
                rows,
            )
        ]
    )


def plot_family(out: SuiteOutput, family: str, path: Path) -> Path | None:
    """Write the family's figure (:func:`aev_ocp.safety.plots.family_figure`) to ``path``; None without cases."""
    fig = family_figure(out, family)
    if fig is None:
        return None
    save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)
    return path


def write_outputs(out: SuiteOutput, folder: str | Path, plots: bool = True) -> list[Path]:
    """safety.csv, safety.json, safety.md, the manifest (and the kept runs' trajectories) and the family figures into
    ``folder``; returns the paths."""
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
    from .outputs import save_suite_manifest

    files += save_suite_manifest(out, folder)  # aev_ocp.load(folder) reads the run back
    if plots:
        for fam in FAMILIES:
            p = plot_family(out, fam, folder / f"safety_{fam.replace('-', '')}.png")
            if p is not None:
                files.append(p)
    return files

"""Figures of the safety suite (matplotlib Agg): one per family of cases. Nothing is written here
(:func:`aev_ocp.safety.report.write_outputs` writes them)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ..plots import LAW_STYLE, plt


def family_figure(out: Any, family: str) -> Figure | None:
    """The figure of one family of a suite run (:class:`aev_ocp.safety.run.SuiteOutput`): min gap [m] per case and
    controller against the bound, the floor dashed, collisions marked ×; None when the run has no case of it."""
    cases = [c for c in out.cases if c.family == family]
    if not cases:
        return None
    fig, ax = plt.subplots(figsize=(max(6.0, 0.12 * len(cases) + 4), 3.8))
    x = np.arange(len(cases))
    acts = list(dict.fromkeys(r.actuator for r in out.rows))
    act = "declared" if "declared" in acts else acts[0]
    rows_a = [r for r in out.rows if r.actuator == act]
    bound = [next(r.bound_min_gap_m for r in rows_a if r.case == c.name) for c in cases]
    ax.plot(x, bound, "k_", ms=10, mew=2, label="bound (max braking from t = 0)")
    ctrls = out.settings["controllers"]
    for j, ctrl in enumerate(ctrls):
        ys = [next((r.min_gap_m for r in rows_a if r.case == c.name and r.controller == ctrl), math.nan) for c in cases]
        coll = [next((r.collision for r in rows_a if r.case == c.name and r.controller == ctrl), False) for c in cases]
        style = LAW_STYLE.get(ctrl.replace("+layer", "").replace("-margin", ""), {})
        off = (j - (len(ctrls) - 1) / 2) * 0.8 / max(len(ctrls), 1)
        mk = "^" if ctrl.endswith("+layer") else "o"
        ax.scatter(x + off, ys, s=14, marker=mk, color=style.get("color"), label=ctrl, zorder=3)
        cx = [xi + off for xi, cc in zip(x, coll) if cc]
        if cx:
            ax.scatter(cx, [0.0] * len(cx), marker="x", s=40, color=style.get("color"), zorder=4)
    ax.axhline(out.settings["floor_m"], color="gray", ls="--", lw=1, label="floor")
    ax.axhline(0.0, color="black", lw=0.8)
    ax.set_ylabel("min gap [m] (× collision)")
    ax.set_xticks(x)
    ax.set_xticklabels([c.name.replace(f"{family}_", "").replace("cutin_", "") for c in cases], rotation=90, fontsize=6)
    ax.set_title(f"{family}: minimum gap per case ({act} actuator)")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    return fig

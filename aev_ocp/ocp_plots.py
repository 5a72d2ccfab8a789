"""Plots of optimal-control results (matplotlib, Agg backend). The solvers in :mod:`aev_ocp.ocp`
know nothing of plotting; these helpers take their results and write PNG files."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .ocp.result import OCPResult  # noqa: E402
from .results import save_figure_atomic  # noqa: E402


def _save(fig: Any, path: str | Path) -> Path:
    try:
        return save_figure_atomic(fig, path, dpi=120)
    finally:
        plt.close(fig)


def _stairs(ax: Any, t: np.ndarray, u: np.ndarray, **kw: Any) -> None:
    ax.step(t, np.append(u, u[-1]), where="post", **kw)


def plot_prop31(cases: dict[str, dict[str, Any]], path: str | Path) -> Path:
    """Optimal currents I*(t) [A] of the four OCP-A cases and the zero-heat alternative
    I = −(V1+V2)/R_s, one panel per case."""
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    for ax, (case, e) in zip(axes.ravel(), cases.items()):
        res: OCPResult = e["result"]
        if res.success:
            _stairs(ax, res.t, res.controls["I"], label=f"I* (J* = {res.objective:.4g} J)")
        sim = e["alternatives"]["neg_polarisation"]["sim"]
        ax.plot(sim["t"], sim["I"], "--", label=f"-(V1+V2)/R_s (∫Q = {e['zero_heat_alternative_objective_J']:.2g} J)")
        ax.set_title(case)
        ax.axhline(0.0, color="gray", lw=0.5)
        ax.legend(fontsize=8)
        ax.set_ylabel("cell current I [A]")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.suptitle("OCP-A (Proposition 3.1): optimal cell current")
    fig.tight_layout()
    return _save(fig, path)


def plot_result(res: OCPResult, path: str | Path, names: Sequence[str] | None = None) -> Path:
    """States, controls and outputs of one OCPResult against time, one panel per quantity."""
    items: list[tuple[str, np.ndarray, bool]] = []
    for nm, v in res.states.items():
        items.append((nm, v, False))
    for nm, v in res.controls.items():
        items.append((nm, v, True))
    for nm, v in res.outputs.items():
        items.append((nm, v, False))
    if names is not None:
        items = [it for it in items if it[0] in names]
    n = max(len(items), 1)
    cols = 2
    rows = (n + 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(10, 2.2 * rows), sharex=True, squeeze=False)
    for ax, (nm, v, is_u) in zip(axes.ravel(), items):
        if is_u:
            _stairs(ax, res.t, v)
        else:
            ax.plot(res.t[: v.size], v)
        ax.set_ylabel(nm)
    for ax in axes[-1]:
        ax.set_xlabel(f"t [{res.time_unit}]")
    fig.suptitle(f"{res.problem} ({res.method}, N = {res.N}): {res.status}, objective {res.objective:.6g}")
    fig.tight_layout()
    return _save(fig, path)


def plot_sweep(rows: list[dict[str, Any]], x: str, ys: Sequence[str], path: str | Path,
               group: str | None = None, ylabel: str = "") -> Path:
    """Line plot of sweep rows (dicts): ys against x, one line per value of ``group``."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    groups = sorted({r[group] for r in rows}) if group else [None]
    for gv in groups:
        sel = [r for r in rows if group is None or r[group] == gv]
        for y in ys:
            ax.plot([r[x] for r in sel], [r[y] for r in sel], "o-", label=f"{y}" + (f" ({group}={gv})" if group else ""))
    ax.set_xlabel(x)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)

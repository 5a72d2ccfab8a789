"""Space-time diagram of a ring run (positions coloured by speed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from .simulate import RingResult


def space_time(res: RingResult, path: str | Path | None = None, title: str = "") -> Figure:
    """Every vehicle's position along the ring [m] against time [s], coloured by its speed [m/s]; the AEVs (not
    human) drawn as black lines. Returns the matplotlib Figure; given a ``path`` it also writes it there (PNG)."""
    from ..plots import plt, save_figure

    t, x, v = res.t_s, res.positions_m(), res.speed_mps
    fig, ax = plt.subplots(figsize=(8, 4.5))
    tt = np.repeat(t, x.shape[1])
    sc: Any = ax.scatter(tt, x.ravel(), c=v.ravel(), s=0.6, cmap="RdYlGn", vmin=0, vmax=max(float(v.max()), 1e-3))
    for i in range(res.ring.n):
        if not res.ring.is_human(i):
            xi = x[:, i].copy()
            xi[np.flatnonzero(np.diff(xi) < 0) + 1] = np.nan  # break the line where it wraps
            ax.plot(t, xi, "k-", lw=0.8)
    fig.colorbar(sc, ax=ax, label="speed [m/s]")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position on the ring [m]")
    ax.set_title(title or f"{res.ring.n} vehicles on {res.ring.length_m:g} m")
    fig.tight_layout()
    return save_figure(fig, path)


def space_time_panels(
    runs: list[tuple[str, RingResult]], path: str | Path | None = None, t_from_s: float = 0.0
) -> Figure:
    """The space-time diagrams of several ring runs side by side (one panel per (label, result), the same
    speed colour scale, from ``t_from_s`` [s] on); the AEVs drawn as black lines. Returns the Figure; given a
    ``path`` it also writes it there (PNG)."""
    from ..plots import plt, save_figure

    k = len(runs)
    cols = min(3, k)
    rows = (k + cols - 1) // cols
    fig, axes = plt.subplots(
        rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False, sharey=True, layout="constrained"
    )
    vmax = max(max(float(r.speed_mps.max()) for _, r in runs), 1e-3)
    sc: Any = None
    for ax, (label, res) in zip(axes.ravel(), runs):
        sel = res.t_s >= t_from_s - 1e-9
        t, x, v = res.t_s[sel], res.positions_m()[sel], res.speed_mps[sel]
        sc = ax.scatter(
            np.repeat(t, x.shape[1]), x.ravel(), c=v.ravel(), s=0.4, cmap="RdYlGn", vmin=0, vmax=vmax, rasterized=True
        )
        for i in range(res.ring.n):
            if not res.ring.is_human(i):
                xi = x[:, i].copy()
                xi[np.flatnonzero(np.diff(xi) < 0) + 1] = np.nan
                ax.plot(t, xi, "k-", lw=0.8)
        ax.set_title(label, fontsize=10)
        ax.set_xlabel("time [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("position on the ring [m]")
    for ax in axes.ravel()[k:]:
        ax.axis("off")
    fig.colorbar(sc, ax=axes.ravel().tolist(), label="speed [m/s]")
    return save_figure(fig, path)

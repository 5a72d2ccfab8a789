"""Space-time diagram of a ring run (positions coloured by speed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .simulate import RingResult


def space_time(res: RingResult, path: str | Path, title: str = "") -> Path:
    """Every vehicle's position along the ring [m] against time [s], coloured by its speed [m/s]; the AEVs (not
    human) drawn as black lines. Written to ``path`` (PNG) and returned."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..results import save_figure_atomic

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
    out = save_figure_atomic(fig, path, dpi=110)
    plt.close(fig)
    return Path(out)

"""Figures of a SUMO run (:class:`aev_ocp.sumo.run.SumoRun`): the space-time diagram of every route (the ring: one).

Each function takes the run (its ``vehicles``, ``controlled``, ``offsets_m``, ``ring_length_m`` and ``name``) and
returns Figures; nothing is written here (:func:`aev_ocp.sumo.outputs.save_space_time` writes them).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def space_time_groups(run: Any) -> dict[str, list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]]:
    """{panel: [(vehicle id, t [s], position [m], speed [m/s])]}: one panel per route (the ring: one panel,
    positions wrapped to the circumference); position = distance driven + the lane position at departure."""
    out: dict[str, list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]] = {}
    for vid, r in run.vehicles.items():
        u = r.units
        t = np.asarray(u.time_to_si(r.t), float)
        x = np.asarray(u.length_to_si(r.positions()[:, 0]), float)
        x = x - x[0] + run.offsets_m.get(vid, 0.0)
        key = "ring" if run.ring_length_m else str(r.meta.get("route", "route"))
        if run.ring_length_m:
            x = np.mod(x, run.ring_length_m)
        out.setdefault(key, []).append((vid, t, x, np.asarray(u.speed_to_si(r.speed[:, 0]), float)))
    return out


def plot_space_time(run: Any) -> dict[str, Any]:
    """{panel: Figure}: every vehicle's position over time coloured by its speed; the toolkit's vehicles drawn
    thicker. Nothing is written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    figs: dict[str, Any] = {}
    vmax = max((float(np.nanmax(s)) for g in space_time_groups(run).values() for _, _, _, s in g), default=1.0)
    for key, rows in space_time_groups(run).items():
        fig, ax = plt.subplots(figsize=(8, 4.5))
        lc = None
        for vid, t, x, v in rows:
            if t.size < 2:
                continue
            seg = np.stack([np.column_stack([t[:-1], x[:-1]]), np.column_stack([t[1:], x[1:]])], axis=1)
            if run.ring_length_m:  # no line across the wrap
                keep = np.abs(np.diff(x)) < run.ring_length_m / 2
                seg, vv = seg[keep], v[:-1][keep]
            else:
                vv = v[:-1]
            lc = LineCollection(
                list(seg),
                cmap="viridis",
                norm=plt.Normalize(0, vmax),
                linewidths=1.8 if run.controlled.get(vid) else 0.6,
            )
            lc.set_array(vv)
            ax.add_collection(lc)
        ax.autoscale()
        ax.set_xlabel("time [s]")
        ax.set_ylabel("position on the ring [m]" if run.ring_length_m else f"position along route {key} [m]")
        n_c = sum(1 for vid, *_ in rows if run.controlled.get(vid))
        ax.set_title(f"{run.name}: {key} ({len(rows)} vehicles, {n_c} driven by the toolkit: thick)")
        if lc is not None:
            fig.colorbar(lc, ax=ax, label="speed [m/s]")
        fig.tight_layout()
        figs[key] = fig
    return figs

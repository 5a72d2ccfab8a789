"""Figures of the string-stability analysis (matplotlib Agg, written atomically; model units)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..plots import Figure, _finish_single, plt, save_figure
from .linear import LinearStability
from .measure import Attenuation


COEFFICIENT_LABELS = {
    "alpha": "α [1/model time]",
    "beta": "β [model length²/model time]",
    "kappa": "κ [1/model length]",
    "eps": "ε [model speed²]",
}


def plot_gain(lins: Sequence[LinearStability], path: str | Path | None = None, title: str | None = None) -> Figure:
    """|G(iω)| against ω for each analysis (one line per equilibrium speed / law)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    w = np.logspace(-2.5, 1.5, 800)
    for lin in lins:
        ax.semilogx(w, lin.gain(w), label=f"{lin.law}, v* = {lin.v_star:g} (C = {lin.criterion:.3g})")
        if lin.unstable_band:
            ax.axvspan(1e-2 * 10**-0.5, lin.unstable_band[1], color="tab:red", alpha=0.06)
    ax.axhline(1.0, color="gray", ls="--", lw=0.8)
    ax.set_xlabel("ω [rad / model time]")
    ax.set_ylabel("|G(iω)| (follower / predecessor speed)")
    return _finish_single(fig, ax, path, title or "Frequency response of one follower")


def plot_region(
    xs: np.ndarray,
    ys: np.ndarray,
    criterion: np.ndarray,
    local: np.ndarray,
    x_name: str,
    y_name: str,
    path: str | Path | None,
    title: str,
    mark: tuple[float, float] | None = None,
) -> Figure:
    """Stable region in a parameter plane: criterion C ≥ 0 (string stable) shaded, C = 0 contour drawn.

    criterion, local: arrays of shape (len(ys), len(xs))."""
    fig, ax = plt.subplots(figsize=(5.6, 4.4))
    cls = np.where(~local, 0, np.where(criterion >= 0, 2, 1))
    cmap = plt.matplotlib.colors.ListedColormap(["#d9d9d9", "#f4a582", "#92c5de"])
    ax.pcolormesh(xs, ys, cls, cmap=cmap, vmin=-0.5, vmax=2.5, shading="nearest")
    if np.nanmin(criterion) < 0 < np.nanmax(criterion):
        ax.contour(xs, ys, criterion, levels=[0.0], colors="k", linewidths=1.0)
    if mark is not None:
        ax.plot(*mark, "kx", ms=8, label="chosen")
    ax.plot([], [], "s", color="#92c5de", label="string stable (C ≥ 0)")
    ax.plot([], [], "s", color="#f4a582", label="string unstable, platoon stable")
    ax.plot([], [], "s", color="#d9d9d9", label="not platoon stable")
    ax.set_xlabel(COEFFICIENT_LABELS.get(x_name, x_name))
    ax.set_ylabel(COEFFICIENT_LABELS.get(y_name, y_name))
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_attenuation(
    series: Mapping[str, Sequence[Attenuation]],
    linear: Mapping[str, Attenuation],
    path: str | Path | None = None,
    title: str | None = None,
) -> Figure:
    """Measured attenuation against disturbance amplitude: geometric-mean step ratio of the peak |ṽ|
    (solid) and the largest step ratio of ‖ṽ‖₂ (dotted); dashed: the linearised law's values."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for k, (label, atts) in enumerate(series.items()):
        if not atts:
            continue
        col = f"C{k}"
        a = [x.amplitude for x in atts]
        ax.semilogx(a, [x.ratio_peak for x in atts], "o-", color=col, label=f"{label}: mean peak ratio")
        ax.semilogx(a, [x.max_step_l2 for x in atts], "s:", color=col, ms=4, label=f"{label}: max ℓ2 step ratio")
        if label in linear:
            ax.axhline(linear[label].ratio_peak, color=col, ls="--", lw=0.8)
    ax.axhline(1.0, color="gray", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("disturbance amplitude A [model speed]")
    ax.set_ylabel("follower-to-follower ratio")
    return _finish_single(fig, ax, path, title or "Measured attenuation (dashed: linear prediction)")


def plot_eigenvalues(
    eigenvalues_per_s: Sequence[Sequence[float]], path: str | Path | None = None, title: str | None = None
) -> Figure:
    """The eigenvalues λ [1/s] of a ring's linearisation in the complex plane ([re, im] pairs, as
    ``ring_stability.json`` and ``mixed_ring_stability.json`` hold them); right of the dashed line: growing."""
    lam = np.asarray(eigenvalues_per_s, float).reshape(-1, 2)
    fig, ax = plt.subplots(figsize=(5.6, 4.4))
    unstable = lam[:, 0] > 0
    ax.plot(lam[~unstable, 0], lam[~unstable, 1], "o", ms=4, color="tab:blue", label="decaying (Re λ ≤ 0)")
    ax.plot(lam[unstable, 0], lam[unstable, 1], "o", ms=4, color="tab:red", label="growing (Re λ > 0)")
    ax.axvline(0.0, color="gray", ls="--", lw=0.8)
    ax.set_xlabel("Re λ [1/s]")
    ax.set_ylabel("Im λ [rad/s]")
    return _finish_single(fig, ax, path, title or "Eigenvalues of the ring's linearisation")

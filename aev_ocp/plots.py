"""Figures of the paper and per-scenario trajectory plots (matplotlib, Agg backend only).

Every function takes results or arrays and returns a matplotlib ``Figure`` (a notebook shows it); given a
``path`` it also writes one PNG there atomically (temporary file in the same folder, then ``os.replace``). Axes are in SI (s, m, km/h, m/s²) through
the scenario's :class:`~aev_ocp.params.Units` by default; ``si=False`` draws the paper's model units.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import matplotlib

if "ipykernel" not in sys.modules:  # files only, no window; a notebook keeps its inline backend
    matplotlib.use("Agg")
import casadi as ca  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from .models.carfollowing import equilibrium_gap  # noqa: E402
from .models.leader import LeaderProfile  # noqa: E402
from .params import Units  # noqa: E402
from .results import SimulationResult, save_figure_atomic  # noqa: E402

LAW_STYLE: dict[str, dict[str, Any]] = {
    "proposed": {"color": "tab:blue", "ls": "-"},
    "ovfl": {"color": "tab:orange", "ls": "--"},
    "ovm": {"color": "tab:green", "ls": "-."},
    "idm": {"color": "tab:purple", "ls": ":"},
    "mpc": {"color": "tab:red", "ls": "-"},
    "ocp-d": {"color": "black", "ls": (0, (1, 1))},
}
# further controllers cycle through these (colour, dash) pairs so that no overlaid line hides another
EXTRA_STYLES = [
    ("tab:brown", (0, (5, 1, 1, 1))),
    ("tab:pink", (0, (3, 1, 1, 1, 1, 1))),
    ("tab:olive", (0, (8, 2))),
    ("tab:cyan", (0, (2, 2))),
    ("tab:gray", (0, (4, 1, 1, 1, 1, 1, 1, 1))),
]
DPI = 120
KMH_PER_MPS = 3.6


@dataclass(frozen=True)
class AxisUnits:
    """Factors from model units to the plotted units, with the axis label of each quantity.

    t, x, v, a: multiply model time, length, speed, acceleration by these to plot them."""

    t: float
    x: float
    v: float
    a: float
    t_label: str
    x_label: str
    v_label: str
    a_label: str

    @classmethod
    def of(cls, units: Units | None, si: bool = True) -> "AxisUnits":
        """SI axes (s, m, km/h, m/s²) from ``units`` (default units if None), or the model units."""
        if not si:
            return cls(1.0, 1.0, 1.0, 1.0, "model time", "model length", "model speed", "model acceleration")
        u = units or Units()
        return cls(u.time_s, u.length_m, u.speed_mps * KMH_PER_MPS, u.accel_mps2, "s", "m", "km/h", "m/s²")


def save_figure(fig: Figure, path: str | os.PathLike[str] | None) -> Figure:
    """Write ``fig`` as PNG to ``path`` atomically (unique temp name, mode as open() gives) when a path is given;
    returns the figure, released by pyplot (it is drawn where it is returned, e.g. in a notebook, and never twice)."""
    try:
        if path is not None:
            save_figure_atomic(fig, path, dpi=DPI, format="png")
    finally:
        plt.close(fig)
    return fig


def _finish_single(fig: Figure, ax: Any, path: str | os.PathLike[str] | None, title: str | None) -> Figure:
    """Grid, legend and title of a one-axes figure, then write it (atomically) when a path is given."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _style(label: str) -> dict[str, Any]:
    return dict(LAW_STYLE.get(label.lower(), {}))


def controller_styles(labels: Sequence[str]) -> dict[str, dict[str, Any]]:
    """A distinct (colour, line style) per label: the known laws keep theirs, others take EXTRA_STYLES."""
    out: dict[str, dict[str, Any]] = {}
    k = 0
    for lab in labels:
        st = _style(lab)
        if not st:
            c, ls = EXTRA_STYLES[k % len(EXTRA_STYLES)]
            st = {"color": c, "ls": ls}
            k += 1
        out[lab] = st
    return out


def _leader_speed_of(r: SimulationResult, i: int) -> np.ndarray:
    """Speed of the vehicle ahead of follower i (0-based) [model speed]."""
    return r.leader_speed if i == 0 else r.speed[:, i - 1]


# ----------------------------------------------------------------------------- Fig. 1 / Fig. 2
def plot_phase_planes(
    panels: Sequence[tuple[str, Mapping[str, SimulationResult]]],
    path: str | os.PathLike[str] | None = None,
    title: str | None = None,
    si: bool = True,
) -> Figure:
    """Phase planes of one follower: gap h vs relative velocity v_l − v (paper Fig. 1, Fig. 2).

    panels: (caption, {law label: result}) per panel. The initial condition is a red dot, the
    equilibrium (V⁻¹(v_l), 0) a magenta ×, the collision line h = 0 gray dashed. Axes in m and km/h
    (the first result's units), or model units with ``si=False``.
    """
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.2), squeeze=False)
    for ax, (caption, runs) in zip(axes[0], panels):
        first = next(iter(runs.values()))
        au = AxisUnits.of(first.units, si)
        styles = controller_styles(list(runs))
        for label, r in runs.items():
            rel = _leader_speed_of(r, 0) - r.speed[:, 0]
            ax.plot(au.x * r.gap[:, 0], au.v * rel, lw=1.4, label=label, **styles[label])
        h0, rel0 = first.gap[0, 0], first.leader_speed[0] - first.speed[0, 0]
        ax.plot([au.x * h0], [au.v * rel0], "o", color="red", ms=7, label="initial condition", zorder=5)
        v_l = float(first.leader_speed[-1])
        ax.plot(
            [au.x * equilibrium_gap(v_l)], [0.0], "x", color="magenta", ms=10, mew=2.5, label="equilibrium", zorder=6
        )
        ax.axvline(0.0, color="gray", ls="--", lw=1.2, label="collision (h = 0)")
        ax.set_xlabel(f"gap h = x_l − x [{au.x_label}]")
        ax.set_ylabel(f"relative velocity v_l − v [{au.v_label}]")
        ax.set_title(caption, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- Fig. 3
def leader_arrays(leader: LeaderProfile, t_end: float, n: int = 7001) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, a_l(t), v_l(t)) sampled on [0, t_end], all in model units."""
    t = np.linspace(0.0, t_end, n)
    ts = ca.SX.sym("t")
    acc = ca.Function("a_l", [ts], [leader.accel(ts)]).map(n)
    return t, np.asarray(acc(t.reshape(1, -1))).ravel(), leader.speed_np(t)


def plot_leader(
    leader: LeaderProfile,
    t_end: float,
    path: str | os.PathLike[str] | None = None,
    title: str | None = None,
    units: Units | None = None,
    si: bool = True,
) -> Figure:
    """The leader's acceleration a_l(t) and speed v_l(t) (paper Fig. 3), in SI through ``units`` (default
    units if None) or in model units with ``si=False``."""
    t, a, v = leader_arrays(leader, t_end)
    au = AxisUnits.of(units, si)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    ax1.plot(au.t * t, au.a * a, color="tab:red", lw=1.0)
    ax1.set_ylabel(f"a_l [{au.a_label}]")
    ax1.set_title("(a) acceleration a_l", fontsize=10)
    ax2.plot(au.t * t, au.v * v, color="tab:blue", lw=1.4)
    ax2.set_ylabel(f"v_l [{au.v_label}]")
    ax2.set_title("(b) velocity v_l", fontsize=10)
    for ax in (ax1, ax2):
        ax.set_xlabel(f"t [{au.t_label}]")
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- Fig. 5
def plot_platoon(
    r: SimulationResult,
    path: str | os.PathLike[str] | None = None,
    *,
    v_eq: float | None = None,
    title: str | None = None,
    si: bool = True,
) -> Figure:
    """Gaps h_n(t) and relative velocities v_{n−1} − v_n of every follower (paper Fig. 5).

    v_eq: the speed [model] whose equilibrium (V⁻¹(v_eq), 0) is drawn as gray dashed lines (the paper
    uses v_l(20)); None draws none. Axes in s, m, km/h (``si=False``: model units).
    """
    au = AxisUnits.of(r.units, si)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    cmap = plt.get_cmap("viridis")
    n = r.n_vehicles
    t = au.t * r.t
    for i in range(n):
        c = cmap(i / max(n - 1, 1))
        ax1.plot(t, au.x * r.gap[:, i], color=c, lw=1.1, label=f"n = {i + 1}")
        ax2.plot(t, au.v * (_leader_speed_of(r, i) - r.speed[:, i]), color=c, lw=1.1, label=f"n = {i + 1}")
    if v_eq is not None:
        ax1.axhline(
            au.x * equilibrium_gap(v_eq),
            color="gray",
            ls="--",
            lw=1.2,
            label=f"V⁻¹(v_eq), v_eq = {au.v * v_eq:.3g} {au.v_label}",
        )
        ax2.axhline(0.0, color="gray", ls="--", lw=1.2, label="0")
    ax1.set_ylabel(f"spacing x(n−1) − x(n) [{au.x_label}]")
    ax1.set_title("(a) spacing", fontsize=10)
    ax2.set_ylabel(f"relative velocity v(n−1) − v(n) [{au.v_label}]")
    ax2.set_title("(b) relative velocity", fontsize=10)
    for ax in (ax1, ax2):
        ax.set_xlabel(f"t [{au.t_label}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- per scenario
MAX_TRAJECTORY_LINES = 50  # vehicles drawn per panel; a larger platoon is shown by an even subset
SPACE_TIME_MAX_POINTS = 2000  # samples per line of a space-time diagram (our choice: ~2x its 960 pixels across)


def _shown(n: int) -> list[int]:
    """Indices of the vehicles drawn: all up to MAX_TRAJECTORY_LINES, else an even subset (ends included)."""
    return (
        list(range(n))
        if n <= MAX_TRAJECTORY_LINES
        else sorted({int(round(k)) for k in np.linspace(0, n - 1, MAX_TRAJECTORY_LINES)})
    )


def plot_space_time(
    r: SimulationResult, path: str | os.PathLike[str] | None = None, title: str | None = None, si: bool = True
) -> Figure:
    """Space-time diagram: the position x_n(t) of the leader and every follower (the standard traffic
    figure; parallel lines = steady flow, bunching = a disturbance travelling through the platoon),
    coloured by speed. Positions are relative to the leader's start; s and m (``si=False``: model units)."""
    from matplotlib.collections import LineCollection

    au = AxisUnits.of(r.units, si)
    fig, ax = plt.subplots(figsize=(8, 5))
    t = au.t * r.t
    x = au.x * r.positions()
    vmax = au.v * float(max(np.max(r.speed), np.max(r.leader_speed), 1e-12))
    norm = plt.Normalize(0.0, vmax)
    lc = None
    # every k-th sample and the last (k: at most SPACE_TIME_MAX_POINTS per line, still more than the figure's
    # pixels across): a 31 101-sample drive cycle drew 31 100 segments per vehicle, 40 s per figure (issue 40)
    keep = np.unique(np.append(np.arange(0, t.size, max(1, -(-t.size // SPACE_TIME_MAX_POINTS))), t.size - 1))
    for i in _shown(r.n_vehicles):
        pts = np.column_stack([t[keep], x[keep, i]]).reshape(-1, 1, 2)
        lc = LineCollection(list(np.concatenate([pts[:-1], pts[1:]], axis=1)), cmap="viridis", norm=norm, lw=1.0)
        lc.set_array(au.v * r.speed[keep[:-1], i])
        ax.add_collection(lc)
    ax.plot(t, au.x * r.leader_position, color="black", lw=1.6, ls="--", label="leader")
    ax.set_xlim(t[0], t[-1])
    ax.set_ylim(float(np.min(x)), float(np.max(au.x * r.leader_position)))
    if lc is not None:
        fig.colorbar(lc, ax=ax, label=f"follower speed [{au.v_label}]")
    ax.set_xlabel(f"t [{au.t_label}]")
    ax.set_ylabel(f"position x [{au.x_label}]")
    note = f"{r.n_vehicles} followers" + (
        "" if r.n_vehicles <= MAX_TRAJECTORY_LINES else f" ({len(_shown(r.n_vehicles))} shown, evenly spaced)"
    )
    ax.plot([], [], color=plt.get_cmap("viridis")(0.6), label=note)
    return _finish_single(fig, ax, path, title)


def plot_trajectories(
    r: SimulationResult,
    path: str | os.PathLike[str] | None = None,
    title: str | None = None,
    si: bool = True,
    h_min: float | None = None,
) -> Figure:
    """Gaps, speeds (with the leader's), accelerations, cell current [A], SOC and pack heat over time (with the
    thermal model also the pack temperature [K] and the dissipated heat) for one run (any controller: closed-form laws, MPC, replayed controls; sampled controls drawn as steps).
    Platoons above MAX_TRAJECTORY_LINES vehicles are drawn as an even subset, first and last included.
    h_min: a minimum gap [model length] drawn and labelled; axes in s, m, km/h (``si=False``: model)."""
    au = AxisUnits.of(r.units, si)
    hot = r.temperature_K is not None  # the thermal model: a fourth row with the pack temperature
    fig, axes = plt.subplots(4 if hot else 3, 2, figsize=(11, 12.5 if hot else 9.5), sharex=True)
    cmap = plt.get_cmap("viridis")
    n = r.n_vehicles
    t = au.t * r.t
    shown = _shown(n)
    mixed = len(set(r.controllers)) > 1
    for i in shown:
        c = cmap(i / max(n - 1, 1))
        lab = (f"n = {i + 1}" + (f" ({r.controllers[i]})" if mixed else "")) if len(shown) <= 10 else None
        axes[0, 0].plot(t, au.x * r.gap[:, i], color=c, lw=0.9, label=lab)
        axes[0, 1].plot(t, au.v * r.speed[:, i], color=c, lw=0.9, label=lab)
        if r.jerk_sampled:
            axes[1, 0].step(t, au.a * r.accel[:, i], where="post", color=c, lw=0.9, label=lab)
        else:
            axes[1, 0].plot(t, au.a * r.accel[:, i], color=c, lw=0.9, label=lab)
        axes[1, 1].plot(t, r.current_A[:, i], color=c, lw=0.9, label=lab)
        axes[2, 0].plot(t, r.S[:, i], color=c, lw=0.9, label=lab)
        axes[2, 1].plot(t, r.heat_J[:, i], color=c, lw=0.9, label=lab)
        if r.temperature_K is not None:
            axes[3, 0].plot(t, r.temperature_K[:, i], color=c, lw=0.9, label=lab)
            axes[3, 1].plot(t, r.heat_irr_J[:, i], color=c, lw=0.9, label=lab)
    if hot:
        th = r.ev.thermal
        axes[3, 0].axhline(th.ambient_K, color="gray", ls="--", lw=1.0, label=f"ambient {th.ambient_K:.5g} K")
        axes[3, 0].set_ylabel("pack temperature T [K]")
        axes[3, 0].legend(fontsize=7)
        axes[3, 1].set_ylabel("pack dissipated heat ∫Q_irr dt [J]")
    axes[0, 1].plot(t, au.v * r.leader_speed, color="black", lw=1.2, ls="--", label="leader")
    axes[0, 0].axhline(0.0, color="gray", ls="--", lw=1.0, label="collision (h = 0)")
    if h_min is not None:
        axes[0, 0].axhline(
            au.x * h_min, color="tab:red", ls=":", lw=1.2, label=f"h_min = {au.x * h_min:.3g} {au.x_label}"
        )
    axes[0, 0].set_ylabel(f"gap [{au.x_label}]")
    axes[0, 1].set_ylabel(f"speed [{au.v_label}]")
    axes[1, 0].set_ylabel(f"acceleration [{au.a_label}]")
    axes[1, 1].set_ylabel("cell current I [A] (> 0 discharges)")
    axes[2, 0].set_ylabel("state of charge S [-]")
    axes[2, 1].set_ylabel("pack heat ∫Q dt [J]")
    for ax in axes[-1]:
        ax.set_xlabel(f"t [{au.t_label}]")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    axes[0, 1].legend(fontsize=7, ncol=2)
    axes[0, 0].legend(fontsize=7)
    notes = [f"stopped: {r.events[0]}"] if r.events else []
    if len(shown) < n:
        notes.append(f"{len(shown)} of {n} vehicles shown (evenly spaced)")
    if notes:
        fig.text(0.01, 0.005, "; ".join(notes), fontsize=8, color="red" if r.events else "black")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return save_figure(fig, path)


def plot_percent_change(
    ours: Sequence[float],
    paper: Sequence[float] | None,
    path: str | os.PathLike[str] | None = None,
    title: str | None = None,
    label: str = "ω(proposed) vs ω(OVFL)",
) -> Figure:
    """Per-follower % change of the paper's ω (signed bars: below zero = the proposed law lowers ω), ours beside the
    paper's printed row; each bar carries its value with its sign."""
    fig, ax = plt.subplots(figsize=(6.5, 4))
    n = np.arange(1, len(ours) + 1)
    w = 0.38 if paper is not None else 0.6
    series = [("ours (computed)", ours, "tab:blue", -w / 2 if paper is not None else 0.0)]
    if paper is not None:
        series.append(("paper (printed)", paper, "tab:gray", w / 2))
    for name, vals, col, off in series:
        bars = ax.bar(n + off, vals, width=w, color=col, label=name, edgecolor="black", lw=0.5)
        for b, v in zip(bars, vals):
            ax.annotate(
                f"{v:+.2f}%",
                (b.get_x() + b.get_width() / 2, v),
                ha="center",
                va="bottom" if v >= 0 else "top",
                fontsize=7,
                xytext=(0, 2 if v >= 0 else -2),
                textcoords="offset points",
            )
    ax.axhline(0.0, color="black", lw=0.8)
    lo = min(min(ours), min(paper) if paper is not None else 0.0, 0.0)
    hi = max(max(ours), max(paper) if paper is not None else 0.0, 0.0)
    pad = 0.15 * max(hi - lo, 1e-9)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xticks(n)
    ax.set_xlabel("follower n")
    ax.set_ylabel(f"% change, {label} [%]\n(< 0: proposed uses less)")
    return _finish_single(fig, ax, path, title)


def plot_compare_omega(
    omegas: Mapping[str, Sequence[float]],
    path: str | os.PathLike[str] | None = None,
    reference: Mapping[str, Sequence[float]] | None = None,
    title: str | None = None,
) -> Figure:
    """The paper's measure ω (its energy per unit mass, not battery energy) per follower for several laws,
    optionally beside reference values."""
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for label, om in omegas.items():
        n = np.arange(1, len(om) + 1)
        ax.plot(n, om, marker="o", label=f"{label} (computed)", **_style(label))
    for label, om in (reference or {}).items():
        n = np.arange(1, len(om) + 1)
        ax.plot(n, om, "s", mfc="none", ms=8, label=f"{label} (paper, printed)", color=_style(label).get("color"))
    ax.set_xlabel("follower n")
    ax.set_ylabel("ω [model units]")
    return _finish_single(fig, ax, path, title)


def plot_theorem41(
    kappa: Sequence[float],
    d_omega: Sequence[float],
    leader: Sequence[str],
    path: str | os.PathLike[str] | None = None,
    title: str | None = None,
) -> Figure:
    """ω(proposed) − ω(OVFL) of random cases against κ; points above zero contradict Theorem 4.1."""
    fig, ax = plt.subplots(figsize=(6.5, 4))
    k, d, lab = np.asarray(kappa, float), np.asarray(d_omega, float), np.asarray(leader)
    rng = np.random.default_rng(0)
    jitter = np.exp(rng.uniform(-0.12, 0.12, k.size))
    for name, marker in (("paper", "o"), ("constant", "^")):
        m = lab == name
        ax.scatter(
            k[m] * jitter[m],
            d[m],
            marker=marker,
            s=22,
            alpha=0.8,
            label=f"{name} leader",
            c=np.where(d[m] > 1e-6, "tab:red", "tab:blue"),
        )
    ax.axhline(0.0, color="gray", ls="--", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_xlabel("κ (jittered)")
    ax.set_ylabel("ω(proposed) − ω(OVFL) [model units]")
    return _finish_single(fig, ax, path, title)


def _number(x: Any) -> float | None:
    """x as a finite float, else None (bools, strings, None, NaN)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        return None
    return float(x) if np.isfinite(x) else None


def comparable_dots(ax: Any, pts: Sequence[tuple[float, float, bool]], color: Any) -> None:
    """Dots of (x, y, comparable) points: filled when comparable with the reference, hollow otherwise."""
    ax.scatter([p[0] for p in pts if p[2]], [p[1] for p in pts if p[2]], color=color, s=14)
    ax.scatter(
        [p[0] for p in pts if not p[2]], [p[1] for p in pts if not p[2]], facecolors="none", edgecolors=color, s=30
    )


def plot_study_rows(
    rows: Sequence[Mapping[str, Any]],
    metric: str,
    axis: str,
    vehicle: int = 1,
    path: str | os.PathLike[str] | None = None,
    title: str | None = None,
) -> Figure:
    """A study's table: ``metric`` (a column, unit in its name: ``heat_pack_J_per_km``) of follower ``vehicle``
    against the column ``axis`` (numeric, or its values in order of appearance), one line per controller through
    the mean at each axis value, every row a dot (hollow: not comparable with the reference). ValueError naming the
    column when no row has a number there."""
    sel = [r for r in rows if r.get("vehicle") in (vehicle, None)]
    raw = [r.get(axis) for r in sel if r.get(axis) is not None]
    cats = [] if all(_number(v) is not None for v in raw) else list(dict.fromkeys(str(v) for v in raw))
    series: dict[str, list[tuple[float, float, bool]]] = {}
    for r in sel:
        v = r.get(axis)
        x = (float(cats.index(str(v))) if v is not None else None) if cats else _number(v)
        y = _number(r.get(metric))
        if x is not None and y is not None:
            series.setdefault(str(r.get("controller")), []).append((x, y, bool(r.get("comparable", True))))
    if not series:
        raise ValueError(
            f"plot: metric = {metric!r} against axis = {axis!r} has no row of follower {vehicle} with numbers in both "
            f"columns; columns are {sorted({k for r in sel for k in r})[:40]}"
        )
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for k, (ctrl, pts) in enumerate(series.items()):
        color = f"C{k % 10}"
        xs = sorted({p[0] for p in pts})
        ax.plot(xs, [float(np.mean([p[1] for p in pts if p[0] == x])) for x in xs], color=color, label=ctrl)
        comparable_dots(ax, pts, color)
    if cats:
        ax.set_xticks(range(len(cats)), cats)
    ax.set_xlabel(axis)
    ax.set_ylabel(metric)
    ax.set_title(title or f"{metric}, follower {vehicle} (hollow: not comparable)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)

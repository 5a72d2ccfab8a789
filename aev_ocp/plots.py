"""Figures of the paper and per-scenario trajectory plots (matplotlib, Agg backend only).

Every function takes results or arrays and a path, writes one PNG atomically (temporary file in
the same folder, then ``os.replace``) and returns the path. Axes are in the paper's model units
unless a label says otherwise.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import casadi as ca  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .models.carfollowing import equilibrium_gap  # noqa: E402
from .models.leader import LeaderProfile  # noqa: E402
from .results import SimulationResult, save_figure_atomic  # noqa: E402

LAW_STYLE = {"proposed": {"color": "tab:blue", "ls": "-"}, "ovfl": {"color": "tab:orange", "ls": "--"},
             "ovm": {"color": "tab:green", "ls": "-."}, "idm": {"color": "tab:purple", "ls": ":"}}
DPI = 120


def save_figure(fig: Any, path: str | os.PathLike[str]) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically (unique temp name, mode as open() gives) and close it."""
    try:
        return save_figure_atomic(fig, path, dpi=DPI, format="png")
    finally:
        plt.close(fig)


def _finish_single(fig: Any, ax: Any, path: str | os.PathLike[str], title: str | None) -> Path:
    """Grid, legend and title of a one-axes figure, then write it (atomically)."""
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _style(label: str) -> dict[str, Any]:
    return dict(LAW_STYLE.get(label.lower(), {}))


def _leader_speed_of(r: SimulationResult, i: int) -> np.ndarray:
    """Speed of the vehicle ahead of follower i (0-based) [model speed]."""
    return r.leader_speed if i == 0 else r.speed[:, i - 1]


# ----------------------------------------------------------------------------- Fig. 1 / Fig. 2
def plot_phase_planes(panels: Sequence[tuple[str, Mapping[str, SimulationResult]]], path: str | os.PathLike[str],
                      title: str | None = None) -> Path:
    """Phase planes of one follower: gap h vs relative velocity v_l − v (paper Fig. 1, Fig. 2).

    panels: (caption, {law label: result}) per panel. The initial condition is a red dot, the
    equilibrium (V⁻¹(v_l), 0) a magenta ×, the collision line h = 0 gray dashed.
    """
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.2), squeeze=False)
    for ax, (caption, runs) in zip(axes[0], panels):
        first = next(iter(runs.values()))
        for label, r in runs.items():
            rel = _leader_speed_of(r, 0) - r.speed[:, 0]
            ax.plot(r.gap[:, 0], rel, lw=1.4, label=label, **_style(label))
        h0, rel0 = first.gap[0, 0], first.leader_speed[0] - first.speed[0, 0]
        ax.plot([h0], [rel0], "o", color="red", ms=7, label="initial condition", zorder=5)
        v_l = float(first.leader_speed[-1])
        ax.plot([equilibrium_gap(v_l)], [0.0], "x", color="magenta", ms=10, mew=2.5, label="equilibrium", zorder=6)
        ax.axvline(0.0, color="gray", ls="--", lw=1.2, label="collision (h = 0)")
        ax.set_xlabel("gap h = x_l − x [model length]")
        ax.set_ylabel("relative velocity v_l − v [model speed]")
        ax.set_title(caption, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- Fig. 3
def leader_arrays(leader: LeaderProfile, t_end: float, n: int = 7001) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, a_l(t), v_l(t)) sampled on [0, t_end] [model units]."""
    t = np.linspace(0.0, t_end, n)
    ts = ca.SX.sym("t")
    acc = ca.Function("a_l", [ts], [leader.accel(ts)]).map(n)
    return t, np.asarray(acc(t.reshape(1, -1))).ravel(), leader.speed_np(t)


def plot_leader(leader: LeaderProfile, t_end: float, path: str | os.PathLike[str], title: str | None = None) -> Path:
    """The leader's acceleration a_l(t) and speed v_l(t) (paper Fig. 3)."""
    t, a, v = leader_arrays(leader, t_end)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    ax1.plot(t, a, color="tab:red", lw=1.0)
    ax1.set_ylabel("a_l [model acceleration]")
    ax1.set_title("(a) acceleration a_l", fontsize=10)
    ax2.plot(t, v, color="tab:blue", lw=1.4)
    ax2.set_ylabel("v_l [model speed]")
    ax2.set_title("(b) velocity v_l", fontsize=10)
    for ax in (ax1, ax2):
        ax.set_xlabel("t [model time]")
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- Fig. 5
def plot_platoon(r: SimulationResult, path: str | os.PathLike[str], *, v_eq: float | None = None,
                 title: str | None = None) -> Path:
    """Gaps h_n(t) and relative velocities v_{n−1} − v_n of every follower (paper Fig. 5).

    v_eq: the speed whose equilibrium (V⁻¹(v_eq), 0) is drawn as gray dashed lines (the paper
    uses v_l(20)); None draws none.
    """
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    cmap = plt.get_cmap("viridis")
    n = r.n_vehicles
    for i in range(n):
        c = cmap(i / max(n - 1, 1))
        ax1.plot(r.t, r.gap[:, i], color=c, lw=1.1, label=f"n = {i + 1}")
        ax2.plot(r.t, _leader_speed_of(r, i) - r.speed[:, i], color=c, lw=1.1, label=f"n = {i + 1}")
    if v_eq is not None:
        ax1.axhline(equilibrium_gap(v_eq), color="gray", ls="--", lw=1.2, label=f"V⁻¹({v_eq:.3f})")
        ax2.axhline(0.0, color="gray", ls="--", lw=1.2, label="0")
    ax1.set_ylabel("spacing x(n−1) − x(n) [model length]")
    ax1.set_title("(a) spacing", fontsize=10)
    ax2.set_ylabel("relative velocity v(n−1) − v(n) [model speed]")
    ax2.set_title("(b) relative velocity", fontsize=10)
    for ax in (ax1, ax2):
        ax.set_xlabel("t [model time]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ----------------------------------------------------------------------------- per scenario
MAX_TRAJECTORY_LINES = 50  # vehicles drawn per panel; a larger platoon is shown by an even subset


def plot_trajectories(r: SimulationResult, path: str | os.PathLike[str], title: str | None = None) -> Path:
    """Gaps, speeds (with the leader's), accelerations, cell current [A] and SOC over time for one run
    (any controller: closed-form laws, MPC, replayed controls; sampled controls drawn as steps).
    Platoons above MAX_TRAJECTORY_LINES vehicles are drawn as an even subset, first and last included."""
    fig, axes = plt.subplots(3, 2, figsize=(11, 9.5), sharex=True)
    cmap = plt.get_cmap("viridis")
    n = r.n_vehicles
    t = r.t
    shown = (list(range(n)) if n <= MAX_TRAJECTORY_LINES
             else sorted({int(round(k)) for k in np.linspace(0, n - 1, MAX_TRAJECTORY_LINES)}))
    mixed = len(set(r.controllers)) > 1
    for i in shown:
        c = cmap(i / max(n - 1, 1))
        lab = (f"n = {i + 1}" + (f" ({r.controllers[i]})" if mixed else "")) if len(shown) <= 10 else None
        axes[0, 0].plot(t, r.gap[:, i], color=c, lw=0.9, label=lab)
        axes[0, 1].plot(t, r.speed[:, i], color=c, lw=0.9, label=lab)
        if r.jerk_sampled:
            axes[1, 0].step(t, r.accel[:, i], where="post", color=c, lw=0.9, label=lab)
        else:
            axes[1, 0].plot(t, r.accel[:, i], color=c, lw=0.9, label=lab)
        axes[1, 1].plot(t, r.current_A[:, i], color=c, lw=0.9, label=lab)
        axes[2, 0].plot(t, r.S[:, i], color=c, lw=0.9, label=lab)
        axes[2, 1].plot(t, r.heat_J[:, i], color=c, lw=0.9, label=lab)
    axes[0, 1].plot(t, r.leader_speed, color="black", lw=1.2, ls="--", label="leader")
    axes[0, 0].axhline(0.0, color="gray", ls="--", lw=1.0)
    u = r.units
    axes[0, 0].set_ylabel(f"gap [model length; × {u.length_m:g} m]")
    axes[0, 1].set_ylabel(f"speed [model speed; × {u.speed_mps:g} m/s]")
    axes[1, 0].set_ylabel(f"acceleration [model; × {u.accel_mps2:g} m/s²]")
    axes[1, 1].set_ylabel("cell current I [A] (> 0 discharges)")
    axes[2, 0].set_ylabel("state of charge S [-]")
    axes[2, 1].set_ylabel("pack heat ∫Q dt [J]")
    for ax in axes[2]:
        ax.set_xlabel(f"t [model time; × {u.time_s:g} s]")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    if len(shown) <= 10:
        axes[0, 1].legend(fontsize=7, ncol=2)
    notes = [f"stopped: {r.events[0]}"] if r.events else []
    if len(shown) < n:
        notes.append(f"{len(shown)} of {n} vehicles shown (evenly spaced)")
    if notes:
        fig.text(0.01, 0.005, "; ".join(notes), fontsize=8, color="red" if r.events else "black")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return save_figure(fig, path)


def plot_compare_omega(omegas: Mapping[str, Sequence[float]], path: str | os.PathLike[str],
                       reference: Mapping[str, Sequence[float]] | None = None, title: str | None = None) -> Path:
    """Energy per unit mass ω per follower for several laws, optionally beside reference values."""
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


def plot_theorem41(kappa: Sequence[float], d_omega: Sequence[float], leader: Sequence[str],
                   path: str | os.PathLike[str], title: str | None = None) -> Path:
    """ω(proposed) − ω(OVFL) of random cases against κ; points above zero contradict Theorem 4.1."""
    fig, ax = plt.subplots(figsize=(6.5, 4))
    k, d, lab = np.asarray(kappa, float), np.asarray(d_omega, float), np.asarray(leader)
    rng = np.random.default_rng(0)
    jitter = np.exp(rng.uniform(-0.12, 0.12, k.size))
    for name, marker in (("paper", "o"), ("constant", "^")):
        m = lab == name
        ax.scatter(k[m] * jitter[m], d[m], marker=marker, s=22, alpha=0.8, label=f"{name} leader",
                   c=np.where(d[m] > 1e-6, "tab:red", "tab:blue"))
    ax.axhline(0.0, color="gray", ls="--", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_xlabel("κ (jittered)")
    ax.set_ylabel("ω(proposed) − ω(OVFL) [model units]")
    return _finish_single(fig, ax, path, title)

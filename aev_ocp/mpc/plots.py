"""Plots of MPC closed loops (matplotlib, Agg): solve time per step and overlays of several controllers
on the same leader. Trajectories of one run are :func:`aev_ocp.plots.plot_trajectories`, shared by every
controller. Each function writes one PNG and returns its path."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..results import SimulationResult, save_figure_atomic


def _plt():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:  # noqa: ANN001
    return save_figure_atomic(fig, path, dpi=110, bbox_inches="tight")


def plot_overlay(results: Mapping[str, SimulationResult], path: str | Path, vehicle: int = 0) -> Path:
    """Gap, speed, acceleration, cell current and SOC of follower ``vehicle`` for each controller."""
    plt = _plt()
    fig, ax = plt.subplots(5, 1, figsize=(9, 11), sharex=True)
    for label, r in results.items():
        i = vehicle
        ax[0].plot(r.t, r.gap[:, i], label=label)
        ax[1].plot(r.t, r.speed[:, i], label=label)
        if r.jerk_sampled:
            ax[2].step(r.t, r.accel[:, i], where="post", label=label)
        else:
            ax[2].plot(r.t, r.accel[:, i], label=label)
        ax[3].plot(r.t, r.current_A[:, i], label=label)
        ax[4].plot(r.t, r.S[:, i], label=label)
    first = next(iter(results.values()))
    ax[1].plot(first.t, first.leader_speed if vehicle == 0 else first.speed[:, vehicle - 1], "k:", lw=1,
               label="vehicle ahead")
    ax[0].axhline(0.2, color="gray", ls="--", lw=0.8)
    for a, lab in zip(ax, ["gap h [model]", "speed v [model]", "accel a [model]", "cell current I [A]", "SOC S [-]"]):
        a.set_ylabel(lab)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    ax[-1].set_xlabel("t [model time]")
    fig.suptitle(f"follower {vehicle + 1}")
    out = _save(fig, Path(path))
    plt.close(fig)
    return out


def plot_solve_times(r: SimulationResult, path: str | Path) -> Path:
    """Solve wall time per step [ms] of every MPC follower (log scale), fallbacks marked."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 3.5))
    steps = r.meta.get("mpc_steps", [])
    for i, st in enumerate(steps):
        if not st:
            continue
        ms = np.asarray(st["solve_ms"])
        tk = r.t[:ms.size]
        ax.semilogy(tk, ms, lw=0.8, label=f"follower {i + 1} ({r.solver_stats[i]['solver_path']})")
        bad = [k for k, s in enumerate(st["status"]) if s not in ("Solve_Succeeded", "Solved_To_Acceptable_Level")]
        if bad:
            ax.semilogy(tk[bad], ms[bad], "rx", label=f"follower {i + 1} fallback")
    ax.set_xlabel("t [model time]")
    ax.set_ylabel("solve time [ms]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    out = _save(fig, Path(path))
    plt.close(fig)
    return out

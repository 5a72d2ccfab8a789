"""Plots of MPC closed loops (matplotlib, Agg): solve time per step and overlays of several controllers
on the same leader. Trajectories of one run are :func:`aev_ocp.plots.plot_trajectories`, shared by every
controller. Each function writes one PNG and returns its path. Axes are in s, m, km/h, m/s² through the
run's units by default (``si=False``: the paper's model units)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..plots import AxisUnits, Figure, controller_styles, plt, save_figure
from ..results import SimulationResult


def plot_overlay(
    results: Mapping[str, SimulationResult],
    path: str | Path | None = None,
    vehicle: int = 0,
    h_min: float | None = None,
    si: bool = True,
) -> Figure:
    """Gap, speed, acceleration, cell current and SOC of follower ``vehicle`` for each controller.

    Each controller has its own colour and dash pattern and is drawn thinner than the one before it (so an
    identical run does not hide another); the vehicle ahead is a wide gray band behind them;
    it is in the speed legend, and ``h_min`` [model length] (default: the gap floor of the first run whose
    follower ``vehicle`` runs an MPC: its formulation's, e.g. the traffic formulation's 2 m standstill floor)
    is drawn and labelled on the gap panel."""
    if not results:
        raise ValueError("plot_overlay: no results to draw")
    first = next(iter(results.values()))
    au = AxisUnits.of(first.units, si)
    styles = controller_styles(list(results))
    if h_min is None:
        h_min = _h_min_of(results, vehicle)
    fig, ax = plt.subplots(5, 1, figsize=(9, 11), sharex=True)
    i = vehicle
    for k, (label, r) in enumerate(results.items()):
        # each line thinner than the one drawn before it, so an identical later run cannot hide an earlier one
        st: dict[str, Any] = {**styles[label], "lw": max(2.6 - 0.5 * k, 0.8), "label": label}
        t = au.t * r.t
        ax[0].plot(t, au.x * r.gap[:, i], **st)
        ax[1].plot(t, au.v * r.speed[:, i], **st)
        if r.jerk_sampled:
            ax[2].step(t, au.a * r.accel[:, i], where="post", **st)
        else:
            ax[2].plot(t, au.a * r.accel[:, i], **st)
        ax[3].plot(t, r.current_A[:, i], **st)
        ax[4].plot(t, r.S[:, i], **st)
    ahead = first.leader_speed if vehicle == 0 else first.speed[:, vehicle - 1]
    ax[1].plot(
        au.t * first.t,
        au.v * ahead,
        color="0.55",
        ls="-",
        lw=3.2,
        alpha=0.45,
        zorder=0,
        label="leader" if vehicle == 0 else f"vehicle ahead (n = {vehicle}, {list(results)[0]})",
    )
    if h_min is not None:
        ax[0].axhline(au.x * h_min, color="gray", ls="--", lw=0.9, label=f"h_min = {au.x * h_min:.3g} {au.x_label}")
    labels = [
        f"gap h [{au.x_label}]",
        f"speed v [{au.v_label}]",
        f"acceleration a [{au.a_label}]",
        "cell current I [A]",
        "SOC S [-]",
    ]
    for a, lab in zip(ax, labels):
        a.set_ylabel(lab)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    ax[1].legend(fontsize=8)
    ax[-1].set_xlabel(f"t [{au.t_label}]")
    fig.suptitle(f"follower {vehicle + 1}")
    fig.tight_layout()
    return save_figure(fig, path)


def _h_min_of(results: Mapping[str, SimulationResult], vehicle: int = 0) -> float | None:
    """The gap floor [model length] of the running formulation: the first run whose follower ``vehicle`` records
    its formulation's bounds (``meta['controllers'][vehicle]['bounds_model']``, an MPC's); None if none does."""
    for r in results.values():
        ctrls = r.meta.get("controllers") or []
        c = ctrls[vehicle] if vehicle < len(ctrls) else None
        if isinstance(c, dict):
            b = c.get("bounds_model")
            if isinstance(b, dict) and b.get("h_min") is not None:
                return float(b["h_min"])
    return None


def fallback_steps(step_record: Mapping[str, Any]) -> np.ndarray:
    """Indices of the steps where the controller really fell back (its ``ok`` flag is False).

    The solver's status string is not the criterion: an RTI step reports its QP's status, and a
    solve accepted by the controller is not a fallback whatever the string says."""
    ok = step_record.get("ok")
    if ok is None:
        raise KeyError("MPC step record has no 'ok' field: cannot tell a fallback from a solve")
    return np.flatnonzero(~np.asarray(ok, dtype=bool))


def plot_solve_times(r: SimulationResult, path: str | Path | None = None, si: bool = True) -> Figure:
    """Solve wall time per step [ms] of every MPC follower (log scale); steps that really fell back
    (the controller's ``ok`` flag False, the same count as the report's 'fallbacks') marked with red ×."""
    au = AxisUnits.of(r.units, si)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    steps = r.meta.get("mpc_steps", [])
    n_fallbacks = 0
    for i, st in enumerate(steps):
        if not st:
            continue
        ms = np.asarray(st["solve_ms"])
        tk = au.t * r.t[: ms.size]
        st_i = r.solver_stats[i] if i < len(r.solver_stats) else None
        path_name = st_i["solver_path"] if st_i else "mpc"
        ax.semilogy(tk, ms, lw=0.8, label=f"follower {i + 1} ({path_name})")
        bad = fallback_steps(st)
        n_fallbacks += bad.size
        if bad.size:
            ax.semilogy(tk[bad], ms[bad], "rx", label=f"follower {i + 1}: {bad.size} fallback(s)")
    ax.set_xlabel(f"t [{au.t_label}]")
    ax.set_ylabel("solve time [ms]")
    ax.set_title(f"MPC solve time per step; {n_fallbacks} fallback(s)", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)

"""Plots of optimal-control results (matplotlib, Agg backend). The solvers in :mod:`aev_ocp.ocp`
know nothing of plotting; these helpers take their results and write PNG files. Quantities carry
readable names and units (:data:`QUANTITY_LABELS`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..models.battery import stored_energy_J
from ..ocp_result import OCPResult, write_json_atomic
from ..params import CellParams
from ..plots import Figure, plt, save_figure

# name in an OCPResult -> (readable name, unit for a time unit in seconds, unit for model time)
QUANTITY_LABELS: dict[str, tuple[str, str, str]] = {
    "x": ("position x", "m", "model length"),
    "h": ("gap h", "m", "model length"),
    "v": ("speed v", "m/s", "model speed"),
    "a": ("acceleration a", "m/s²", "model acceleration"),
    "V1": ("RC voltage V1", "V", "V"),
    "V2": ("RC voltage V2", "V", "V"),
    "S": ("state of charge S", "-", "-"),
    "E": ("delivered energy E", "J", "J"),
    "I": ("cell current I", "A", "A"),
    "Q": ("cell heat rate Q", "W", "W"),
    "Q_pack_W": ("pack heat rate", "W", "W"),
    "P_w_W": ("wheel power P_w", "W", "W"),
    "P_b_W": ("battery power P_b", "W", "W"),
    "disc": ("current-map discriminant E² − 4R_sP_c", "V²", "V²"),
    "omega_rate": ("the paper's ω rate v·g(a)", "W/kg", "model units"),
    "s": ("epigraph variable s (≥ v·g(a))", "W/kg", "model"),
}
# A current below this magnitude [A] is drawn and labelled as 0: IPOPT's tol 1e-8 on the scaled current
# (u_scale 10 A, ocp/cell.py) leaves residues of ~1e-6 A (OCP-A's relaxing case with Q >= 0: 6e-7 A).
ZERO_CURRENT_A = 1e-5
ZERO_HEAT_J = 1e-6  # an objective within this of 0 [J] is 0 at the solver's tolerance (ocp/prop31.py uses the same)


def quantity_label(name: str, time_unit: str = "s") -> str:
    """'readable name [unit]' of an OCP quantity; the raw name if unknown."""
    if name not in QUANTITY_LABELS:
        return name
    nm, si, model = QUANTITY_LABELS[name]
    return f"{nm} [{si if time_unit == 's' else model}]"


def _stairs(ax: Any, t: np.ndarray, u: np.ndarray, **kw: Any) -> None:
    ax.step(t, np.append(u, u[-1]), where="post", **kw)


def plot_prop31(
    cases: dict[str, dict[str, Any]], path: str | Path | None = None, cell: CellParams | None = None
) -> Figure:
    """Proposition 3.1 (OCP-A), one column per case: top, the optimal current I*(t) [A] beside the zero-heat
    alternative I = −(V1+V2)/R_s (a current below ZERO_CURRENT_A is drawn as 0 and labelled 'numerically
    zero' with its largest magnitude); bottom, the stored RC energy W(t) = ½C1V1² + ½C2V2² [J] under both,
    the mechanism: ∫Q dt = ∫Q_irr dt + W(t_f) − W(0), so a current that drains W makes ∫Q negative."""
    cell = cell or CellParams()
    n = len(cases)
    fig, axes = plt.subplots(2, n, figsize=(3.6 * n, 6.2), sharex=True, squeeze=False)
    for k, (case, e) in enumerate(cases.items()):
        ax_i, ax_w = axes[0, k], axes[1, k]
        res: OCPResult = e["result"]
        sim = e["alternatives"]["neg_polarisation"]["sim"]
        alt_J = e["zero_heat_alternative_objective_J"]
        alt_I = np.asarray(sim["I"], float)
        if float(np.max(np.abs(alt_I))) < ZERO_CURRENT_A:
            alt_I = np.zeros_like(alt_I)
        ax_i.plot(sim["t"], alt_I, color="tab:orange", ls="--", lw=1.4, label=f"I = −(V1+V2)/R_s: ∫Q = {_j(alt_J)} J")
        ax_w.plot(
            sim["t"],
            stored_energy_J(np.asarray(sim["V1"]), np.asarray(sim["V2"]), cell),
            color="tab:orange",
            ls="--",
            lw=1.4,
            label="I = −(V1+V2)/R_s",
        )
        if res.success:
            I = np.asarray(res.controls["I"], float)
            peak = float(np.max(np.abs(I)))
            zero = peak < ZERO_CURRENT_A
            lab = f"I* = 0 (numerically: max |I*| = {peak:.1e} A)" if zero else f"I* (max |I*| = {peak:.3g} A)"
            _stairs(ax_i, res.t, np.zeros_like(I) if zero else I, color="tab:blue", lw=1.6, label=lab)
            ax_i.plot([], [], " ", label=f"J* = ∫Q dt = {_j(res.objective)} J")
            zero_all = zero and float(np.max(np.abs(alt_I))) == 0.0
            if "V1" in res.states and "V2" in res.states:
                ax_w.plot(
                    res.t,
                    stored_energy_J(res.states["V1"], res.states["V2"], cell),
                    color="tab:blue",
                    lw=1.6,
                    label="I*",
                )
        else:
            zero_all = False
            ax_i.plot([], [], " ", label=f"no optimum: {res.status}")
        if zero_all:  # every current is zero: a readable band around 0
            ax_i.set_ylim(-1.0, 1.0)
        ax_i.axhline(0.0, color="gray", lw=0.5)
        v0 = e.get("V0", (0.0, 0.0))
        ax_i.set_title(case.replace("_Q_nonneg", ", Q ≥ 0") + f"\nV1(0) = {v0[0]:g} V, V2(0) = {v0[1]:g} V", fontsize=9)
        ax_i.legend(fontsize=7, loc="best")
        ax_w.legend(fontsize=7, loc="best")
        lo, hi = ax_w.get_ylim()
        if hi - lo < 1e-9:
            ax_w.set_ylim(-0.5, 0.5)
        ax_w.set_xlabel("t [s]")
        if k == 0:
            ax_i.set_ylabel("cell current I [A]")
            ax_w.set_ylabel("stored RC energy W [J]")
        for ax in (ax_i, ax_w):
            ax.grid(alpha=0.3)
    fig.suptitle(
        "OCP-A (Proposition 3.1): optimal cell current (top) and the RC energy W it drains (bottom)", fontsize=10
    )
    fig.tight_layout()
    return save_figure(fig, path)


def _j(x: float) -> str:
    """An energy for a legend: 3 significant figures; within ZERO_HEAT_J of 0 shown as 0 (with its value if
    that is not negligible)."""
    if not math.isfinite(x) or abs(x) >= ZERO_HEAT_J:
        return f"{x:.3g}"
    return "0" if abs(x) < 1e-12 else f"{x:.1e} ≈ 0"


def plot_result(res: OCPResult, path: str | Path | None = None, names: Sequence[str] | None = None) -> Figure:
    """States, controls and outputs of one OCPResult against time, one panel per quantity, each with a
    readable name and its unit (controls as piecewise-constant steps)."""
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
        ax.set_ylabel(quantity_label(nm, res.time_unit), fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel(f"t [{res.time_unit}]")
    fig.suptitle(
        f"{res.problem} ({res.method}, N = {res.N}): {res.status}, objective {res.objective:.6g}"
        + (f" ({res.objective_name})" if res.objective_name else ""),
        fontsize=10,
    )
    fig.tight_layout()
    return save_figure(fig, path)


def percent_saving(optimal: float, reference: float) -> float:
    """100 (reference − optimal)/reference [%]: how much less heat the optimum dissipates."""
    return 100.0 * (reference - optimal) / reference


CURRENT_PROFILE_REFERENCES = {
    "constant_current_heat_J": ("constant current", "o-"),
    "constant_power_heat_J": ("constant power", "s--"),
}


def plot_current_profile_sweep(rows: list[dict[str, Any]], path: str | Path | None = None) -> Figure:
    """OCP-B sweep: the heat the optimal current profile saves against the constant-current and the
    constant-power profile delivering the same energy, 100 (∫Q_ref − ∫Q*)/∫Q_ref [%] against the required
    energy E_req [J], one colour per horizon t_f [s]. Rows need E_req_J, t_f_s, optimal_heat_J and the
    reference heats; infeasible rows (NaN optimum) are skipped."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    horizons = sorted({r["t_f_s"] for r in rows})
    for k, tf in enumerate(horizons):
        sel = sorted(
            (r for r in rows if r["t_f_s"] == tf and math.isfinite(r.get("optimal_heat_J", math.nan))),
            key=lambda r: r["E_req_J"],
        )
        for key, (name, fmt) in CURRENT_PROFILE_REFERENCES.items():
            pts = [
                (r["E_req_J"], percent_saving(r["optimal_heat_J"], r[key]))
                for r in sel
                if math.isfinite(r.get(key, math.nan)) and r[key] > 0
            ]
            if pts:
                xs, ys = zip(*pts)
                ax.plot(xs, ys, fmt, color=f"C{k}", label=f"vs {name}, t_f = {tf:g} s")
    ax.axhline(0.0, color="gray", lw=0.8)
    ax.set_xlabel("required energy E_req [J per cell]")
    ax.set_ylabel("heat saved by the optimal profile [%]")
    ax.set_title("OCP-B: optimal current profile against simple profiles", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def write_prop31_outputs(cases: dict[str, dict[str, Any]], out_dir: str | Path, plots: bool = True) -> dict[str, Path]:
    """prop31.json (one entry per case, without the trajectories) and (plots) prop31_currents.png."""
    out_dir = Path(out_dir)
    keep = (
        "objective_J",
        "max_abs_current_A",
        "zero_heat_alternative_objective_J",
        "zero_heat_alternative_max_abs_current_A",
        "switched_alternative_objective_J",
        "status",
        "iterations",
        "solve_time_s",
        "max_violation",
        "stored_rc_energy_W0_J",
        "Q_nonneg_constraint",
        "V0",
        "lq_exact_discrete_J",
        "objective_exact_J",
        "objective_2N_J",
        "warnings",
        "verdict",
    )
    js = {c: {k: e[k] for k in keep if k in e} for c, e in cases.items()}
    paths = {"json": write_json_atomic(out_dir / "prop31.json", js)}
    if plots:
        paths["png"] = out_dir / "prop31_currents.png"
        plot_prop31(cases, paths["png"])
    return paths

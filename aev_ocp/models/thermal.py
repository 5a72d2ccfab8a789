"""Lumped thermal model of a pack: one temperature node per pack, SI units (K, W, J/K, s).

    C_pack dT/dt = Q_irr_pack − hA (T − T_amb) − P_cool,
    C_pack = n_cells · cell.heat_capacity_JpK,   hA = n_cells · h · cell.surface_area_m2,

where Q_irr_pack = n_cells (R_s I² + V1²/R1 + V2²/R2) ≥ 0 is the heat the pack dissipates
(:func:`aev_ocp.models.battery.heat_irreversible`) and P_cool ≥ 0 an optional constant cooling power. For a
constant Q_irr the response from T(0) = T_amb is T(t) = T_amb + (Q_irr − P_cool)/hA · (1 − e^{−t hA/C_pack})
(:func:`step_response_K`). The model knows nothing of solvers: the plant and the OCP builders integrate it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..numerics import trapezoid
from ..params import CellParams, PackParams, ThermalParams


def heat_capacity_JpK(cell: CellParams, pack: PackParams) -> float:
    """C_pack = n_cells · m c_p of one cell [J/K]."""
    return pack.n_cells * cell.heat_capacity_JpK


def conductance_WpK(cell: CellParams, pack: PackParams, thermal: ThermalParams) -> float:
    """hA = n_cells · h · A_cell [W/K]: the pack's convective conductance to the ambient."""
    return pack.n_cells * thermal.h_Wpm2K * cell.surface_area_m2


def time_constant_s(cell: CellParams, pack: PackParams, thermal: ThermalParams) -> float:
    """C_pack / hA [s] (independent of the number of cells)."""
    return heat_capacity_JpK(cell, pack) / conductance_WpK(cell, pack, thermal)


def temperature_rate_Kps(
    T_K: Any, Q_irr_pack_W: Any, cell: CellParams, pack: PackParams, thermal: ThermalParams
) -> Any:
    """dT/dt [K/s] of the pack at temperature T_K [K] dissipating Q_irr_pack_W [W] (numbers or CasADi)."""
    hA = conductance_WpK(cell, pack, thermal)
    return (Q_irr_pack_W - hA * (T_K - thermal.ambient_K) - thermal.cooling_power_W) / heat_capacity_JpK(cell, pack)


def step_response_K(
    t_s: Any, Q_pack_W: float, cell: CellParams, pack: PackParams, thermal: ThermalParams, T0_K: float | None = None
) -> Any:
    """Closed form T(t) [K] for a constant pack heat Q_pack_W [W] from T0_K (default the thermal's T(0)):
    T_∞ + (T0 − T_∞) e^{−t/τ} with T_∞ = T_amb + (Q − P_cool)/hA and τ = C_pack/hA."""
    hA = conductance_WpK(cell, pack, thermal)
    T_inf = thermal.ambient_K + (Q_pack_W - thermal.cooling_power_W) / hA
    T0 = thermal.initial_K if T0_K is None else T0_K
    tau = time_constant_s(cell, pack, thermal)
    return T_inf + (T0 - T_inf) * np.exp(-np.asarray(t_s, float) / tau)


def temperature_metrics(t_s: Any, T_K: Any, T_max_K: float) -> dict[str, float]:
    """Peak [K], time-mean [K] (trapezoid in t) and time above T_max_K [s] (linear between samples) of one
    pack's temperature history (t_s, T_K)."""
    t, T = np.asarray(t_s, float), np.asarray(T_K, float)
    ok = np.isfinite(T)
    t, T = t[ok], T[ok]
    if T.size == 0:
        return {"peak_K": math.nan, "mean_K": math.nan, "time_above_s": math.nan}
    span = t[-1] - t[0]
    mean = trapezoid(T, t) / span if span > 0 else float(T[0])
    above = 0.0
    for t0, t1, a, b in zip(t[:-1], t[1:], T[:-1] - T_max_K, T[1:] - T_max_K):
        if a > 0 and b > 0:
            above += t1 - t0
        elif a > 0 or b > 0:  # crosses: the part above, linearly
            above += (t1 - t0) * max(a, b) / (abs(a) + abs(b))
    return {"peak_K": float(np.max(T)), "mean_K": mean, "time_above_s": float(above)}

"""Powertrain and the current map between vehicle motion and cell current (model guide §5, §7).

The paper's current equation (paper eq. current_dynamics) is implicit because V_T depends on I.
It is solved exactly: with E = OCV(S) − V1 − V2, P_c = I (E − R_s I) gives the physical root
I = 2 P_c / (E + sqrt(E² − 4 R_s P_c)), continuous through P_c = 0. When E² < 4 R_s P_c the cell
cannot deliver the demand: :func:`current_from_power` also returns the discriminant so that a
simulator can report it and an optimiser can constrain it.

One floor policy: the square root is taken of max(disc, DISC_FLOOR_V2), so every user (plant,
OCP, MPC) evaluates the same finite root up to an event (the plant reports disc < 0, optimisers
constrain disc ≥ 0). One η-switch default: the models use the EXACT switch unless a caller passes
:class:`~aev_ocp.params.PowertrainOptions` (optimisers do, model guide §7).
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from ..params import CellParams, EVParams, PackParams, PowertrainOptions, VehicleParams
from . import battery, vehicle

DISC_FLOOR_V2 = 1e-12  # [V²] floor under the discriminant's square root (keeps the root and its derivative finite)


def battery_power_W(P_w: Any, p: VehicleParams) -> Any:
    """Exact η switch (model guide §5): P_b = P_w/η if P_w > 0 else η P_w, plus P_aux [W]."""
    return ca.if_else(P_w > 0, P_w / p.efficiency, p.efficiency * P_w) + p.aux_power_W


def battery_power_smooth_W(P_w: Any, p: VehicleParams, opts: PowertrainOptions | None = None) -> Any:
    """Smoothed η switch for optimisers (model guide §7): P_b = P_w (σ/η + (1−σ)η) + P_aux,
    σ = ½(1 + tanh(P_w / width)) [W]."""
    w = (opts or PowertrainOptions()).smoothing_width_W
    sigma = 0.5 * (1 + ca.tanh(P_w / w))
    return P_w * (sigma / p.efficiency + (1 - sigma) * p.efficiency) + p.aux_power_W


def cell_power_W(P_b: Any, pack: PackParams) -> Any:
    """Cell power P_c = P_b / (N_s N_p) [W] (paper §3.1)."""
    return P_b / pack.n_cells


def current_discriminant(P_c: Any, E: Any, cell: CellParams) -> Any:
    """E² − 4 R_s P_c [V²]; negative means the cell cannot deliver P_c."""
    return E**2 - 4.0 * cell.R_s_ohm * P_c


def current_from_power(P_c: Any, E: Any, cell: CellParams) -> tuple[Any, Any]:
    """Cell current I [A] that delivers P_c [W] at the terminals, and the discriminant [V²].

    I = 2 P_c / (E + sqrt(max(disc, DISC_FLOOR_V2))); exact to 1e-6 relative where disc ≥ 0. Where
    disc < 0 the returned I is about the current at maximum power (E / 2R_s) and the caller must
    treat the demand as infeasible.
    """
    disc = current_discriminant(P_c, E, cell)
    return 2.0 * P_c / (E + ca.sqrt(ca.fmax(disc, DISC_FLOOR_V2))), disc


def cell_current_from_motion(
    v_mps: Any,
    a_mps2: Any,
    V1: Any,
    V2: Any,
    S: Any,
    p: EVParams,
    smooth: PowertrainOptions | None = None,
    cell: Any = None,
) -> dict[str, Any]:
    """The whole current map: vehicle motion and cell state -> cell current and its pieces.

    Returns a dict with P_w [W], P_b [W], P_c [W], E [V], I [A], disc [V²]. ``smooth=None``
    uses the exact η switch (simulation); otherwise the smoothed one (optimisation). ``cell``: the cell at
    its temperature (:func:`aev_ocp.models.battery.cell_at`); None: ``p.cell``.
    """
    P_w = vehicle.wheel_power_W(v_mps, a_mps2, p.vehicle)
    P_b = battery_power_W(P_w, p.vehicle) if smooth is None else battery_power_smooth_W(P_w, p.vehicle, smooth)
    P_c = cell_power_W(P_b, p.pack)
    E = battery.ocv(S, p.cell) - V1 - V2
    I, disc = current_from_power(P_c, E, p.cell if cell is None else cell)
    return {"P_w": P_w, "P_b": P_b, "P_c": P_c, "E": E, "I": I, "disc": disc}

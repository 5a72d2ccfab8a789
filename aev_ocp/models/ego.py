"""The ego vehicle with its battery pack: the battery side of a motion and the following dynamics.

One place for the physics that the plant (simulation, closed loops), the OCPs and the MPC share
(model guide §5–§7, §9). Speeds, gaps and accelerations are in model units (converted with
``ev.units``); the cell states V1, V2 [V] and S [-] evolve in seconds.

Policies stated once:
* the η switch is EXACT unless ``smooth`` (a :class:`~aev_ocp.params.PowertrainOptions`) is given;
  optimisers pass it (model guide §7), the plant never does;
* the OCV is evaluated at S clamped to the table's range [0, 1] (the plant reports S leaving [0, 1]
  as an event, optimisers bound S), so right-hand sides stay finite up to an event;
* the current root uses :data:`aev_ocp.models.powertrain.DISC_FLOOR_V2`.
"""

from __future__ import annotations

from typing import Any

import casadi as ca

from ..params import EVParams, PowertrainOptions
from . import battery, thermal
from .powertrain import cell_current_from_motion

STATE_NAMES = ("h", "v", "V1", "V2", "S")  # ego state z: gap, speed [model], V1, V2 [V], S [-]


def battery_side(
    v: Any, a: Any, V1: Any, V2: Any, S: Any, ev: EVParams, smooth: PowertrainOptions | None = None, T_K: Any = None
) -> dict[str, Any]:
    """Battery side of one vehicle at model speed v and acceleration a; T_K: the pack temperature [K] (None:
    no thermal state; the cell's resistances at their reference temperature).

    Returns I [A per cell], disc [V²] (E² − 4 R_s P_c; < 0 = infeasible demand), P_b [W],
    dV1, dV2 [V/s], dS [1/s], Q [W per cell], Q_pack [W] and Q_irr_pack [W] (model guide §6), and with T_K
    dT [K/s] of the lumped thermal model (:mod:`aev_ocp.models.thermal`).
    """
    u = ev.units
    S_in = ca.fmin(ca.fmax(S, 0.0), 1.0)
    cell = battery.cell_at(ev.cell, T_K, S_in, smooth is not None)  # a table cell: R, C at (S, T)
    cm = cell_current_from_motion(u.speed_to_si(v), u.accel_to_si(a), V1, V2, S_in, ev, smooth=smooth, cell=cell)
    I = cm["I"]
    dV1, dV2, dS = battery.cell_derivatives(V1, V2, I, cell)
    Q = battery.heat_Q(V1, V2, I, cell)
    n = ev.pack.n_cells
    out = {
        "I": I,
        "disc": cm["disc"],
        "P_b": cm["P_b"],
        "dV1": dV1,
        "dV2": dV2,
        "dS": dS,
        "Q": Q,
        "Q_pack": n * Q,
        "Q_irr_pack": n * battery.heat_irreversible(V1, V2, I, cell),
    }
    if T_K is not None:
        out["dT"] = thermal.temperature_rate_Kps(T_K, out["Q_irr_pack"], ev.cell, ev.pack, ev.thermal)
    return out


def following_ode(
    z: Any, a: Any, v_l: Any, ev: EVParams, smooth: PowertrainOptions | None = None, T_K: Any = None
) -> Any:
    """dz/dt in model time for z = (h, v, V1, V2, S): ḣ = v_l − v, v̇ = a, and the cell ODE
    (paper eqs. V_1_V_2, change_SOC) scaled by the time unit T [s]; T_K: the pack temperature [K] that sets the
    cell's resistances (None: their reference values)."""
    b = battery_side(z[1], a, z[2], z[3], z[4], ev, smooth, T_K)
    T = ev.units.time_s
    return ca.vertcat(v_l - z[1], a, T * b["dV1"], T * b["dV2"], T * b["dS"])

"""The battery of every SUMO vehicle, integrated on the motion SUMO realised (all vehicles in one call per step).

Per vehicle the state is (V1, V2 [V], S [-], ω [model], pack ∫Q, ∫Q_irr [J], battery energy ∫P_b [J]). Over one SUMO step of dt [s] the
vehicle's speed goes from v0 to v1 (SUMO's ballistic update: constant acceleration a = (v1 − v0)/dt over the step),
so the cell ODE of :func:`aev_ocp.models.ego.battery_side` is integrated with one classical Runge–Kutta step at
v(t) = v0 + a t (the cell's time constants, 3.9 s and 100 s, are far above a SUMO step of 0.1 s: RK4's local error
is O((dt/τ)^5)); battery energy ∫P_b dt (the vehicle's exact powertrain, :mod:`aev_ocp.models.powertrain`) is
integrated by the same step (Simpson's rule for a quadrature), and the paper's ω = ∫ v g(a) dt is exact for the
constant a: g(a) (v0 + v1)/2 · dt.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np

from ..fastcall import column_call
from ..models.energy import g_exact
from ..models.ego import battery_side
from ..params import EVParams

N_STATE = 7  # V1, V2, S, omega_model, heat_J, heat_irr_J, battery_energy_J
BATTERY_ENERGY_ROW = 6  # the row of ∫P_b [J] in the state


@lru_cache(maxsize=8)
def battery_step(ev: EVParams) -> ca.Function:
    """F(x[7], v0, a, dt_s) -> (x_next[7], I [A per cell] at the step's start, disc [V²] at start and end):
    one step of the battery of a vehicle whose model speed goes linearly from v0 with model acceleration a
    over dt_s seconds. Called with 1×N rows (7×N for x) it evaluates N vehicles at once."""
    x = ca.SX.sym("x", N_STATE)
    v0, a, dt = ca.SX.sym("v0"), ca.SX.sym("a"), ca.SX.sym("dt_s")
    T = ev.units.time_s

    def rhs(t_s: Any, y: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        b = battery_side(v0 + a * t_s / T, a, y[0], y[1], y[2], ev)
        return ca.vertcat(b["dV1"], b["dV2"], b["dS"], b["Q_pack"], b["Q_irr_pack"], b["P_b"]), b["I"], b["disc"]

    y = x[[0, 1, 2, 4, 5, 6]]
    k1, I0, disc0 = rhs(0, y)
    k2 = rhs(dt / 2, y + dt / 2 * k1)[0]
    k3 = rhs(dt / 2, y + dt / 2 * k2)[0]
    k4, _, disc1 = rhs(dt, y + dt * k3)
    y1 = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    v1 = v0 + a * dt / T
    omega1 = x[3] + g_exact(a, ev.vehicle.efficiency) * (v0 + v1) / 2 * (dt / T)
    x1 = ca.vertcat(y1[0], y1[1], y1[2], omega1, y1[3], y1[4], y1[5])
    return ca.Function(
        "sumo_battery_step",
        [x, v0, a, dt],
        [x1, I0, ca.fmin(disc0, disc1)],
        ["x", "v0", "a", "dt_s"],
        ["x_next", "I", "disc"],
    )


def initial_state(ev: EVParams, n: int) -> np.ndarray:
    """7×n initial battery states: cell at rest (V1 = V2 = 0), S = the cell's soc0, zero integrals."""
    x = np.zeros((N_STATE, n))
    x[2] = ev.cell.soc0
    return x


def step(
    ev: EVParams, x: np.ndarray, v0: np.ndarray, a: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance the 7×n states ``x`` by dt_s [s] (model speeds v0, accelerations a, 1-D of length n):
    (x_next 7×n, I [A per cell], disc [V²])."""
    if x.shape[1] == 0:
        return x.copy(), np.zeros(0), np.zeros(0)
    x1, I, disc = column_call(battery_step(ev))(x, v0, a, dt_s)
    return x1, I.ravel(), disc.ravel()

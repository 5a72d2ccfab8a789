"""The car-following stage cost, dynamics and constraints of PROBLEM.md §9 — in ONE place.

Shared by OCP-D (the oracle lower bound, :mod:`aev_ocp.ocp.oracle`) and the MPC (issue 4).

Model units throughout (PROBLEM.md §1): gap h, speed v, acceleration a, time in model time units;
the cell states V1, V2 [V] and S [-] evolve in seconds, converted with ``ev.units.time_s``.
State ``z = (h, v, V1, V2, S)``; control ``a`` held constant over each interval of length dt.

Stage cost (PROBLEM.md §9):
    ℓ = w_Q Q_pack/(1 kW) + w_V (V(h) − v)² + w_r (v̂_l − v)² + w_a a²,
summed as Σ ℓ(z_k, a_k)·dt (dt in model time units), evaluated at the start of each interval.
``objective="energy"`` replaces Q_pack/(1 kW) by v g̃(a) (smoothed g, model units).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca

from ..models import battery, energy
from ..models.carfollowing import optimal_velocity
from ..models.powertrain import cell_current_from_motion
from ..params import EVParams, ParameterError, PowertrainOptions

STATE_NAMES = ("h", "v", "V1", "V2", "S")
OBJECTIVES = ("heat", "energy")
G_SMOOTH_WIDTH = 0.01  # model acceleration; width of the smoothed g (aev_ocp.models.energy.g_smooth default)


@dataclass(frozen=True)
class FollowingWeights:
    """Stage-cost weights (PROBLEM.md §9 defaults w_Q = 1, w_V = 1, w_r = 1, w_a = 0.1)."""

    w_Q: float = 1.0  # PROBLEM.md §9
    w_V: float = 1.0  # PROBLEM.md §9
    w_r: float = 1.0  # PROBLEM.md §9
    w_a: float = 0.1  # PROBLEM.md §9

    def __post_init__(self) -> None:
        for nm in ("w_Q", "w_V", "w_r", "w_a"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ParameterError(f"FollowingWeights.{nm} = {v!r} is not allowed: must be a finite number >= 0")


@dataclass(frozen=True)
class FollowingBounds:
    """Bounds of PROBLEM.md §9 (model units): h ≥ h_min and v_min ≤ v ≤ v_max at nodes 1…N,
    a_min ≤ a ≤ a_max; |I| ≤ cell.max_current_A and disc ≥ 0 at the start of every interval."""

    h_min: float = 0.2  # PROBLEM.md §9 (2 m at L = 10 m)
    v_min: float = 0.0  # PROBLEM.md §9
    v_max: float = 2.0  # PROBLEM.md §9
    a_min: float = -3.0  # PROBLEM.md §9 (−7.5 m/s² at default units)
    a_max: float = 2.0  # PROBLEM.md §9 (5 m/s² at default units)

    def __post_init__(self) -> None:
        for nm in ("h_min", "v_min", "v_max", "a_min", "a_max"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ParameterError(f"FollowingBounds.{nm} = {v!r} is not allowed: must be finite")
        if self.v_min >= self.v_max:
            raise ParameterError(f"FollowingBounds.v_min = {self.v_min} must be < v_max = {self.v_max}")
        if self.a_min >= self.a_max:
            raise ParameterError(f"FollowingBounds.a_min = {self.a_min} must be < a_max = {self.a_max}")


def following_cell(z: Any, a: Any, ev: EVParams, smooth: PowertrainOptions | None = PowertrainOptions()) -> dict[str, Any]:
    """Current map for state z (model units) and acceleration a (model): I [A], disc [V²],
    Q [W per cell], Q_pack [W], Q_irr_pack [W], P_b [W]. ``smooth=None``: exact η switch."""
    u = ev.units
    h, v, V1, V2, S = (z[i] for i in range(5))
    cm = cell_current_from_motion(u.speed_to_si(v), u.accel_to_si(a), V1, V2, S, ev, smooth=smooth)
    I = cm["I"]
    Q = battery.heat_Q(V1, V2, I, ev.cell)
    n = ev.pack.n_cells
    return {"I": I, "disc": cm["disc"], "Q": Q, "Q_pack": n * Q,
            "Q_irr_pack": n * battery.heat_irreversible(V1, V2, I, ev.cell), "P_b": cm["P_b"]}


def following_ode(z: Any, a: Any, v_l_mean: Any, ev: EVParams,
                  smooth: PowertrainOptions | None = PowertrainOptions()) -> Any:
    """dz/dt in model time: ḣ = v̄_l − v (interval-mean leader speed), v̇ = a, and the cell ODE
    (paper eqs. V_1_V_2, change_SOC) scaled by the time unit T [s]."""
    c = following_cell(z, a, ev, smooth)
    dV1, dV2, dS = battery.cell_derivatives(z[2], z[3], c["I"], ev.cell)
    T = ev.units.time_s
    return ca.vertcat(v_l_mean - z[1], a, T * dV1, T * dV2, T * dS)


def following_stage_cost(z: Any, a: Any, v_l_hat: Any, weights: FollowingWeights, ev: EVParams,
                         smooth: PowertrainOptions | None = PowertrainOptions(),
                         objective: str = "heat") -> Any:
    """ℓ(z, a) of PROBLEM.md §9 [model units; multiply by dt in model time]:
    w_Q Q_pack/(1 kW) + w_V (V(h) − v)² + w_r (v̂_l − v)² + w_a a².
    objective='energy' uses v g̃(a) (smoothed g, η = ev.vehicle.efficiency) in place of Q_pack/(1 kW)."""
    return sum(following_stage_terms(z, a, v_l_hat, weights, ev, smooth, objective).values())


def following_stage_terms(z: Any, a: Any, v_l_hat: Any, weights: FollowingWeights, ev: EVParams,
                          smooth: PowertrainOptions | None = PowertrainOptions(),
                          objective: str = "heat") -> dict[str, Any]:
    """The four weighted terms of ℓ separately: 'energy', 'ovm', 'relative', 'accel'."""
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective = {objective!r} is not allowed: must be one of {OBJECTIVES}")
    h, v = z[0], z[1]
    if objective == "heat":
        e = following_cell(z, a, ev, smooth)["Q_pack"] / 1000.0
    else:
        e = v * energy.g_smooth(a, ev.vehicle.efficiency, G_SMOOTH_WIDTH)
    return {"energy": weights.w_Q * e, "ovm": weights.w_V * (optimal_velocity(h) - v) ** 2,
            "relative": weights.w_r * (v_l_hat - v) ** 2, "accel": weights.w_a * a**2}


def following_path_constraints(z: Any, a: Any, ev: EVParams,
                               smooth: PowertrainOptions | None = PowertrainOptions()) -> tuple[Any, list[float], list[float]]:
    """Constraints at the start of every interval (PROBLEM.md §9): c = (I [A], disc [V²]) with
    −I_max ≤ I ≤ I_max and disc ≥ 0. Returns (c, lb, ub)."""
    c = following_cell(z, a, ev, smooth)
    Imax = ev.cell.max_current_A
    return ca.vertcat(c["I"], c["disc"]), [-Imax, 0.0], [Imax, ca.inf]


def following_state_bounds(bounds: FollowingBounds) -> tuple[list[float], list[float]]:
    """Simple bounds on z at nodes 1…N (PROBLEM.md §9): h ≥ h_min, v_min ≤ v ≤ v_max, S ∈ [0, 1]."""
    inf = ca.inf
    return [bounds.h_min, bounds.v_min, -inf, -inf, 0.0], [inf, bounds.v_max, inf, inf, 1.0]


def following_functions(ev: EVParams, weights: FollowingWeights,
                        smooth: PowertrainOptions | None = PowertrainOptions(),
                        objective: str = "heat") -> dict[str, ca.Function]:
    """SX Functions of (z, a, w, p) with w = (v̄_l interval-mean, v̂_l(t_k)) and p empty:
    'ode', 'stage', 'path', 'outputs' (I, Q, Q_pack, Q_irr_pack, disc, ell)."""
    z, a, w, p = ca.SX.sym("z", 5), ca.SX.sym("a"), ca.SX.sym("w", 2), ca.SX.sym("p", 0)
    args, names = [z, a, w, p], ["x", "u", "w", "p"]
    cell = following_cell(z, a, ev, smooth)
    ell = following_stage_cost(z, a, w[1], weights, ev, smooth, objective)
    path, _, _ = following_path_constraints(z, a, ev, smooth)
    return {
        "ode": ca.Function("follow_ode", args, [following_ode(z, a, w[0], ev, smooth)], names, ["zdot"]),
        "stage": ca.Function("follow_stage", args, [ell], names, ["ell"]),
        "path": ca.Function("follow_path", args, [path], names, ["c"]),
        "outputs": ca.Function("follow_out", args, [cell["I"], cell["Q"], cell["Q_pack"], cell["Q_irr_pack"],
                                                    cell["disc"], ell], names,
                               ["I", "Q", "Q_pack_W", "Q_irr_pack_W", "disc", "ell"]),
    }

"""Powertrain and the current map between vehicle motion and cell current (model guide §5, §7).

Between wheel and battery (``VehicleParams.powertrain``):

* ``"constant"`` — the paper's η switch, P_b = P_w/η (P_w > 0) or η P_w (P_w ≤ 0), plus P_aux: the default and
  what the paper's reproduction uses (unchanged, bit for bit);
* ``"map"`` — the 2022 Tesla Model 3 RWD of NREL FASTSim 3.1 (vehicle file "2022 Tesla Model 3 RWD thrml.yaml"):
  a transmission of efficiency η_t, the motor + inverter efficiency η_m over the motor's output power fraction
  x = |P_m| / P_max (FASTSim's em.eff_interp_achieved: its map is a function of shaft power, i.e. of speed × torque,
  not of either alone), interpolated linearly between FASTSim's grid points and held at x > 1; in traction
  P_m = P_w/η_t and P_b = P_m/η_m(x); in braking the motor recuperates P_m = max(η_t P_w, −P_regen,max) at
  η_r (``regen_efficiency``; None: η_m(x)) and the friction brakes take the rest (``powertrain_flows``).

Both are exact (kinks, switches) for the plants and smooth for optimisers (:class:`~aev_ocp.params.PowertrainOptions`):
the sign switch is blended with σ = ½(1 + tanh(P_w / w)) as before, max(z, 0) of the piecewise-linear map becomes
½(z + sqrt(z² + w_x²)) with w_x = w / P_max, |P_m| becomes sqrt(P_m² + w²) and the regenerative limit a smooth
minimum; :data:`SMOOTH_MAP_TOLERANCE` states how far the smooth map may be from the exact one.

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

#: FASTSim 3.1, 2022 Tesla Model 3 RWD, em.eff_interp_achieved: grid = motor output power fraction |P_m| / P_max [-]
MOTOR_MAP_POWER_FRACTION: tuple[float, ...] = (0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0)
#: ... and its values: motor + inverter efficiency [-] at those fractions (same file).
MOTOR_MAP_EFFICIENCY: tuple[float, ...] = (0.84, 0.86, 0.88, 0.90, 0.91, 0.92, 0.94, 0.95, 0.95, 0.94, 0.93)


def _map_slopes() -> list[float]:
    """Slopes of the piecewise-linear map on each interval, then 0 (held beyond x = 1) [1/-]."""
    xs, es = MOTOR_MAP_POWER_FRACTION, MOTOR_MAP_EFFICIENCY
    return [(es[k + 1] - es[k]) / (xs[k + 1] - xs[k]) for k in range(len(xs) - 1)] + [0.0]


#: Largest |smooth − exact| motor efficiency [-] per unit of w_x = w / P_max: Σ|slope changes| / 2 of the map
#: (each smoothed kink is within w_x / 2 of the exact one): 0.55, i.e. 7e-4 at the default w = 300 W, P_max = 239 kW.
SMOOTH_MAP_TOLERANCE = 0.5 * sum(abs(b - a) for a, b in zip(_map_slopes()[:-1], _map_slopes()[1:]))


def _relu(z: Any, w: float | None) -> Any:
    """max(z, 0) (w None) or its smooth version ½(z + sqrt(z² + w²)), within w/2 of it."""
    return ca.fmax(z, 0.0) if w is None else 0.5 * (z + ca.sqrt(z * z + w * w))


def motor_efficiency(x: Any, width: float | None = None) -> Any:
    """Motor + inverter efficiency η_m [-] at the output power fraction x = |P_m| / P_max ≥ 0 (FASTSim 3.1's Model 3
    map): linear between the grid points, held at x ≥ 1; ``width`` (in x): the smooth map for optimisers (within
    SMOOTH_MAP_TOLERANCE · width of the exact one)."""
    xs, es = MOTOR_MAP_POWER_FRACTION, MOTOR_MAP_EFFICIENCY
    slopes = _map_slopes()
    eta = es[0] + slopes[0] * x
    for k in range(1, len(slopes)):  # η = η_0 + s_0 x + Σ_k (s_k − s_{k−1}) max(x − x_k, 0): exact linear interpolation
        ds = slopes[k] - slopes[k - 1]
        if ds != 0.0:
            eta = eta + ds * _relu(x - xs[k], width)
    return eta


def _map_battery_power_W(P_w: Any, p: VehicleParams, width_W: float | None) -> Any:
    """P_b of the map powertrain [W], exact (width_W None) or smooth (width_W: w [W])."""
    wx = None if width_W is None else width_W / p.motor_power_max_W
    eta_t = p.transmission_efficiency
    # traction: P_m = P_w / η_t > 0, P_b = P_m / η_m(P_m / P_max)
    Pm_t = P_w / eta_t
    mag_t = ca.fabs(Pm_t) if width_W is None else ca.sqrt(Pm_t * Pm_t + width_W * width_W)
    P_trac = Pm_t / motor_efficiency(mag_t / p.motor_power_max_W, wx)
    # braking: the motor recuperates min(η_t |P_w|, P_regen,max), the rest goes to the friction brakes
    lim = p.regen_power_max_W
    brake = -eta_t * P_w  # mechanical power offered to the motor [W] (> 0 when braking)
    if width_W is None:
        rec = ca.fmin(brake, lim)
    else:
        rec = 0.5 * (brake + lim - ca.sqrt((brake - lim) ** 2 + width_W * width_W))
    if p.regen_efficiency is not None:
        eta_r: Any = p.regen_efficiency
    else:
        mag_r = ca.fabs(rec) if width_W is None else ca.sqrt(rec * rec + width_W * width_W)
        eta_r = motor_efficiency(mag_r / p.motor_power_max_W, wx)
    P_regen = -eta_r * rec
    if width_W is None:
        return ca.if_else(P_w > 0, P_trac, P_regen) + p.aux_power_W
    sigma = 0.5 * (1 + ca.tanh(P_w / width_W))
    return sigma * P_trac + (1 - sigma) * P_regen + p.aux_power_W


def battery_power_W(P_w: Any, p: VehicleParams) -> Any:
    """Exact battery power P_b [W] of the wheel power P_w [W]: the paper's η switch (``powertrain = "constant"``:
    P_b = P_w/η if P_w > 0 else η P_w, plus P_aux; model guide §5) or the map powertrain (module docstring)."""
    if p.powertrain == "map":
        return _map_battery_power_W(P_w, p, None)
    return ca.if_else(P_w > 0, P_w / p.efficiency, p.efficiency * P_w) + p.aux_power_W


def battery_power_smooth_W(P_w: Any, p: VehicleParams, opts: PowertrainOptions | None = None) -> Any:
    """Smoothed battery power for optimisers (model guide §7) [W]: the η switch P_b = P_w (σ/η + (1−σ)η) + P_aux,
    σ = ½(1 + tanh(P_w / width)), or the smooth map powertrain with the same width."""
    w = (opts or PowertrainOptions()).smoothing_width_W
    if p.powertrain == "map":
        return _map_battery_power_W(P_w, p, w)
    sigma = 0.5 * (1 + ca.tanh(P_w / w))
    return P_w * (sigma / p.efficiency + (1 - sigma) * p.efficiency) + p.aux_power_W


def powertrain_flows(P_w: Any, p: VehicleParams) -> dict[str, Any]:
    """Where the exact wheel power P_w [W] comes from and goes [W], each from its own formula: P_b (battery,
    :func:`battery_power_W`), traction (wheel power delivered, max(P_w, 0)), regen (wheel power the motor takes when
    braking), friction (wheel power the brakes dissipate), loss (transmission + motor/inverter losses, both
    directions) and aux. Energy balances: P_b = traction + loss + aux − regen and max(−P_w, 0) = regen + friction."""
    brake = ca.fmax(-P_w, 0.0)
    traction = ca.fmax(P_w, 0.0)
    if p.powertrain == "map":
        eta_t = p.transmission_efficiency
        rec = ca.fmin(eta_t * brake, p.regen_power_max_W)  # mechanical power the motor recuperates
        regen = rec / eta_t
        friction = ca.fmax(eta_t * brake - p.regen_power_max_W, 0.0) / eta_t  # the rest: the friction brakes
        Pm = traction / eta_t
        eta_r = p.regen_efficiency if p.regen_efficiency is not None else motor_efficiency(rec / p.motor_power_max_W)
        loss = (
            (Pm - traction)  # transmission, traction
            + Pm * (1.0 / motor_efficiency(Pm / p.motor_power_max_W) - 1.0)  # motor + inverter, traction
            + (regen - rec)  # transmission, braking
            + (1.0 - eta_r) * rec  # motor + inverter, braking
        )
    else:
        eta = p.efficiency
        regen = brake
        friction = 0 * P_w
        loss = traction * (1.0 / eta - 1.0) + (1.0 - eta) * brake
    return {
        "P_b": battery_power_W(P_w, p),
        "traction": traction,
        "regen": regen,
        "friction": friction,
        "loss": loss,
        "aux": p.aux_power_W + 0 * P_w,
    }


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

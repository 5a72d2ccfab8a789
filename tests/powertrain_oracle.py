"""An independent NumPy model of FASTSim's 2022 Tesla Model 3 RWD powertrain for tests (written from FASTSim 3.1's
vehicle file "2022 Tesla Model 3 RWD thrml.yaml", not from aev_ocp.models.powertrain): wheel power of a constant-
acceleration interval, the battery power through transmission, motor map (np.interp) and regenerative limit."""

from __future__ import annotations

import numpy as np

from aev_ocp.params import VehicleParams

# FASTSim 3.1 Model 3 RWD em.eff_interp_achieved (grid: output power fraction; values: efficiency)
FRACTION = np.array([0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0])
EFFICIENCY = np.array([0.84, 0.86, 0.88, 0.9, 0.91, 0.92, 0.94, 0.95, 0.95, 0.94, 0.93])


def wheel_power(v: np.ndarray, a: float, p: VehicleParams) -> np.ndarray:
    """(m + m_rot) a v + (C_r m g + ½ ρ C_d A v²) v on a flat road [W]."""
    drag = 0.5 * p.air_density_kgpm3 * p.drag_coefficient * p.frontal_area_m2
    return ((p.mass_kg + p.rotating_mass_kg) * a + p.rolling_coefficient * p.mass_kg * p.gravity_mps2 + drag * v**2) * v


def battery_power(Pw: np.ndarray, p: VehicleParams) -> np.ndarray:
    """P_b [W] of the wheel power P_w [W]: the paper's η switch or the map powertrain."""
    Pw = np.asarray(Pw, float)
    if p.powertrain == "constant":
        return np.where(Pw > 0, Pw / p.efficiency, Pw * p.efficiency) + p.aux_power_W
    et, Pmax = p.transmission_efficiency, p.motor_power_max_W
    Pm = np.abs(Pw) / et
    trac = Pm / np.interp(np.minimum(Pm / Pmax, 1.0), FRACTION, EFFICIENCY)
    rec = np.minimum(et * np.abs(Pw), p.regen_power_max_W)
    er = (
        p.regen_efficiency
        if p.regen_efficiency is not None
        else np.interp(np.minimum(rec / Pmax, 1.0), FRACTION, EFFICIENCY)
    )
    return np.where(Pw > 0, trac, -er * rec) + p.aux_power_W

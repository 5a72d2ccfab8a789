"""Longitudinal vehicle model (paper §3.3, model guide §5), SI units.

Functions accept floats, numpy arrays or CasADi expressions.
"""

from __future__ import annotations

import math
from typing import Any

from ..params import VehicleParams


def road_load_force_N(v_mps: Any, p: VehicleParams) -> Any:
    """Resistive force F_res(v) = ½ρAC_d v² + C_r m g + m g sin θ [N] (paper eqs. air_drag–graviational_force)."""
    return (
        0.5 * p.air_density_kgpm3 * p.frontal_area_m2 * p.drag_coefficient * v_mps**2
        + p.rolling_coefficient * p.mass_kg * p.gravity_mps2
        + p.mass_kg * p.gravity_mps2 * math.sin(p.grade_rad)
    )


def inertial_mass_kg(p: VehicleParams) -> float:
    """Mass that the acceleration moves, m + m_rot [kg] (m_rot: the wheels' inertia as an equivalent mass)."""
    return p.mass_kg + p.rotating_mass_kg


def wheel_power_W(v_mps: Any, a_mps2: Any, p: VehicleParams) -> Any:
    """Wheel power P_w = (m a + F_res(v)) v [W] (paper eq. p_output_dynamic_motoer); with ``rotating_mass_kg`` > 0
    the acceleration moves m + m_rot (the wheels' inertia), else exactly the paper's expression."""
    m = p.mass_kg if p.rotating_mass_kg == 0 else inertial_mass_kg(p)
    return (m * a_mps2 + road_load_force_N(v_mps, p)) * v_mps

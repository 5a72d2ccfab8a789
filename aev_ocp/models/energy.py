"""The paper's energy consumption per unit mass (paper eqs. energy_consumption, g_function).

ω = ∫ v g(v̇) dt with the leaky ReLU g(u) = u/η for u ≥ 0, η u for u < 0 (model units: U²).
"""

from __future__ import annotations

from typing import Any

import casadi as ca


def g_exact(u: Any, eta: float) -> Any:
    """g(u) = u/η (u ≥ 0), η u (u < 0) — exact, non-smooth at u = 0."""
    return ca.if_else(u >= 0, u / eta, eta * u)


def g_smooth(u: Any, eta: float, width: float = 0.01) -> Any:
    """Smoothed g for optimisers: u (σ/η + (1 − σ) η), σ = ½(1 + tanh(u / width)); width in model acceleration."""
    sigma = 0.5 * (1 + ca.tanh(u / width))
    return u * (sigma / eta + (1 - sigma) * eta)

"""Discretisation helpers shared by the transcription, the MPC and the initial-guess rollouts."""

from __future__ import annotations

from typing import Any, Callable


def rk4(f: Callable[[Any], Any], x: Any, h: Any, substeps: int = 1,
        g: Callable[[Any], Any] | None = None) -> tuple[Any, Any]:
    """Classical Runge–Kutta 4 over one interval of length h with ``substeps`` equal steps.

    f(x) -> ẋ; g(x) -> integrand of an optional quadrature ∫g dt over the interval (same stages).
    Works on floats, NumPy arrays and CasADi SX/MX. Returns (x(h), ∫g) (∫g is 0 without g).
    """
    dt = h / substeps
    q: Any = 0
    for _ in range(substeps):
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        if g is not None:
            q = q + dt / 6 * (g(x) + 2 * g(x + dt / 2 * k1) + 2 * g(x + dt / 2 * k2) + g(x + dt * k3))
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x, q

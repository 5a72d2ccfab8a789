"""Discretisation helpers shared by the transcription, the MPC and the initial-guess rollouts, and the least-squares
slope the forecasts and the ring's measurements fit."""

from __future__ import annotations

from typing import Any, Callable, Literal

# How far a sample may be beyond a bound [model units: length for a gap, speed for a speed] and still count as on it:
# the tolerance a controller's plan is accepted with (aev_ocp.plant.PLAN_TOLERANCE is this number). A plan that
# keeps its gap floor to this tolerance is a feasible plan to the solver; counting the plant's samples against a
# tighter one labelled a run 'violated' for 3.5e-8 m below a 3 m floor (2.3e-9 in model length), a solver's rounding.
BOUND_TOLERANCE = 1e-6


def rk4(
    f: Callable[[Any], Any], x: Any, h: Any, substeps: int = 1, g: Callable[[Any], Any] | None = None
) -> tuple[Any, Any]:
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


def bracketed_root(
    f: Callable[[float], float],
    a: float,
    b: float,
    xtol: float = 1e-13,
    max_iter: int = 200,
    *,
    side: Literal["nearest", "b"] = "nearest",
) -> float:
    """The root of a continuous scalar f on [a, b] where f(a) and f(b) differ in sign (or one is 0), by the
    Illinois variant of regula falsi with a bisection step every third iteration (so the bracket at least halves
    every three steps; no SciPy at run time); stops when the bracket is shorter than ``xtol`` (relative to
    max(1, |x|)) or f is exactly 0, and returns the end with the smaller |f|.

    ``side="b"``: the sides are f < 0 and f ≥ 0 (a zero is not a root but a value on the non-negative side), f(a)
    and f(b) must be on different sides, and the end returned is the one of the last bracket on f(b)'s side, e.g.
    the time where an event rule fires when f(b) is a sample where it fires."""
    fa, fb = f(a), f(b)
    nearest = side == "nearest"
    if nearest and fa == 0.0:
        return a
    if nearest and fb == 0.0:
        return b
    if (fa < 0.0) == (fb < 0.0):
        raise ValueError(f"bracketed_root: f({a!r}) = {fa!r} and f({b!r}) = {fb!r} have the same sign")
    wa, wb = fa, fb  # the secant's weights (Illinois halves the weight of an end that stays)
    for k in range(max_iter):
        if abs(b - a) <= xtol * max(1.0, abs(a), abs(b)):
            break
        x = (a * wb - b * wa) / (wb - wa) if k % 3 != 2 else 0.5 * (a + b)
        if not (min(a, b) < x < max(a, b)):
            x = 0.5 * (a + b)
        fx = f(x)
        if nearest and fx == 0.0:
            return x
        if (fx < 0.0) != (fa < 0.0):  # the root is in [a, x]: b moves, a stays (signs compared: no underflow)
            b, fb, wb = x, fx, fx
            wa *= 0.5
        else:  # the root is in [x, b]
            a, fa, wa = x, fx, fx
            wb *= 0.5
    return b if not nearest or abs(fb) < abs(fa) else a


def trapezoid(y: Any, x: Any) -> float:
    """∫ y dx by the trapezoid rule on samples (y, x) (1-D). np.trapezoid is numpy >= 2 only and np.trapz is gone
    from numpy 2.4; the toolkit supports numpy >= 1.24 (the life extra runs on numpy 1.26), so it is written out."""
    import numpy as np

    yy, xx = np.asarray(y, float).ravel(), np.asarray(x, float).ravel()
    return float(np.sum(0.5 * (yy[1:] + yy[:-1]) * np.diff(xx))) if yy.size > 1 else 0.0


def integrate_held(F: Any, x0: Any, inputs: Any, steps: Any) -> tuple[Any, Any]:
    """Run an integrator Function ``F`` (x0, p = [u_k, h_k]) -> (xf, qf) over consecutive intervals with input
    u_k held over a step of length h_k; returns (end state, sum of the intervals' quadratures) as 1-D arrays."""
    import numpy as np

    xk = np.asarray(x0, float).ravel()
    q = np.zeros(F.size1_out("qf"))
    for uk, hk in zip(inputs, steps):
        out = F(x0=xk, p=[uk, hk])
        xk = np.asarray(out["xf"]).ravel()
        q += np.asarray(out["qf"]).ravel()
    return xk, q


def least_squares_slope(t: Any, v: Any) -> float:
    """The slope of the least-squares line through (t_i, v_i) [v's unit per t's unit], 0 for fewer than two points
    or a single time: Σ(t − t̄)(v − v̄) / Σ(t − t̄)², the closed form of ``np.polyfit(t, v, 1)[0]`` (the same
    problem, solved there by an SVD: 20 µs a call on a five-sample window against 8 µs here; every MPC step calls it)."""
    import numpy as np

    tt, vv = np.asarray(t, float).ravel(), np.asarray(v, float).ravel()
    if tt.size < 2:
        return 0.0
    dt = tt - tt.mean()
    den = float(dt @ dt)
    return float(dt @ (vv - vv.mean())) / den if den > 0 else 0.0

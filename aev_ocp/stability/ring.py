"""Linear stability of uniform flow on a ring of n identical vehicles, mode by mode, and its n → ∞ limit.

Uniform flow: every gap h* = L/n − ℓ, every speed v* with f(h*, v*, v*) = 0. With f_h, f_v (at fixed Δv) and
f_Δv the exact partials of the law (CasADi, :func:`aev_ocp.stability.linear.partials_function`) the linearised
ring is, for deviations (η_i, ν_i) of gap and speed (vehicle i follows i − 1, indices mod n),

    η̇_i = ν_{i−1} − ν_i,     τ ν̈_i + ν̇_i = f_h η_i + (f_v − f_Δv) ν_i + f_Δv ν_{i−1}

(τ the actuator lag when the vehicle has one, else the second equation is first order). The system is circulant,
so the Fourier modes η_i, ν_i ∝ e^{iθ_k i}, θ_k = 2πk/n, k = 0 … n − 1, decouple: with z = e^{−iθ_k}
(ν_{i−1} = z ν_i) and λη = (z − 1)ν, each mode's eigenvalues are the roots of

    τ λ³ + λ² + (f_Δv (1 − z) − f_v) λ + f_h (1 − z) = 0      (τ = 0: the quadratic).

k = 0 gives λ = 0 (a gap pattern with the same sum: uniform shift) and λ = f_v (a common speed change). The
ring's growth rate is the largest Re λ over k = 1 … n − 1; its wavelength L/min(k, n − k) and its wave speed
v* + s Im λ / θ_k (s = L/n; the phase moves back through the vehicles). As n → ∞ the θ_k fill (0, 2π), so the
limit is the supremum of Re λ(θ) over θ ∈ (0, π]: positive iff the head-to-tail criterion
C = f_v²/2 − f_Δv f_v − f_h of :mod:`aev_ocp.stability.linear` is negative (the long waves θ → 0 grow at
Re λ ≈ −(f_h C / f_v³) θ², from expanding the quadratic's small root to second order in θ).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import casadi as ca
import numpy as np

from ..models.carfollowing import CarFollowingLaw
from ..numerics import least_squares_slope
from ..params import EVParams, ParameterError
from .linear import head_to_tail_criterion, partials_function
from ..ring.simulate import _equilibrium_speed


@dataclass(frozen=True)
class RingStability:
    """Linear stability of uniform flow on a ring (SI unless ``_model``). ``modes``: per k, the eigenvalues
    [1/s] as [re, im] pairs; growth_rate_per_s: max Re λ over k ≥ 1 (> 0: uniform flow is unstable);
    most_unstable_k, wavelength_m, wave_speed_mps of that mode; limit_growth_rate_per_s: the n → ∞ supremum and
    limit_theta its θ; criterion_per_s2: the head-to-tail C (≥ 0: string stable)."""

    law: str
    n: int
    length_m: float
    gap_m: float
    v_star_mps: float
    f_h_per_s2: float
    f_v_per_s: float
    f_dv_per_s: float
    lag_s: float
    modes: list[list[list[float]]]
    growth_rate_per_s: float
    most_unstable_k: int
    wavelength_m: float
    wave_speed_mps: float
    limit_growth_rate_per_s: float
    limit_theta: float
    criterion_per_s2: float
    string_stable: bool
    ring_stable: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return asdict(self)


def mode_polynomial(f_h: float, f_v: float, f_dv: float, theta: float, tau: float = 0.0) -> np.ndarray:
    """Coefficients (highest first) of the characteristic polynomial of mode θ (any consistent time unit)."""
    w = 1.0 - np.exp(-1j * theta)
    quad = [1.0, f_dv * w - f_v, f_h * w]
    return np.array([tau, *quad], complex) if tau > 0 else np.array(quad, complex)


def mode_eigenvalues(f_h: float, f_v: float, f_dv: float, theta: float, tau: float = 0.0) -> np.ndarray:
    """Eigenvalues of mode θ (closed form for τ = 0, the quadratic formula; cubic roots otherwise)."""
    c = mode_polynomial(f_h, f_v, f_dv, theta, tau)
    if tau > 0:
        return np.roots(c)
    b, cc = c[1], c[2]
    d = np.sqrt(b * b - 4 * cc + 0j)
    return np.array([(-b + d) / 2, (-b - d) / 2])


def _max_re(f_h: float, f_v: float, f_dv: float, theta: float, tau: float) -> float:
    return float(np.max(mode_eigenvalues(f_h, f_v, f_dv, theta, tau).real))


def limit_growth(f_h: float, f_v: float, f_dv: float, tau: float = 0.0, grid: int = 1201) -> tuple[float, float]:
    """(sup over θ ∈ (0, π] of max Re λ(θ), the θ) — the n → ∞ ring (grid, then golden-section refinement)."""
    th = np.linspace(0.0, math.pi, grid)[1:]
    vals = np.array([_max_re(f_h, f_v, f_dv, t, tau) for t in th])
    j = int(np.argmax(vals))
    a, b = th[max(j - 1, 0)] if j > 0 else 1e-12, th[min(j + 1, th.size - 1)]
    g = (math.sqrt(5) - 1) / 2
    for _ in range(80):
        c, d = b - g * (b - a), a + g * (b - a)
        if _max_re(f_h, f_v, f_dv, c, tau) > _max_re(f_h, f_v, f_dv, d, tau):
            b = d
        else:
            a = c
    t = 0.5 * (a + b)
    return max(float(vals[j]), _max_re(f_h, f_v, f_dv, t, tau)), t


def uniform_state(
    law: CarFollowingLaw, n: int, length_m: float, vehicle_length_m: float, ev: EVParams
) -> tuple[float, float]:
    """(h*, v*) of uniform flow [model units]: h* = L/n − ℓ and the law's equilibrium speed there."""
    u = ev.units
    gap_m = length_m / n - vehicle_length_m
    if not gap_m > 0:
        raise ParameterError(
            f"ring stability: spacing {length_m / n:g} m leaves no gap between vehicles of {vehicle_length_m:g} m"
        )
    h = float(u.length_from_si(gap_m))
    v = _equilibrium_speed(law, h, float(u.speed_from_si(ev.limits.v_max_mps)))
    return h, v


def ring_stability(
    law: CarFollowingLaw, n: int, length_m: float, vehicle_length_m: float = 5.0, ev: EVParams | None = None
) -> RingStability:
    """Mode-by-mode stability of uniform flow of ``law`` on a ring of n vehicles and length L [m]."""
    if not (isinstance(n, int) and not isinstance(n, bool) and n >= 2):
        raise ParameterError(f"ring stability: n = {n!r} is not allowed: must be an integer >= 2")
    if not (isinstance(length_m, (int, float)) and math.isfinite(length_m) and length_m > 0):
        raise ParameterError(f"ring stability: length_m = {length_m!r} is not allowed: must be a finite number > 0")
    if not (isinstance(vehicle_length_m, (int, float)) and math.isfinite(vehicle_length_m) and vehicle_length_m >= 0):
        raise ParameterError(
            f"ring stability: vehicle_length_m = {vehicle_length_m!r} is not allowed: must be a finite number >= 0"
        )
    ev = ev or EVParams()
    u = ev.units
    T = u.time_s
    h, v = uniform_state(law, n, length_m, vehicle_length_m, ev)
    if not v > 0:
        raise ParameterError(
            f"ring stability: law {law.name!r} has no moving uniform flow at gap "
            f"{length_m / n - vehicle_length_m:g} m (its equilibrium speed is 0)"
        )
    _, fh, fv, fdv = (float(x) for x in partials_function(law)(h, v, v))
    tau = float(u.time_from_si(ev.limits.actuator_tau_s)) if ev.limits.has_actuator_state else 0.0
    modes: list[list[list[float]]] = []
    best, best_k, best_lam = -math.inf, 0, 0j
    for k in range(n):
        theta = 2 * math.pi * k / n
        lam = mode_eigenvalues(fh, fv, fdv, theta, tau) / T
        modes.append([[float(x.real), float(x.imag)] for x in lam])
        if k > 0:
            j = int(np.argmax(lam.real))
            if lam[j].real > best + 1e-15:
                best, best_k, best_lam = float(lam[j].real), k, complex(lam[j])
    lim, lim_theta = limit_growth(fh, fv, fdv, tau)
    kk = min(best_k, n - best_k)
    theta = 2 * math.pi * best_k / n
    theta = theta if theta <= math.pi else theta - 2 * math.pi
    s = length_m / n
    C = head_to_tail_criterion(fh, fv, fdv)
    return RingStability(
        law.name,
        n,
        float(length_m),
        float(u.length_to_si(h)),
        float(u.speed_to_si(v)),
        fh / T**2,
        fv / T,
        fdv / T,
        tau * T,
        modes,
        best,
        best_k,
        length_m / kk,
        float(u.speed_to_si(v)) + s * best_lam.imag / theta,
        lim / T,
        lim_theta,
        C / T**2,
        bool(C >= 0),
        bool(best <= 1e-12),
    )


def ring_jacobian(
    law: CarFollowingLaw, n: int, length_m: float, vehicle_length_m: float = 5.0, ev: EVParams | None = None
) -> np.ndarray:
    """The full Jacobian [1/s] of the ring's motion (h_i, v_i[, a_i]) at uniform flow, from CasADi applied to the
    whole ring's right-hand side (no Fourier analysis): the independent check of :func:`ring_stability`."""
    ev = ev or EVParams()
    u = ev.units
    h0, v0 = uniform_state(law, n, length_m, vehicle_length_m, ev)
    lag = ev.limits.has_actuator_state
    tau = float(u.time_from_si(ev.limits.actuator_tau_s)) if lag else 0.0
    H, V = ca.SX.sym("h", n), ca.SX.sym("v", n)
    A = ca.SX.sym("a", n) if lag else None
    rhs_h, rhs_v, rhs_a = [], [], []
    for i in range(n):
        p = (i - 1) % n
        f = law.accel(H[i], V[i], V[p])
        rhs_h.append(V[p] - V[i])
        if lag:
            assert A is not None
            rhs_v.append(A[i])
            rhs_a.append((f - A[i]) / tau)
        else:
            rhs_v.append(f)
    x = ca.vertcat(H, V, A) if A is not None else ca.vertcat(H, V)
    J = ca.Function("J", [x], [ca.jacobian(ca.vertcat(*rhs_h, *rhs_v, *rhs_a), x)])
    x0 = np.concatenate([np.full(n, h0), np.full(n, v0)] + ([np.zeros(n)] if lag else []))
    return np.asarray(J(x0)) / u.time_s


def measured_growth(
    law: CarFollowingLaw,
    n: int,
    length_m: float,
    vehicle_length_m: float = 5.0,
    ev: EVParams | None = None,
    amplitude_m: float = 1e-4,
    t_end_s: float | None = None,
    k: int | None = None,
) -> dict[str, Any]:
    """The growth rate [1/s] of a small perturbation measured in simulation (the compiled ring, rtol 1e-11):
    uniform flow plus mode k (default the most unstable) with gap amplitude ``amplitude_m``, set on that mode's
    eigenvector (the dominant root only), and the slope of log |Σ_i η_i e^{−iθ_k i}| fitted over the run."""
    from ..ring.simulate import RingInitial, RingOptions, RingRoad, RingSimulator

    ev = ev or EVParams()
    u = ev.units
    rs = ring_stability(law, n, length_m, vehicle_length_m, ev)
    k = rs.most_unstable_k if k is None else int(k)
    theta = 2 * math.pi * k / n
    lam_model = mode_eigenvalues(
        rs.f_h_per_s2 * u.time_s**2, rs.f_v_per_s * u.time_s, rs.f_dv_per_s * u.time_s, theta, rs.lag_s / u.time_s
    )
    lam = complex(lam_model[int(np.argmax(lam_model.real))])
    sigma = lam.real / u.time_s
    T_run = t_end_s if t_end_s is not None else min(600.0, max(20.0, 3.0 / max(abs(sigma), 1e-6)))
    idx = np.arange(n)
    phase = np.exp(1j * theta * idx)
    eta = np.real(amplitude_m * phase)  # gap deviation [m]
    z = np.exp(-1j * theta)
    nu_hat = (lam / u.time_s) * amplitude_m / (z - 1)  # λ η̂ = (z − 1) ν̂, in SI
    nu = np.real(nu_hat * phase)
    s = length_m / n
    gaps = rs.gap_m + eta
    x = np.empty(n)  # x_i = x_{i−1} − ℓ − h_i, x_0 = 0 (the gaps sum to L − nℓ: the ring closes)
    x[0] = 0.0
    for i in range(1, n):
        x[i] = x[i - 1] - vehicle_length_m - gaps[i]
    ring = RingRoad(length_m, tuple([law] * n), vehicle_length_m, ev)
    init = RingInitial(
        tuple((x % length_m).tolist()),
        tuple((rs.v_star_mps + nu).tolist()),
        None,
        f"uniform flow plus mode k = {k} with gap amplitude {amplitude_m:g} m",
    )
    res = RingSimulator(ring, RingOptions(rtol=1e-11, atol=1e-13, dt_out_s=max(T_run / 400, 0.05))).run(init, T_run)
    c = np.abs((res.gap_m - rs.gap_m) @ np.exp(-1j * theta * idx))
    t = res.t_s
    keep = c > 0
    slope = least_squares_slope(t[keep], np.log(c[keep]))
    _ = s
    return {
        "k": k,
        "predicted_per_s": sigma,
        "measured_per_s": slope,
        "t_end_s": T_run,
        "amplitude_m": amplitude_m,
        "relative_error": abs(slope - sigma) / abs(sigma) if sigma else math.nan,
        "status": res.status,
    }

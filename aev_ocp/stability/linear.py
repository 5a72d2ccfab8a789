"""Linear string-stability analysis of any car-following law at an equilibrium (model units).

Sign convention. A law is v̇ = f(h, v, v_l); we write it as f(h, v, Δv) with Δv = v_l − v (the
predecessor's speed minus one's own) and take, at the equilibrium (h*, v*, Δv = 0),

* f_h  = ∂f/∂h                        [1/model time²]
* f_v  = ∂f/∂v at fixed Δv           [1/model time]  (= ∂f/∂v|_{v_l} + ∂f/∂v_l)
* f_Δv = ∂f/∂Δv at fixed v = ∂f/∂v_l [1/model time]

all exact (CasADi's algorithmic derivatives of the law's own expression). For speed deviations
ṽ_{n−1} → ṽ_n the linearised follower has the transfer function

    G(s) = (f_Δv s + f_h) / (s² + (f_Δv − f_v) s + f_h),

platoon (local) stability is f_h > 0 and f_Δv − f_v > 0 (both poles in the left half plane), and

    |G(iω)|² − 1 = −ω² (ω² + 2 C) / |den|²,   C = f_v²/2 − f_Δv f_v − f_h,

so |G(iω)| ≤ 1 at every ω iff C ≥ 0 (the head-to-tail criterion of Wilson & Ward 2011; for OVM it
is Bando's α ≥ 2V'(h*)); if C < 0, |G| > 1 exactly on the band 0 < ω < sqrt(−2C), and its maximum
is in closed form (:func:`max_gain`). ``peak_gain`` = ∫|g(t)| dt (g the impulse response) bounds the
growth of the *peak* |ṽ| from one vehicle to the next (ℓ∞ string stability); it is 1 iff g ≥ 0.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import casadi as ca
import numpy as np

from ..models.carfollowing import CarFollowingLaw
from ..numerics import bracketed_root
from ..params import ParameterError, Units

_PARTIALS: dict[Any, ca.Function] = {}
_GRID = np.logspace(-4, 3, 600)  # gaps scanned for a sign change of f(h, v*, v*) [model length]


def partials_function(law: CarFollowingLaw) -> ca.Function:
    """CasADi Function (h, v, v_l) -> (f, f_h, f_v, f_dv) of ``law`` (f_v at fixed Δv; built once per law)."""
    key = (type(law), law)
    fn = _PARTIALS.get(key)
    if fn is None:
        h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("v_l")
        f = law.accel(h, v, vl)
        jac = ca.jacobian(f, ca.vertcat(h, v, vl))
        fn = ca.Function(
            f"{law.name}_partials",
            [h, v, vl],
            [f, jac[0], jac[1] + jac[2], jac[2]],
            ["h", "v", "v_l"],
            ["f", "f_h", "f_v", "f_dv"],
        )
        if len(_PARTIALS) > 4096:
            _PARTIALS.clear()
        _PARTIALS[key] = fn
    return fn


def _accel(law: CarFollowingLaw, h: float, v: float) -> float:
    return float(partials_function(law)(h, v, v)[0])


def _accel_on_grid(law: CarFollowingLaw, v: float) -> np.ndarray:
    key = ("grid", type(law), law)
    fn = _PARTIALS.get(key)
    if fn is None:
        h = ca.SX.sym("h")
        vv = ca.SX.sym("v")
        one = ca.Function("f", [h, vv], [law.accel(h, vv, vv)])
        fn = _PARTIALS[key] = one.map(_GRID.size)
    return np.asarray(fn(_GRID.reshape(1, -1), v)).ravel()


def equilibrium_gap_of(law: CarFollowingLaw, v_star: float, tol: float = 1e-13) -> float:
    """Equilibrium gap h* of ``law`` at speed v_star [model units]: the root of f(h, v*, v*) = 0.

    A bracketed solve, valid for any law (with or without an optimal-velocity function, e.g. IDM): the
    first sign change from f < 0 (too close: brake) to f > 0 on a log grid of h ∈ [1e-4, 1e3], then
    :func:`aev_ocp.numerics.bracketed_root` (Illinois) to |Δh| ≤ tol·max(1, h). Raises ParameterError if none exists.
    """
    if not (isinstance(v_star, (int, float)) and math.isfinite(v_star) and v_star >= 0):
        raise ParameterError(f"stability: speed v* = {v_star!r} is not allowed: must be a finite number >= 0")
    grid = _GRID
    fv = _accel_on_grid(law, float(v_star))
    idx = np.flatnonzero((fv[:-1] < 0) & (fv[1:] >= 0))
    if idx.size == 0:
        raise ParameterError(
            f"stability: law {law.name!r} has no equilibrium gap at speed v* = {v_star:g} "
            "(f(h, v*, v*) does not change sign for h in [1e-4, 1e3])"
        )
    a, b = float(grid[idx[0]]), float(grid[idx[0] + 1])
    return bracketed_root(lambda h: _accel(law, h, v_star), a, b, tol)


def transfer(f_h: float, f_v: float, f_dv: float, omega: np.ndarray | float) -> np.ndarray:
    """G(iω) = (f_Δv iω + f_h)/((iω)² + (f_Δv − f_v) iω + f_h), ω [rad/model time]."""
    s = 1j * np.asarray(omega, dtype=float)
    return (f_dv * s + f_h) / (s * s + (f_dv - f_v) * s + f_h)


def head_to_tail_criterion(f_h: float, f_v: float, f_dv: float) -> float:
    """C = f_v²/2 − f_Δv f_v − f_h [1/model time²]; C ≥ 0 ⟺ |G(iω)| ≤ 1 for all ω."""
    return 0.5 * f_v * f_v - f_dv * f_v - f_h


def max_gain(f_h: float, f_v: float, f_dv: float) -> tuple[float, float]:
    """(sup_ω |G(iω)|, the ω where it is reached) in closed form, for a locally stable follower.

    With x = ω², a = f_h, b = f_Δv², C the criterion: d|G|²/dx = 0 ⟺ b x² + 2a² x + 2a² C = 0, whose
    positive root, x = −2aC/(sqrt(a² − 2bC) + a), exists iff C < 0. Otherwise the supremum is |G(0)| = 1
    at ω = 0.
    """
    C = head_to_tail_criterion(f_h, f_v, f_dv)
    if C >= 0:
        return 1.0, 0.0
    a, b = f_h, f_dv * f_dv
    x = -2.0 * a * C / (math.sqrt(a * a - 2.0 * b * C) + a)  # = a (sqrt(a² − 2bC) − a)/b, no cancellation
    w = math.sqrt(max(x, 0.0))
    return float(abs(transfer(f_h, f_v, f_dv, w))), w


def impulse_response(f_h: float, f_v: float, f_dv: float, t: np.ndarray) -> np.ndarray:
    """g(t) of G(s) (speed-deviation impulse response), by the eigen-decomposition of its 2×2 realisation."""
    A = np.array([[0.0, 1.0], [-f_h, -(f_dv - f_v)]])
    B = np.array([0.0, 1.0])
    Cv = np.array([f_h, f_dv])
    lam, W = np.linalg.eig(A)
    if abs(lam[0] - lam[1]) < 1e-9 * (1 + abs(lam[0])):  # repeated pole: expm by series-free formula
        l0 = lam[0].real
        N = A - l0 * np.eye(2)
        tt = np.asarray(t, float)[:, None, None]
        E = np.exp(l0 * tt) * (np.eye(2) + N * tt)
        return np.einsum("i,kij,j->k", Cv, E, B)
    Winv = np.linalg.inv(W)
    cw, wb = Cv @ W, Winv @ B
    return np.real(np.exp(np.outer(np.asarray(t, float), lam)) @ (cw * wb))


def peak_gain(f_h: float, f_v: float, f_dv: float) -> float:
    """∫₀^∞ |g(t)| dt: the largest possible growth of sup_t |ṽ| from one vehicle to the next (ℓ∞ gain).

    g = Σ r_i e^{λ_i t} is integrated exactly between its sign changes (located by bisection)."""
    lam = np.roots([1.0, f_dv - f_v, f_h]).astype(complex)
    if lam.real.max() >= 0:
        return math.inf
    t_end = 60.0 / -lam.real.max()
    t = np.linspace(0.0, t_end, 20001)
    if abs(lam[0] - lam[1]) < 1e-6 * (1.0 + abs(lam[0])):  # (nearly) repeated pole: fine trapezoid
        g = np.abs(impulse_response(f_h, f_v, f_dv, t))
        return float(np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(t)))
    res = (f_dv * lam + f_h) / (lam - lam[::-1])  # residues of G at its poles

    def g_at(x: float) -> float:
        return float(np.real(np.sum(res * np.exp(lam * x))))

    def prim(x: float) -> float:  # ∫_0^x g
        return float(np.real(np.sum(res / lam * (np.exp(lam * x) - 1.0))))

    gs = np.real(np.exp(np.outer(t, lam)) @ res)
    cuts = [0.0]
    for k in np.flatnonzero(np.sign(gs[:-1]) * np.sign(gs[1:]) < 0):
        a, b = float(t[k]), float(t[k + 1])
        fa = g_at(a)
        for _ in range(60):
            m = 0.5 * (a + b)
            if (g_at(m) > 0) == (fa > 0):
                a = m
            else:
                b = m
        cuts.append(0.5 * (a + b))
    total = sum(abs(prim(b) - prim(a)) for a, b in zip(cuts[:-1], cuts[1:]))
    total += abs(float(np.real(np.sum(-res / lam))) - prim(cuts[-1]))  # tail to ∞
    return float(total)


@dataclass(frozen=True)
class LinearStability:
    """Linear analysis of one law at one equilibrium (model units; ω in rad/model time).

    criterion: C = f_v²/2 − f_Δv f_v − f_h (≥ 0: string stable); locally_stable: f_h > 0 and f_Δv > f_v;
    max_gain, omega_max_gain: sup_ω |G(iω)| and where; unstable_band: (0, sqrt(−2C)) where |G| > 1, or None;
    peak_gain: ∫|g| dt (ℓ∞ gain, 1 iff the impulse response never changes sign); poles: of G.
    """

    law: str
    v_star: float
    h_star: float
    f_h: float
    f_v: float
    f_dv: float
    criterion: float
    string_stable: bool
    locally_stable: bool
    max_gain: float
    omega_max_gain: float
    unstable_band: tuple[float, float] | None
    peak_gain: float
    poles: tuple[complex, complex]

    def gain(self, omega: np.ndarray | float) -> np.ndarray:
        """|G(iω)| at ω [rad/model time]."""
        return np.abs(transfer(self.f_h, self.f_v, self.f_dv, omega))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (poles as [re, im] pairs)."""
        d = asdict(self)
        d["poles"] = [[p.real, p.imag] for p in self.poles]
        d["unstable_band"] = list(self.unstable_band) if self.unstable_band else None
        return d

    def to_table(self, units: Units) -> dict[str, Any]:
        """JSON-ready, SI first: every dimensional field with its unit in the name (v_star_mps, h_star_m,
        f_h_per_s2, f_v_per_s, f_dv_per_s, criterion_per_s2, omega_max_gain_rad_per_s,
        unstable_band_rad_per_s, poles_per_s) converted with ``units`` (time unit T = L/U), then the
        dimensionless ones (string_stable, locally_stable, max_gain, peak_gain), then the model-unit values
        with a ``_model`` suffix."""
        d = self.to_dict()
        T = units.time_s
        per_s = {
            "f_h": ("f_h_per_s2", T**-2),
            "f_v": ("f_v_per_s", 1.0 / T),
            "f_dv": ("f_dv_per_s", 1.0 / T),
            "criterion": ("criterion_per_s2", T**-2),
            "omega_max_gain": ("omega_max_gain_rad_per_s", 1.0 / T),
        }
        out: dict[str, Any] = {
            "law": d["law"],
            "v_star_mps": float(units.speed_to_si(self.v_star)),
            "h_star_m": float(units.length_to_si(self.h_star)),
        }
        out.update({si: d[k] * f for k, (si, f) in per_s.items()})
        out["unstable_band_rad_per_s"] = [x / T for x in d["unstable_band"]] if d["unstable_band"] else None
        out["poles_per_s"] = [[re / T, im / T] for re, im in d["poles"]]
        out.update({k: d[k] for k in ("string_stable", "locally_stable", "max_gain", "peak_gain")})
        out.update(
            {
                f"{k}_model": d[k]
                for k in (
                    "v_star",
                    "h_star",
                    "f_h",
                    "f_v",
                    "f_dv",
                    "criterion",
                    "omega_max_gain",
                    "unstable_band",
                    "poles",
                )
            }
        )
        return out


def analyse(
    law: CarFollowingLaw, v_star: float, h_star: float | None = None, with_peak_gain: bool = True
) -> LinearStability:
    """Linear string and platoon stability of ``law`` at the equilibrium speed v_star [model speed].

    h_star: the equilibrium gap; default the root of f(h, v*, v*) = 0 (:func:`equilibrium_gap_of`).
    with_peak_gain: compute ∫|g| (a few ms; NaN when skipped, e.g. in large parameter maps).
    """
    h = equilibrium_gap_of(law, v_star) if h_star is None else float(h_star)
    _, fh, fv, fdv = (float(x) for x in partials_function(law)(h, v_star, v_star))
    if not all(math.isfinite(x) for x in (fh, fv, fdv)):
        raise ParameterError(f"stability: law {law.name!r} has non-finite derivatives at h = {h:g}, v = {v_star:g}")
    C = head_to_tail_criterion(fh, fv, fdv)
    local = fh > 0 and fdv - fv > 0
    r = np.roots([1.0, fdv - fv, fh])  # a monic quadratic: two roots
    poles = (complex(r[0]), complex(r[1]))
    if local:
        g, w = max_gain(fh, fv, fdv)
        pk = peak_gain(fh, fv, fdv) if with_peak_gain else math.nan
    else:
        g, w, pk = math.inf, math.nan, math.inf
    band = (0.0, math.sqrt(-2.0 * C)) if C < 0 else None
    return LinearStability(
        law.name, float(v_star), h, fh, fv, fdv, C, bool(C >= 0 and local), bool(local), g, w, band, pk, poles
    )


def analyse_speeds(law: CarFollowingLaw, speeds: Sequence[float]) -> list[LinearStability]:
    """:func:`analyse` at each equilibrium speed (model units)."""
    return [analyse(law, float(v)) for v in speeds]


@dataclass(frozen=True)
class LinearizedLaw(CarFollowingLaw):
    """The linearisation of a law at (h*, v*): v̇ = f_h (h − h*) + f_v (v − v*) + f_Δv (v_l − v).

    Simulated with the same simulator, it is the linear prediction of any perturbation response. Every field is
    required (a linearisation has no default operating point); :meth:`of` takes them from an analysis."""

    h_star: float
    v_star: float
    f_h: float
    f_v: float
    f_dv: float
    name = "linearized"

    @classmethod
    def of(cls, lin: LinearStability) -> "LinearizedLaw":
        """The linearised law of an analysis."""
        return cls(lin.h_star, lin.v_star, lin.f_h, lin.f_v, lin.f_dv)

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return self.f_h * (h - self.h_star) + self.f_v * (v - self.v_star) + self.f_dv * (v_l - v)

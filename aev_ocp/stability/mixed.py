"""Linear stability of a ring of *different* vehicles: AEVs among human drivers, any placement, lag and delay (SI).

Vehicle i follows vehicle i − 1 (indices mod n) and accelerates by its own law a_i = f_i(h_i, v_i, v_{i−1}) [m/s²].
At the ring's equilibrium every vehicle drives at one speed v* and keeps its own gap h_i*, f_i(h_i*, v*, v*) = 0,
and the spacings fill the ring, Σ_i (h_i* + ℓ_i) = L (ℓ_i the vehicle lengths): v* is the root of that sum.

With the exact partials at the equilibrium, f_h,i [1/s²], f_v,i [1/s] (at fixed Δv) and f_Δv,i [1/s] (as in
:mod:`aev_ocp.stability.linear`), an actuator lag τ_i (τ_i ȧ_i + a_i = commanded) and a reaction delay T_i (the law
sees the state T_i ago), the deviations (η_i, ν_i) of gap and speed obey

    η̇_i = ν_{i−1} − ν_i,    (τ_i d/dt + 1) ν̇_i(t) = [f_h,i η_i + (f_v,i − f_Δv,i) ν_i + f_Δv,i ν_{i−1}](t − T_i).

In Laplace form each vehicle passes its predecessor's speed on, D_i(λ) ν_i = N_i(λ) ν_{i−1}, with

    N_i(λ) = f_Δv,i λ + f_h,i,    D_i(λ) = λ² (1 + τ_i λ) e^{λ T_i} + (f_Δv,i − f_v,i) λ + f_h,i,

so going once around the ring the eigenvalues are the roots of the characteristic function

    χ(λ) = Π_i D_i(λ) − Π_i N_i(λ).

λ = 0 is always a root (the gaps' sum is fixed: moving every vehicle by the same distance changes nothing); the
ring is linearly stable when every other root has Re λ < 0. For identical vehicles χ factors into the Fourier
modes of :mod:`aev_ocp.stability.ring`; in general it does not, and the spectrum is computed from the state
matrix of the linearised ring (:func:`state_matrix`, its eigenvalues by LAPACK): exact when no vehicle has a delay.
A delay makes the spectrum infinite: the state matrix then carries a Padé approximant of e^{−λT_i} of a stated
order, and each of its rightmost eigenvalues is refined by Newton's method on χ itself, so the returned rightmost
roots satisfy the exact characteristic equation (|χ| at round-off, reported as ``residual``).

:func:`min_aev_count` and :func:`min_aev_gain` answer the design questions of mixed rings (cf. Cui, Seibold, Stern,
Work 2017, "Stabilizing traffic flow via a single autonomous vehicle", IEEE IV; Zheng, Wang, Shi, Li, Wang 2020,
"Smoothing traffic flow via control of autonomous vehicles", IEEE IoT J.): the fewest AEVs, evenly spread, that make
the ring linearly stable, and the smallest gain of a family of AEV laws that does.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from ..fastcall import column_call
from ..models.carfollowing import CarFollowingLaw
from ..numerics import bracketed_root
from ..params import ParameterError, Units

_GAPS_M = np.logspace(-3, 4, 1401)  # gaps scanned for each law's equilibrium [m]


@dataclass(frozen=True)
class LinearVehicle:
    """One vehicle of the linearised ring (SI): its law's partials at the equilibrium, lag and delay."""

    f_h_per_s2: float
    f_v_per_s: float
    f_dv_per_s: float
    lag_s: float = 0.0
    delay_s: float = 0.0
    gap_m: float = float("nan")  # its equilibrium gap (information only)
    name: str = "vehicle"

    def __post_init__(self) -> None:
        for k in ("f_h_per_s2", "f_v_per_s", "f_dv_per_s", "lag_s", "delay_s"):
            x = getattr(self, k)
            if not (isinstance(x, (int, float)) and math.isfinite(x)):
                raise ParameterError(f"LinearVehicle.{k} = {x!r} is not allowed: must be a finite number")
        for k in ("lag_s", "delay_s"):
            if getattr(self, k) < 0:
                raise ParameterError(f"LinearVehicle.{k} = {getattr(self, k)!r} is not allowed: must be >= 0")

    def N(self, lam: complex) -> complex:
        """N_i(λ) = f_Δv λ + f_h."""
        return self.f_dv_per_s * lam + self.f_h_per_s2

    def D(self, lam: complex) -> complex:
        """D_i(λ) = λ² (1 + τ λ) e^{λT} + (f_Δv − f_v) λ + f_h."""
        return (
            lam * lam * (1.0 + self.lag_s * lam) * np.exp(lam * self.delay_s)
            + (self.f_dv_per_s - self.f_v_per_s) * lam
            + self.f_h_per_s2
        )

    def dN(self, lam: complex) -> complex:
        return complex(self.f_dv_per_s)

    def dD(self, lam: complex) -> complex:
        tau, T = self.lag_s, self.delay_s
        e = np.exp(lam * T)
        return (2 * lam + 3 * tau * lam * lam + T * lam * lam * (1 + tau * lam)) * e + self.f_dv_per_s - self.f_v_per_s


def si_accel(law: CarFollowingLaw, units: Units | None = None) -> ca.Function:
    """The law as a CasADi Function (h [m], v [m/s], v_l [m/s]) -> a [m/s²]: a law with SI parameters of its own
    (``has_si``: OVM, OVFL, the proposed law, IDM) through its ``accel_si``; a law written in a simulator's model
    units through ``units`` (required then)."""
    h, v, vl = ca.SX.sym("h_m"), ca.SX.sym("v_mps"), ca.SX.sym("vl_mps")
    if getattr(law, "has_si", False):
        a = law.accel_si(h, v, vl)
    elif units is None:
        raise ParameterError(f"mixed ring: law {law.name!r} is written in model units: give its units")
    else:
        a = units.accel_to_si(law.accel(units.length_from_si(h), units.speed_from_si(v), units.speed_from_si(vl)))
    return ca.Function(f"{law.name}_si", [h, v, vl], [a], ["h_m", "v_mps", "vl_mps"], ["a_mps2"])


def _partials(fn: ca.Function) -> ca.Function:
    h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl")
    f = fn(h, v, vl)
    J = ca.jacobian(f, ca.vertcat(h, v, vl))
    return ca.Function("partials", [h, v, vl], [f, J[0], J[1] + J[2], J[2]])


def gap_scan(accel: ca.Function) -> ca.Function:
    """``accel`` mapped over the scanned gaps (:func:`equilibrium_gap_m`'s ``scan``): build it once per law and
    pass it to every call that scans that law (a CasADi map is built anew on each call otherwise)."""
    return accel.map(_GAPS_M.size)


def equilibrium_gap_m(accel: ca.Function, v_mps: float, scan: ca.Function | None = None) -> float:
    """The gap [m] at which ``accel`` holds speed v_mps behind a lead at the same speed: the first sign change of
    f(h, v, v) from braking to accelerating on h ∈ [1 mm, 10 km], then a bracketed root to 1e-13 (relative); 0 when
    it does not brake even at 1 mm. ``scan``: :func:`gap_scan` of ``accel`` (built here when not given)."""
    scan = gap_scan(accel) if scan is None else scan
    f = np.asarray(scan(_GAPS_M.reshape(1, -1), v_mps, v_mps)).ravel()
    if f[0] >= 0:  # holds the speed at any gap from 1 mm up (an OV law at standstill): bumper to bumper
        return 0.0
    idx = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0))
    if idx.size == 0:
        raise ParameterError(
            f"mixed ring: law {accel.name()!r} has no equilibrium gap at {v_mps:g} m/s (no sign change of "
            "f(h, v, v) for h in [1 mm, 10 km])"
        )
    a, b = float(_GAPS_M[idx[0]]), float(_GAPS_M[idx[0] + 1])
    f1 = column_call(accel)
    return bracketed_root(lambda h: f1.scalar(h, v_mps, v_mps), a, b, 1e-13)


class GapMemo:
    """Equilibrium gaps [m] of laws at speeds already solved (:func:`equilibrium_gap_m`, a pure function of the law and
    the speed) and each law's gap scan, kept for the analyses of one search (:func:`min_aev_count`,
    :func:`min_aev_gain`: every analysis scans the same speed grid for the same human law). It holds the laws it
    saw, so their ids name them for its whole life; results are those computed without it, bit for bit."""

    def __init__(self) -> None:
        self._gaps: dict[tuple[int, float], float] = {}
        self._scans: dict[int, tuple[ca.Function, ca.Function]] = {}

    def gap(self, accel: ca.Function, v_mps: float) -> float:
        """:func:`equilibrium_gap_m` of ``accel`` at ``v_mps``, computed once."""
        key = id(accel)
        if key not in self._scans:
            self._scans[key] = (accel, gap_scan(accel))
        v = float(v_mps)
        if (key, v) not in self._gaps:
            self._gaps[(key, v)] = equilibrium_gap_m(accel, v, self._scans[key][1])
        return self._gaps[(key, v)]


def equilibrium(
    accels: Sequence[ca.Function],
    length_m: float,
    vehicle_lengths_m: Sequence[float],
    v_max_mps: float,
    memo: GapMemo | None = None,
) -> tuple[float, np.ndarray]:
    """(v* [m/s], gaps h_i* [m]) of the mixed ring: the common speed whose equilibrium gaps fill the ring.

    The total spacing Σ (h_i*(v) + ℓ_i) is scanned on a speed grid of [0, v_max_mps] for the crossing of L, which is
    then bracketed to 1e-13; a ParameterError names the cause when the ring is too short or too long for any speed."""
    n = len(accels)
    if len(vehicle_lengths_m) != n:
        raise ParameterError(f"mixed ring: {len(vehicle_lengths_m)} vehicle lengths for {n} vehicles")

    distinct: dict[int, tuple[ca.Function, int]] = {}  # vehicles sharing one Function share its gap
    for f in accels:
        distinct[id(f)] = (f, distinct.get(id(f), (f, 0))[1] + 1)
    memo = GapMemo() if memo is None else memo  # one gap scan (a CasADi map) per law, not one per speed tried

    def excess(v: float) -> float:
        gaps = sum(k * memo.gap(f, v) for f, k in distinct.values())
        return gaps + float(sum(vehicle_lengths_m)) - length_m

    grid = np.linspace(0.0, v_max_mps, 65)
    vals = []
    for v in grid:
        try:
            vals.append(excess(float(v)))
        except ParameterError:
            vals.append(math.inf)  # a law that cannot hold this speed at any gap: the ring cannot either
    vals_a = np.asarray(vals)
    if vals_a[0] > 0:
        raise ParameterError(
            f"mixed ring: length_m = {length_m:g} is too short: at standstill the {n} vehicles need "
            f"{vals_a[0] + length_m:.6g} m"
        )
    idx = np.flatnonzero((vals_a[:-1] <= 0) & (vals_a[1:] > 0))
    if idx.size == 0:
        raise ParameterError(
            f"mixed ring: length_m = {length_m:g} is too long: the vehicles' equilibrium gaps do not fill it at "
            f"any speed up to v_max = {v_max_mps:g} m/s"
        )
    lo, hi = float(grid[idx[0]]), float(grid[idx[0] + 1])
    if not math.isfinite(vals_a[idx[0] + 1]):  # find a speed every law can hold where the spacings exceed L
        found = False
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            try:
                e = excess(mid)
            except ParameterError:
                hi = mid
                continue
            if e > 0:
                hi, found = mid, True
                break
            lo = mid
        if not found:
            raise ParameterError(
                f"mixed ring: length_m = {length_m:g} is too long: the vehicles' equilibrium gaps do not fill it "
                f"at any speed they can hold (up to {lo:.6g} m/s)"
            )
    v = bracketed_root(excess, lo, hi, 1e-13) if excess(lo) != 0 else lo
    gap = {key: memo.gap(f, v) for key, (f, _) in distinct.items()}
    return v, np.array([gap[id(f)] for f in accels])


def linearise(
    accels: Sequence[ca.Function],
    length_m: float,
    vehicle_lengths_m: Sequence[float],
    v_max_mps: float,
    lags_s: Sequence[float] | None = None,
    delays_s: Sequence[float] | None = None,
    names: Sequence[str] | None = None,
    memo: GapMemo | None = None,
) -> tuple[float, list[LinearVehicle]]:
    """(v* [m/s], the linearised vehicles) of a mixed ring at its equilibrium (exact partials by CasADi); ``memo``:
    the equilibrium gaps of an earlier analysis of the same laws (:class:`GapMemo`)."""
    n = len(accels)
    lags = [0.0] * n if lags_s is None else list(lags_s)
    delays = [0.0] * n if delays_s is None else list(delays_s)
    nm = [f.name() for f in accels] if names is None else list(names)
    v, gaps = equilibrium(accels, length_m, vehicle_lengths_m, v_max_mps, memo)
    out, partials = [], {id(f): _partials(f) for f in accels}
    for i, f in enumerate(accels):
        _, fh, fv, fdv = (float(x) for x in partials[id(f)](gaps[i], v, v))
        out.append(LinearVehicle(fh, fv, fdv, lags[i], delays[i], float(gaps[i]), nm[i]))
    return v, out


def _pade(T: float, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A state-space realisation (A, B, C, D) of the [order/order] Padé approximant of e^{−sT}."""
    m = order
    c = [math.factorial(2 * m - k) * math.factorial(m) / (math.factorial(2 * m) * math.factorial(k) *
         math.factorial(m - k)) * T**k for k in range(m + 1)]  # fmt: skip
    num = np.array([c[k] * (-1) ** k for k in range(m, -1, -1)])  # highest power first
    den = np.array([c[k] for k in range(m, -1, -1)])
    num, den = num / den[0], den / den[0]
    d = float(num[0])
    r = num[1:] - d * den[1:]  # strictly proper remainder
    A = np.zeros((m, m))
    A[0, :] = -den[1:]
    A[1:, :-1] = np.eye(m - 1)
    B = np.zeros((m, 1))
    B[0, 0] = 1.0
    C = r.reshape(1, -1)
    return A, B, C, d


def state_matrix(vehicles: Sequence[LinearVehicle], pade_order: int = 6) -> np.ndarray:
    """The linearised ring's state matrix: per vehicle (η_i, ν_i), an acceleration state when it has a lag, and
    ``pade_order`` states of a Padé approximant of its delay when it has one."""
    n = len(vehicles)
    if n < 2:
        raise ParameterError(f"mixed ring: needs at least 2 vehicles, got {n}")
    sizes = [2 + (p.lag_s > 0) + (pade_order if p.delay_s > 0 else 0) for p in vehicles]
    start = np.concatenate([[0], np.cumsum(sizes)])
    A = np.zeros((start[-1], start[-1]))
    for i, p in enumerate(vehicles):
        j = (i - 1) % n
        e, nu, nu_l = start[i], start[i] + 1, start[j] + 1
        A[e, nu_l] += 1.0
        A[e, nu] -= 1.0
        # the law's input u = f_h η + (f_v − f_Δv) ν + f_Δv ν_l, as a row over the state
        u = np.zeros(start[-1])
        u[e] += p.f_h_per_s2
        u[nu] += p.f_v_per_s - p.f_dv_per_s
        u[nu_l] += p.f_dv_per_s
        k = start[i] + 2
        if p.delay_s > 0:  # w = delayed u through the Padé states z: ż = Ap z + Bp u, w = Cp z + d u
            Ap, Bp, Cp, d = _pade(p.delay_s, pade_order)
            z = slice(k + (p.lag_s > 0), k + (p.lag_s > 0) + pade_order)
            A[z, z] = Ap
            A[z, :] += Bp @ u.reshape(1, -1)
            w = d * u
            w[z] += Cp.ravel()
        else:
            w = u
        if p.lag_s > 0:  # ν̇ = a, τ ȧ = w − a
            A[nu, k] = 1.0
            A[k, :] += w / p.lag_s
            A[k, k] -= 1.0 / p.lag_s
        else:
            A[nu, :] += w
    return A


def characteristic(vehicles: Sequence[LinearVehicle], lam: complex) -> tuple[complex, complex]:
    """(χ(λ), χ'(λ)) with χ = Π D_i − Π N_i (module docstring)."""
    Ds = [p.D(lam) for p in vehicles]
    Ns = [p.N(lam) for p in vehicles]
    dDs = [p.dD(lam) for p in vehicles]
    dNs = [p.dN(lam) for p in vehicles]

    def prod_and_derivative(vals: list[complex], ders: list[complex]) -> tuple[complex, complex]:
        P, dP = complex(1.0), complex(0.0)
        for x, dx in zip(vals, ders):
            P, dP = P * x, dP * x + P * dx
        return P, dP

    PD, dPD = prod_and_derivative(Ds, dDs)
    PN, dPN = prod_and_derivative(Ns, dNs)
    return PD - PN, dPD - dPN


@dataclass(frozen=True)
class MixedRingStability:
    """Linear stability of a mixed ring (SI). ``eigenvalues_per_s``: the rightmost ones as [re, im], largest
    real part first, the structural zero left out; ``growth_rate_per_s`` the largest real part (> 0: the uniform
    flow is unstable); ``frequency_rad_per_s`` its |Im λ|; ``residual``: max |χ(λ)| / scale over the reported
    eigenvalues (round-off for an exact spectrum); ``exact``: no delay (else the rightmost are Newton-refined roots
    of χ, the rest of the Padé order ``pade_order``)."""

    n: int
    v_star_mps: float
    gaps_m: list[float]
    names: list[str]
    growth_rate_per_s: float
    frequency_rad_per_s: float
    eigenvalues_per_s: list[list[float]]
    residual: float
    ring_stable: bool
    exact: bool
    pade_order: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return asdict(self)


def _refine(vehicles: Sequence[LinearVehicle], lam: complex, iters: int = 60) -> complex:
    for _ in range(iters):
        f, df = characteristic(vehicles, lam)
        if df == 0:
            break
        step = f / df
        lam -= step
        if abs(step) <= 1e-14 * max(1.0, abs(lam)):
            break
    return lam


def _scale(vehicles: Sequence[LinearVehicle], lam: complex) -> float:
    return max(
        float(abs(np.prod([p.D(lam) for p in vehicles]))), float(abs(np.prod([p.N(lam) for p in vehicles]))), 1e-300
    )


def spectrum(vehicles: Sequence[LinearVehicle], pade_order: int = 6, keep: int = 12) -> MixedRingStability:
    """The rightmost ``keep`` eigenvalues of the linearised ring and its growth rate (module docstring)."""
    if not (isinstance(pade_order, int) and 1 <= pade_order <= 20):
        raise ParameterError(f"mixed ring: pade_order = {pade_order!r} is not allowed: must be an integer in [1, 20]")
    A = state_matrix(vehicles, pade_order)
    lam = np.linalg.eigvals(A)
    exact = all(p.delay_s == 0 for p in vehicles)
    # the structural zero: the eigenvalue nearest 0 (exactly one: Σ η_i is conserved)
    z = int(np.argmin(np.abs(lam)))
    rest = np.delete(lam, z)
    rest = rest[np.argsort(-rest.real)][: max(keep, 1) * (1 if exact else 2)]
    if not exact:
        rest = np.array([_refine(vehicles, complex(x)) for x in rest])
        rest = rest[np.abs(rest) > 1e-9]
        # Newton may land two starts on one root: keep distinct roots
        uniq: list[complex] = []
        for x in rest[np.argsort(-rest.real)]:
            if all(abs(x - y) > 1e-8 * max(1.0, abs(x)) for y in uniq):
                uniq.append(complex(x))
        rest = np.array(uniq)
    rest = rest[np.argsort(-rest.real)][:keep]
    res = max((abs(characteristic(vehicles, complex(x))[0]) / _scale(vehicles, complex(x)) for x in rest), default=0.0)
    g = float(rest[0].real)
    return MixedRingStability(
        n=len(vehicles),
        v_star_mps=float("nan"),
        gaps_m=[p.gap_m for p in vehicles],
        names=[p.name for p in vehicles],
        growth_rate_per_s=g,
        frequency_rad_per_s=float(abs(rest[0].imag)),
        eigenvalues_per_s=[[float(x.real), float(x.imag)] for x in rest],
        residual=float(res),
        ring_stable=g < 0,
        exact=exact,
        pade_order=pade_order,
    )


def analyse_mixed_ring(
    accels: Sequence[ca.Function],
    length_m: float,
    vehicle_lengths_m: Sequence[float] | float,
    v_max_mps: float,
    lags_s: Sequence[float] | float = 0.0,
    delays_s: Sequence[float] | float = 0.0,
    names: Sequence[str] | None = None,
    pade_order: int = 6,
    memo: GapMemo | None = None,
) -> MixedRingStability:
    """Equilibrium, linearisation and spectrum of a ring of n = len(accels) vehicles (each an SI Function
    (h [m], v [m/s], v_l [m/s]) -> a [m/s²], e.g. from :func:`si_accel`); scalars apply to every vehicle. ``memo``: a
    :class:`GapMemo` shared by analyses of the same laws (the same result, faster)."""
    n = len(accels)
    if n < 2:
        raise ParameterError(f"mixed ring: needs at least 2 vehicles, got {n}")

    def per(x: Sequence[float] | float, what: str) -> list[float]:
        xs = [float(x)] * n if isinstance(x, (int, float)) else [float(y) for y in x]
        if len(xs) != n:
            raise ParameterError(f"mixed ring: {what} has {len(xs)} entries for {n} vehicles")
        return xs

    lengths = per(vehicle_lengths_m, "vehicle_lengths_m")
    if any(not (math.isfinite(x) and x >= 0) for x in lengths):
        raise ParameterError("mixed ring: vehicle_lengths_m must be finite numbers >= 0")
    if not (math.isfinite(length_m) and length_m > sum(lengths)):
        raise ParameterError(
            f"mixed ring: length_m = {length_m!r} is not allowed: must exceed the vehicles' total length "
            f"{sum(lengths):g} m"
        )
    v, lin = linearise(
        accels, length_m, lengths, v_max_mps, per(lags_s, "lags_s"), per(delays_s, "delays_s"), names, memo
    )
    s = spectrum(lin, pade_order)
    return MixedRingStability(**{**s.to_dict(), "v_star_mps": v})


def even_placement(n: int, m: int) -> list[int]:
    """Indices of m AEVs spread as evenly as possible over n vehicles (the first at index 0)."""
    if not (0 <= m <= n):
        raise ParameterError(f"mixed ring: {m} AEVs do not fit among {n} vehicles")
    return sorted({int(math.floor(k * n / m)) for k in range(m)}) if m else []


def min_aev_count(
    human: ca.Function,
    aev: ca.Function,
    n: int,
    length_m: float,
    vehicle_length_m: float,
    v_max_mps: float,
    human_lag_s: float = 0.0,
    human_delay_s: float = 0.0,
    aev_lag_s: float = 0.0,
    aev_delay_s: float = 0.0,
) -> tuple[int | None, list[float]]:
    """(the fewest AEVs, evenly placed, that make the ring linearly stable, or None if even n do not; the growth
    rate [1/s] for m = 0 … n AEVs, up to the first stable m)."""
    growth: list[float] = []
    memo = GapMemo()  # every count scans the same speeds for the same two laws
    for m in range(n + 1):
        idx = set(even_placement(n, m))
        acc = [aev if i in idx else human for i in range(n)]
        lags = [aev_lag_s if i in idx else human_lag_s for i in range(n)]
        dels = [aev_delay_s if i in idx else human_delay_s for i in range(n)]
        g = analyse_mixed_ring(acc, length_m, vehicle_length_m, v_max_mps, lags, dels, memo=memo).growth_rate_per_s
        growth.append(g)
        if g < 0:
            return m, growth
    return None, growth


def min_aev_gain(
    human: ca.Function,
    aev_of_gain: Callable[[float], ca.Function],
    aev_positions: Sequence[int],
    n: int,
    length_m: float,
    vehicle_length_m: float,
    v_max_mps: float,
    gain_range: tuple[float, float],
    human_lag_s: float = 0.0,
    human_delay_s: float = 0.0,
    tol: float = 1e-6,
) -> float | None:
    """The smallest gain k in ``gain_range`` for which AEVs ``aev_of_gain(k)`` at ``aev_positions`` make the ring
    linearly stable (bisection on the growth rate's sign, assumed to change once in the range); None if the
    range's upper end does not stabilise it; the lower end if it is already stable there."""
    pos = set(aev_positions)
    if any(not (0 <= i < n) for i in pos):
        raise ParameterError(f"mixed ring: aev_positions {sorted(pos)} are not all in 0 … {n - 1}")

    memo = GapMemo()  # every gain scans the same speeds for the same human law

    def growth(k: float) -> float:
        acc = [aev_of_gain(k) if i in pos else human for i in range(n)]
        lags = [0.0 if i in pos else human_lag_s for i in range(n)]
        dels = [0.0 if i in pos else human_delay_s for i in range(n)]
        return analyse_mixed_ring(acc, length_m, vehicle_length_m, v_max_mps, lags, dels, memo=memo).growth_rate_per_s

    lo, hi = gain_range
    if growth(hi) >= 0:
        return None
    if growth(lo) < 0:
        return lo
    while hi - lo > tol * max(1.0, abs(hi)):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if growth(mid) < 0 else (mid, hi)
    return hi

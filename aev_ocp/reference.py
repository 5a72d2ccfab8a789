"""An independent plain-NumPy/SciPy implementation of the platoon ODE, for verification and benchmarks.

It shares no code with :mod:`aev_ocp.simulate` beyond the parameter dataclasses and the OCV table:
the laws, the current map and the cell model are written out again in NumPy, and the system is
integrated with ``scipy.integrate.solve_ivp``. SciPy is a test/benchmark dependency only.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from .models.battery import ocv_table
from .params import CarFollowingParams, EVParams

TANH2 = math.tanh(2.0)


def paper_leader_speed(t: float, v0: float = 1.7, c: float = 1.65 / 1.37, t_end: float = 20.0) -> float:
    """The paper leader's speed, written independently of aev_ocp.models.leader."""
    tt = min(t, t_end)
    return v0 - c * (
        (1 - math.cos(0.5 * math.pi * tt)) / (0.5 * math.pi) + math.sin(3.2 * math.pi * tt) / (3.2 * math.pi)
    )


def law_accel(kind: str, p: CarFollowingParams, h: np.ndarray, v: np.ndarray, vl: np.ndarray) -> np.ndarray:
    """OVM / OVFL / proposed accelerations in NumPy."""
    a = p.alpha * (np.tanh(h - 2.0) + TANH2 - v)
    if kind in ("ovfl", "proposed"):
        a = a + p.beta * (vl - v) / h**2
    if kind == "proposed":
        d2 = (vl - v) ** 2
        a = a - p.kappa * v**2 * d2 / (d2 + p.eps)
    return a


def make_ocv_numpy(cell: Any = None) -> Callable[[np.ndarray], np.ndarray]:
    """Not-a-knot cubic spline of the cell's OCV table (scipy's CubicSpline), independent of CasADi's B-spline
    (None: the shipped A123 table)."""
    from scipy.interpolate import CubicSpline

    soc, ocv = ocv_table(cell)
    return CubicSpline(soc, ocv, bc_type="not-a-knot")


def platoon_rhs_factory(
    kind: str,
    n: int,
    leader_speed: Callable[[float], float],
    ev: EVParams,
    p: CarFollowingParams | None = None,
    battery: bool = True,
) -> Callable[[float, np.ndarray], np.ndarray]:
    """RHS f(t, y) with y = [h(n), v(n), V1, V2, S (n each if battery), ω(n), heat_J(n)]."""
    p = p or CarFollowingParams()
    u, veh, cell, pack = ev.units, ev.vehicle, ev.cell, ev.pack
    ocv = make_ocv_numpy(cell)
    T = u.time_s
    eta = veh.efficiency

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        h, v = y[:n], y[n : 2 * n]
        vl = np.empty(n)
        vl[0] = leader_speed(t)
        vl[1:] = v[:-1]
        a = law_accel(kind, p, h, v, vl)
        g = np.where(a >= 0, a / eta, eta * a)
        out = [vl - v, a]
        if battery:
            V1, V2, S = y[2 * n : 3 * n], y[3 * n : 4 * n], y[4 * n : 5 * n]
            vs, as_ = v * u.speed_mps, a * u.accel_mps2
            Fres = (
                0.5 * veh.air_density_kgpm3 * veh.frontal_area_m2 * veh.drag_coefficient * vs**2
                + veh.rolling_coefficient * veh.mass_kg * veh.gravity_mps2
                + veh.mass_kg * veh.gravity_mps2 * math.sin(veh.grade_rad)
            )
            Pw = (veh.mass_kg * as_ + Fres) * vs
            Pb = np.where(Pw > 0, Pw / eta, eta * Pw) + veh.aux_power_W
            Pc = Pb / (pack.n_series * pack.n_parallel)
            E = ocv(S) - V1 - V2
            I = 2 * Pc / (E + np.sqrt(np.maximum(E**2 - 4 * cell.R_s_ohm * Pc, 0.0)))
            Q = I * (V1 + V2) + cell.R_s_ohm * I**2
            out += [
                T * (-V1 / (cell.R1_ohm * cell.C1_F) + I / cell.C1_F),
                T * (-V2 / (cell.R2_ohm * cell.C2_F) + I / cell.C2_F),
                T * (-I / (3600 * cell.capacity_Ah)),
            ]
        out.append(v * g)
        if battery:
            out.append(T * pack.n_series * pack.n_parallel * Q)
        return np.concatenate(out)

    return rhs


def simulate_reference(
    kind: str,
    gaps0: np.ndarray,
    speeds0: np.ndarray,
    t_end: float,
    ev: EVParams | None = None,
    leader_speed: Callable[[float], float] = paper_leader_speed,
    breakpoints: tuple[float, ...] = (20.0,),
    rtol: float = 1e-10,
    atol: float = 1e-10,
    method: str = "DOP853",
    battery: bool = True,
    p: CarFollowingParams | None = None,
) -> dict[str, Any]:
    """Integrate the platoon with solve_ivp, split at the leader's breakpoints. Returns final ω, heat_J, S and nfev."""
    from scipy.integrate import solve_ivp

    ev = ev or EVParams()
    n = len(gaps0)
    rhs = platoon_rhs_factory(kind, n, leader_speed, ev, p, battery)
    y = np.concatenate(
        [gaps0, speeds0]
        + ([np.zeros(n), np.zeros(n), np.full(n, ev.cell.soc0)] if battery else [])
        + [np.zeros(n)]
        + ([np.zeros(n)] if battery else [])
    )
    cuts = [0.0] + [b for b in breakpoints if 0 < b < t_end] + [t_end]
    nfev = 0
    for a, b in zip(cuts[:-1], cuts[1:]):
        sol = solve_ivp(rhs, (a, b), y, method=method, rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(sol.message)
        y, nfev = sol.y[:, -1], nfev + sol.nfev
    k = 5 * n if battery else 2 * n
    out = {"omega": y[k : k + n], "gap": y[:n], "speed": y[n : 2 * n], "nfev": nfev}
    if battery:
        out.update(heat_J=y[k + n : k + 2 * n], S=y[4 * n : 5 * n])
    return out

"""2-RC equivalent-circuit cell (paper §3, model guide §6), SI units, time in seconds, I > 0 discharges.

The OCV curve is a cubic B-spline interpolant of the A123 ANR26650 table shipped in
``aev_ocp/data/a123_ocv_25C.csv`` (provenance in ``aev_ocp/data/README.md``).
"""

from __future__ import annotations

import csv
from contextlib import contextmanager
from contextvars import ContextVar
from functools import lru_cache
from importlib import resources
from typing import Any, Iterator

import casadi as ca
import numpy as np

from ..params import CellParams


@lru_cache(maxsize=1)
def ocv_table() -> tuple[np.ndarray, np.ndarray]:
    """The shipped OCV table: SOC [-] and OCV [V] at 25 °C."""
    path = resources.files("aev_ocp") / "data" / "a123_ocv_25C.csv"
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    return np.array([float(r["soc"]) for r in rows]), np.array([float(r["ocv_V"]) for r in rows])


@lru_cache(maxsize=1)
def ocv_function() -> ca.Function:
    """OCV(S) [V] as a CasADi cubic B-spline interpolant (model guide §6). Defined on S ∈ [0, 1];
    callers check S stays there (the simulator reports it, the optimisers constrain it)."""
    soc, ocv = ocv_table()
    return ca.interpolant("ocv", "bspline", [soc], ocv)


@lru_cache(maxsize=1)
def ocv_pieces() -> tuple[np.ndarray, np.ndarray]:
    """The B-spline of :func:`ocv_function` as its cubic pieces: breakpoints s_k (the table's SOC grid)
    and the coefficients (a_k, b_k, c_k, d_k) of OCV = a + b u + c u² + d u³, u = S − s_k, on
    [s_k, s_{k+1}] (fitted to the spline at four points per piece: it is exactly cubic there)."""
    soc, _ = ocv_table()
    f = ocv_function()
    coef = []
    for a, b in zip(soc[:-1], soc[1:]):
        us = (b - a) * np.array([0.0, 1 / 3, 2 / 3, 1.0])
        ys = np.asarray(f(ca.DM(a + us).T)).ravel()
        coef.append(np.linalg.solve(np.vander(us, 4, increasing=True), ys))
    return soc, np.array(coef)


def ocv_piecewise(S: Any) -> Any:
    """OCV(S) [V] as the same piecewise cubic written with comparisons: an SX expression whose
    derivatives are plain arithmetic (cheaper than B-spline calls in generated Hessians); equal to
    :func:`ocv_function` within 1e-14 V on [0, 1] (tests/test_mpc_export.py); the end pieces extended."""
    s, c = ocv_pieces()
    step = [S >= s[k] for k in range(1, len(c))]
    s0, a, b, cc, d = (v[0] + sum((v[k] - v[k - 1]) * step[k - 1] for k in range(1, len(c)))
                       for v in (s[:-1], c[:, 0], c[:, 1], c[:, 2], c[:, 3]))
    u = S - s0
    return a + u * (b + u * (cc + u * d))


_PIECEWISE: ContextVar[bool] = ContextVar("aev_ocp_ocv_piecewise", default=False)


@contextmanager
def piecewise_ocv() -> Iterator[None]:
    """Within this block, :func:`ocv` of an SX expression is :func:`ocv_piecewise` (the same values;
    the MPC builds its prediction model so). Numeric and MX arguments keep the B-spline Function."""
    token = _PIECEWISE.set(True)
    try:
        yield
    finally:
        _PIECEWISE.reset(token)


def ocv(S: Any) -> Any:
    """Open-circuit voltage OCV(S) [V]."""
    if _PIECEWISE.get() and isinstance(S, ca.SX):
        return ocv_piecewise(S)
    return ocv_function()(S)


def cell_derivatives(V1: Any, V2: Any, I: Any, p: CellParams) -> tuple[Any, Any, Any]:
    """(dV1/dt [V/s], dV2/dt [V/s], dS/dt [1/s]) for cell current I [A] (paper eqs. V_1_V_2, change_SOC)."""
    return (-V1 / (p.R1_ohm * p.C1_F) + I / p.C1_F,
            -V2 / (p.R2_ohm * p.C2_F) + I / p.C2_F,
            -I / (3600.0 * p.capacity_Ah))


def terminal_voltage(S: Any, V1: Any, V2: Any, I: Any, p: CellParams) -> Any:
    """V_T = OCV(S) − V1 − V2 − R_s I [V] (paper eq. terminal_voltage)."""
    return ocv(S) - V1 - V2 - p.R_s_ohm * I


def heat_Q(V1: Any, V2: Any, I: Any, p: CellParams) -> Any:
    """The paper's power loss Q = I (OCV − V_T) = I (V1 + V2) + R_s I² [W per cell] (paper eq. power_lossQ).
    It can be negative while the RC capacitors give back stored energy."""
    return I * (V1 + V2) + p.R_s_ohm * I**2


def heat_irreversible(V1: Any, V2: Any, I: Any, p: CellParams) -> Any:
    """Dissipated heat Q_irr = R_s I² + V1²/R1 + V2²/R2 ≥ 0 [W per cell] (model guide §6)."""
    return p.R_s_ohm * I**2 + V1**2 / p.R1_ohm + V2**2 / p.R2_ohm


def stored_energy_J(V1: Any, V2: Any, p: CellParams) -> Any:
    """Energy in the RC capacitors ½C1V1² + ½C2V2² [J]; Q = Q_irr + d/dt of this."""
    return 0.5 * p.C1_F * V1**2 + 0.5 * p.C2_F * V2**2

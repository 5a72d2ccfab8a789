"""2-RC equivalent-circuit cell (paper §3, model guide §6), SI units, time in seconds, I > 0 discharges.

The OCV curve is a cubic B-spline interpolant of the cell's table (``CellParams.ocv_soc``/``ocv_V``; a cell
file's OCV, :mod:`aev_ocp.cells`), by default the A123 ANR26650 table shipped in
``aev_ocp/data/a123_ocv_25C.csv`` (provenance in ``aev_ocp/data/README.md``). With an activation energy the
resistances follow Arrhenius in the temperature (:func:`cell_at`).
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

from ..params import R_GAS_JPMOLK, CellParams


def _key(cell: Any) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """The OCV table of ``cell`` as a hashable key (None: the shipped A123 table)."""
    soc = getattr(cell, "ocv_soc", None) if cell is not None else None
    return None if soc is None else (tuple(soc), tuple(cell.ocv_V))


@lru_cache(maxsize=1)
def _shipped_table() -> tuple[np.ndarray, np.ndarray]:
    path = resources.files("aev_ocp") / "data" / "a123_ocv_25C.csv"
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    return np.array([float(r["soc"]) for r in rows]), np.array([float(r["ocv_V"]) for r in rows])


def ocv_table(cell: CellParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The OCV table of ``cell``: SOC [-] and OCV [V] (None, or a cell without its own table: the shipped
    A123 table at 25 °C)."""
    key = _key(cell)
    if key is None:
        return _shipped_table()
    return np.array(key[0]), np.array(key[1])


@lru_cache(maxsize=16)
def _ocv_function(key: tuple[tuple[float, ...], tuple[float, ...]] | None) -> ca.Function:
    soc, ocv_v = _shipped_table() if key is None else (np.array(key[0]), np.array(key[1]))
    return ca.interpolant("ocv", "bspline", [soc], ocv_v)


def ocv_function(cell: CellParams | None = None) -> ca.Function:
    """OCV(S) [V] of ``cell`` as a CasADi cubic B-spline interpolant (model guide §6). Defined on S ∈ [0, 1];
    callers check S stays there (the simulator reports it, the optimisers constrain it)."""
    return _ocv_function(_key(cell))


@lru_cache(maxsize=16)
def _ocv_pieces(key: tuple[tuple[float, ...], tuple[float, ...]] | None) -> tuple[np.ndarray, np.ndarray]:
    soc = _shipped_table()[0] if key is None else np.array(key[0])
    f = _ocv_function(key)
    coef = []
    for a, b in zip(soc[:-1], soc[1:]):
        us = (b - a) * np.array([0.0, 1 / 3, 2 / 3, 1.0])
        ys = np.asarray(f(ca.DM(a + us).T)).ravel()
        coef.append(np.linalg.solve(np.vander(us, 4, increasing=True), ys))
    return soc, np.array(coef)


def ocv_pieces(cell: CellParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The B-spline of :func:`ocv_function` as its cubic pieces: breakpoints s_k (the table's SOC grid)
    and the coefficients (a_k, b_k, c_k, d_k) of OCV = a + b u + c u² + d u³, u = S − s_k, on
    [s_k, s_{k+1}] (fitted to the spline at four points per piece: it is exactly cubic there)."""
    return _ocv_pieces(_key(cell))


def ocv_piecewise(S: Any, cell: CellParams | None = None) -> Any:
    """OCV(S) [V] as the same piecewise cubic written with comparisons: an SX expression whose
    derivatives are plain arithmetic (cheaper than B-spline calls in generated Hessians); equal to
    :func:`ocv_function` within 1e-14 V on [0, 1] (tests/test_mpc_export.py); the end pieces extended."""
    s, c = ocv_pieces(cell)
    step = [S >= s[k] for k in range(1, len(c))]
    s0, a, b, cc, d = (
        v[0] + sum((v[k] - v[k - 1]) * step[k - 1] for k in range(1, len(c)))
        for v in (s[:-1], c[:, 0], c[:, 1], c[:, 2], c[:, 3])
    )
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


def ocv(S: Any, cell: CellParams | None = None) -> Any:
    """Open-circuit voltage OCV(S) [V] of ``cell`` (None: the shipped A123 table)."""
    if _PIECEWISE.get() and isinstance(S, ca.SX):
        return ocv_piecewise(S, cell)
    return ocv_function(cell)(S)


def arrhenius_factor(T_K: Any, p: CellParams) -> Any:
    """R(T)/R_ref = exp(E_a/R_gas (1/T − 1/T_ref)) [-]; 1 when the cell declares no activation energy."""
    if p.activation_energy_Jpmol is None:
        return 1.0
    return (
        ca.exp(p.activation_energy_Jpmol / R_GAS_JPMOLK * (1.0 / T_K - 1.0 / p.T_ref_K))
        if not isinstance(T_K, (int, float))
        else float(np.exp(p.activation_energy_Jpmol / R_GAS_JPMOLK * (1.0 / T_K - 1.0 / p.T_ref_K)))
    )


class CellAtTemperature:
    """``cell`` with R_s, R1 and R2 at temperature T [K] by :func:`arrhenius_factor` (numbers or CasADi
    expressions); every other attribute is the cell's. Passed where a CellParams is read."""

    def __init__(self, cell: CellParams, T_K: Any) -> None:
        f = arrhenius_factor(T_K, cell)
        self.base, self.T_K = cell, T_K
        self.R_s_ohm, self.R1_ohm, self.R2_ohm = cell.R_s_ohm * f, cell.R1_ohm * f, cell.R2_ohm * f

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


def cell_at(cell: CellParams, T_K: Any | None) -> Any:
    """The cell at temperature T_K (None, or no activation energy: the cell itself)."""
    if T_K is None or cell.activation_energy_Jpmol is None:
        return cell
    return CellAtTemperature(cell, T_K)


def cell_derivatives(V1: Any, V2: Any, I: Any, p: CellParams) -> tuple[Any, Any, Any]:
    """(dV1/dt [V/s], dV2/dt [V/s], dS/dt [1/s]) for cell current I [A] (paper eqs. V_1_V_2, change_SOC)."""
    return (
        -V1 / (p.R1_ohm * p.C1_F) + I / p.C1_F,
        -V2 / (p.R2_ohm * p.C2_F) + I / p.C2_F,
        -I / (3600.0 * p.capacity_Ah),
    )


def terminal_voltage(S: Any, V1: Any, V2: Any, I: Any, p: CellParams) -> Any:
    """V_T = OCV(S) − V1 − V2 − R_s I [V] (paper eq. terminal_voltage)."""
    return ocv(S, p) - V1 - V2 - p.R_s_ohm * I


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

"""2-RC equivalent-circuit cell (paper §3, model guide §6), SI units, time in seconds, I > 0 discharges.

The OCV curve is a cubic B-spline interpolant of the cell's table (``CellParams.ocv_soc``/``ocv_V``; a cell
file's OCV, :mod:`aev_ocp.cells`), by default the A123 ANR26650 table shipped in
``aev_ocp/data/a123_ocv_25C.csv`` (provenance in ``aev_ocp/data/README.md``). With an activation energy the
resistances follow Arrhenius in the temperature (:func:`cell_at`); with a table (``CellParams.rc_table``, a cell
file's ``[rc_table]``) R_s, R1, C1, R2 and C2 follow the SOC and the temperature (:func:`rc_function`).
"""

from __future__ import annotations

import copy
import csv
from contextlib import contextmanager
from contextvars import ContextVar
from functools import lru_cache
from importlib import resources
from typing import Any, Callable, Iterator

import casadi as ca
import numpy as np

from ..params import R_GAS_JPMOLK, RC_TABLE_KEYS, CellParams, RCTable


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
    :func:`ocv_function` within 1e-14 V on [0, 1] (tests/test_mpc_export.py); the end pieces extended.

    A dense SX argument of a cell with numbers (not :func:`runtime_cell`'s parameters) gets the expression through
    a Function built once per OCV table and shape: the same operations on the same nodes, so the same values to the
    bit (tests/test_battery.py), where writing it out again from Python took about 80 times longer at every model
    built."""
    sym = getattr(cell, RUNTIME_OCV, None)  # a run-time cell (:func:`runtime_cell`): the same numbers as parameters
    if sym is None and isinstance(S, ca.SX) and S.is_dense():
        return _ocv_piecewise_function(_key(cell), S.shape)(S)
    return _ocv_piecewise_expression(S, cell, sym)


@lru_cache(maxsize=32)
def _ocv_piecewise_function(
    key: tuple[tuple[float, ...], tuple[float, ...]] | None,
    shape: tuple[int, int],
) -> ca.Function:
    """:func:`_ocv_piecewise_expression` of the OCV table ``key`` as a Function of S of ``shape``."""
    S = ca.SX.sym("S", *shape)
    return ca.Function(
        "ocv_piecewise", [S], [_ocv_piecewise_expression(S, None if key is None else _KeyCell(key), None)]
    )


class _KeyCell:
    """The OCV table of a :func:`_key` where a cell is asked for (:func:`ocv_pieces` reads these two fields)."""

    def __init__(self, key: tuple[tuple[float, ...], tuple[float, ...]]) -> None:
        self.ocv_soc, self.ocv_V = key


def _ocv_piecewise_expression(S: Any, cell: Any, sym: Any) -> Any:
    """:func:`ocv_piecewise` written out: the piece's numbers picked by the comparisons S ≥ s_k (from ``sym``, the
    run-time cell's coefficients, when given)."""
    s, c = ocv_pieces(cell)
    step = [S >= s[k] for k in range(1, len(c))]
    s0, a, b, cc, d = (
        v[0] + sum((v[k] - v[k - 1]) * step[k - 1] for k in range(1, len(c)))
        if sym is None or j == 0
        else sym[0, j - 1] + sum(sym[k, j - 1] * step[k - 1] for k in range(1, len(c)))
        for j, v in enumerate((s[:-1], c[:, 0], c[:, 1], c[:, 2], c[:, 3]))
    )
    u = S - s0
    return a + u * (b + u * (cc + u * d))


def ocv_segments(cell: CellParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ocv_piecewise` as a table for a compiled lookup: the breakpoints s_k (its comparisons S ≥ s_k pick
    the piece) and, per piece k, the numbers (s0, a, b, c, d) it evaluates there, a + u (b + u (c + u d)) with
    u = S − s0. They are its sums of the pieces' differences in its order, so a lookup returns its value to the
    bit (tests/test_ring_ocv.py); S below s_1 (or NaN) takes piece 0, S ≥ s_{n−1} the last."""
    s, c = ocv_pieces(cell)
    out = np.empty((len(c), 5))
    for j, v in enumerate((s[:-1], c[:, 0], c[:, 1], c[:, 2], c[:, 3])):
        diffs = [v[k] - v[k - 1] for k in range(1, len(c))]
        for piece in range(len(c)):
            terms = [d * float(k < piece) for k, d in enumerate(diffs)]  # d (S ≥ s_k+1) in ocv_piecewise
            acc = terms[0] if terms else 0.0
            for t in terms[1:]:
                acc = acc + t
            out[piece, j] = v[0] + acc
    return s, out


_PIECEWISE: ContextVar[bool] = ContextVar("aev_ocp_ocv_piecewise", default=False)
_INPUTS: ContextVar[list[tuple[Any, Any, CellParams | None]] | None] = ContextVar("aev_ocp_ocv_inputs", default=None)


@contextmanager
def piecewise_ocv() -> Iterator[None]:
    """Within this block, :func:`ocv` of an SX expression is :func:`ocv_piecewise` (the same values;
    the MPC builds its prediction model so). Numeric and MX arguments keep the B-spline Function."""
    token = _PIECEWISE.set(True)
    try:
        yield
    finally:
        _PIECEWISE.reset(token)


@contextmanager
def ocv_inputs() -> Iterator[list[tuple[Any, Any, CellParams | None]]]:
    """Within this block, :func:`ocv` of an SX expression S is a new SX symbol E of S's shape, and (S, E, cell) is
    appended to the yielded list: a compiled driver that evaluates S itself passes OCV(S) as E, looked up in
    :func:`ocv_segments` (the ring: aev_ocp/c/ocv_lookup.h). Numeric and MX arguments keep the B-spline."""
    calls: list[tuple[Any, Any, CellParams | None]] = []
    token = _INPUTS.set(calls)
    try:
        yield calls
    finally:
        _INPUTS.reset(token)


def ocv_form() -> tuple[bool, bool]:
    """How :func:`ocv` writes an SX argument here: (inside :func:`piecewise_ocv`, inside :func:`ocv_inputs`): a model
    built under one is not the model built under another (a key of models kept for reuse)."""
    return _PIECEWISE.get(), _INPUTS.get() is not None


def ocv(S: Any, cell: CellParams | None = None) -> Any:
    """Open-circuit voltage OCV(S) [V] of ``cell`` (None: the shipped A123 table)."""
    calls = _INPUTS.get()
    if calls is not None and isinstance(S, ca.SX):
        E = ca.SX.sym(f"ocv_{len(calls)}", S.sparsity())
        calls.append((S, E, cell))
        return E
    if isinstance(S, ca.SX) and (_PIECEWISE.get() or getattr(cell, RUNTIME_OCV, None) is not None):
        return ocv_piecewise(S, cell)  # a run-time cell's OCV: its pieces' coefficients are parameters
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


def _segment(x: Any, grid: list[float], vals: list[Any]) -> Any:
    """Linear interpolation of (grid, vals) at x ∈ [grid[0], grid[-1]] written as v_k + w (v_k+1 − v_k) on the
    segment picked by comparisons: exact at the grid points and for equal neighbours (a constant table
    returns its constant to the bit, which CasADi's 'linear' interpolant does not)."""
    if len(grid) == 1:
        return vals[0]
    x0, x1, v0, v1 = grid[0], grid[1], vals[0], vals[1]
    for k in range(1, len(grid) - 1):
        on = x >= grid[k]
        x0, x1 = ca.if_else(on, grid[k], x0), ca.if_else(on, grid[k + 1], x1)
        v0, v1 = ca.if_else(on, vals[k], v0), ca.if_else(on, vals[k + 1], v1)
    return v0 + (x - x0) / (x1 - x0) * (v1 - v0)


def _log_spline(key: str, grid: list[list[float]], logs: Any, x: Any, basis: dict[str, Any]) -> Any:
    """The cubic (degree ≤ points − 1 per axis) B-spline through ``logs`` on ``grid`` at the point ``x``: the values
    numeric (compiled in) or SX (run-time parameters: φ(x)·logs, φ(x) evaluated once per point in ``basis``)."""
    deg = [min(3, len(g) - 1) for g in grid]
    if isinstance(logs, np.ndarray):
        return ca.interpolant(key, "bspline", grid, logs, {"degree": deg})(x)
    if "phi" not in basis:
        basis["phi"] = _spline_basis(tuple(tuple(g) for g in grid), tuple(deg))(x)
    return ca.dot(basis["phi"], logs)


@lru_cache(maxsize=16)
def _spline_basis(grid: tuple[tuple[float, ...], ...], deg: tuple[int, ...]) -> ca.Function:
    """The grid's cardinal splines φ_j (the B-spline through the unit values e_j) as one interpolant with one output
    per point: the spline through values v is φ·v (it is linear in them), its coefficients fitted once, at build
    time (CasADi's parametric B-spline refits them at every call: it made the MPC's closed loop ~28 times slower)."""
    n = int(np.prod([len(g) for g in grid]))
    return ca.interpolant("rc_basis", "bspline", [list(g) for g in grid], np.eye(n).ravel(), {"degree": list(deg)})


def _rc_outputs(table: RCTable, Sc: Any, Tc: Any, smooth: bool) -> list[Any]:
    """R_s, R1, C1, R2, C2 of ``table`` at the clamped (Sc, Tc): bilinear, or exp of the log-spline with
    ``smooth``; the table's values numbers or (:func:`runtime_cell`) SX parameters."""
    soc, temps = list(table.soc), list(table.T_K)
    outs: list[Any] = []
    basis: dict[str, Any] = {}
    for key in RC_TABLE_KEYS:
        raw = getattr(table, key)
        numeric = all(isinstance(x, float) for r in raw for x in r)
        vals = np.array(raw, dtype=float if numeric else object)  # (n_T, n_soc)
        if not smooth:
            outs.append(_segment(Tc, temps, [_segment(Sc, soc, list(row)) for row in vals]))
            continue
        logs = np.log(vals) if numeric else ca.log(ca.vertcat(*vals.ravel()))  # T rows: soc runs fastest
        if len(temps) == 1:  # the spline of log(value): positive between the points too
            outs.append(ca.exp(_log_spline(key, [soc], logs[0] if numeric else logs, Sc, basis)))
        elif not numeric and isinstance(Tc, float):  # T a number (the MPC without a temperature state): the
            # interpolating tensor spline is the product of the axes' cardinal splines, so along T it is a fixed
            # combination of the rows (weights ψ_j(T)); 1-D along SOC then (half the generated code)
            psi = np.asarray(_spline_basis((tuple(temps),), (min(3, len(temps) - 1),))(Tc)).ravel()
            rows = ca.reshape(logs, len(soc), len(temps))  # column j: the row of T_K[j]
            outs.append(ca.exp(_log_spline(key, [soc], ca.mtimes(rows, ca.DM(psi)), Sc, basis)))
        else:  # CasADi's grid order: the first axis (soc) runs fastest
            flat = np.log(vals.T.ravel(order="F")) if numeric else logs
            outs.append(ca.exp(_log_spline(key, [soc, temps], flat, ca.vertcat(Sc, Tc), basis)))
    return outs


@lru_cache(maxsize=32)
def rc_function(table: RCTable, smooth: bool = False) -> ca.Function:
    """(S [-], T [K]) → (R_s [Ω], R1 [Ω], C1 [F], R2 [Ω], C2 [F]) of ``table`` as one CasADi Function, built
    once per table: bilinear (the plant: exact at the grid points, along SOC then T, :func:`_segment`) or,
    with ``smooth``, exp of CasADi cubic B-spline interpolants of the logarithms through the same points (degree
    ≤ points − 1 per axis; for optimisers: twice differentiable, and positive between the points where a
    table spans decades, e.g. an LFP C2). S and T are clamped to the grid first: outside it the end
    values hold."""
    S, T = ca.SX.sym("S"), ca.SX.sym("T_K")
    outs = _rc_outputs(table, *_clamped(table, S, T), smooth)
    return ca.Function("rc_spline" if smooth else "rc_linear", [S, T], outs, ["S", "T_K"], list(RC_TABLE_KEYS))


def _clamped(table: RCTable, S: Any, T: Any) -> tuple[Any, Any]:
    """(S, T) clamped to the table's grid (outside it the end values hold)."""
    soc, temps = table.soc, table.T_K
    return ca.fmin(ca.fmax(S, soc[0]), soc[-1]), ca.fmin(ca.fmax(T, temps[0]), temps[-1])


#: The attribute of a run-time cell (:func:`runtime_cell`) holding its OCV pieces' coefficients as parameters.
RUNTIME_OCV = "_runtime_ocv_coefficients"


def runtime_cell(cell: CellParams, twin: CellParams, parameter: Callable[[str, float], Any], prefix: str) -> Any:
    """``twin`` (a copy of ``cell`` whose float fields are a problem's run-time parameters) with the cell's tables
    as run-time parameters too, so that the code generated from a model of it does not depend on the cell's
    values: the RC tables' values (``<prefix>__rc_table__<key>__<T index>_<SOC index>``) and, for a cell with its
    own OCV table, the coefficients of :func:`ocv_pieces` (``<prefix>__ocv__<piece>_<power>``: piece 0's, then
    each piece's difference from the one before, the terms :func:`ocv_piecewise` sums); ``parameter(name,
    value)`` makes one. The grids (SOC, T, the OCV's SOC), ``soc_ref`` and ``T_ref_K`` stay numbers: cells of the
    same grids share one generated model, a cell on another grid generates its own. The model of the twin gives
    the numbers-in model's values (the OCV within 1e-14 V: :func:`ocv_piecewise` in place of the B-spline)."""
    tab = cell.rc_table
    if tab is not None:
        rc = copy.copy(tab)
        for key in RC_TABLE_KEYS:
            rows = tuple(
                tuple(parameter(f"{prefix}__rc_table__{key}__{j}_{i}", v) for i, v in enumerate(r))
                for j, r in enumerate(getattr(tab, key))
            )
            object.__setattr__(rc, key, rows)
        object.__setattr__(twin, "rc_table", rc)
        object.__setattr__(twin, "T_ref_K", cell.T_ref_K)  # the table's reference point: a number
    if cell.ocv_soc is not None:
        _, c = ocv_pieces(cell)
        diff = [c[0]] + [c[k] - c[k - 1] for k in range(1, len(c))]  # what ocv_piecewise sums, as it computes it
        sym = np.array(
            [[parameter(f"{prefix}__ocv__{k}_{m}", float(diff[k][m])) for m in range(4)] for k in range(len(c))],
            dtype=object,
        )
        object.__setattr__(twin, RUNTIME_OCV, sym)
    return twin


class CellAt:
    """``cell`` at temperature T [K] and SOC S [-] (numbers or CasADi expressions): R_s, R1 and R2 by
    :func:`arrhenius_factor` when the cell has no ``rc_table``; with one, R_s, R1, C1, R2, C2 from
    :func:`rc_function` (T None: T_ref_K) times the cell's level (CellParams.rc_table). Every other
    attribute is the cell's. Passed where a CellParams is read."""

    def __init__(self, cell: CellParams, T_K: Any, S: Any = None, smooth: bool = False) -> None:
        self.base, self.T_K, self.S = cell, T_K, S
        tab = cell.rc_table
        if tab is None:
            f = arrhenius_factor(T_K, cell)
            self.R_s_ohm, self.R1_ohm, self.R2_ohm = cell.R_s_ohm * f, cell.R1_ohm * f, cell.R2_ohm * f
            return
        T = cell.T_ref_K if T_K is None else T_K
        S = tab.soc_ref if S is None else S
        if all(isinstance(x, float) for x in tab.R_s_ohm[0]):
            vals = rc_function(tab, smooth)(S, T)
        else:  # a run-time cell's table (:func:`runtime_cell`): the values are parameters
            vals = _rc_outputs(tab, *_clamped(tab, S, T), smooth)
        numeric = all(isinstance(x, (int, float, np.floating)) for x in (S, T) if x is not None)
        for key, v in zip(RC_TABLE_KEYS, vals):
            scale = getattr(cell, key) / tab.value(key, tab.soc_ref, cell.T_ref_K)
            v = float(v) if numeric else v
            setattr(self, key, v if isinstance(scale, float) and scale == 1.0 else v * scale)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


def cell_at(cell: CellParams, T_K: Any | None, S: Any = None, smooth: bool = False) -> Any:
    """The cell at temperature T_K [K] and SOC S [-]: a cell without ``rc_table`` at T_K by Arrhenius (None,
    or no activation energy: the cell itself; S is not read); a table cell from its tables (T_K None: T_ref_K;
    S None: the table's soc_ref), linear, or the cubic B-spline with ``smooth`` (optimisers)."""
    if cell.rc_table is not None:
        return CellAt(cell, T_K, S, smooth)
    if T_K is None or cell.activation_energy_Jpmol is None:
        return cell
    return CellAt(cell, T_K)


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

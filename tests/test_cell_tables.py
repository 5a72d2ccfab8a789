"""Cells whose R_s, R1, C1, R2, C2 follow the SOC and the temperature (CellParams.rc_table, a cell file's
[rc_table]) and the cells identified from PyBaMM's parameter sets (tools/identify_cell.py, issue 37).

Independent checks: the table cell against the constant cell (bit-equal when the tables are constant), against a
SciPy integration of the 2-RC ODE with the same tables read by SciPy's own interpolator, and each shipped
identified file against its own stored HPPC test (the stated residual re-evaluated by CVODES)."""

from __future__ import annotations

import csv
import dataclasses
import importlib.util
import json
import re
import tomllib
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import RegularGridInterpolator

from aev_ocp.cells import CellFileError, load_cell, load_cell_file, shipped_cells
from aev_ocp.errors import AevOcpWarning
from aev_ocp.models import battery
from aev_ocp.models.ego import battery_side
from aev_ocp.params import RC_TABLE_KEYS, CellParams, EVParams, ParameterError, RCTable
from aev_ocp.scenarios import find_scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]
CELLS = ROOT / "aev_ocp" / "data" / "cells"
IDENTIFIED = sorted(n for n in shipped_cells() if load_cell_file(n).cell.rc_table is not None)

SOC = (0.05, 0.3, 0.55, 0.8, 0.97)  # 5 SOCs × 3 temperatures: a swapped axis cannot go unnoticed
TEMPS = (281.0, 297.5, 318.0)


def _grid_tables(cell: CellParams) -> dict[str, list[list[float]]]:
    """Tables varying in SOC and T differently per quantity (R1, R2 of different size and time constant)."""
    s, T = np.meshgrid(SOC, TEMPS)  # (n_T, n_soc)
    arr = np.exp(2300.0 * (1.0 / T - 1.0 / 297.5))
    shape = {
        "R_s_ohm": cell.R_s_ohm * (1.0 + 0.9 * (s - 0.55) ** 2) * arr,
        "R1_ohm": cell.R1_ohm * (1.4 - 0.7 * s) * arr**1.3,
        "C1_F": cell.C1_F * (0.8 + 0.5 * s) / arr**0.4,
        "R2_ohm": cell.R2_ohm * (0.6 + 1.1 * s**2) * arr**0.7,
        "C2_F": cell.C2_F * (1.3 - 0.6 * s) * (1.0 + 0.002 * (T - 297.5)),
    }
    return {k: v.tolist() for k, v in shape.items()}


def _table_cell(const: bool = False, capacity_Ah: float = 2.3) -> CellParams:
    base = CellParams(capacity_Ah=capacity_Ah)
    if const:
        tabs = {k: [[getattr(base, k)] * len(SOC)] * len(TEMPS) for k in RC_TABLE_KEYS}
    else:
        tabs = _grid_tables(base)
    table = RCTable(soc=SOC, T_K=TEMPS, soc_ref=0.55, **tabs)
    # the scalars: the table's level at (soc_ref, T_ref_K), so the table is used as it is
    ref = {k: table.value(k, 0.55, 297.5) for k in RC_TABLE_KEYS}
    return dataclasses.replace(base, rc_table=table, T_ref_K=297.5, **ref)


# ------------------------------------------------------------------ the constant table is the constant cell


def test_constant_tables_are_bit_equal_to_the_constant_cell() -> None:
    const, tab = CellParams(), _table_cell(const=True)
    assert tab.rc_table is not None and tab.R_s_ohm == const.R_s_ohm
    ev_c, ev_t = EVParams(cell=const), EVParams(cell=tab)
    rng = np.random.default_rng(37)
    for _ in range(40):
        v, a = rng.uniform(0.0, 1.8), rng.uniform(-1.2, 1.2)
        V1, V2, S = rng.uniform(-0.2, 0.3), rng.uniform(-0.2, 0.3), rng.uniform(-0.1, 1.1)  # S also off the grid
        T = rng.choice([None, float(rng.uniform(250.0, 340.0))])
        bc, bt = battery_side(v, a, V1, V2, S, ev_c, T_K=T), battery_side(v, a, V1, V2, S, ev_t, T_K=T)
        assert set(bc) == set(bt)
        for k in bc:
            assert np.array_equal(np.asarray(bc[k], float), np.asarray(bt[k], float)), k


def test_constant_table_file_runs_bit_equal_closed_loop(tmp_path: Path) -> None:
    """A cell file with a constant [rc_table] runs the platoon bit-equal to the same file without it."""
    text = (
        (CELLS / "a123_anr26650.toml")
        .read_text()
        .replace('"../a123_ocv_25C.csv"', f'"{CELLS.parent}/a123_ocv_25C.csv"')
    )
    c = CellParams()
    rows = lambda x: "[" + ", ".join("[" + ", ".join([repr(x)] * 3) + "]" for _ in range(2)) + "]"  # noqa: E731
    table = '\n[rc_table]\nsource = "test"\nsoc = [0.2, 0.5, 0.9]\nT_K = [290.0, 310.0]\n' + "".join(
        f"{k} = {rows(getattr(c, k))}\n" for k in RC_TABLE_KEYS
    )
    (tmp_path / "plain.toml").write_text(text)
    (tmp_path / "table.toml").write_text(text + table)
    assert load_cell(tmp_path / "table.toml").rc_table is not None
    base = find_scenario("udds_platoon").read_text()
    out = {}
    for n in ("plain", "table"):
        p = tmp_path / f"s_{n}.toml"
        p.write_text(base + f'\n[cell]\nfile = "{n}.toml"\nsoc0 = 0.61\n')
        out[n] = load_scenario(p).replace(t_end=40.0).run(only="proposed")["proposed"]
    for k in ("gap", "speed", "V1", "V2", "S", "current_A", "heat_J", "heat_irr_J"):
        assert np.array_equal(np.asarray(getattr(out["plain"], k)), np.asarray(getattr(out["table"], k))), k


# ------------------------------------------------------------------ the tables against SciPy


def _scipy_tables(cell: CellParams) -> dict[str, RegularGridInterpolator]:
    t = cell.rc_table
    assert t is not None
    return {
        k: RegularGridInterpolator((np.array(t.soc), np.array(t.T_K)), np.array(getattr(t, k)).T, method="linear")
        for k in RC_TABLE_KEYS
    }


def test_table_cell_matches_scipy_2rc_ode_on_a_random_profile() -> None:
    """V1, V2, S and V_T of the toolkit's table cell (CasADi CVODES, SOC and T as states) against solve_ivp of
    the 2-RC ODE written out with SciPy's interpolator, on a random held current while T sweeps 276 → 324 K
    and S runs across the SOC grid."""
    cell = _table_cell(capacity_Ah=0.0052)
    interp, ocv = _scipy_tables(cell), battery.ocv_function(cell)
    rate_Kps = 48.0 / 80.0
    rng = np.random.default_rng(2037)
    I_k = rng.uniform(-0.18, 0.55, 40)  # [A], 2 s each, net discharge through the SOC grid
    t_k = np.arange(41) * 2.0

    def lookup(S: float, T: float) -> dict[str, float]:
        q = np.array([[np.clip(S, SOC[0], SOC[-1]), np.clip(T, TEMPS[0], TEMPS[-1])]])
        return {k: float(f(q)[0]) for k, f in interp.items()}

    def rhs(I: float):  # noqa: ANN202
        def f(_t: float, y: np.ndarray) -> list[float]:
            p = lookup(y[2], y[3])
            return [
                -y[0] / (p["R1_ohm"] * p["C1_F"]) + I / p["C1_F"],
                -y[1] / (p["R2_ohm"] * p["C2_F"]) + I / p["C2_F"],
                -I / (3600.0 * cell.capacity_Ah),
                rate_Kps,
            ]

        return f

    x, u = ca.MX.sym("x", 4), ca.MX.sym("u")
    view = battery.cell_at(cell, x[3], x[2])
    d1, d2, dS = battery.cell_derivatives(x[0], x[1], u, view)
    F = ca.integrator(
        "F",
        "cvodes",
        {"x": x, "p": u, "ode": ca.vertcat(d1, d2, dS, rate_Kps)},
        0.0,
        2.0,
        {"abstol": 1e-12, "reltol": 1e-12},
    )
    vt = ca.Function("vt", [x, u], [battery.terminal_voltage(x[2], x[0], x[1], u, view)])
    y_ref = y_ca = np.array([0.013, -0.004, 0.93, 276.0])
    for k, I in enumerate(I_k):
        y_ref = solve_ivp(rhs(I), (t_k[k], t_k[k + 1]), y_ref, method="LSODA", rtol=1e-11, atol=1e-13).y[:, -1]
        y_ca = np.asarray(F(x0=y_ca, p=I)["xf"]).ravel()
        assert np.allclose(y_ca, y_ref, rtol=1e-7, atol=1e-9), (k, y_ca, y_ref)
        p = lookup(y_ref[2], y_ref[3])
        vt_ref = float(ocv(y_ref[2])) - y_ref[0] - y_ref[1] - p["R_s_ohm"] * I
        assert float(vt(y_ca, I)) == pytest.approx(vt_ref, abs=1e-8)
    assert y_ref[2] < 0.3 and y_ref[3] > 323.0  # the run crossed the SOC grid and the temperature grid


def test_table_lookup_holds_the_ends_and_the_spline_passes_the_grid() -> None:
    cell = _table_cell()
    t = cell.rc_table
    assert t is not None
    lin, spl = battery.rc_function(t), battery.rc_function(t, smooth=True)
    for j, T in enumerate(TEMPS):
        for i, s in enumerate(SOC):
            got_lin = [float(v) for v in lin(s, T)]
            got_spl = [float(v) for v in spl(s, T)]
            want = [getattr(t, k)[j][i] for k in RC_TABLE_KEYS]
            assert got_lin == pytest.approx(want, rel=1e-14) and got_spl == pytest.approx(want, rel=1e-10)
    # outside the grid: the end values (no linear extrapolation to negative resistances)
    for s, T, s_in, T_in in (
        (-0.3, 200.0, SOC[0], TEMPS[0]),
        (1.4, 420.0, SOC[-1], TEMPS[-1]),
        (0.42, 500.0, 0.42, TEMPS[-1]),
    ):
        assert [float(v) for v in lin(s, T)] == [float(v) for v in lin(s_in, T_in)]
    # the numeric view equals the table's own NumPy-free bilinear value, off the grid too
    v = battery.cell_at(cell, 303.3, 0.47)
    for k in RC_TABLE_KEYS:
        assert getattr(v, k) == pytest.approx(t.value(k, 0.47, 303.3), rel=1e-13)
    # the spline is smooth: a finite Hessian in (S, T) between the grid points
    S, T = ca.SX.sym("S"), ca.SX.sym("T")
    e = spl(S, T)[0]
    H = ca.Function("H", [S, T], [ca.hessian(e, ca.vertcat(S, T))[0]])
    assert np.all(np.isfinite(np.asarray(H(0.41, 301.0))))
    # an override of a scalar scales its whole table (a mismatch factor, [cell] R1_ohm = ...)
    c2 = dataclasses.replace(cell, R1_ohm=cell.R1_ohm * 1.7)
    assert battery.cell_at(c2, 289.0, 0.33).R1_ohm == pytest.approx(1.7 * battery.cell_at(cell, 289.0, 0.33).R1_ohm)


def test_bad_tables_are_one_line_errors(tmp_path: Path) -> None:
    tabs = _grid_tables(CellParams())
    with pytest.raises(ParameterError, match=r"RCTable\.R1_ohm.*3 rows"):
        RCTable(soc=SOC, T_K=TEMPS, **{**tabs, "R1_ohm": tabs["R1_ohm"][:2]})
    with pytest.raises(ParameterError, match=r"RCTable\.C2_F.*> 0"):
        RCTable(soc=SOC, T_K=TEMPS, **{**tabs, "C2_F": [[-1.0] * 5] * 3})
    with pytest.raises(ParameterError, match=r"RCTable\.soc"):
        RCTable(soc=(0.5, 0.3, 0.9, 0.95, 0.99), T_K=TEMPS, **tabs)
    with pytest.raises(ParameterError, match=r"RCTable\.T_K"):
        RCTable(soc=SOC, T_K=(300.0, 290.0, 310.0), **tabs)
    with pytest.raises(ParameterError, match="activation_energy_Jpmol.*rc_table"):
        CellParams(activation_energy_Jpmol=3e4, rc_table=RCTable(soc=SOC, T_K=TEMPS, **tabs))
    name = IDENTIFIED[0]
    text = (CELLS / f"{name}.toml").read_text().replace(f'"{name}_ocv.csv"', f'"{CELLS}/{name}_ocv.csv"')
    no_c2 = re.sub(r"\nC2_F = \[\n(?:    .*\n)+\]", "", text)
    assert no_c2 != text
    for bad, where in (
        (text.replace("[rc_table]\n", "[rc_table]\nR3_ohm = 1.0\n", 1), "unknown key rc_table.R3_ohm"),
        (no_c2, "rc_table.C2_F is missing"),
        (text.replace("\nT_K = [", "\nT_K = [0.0, ", 1), "rc_table: T_K"),
        (text.replace("\nR1_ohm = [\n", "\nR1_ohm = [\n    [1.0],\n", 1), "rc_table: R1_ohm"),
    ):
        p = tmp_path / "bad.toml"
        p.write_text(bad)
        with pytest.raises(CellFileError) as exc:
            load_cell(p)
        assert where in str(exc.value) and "\n" not in str(exc.value)


# ------------------------------------------------------------------ the shipped identified cells


def test_identified_cells_cover_lfp_nmc_nca() -> None:
    chem = {load_cell_file(n).chemistry for n in shipped_cells()}
    assert len(shipped_cells()) >= 4 and chem == {"LFP", "NMC", "NCA"}
    assert {"lg_m50", "nca_kim2011", "a123_prada2013"} <= set(IDENTIFIED)


@pytest.mark.parametrize("name", IDENTIFIED)
def test_identified_file_round_trips_and_states_its_fit(name: str) -> None:
    cf = load_cell_file(name)
    c, doc = cf.cell, tomllib.loads((CELLS / f"{name}.toml").read_text())
    t = c.rc_table
    assert t is not None
    # the file's tables are the cell's, value for value, rows per T_K
    assert list(t.soc) == doc["rc_table"]["soc"] and list(t.T_K) == doc["rc_table"]["T_K"]
    for k in RC_TABLE_KEYS:
        assert [list(r) for r in getattr(t, k)] == doc["rc_table"][k]
        assert getattr(c, k) == t.value(k, t.soc_ref, c.T_ref_K)  # the scalars are the table at the reference
    ident = cf.identification
    summary = json.loads((CELLS / "identification.json").read_text())[name]
    assert ident["parameter_set"] == summary["parameter_set"] and ident["pybamm_version"] == summary["pybamm_version"]
    assert ident["fit_rms_V"] == summary["fit_rms_V"] and cf.chemistry == summary["chemistry"]
    assert 0.0 < ident["fit_rms_V"] <= ident["fit_max_rms_V"] < 0.01  # below 10 mV
    # the validation the file reports is the script's output (identification.json)
    assert {k: v for k, v in summary["validation"].items() if v is not None} == ident["validation"]
    assert ident["validation"]["thevenin_max_abs_V"] < 1e-5  # PyBaMM's Thevenin: the same equations
    # the optimisers' spline stays positive and finite across the whole (S, T) range, off the grid too
    spl = battery.rc_function(t, smooth=True)
    S, T = np.meshgrid(np.linspace(-0.05, 1.05, 45), np.linspace(t.T_K[0] - 5.0, t.T_K[-1] + 5.0, 9))
    for out in spl(S.ravel()[None, :], T.ravel()[None, :]):
        v = np.asarray(out).ravel()
        assert np.all(np.isfinite(v)) and np.all(v > 0.0)


@pytest.mark.parametrize("name", IDENTIFIED)
def test_stated_residual_matches_the_stored_hppc_test(name: str) -> None:
    """The stored DFN pulse test (25 °C, SOC 0.5) through the toolkit's cell at that point's values, CVODES with the
    current held between samples: the RMS error equals the residual the file states (the fit used an exact
    zero-order-hold discretisation instead)."""
    cf = load_cell_file(name)
    ident = cf.identification
    with (CELLS / ident["hppc_file"]).open() as fh:
        rows = np.array([[float(r["t_s"]), float(r["current_A"]), float(r["voltage_V"])] for r in csv.DictReader(fh)])
    t, I, V = rows.T
    s0, T = ident["hppc_soc0"], ident["hppc_T_K"]
    view = battery.cell_at(cf.cell, T, s0)  # the point's R, C (the fit's parameters)
    x, u, h = ca.MX.sym("x", 3), ca.MX.sym("u"), ca.MX.sym("h")
    d1, d2, dS = battery.cell_derivatives(x[0], x[1], u, view)
    F = ca.integrator(
        "F",
        "cvodes",
        {"x": x, "p": ca.vertcat(u, h), "ode": h * ca.vertcat(d1, d2, dS)},
        0.0,
        1.0,
        {"abstol": 1e-12, "reltol": 1e-12},
    )
    y = np.array([0.0, 0.0, s0])
    model = []
    for k in range(t.size):
        model.append(float(battery.terminal_voltage(y[2], y[0], y[1], I[k], view)))
        if k + 1 < t.size and t[k + 1] > t[k]:
            y = np.asarray(F(x0=y, p=[I[k], t[k + 1] - t[k]])["xf"]).ravel()
    rms = float(np.sqrt(np.mean((np.array(model) - V) ** 2)))
    assert rms == pytest.approx(ident["hppc_rms_V"], rel=1e-5)
    assert np.ptp(I) > 0.9 * cf.cell.capacity_Ah  # a pulse test: ±1C pulses


# ------------------------------------------------------------------ one compiled library for every identified cell


def _runtime_twin(cell: CellParams) -> tuple[CellParams, ca.SX, list[float]]:
    """The cell as a problem's run-time parameters (what the MPC builds): (the twin, the parameters, their values)."""
    from aev_ocp.ocp.problem import ProblemBuilder

    pb = ProblemBuilder("twin")
    twin = pb.parameters_of(EVParams(cell=cell), "ev").cell
    return twin, ca.vertcat(*pb.p.values()), [pb._p_values[k] for k in pb.p]


@pytest.mark.parametrize("name", IDENTIFIED)
def test_runtime_cell_is_the_numbers_in_cell(name: str) -> None:
    """The cell with its RC tables' values and OCV pieces as run-time parameters (one generated model for every cell
    of the same grids) gives the model with the numbers written in: OCV and R_s, R1, C1, R2, C2 at every OCV and
    table knot, between the knots and outside the grids, linear (bit-equal) and spline (≤ 1e-12 relative); also with
    R1 and C2 scaled (a mismatch factor: the scale is computed at run time)."""
    for cell in (load_cell(name), dataclasses.replace(load_cell(name), R1_ohm=0.0173, C2_F=2.9e3 * (1 + len(name)))):
        _check_runtime_cell(cell)


def _check_runtime_cell(cell: CellParams) -> None:
    t = cell.rc_table
    assert t is not None and cell.ocv_soc is not None
    twin, p, pv = _runtime_twin(cell)
    assert len(pv) > 4 * (len(cell.ocv_soc) - 1) + 5 * len(t.soc) * len(t.T_K)  # the tables are parameters
    knots = sorted({*cell.ocv_soc, *t.soc})
    mids = [0.5 * (a + b) for a, b in zip(knots, knots[1:])]
    rng = np.random.default_rng(40)
    S_all = np.array([*knots, *mids, *rng.uniform(0.0, 1.0, 300), -0.2, -1e-9, 1.0 + 1e-9, 1.3, t.soc[0] - 0.03])
    T_all = [*t.T_K, *(0.5 * (a + b) for a, b in zip(t.T_K, t.T_K[1:])), t.T_K[0] - 20.0, t.T_K[-1] + 7.0, 301.7]
    S, T = ca.SX.sym("S"), ca.SX.sym("T")
    pm = ca.repmat(ca.DM(pv), 1, S_all.size)  # the parameters' values at every S (built once: issue 40)
    for smooth in (False, True):
        with battery.piecewise_ocv():  # the MPC's OCV (the B-spline's pieces); the twin's is these pieces anyway
            want = battery.cell_at(cell, T, S, smooth)
            got = battery.cell_at(twin, T, S, smooth)
            f_want = ca.Function("w", [S, T], [battery.ocv(S, cell), *(getattr(want, k) for k in RC_TABLE_KEYS)])
        f_got = ca.Function("g", [S, T, p], [battery.ocv(S, twin), *(getattr(got, k) for k in RC_TABLE_KEYS)])
        assert ca.symvar(f_got(S, T, p)[0])  # the OCV is an expression of the parameters, not of numbers
        m_want, m_got = f_want.map(S_all.size), f_got.map(S_all.size)  # T an input: one map for every T_K
        for T_K in T_all:
            a = np.array([np.asarray(v).ravel() for v in m_want(S_all, T_K)])
            b = np.array([np.asarray(v).ravel() for v in m_got(S_all, T_K, pm)])
            assert np.all(np.isfinite(a))
            if smooth:  # the parametric B-spline fits its coefficients at run time: rounding apart
                np.testing.assert_allclose(b, a, rtol=1e-12, atol=0)
                assert np.array_equal(b[0], a[0])  # the OCV pieces: bit-equal
            else:
                assert np.array_equal(b, a), (T_K, np.abs(b - a).max())
    # T a number (the MPC without a temperature state): the same, through the rows' fixed combination along T
    for smooth in (False, True):
        for T_K in T_all:
            want, got = battery.cell_at(cell, float(T_K), S, smooth), battery.cell_at(twin, float(T_K), S, smooth)
            f_want = ca.Function("w", [S], [getattr(want, k) for k in RC_TABLE_KEYS])
            f_got = ca.Function("g", [S, p], [getattr(got, k) for k in RC_TABLE_KEYS])
            a = np.array([np.asarray(v).ravel() for v in f_want.map(S_all.size)(S_all)])
            b = np.array([np.asarray(v).ravel() for v in f_got.map(S_all.size)(S_all, pm)])
            np.testing.assert_allclose(b, a, rtol=1e-12 if smooth else 0.0, atol=0)
    # the twin's OCV (B-spline pieces) outside the piecewise block: the numbers-in B-spline within 1e-12 on [0, 1]
    f_bs = ca.Function("b", [S], [battery.ocv(S, cell)])
    f_tw = ca.Function("t", [S, p], [battery.ocv(S, twin)])
    inside = S_all[(S_all >= 0.0) & (S_all <= 1.0)]
    np.testing.assert_allclose(
        np.asarray(f_tw.map(inside.size)(inside, pm[:, : inside.size])).ravel(),
        np.asarray(f_bs.map(inside.size)(inside)).ravel(),
        rtol=1e-12,
        atol=0,
    )


def test_identified_cells_make_one_generated_problem() -> None:
    """Two identified cells (the same grids, other values): the MPC problem with the numbers as run-time parameters is
    the same CasADi graph (hence the same generated C) and equals each cell's numbers-in problem (no fallback)."""
    import warnings

    from aev_ocp.ocp.formulation import DEFAULT_FORMULATION, same_problem

    a, b = (EVParams(cell=load_cell(n)) for n in ("lg_m50", "nca_kim2011"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fallback to the numbers in warns
        pa, pb = DEFAULT_FORMULATION.mpc_problem(a, 0.1), DEFAULT_FORMULATION.mpc_problem(b, 0.1)
    for ev, pr in ((a, pa), (b, pb)):
        assert same_problem(DEFAULT_FORMULATION.build(ev, 0.1), pr) == ""
        assert "ev__cell__rc_table__R1_ohm__2_8" in pr.meta["parameter_defaults"]
    assert pa.meta["parameter_names"] == pb.meta["parameter_names"]
    assert pa.meta["parameter_defaults"] != pb.meta["parameter_defaults"]
    for nm in ("ode", "stage", "path", "outputs"):
        assert getattr(pa, nm).serialize() == getattr(pb, nm).serialize(), nm


@pytest.fixture(scope="module")
def cell_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[list[str], dict]]:  # type: ignore[type-arg]
    """The identified cells' closed loops, one after the other, in the environment's compile cache: {cell: (the MPC
    step libraries its controllers loaded, its runs)}. The library a controller loads is named by a hash of its
    generated source, so two cells that compiled their own libraries load two paths whether the cache was empty or
    not (an empty cache per run would compile the shared library, ~20 s of gcc, in every run of the suite)."""
    from aev_ocp.mpc.cstep import CStep
    from aev_ocp.mpc.cycles import run_cycle

    out = {}
    tmp = tmp_path_factory.mktemp("cells")
    loaded: list[str] = []
    init = CStep.__init__

    def spy(self: CStep, lib_path: str | Path) -> None:
        loaded.append(str(lib_path))
        init(self, lib_path)

    with pytest.MonkeyPatch.context() as m, warnings.catch_warnings():
        warnings.simplefilter("error", AevOcpWarning)  # a cell that falls back to numbers in fails here
        m.setattr(CStep, "__init__", spy)
        for name in IDENTIFIED:
            p = tmp / f"{name}.toml"
            p.write_text(find_scenario("mpc_udds_single").read_text() + f'\n[cell]\nname = "{name}"\nsoc0 = 0.68\n')
            sc = load_scenario(p).replace(t_end=0.3)
            assert sc.ev.cell.rc_table is not None
            n0 = len(loaded)
            runs, _ = run_cycle(sc, (sc.extra["mpc"].settings.predictor,), laws=("proposed", "ovfl"))
            out[name] = (loaded[n0:], runs)
    return out


def test_identified_cells_share_one_mpc_library(cell_runs) -> None:  # noqa: ANN001
    """Every identified cell's MPC loads the same compiled step library (one library per grid, not per cell)."""
    libs = {name: set(v[0]) for name, v in cell_runs.items()}
    assert all(len(v) == 1 for v in libs.values()), libs
    assert len(set.union(*libs.values())) == 1, libs


@pytest.mark.parametrize("name", IDENTIFIED)
def test_mpc_runs_on_each_identified_cell(cell_runs, name: str) -> None:  # noqa: ANN001
    """The UDDS MPC scenario (one follower) on the cell for 3 MPC steps, and the proposed law and OVFL beside it."""
    sc = load_scenario(find_scenario("mpc_udds_single")).replace(t_end=0.3)
    runs = cell_runs[name][1]
    assert set(runs) == {("mpc", sc.extra["mpc"].settings.predictor), ("proposed", None), ("ovfl", None)}
    for r in runs.values():
        assert r.status == "ok" and r.t[-1] == pytest.approx(0.3)
        assert np.all(np.asarray(r.S) <= 0.68 + 1e-12) and np.all(np.isfinite(np.asarray(r.V1)))


def test_saved_run_of_a_table_cell_loads_back(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """aev-ocp simulate on lg_m50 writes the cell with its tables; the loaded run has the same cell (RCTable)."""
    from aev_ocp.cli import main
    from aev_ocp.saved import load_all

    p = tmp_path / "s.toml"
    p.write_text(find_scenario("udds_platoon").read_text() + '\n[cell]\nname = "lg_m50"\nsoc0 = 0.77\n')
    rc = main(["simulate", str(p), "--no-plots", "--out", str(tmp_path / "out"), "--set", "simulation.t_end=6.0"])
    capsys.readouterr()
    assert rc == 0
    runs = load_all(tmp_path / "out")
    for r in runs.values():
        assert r.ev.cell == load_scenario(p).ev.cell and isinstance(r.ev.cell.rc_table, RCTable)


def _script():  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("identify_cell", ROOT / "tools" / "identify_cell.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_script_reproduces_the_shipped_point() -> None:
    """tools/identify_cell.py's identification at one point (SOC 0.5 at 25 °C: one DFN HPPC test, the resistances
    fitted with the file's time constants) gives the shipped lg_m50 values there. Needs PyBaMM (the identify
    extra); about 5 s."""
    pytest.importorskip("pybamm", reason="the identify extra (pybamm) is not installed")
    mod = _script()
    cf = load_cell_file("lg_m50")
    if cf.identification["pybamm_version"] != __import__("pybamm").__version__:
        pytest.skip("the shipped file was identified with another PyBaMM version")
    t = cf.cell.rc_table
    assert t is not None
    k = t.T_K.index(298.15)  # the file's time constants at 25 °C: the DFN test and the linear fit of R0, R1, R2
    fit = mod.identify("lg_m50", quick=True, taus=[(cf.identification["tau1_s"][k], cf.identification["tau2_s"][k])])[
        "fit"
    ]
    for k in RC_TABLE_KEYS:
        assert fit[k][0][0] == pytest.approx(getattr(cf.cell, k), rel=1e-6), k
    assert fit["rms_V"] == pytest.approx(cf.identification["hppc_rms_V"], rel=1e-6)


def test_docs_tables_are_the_scripts_output() -> None:
    """docs/guide/cells.md's tables between the markers are markdown(identification.json) (not typed by hand)."""
    mod = _script()
    summary = json.loads((CELLS / "identification.json").read_text())
    text = (ROOT / "docs" / "guide" / "cells.md").read_text(encoding="utf-8")
    between = text.split(mod.BEGIN, 1)[1].split(mod.END, 1)[0]
    assert between == "\n" + mod.markdown(summary)
    assert set(summary) == set(IDENTIFIED)

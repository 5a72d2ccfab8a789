"""Identify 2-RC cells from PyBaMM's published parameter sets and validate them (issue 37).

Run in the ``identify`` extra (pyproject.toml: pybamm, scipy), never imported by the package::

    PYTHONPATH=. python tools/identify_cell.py                 # every cell of CELLS
    PYTHONPATH=. python tools/identify_cell.py lg_m50 --quick  # one SOC, one temperature (the reproduction test)

For each cell of :data:`CELLS`:

1. **OCV(SOC)** from the set's electrode OCPs, U_p(y(SOC)) − U_n(x(SOC)), with PyBaMM's stoichiometry
   limits at 0 and 100 % SOC (the same map PyBaMM's ``initial_soc`` uses); capacity (x100 − x0)·Q_n [A h].
2. **HPPC** on PyBaMM's DFN (isothermal at each temperature of :data:`TEMPS_K`), at each SOC of :data:`SOCS`:
   rest 10 s, discharge 1C 20 s, rest 100 s, charge 1C 20 s, rest 100 s, sampled every 0.5 s.
3. **Fit** on the terminal voltage of the 2-RC model (the toolkit's OCV interpolant, the RC branches propagated
   exactly under the held current): per temperature, time constants τ1 ∈ [0.2, 20] s < τ2 ∈ [20, 1000] s
   shared by every SOC (so the branches cannot swap and the tables stay smooth in SOC), fitted with
   ``scipy.optimize.least_squares``, and R0, R1, R2 per SOC by linear least squares inside (variable
   projection); C1 = τ1/R1, C2 = τ2/R2. Residual = RMS voltage error.
4. **Validation** at 25 °C from SOC 0.8: the per-cell current of the toolkit's UDDS platoon run (the lead
   follower, A123 pack), scaled by capacity (same C-rate), through (a) PyBaMM's DFN, (b) the toolkit's model
   of the written cell file (:mod:`aev_ocp.models.battery`, CasADi CVODES) and (c) PyBaMM's Thevenin
   equivalent circuit with the same tables. Reported: voltage RMSE DFN vs 2-RC, heat (DFN Ohmic +
   irreversible electrochemical heat vs the 2-RC Q_irr) and max |V_2RC − V_Thevenin|.

Writes ``aev_ocp/data/cells/<name>.toml``, ``<name>_ocv.csv``, ``<name>_hppc.csv`` (the 25 °C, SOC 0.5 pulse
test, for the residual test), ``identification.json`` and the tables of ``docs/guide/cells.md`` (between its markers).
The DFN (not the SPMe): one HPPC solve takes ~0.3 s with IDAKLU, so 9 SOCs × 3 temperatures × 3 cells fit
the two-core budget in about a minute of CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "aev_ocp" / "data" / "cells"
SOCS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
TEMPS_K = (283.15, 298.15, 313.15)
T_REF_K = 298.15
SOC_REF = 0.5
SAMPLE_S = 0.5
TAU1_S = (0.2, 20.0)
TAU2_S = (20.0, 1000.0)
VALIDATION_SOC0 = 0.8
RTOL = 1e-8

#: The cells: PyBaMM parameter set, chemistry for BLAST-Lite (aev_ocp.life.BLAST_MODELS), citation and the
#: values the set does not hold (with their source).
CELLS: dict[str, dict[str, Any]] = {
    "lg_m50": {
        "set": "Chen2020",
        "chemistry": "NMC",
        "description": "LG M50 (INR21700-M50) NMC811/graphite-SiOx 21700, identified from PyBaMM's Chen2020 DFN",
        "citation": "C.-H. Chen et al., Development of experimental techniques for parameterization of multi-scale "
        "lithium-ion battery models, J. Electrochem. Soc. 167 (2020) 080534",
    },
    "nca_kim2011": {
        "set": "NCA_Kim2011",
        "chemistry": "NCA",
        "description": "NCA/graphite pouch cell of Kim et al. 2011, identified from PyBaMM's NCA_Kim2011 DFN",
        "citation": "G.-H. Kim et al., Multi-domain modeling of lithium-ion batteries encompassing multi-physics in "
        "varied length scales, J. Electrochem. Soc. 158 (2011) A955-A969",
    },
    "a123_prada2013": {
        "set": "Prada2013",
        "chemistry": "LFP",
        "description": "A123 ANR26650 LFP/graphite, identified from PyBaMM's Prada2013 DFN (the physics model of "
        "the same cell as a123_anr26650, whose 2-RC values come from a measured ECM)",
        "citation": "E. Prada et al., Simplified electrochemical and thermal model of LiFePO4-graphite Li-ion "
        "batteries for fast charge applications, J. Electrochem. Soc. 159 (2012) A1508-A1519 (PyBaMM's "
        "Prada2013 set; negative-electrode OCP from Chen2020, LFP OCP from Afshar2017)",
        # the set has no thermal data: the A123 file's values (same cell)
        "thermal": {
            "heat_capacity_JpK": (67.2, "a123_anr26650.toml (Lin et al. 2014, J. Power Sources 257:1-11): same cell"),
            "surface_area_m2": (6.37e-3, "26650 geometry, d = 26 mm, L = 65 mm (as a123_anr26650.toml)"),
        },
    },
}


def pybamm_mod() -> Any:
    import pybamm

    pybamm.set_logging_level("ERROR")
    return pybamm


# --------------------------------------------------------------------------------------------- the set


def set_values(name: str, T_K: float = T_REF_K) -> Any:
    pb = pybamm_mod()
    p = pb.ParameterValues(CELLS[name]["set"])
    p.update({"Ambient temperature [K]": T_K, "Initial temperature [K]": T_K})
    return p


def ocv_and_capacity(name: str, n: int = 101) -> tuple[np.ndarray, np.ndarray, float]:
    """SOC grid, OCV [V] from the electrode OCPs and the capacity [A h] between the set's 0 and 100 % SOC."""
    pb = pybamm_mod()
    p = set_values(name)
    x0, x100, y100, y0 = pb.lithium_ion.get_min_max_stoichiometries(p)
    soc = np.linspace(0.0, 1.0, n)
    up, un = p["Positive electrode OCP [V]"], p["Negative electrode OCP [V]"]
    ocv = np.array(
        [
            float(up(pb.Scalar(y0 + s * (y100 - y0))).evaluate())
            - float(un(pb.Scalar(x0 + s * (x100 - x0))).evaluate())
            for s in soc
        ]
    )
    q_n = float(p.evaluate(pb.LithiumIonParameters().n.Q_init))
    return soc, ocv, (x100 - x0) * q_n


def lumped_heat_capacity_JpK(p: Any) -> float:
    """PyBaMM's lumped thermal model's heat capacity: the thickness-averaged ρ c_p of the stack × cell volume."""
    layers = [
        ("Negative current collector", "Negative current collector thickness [m]"),
        ("Negative electrode", "Negative electrode thickness [m]"),
        ("Separator", "Separator thickness [m]"),
        ("Positive electrode", "Positive electrode thickness [m]"),
        ("Positive current collector", "Positive current collector thickness [m]"),
    ]
    num = sum(p[f"{k} density [kg.m-3]"] * p[f"{k} specific heat capacity [J.kg-1.K-1]"] * p[th] for k, th in layers)
    den = sum(p[th] for _, th in layers)
    return float(num / den * p["Cell volume [m3]"])


# --------------------------------------------------------------------------------------------- HPPC


def hppc_experiment(capacity_Ah: float) -> Any:
    pb = pybamm_mod()
    i = capacity_Ah  # 1C
    return pb.Experiment(
        [
            "Rest for 10 s",
            f"Discharge at {i:.6g} A for 20 s",
            "Rest for 100 s",
            f"Charge at {i:.6g} A for 20 s",
            "Rest for 100 s",
        ],
        period=f"{SAMPLE_S} s",
    )


def run_hppc(
    name: str, capacity_Ah: float, socs: tuple[float, ...], T_K: float, cache: Path | None = None
) -> dict[float, np.ndarray]:
    """{soc: array of rows (t_s, I_A, V)} of the DFN HPPC test at temperature T_K (isothermal); ``cache``: a
    folder where the runs are kept (reused when present)."""
    pb = pybamm_mod()
    f = (
        None
        if cache is None
        else cache / f"hppc_{name}_{T_K:.2f}_{'_'.join(f'{s:g}' for s in socs)}_{pb.__version__}.npz"
    )
    if f is not None and f.exists():
        z = np.load(f)
        return {s: z[f"s{i}"] for i, s in enumerate(socs)}
    sim = pb.Simulation(
        pb.lithium_ion.DFN(),
        parameter_values=set_values(name, T_K),
        experiment=hppc_experiment(capacity_Ah),
        solver=pb.IDAKLUSolver(rtol=RTOL, atol=RTOL),
    )
    out = {}
    for s in socs:
        sol = sim.solve(initial_soc=s)
        out[s] = np.column_stack([sol["Time [s]"].entries, sol["Current [A]"].entries, sol["Voltage [V]"].entries])
    if f is not None:
        np.savez(f, **{f"s{i}": out[s] for i, s in enumerate(socs)})
    return out


def rc_response(data: np.ndarray, tau_s: float) -> np.ndarray:
    """Voltage [V per Ω] of an RC branch of time constant tau_s under the current of ``data`` (held between
    samples; zero at the first sample): V_k+1 = V_k e^(−Δt/τ) + I_k (1 − e^(−Δt/τ)), exact."""
    t, I = data[:, 0], data[:, 1]
    e = np.exp(-np.diff(t) / tau_s)
    v = np.zeros_like(t)
    for k in range(e.size):
        v[k + 1] = v[k] * e[k] + I[k] * (1.0 - e[k])
    return v


def ocv_of(data: np.ndarray, soc0: float, capacity_Ah: float, ocv: Any) -> np.ndarray:
    """OCV(S(t)) [V] along ``data`` with S coulomb-counted from soc0 (current held between samples)."""
    t, I = data[:, 0], data[:, 1]
    S = soc0 - np.concatenate([[0.0], np.cumsum(I[:-1] * np.diff(t))]) / (3600.0 * capacity_Ah)
    return np.asarray(ocv(S)).ravel()


def fit_resistances(
    data: np.ndarray, soc0: float, capacity_Ah: float, ocv: Any, taus: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """(R0, R1, R2) [Ω] ≥ 1e-6 by linear least squares for fixed time constants, and the voltage residual [V]:
    V = OCV(S) − R0 I − R1 h(τ1) − R2 h(τ2) is linear in the resistances."""
    from scipy.optimize import lsq_linear

    A = np.column_stack([data[:, 1], rc_response(data, taus[0]), rc_response(data, taus[1])])
    b = ocv_of(data, soc0, capacity_Ah, ocv) - data[:, 2]
    R = lsq_linear(A, b, bounds=(1e-6, np.inf), method="bvls", tol=1e-14).x
    return R, A @ R - b


def fit_temperature(
    runs: dict[float, np.ndarray], capacity_Ah: float, ocv: Any, taus: tuple[float, float] | None = None
) -> tuple[tuple[float, float], dict[float, np.ndarray], dict[float, float]]:
    """The HPPC tests of one temperature: τ1, τ2 shared by every SOC (``scipy.optimize.least_squares`` over
    log τ, the resistances of each SOC by linear least squares inside: variable projection), R0, R1, R2 per SOC
    and the RMS residual [V] per SOC. ``taus`` given: only the resistances (the reproduction test)."""
    from scipy.optimize import least_squares

    def resid(x: np.ndarray) -> np.ndarray:
        tt = (float(np.exp(x[0])), float(np.exp(x[1])))
        return np.concatenate([fit_resistances(d, s, capacity_Ah, ocv, tt)[1] for s, d in runs.items()])

    if taus is None:
        lo, hi = np.log([TAU1_S[0], TAU2_S[0]]), np.log([TAU1_S[1], TAU2_S[1]])
        best = None
        for start in ((2.0, 40.0), (6.0, 90.0), (12.0, 300.0)):  # a few starts: the fit is not convex in τ
            sol = least_squares(resid, np.log(start), bounds=(lo, hi), xtol=1e-10, ftol=1e-12, diff_step=1e-6)
            if best is None or sol.cost < best.cost:
                best = sol
        assert best is not None
        taus = (float(np.exp(best.x[0])), float(np.exp(best.x[1])))
    R, rms = {}, {}
    for s, d in runs.items():
        R[s], r = fit_resistances(d, s, capacity_Ah, ocv, taus)
        rms[s] = float(np.sqrt(np.mean(r**2)))
    return taus, R, rms


# --------------------------------------------------------------------------------------------- files


def _fmt(x: float) -> str:
    return repr(float(x))


def _row(v: np.ndarray) -> str:
    return "[" + ", ".join(_fmt(x) for x in v) + "]"


def write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w", newline="") as fh:
        fh.write(text)
    os.replace(tmp, path)


def write_cell(name: str, info: dict[str, Any], fit: dict[str, Any], version: str) -> None:
    """The cell file <name>.toml, its OCV CSV and its stored HPPC test."""
    spec = CELLS[name]
    socs, temps = fit["soc"], fit["T_K"]
    tab = {k: np.array(fit[k]) for k in ("R_s_ohm", "R1_ohm", "C1_F", "R2_ohm", "C2_F")}
    i, j = socs.index(SOC_REF), temps.index(T_REF_K)
    src = f"tools/identify_cell.py (PyBaMM {version}, {spec['set']} DFN HPPC fit)"
    ref = f"{src}: the [rc_table] value at SOC {SOC_REF:g}, {T_REF_K - 273.15:g} °C"
    th = spec.get("thermal") or {
        "heat_capacity_JpK": (
            info["heat_capacity_JpK"],
            f"PyBaMM {spec['set']}: thickness-averaged ρ c_p of the "
            "stack × cell volume (PyBaMM's lumped thermal model)",
        ),
        "surface_area_m2": (info["surface_area_m2"], f"PyBaMM {spec['set']}: Cell cooling surface area [m2]"),
    }
    lines = [
        f"# {spec['description']}.",
        f"# Generated by tools/identify_cell.py from PyBaMM {version}'s {spec['set']} parameter set; do not edit by hand.",
        f"# Parameter set: {spec['citation']}.",
        f"# HPPC fit residual (RMS terminal voltage over {len(socs)} SOCs x {len(temps)} temperatures): "
        f"{fit['rms_V'] * 1e3:.3f} mV (max per point {fit['max_rms_V'] * 1e3:.3f} mV).",
        "# Validation on the toolkit's UDDS current at 25 °C: [identification.validation] below, docs/guide/cells.md.",
        f'name = "{name}"',
        f'chemistry = "{spec["chemistry"]}"',
        f'description = "{spec["description"]}"',
        "",
        f'capacity_Ah = {{ value = {_fmt(info["capacity_Ah"])}, source = "PyBaMM {spec["set"]}: (x100 - x0) Q_n '
        "between the set's 0 and 100 % SOC stoichiometries (nominal " + f'{info["nominal_Ah"]:g} A h)" }}',
    ]
    for k in tab:
        lines.append(f'{k} = {{ value = {_fmt(tab[k][j, i])}, source = "{ref}" }}')
    lines += [
        f'max_current_A = {{ value = {_fmt(5.0 * info["capacity_Ah"])}, source = "our statement: 5C (the set '
        'states no current limit; the HPPC test probed 1C)" }',
        f'heat_capacity_JpK = {{ value = {_fmt(th["heat_capacity_JpK"][0])}, source = "{th["heat_capacity_JpK"][1]}" }}',
        f'surface_area_m2 = {{ value = {_fmt(th["surface_area_m2"][0])}, source = "{th["surface_area_m2"][1]}" }}',
        'activation_energy_Jpmol = { source = "not set: the temperature dependence is the [rc_table] over T_K" }',
        f'T_ref_K = {{ value = {_fmt(T_REF_K)}, source = "the reference point of the scalar values above" }}',
        "",
        "[ocv]",
        f'file = "{name}_ocv.csv"',
        f"source = \"PyBaMM {version} {spec['set']}: U_p(y(SOC)) - U_n(x(SOC)) at the set's stoichiometry limits, "
        '101 points"',
        "",
        "[rc_table]",
        f'source = "{src}: least-squares fit per (SOC, T) of a 10 s rest, 20 s 1C discharge, 100 s rest, 20 s 1C '
        'charge, 100 s rest"',
        f"soc = {_row(np.array(socs))}",
        f"T_K = {_row(np.array(temps))}",
        "# each table: one row per temperature (T_K), one column per SOC (soc)",
    ]
    for k, v in tab.items():
        lines.append(f"{k} = [")
        lines += [f"    {_row(r)}," for r in v]
        lines.append("]")
    lines += [
        "",
        "[identification]",
        f'parameter_set = "{spec["set"]}"',
        f'citation = "{spec["citation"]}"',
        'script = "tools/identify_cell.py"',
        f'pybamm_version = "{version}"',
        'model = "DFN"',
        f"fit_rms_V = {_fmt(fit['rms_V'])}",
        f"fit_max_rms_V = {_fmt(fit['max_rms_V'])}",
        f'hppc_file = "{name}_hppc.csv"',
        f"hppc_soc0 = {_fmt(SOC_REF)}",
        f"hppc_T_K = {_fmt(T_REF_K)}",
        f"hppc_rms_V = {_fmt(fit['rms_grid'][j][i])}",
        "# the time constants shared by every SOC, one per T_K (the fit's outer variables)",
        f"tau1_s = {_row(np.array([t[0] for t in fit['tau_s']]))}",
        f"tau2_s = {_row(np.array([t[1] for t in fit['tau_s']]))}",
        "",
    ]
    write_atomic(OUT / f"{name}.toml", "\n".join(lines))
    write_atomic(
        OUT / f"{name}_ocv.csv",
        "soc,ocv_V\n" + "".join(f"{_fmt(s)},{_fmt(v)}\n" for s, v in zip(info["ocv_soc"], info["ocv_V"])),
    )
    d = fit["hppc_ref"]
    write_atomic(
        OUT / f"{name}_hppc.csv",
        "t_s,current_A,voltage_V\n" + "".join(f"{_fmt(a)},{_fmt(b)},{_fmt(c)}\n" for a, b, c in d),
    )


# --------------------------------------------------------------------------------------------- validation


def udds_cell_current() -> tuple[np.ndarray, np.ndarray]:
    """t_s, I_A per cell [A] of the lead follower of the toolkit's UDDS platoon run (A123 cell, 2.3 A h)."""
    import aev_ocp

    r = aev_ocp.load_scenario("udds_platoon").run()
    res = r["proposed"] if isinstance(r, dict) else r
    t_s = np.asarray(res.t) * res.ev.units.time_s
    I = np.asarray(res.current_A)
    I = I[:, 0] if I.ndim == 2 and I.shape[0] == t_s.size else np.asarray(I).reshape(-1, t_s.size)[0]
    return t_s, I / res.ev.cell.capacity_Ah


def validate(name: str, version: str) -> dict[str, Any]:
    """DFN vs the toolkit's 2-RC model vs PyBaMM's Thevenin on the UDDS current (25 °C, SOC 0.8)."""
    import casadi as ca

    import aev_ocp.cells as cells
    from aev_ocp.models import battery

    pb = pybamm_mod()
    cf = cells.load_cell_file(OUT / f"{name}.toml")
    cell = cf.cell
    t_s, c_rate = udds_cell_current()
    grid = np.arange(0.0, float(t_s[-1]), 1.0)
    I = np.interp(grid, t_s, c_rate) * cell.capacity_Ah
    # (a) DFN with the current as a step function of time (held over each second: the ECM holds it too)
    p = set_values(name, T_REF_K)
    tt = np.repeat(grid, 2)[1:]  # knots (t0, t1 - 1e-4, t1, t2 - 1e-4, t2, ...): I[k] held over [t_k, t_k+1),
    ii = np.repeat(I, 2)[:-1]  # ramped to I[k+1] over the last 0.1 ms (at t_k+1 the DFN sees I[k+1], as the ECM)
    tt[1::2] -= 1e-4
    p["Current function [A]"] = pb.Interpolant(tt, ii, pb.t, interpolator="linear")
    # output at each second (the voltage), and inside each second at 0.5 s and just before the ramp (the heat,
    # trapezoidal over [t_k, t_k + 0.5, t_k+1 - 2e-4] where the current is held)
    t_eval = np.unique(np.concatenate([grid, grid[:-1] + 0.5, grid[1:] - 2e-4]))
    heat_keys = ("Ohmic heating [W]", "Irreversible electrochemical heating [W]")
    try:  # PyBaMM's heat needs the set's thermal data (Prada2013 has none: the terminal loss below only)
        model = pb.lithium_ion.DFN(options={"calculate heat source for isothermal models": "true"})
        sim = pb.Simulation(model, parameter_values=p, solver=pb.IDAKLUSolver(rtol=RTOL, atol=RTOL))
        sol = sim.solve(t_eval, initial_soc=VALIDATION_SOC0, t_interp=t_eval)  # output at t_eval only
        q_heat: np.ndarray | None = sum(sol[k].entries for k in heat_keys)
    except KeyError:
        sim = pb.Simulation(pb.lithium_ion.DFN(), parameter_values=p, solver=pb.IDAKLUSolver(rtol=RTOL, atol=RTOL))
        sol = sim.solve(t_eval, initial_soc=VALIDATION_SOC0, t_interp=t_eval)
        q_heat = None
    t_out = sol["Time [s]"].entries
    on_grid = np.isin(np.round(t_out, 9), grid)
    V_all = sol["Voltage [V]"].entries
    V_dfn = V_all[on_grid]
    starts = np.flatnonzero(on_grid)[:-1]

    def held_integral(q: np.ndarray) -> float:  # ∫ q dt over the held part of every second
        return float(sum(np.trapezoid(q[i : i + 3], t_out[i : i + 3]) for i in starts))

    # the terminal loss Q = I (OCV(S) - V) of the paper's model, S coulomb-counted, OCV the cell file's
    I_out = np.interp(t_out, tt, ii)
    S_out = VALIDATION_SOC0 - np.interp(t_out, grid, np.concatenate([[0.0], np.cumsum(I[:-1])])) / (
        3600.0 * cell.capacity_Ah
    )
    loss_dfn = held_integral(I_out * (np.asarray(battery.ocv_function(cell)(S_out.reshape(1, -1))).ravel() - V_all))
    E_dfn = None if q_heat is None else held_integral(q_heat)
    # (b) the toolkit's 2-RC cell of the written file, CVODES on the same held current
    x = ca.MX.sym("x", 3)
    u = ca.MX.sym("u")
    Tk = ca.MX(T_REF_K)
    view = battery.cell_at(cell, Tk, x[2])
    d1, d2, dS = battery.cell_derivatives(x[0], x[1], u, view)
    q = ca.vertcat(battery.heat_irreversible(x[0], x[1], u, view), battery.heat_Q(x[0], x[1], u, view))
    F = ca.integrator(
        "F",
        "cvodes",
        {"x": x, "p": u, "ode": ca.vertcat(d1, d2, dS), "quad": q},
        0.0,
        1.0,
        {"abstol": 1e-10, "reltol": 1e-10},
    )
    vt = ca.Function("vt", [x, u], [battery.terminal_voltage(x[2], x[0], x[1], u, view)])
    xk = np.array([0.0, 0.0, VALIDATION_SOC0])
    V_ecm, E_ecm, loss_ecm = [], 0.0, 0.0
    for k in range(len(grid)):
        V_ecm.append(float(vt(xk, I[k])))
        if k + 1 < len(grid):
            r = F(x0=xk, p=I[k])
            xk = np.asarray(r["xf"]).ravel()
            E_ecm += float(r["qf"][0])
            loss_ecm += float(r["qf"][1])
    V_ecm = np.array(V_ecm)
    # (c) PyBaMM's Thevenin with the same OCV spline and tables
    V_thev = thevenin(name, cell, grid, I, tt, ii)
    n = min(len(V_dfn), len(V_ecm))
    return {
        "duration_s": float(grid[-1]),
        "rms_current_A": float(np.sqrt(np.mean(I**2))),
        "soc_end": float(xk[2]),
        "voltage_rmse_V": float(np.sqrt(np.mean((V_dfn[:n] - V_ecm[:n]) ** 2))),
        "voltage_max_abs_V": float(np.max(np.abs(V_dfn[:n] - V_ecm[:n]))),
        "loss_dfn_J": loss_dfn,
        "loss_ecm_J": loss_ecm,
        "loss_rel_diff": (loss_ecm - loss_dfn) / loss_dfn,
        "heat_dfn_J": E_dfn,
        "heat_ecm_J": E_ecm,
        "heat_rel_diff": None if E_dfn is None else (E_ecm - E_dfn) / E_dfn,
        "thevenin_max_abs_V": float(np.max(np.abs(V_thev - V_ecm))),
    }


def thevenin(name: str, cell: Any, grid: np.ndarray, I: np.ndarray, tt: np.ndarray, ii: np.ndarray) -> np.ndarray:
    """PyBaMM's 2-RC Thevenin model with the cell's OCV and [rc_table] tables (linear in SOC and T), isothermal."""
    pb = pybamm_mod()
    tab = cell.rc_table
    m = pb.equivalent_circuit.Thevenin(options={"number of rc elements": 2})
    p = m.default_parameter_values
    soc_o, ocv_o = np.array(cell.ocv_soc), np.array(cell.ocv_V)
    axes = (np.array(tab.soc), np.array(tab.T_K))

    def clamp(x: Any, grid: np.ndarray) -> Any:  # the toolkit holds the end values outside the grid
        return pb.maximum(pb.minimum(x, float(grid[-1])), float(grid[0]))

    def table(key: str) -> Any:  # PyBaMM's ECM passes T_cell in °C
        vals = np.array(getattr(tab, key)).T  # (soc, T)
        return lambda T_cell, current, soc: pb.Interpolant(
            axes, vals, [clamp(soc, axes[0]), clamp(T_cell + 273.15, axes[1])], interpolator="linear"
        )

    p.update(
        {
            "Cell capacity [A.h]": cell.capacity_Ah,
            "Nominal cell capacity [A.h]": cell.capacity_Ah,
            "Initial SoC": VALIDATION_SOC0,
            "Current function [A]": pb.Interpolant(tt, ii, pb.t, interpolator="linear"),
            "Open-circuit voltage [V]": lambda sto: pb.Interpolant(soc_o, ocv_o, sto, interpolator="cubic"),
            "Entropic change [V/K]": 0.0,
            "Cell thermal mass [J/K]": 1e20,
            "Upper voltage cut-off [V]": 10.0,
            "Lower voltage cut-off [V]": 0.0,
            "R0 [Ohm]": table("R_s_ohm"),
            "R1 [Ohm]": table("R1_ohm"),
            "C1 [F]": table("C1_F"),
            "R2 [Ohm]": table("R2_ohm"),
            "C2 [F]": table("C2_F"),
            "Element-2 initial overpotential [V]": 0.0,
        },
        check_already_exists=False,
    )
    sim = pb.Simulation(m, parameter_values=p, solver=pb.CasadiSolver(rtol=1e-10, atol=1e-10, mode="fast"))
    sol = sim.solve(grid)
    return np.asarray(sol["Voltage [V]"].entries)


# --------------------------------------------------------------------------------------------- main


def identify(
    name: str, quick: bool = False, taus: list[tuple[float, float]] | None = None, cache: Path | None = None
) -> dict[str, Any]:
    """OCV, capacity, HPPC fit tables of one cell (quick: SOC 0.5 at 25 °C only; taus: the time constants per
    temperature, fixed; cache: a folder keeping the DFN runs)."""
    import casadi as ca

    pb = pybamm_mod()
    soc_o, ocv_o, cap = ocv_and_capacity(name)
    ocv = ca.interpolant("ocv", "bspline", [soc_o], ocv_o)  # the toolkit's OCV interpolant (models/battery.py)
    socs = (SOC_REF,) if quick else SOCS
    temps = (T_REF_K,) if quick else TEMPS_K
    p = set_values(name)
    info = {
        "capacity_Ah": cap,
        "nominal_Ah": float(p["Nominal cell capacity [A.h]"]),
        "ocv_soc": soc_o,
        "ocv_V": ocv_o,
    }
    if "thermal" not in CELLS[name]:
        info["heat_capacity_JpK"] = lumped_heat_capacity_JpK(p)
        info["surface_area_m2"] = float(p["Cell cooling surface area [m2]"])
    keys = ("R_s_ohm", "R1_ohm", "C1_F", "R2_ohm", "C2_F")
    fit: dict[str, Any] = {"soc": list(socs), "T_K": list(temps), **{k: [] for k in keys}, "rms_grid": []}
    fit["tau_s"] = []
    for T in temps:
        runs = run_hppc(name, cap, socs, T, cache)
        fixed = None if taus is None else taus[temps.index(T)]
        (t1, t2), R, rms = fit_temperature(runs, cap, ocv, fixed)
        fit["tau_s"].append([t1, t2])
        rows: dict[str, list[float]] = {k: [] for k in keys}
        for s in socs:
            R0, R1, R2 = R[s]
            for k, v in zip(keys, (R0, R1, t1 / R1, R2, t2 / R2)):
                rows[k].append(float(v))
            if s == SOC_REF and T == T_REF_K:
                fit["hppc_ref"] = runs[s]
            print(
                f"{name} T={T:.2f} K SOC={s:.2f}: R0={R0 * 1e3:.3f} R1={R1 * 1e3:.3f} mOhm tau1={t1:.2f} s "
                f"R2={R2 * 1e3:.3f} mOhm tau2={t2:.1f} s rms={rms[s] * 1e3:.3f} mV",
                flush=True,
            )
        for k in keys:
            fit[k].append(rows[k])
        fit["rms_grid"].append([rms[s] for s in socs])
    g = np.array(fit["rms_grid"])
    fit["rms_V"] = float(np.sqrt(np.mean(g**2)))
    fit["max_rms_V"] = float(g.max())
    return {"info": info, "fit": fit, "version": pb.__version__}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cells", nargs="*", default=list(CELLS), help=f"cells to identify (default: {', '.join(CELLS)})")
    ap.add_argument("--quick", action="store_true", help="SOC 0.5 at 25 °C only; print the fit, write nothing")
    ap.add_argument("--no-validation", action="store_true", help="skip the UDDS validation")
    ap.add_argument("--hppc-cache", type=Path, help="a folder keeping the DFN HPPC runs between invocations")
    a = ap.parse_args(argv)
    unknown = [c for c in a.cells if c not in CELLS]
    if unknown:
        ap.error(f"unknown cell {unknown[0]!r}; known: {', '.join(CELLS)}")
    summary_path = OUT / "identification.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    for name in a.cells:
        taus = None
        if a.quick and (OUT / f"{name}.toml").exists():  # the shipped time constants at 25 °C: only R0, R1, R2
            import tomllib

            doc = tomllib.loads((OUT / f"{name}.toml").read_text())
            ident, k = doc["identification"], doc["rc_table"]["T_K"].index(T_REF_K)
            taus = [(ident["tau1_s"][k], ident["tau2_s"][k])]
        r = identify(name, a.quick, taus, a.hppc_cache)
        f = r["fit"]
        if a.quick:
            print(json.dumps({k: f[k] for k in ("R_s_ohm", "R1_ohm", "C1_F", "R2_ohm", "C2_F", "rms_V")}))
            continue
        write_cell(name, r["info"], f, r["version"])
        entry = {
            "parameter_set": CELLS[name]["set"],
            "chemistry": CELLS[name]["chemistry"],
            "pybamm_version": r["version"],
            "model": "DFN",
            "capacity_Ah": r["info"]["capacity_Ah"],
            "fit_rms_V": f["rms_V"],
            "fit_max_rms_V": f["max_rms_V"],
        }
        if not a.no_validation:
            entry["validation"] = v = validate(name, r["version"])
            print(name, json.dumps(v), flush=True)
            lines = [
                "",
                "[identification.validation]",
                f"# the UDDS current at {T_REF_K - 273.15:g} °C from SOC {VALIDATION_SOC0:g}: the DFN against this file's "
                "2-RC model (CVODES) and PyBaMM's Thevenin model with these tables (docs/guide/cells.md)",
            ] + [f"{k} = {_fmt(x)}" for k, x in v.items() if x is not None]
            path = OUT / f"{name}.toml"
            write_atomic(path, path.read_text() + "\n".join(lines) + "\n")
        summary[name] = entry
        write_atomic(summary_path, json.dumps(summary, indent=2, sort_keys=True) + "\n")
    if not a.quick:
        write_docs(summary)
    return 0


DOCS = ROOT / "docs" / "guide" / "cells.md"
BEGIN, END = "<!-- identify_cell: begin -->", "<!-- identify_cell: end -->"


def write_docs(summary: dict[str, Any]) -> None:
    """The tables of :func:`markdown` between the markers of docs/guide/cells.md."""
    text = DOCS.read_text(encoding="utf-8")
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    write_atomic(DOCS, head + BEGIN + "\n" + markdown(summary) + END + tail)


def markdown(summary: dict[str, Any]) -> str:
    """The docs page's tables (docs/guide/cells.md, between the markers)."""
    out = [
        "| cell | set | chemistry | capacity [A h] | HPPC fit RMS [mV] | worst point [mV] |",
        "|---|---|---|---|---|---|",
    ]
    for n, e in sorted(summary.items()):
        out.append(
            f"| `{n}` | {e['parameter_set']} | {e['chemistry']} | {e['capacity_Ah']:.4g} | {e['fit_rms_V'] * 1e3:.3f} "
            f"| {e['fit_max_rms_V'] * 1e3:.3f} |"
        )
    out += [
        "",
        "| cell | UDDS RMS current [A] | V RMSE DFN vs 2-RC [mV] | max abs [mV] | terminal loss DFN [J] | "
        "2-RC [J] | difference | irreversible heat DFN [J] | 2-RC Q_irr [J] | difference | "
        "max abs 2-RC vs PyBaMM Thevenin [V] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n, e in sorted(summary.items()):
        v = e.get("validation")
        if v is None:
            continue
        heat = (
            ["n/a (no thermal data in the set)", f"{v['heat_ecm_J']:.4g}", "n/a"]
            if v["heat_dfn_J"] is None
            else [f"{v['heat_dfn_J']:.4g}", f"{v['heat_ecm_J']:.4g}", f"{v['heat_rel_diff'] * 100:+.1f} %"]
        )
        out.append(
            f"| `{n}` | {v['rms_current_A']:.3g} | {v['voltage_rmse_V'] * 1e3:.2f} | {v['voltage_max_abs_V'] * 1e3:.2f} "
            f"| {v['loss_dfn_J']:.4g} | {v['loss_ecm_J']:.4g} | {v['loss_rel_diff'] * 100:+.1f} % | "
            + " | ".join(heat)
            + f" | {v['thevenin_max_abs_V']:.1e} |"
        )
    first = next(iter(summary.values()), {})
    out += [
        "",
        f"PyBaMM {first.get('pybamm_version', '?')}, model {first.get('model', '?')}; "
        "generated by tools/identify_cell.py (identification.json).",
    ]
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    sys.exit(main())

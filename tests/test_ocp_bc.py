"""OCP-B (current profile), OCP-C (eco-trip), failures and the transcription layer's contract:
independent re-simulation with scipy, transcription agreement, clear failure statuses."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import cell_oracle
from cell_oracle import cell_rhs
from aev_ocp.models.battery import ocv_function
from aev_ocp.ocp.current_profile import CurrentProfileSolver, compare_profiles
from aev_ocp.ocp.eco_trip import EcoTrip, EcoTripSolver
from aev_ocp.ocp.transcription import TranscriptionOptions
from aev_ocp.params import CellParams, EVParams, ParameterError

CELL = CellParams()
EV = EVParams()
OCV = ocv_function()


def resim_cell(t, I, S0=0.5):
    return cell_oracle.resim_cell(t, I, [0, 0, S0, 0, 0], rtol=1e-10, atol=1e-12)


@pytest.fixture(scope="module")
def ocp_b():
    return {m: CurrentProfileSolver(m, N=100) for m in ("ms", "collocation")}


def test_ocp_b_resimulated_and_beats_references(ocp_b):
    out = {m: compare_profiles(3000.0, 60.0, solver=s) for m, s in ocp_b.items()}
    r = out["ms"]["result"]
    assert r.status == "optimal"
    assert r.objective == pytest.approx(out["collocation"]["result"].objective, rel=1e-4)
    np.testing.assert_allclose(r.controls["I"], out["collocation"]["result"].controls["I"], atol=2e-3)
    y = resim_cell(r.t, r.controls["I"])
    assert y[3] == pytest.approx(3000.0, rel=1e-6)  # delivers E_req
    assert y[4] == pytest.approx(r.objective, rel=1e-6)  # same ∫Q
    assert np.max(np.abs(r.controls["I"])) <= 46 + 1e-9

    # constant current, found independently with brentq + solve_ivp
    def energy(I):
        return solve_ivp(cell_rhs(I), (0, 60), [0, 0, 0.5, 0, 0], rtol=1e-10, atol=1e-12).y[3, -1] - 3000.0

    Ic = brentq(energy, 1.0, 46.0, xtol=1e-10)
    q_cc = solve_ivp(cell_rhs(Ic), (0, 60), [0, 0, 0.5, 0, 0], rtol=1e-10, atol=1e-12).y[4, -1]
    ref = out["ms"]["references"]
    assert ref["constant_current"]["current_A"] == pytest.approx(Ic, rel=1e-6)
    assert ref["constant_current"]["heat_J"] == pytest.approx(q_cc, rel=1e-6)
    assert ref["constant_power"]["energy_J"] == pytest.approx(3000.0, rel=1e-6)
    # the optimum is at least as good as both (up to discretisation), strictly better than CC
    assert r.objective < q_cc
    assert r.objective < ref["constant_power"]["heat_J"]


def test_ocp_b_infeasible_demand_reports_status(ocp_b):
    r = ocp_b["ms"].solve(E_req=50_000.0, t_f=60.0)
    assert not r.success
    assert r.status in ("infeasible", "restoration_failed")
    assert "E_req" in r.message
    ref = compare_profiles(50_000.0, 60.0, solver=ocp_b["ms"])
    assert not ref["references"]["constant_current"]["feasible"]
    assert not ref["references"]["constant_power"]["feasible"]
    # the solver is reusable after a failure (parametric, not rebuilt)
    ok = ocp_b["ms"].solve(E_req=2000.0, t_f=60.0)
    assert ok.status == "optimal"


def test_warm_start_resolve(ocp_b):
    s = ocp_b["collocation"]
    s.solve(E_req=2500.0, t_f=60.0)  # the solve the next one warm-starts from
    r2 = s.solve(E_req=2600.0, t_f=60.0, warm=True)
    r3 = s.solve(E_req=2600.0, t_f=60.0)
    assert r2.status == "optimal" and r2.objective == pytest.approx(r3.objective, rel=1e-7)
    assert r2.iterations <= r3.iterations


def resim_vehicle(t, a, trip, exact=True):
    """scipy re-simulation of the eco-trip with the exact η switch: x, v, cell, pack ∫Q."""
    veh, cell, n = EV.vehicle, EV.cell, EV.pack.n_cells
    y = np.array([0, trip.v0_mps, 0, 0, trip.S0, 0], float)
    for k in range(a.size):
        ak = a[k]

        def f(_t, z):
            x, v, V1, V2, S, _ = z
            Pw = (
                veh.mass_kg * ak
                + 0.5 * veh.air_density_kgpm3 * veh.frontal_area_m2 * veh.drag_coefficient * v**2
                + veh.rolling_coefficient * veh.mass_kg * veh.gravity_mps2
            ) * v
            if exact:
                Pb = Pw / veh.efficiency if Pw > 0 else veh.efficiency * Pw
            else:
                sg = 0.5 * (1 + np.tanh(Pw / 300.0))
                Pb = Pw * (sg / veh.efficiency + (1 - sg) * veh.efficiency)
            Pc = Pb / n
            E = float(OCV(S)) - V1 - V2
            I = 2 * Pc / (E + np.sqrt(max(E**2 - 4 * cell.R_s_ohm * Pc, 0)))
            return [
                v,
                ak,
                -V1 / cell.tau1_s + I / cell.C1_F,
                -V2 / cell.tau2_s + I / cell.C2_F,
                -I / (3600 * cell.capacity_Ah),
                n * (I * (V1 + V2) + cell.R_s_ohm * I**2),
            ]

        y = solve_ivp(f, (t[k], t[k + 1]), y, rtol=1e-10, atol=1e-10, max_step=0.05).y[:, -1]
    return y


@pytest.fixture(scope="module")
def ocp_c():
    trip = EcoTrip()
    # N = 50 (issue 40; was 100): the methods agree to 1.4e-6 in the objective and 2.7e-5 in v (1.5e-7 and 4.5e-7 at
    # N = 100), the re-simulations to 7e-7 (1.7e-6), the reported heat to 3.2e-7 (1.7e-7): inside every bound below
    return trip, {m: EcoTripSolver(trip, m, N=50).solve() for m in ("ms", "collocation")}


def test_ocp_c_agree_and_resimulate(ocp_c):
    trip, res = ocp_c
    a, b = res["ms"], res["collocation"]
    assert a.status == "optimal" and b.status == "optimal"
    assert a.objective == pytest.approx(b.objective, rel=1e-4)
    np.testing.assert_allclose(a.states["v"], b.states["v"], atol=1e-3)
    assert np.all(a.states["v"] >= -1e-7) and np.all(a.states["v"] <= trip.v_max_mps + 1e-7)
    assert np.all(np.abs(a.I) <= 46 + 1e-6)
    # smoothed model, independent integrator: distance, final speed and the objective (kJ) agree
    ys = resim_vehicle(a.t, a.controls["a"], trip, exact=False)
    assert ys[0] == pytest.approx(trip.distance_m, rel=1e-6)
    assert ys[1] == pytest.approx(trip.vf_mps, abs=1e-6)
    assert ys[5] / 1000 == pytest.approx(a.objective, rel=1e-5)
    # exact η switch (what a simulator would use): same trip, heat within a few per cent
    ye = resim_vehicle(a.t, a.controls["a"], trip, exact=True)
    assert ye[0] == pytest.approx(trip.distance_m, rel=1e-9)
    assert abs(ye[5] / 1000 - a.objective) < 0.05 * a.objective
    # the reported metrics are the exact model's: heat as SciPy's exact re-simulation, and ω by the
    # closed form Σ g(a_k)(v_k + v_k+1)/2·dt for piecewise-constant a (model guide §10)
    assert a.meta["pack_heat_J"] == pytest.approx(ye[5], rel=1e-6)
    eta, ak, v = trip.ev.vehicle.efficiency, a.controls["a"], a.states["v"]
    g = np.where(ak >= 0, ak / eta, eta * ak)
    assert a.meta["omega_J_per_kg"] == pytest.approx(float(np.sum(g * 0.5 * (v[1:] + v[:-1]) * np.diff(a.t))), rel=1e-6)


def test_ocp_c_infeasible_and_bad_input():
    s = EcoTripSolver(EcoTrip(), "collocation", N=40)
    r = s.solve(dataclasses.replace(s.trip, distance_m=6000.0))
    assert not r.success and r.status in ("infeasible", "restoration_failed")
    assert "6000 m in 100 s" in r.message
    with pytest.raises(ParameterError, match="distance_m"):
        EcoTrip(distance_m=-1.0)
    with pytest.raises(ParameterError, match="x0"):
        s.solver.solve([0.0, 1.0], 10.0, p=[100.0, 0.0])
    with pytest.raises(ParameterError, match="method"):
        TranscriptionOptions(method="shooting")


def test_iteration_limit_is_reported_and_result_io(tmp_path):
    s = EcoTripSolver(EcoTrip(), "ms", N=40, max_iter=2)
    r = s.solve()
    assert r.status == "iteration_limit" and not r.success
    assert r.max_violation > 0
    r.to_json(tmp_path / "r.json")
    js = json.loads((tmp_path / "r.json").read_text())
    assert js["status"] == "iteration_limit" and js["iterations"] == 2
    r.to_csv(tmp_path / "r.csv")
    rows = (tmp_path / "r.csv").read_text().splitlines()
    assert len(rows) == 42 and rows[0].startswith("t_s,x,v,V1,V2,S,a,I")

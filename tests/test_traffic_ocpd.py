"""OCP-D of the traffic formulation (the MPC's own offline optimum) and ``cost_traffic`` of every run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aev_ocp.models.ego import battery_side
from aev_ocp.mpc import MPCSettings
from aev_ocp.mpc.run import run_comparison
from aev_ocp.ocp.following import following_problem
from aev_ocp.ocp.oracle import OracleScenario, OracleSolver, leader_forecast, scenario_oracle
from aev_ocp.ocp.formulation import traffic_formulation
from aev_ocp.ocp.traffic import TrafficParams, traffic_problem
from aev_ocp.ocp.traffic_cost import cost_traffic_of_trajectory
from aev_ocp.params import EVParams, ParameterError, PowertrainOptions, Units
from aev_ocp.scenarios import find_scenario, load_scenario


def _numpy_traffic_cost(
    ev: EVParams,
    tp: TrafficParams,
    t: np.ndarray,
    z: np.ndarray,
    a: np.ndarray,
    v_hat: np.ndarray,
    smooth: PowertrainOptions,
) -> float:
    """The traffic objective written out in SI from its definition (aev_ocp/ocp/traffic.py docstring), with
    the epigraph at v g(a), the slack at the smallest σ ≥ 0 and a_prev the previously applied a (0 at t_0)."""
    u = ev.units
    T, L, U, A = u.time_s, u.length_m, u.speed_mps, u.speed_mps / u.time_s
    eta, m = ev.vehicle.efficiency, ev.vehicle.mass_kg
    h, v, vl = z[0] * L, z[1] * U, v_hat * U
    a_si, dt_s = a * A, np.diff(t) * T
    a_prev = np.concatenate([[0.0], a_si[:-1]])
    total = 0.0
    for k in range(a.size):
        e = max(v[k] * a_si[k] / eta, eta * v[k] * a_si[k])
        q = float(battery_side(z[1, k], a[k], z[2, k], z[3, k], z[4, k], ev, smooth)["Q_pack"])  # W, the model's
        h_des = tp.target_gap_m + tp.target_time_gap_s * v[k]
        sig = max(
            0.0,
            tp.standstill_gap_m + tp.time_headway_s * v[k] - h[k],
            tp.standstill_gap_m
            + tp.reaction_time_s * v[k]
            + (v[k] ** 2 - vl[k] ** 2) / (2 * tp.brake_decel_mps2)
            - h[k],
        )
        ell = (
            tp.omega_weight * e
            + tp.heat_weight * q / m
            + tp.accel_weight * a_si[k] ** 2
            + tp.jerk_weight * ((a_si[k] - a_prev[k]) / dt_s[k]) ** 2
            + tp.relative_speed_weight * (vl[k] - v[k]) ** 2
            + tp.gap_weight * (h[k] - h_des) ** 2
            + tp.safe_penalty * sig
            + 1e-3 * sig**2
        )
        total += ell * dt_s[k]
    return total + tp.terminal_gap_weight * (h[-1] - tp.target_gap_m - tp.target_time_gap_s * v[-1]) ** 2


def test_cost_traffic_equals_a_numpy_evaluation_in_si() -> None:
    """Five intervals at non-default units and weights, accelerating and braking, one gap below the headway
    bound and one below the braking-distance bound (slack > 0), one at rest: the problem's own interval
    function with the auxiliary controls at their optimum equals the hand-written SI cost."""
    ev = EVParams(units=Units(13.0, 11.0))
    tp = TrafficParams(jerk_weight=0.7, gap_weight=0.03, relative_speed_weight=0.2, terminal_gap_weight=1.3)
    smooth = PowertrainOptions()
    dt = 0.13
    pr = traffic_problem(ev, tp, dt, smooth).build()
    t = np.arange(6) * dt
    z = np.array(
        [
            [0.9, 0.23, 0.31, 0.55, 0.72, 0.81],  # h: 0.23 L = 3 m is below 2 m + 1 s·v
            [0.85, 0.93, 0.62, 0.0, 0.37, 0.41],
            [0.012, 0.021, -0.013, 0.004, 0.007, 0.009],
            [0.003, 0.006, -0.002, 0.001, 0.002, 0.002],
            [0.8, 0.7994, 0.7991, 0.7991, 0.7989, 0.7987],
        ]
    )
    a = np.array([0.45, -1.7, 0.0, 0.62, -0.33])
    v_hat = np.array([0.7, 1.35, 0.35, 0.15, 0.52])
    got = cost_traffic_of_trajectory(pr, t, z, a, np.vstack([v_hat, v_hat]))
    want = _numpy_traffic_cost(ev, tp, t, z, a, v_hat, smooth)
    assert got["total"] == pytest.approx(want, rel=1e-10)
    assert got["terminal"] > 0 and got["stage"] + got["terminal"] == pytest.approx(got["total"])


def test_cost_traffic_refuses_a_problem_without_the_traffic_controls() -> None:
    pr = following_problem(EVParams()).build()
    t = np.linspace(0.0, 0.3, 4)
    z = np.tile(np.array([[0.5], [1.0], [0.0], [0.0], [0.8]]), (1, 4))
    with pytest.raises(ParameterError, match="omega_rate"):
        cost_traffic_of_trajectory(pr, t, z, np.zeros(3), np.ones((2, 3)))
    with pytest.raises(ParameterError, match="formulation"):
        OracleScenario(formulation="traffic")  # a Formulation, not its name


@pytest.fixture(scope="module")
def paper_traffic() -> object:
    """The paper leader, a traffic MPC on the oracle forecast, 4 time units (40 steps), vs the proposed law."""
    sc = load_scenario(find_scenario("mpc_paper_single")).replace(t_end=4.0)
    s = MPCSettings(N=15, predictor="oracle")
    return sc, s, run_comparison(sc, s, laws=("proposed",), formulation=traffic_formulation())


def test_traffic_ocpd_bounds_the_traffic_mpc_on_its_grid(paper_traffic) -> None:
    sc, s, c = paper_traffic
    o = c.ocpd
    assert o["success"] and o["objective"] == "traffic objective (the MPC's)" and o["grid_dt"] == pytest.approx(s.dt)
    assert o["N"] == 40 and not c.warnings
    mpc, law = c.metrics["mpc"][0]["cost_traffic"], c.metrics["proposed"][0]["cost_traffic"]
    # the bound holds on the same grid (up to the exact plant vs the optimiser's RK4/smoothed model: 1e-4)
    assert o["cost_traffic"] <= mpc * (1 + 1e-4) and o["cost_traffic"] <= law
    # OCP-D's controls replayed through the exact plant cost what the optimiser predicted (measured: 5e-7;
    # the exact plant vs the optimiser's RK4 and smoothed η switch)
    assert o["cost_traffic_replayed"] == pytest.approx(o["cost_traffic"], rel=1e-5)
    assert "cost_s9" in o and "cost_s9" in c.metrics["mpc"][0]  # §9's cost stays beside it
    # ... in a secondary table only, where OCP-D is not called a bound (it does not optimise §9's cost)
    from aev_ocp.mpc.report import comparison_table

    whole, other = comparison_table(c, views=False).split("Another formulation's cost")
    assert "ocp-d (bound)" in whole and "cost_s9" not in whole
    assert "cost_s9" in other and "(bound)" not in other and "no verdict" in other


def test_cost_traffic_of_a_simulation_result_equals_numpy(paper_traffic) -> None:
    """cost_traffic of a run (the MPC's closed loop and the proposed law's: a SimulationResult) equals the
    hand-written SI cost on the run's samples at the MPC's nodes (v̂_l = the leader's speed at t_k; the
    law's run is sampled more finely, so its nodes are interpolated as cost_traffic_of_result does)."""
    from aev_ocp.ocp.traffic_cost import cost_traffic_of_result

    sc, s, c = paper_traffic
    f = traffic_formulation()
    pr = traffic_problem(sc.ev, f.traffic, s.dt, f.smooth).build()
    tg = np.arange(41) * s.dt
    for lab in ("mpc", "proposed"):
        r = c.results[lab]
        if lab == "mpc":  # the MPC's nodes are samples of its run
            assert np.allclose(r.t[np.searchsorted(r.t, tg - 1e-9)], tg)

        def at(y: np.ndarray) -> np.ndarray:
            return np.interp(tg, r.t, y)

        z = np.vstack([at(r.gap[:, 0]), at(r.speed[:, 0]), at(r.V1[:, 0]), at(r.V2[:, 0]), at(r.S[:, 0])])
        want = _numpy_traffic_cost(sc.ev, f.traffic, tg, z, at(r.accel[:, 0])[:-1], at(r.leader_speed)[:-1], f.smooth)
        got = cost_traffic_of_result(r, 0, s.dt, pr)["total"]
        assert got == pytest.approx(want, rel=1e-9), lab
        assert got == pytest.approx(c.metrics[lab][0]["cost_traffic"], rel=1e-12)


@pytest.mark.parametrize("name, t_end", [("mpc_paper_single", 4.0), ("mpc_udds_single", 20.0)])
def test_traffic_ocpd_objective_equals_cost_traffic_of_its_own_trajectory(name: str, t_end: float) -> None:
    """The NLP objective is the traffic cost re-evaluated on the optimum's states and a (slack and epigraph
    recomputed, a_prev shifted), to the solver's tolerance; a different initial a_prev changes it. (Behind
    UDDS at rest the slack is inactive: IPOPT's default 1e-8 bound relaxation made it −1e-8 and the
    objective 4.5e-5 too low.)"""
    sc, s, f = load_scenario(find_scenario(name)).replace(t_end=t_end), MPCSettings(), traffic_formulation()
    scn = scenario_oracle(sc, s.dt, f)
    res = OracleSolver(scn, time_limit_s=None).solve()
    assert res.success and abs(res.states["a_prev"][0]) < 1e-12
    t = np.linspace(0.0, scn.t_end, scn.N + 1)
    z = np.vstack([res.states[k] for k in ("h", "v", "V1", "V2", "S")])
    w = np.vstack(leader_forecast(scn.leader, t))
    pr = traffic_problem(scn.ev, f.traffic, scn.dt, f.smooth).build()
    got = cost_traffic_of_trajectory(pr, t, z, res.controls["a"], w)["total"]
    assert got == pytest.approx(res.objective, rel=1e-7)
    assert res.meta["cost_terms"]["total"] == pytest.approx(got, rel=1e-12)
    other = cost_traffic_of_trajectory(pr, t, z, res.controls["a"], w, a_prev0=0.37)["total"]
    assert other > got * (1 + 1e-4)


def test_s9_comparison_keeps_its_ocpd(tmp_path) -> None:
    """The §9 formulation: OCP-D of §9's cost as before, no cost_traffic anywhere."""
    sc = load_scenario(find_scenario("mpc_paper_single")).replace(t_end=1.0)
    s, f = sc.extra["mpc"].settings, sc.extra["mpc"].formulation
    c = run_comparison(sc, laws=())
    assert c.ocpd["objective"] == "model guide §9 cost" and "cost_traffic" not in c.ocpd
    assert "cost_traffic" not in c.metrics["mpc"][0]
    direct = OracleSolver(scenario_oracle(sc, s.dt, f)).solve()
    assert c.ocpd["cost_s9"] == direct.objective


def test_coarse_grid_traffic_ocpd_is_a_reference(monkeypatch, paper_traffic) -> None:
    """A traffic OCP-D on a coarser grid: its controls are replayed on the MPC's grid (held, not interpolated)
    and that replay's cost_traffic is reported, said so; the MPC-grid OCP-D stays below it (the bound)."""
    import aev_ocp.ocp.oracle as oracle

    sc, s, _ = paper_traffic
    fine = run_comparison(sc.replace(t_end=2.0), s, laws=(), formulation=traffic_formulation()).ocpd
    monkeypatch.setattr(oracle, "oracle_grid_dt", lambda t_end, dt, units, **kw: 2 * dt)
    c = run_comparison(sc.replace(t_end=2.0), s, laws=(), formulation=traffic_formulation())
    o = c.ocpd
    assert o["grid_dt"] == pytest.approx(2 * s.dt) and o["N"] == 10 and fine["N"] == 20
    np.testing.assert_allclose(np.diff(c.results["ocp-d"].t), s.dt, rtol=1e-9)  # replayed on the MPC's grid
    a = c.results["ocp-d"].accel[:, 0]
    np.testing.assert_array_equal(a[0:-1:2], a[1::2])  # each command held for two MPC steps
    assert o["cost_traffic"] == o["cost_traffic_replayed"] != o["cost_traffic_grid"]
    assert fine["cost_traffic"] <= o["cost_traffic"]
    assert any("coarser grid" in w and "cost_traffic" in w for w in c.warnings)


def test_cli_writes_the_traffic_ocpd_row(tmp_path, capsys) -> None:
    from cli_helpers import run_cli

    rc, out, err = run_cli(
        ["mpc", "mpc_udds_single", "--set", "simulation.t_end=20", "--out", str(tmp_path), "--laws", "proposed"], capsys
    )
    assert rc == 0 and "cost_s9 row only" not in err
    row = next(ln for ln in out.splitlines() if ln.startswith("cost_traffic"))
    assert len(row.split()) == 4  # mpc, proposed, ocp-d
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["ocp_d"]["objective"] == "traffic objective (the MPC's)"
    assert 0 < res["ocp_d"]["cost_traffic"] <= res["metrics"]["mpc"][0]["cost_traffic"]
    assert res["metrics"]["proposed"][0]["cost_traffic"] > 0


def test_held_plan_never_commands_a_reverse() -> None:
    """The coarse OCP-D's replay on the MPC's grid: the plan's a_k, but never below −v_k/dt (no reverse)."""
    from aev_ocp.control import Observation
    from aev_ocp.ocp.oracle import HeldPlan as _HeldPlan, on_grid as _on_grid

    a = _on_grid(np.array([0.4, -2.5, 0.7]), 0.3, 0.1, 0.9)
    np.testing.assert_array_equal(a, [0.4, 0.4, 0.4, -2.5, -2.5, -2.5, 0.7, 0.7, 0.7])
    plan = _HeldPlan(tuple(a), 0.1, "ocp-d")

    def obs(t: float, v: float) -> Observation:
        return Observation(t, 0.1, 0, np.array([0.6, v, 0.0, 0.0, 0.8]), np.zeros(1), np.zeros(1))

    assert plan.command(obs(0.4, 0.13)).a == pytest.approx(-1.3)  # −v/dt: stops in one step
    assert plan.command(obs(0.4, 0.9)).a == -2.5 and plan.command(obs(0.7, 0.0)).a == 0.7


def test_runs_that_stop_early_report_no_cost() -> None:
    """A run ended by an event (here every controller collides: 4.5 m behind at 32 m/s, units (15 m, 17 m/s))
    is costed over part of the horizon only: its cost_traffic / cost_s9 are NaN with a warning, not a number
    that undercuts the bound; the OCP-D optimum itself stays (its replay stopped too)."""
    import dataclasses

    sc = load_scenario(find_scenario("mpc_paper_single")).replace(t_end=2.0)
    u = Units(15.0, 17.0)
    sc = sc.replace(ev=dataclasses.replace(sc.ev, units=u), units=u)
    c = run_comparison(sc, MPCSettings(N=10, predictor="oracle"), laws=("proposed",), formulation=traffic_formulation())
    assert c.results["mpc"].events and np.isnan(c.metrics["mpc"][0]["cost_traffic"])
    assert np.isnan(c.metrics["mpc"][0]["cost_s9"]) and np.isfinite(c.metrics["proposed"][0]["cost_traffic"])
    assert any(w.startswith("run mpc stopped early") for w in c.warnings)
    assert c.ocpd["success"] and np.isfinite(c.ocpd["cost_traffic"]) and np.isnan(c.ocpd["cost_traffic_replayed"])
    assert any("OCP-D replay stopped early" in w for w in c.warnings)


def test_held_plan_never_brakes_at_a_stop() -> None:
    """A coarse plan replayed on the MPC's grid: no command below −v/dt, and none below 0 at a stop (a tiny
    speed would otherwise shrink geometrically without reaching 0 and stall the plant's integrator)."""
    from aev_ocp.control import Observation
    from aev_ocp.ocp.oracle import HeldPlan as _HeldPlan

    plan = _HeldPlan((-2.5, -2.5, 0.7), 0.1, "ocp-d")

    def cmd(t: float, v: float) -> float:
        return plan.command(
            Observation(
                t=t, dt=0.1, vehicle=0, z=np.array([0.5, v, 0.0, 0.0, 0.8]), meas_t=np.zeros(1), meas_v=np.zeros(1)
            )
        ).a

    assert cmd(0.0, 0.13) == pytest.approx(-1.3) and cmd(0.1, 0.4) == -2.5
    assert cmd(0.1, 1e-12) == 0.0 and cmd(0.2, 0.0) == 0.7

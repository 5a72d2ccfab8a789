"""The traffic formulation of the MPC (aev_ocp/ocp/traffic.py, issue 8): SI parameters (same closed loop
under two [units]), exact soft constraints, the RTI Hessian projection, the per-step budget, and a short
drive-cycle closed loop with a measured forecast."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from aev_ocp.loop import fallback_causes
from aev_ocp.models import drive_cycle
from aev_ocp.models.leader import SpeedTrace
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.mpc.controller import RTI_HESSIAN_FLOOR, MPCController
from aev_ocp.ocp.formulation import formulation_from_dict, traffic_formulation
from aev_ocp.ocp.traffic import TrafficParams, traffic_bounds
from aev_ocp.params import EVParams, ParameterError, Units

DT_S = 0.23  # [s] the MPC interval in SI for the two-units test (not a special value)


def _si_leader(units: Units) -> SpeedTrace:
    """An SI leader: 7.3 m/s, accelerates to 13.1 m/s, brakes to 4.2 m/s (times in s)."""
    return SpeedTrace.from_si(
        np.array([0.0, 1.5, 5.5, 7.0, 9.5, 30.0]), np.array([7.3, 7.3, 13.1, 13.1, 4.2, 4.2]), units
    )


def _run_si(units: Units, t_end_s: float) -> tuple[np.ndarray, ...]:
    ev = EVParams(units=units)
    dt = DT_S / units.time_s
    s = MPCSettings(N=12, dt=dt, codegen=False, predictor="constant-velocity", rti_cold_iterations=30)
    f = traffic_formulation(TrafficParams(jerk_weight=0.37, heat_weight=13.0))
    h0, v0 = units.length_from_si(11.3), units.speed_from_si(6.1)
    r = run_closed_loop(
        _si_leader(units), [MPCVehicle(s, formulation=f)], [h0], [v0], round(t_end_s / DT_S) * dt, ev=ev
    )
    t_s = r.t * units.time_s
    return (
        t_s,
        units.length_to_si(r.gap[:, 0]),
        units.speed_to_si(r.speed[:, 0]),
        units.accel_to_si(r.accel[:, 0]),
        float(r.heat_J[-1, 0]),
        r.solver_stats[0]["fallbacks"],
    )


def test_same_si_closed_loop_under_two_units():
    """The formulation's parameters are SI: the closed loop in SI does not depend on L, U (the plant,
    the battery and the forecast are unit-free too). A model-unit weight would break this."""
    a = _run_si(Units(15.0, 17.0), 6.9)
    b = _run_si(Units(7.0, 4.3), 6.9)
    assert a[5] == 0 and b[5] == 0
    for x, y in zip(a[:4], b[:4]):
        assert x.shape == y.shape
    np.testing.assert_allclose(a[0], b[0], rtol=1e-9)
    assert np.ptp(a[3]) > 0.5  # the follower really manoeuvres (accelerates and brakes)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-4, atol=1e-4)  # gap [m]
    np.testing.assert_allclose(a[2], b[2], rtol=1e-4, atol=1e-4)  # speed [m/s]
    np.testing.assert_allclose(a[3], b[3], rtol=1e-3, atol=1e-3)  # commanded acceleration [m/s²]
    assert a[4] == pytest.approx(b[4], rel=1e-3)  # pack heat [J]


@pytest.mark.parametrize("solver", ["rti", "ipopt"])
def test_soft_gap_constraint_slack_equals_violation(solver):
    """Starting too close and too fast, the time-headway and braking-distance constraints at node 0 (the
    measured state) cannot hold: a hard problem is infeasible; the soft one is solved and its slack at
    node 0 equals the larger violation, computed here by hand in SI."""
    units = Units(13.0, 11.0)
    ev = EVParams(units=units)
    tp = TrafficParams()
    s = MPCSettings(N=8, codegen=False, solver=solver)
    c = MPCController(s, ev, formulation=traffic_formulation(tp))
    h0_m, v0_ms, vl_ms = 5.1, 14.3, 9.7
    z0 = np.array([units.length_from_si(h0_m), units.speed_from_si(v0_ms), 0.0, 0.0, 0.8])
    vl = np.full(s.N, units.speed_from_si(vl_ms))
    sol = c.solve(z0, vl, vl, own={"a_prev": 0.0})
    assert sol.success, sol.status
    headway = tp.standstill_gap_m + tp.time_headway_s * v0_ms - h0_m
    braking = (
        tp.standstill_gap_m + v0_ms * tp.reaction_time_s + (v0_ms**2 - vl_ms**2) / (2 * tp.brake_decel_mps2) - h0_m
    )
    k = c.problem.control_names.index("slack_gap")
    sigma0_m = units.length_to_si(sol.U[k, 0])
    assert max(headway, braking) > 1.0
    assert sigma0_m == pytest.approx(max(headway, braking), rel=1e-5, abs=1e-5)
    assert sol.a[0] < 0  # and it brakes


def test_rti_hessian_projection_makes_the_reduced_hessian_pd():
    """With large multipliers on the (bilinear) energy-epigraph constraints the exact Lagrangian Hessian is
    indefinite on the null space of the QP's equality constraints; the block-wise projection makes it PD,
    and each projected block has the exact block's eigenvectors with eigenvalues max(λ, floor)."""
    ev = EVParams(units=Units(15.0, 17.0))
    s = MPCSettings(N=5, codegen=False, qp_solver="hpipm")  # the Python RTI step (its QP data in one function)
    c = MPCController(s, ev)
    z0 = np.array([0.9, 0.6, 0.0, 0.0, 0.8, 0.05])
    vl = np.full(s.N, 0.55)
    p = c._params(np.vstack([vl, vl]), None, None)
    x = c.guess(z0, p)
    lam = np.zeros(c.ng)
    names = c.problem.meta["path_names"]
    ngs, nx = c.nlp.ng_stage, c.nx
    for k in range(s.N):
        lam[k * ngs + nx + names.index("omega_epi_drive")] = -523.0
    lbx, ubx = c.nlp.lbx.copy(), c.nlp.ubx.copy()
    lbx[:nx] = ubx[:nx] = z0 / c.x_scale
    d = c.rti.data(x, p, lam, lbx, ubx, c.nlp.lbg, c.nlp.ubg)
    nb = c.nx + c.nu
    blocks = np.asarray(d[0]).reshape(nb, s.N, nb).transpose(1, 0, 2)
    H_exact = scipy.linalg.block_diag(*blocks, np.asarray(d[1]))
    H_reg = np.asarray(c.rti.regularised_hessian(d[0], d[1]).full())
    # equality constraints of the QP: dynamics rows (lba = uba) and the fixed initial state (lbdx = ubdx)
    A = np.asarray(d[3].full())
    eq = np.asarray(d[4]).ravel() == np.asarray(d[5]).ravel()
    fixed = np.asarray(d[6]).ravel() == np.asarray(d[7]).ravel()
    C = np.vstack([A[eq], np.eye(c.nv)[fixed]])
    Z = scipy.linalg.null_space(C)
    assert np.linalg.eigvalsh(Z.T @ H_exact @ Z).min() < -1e-3
    assert np.linalg.eigvalsh(Z.T @ H_reg @ Z).min() > 0
    # each block independently: eigenvalues raised to the floor, eigenvectors kept
    for k in range(s.N):
        B = blocks[k]
        lam_e, Q = np.linalg.eigh(0.5 * (B + B.T))
        floor = RTI_HESSIAN_FLOOR * (1 + np.abs(lam_e).max())
        ref = Q @ np.diag(np.maximum(lam_e, floor)) @ Q.T
        got = H_reg[k * nb : (k + 1) * nb, k * nb : (k + 1) * nb]
        np.testing.assert_allclose(got, ref, atol=1e-9 * (1 + np.abs(B).max()))


def test_step_over_budget_falls_back_with_cause_budget():
    """A budget no step can meet: every step falls back to the clipped law, each counted with cause 'budget'."""
    units = Units(15.0, 17.0)
    s = MPCSettings(N=6, codegen=False, budget="wall", max_step_ms=1e-6, predictor="constant-velocity")
    r = run_closed_loop(drive_cycle("udds", units), [MPCVehicle(s)], [0.8], [0.0], 1.2, ev=EVParams(units=units))
    st = r.solver_stats[0]
    assert st["fallbacks"] == st["n_steps"] == 12
    assert st["fallback_causes"] == {"budget": 12}
    steps = r.meta["mpc_steps"][0]
    assert all(str(x).startswith("budget") for x in steps["status"])
    assert fallback_causes(["budget: 3 ms", "QP failed: 1", "RTI_Step"], [False, False, True]) == {
        "budget": 1,
        "QP failed": 1,
    }


def test_drive_cycle_constant_velocity_no_fallback_and_gap_kept():
    """40 s of UDDS from rest (start, acceleration, a stop) with the constant-velocity forecast: no
    fallback, the gap never below the standstill gap, no negative speed, and the MPC ends near the law."""
    units = Units(15.0, 17.0)
    ev = EVParams(units=units)
    s = MPCSettings(N=20, codegen=False, predictor="constant-velocity")
    t_end = round(units.time_from_si(40.0) / s.dt) * s.dt
    r = run_closed_loop(drive_cycle("udds", units), [MPCVehicle(s)], [0.8], [0.0], t_end, ev=ev)
    assert r.status == "ok"
    st = r.solver_stats[0]
    assert st["fallbacks"] == 0, st["fallback_causes"]
    m = r.metrics()[0]
    tp = TrafficParams()  # the default formulation's
    assert m["min_gap_m"] >= tp.standstill_gap_m - 1e-6
    assert m["min_speed_model"] >= -1e-9
    assert m["distance_m"] > 50.0  # it moved with the leader
    # violations are counted against the MPC's own floor (2 m), not §9's 0.2 L (3 m here): recounted
    assert m["gap_violations"] == int(np.sum(r.gap[1:, 0] * units.length_m < tp.standstill_gap_m - 1e-6)) == 0
    r.meta["controllers"][0]["bounds_model"]["h_min"] = 1.1  # a floor above part of the run: recounted
    assert r.metrics()[0]["gap_violations"] == int(np.sum(r.gap[1:, 0] < 1.1 - 1e-9)) > 0
    assert traffic_bounds(ev, tp).h_min == pytest.approx(2.0 / 15.0)


def test_traffic_params_validated():
    with pytest.raises(ParameterError, match="a_min_mps2"):
        TrafficParams(a_min_mps2=0.5)
    with pytest.raises(ParameterError, match="target_gap_m"):
        TrafficParams(target_gap_m=1.0)
    with pytest.raises(ParameterError, match="formulation"):
        formulation_from_dict({"formulation": "highway"})
    with pytest.raises(ParameterError, match="formulation"):
        MPCSettings().with_(formulation="s9")  # the problem is not a solver option
    assert formulation_from_dict({"time_headway_s": 1.7}).traffic.time_headway_s == 1.7


def test_comparison_table_flags_runs_of_different_duration():
    """A run 20 % shorter than the proposed law's is flagged and its column marked; a run of the same
    length and distance is not (distance within 1 %: OVFL and the proposed law behind the same leader)."""
    from aev_ocp.models import OVFL, PaperLeader, Proposed
    from aev_ocp.mpc.report import comparison_table
    from aev_ocp.mpc.run import Comparison, _flag_comparability
    from aev_ocp.simulate import simulate_platoon

    runs = {
        "proposed": simulate_platoon(PaperLeader(), [Proposed()], [0.3], [1.87], 5.0, dt_out=0.1),
        "mpc": simulate_platoon(PaperLeader(), [Proposed()], [0.3], [1.87], 4.0, dt_out=0.1),
        "ovfl": simulate_platoon(PaperLeader(), [OVFL()], [0.3], [1.87], 5.0, dt_out=0.1),
    }
    metrics = {k: r.metrics() for k, r in runs.items()}
    _flag_comparability(metrics)
    assert metrics["mpc"][0]["flag_duration"] and not metrics["mpc"][0]["comparable"]
    assert metrics["mpc"][0]["duration_diff_pct"] == pytest.approx(-20.0, abs=0.01)
    assert metrics["ovfl"][0]["comparable"] and metrics["proposed"][0]["comparable"]
    table = comparison_table(Comparison(runs, metrics))
    assert "mpc (NOT COMPARABLE)" in table and "ovfl (NOT" not in table
    assert "heat_pack_J_per_km" in table and "min_ttc_s" in table and "distance_m" in table


def test_after_a_failure_the_rti_path_restarts_by_rti_not_ipopt():
    """The step after a failure starts cold by RTI iterations from the law's rollout (bounded work), never
    by a cold IPOPT solve (which took seconds on the §9 problem)."""
    units = Units(15.0, 17.0)
    s = MPCSettings(N=8, codegen=False, rti_cold_iterations=3)
    c = MPCController(s, EVParams(units=units))
    z0 = np.array([1.3, 0.4, 0.0, 0.0, 0.8])
    vl = np.full(s.N, 0.45)
    first = c.solve(z0, vl, vl, own={"a_prev": 0.0})
    assert first.success and first.path == "rti" and 1 <= first.iterations <= 3
    c.failed("QP failed: planted", 1, 0.0, float("inf"), "rti")  # what a failed step leaves behind
    again = c.solve(z0, vl, vl, own={"a_prev": 0.0})
    assert again.success and again.path == "rti" and 1 <= again.iterations <= 3
    np.testing.assert_allclose(again.a, first.a, rtol=1e-9, atol=1e-12)


def test_ocpd_beside_a_traffic_mpc_is_the_traffic_optimum(tmp_path, capsys) -> None:
    """`aev-ocp mpc` on a traffic scenario solves OCP-D of the MPC's own traffic objective and says so
    (results.json); the old warning that it was §9's bound is gone (tests/test_traffic_ocpd.py)."""
    import json

    from cli_helpers import run_cli

    rc, _, err = run_cli(
        ["mpc", "mpc_udds_single", "--t-end", "3", "--out", str(tmp_path), "--laws", "proposed"], capsys
    )
    assert rc == 0 and "a lower bound for the cost_s9 row only" not in err
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["ocp_d"]["objective"] == "traffic objective (the MPC's)"


def test_a_late_step_keeps_its_plan_as_the_next_warm_start() -> None:
    """A step over max_step_ms is not applied (cause 'budget') but warm-starts the next one: with a budget
    no step can meet, the first (cold, rti_cold_iterations) step and every later one fail on the budget, and
    every later one is a warm single iteration — not a cold start again (which made every step late)."""
    units = Units(15.0, 17.0)
    s = MPCSettings(N=8, codegen=False, rti_cold_iterations=3, budget="wall", max_step_ms=1e-6)
    c = MPCController(s, EVParams(units=units))
    z0 = np.array([1.3, 0.4, 0.0, 0.0, 0.8])
    vl = np.full(s.N, 0.45)
    sols = [c.solve(z0, vl, vl, own={"a_prev": 0.0}) for _ in range(3)]
    assert all(not x.success and x.status.startswith("budget") for x in sols)
    assert sols[0].iterations > 1 and [x.iterations for x in sols[1:]] == [1, 1]


def test_qp_solver_choices_refuse_what_they_cannot_do() -> None:
    """qrqp refuses the traffic formulation by name (its energy epigraph control has no curvature); the
    compiled whole step (riccati + codegen) takes the traffic formulation (terminal cost, projected
    Hessian); 'riccati' with the 'sqp' path (CasADi's sqpmethod) is refused by name."""
    ev = EVParams(units=Units(15.0, 17.0))
    with pytest.raises(ParameterError, match="qp_solver = 'qrqp'"):
        MPCController(MPCSettings(N=6, qp_solver="qrqp", codegen=True), ev)
    with pytest.raises(ParameterError, match="qp_solver = 'riccati'.*'sqp'"):
        MPCSettings(N=6, qp_solver="riccati", solver="sqp")
    c = MPCController(MPCSettings(N=6, qp_solver="riccati", codegen=True), ev)
    assert c.compiled_step is not None and c.problem.terminal_cost is not None


def test_acceptable_qps_are_counted_in_the_controller_statistics(monkeypatch) -> None:
    """Every applied step whose QPs ended at their acceptable level (the solution's stats 'qp_acceptable') adds its
    count to the run's statistics; steps without the key (another QP path) add nothing."""
    units = Units(15.0, 17.0)
    s = MPCSettings(N=6, codegen=False, predictor="constant-velocity")
    solve = MPCController.solve
    marks = iter([0, 2, 0, 0, 1, 0, 3, 0, 0, 0, 0, 0, 0, 0, 0])

    def marked(self, *a, **k):
        sol = solve(self, *a, **k)
        n = next(marks, 0)
        if n:
            sol.stats["qp_acceptable"] = n
        return sol

    monkeypatch.setattr(MPCController, "solve", marked)
    r = run_closed_loop(drive_cycle("udds", units), [MPCVehicle(s)], [0.8], [0.0], 1.2, ev=EVParams(units=units))
    st = r.solver_stats[0]
    assert st["n_steps"] == 12 and st["fallbacks"] == 0
    assert st["qp_acceptable"] == 6

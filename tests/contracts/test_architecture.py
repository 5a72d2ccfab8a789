"""The architecture's contracts: one problem description (OCP and MPC solve the same problem, soft
constraints are exact penalties), one plant with one event table (simulator, closed loop and C
cascade agree), and the Controller protocol (a user's controller on any vehicle)."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from aev_ocp.control import ClosedLoop, Command, ControlSequence, Observation, SampledLaw
from aev_ocp.models import OVFL, ConstantSpeed, PaperLeader, Proposed
from aev_ocp.mpc import MPCController, MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.ocp import OCPSolver, TranscriptionOptions, following_problem
from aev_ocp.ocp.following import FollowingWeights, weight_vector
from aev_ocp.ocp.formulation import problem_formulation, s9_formulation
from aev_ocp.ocp.problem import ProblemBuilder
from aev_ocp.params import UNLIMITED, EVParams, ParameterError
from aev_ocp.plant import EVENT_RULES, PLAN_TOLERANCE, event_header
from aev_ocp.simulate import simulate_platoon

sys.path.insert(0, str(Path(__file__).parents[2] / "examples"))
EV = EVParams()


# ----------------------------------------------------------------------------- problem description
def _tracking_problem(soft: float | None) -> ProblemBuilder:
    """ẋ = u, minimise Σ (u − 2.3)²·h with u ≤ 1.1 (hard, or soft with penalty ``soft``)."""
    pb = ProblemBuilder("track", time_unit="s")
    x = pb.state("x")
    u = pb.control("u")
    pb.set_der(x, u)
    pb.add_stage_cost((u - 2.3) ** 2, "track")
    pb.subject_to(u, ub=1.1, soft=soft, soft_quadratic=0.004, name="cap")
    return pb


@pytest.mark.parametrize(
    "soft, expected",
    [
        (None, 1.1),  # hard: the bound; its multiplier is 2 (2.3 − 1.1) = 2.4 per unit time
        (5.7, 1.1),  # exact penalty: a penalty above the multiplier recovers the hard optimum exactly
        # below it the optimum of (u − 2.3)² + ρ σ + q σ² with σ = u − 1.1: 2(u − 2.3) + ρ + 2q(u − 1.1) = 0
        (1.3, (4.6 - 1.3 + 2 * 0.004 * 1.1) / (2 + 2 * 0.004)),
    ],
)
def test_soft_constraint_is_an_exact_penalty(soft: float | None, expected: float) -> None:
    pr = _tracking_problem(soft).build()
    res = OCPSolver(pr, TranscriptionOptions(N=6)).solve([0.37], 2.5)
    assert res.success
    np.testing.assert_allclose(res.controls["u"], expected, atol=1e-7)
    np.testing.assert_allclose(res.states["x"][-1], 0.37 + 2.5 * expected, atol=1e-6)


def test_builder_rejects_bad_declarations() -> None:
    pb = ProblemBuilder("bad")
    x = pb.state("x")
    with pytest.raises(ParameterError, match="exists already"):
        pb.control("x")
    with pytest.raises(ParameterError, match="no set_der"):
        pb.add_stage_cost(x**2)
        pb.build()
    with pytest.raises(ParameterError, match="penalty soft > 0"):
        pb.subject_to(x, lb=0.4, soft=-2.0)


def test_ocp_and_mpc_solve_the_same_custom_problem() -> None:
    """A user's extra soft constraint and cost term, added ONCE to the builder, reach both the
    whole-horizon OCP and the MPC: the MPC's first problem over the same horizon has the same optimum."""
    from custom_mpc_term import headway_problem

    s = MPCSettings(N=30)
    f9 = s9_formulation(weights=FollowingWeights(w_Q=1.7, w_V=0.6, w_r=2.2, w_a=0.35))
    pb = headway_problem(EV, f9)
    pr = pb.build()
    assert "slack_headway" in pr.control_names
    t = np.linspace(0.0, 3.0, 31)
    leader = PaperLeader()
    x = leader.position(t)
    vm, vh = np.diff(x) / 0.1, leader.speed_np(t[:-1])
    z0 = [0.45, 1.87, 0.0, 0.0, 0.8]
    ocp = OCPSolver(pr, TranscriptionOptions(N=30, rk4_substeps=1, tol=1e-10)).solve(
        z0, 3.0, p=weight_vector(f9.weights), w=np.vstack([vm, vh])
    )
    assert ocp.success
    sol = MPCController(s, EV, formulation=problem_formulation(pb, weights=f9.weights)).solve(z0, vm, vh)
    assert sol.success
    assert sol.cost == pytest.approx(ocp.objective, rel=1e-6)
    np.testing.assert_allclose(sol.a, ocp.controls["a"], atol=1e-5)
    # the constraint is active (the §9 problem alone violates it) and its slack is reported
    assert np.max(sol.U[1]) > 1e-3


def test_custom_term_example_runs() -> None:
    """examples/custom_mpc_term.py (shown in the README): the headway constraint holds where the
    §9 MPC alone breaks it."""
    from custom_mpc_term import main

    out = main(quick=True)
    assert out["mpc (§9)"]["margin"] < 0.2 - 0.05 and out["mpc (§9)"]["formulation"] == "s9"
    assert out["mpc (§9) + headway"]["margin"] >= 0.2 - 1e-3 and out["mpc (§9) + headway"]["family"] == "s9"


def test_mpc_rejects_a_problem_without_the_closed_loop_layout() -> None:
    pb = ProblemBuilder("not_following", time_unit="model")
    x = pb.state("q")
    pb.set_der(x, pb.control("a"))
    pb.stage_parameter("w1")
    pb.stage_parameter("w2")
    pb.add_stage_cost(x**2)
    with pytest.raises(ParameterError, match="must start with states"):
        MPCController(MPCSettings(N=5), EV, problem=pb)


# ----------------------------------------------------------------------------- one plant, one event table
def test_event_table_reaches_the_c_cascade() -> None:
    header = event_header()
    for r in EVENT_RULES:
        assert f"#define AEV_EV{r.code}_OFFSET ({r.offset!r})" in header
        assert f"#define AEV_EV{r.code}_SIGN ({r.sign!r})" in header
    assert next(r for r in EVENT_RULES if r.kind == "negative_speed").offset == -PLAN_TOLERANCE


@pytest.mark.quick
def test_closed_loop_and_simulator_stop_at_the_same_rule() -> None:
    """Braking at 1.3 from v = 0.65: the simulator's law run (cascade and CVODES) and a replayed command
    in the closed loop all stop where v crosses −PLAN_TOLERANCE, t = 0.5 + tol/1.3 (exact kinematics)."""
    from aev_ocp.models.carfollowing import CarFollowingLaw

    class Brake(CarFollowingLaw):
        name = "brake13"

        def accel(self, h, v, v_l):  # type: ignore[no-untyped-def]
            return -1.3 + 0 * h

    t_exact = 0.5 + PLAN_TOLERANCE / 1.3
    free = dataclasses.replace(EV, limits=UNLIMITED)  # (with vehicle limits the brakes hold a stopped car)
    for method in ("cascade", "cvodes"):
        r = simulate_platoon(ConstantSpeed(1.0), [Brake()], [5.0], [0.65], 2.0, method=method, ev=free)
        assert r.status == "negative_speed" and r.events[0].time == pytest.approx(t_exact, abs=1e-9)
    r = ClosedLoop(ConstantSpeed(1.0), [ControlSequence((-1.3,) * 20, 0.1)], free).run([5.0], [0.65], 2.0)
    assert r.status == "negative_speed" and r.events[0].time == pytest.approx(t_exact, abs=1e-9)


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_a_plan_within_tolerance_never_stops_the_plant() -> None:
    """Issue 7's reproduction: the canonical scenario with the ω objective, w_Q = 5, N = 30 and
    IPOPT stopped at t = 1.5 on a speed of −6.4e-9 that the MPC had accepted as feasible."""
    s = MPCSettings(N=30, solver="ipopt")
    f = s9_formulation(weights=FollowingWeights(w_Q=5.0), objective="omega")
    r = run_closed_loop(PaperLeader(), [MPCVehicle(s, formulation=f)], [0.3], [1.87], 2.4, ev=EV)
    assert r.status == "ok", r.events
    assert r.speed[:, 0].min() > -PLAN_TOLERANCE


# ----------------------------------------------------------------------------- controllers
class ACC:
    """A user's adaptive cruise control (no aev_ocp base class): a = k_h (h − h0 − T v) + k_v (v_l − v)."""

    name = "acc"

    def __init__(self, dt: float, k_h: float = 0.7, k_v: float = 1.6, h0: float = 0.4, T: float = 1.3) -> None:
        self.dt, self.k_h, self.k_v, self.h0, self.T = dt, k_h, k_v, h0, T
        self.calls = 0

    def reset(self) -> None:
        self.calls = 0

    def command(self, obs: Observation) -> Command:
        self.calls += 1
        h, v = obs.z[0], obs.z[1]
        return Command(self.k_h * (h - self.h0 - self.T * v) + self.k_v * (obs.meas_v[-1] - v))

    def describe(self) -> dict[str, float]:
        return {"controller": "acc", "k_h": self.k_h, "k_v": self.k_v}


@pytest.mark.quick
def test_a_users_controller_runs_on_any_vehicle() -> None:
    """Vehicle 2 of 3 runs the user's ACC between two laws: its applied accelerations are exactly the
    ACC formula on the plant's samples, and its speed follows the held commands exactly."""
    acc = ACC(0.2)
    laws = [Proposed(kappa=0.041), acc, OVFL(alpha=1.7, beta=2.4)]
    r = ClosedLoop(PaperLeader(), laws, EV).run([0.5, 2.6, 2.9], [1.7, 1.65, 1.6], 6.0)
    assert r.status == "ok" and acc.calls == 30 and r.controllers[1] == "acc"
    h, v, vp, a = r.gap[:, 1], r.speed[:, 1], r.speed[:, 0], r.accel[:, 1]
    np.testing.assert_allclose(a[:-1], 0.7 * (h[:-1] - 0.4 - 1.3 * v[:-1]) + 1.6 * (vp[:-1] - v[:-1]), atol=1e-12)
    np.testing.assert_allclose(np.diff(v), a[:-1] * 0.2, atol=1e-8)
    # the laws around it are untouched: the first follower equals a simulation without the ACC
    ref = simulate_platoon(PaperLeader(), [Proposed(kappa=0.041)], [0.5], [1.7], 6.0, dt_out=0.2, method="cvodes")
    common = np.isin(np.round(ref.t, 9), np.round(r.t, 9))
    np.testing.assert_allclose(
        r.speed[np.isin(np.round(r.t, 9), np.round(ref.t, 9)), 0], ref.speed[common, 0], atol=1e-7
    )


@pytest.mark.quick
def test_sampled_law_converges_to_the_continuous_law() -> None:
    """OVFL evaluated every dt and held (SampledLaw) approaches the continuous OVFL as dt → 0, at first order."""
    law = OVFL(alpha=1.9, beta=2.6)
    ref = simulate_platoon(PaperLeader(), [law], [0.6], [1.75], 4.0, dt_out=0.05, method="cvodes")
    errs = []
    for dt in (0.05, 0.025):
        r = ClosedLoop(PaperLeader(), [SampledLaw(law, dt)], EV).run([0.6], [1.75], 4.0)
        errs.append(float(np.max(np.abs(np.interp(ref.t, r.t, r.speed[:, 0]) - ref.speed[:, 0]))))
    assert errs[1] < 0.015
    assert 1.6 < errs[0] / errs[1] < 2.5  # first order in dt


def test_closed_loop_rejects_non_controllers() -> None:
    with pytest.raises(ParameterError, match="vehicle 1 must be a CarFollowingLaw or a Controller"):
        ClosedLoop(PaperLeader(), [object()], EV)
    with pytest.raises(ParameterError, match="same dt"):
        ClosedLoop(PaperLeader(), [ACC(0.2), ACC(0.1)], EV)


def test_package_root_exports_resolve() -> None:
    import aev_ocp

    for name in aev_ocp.__all__[1:]:
        assert getattr(aev_ocp, name) is not None, name
    assert aev_ocp.ClosedLoop is ClosedLoop and aev_ocp.following_problem is following_problem
    with pytest.raises(AttributeError):
        aev_ocp.no_such_name  # noqa: B018


def test_api_arguments_are_checked_with_one_line_errors() -> None:
    """Wrong types name the argument (no AttributeError from deep inside); bad values name the field."""
    with pytest.raises(TypeError, match="leader must be LeaderProfile"):
        simulate_platoon("paper", [Proposed()], [0.3], [1.8], 5.0)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"laws\[0\] must be CarFollowingLaw"):
        simulate_platoon(PaperLeader(), ["proposed"], [0.3], [1.8], 5.0)  # type: ignore[list-item]
    with pytest.raises(ParameterError, match="soc0"):
        simulate_platoon(PaperLeader(), [Proposed()], [0.3], [1.8], 5.0, soc0=float("nan"))
    with pytest.raises(TypeError, match="ev must be EVParams"):
        ClosedLoop(PaperLeader(), [ACC(0.2)], {})  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="rtol"):
        ClosedLoop(PaperLeader(), [ACC(0.2)], EV, rtol=1e-30)
    with pytest.raises(ParameterError, match="lower MPCSettings.N"):
        ClosedLoop(PaperLeader(), [MPCSettings(N=10**7)], EV)


def test_discrete_state_gives_a_delta_u_penalty_in_ocp_and_mpc() -> None:
    """A discrete-time state a_prev (a_prev_{k+1} = a_k) and a stage cost on (a − a_prev)²: the same
    problem in OCPSolver (both transcriptions) and the MPC has the same optimum, a_prev is exactly the
    previous control, and the penalty makes the closed loop smoother."""
    s = MPCSettings(N=20, predictor="oracle")  # the §9 problem's forecast (the numbers below were measured so)
    f9 = s9_formulation()

    def jerky(w_j: float) -> ProblemBuilder:
        pb = following_problem(EV, f9.bounds, f9.smooth, f9.objective, name="mpc_jerk")
        a_prev = pb.state("a_prev")
        pb.set_next(a_prev, pb.u["a"])
        pb.add_stage_cost(w_j * ((pb.u["a"] - a_prev) / s.dt) ** 2, name="jerk")
        return pb

    pr = jerky(0.013).build()
    assert list(pr.discrete_states) == [5]
    t = np.linspace(0.0, 2.0, 21)
    leader = PaperLeader()
    vm, vh = np.diff(leader.position(t)) / 0.1, leader.speed_np(t[:-1])
    z0 = [0.45, 1.87, 0.0, 0.0, 0.8, -0.37]
    res = {
        m: OCPSolver(pr, TranscriptionOptions(method=m, N=20, rk4_substeps=1, tol=1e-10)).solve(
            z0, 2.0, p=weight_vector(f9.weights), w=np.vstack([vm, vh])
        )
        for m in ("ms", "collocation")
    }
    for r in res.values():
        assert r.success
        np.testing.assert_allclose(r.states["a_prev"][1:], r.controls["a"], atol=1e-9)  # exact discrete update
        assert r.states["a_prev"][0] == pytest.approx(-0.37)
    mpc = MPCController(s, EV, problem=pr)
    sol = mpc.solve(z0[:5], vm, vh, own={"a_prev": -0.37})
    assert sol.success and sol.cost == pytest.approx(res["ms"].objective, rel=1e-6)
    jerk = {}
    for w_j, name in ((0.0, "none"), (0.02, "penalised")):
        r = run_closed_loop(PaperLeader(), [MPCVehicle(s, problem=jerky(w_j))], [0.45], [1.87], 6.0, ev=EV)
        assert r.status == "ok"
        jerk[name] = r.metrics()[0]["rms_jerk_model"]
    assert jerk["penalised"] < 0.8 * jerk["none"]  # 1.50 -> 1.00 measured


def test_builder_rejects_a_derivative_for_a_discrete_state() -> None:
    pb = ProblemBuilder("d")
    x = pb.state("x")
    pb.set_next(x, x + 1.3)
    with pytest.raises(ParameterError, match="discrete"):
        pb.set_der(x, 2.0 * x)

"""The MPC with the pack temperature as a state (TemperatureTerms): its prediction equals the plant's temperature
under the same commands, its soft limit T ≤ T_max holds on, inside and outside the limit, and in the closed loop a
tight limit is kept where the MPC without it exceeds it. The [mpc] keys and their errors.

A small pack (106s5p: the A123 cells carry 14× the cell current of the 106s70p default, so they warm in seconds)
keeps the runs short; ambient and T(0) are distinct and not 25 °C.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from aev_ocp.control import ControlSequence, run_closed_loop
from aev_ocp.models import thermal
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.mpc import MPCSettings, MPCVehicle
from aev_ocp.mpc.controller import MPCController
from aev_ocp.ocp.following import TemperatureTerms
from aev_ocp.ocp.formulation import formulation_from_dict, s9_formulation, traffic_formulation
from aev_ocp.params import EVParams, PackParams, ParameterError, ThermalParams
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario

AMBIENT_K = 303.4  # 30.25 °C
T0_K = 304.1
EV = dataclasses.replace(
    EVParams(),
    pack=PackParams(n_series=106, n_parallel=5),
    thermal=ThermalParams(enabled=True, ambient_K=AMBIENT_K, T0_K=T0_K, h_Wpm2K=37.0),
)
S = MPCSettings(
    N=15, codegen=False, qp_solver="hpipm", predictor="constant-velocity", rti_cold_iterations=20, max_step_ms=5000.0
)  # a cold start on a busy machine: the timing is not under test


def _controller(T_max_K: float | None = None, kind: str = "traffic") -> MPCController:
    terms = TemperatureTerms(temperature_state=True, temperature_max_K=T_max_K)
    f = traffic_formulation(temperature=terms) if kind == "traffic" else s9_formulation(temperature=terms)
    return MPCController(S, EV, formulation=f)


def _row(c: MPCController, name: str) -> int:
    return list(c.problem.state_names).index(name)


@pytest.mark.parametrize("kind", ["traffic", "s9"])
def test_predicted_temperature_equals_the_plant_under_the_same_commands(kind: str) -> None:
    """The plan's T at every node equals the plant's T (its own integrator) when the plan's accelerations are
    replayed on the plant from the same state: the prediction model is the plant's thermal model."""
    c = _controller(kind=kind)
    N, dt = S.N, S.dt
    h0, v0, S0 = 0.9, 0.6, 0.71
    lead = 1.9  # the leader far ahead and faster: the follower accelerates hard (a large current, heat)
    sol = c.solve(np.array([h0, v0, 0.0, 0.0, S0]), np.full(N, lead), np.full(N, lead), own={"T": T0_K})
    assert sol.success, sol.status
    T_plan = sol.X[_row(c, "T")]
    assert T_plan[0] == T0_K
    res = run_closed_loop(ConstantSpeed(lead), [ControlSequence(tuple(sol.a), dt)], [h0], [v0], N * dt, ev=EV, soc0=S0)
    assert res.status == "ok"
    t = np.asarray(res.t)
    T_plant = np.array([np.interp(k * dt, t, res.temperature_K[:, 0]) for k in range(N + 1)])
    # the heat matters here: without it T would fall towards the ambient by ~1e-3 K; with it, it rises
    T_cool = thermal.step_response_K(np.arange(N + 1) * dt * EV.units.time_s, 0.0, EV.cell, EV.pack, EV.thermal)
    assert T_plant[-1] - T_cool[-1] > 0.01
    assert np.max(np.abs(T_plan - T_plant)) < 2e-4 * (T_plant[-1] - T_cool[-1])


def test_limit_inside_on_and_outside() -> None:
    """Inside: the limit costs nothing (slack 0, the plan is the plan without a limit); on: the plan's T stays at
    or below T_max; outside: the solve still succeeds (the limit is soft), the slack at node 0 is exactly the excess
    T(0) − T_max and the plan cools."""
    N = S.N
    z0 = np.array([0.9, 0.6, 0.0, 0.0, 0.71])
    fc = np.full(N, 1.9)
    free = _controller(T_max_K=400.0)
    ref = free.solve(z0, fc, fc, own={"T": T0_K})
    T_ref = ref.X[_row(free, "T")]
    rise = T_ref.max() - T0_K
    assert rise > 0.01  # the unlimited plan warms the pack
    # inside: a limit above the unlimited plan's peak changes nothing
    inside = _controller(T_max_K=T0_K + 1.5 * rise)
    sol = inside.solve(z0, fc, fc, own={"T": T0_K})
    assert sol.success and np.allclose(sol.a, ref.a, atol=1e-5)
    assert np.max(sol.U[list(inside.problem.control_names).index("slack_T")]) < 1e-6
    # on: T(0) on the limit; the plan keeps T ≤ T_max at every node, and accelerates less than the unlimited one
    on = _controller(T_max_K=T0_K)
    sol = on.solve(z0, fc, fc, own={"T": T0_K})
    assert sol.success, sol.status
    T_on = sol.X[_row(on, "T")]
    assert np.max(T_on[:-1]) <= T0_K + 1e-6
    assert np.sum(sol.a) < np.sum(ref.a) - 0.1
    # outside: T(0) above the limit by 0.37 K
    out = _controller(T_max_K=T0_K - 0.37)
    sol = out.solve(z0, fc, fc, own={"T": T0_K})
    assert sol.success, sol.status
    slack = sol.U[list(out.problem.control_names).index("slack_T")]
    assert slack[0] == pytest.approx(0.37, abs=1e-6)
    T_out = sol.X[_row(out, "T")]
    # it cools towards the ambient at every node that carries the limit (0…N−1: the path constraints' nodes)
    assert np.all(np.diff(T_out[:-1]) < 0)
    assert np.all(slack[1:] <= slack[:-1] + 1e-9)


def _drive(terms: TemperatureTerms) -> tuple[float, int, float]:
    """(peak T [K], fallbacks, final speed [model]) of an MPC follower catching up with a leader at 9.5 m/s."""
    veh = MPCVehicle(S, formulation=traffic_formulation(temperature=terms))
    r = run_closed_loop(ConstantSpeed(1.9), [veh], [2.2], [0.45], 14.0, ev=EV)
    assert r.status == "ok"
    return float(r.metrics()[0]["peak_temperature_K"]), int(r.solver_stats[0]["fallbacks"]), float(r.speed[-1, 0])


def test_closed_loop_keeps_a_tight_limit_that_the_unlimited_mpc_exceeds() -> None:
    """Catching up from 2.25 m/s the unlimited MPC warms the pack by `rise`; with T_max at 45 % of that rise the
    MPC accelerates more gently and its closed-loop peak stays at the limit (to 1e-6 K), without a fallback."""
    peak_free, _, v_free = _drive(TemperatureTerms(temperature_state=True, temperature_max_K=400.0))
    rise = peak_free - T0_K
    assert rise > 0.05
    limit = T0_K + 0.45 * rise  # tight: the unlimited MPC goes 0.55·rise above it
    peak, fallbacks, v_end = _drive(TemperatureTerms(temperature_state=True, temperature_max_K=limit))
    assert peak_free > limit + 0.5 * rise
    assert peak <= limit + 1e-6
    assert peak > limit - 0.05 * rise  # it uses the allowance: the limit is active, not a slower drive by chance
    assert fallbacks == 0
    assert v_end > 0.9 * v_free  # and still catches up with the leader


def test_mpc_keys_in_a_scenario(tmp_path: Path) -> None:
    base = find_scenario("udds_platoon").read_text()
    p = tmp_path / "s.toml"
    p.write_text(base + "\n[thermal]\nenabled = true\n\n[mpc]\ntemperature_state = true\ntemperature_max_K = 310.5\n")
    f = load_scenario(p).extra["mpc"].formulation
    assert f.temperature.temperature_state and f.temperature.temperature_max_K == 310.5
    assert f.describe()["temperature"]["temperature_max_K"] == 310.5
    # without the thermal model: refused before anything is built, naming the key
    p.write_text(base + "\n[mpc]\ntemperature_state = true\n")
    from aev_ocp.mpc.scenario import closed_loop_from_scenario

    with pytest.raises(ScenarioError, match="temperature_state"):
        closed_loop_from_scenario(load_scenario(p))
    p.write_text(base + "\n[thermal]\nenabled = true\n\n[mpc]\ntemperature_state = true\ntemperature_max_K = -4.0\n")
    with pytest.raises(ScenarioError, match="temperature_max_K"):
        load_scenario(p)
    with pytest.raises(ParameterError, match="temperature_penalty"):
        formulation_from_dict({"temperature_penalty": 0.0})
    # off by default: the formulation and its problem are the ones without temperature
    assert formulation_from_dict({}) == traffic_formulation()
    assert "T" not in traffic_formulation().build(EV, 0.1).state_names


def test_a_plant_without_temperature_is_a_clear_error() -> None:
    """The ring road has no thermal model: an MPC that predicts T refuses to run there, naming what is missing."""
    from aev_ocp.control import Observation
    from aev_ocp.ring.laws import ring_mpc

    pol = ring_mpc(
        EV,
        MPCSettings(N=4, codegen=False),
        "constant-velocity",
        traffic_formulation(temperature=TemperatureTerms(temperature_state=True)),
    )
    obs = Observation(0.0, 0.1, 0, np.array([1.3, 0.9, 0.0, 0.0, 0.62]), np.array([0.0]), np.array([0.9]))
    with pytest.raises(ParameterError, match="Observation.T_K"):
        pol.command(obs)


def test_export_refuses_the_temperature_state(tmp_path: Path) -> None:
    """The exported step has only the Riccati QP solver, which fails on active temperature limits: such a
    scenario is refused by name, nothing is written; the same scenario without the state exports."""
    from aev_ocp.mpc.export import ExportError, export_mpc

    base = find_scenario("udds_platoon").read_text()
    p = tmp_path / "s.toml"
    p.write_text(base + "\n[thermal]\nenabled = true\n\n[mpc]\ntemperature_state = true\n")
    with pytest.raises(ExportError, match="temperature_state"):
        export_mpc(load_scenario(p), tmp_path / "out")
    assert not (tmp_path / "out").exists()
    from aev_ocp.mpc.export import cli_mpc_export

    assert cli_mpc_export([str(p), "--out", str(tmp_path / "cli")]) == 2  # one bad-input line, before the folder
    assert not (tmp_path / "cli").exists()
    p.write_text(base + "\n[thermal]\nenabled = true\n\n[mpc]\nN = 8\n")
    written = export_mpc(load_scenario(p), tmp_path / "out2")
    assert any(f.name == "mpc_step.c" for f in written)


@pytest.mark.parametrize("kind, solver", [("traffic", "ipopt"), ("s9", "rti"), ("s9", "ipopt")])
def test_a_hot_start_above_the_limit_is_solved_without_fallbacks(kind: str, solver: str) -> None:
    """T(0) 0.5 K above the limit: every step's plan is accepted (no fallback to the law, which ignores
    temperature) and the MPC does not let T rise. IPOPT's relaxed bounds (1e-8·|300 K|) and a §9 penalty of the
    traffic cost's size made these plans fail before."""
    s = dataclasses.replace(S, solver=solver, qp_solver="auto")
    f = (traffic_formulation if kind == "traffic" else s9_formulation)(
        temperature=TemperatureTerms(temperature_state=True, temperature_max_K=T0_K - 0.5)
    )
    r = run_closed_loop(ConstantSpeed(1.9), [MPCVehicle(s, formulation=f)], [2.2], [0.45], 2.0, ev=EV)
    st = r.solver_stats[0]
    assert r.status == "ok" and st["n_steps"] >= 20
    assert st["fallbacks"] == 0, st.get("fallback_causes")
    assert np.max(r.temperature_K[:, 0]) <= T0_K + 1e-6


def test_a_user_state_named_T_is_not_the_pack_temperature() -> None:
    """Only the state add_temperature_state marks is the pack temperature: a user's own state called 'T' (a timer)
    on a plant without the thermal model runs, starts at 0 and integrates its own derivative."""
    from aev_ocp.ocp.following import following_problem

    ev = EVParams()
    pb = following_problem(ev)
    timer = pb.state("T", 0.0, 100.0)
    pb.set_der(timer, 1.0)
    s = dataclasses.replace(S, N=8, qp_solver="auto")
    r = run_closed_loop(ConstantSpeed(1.9), [MPCVehicle(s, problem=pb)], [1.0], [1.8], 0.6, ev=ev)
    assert r.status == "ok" and r.temperature_K is None
    c = MPCController(s, ev, problem=pb)
    assert not c.has_temperature and c.temperature_state_name is None
    assert c.layout.x_own0.tolist() == [0.0]  # the timer's own start, not the thermal model's T(0)
    assert _controller(T0_K + 1.0).temperature_state_name == "T"  # the marked one is

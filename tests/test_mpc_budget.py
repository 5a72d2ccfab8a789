"""What bounds an MPC step (``MPCSettings.budget``): with 'counted' (the default, every simulation) the iteration
limits alone, so a closed loop's numbers do not depend on how busy the machine is; with 'wall' (real time) the wall
clock too: a step longer than ``max_step_ms`` falls back (cause 'budget'), IPOPT stops at ``max_cpu_time_s``.

The clock is a fake one on which every MPC step takes 1 s (10x the default 100 ms budget): a counted closed loop
on it equals the one on the real clock to the last bit and reports the 1 s it measured; a wall closed loop on it
falls back at every step, each with cause 'budget'. Both the Python real-time iteration (HPIPM through ca.conic)
and the compiled whole step (ocp_qp.c) are run. The compiled ring, the other simulation that reads the clock (to choose
how it calls its C), is shown to give the same bits either way."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import aev_ocp.mpc.rti as rti
from aev_ocp.compiled import compiler
from aev_ocp.models import drive_cycle
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.mpc.controller import MPCController
from aev_ocp.mpc.settings import BUDGETS
from aev_ocp.params import EVParams, ParameterError, Units
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario

UNITS = Units(15.0, 17.0)
T_END = 1.3  # model time: 13 MPC steps of dt = 0.1 from rest on UDDS (start, first acceleration)
STEP_S = 1.0  # [s] every step on the fake clock (the default max_step_ms is 100)
#: the rti path's two implementations: the Python step (HPIPM through ca.conic, interpreted, a short horizon) and
#: the compiled whole step (qp_solver 'riccati', the default N = 25 library other tests build too)
PATHS: dict[str, dict[str, Any]] = {
    "python": {"N": 6, "codegen": False, "qp_solver": "hpipm"},
    "compiled": {"qp_solver": "riccati", "codegen": True},
}
ARRAYS = ("t", "gap", "speed", "accel", "V1", "V2", "S", "current_A", "omega", "heat_J", "int_jerk2")


class SlowClock:
    """``time`` for aev_ocp.mpc.rti: each perf_counter() call is STEP_S after the previous one, and the rti step
    reads the clock twice (start, end), so every step measures STEP_S of wall time."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def perf_counter(self) -> float:
        self.now_s += STEP_S
        return self.now_s


def _closed_loop(s: MPCSettings, slow: bool) -> Any:
    with pytest.MonkeyPatch.context() as mp:
        if slow:
            mp.setattr(rti, "time", SlowClock())
        ev = EVParams(units=UNITS)
        return run_closed_loop(drive_cycle("udds", UNITS), [MPCVehicle(s)], [0.8], [0.0], T_END, ev=ev)


@pytest.fixture(scope="module", params=sorted(PATHS))
def runs(request: pytest.FixtureRequest) -> dict[str, Any]:
    """The same closed loop on the real clock (counted), and on the slow clock counted and wall."""
    if request.param == "compiled" and compiler() is None:
        pytest.skip("no C compiler")
    base = MPCSettings(predictor="constant-velocity", **PATHS[request.param])
    assert base.budget == "counted"  # the default
    out = {
        "path": request.param,
        "real": _closed_loop(base, slow=False),
        "counted": _closed_loop(base, slow=True),
        "wall": _closed_loop(base.with_(budget="wall"), slow=True),
    }
    st = out["real"].solver_stats[0]
    want = "rti+codegen" if request.param == "compiled" else "rti"
    assert st["solver_path"] == want and st["qp_solver"] == PATHS[request.param]["qp_solver"]
    return out


def test_counted_budget_gives_the_same_bits_whatever_the_clock(runs: dict[str, Any]) -> None:
    """Every step 'took' 1 s, 10x max_step_ms: with the counted budget no step falls back and every trajectory
    equals the real-clock run's to the last bit; the 1 s is still measured and reported."""
    real, slow = runs["real"], runs["counted"]
    assert real.status == slow.status == "ok"
    for name in ARRAYS:
        a, b = getattr(real, name), getattr(slow, name)
        assert a.shape == b.shape and np.array_equal(a, b), name
    sr, ss = real.solver_stats[0], slow.solver_stats[0]
    assert ss["fallbacks"] == sr["fallbacks"] == 0 and ss["fallback_causes"] == {}
    assert ss["n_steps"] == sr["n_steps"] == round(T_END / 0.1)
    steps_r, steps_s = real.meta["mpc_steps"][0], slow.meta["mpc_steps"][0]
    for key in ("status", "iterations", "ok"):
        assert steps_s[key] == steps_r[key], key
    assert steps_s["solve_ms"] == [STEP_S * 1e3] * ss["n_steps"]  # measured on the (fake) clock and reported
    assert max(steps_r["solve_ms"]) < STEP_S * 1e3  # the real run measured its own, shorter, times


def test_wall_budget_falls_back_on_the_slow_clock(runs: dict[str, Any]) -> None:
    """The same slow clock with budget 'wall': every step is over max_step_ms (100 ms), so every step falls back,
    each with cause 'budget' naming the time it took and the budget; the run is no longer the counted one."""
    slow, real = runs["wall"], runs["real"]
    st = slow.solver_stats[0]
    n = round(T_END / 0.1)
    assert st["n_steps"] == n and st["fallbacks"] == n and st["fallback_causes"] == {"budget": n}
    status = slow.meta["mpc_steps"][0]["status"]
    assert all(x == "budget: the step took 1e+03 ms > max_step_ms = 100" for x in status), status[:2]
    assert not np.array_equal(slow.accel, real.accel)  # the fallback law drove instead


def test_over_budget_on_inside_and_outside_the_limit() -> None:
    """MPCSettings.over_budget: with 'wall', late only past max_step_ms (on the limit is in time); with 'counted'
    never, even at 1e6 s."""
    wall = MPCSettings(budget="wall", max_step_ms=2.5)
    assert not wall.over_budget(2.4e-3) and not wall.over_budget(2.5e-3) and wall.over_budget(2.6e-3)
    counted = MPCSettings(max_step_ms=2.5)
    assert not any(counted.over_budget(t) for t in (2.4e-3, 2.6e-3, 1e6))


def test_ipopt_time_limit_acts_with_the_wall_budget_only() -> None:
    """IPOPT's wall-time limit (max_cpu_time_s, IPOPT's max_wall_time) set far below any solve: with the counted
    budget IPOPT is not given it (max_iter bounds it) and the solve equals the one with the default limit to the
    last bit; with 'wall' IPOPT stops at it and the step fails, IPOPT's status naming the wall time."""
    ev = EVParams(units=UNITS)
    z0 = np.array([1.3, 0.4, 0.0, 0.0, 0.8])
    vl = np.full(6, 0.45)

    def solve(**kw: Any) -> Any:
        s = MPCSettings(N=6, solver="ipopt", codegen=False, predictor="constant-velocity", **kw)
        return MPCController(s, ev).solve(z0, vl, vl, own={"a_prev": 0.0})

    ref = solve()
    tiny = solve(max_cpu_time_s=1e-9)
    assert ref.success and tiny.success and ref.iterations == tiny.iterations > 1
    assert np.array_equal(ref.X, tiny.X) and np.array_equal(ref.U, tiny.U)
    late = solve(max_cpu_time_s=1e-9, budget="wall")
    assert not late.success and "WallTime" in late.status, late.status


def test_budget_is_validated_and_read_from_the_mpc_table(tmp_path: Path) -> None:
    """An unknown budget is a ParameterError naming MPCSettings.budget; a scenario's [mpc] table sets it, and a
    bad value there is an error naming the key."""
    assert BUDGETS == ("counted", "wall")
    for bad in ("timed", "Wall", "", 1):
        with pytest.raises(ParameterError, match=r"MPCSettings\.budget = .* is not allowed"):
            MPCSettings(budget=bad)
    base = find_scenario("mpc_udds_single").read_text()
    p = tmp_path / "s.toml"
    p.write_text(base.replace("[mpc]\n", '[mpc]\nbudget = "wall"\n', 1))
    assert load_scenario(p).extra["mpc"].settings.budget == "wall"
    assert load_scenario(find_scenario("mpc_udds_single")).extra["mpc"].settings.budget == "counted"
    p.write_text(base.replace("[mpc]\n", '[mpc]\nbudget = "timed"\n', 1))
    with pytest.raises(ScenarioError, match=r"mpc\.budget = .timed. is not allowed"):
        load_scenario(p)


def test_ring_call_path_chosen_by_the_clock_changes_no_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled ring is the other simulation that reads the clock: an advance after one faster than
    DIRECT_CALL_S is called directly, else in a helper thread (to stay interruptible). Both call the same C on the
    same arrays, so the choice changes no bit: every advance threaded (limit 0 s) equals every advance direct."""
    import aev_ocp.ring.simulate as rs
    from aev_ocp.ring.laws import FollowerStopper
    from aev_ocp.ring.run import human_ring

    ev = EVParams()
    ring = human_ring(230.0, aevs={0: FollowerStopper.from_si(ev.units, 3.1)}, noise_mps2=0.3, seed=11)
    threaded = [0]
    call = rs._interruptible_call

    def counted(*args: Any) -> int:
        threaded[0] += 1
        return call(*args)

    monkeypatch.setattr(rs, "_interruptible_call", counted)
    runs = {}
    for limit_s in (0.0, 1e9):
        monkeypatch.setattr(rs, "DIRECT_CALL_S", limit_s)
        threaded[0] = 0
        runs[limit_s] = (
            rs.RingSimulator(ring, rs.RingOptions(dt_out_s=1.0)).run(rs.uniform_flow(ring), 30.0),
            threaded[0],
        )
    (a, n_a), (b, n_b) = runs[0.0], runs[1e9]
    assert n_a > 10 and n_b == 1  # every advance in a thread / only the first (it runs interruptibly)
    assert a.status == b.status and np.array_equal(a.speed_mps, b.speed_mps) and np.array_equal(a.t_s, b.t_s)

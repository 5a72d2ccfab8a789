"""The defects a third independent reliability probe found (benchmarks/probe_reliability_3.py), one test each:
units whose derived units overflow, ProblemBuilder expressions that were only refused by CasADi at build()
(or never), ClosedLoop controllers with a bad sampling period or a non-finite command (a NaN command was
saturated into full braking without a word), and a SUMO 'module:function' controller that raises."""

from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from cli_helpers import one_error, run_cli
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.control import ClosedLoop, Command
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.ocp.problem import ProblemBuilder
from aev_ocp.params import ParameterError, Units
from aev_ocp.scenarios import load_scenario
from aev_ocp.scenarios.tables import ScenarioError

SCENARIO = """\
name = "units_probe"
[units]
length_m = {L}
speed_mps = {U}
[leader]
kind = "constant"
v = 1.3
[platoon]
followers = 1
law = "proposed"
gap0 = 2.5
speed0 = 1.3
[simulation]
t_end = 2.0
"""


# ----------------------------------------------------------------------------- units
@settings(max_examples=60, deadline=None)
@given(st.floats(0, 1.7e308, exclude_min=True), st.floats(0, 1.7e308, exclude_min=True))
def test_units_either_refused_or_every_derived_unit_finite(L: float, U: float) -> None:
    """Property: for any finite positive L, U, Units either raises ParameterError or its time, acceleration and
    energy units are finite and positive, and equal the closed forms L/U, U²/L, U² (no OverflowError later)."""
    try:
        u = Units(L, U)
    except ParameterError as exc:
        assert "speed_mps" in str(exc) and "not a finite positive number" in str(exc)
        return
    for value in (u.time_s, u.accel_mps2, u.energy_per_mass_to_si(1.0)):
        assert math.isfinite(value) and value > 0
    assert u.time_s == L / U and u.accel_mps2 == U**2 / L


@pytest.mark.parametrize("L, U", [(10.0, 1e308), (1e-300, 1e10), (1e300, 1e-10), (1e-170, 1e-170)])
def test_units_overflowing_a_derived_unit_are_refused(L: float, U: float) -> None:
    with pytest.raises(ParameterError, match="Units.speed_mps .* not a finite positive number"):
        Units(L, U)


def test_scenario_units_overflow_is_bad_input_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    f = tmp_path / "u.toml"
    f.write_text(SCENARIO.format(L=10.0, U=1e308))
    with pytest.raises(ScenarioError, match=r"u\.toml: units\.speed_mps"):
        load_scenario(f)
    rc, _, err = run_cli(["simulate", str(f), "--out", str(tmp_path / "o"), "--no-plots"], capsys)
    assert rc == 2 and "units.speed_mps" in one_error(err) and "internal error" not in err
    f.write_text(SCENARIO.format(L=12.5, U=7.25))  # everyday units still load, with the closed-form time unit
    assert load_scenario(f).units.time_s == 12.5 / 7.25


# ----------------------------------------------------------------------------- ProblemBuilder
def _toy() -> tuple[ProblemBuilder, ca.SX, ca.SX, ca.SX]:
    pb = ProblemBuilder("toy")
    x, u, p = pb.state("x"), pb.control("u"), pb.parameter("p")
    return pb, x, u, p


OUTSIDER = ca.SX.sym("x")  # same name as the builder's state, another symbol


@pytest.mark.parametrize(
    "act, says",
    [
        (lambda pb, x, u, p: pb.set_der(x, "fast"), "set_der of state 'x' must be a CasADi SX expression"),
        (lambda pb, x, u, p: pb.set_der(x, ca.MX.sym("m")), "got MX"),
        (lambda pb, x, u, p: pb.set_der(x, float("nan")), "set_der of state 'x' = nan is not a finite"),
        (lambda pb, x, u, p: pb.set_der(x, ca.vertcat(u, u)), "must be a scalar expression, got 2 entries"),
        (lambda pb, x, u, p: pb.set_der(x, OUTSIDER), "depends on 'x', which is not one of the problem's"),
        (lambda pb, x, u, p: pb.set_next(x, np.array([1.5, 2.5])), "set_next of state 'x' must be a scalar"),
        (lambda pb, x, u, p: pb.add_stage_cost(ca.vertcat(u, x), "c"), "stage cost term 'c' must be a scalar"),
        (lambda pb, x, u, p: pb.add_integral_cost(math.inf * 1.0, "q"), "integral cost term 'q' = inf"),
        (lambda pb, x, u, p: pb.add_terminal_cost("x"), "terminal cost must be a CasADi SX"),
        (lambda pb, x, u, p: pb.add_terminal_cost(u**2), "terminal cost depends on 'u'"),
        (lambda pb, x, u, p: pb.add_output("o", "x"), "output 'o' must be a CasADi SX"),
        (lambda pb, x, u, p: pb.subject_to(OUTSIDER, 0.0, 1.0), "constraint 'c0' depends on 'x'"),
    ],
)
def test_builder_refuses_a_bad_expression_where_it_is_given(act, says: str) -> None:  # noqa: ANN001
    pb, x, u, p = _toy()
    with pytest.raises(ParameterError, match=says.replace("(", r"\(")):
        act(pb, x, u, p)
    assert not pb.stage_terms and not pb.integral_terms and not pb._outputs  # nothing half-added


def test_builder_valid_expressions_evaluate_as_written() -> None:
    """Numbers and expressions still go in; the built Functions evaluate to the closed forms at x = 0.7,
    u = -1.3, p = 2.5 (stage: u² + 1.5 = 3.19; ode: u·p = -3.25; Mayer: x·p = 1.75; output: 2.25 constant)."""
    pb, x, u, p = _toy()
    pb.set_der(x, u * p)
    pb.add_stage_cost(u**2 + 1.5, "effort")
    pb.add_terminal_cost(x * p)
    pb.add_output("const", 2.25)
    pr = pb.build()
    args = (0.7, -1.3, ca.DM(0, 1), 2.5)
    assert float(pr.stage(*args)) == pytest.approx(3.19, rel=1e-15)
    assert float(pr.ode(*args)) == pytest.approx(-3.25, rel=1e-15)
    assert float(pr.terminal_cost(0.7, 2.5)) == pytest.approx(1.75, rel=1e-15)
    outs = pr.outputs(*args)
    assert float(outs[0]) == 2.25 and float(outs[1]) == pytest.approx(3.19, rel=1e-15)


# ----------------------------------------------------------------------------- ClosedLoop
class Held:
    """A user controller holding a (returned as given) every dt."""

    name = "held"

    def __init__(self, a: object, dt: object = 0.1) -> None:
        self.a, self.dt = a, dt

    def reset(self) -> None:
        pass

    def describe(self) -> dict:
        return {"controller": self.name}

    def command(self, obs: object) -> object:
        return Command(self.a)  # type: ignore[arg-type]


LEADER = ConstantSpeed(1.3)


@pytest.mark.parametrize("dt", [0.0, -0.1, math.nan, math.inf, True, "0.1", None])
def test_closed_loop_refuses_a_bad_sampling_period(dt: object) -> None:
    with pytest.raises(ParameterError, match=r"controller 'held' of vehicle 1: dt = .* not allowed"):
        ClosedLoop(LEADER, [Held(0.0, dt)])


@pytest.mark.parametrize("a", [math.nan, math.inf, -math.inf, True, "fast", [0.1, 0.2]])
def test_closed_loop_refuses_a_non_finite_command(a: object) -> None:
    with pytest.raises(ParameterError, match=r"controller 'held' of vehicle 1 returned Command\(a = .*\) at t = 0"):
        ClosedLoop(LEADER, [Held(a)]).run([2.5], [1.3], 0.5)


def test_closed_loop_refuses_a_non_command() -> None:
    class Bare(Held):
        def command(self, obs: object) -> object:
            return None

    with pytest.raises(ParameterError, match=r"returned NoneType None at t = 0: command\(\) must return a Command"):
        ClosedLoop(LEADER, [Bare(0.0)]).run([2.5], [1.3], 0.5)


def test_closed_loop_applies_a_finite_command_exactly() -> None:
    """A held -0.35 (model units; -0.875 m/s², inside the default limits) from v = 1.3 behind a leader far ahead:
    v(t) = 1.3 - 0.35 t at every node (closed form), numpy scalars accepted like floats."""
    r = ClosedLoop(LEADER, [Held(np.float32(-0.35))]).run([4.5], [1.3], 1.0)
    t = np.asarray(r.t)
    nodes = np.isclose(t[:, None], np.arange(0, 1.01, 0.1)[None, :], atol=1e-9).any(axis=1)
    np.testing.assert_allclose(np.asarray(r.speed)[nodes, 0], 1.3 - float(np.float32(0.35)) * t[nodes], atol=1e-8)


@pytest.mark.parametrize(
    ("a", "dt"),
    [(np.array(-0.35), np.float32(0.125)), (np.array([-0.35]), np.int64(1)), (np.float64(-0.35), np.float64(0.1))],
)
def test_closed_loop_takes_numpy_scalars_and_one_element_arrays_like_floats(a: object, dt: object) -> None:
    """What np.clip/np.minimum give (0-d arrays) and NumPy scalar periods run exactly as the plain floats do: the
    same speeds at every sample (they ran before the checks that refuse NaN commands were added)."""
    plain = ClosedLoop(LEADER, [Held(-0.35, float(dt))]).run([4.5], [1.3], 1.0)  # type: ignore[arg-type]
    r = ClosedLoop(LEADER, [Held(a, dt)]).run([4.5], [1.3], 1.0)
    np.testing.assert_array_equal(np.asarray(r.speed), np.asarray(plain.speed))
    np.testing.assert_array_equal(np.asarray(r.gap), np.asarray(plain.gap))


@pytest.mark.parametrize("a", [np.array(math.nan), np.array([0.1, 0.2]), np.array(True), np.array("x")])
def test_closed_loop_refuses_arrays_that_are_not_one_finite_number(a: object) -> None:
    with pytest.raises(ParameterError, match=r"controller 'held' of vehicle 1 returned Command\(a = .*\) at t = 0"):
        ClosedLoop(LEADER, [Held(a)]).run([2.5], [1.3], 0.5)


# ----------------------------------------------------------------------------- SUMO 'module:function'
def broken_factory(ev: object) -> object:
    """A user controller factory with a bug of its own."""
    raise TypeError("expected str, got EVParams")


def test_sumo_user_factory_error_names_the_key() -> None:
    pytest.importorskip("libsumo")
    from aev_ocp.sumo import SumoError
    from aev_ocp.sumo.run import make_controller_factory
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    def scenario(controller: str):  # noqa: ANN202
        return parse_sumo_scenario({"sumo": {"network": "ring", "t_end_s": 2.5, "controller": controller}})

    _, factory = make_controller_factory(scenario(f"{__name__}:broken_factory"))
    assert factory is not None
    with pytest.raises(SumoError, match=r"sumo.controller = '.*:broken_factory': .* raised TypeError: expected str"):
        factory()
    with pytest.raises(SumoError, match=r"sumo.controller = 'os:sep': sep in os is a str, not a function"):
        make_controller_factory(scenario("os:sep"))


# ----------------------------------------------------------------------------- $AEV_OCP_MAX_MEMORY_GB and load()
@pytest.mark.parametrize("raw", ["lots", "nan", "-4", "inf", "0", "1e400"])
def test_a_bad_memory_budget_is_refused_not_replaced(monkeypatch: pytest.MonkeyPatch, raw: str) -> None:
    from aev_ocp.limits import memory_limit_bytes

    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", raw)
    with pytest.raises(ParameterError, match=r"\$AEV_OCP_MAX_MEMORY_GB = .* is not allowed"):
        memory_limit_bytes()


def test_memory_budget_values(monkeypatch: pytest.MonkeyPatch) -> None:
    from aev_ocp.limits import DEFAULT_MEMORY_LIMIT_GB, memory_limit_bytes

    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", " 0.75 ")
    assert memory_limit_bytes() == 0.75e9
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "")
    assert memory_limit_bytes() == DEFAULT_MEMORY_LIMIT_GB * 1e9
    monkeypatch.delenv("AEV_OCP_MAX_MEMORY_GB")
    assert memory_limit_bytes() == DEFAULT_MEMORY_LIMIT_GB * 1e9


def test_bad_memory_budget_is_bad_input_for_commands_and_load(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    import aev_ocp

    f = tmp_path / "u.toml"
    f.write_text(SCENARIO.format(L=12.5, U=7.25))
    out = tmp_path / "o"
    rc, _, err = run_cli(["simulate", str(f), "--out", str(out), "--no-plots"], capsys)
    assert rc == 0
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "lots")
    rc, _, err = run_cli(["simulate", str(f), "--out", str(tmp_path / "o2"), "--no-plots"], capsys)
    assert rc == 2 and "$AEV_OCP_MAX_MEMORY_GB = 'lots'" in one_error(err)
    with pytest.raises(ParameterError, match="AEV_OCP_MAX_MEMORY_GB"):  # the caller's setting, not a damaged folder
        aev_ocp.load(out)
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "0.5")
    assert aev_ocp.load(out).speed.shape[1] == 1


@pytest.mark.parametrize("path", [12345, None, 2.5, ["o"]])
def test_load_of_a_non_path_says_so(path: object) -> None:
    import aev_ocp
    from aev_ocp.saved import LoadError

    with pytest.raises(LoadError, match=r"expected an output folder \(a str or pathlib.Path\), got"):
        aev_ocp.load(path)  # type: ignore[arg-type]
    with pytest.raises(LoadError, match="expected an output folder"):
        aev_ocp.load_all(path)  # type: ignore[arg-type]


@pytest.mark.parametrize("key", [3, None, ("carfollowing", "kappa"), b"carfollowing.kappa"])
def test_override_key_that_is_not_a_string_is_named(key: object) -> None:
    """with_overrides({3: 1}) was an AttributeError ('int' object has no attribute 'split')."""
    from aev_ocp.overrides import OverrideError

    with pytest.raises(OverrideError, match=r"override key .* is not a dotted key path string"):
        load_scenario("table1").with_overrides({key: 0.05})  # type: ignore[dict-item]
    s = load_scenario("table1").with_overrides({"carfollowing.kappa": 0.07})  # a string key still works
    assert s.cf.kappa == 0.07


# ----------------------------------------------------------------------------- register_law / make_law
@pytest.mark.parametrize(
    "name, factory, says",
    [
        ("mine_probe", 42, "factory = 42 is not allowed"),
        (42, object, "name = 42 is not allowed"),
        ("", object, "name = '' is not allowed"),
        ("../x", object, "name = '../x' is not allowed"),
        ("a b", object, "name = 'a b' is not allowed"),
    ],
)
def test_register_law_refuses_what_make_law_could_never_build(name: object, factory: object, says: str) -> None:
    from aev_ocp.models.carfollowing import LAW_REGISTRY, register_law

    before = dict(LAW_REGISTRY)
    with pytest.raises(ParameterError, match=says.replace("(", r"\(")):
        register_law(name, factory)  # type: ignore[arg-type]
    assert LAW_REGISTRY == before


def test_registered_law_builds_by_name_and_make_law_of_a_non_string_is_named() -> None:
    """A law registered under a valid name builds with its coefficient: OVM with alpha = 1.7 at h = 2.3, v = 1.1
    gives alpha (V(h) - v) = 1.7 (tanh(0.3) + tanh(2) - 1.1) (paper eq. OVM, closed form)."""
    from aev_ocp.models.carfollowing import LAW_REGISTRY, OVM, make_law, register_law

    register_law("ovm-probe_3", OVM)
    try:
        law = make_law("OVM-probe_3", alpha=1.7)
        got = float(law.function(2.3, 1.1, 1.2))
        assert got == pytest.approx(1.7 * (math.tanh(0.3) + math.tanh(2.0) - 1.1), rel=1e-12)
    finally:
        LAW_REGISTRY.pop("ovm-probe_3", None)
    for bad in (42, None):
        with pytest.raises(ParameterError, match=f"unknown car-following law {bad!r}"):
            make_law(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", ["0.1", "0.02,0.03,0.04", "a,b", "0.02,nan"])
def test_ocp_v_relax_option_is_named_as_typed(value: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The message named run_prop31's v_relax_V, not the --v-relax-V the user typed."""
    rc, _, err = run_cli(["ocp", "prop31", "--v-relax-V", value, "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and f"--v-relax-V = {value!r} is not allowed" in one_error(err)


# ----------------------------------------------------------------------------- the cascade's step limit
def test_cascade_step_limit_grows_with_the_horizon(monkeypatch: pytest.MonkeyPatch) -> None:
    """A fixed total of max_num_steps per vehicle cut long trips short with an unactionable 'raise max_num_steps'
    (e.g. a US06 leader held past its end, 5000 s: integration_failed at 4660 s). The limit is now per
    STEP_LIMIT_SPAN of model time. Scaled down here (span 20, 1000 steps) so that Table 1's 70 time units need
    4 spans: the run completes and equals the run with an unlimited budget to the last bit; with the horizon's
    single span it stops, and the message names the limit and the keys a user can change."""
    import aev_ocp.simulate as sim
    from aev_ocp.models.carfollowing import Proposed
    from aev_ocp.models.leader import PaperLeader
    from aev_ocp.params import SimOptions

    def run(max_steps: int):  # noqa: ANN202
        opts = SimOptions(dt_out=0.05, max_num_steps=max_steps, method="cascade")
        return sim.PlatoonSimulator(PaperLeader(), [Proposed()] * 2, None, opts).run([0.3, 3.5], [1.87, 1.87], 70.0)

    assert sim.cascade_step_limit(1000, 70.0) == 1000 and sim.cascade_step_limit(1000, 2500.0) == 3000
    monkeypatch.setattr(sim, "STEP_LIMIT_SPAN", 20.0)
    ref, got = run(10**9), run(1000)
    if "cascade" not in str(ref.meta):
        pytest.skip("no C compiler: the cascade did not run")
    assert max(s["nsteps"] + s["nrejected"] for s in ref.solver_stats) > 1000  # the old fixed total was too small
    assert got.status == "ok" and np.array_equal(got.omega, ref.omega) and np.array_equal(got.speed, ref.speed)
    monkeypatch.setattr(sim, "STEP_LIMIT_SPAN", 1000.0)
    cut = run(1000)
    assert cut.status == "integration_failed"
    assert "more than 1000 steps for this vehicle: loosen simulation.rtol/atol" in cut.events[0].message


# ----------------------------------------------------------------------------- OCPSolver inputs
def _lq_solver(N: int = 12):  # noqa: ANN202
    from aev_ocp import OCPSolver, TranscriptionOptions

    pb = ProblemBuilder("lq")
    x, u = pb.state("x"), pb.control("u", -1.5, 1.5)
    w = pb.stage_parameter("w")
    pb.set_der(x, u + w)
    pb.add_stage_cost(x**2 + 0.1 * u**2, "c")
    return OCPSolver(pb.build(), TranscriptionOptions(N=N))


@pytest.mark.parametrize(
    "kw, says",
    [
        (
            {"guess": (np.zeros((3, 3)), np.zeros((1, 12)))},
            r"guess X \(states at the nodes\) must be 1 × 13 finite numbers, got shape \(3, 3\)",
        ),
        ({"guess": (np.zeros(13), np.zeros((1, 5)))}, r"guess U must be \(up to\) 1 × 12 controls"),
        ({"guess": (np.full(13, np.nan), np.zeros(12))}, "guess X .* got a NaN or infinite entry"),
        ({"guess": "junk"}, r"guess must be a pair \(X, U\), got str"),
        ({"guess": (np.zeros(13), ["a"] * 12)}, "guess U .* must be an array of numbers"),
        ({"w": np.zeros(5)}, r"w \(per-interval parameters\) must be 1 × 12 finite numbers, got shape \(5,\)"),
        ({"w": np.full(12, np.inf)}, r"w \(per-interval parameters\) .* NaN or infinite"),
    ],
)
def test_ocp_solver_names_a_bad_guess_or_stage_parameter(kw: dict, says: str) -> None:
    """These were numpy's 'cannot reshape array of size 9 into shape (1,13)' (or a NaN sent to IPOPT)."""
    with pytest.raises(ParameterError, match=f"lq: {says}"):
        _lq_solver().solve([0.8], 2.5, **kw)


def test_ocp_solver_guess_equal_to_the_default_gives_the_same_optimum() -> None:
    """Second method: the default start (x0 held, u = 0) passed explicitly as the guess, with w = 0.3 given in
    either layout, finds the same optimum (IPOPT is deterministic)."""
    s = _lq_solver()
    a = s.solve([0.8], 2.5, w=np.full((1, 12), 0.3))
    b = s.solve([0.8], 2.5, w=[0.3] * 12, guess=(np.full((1, 13), 0.8), np.zeros((1, 12))))
    assert a.status == b.status == "optimal"
    assert a.objective == pytest.approx(b.objective, rel=1e-12) and a.objective > 0


@pytest.mark.parametrize("ls", ["magic", 5, None])
def test_transcription_options_refuse_an_unknown_linear_solver(ls: object) -> None:
    from aev_ocp import TranscriptionOptions

    with pytest.raises(ParameterError, match=r"TranscriptionOptions.linear_solver = .* is not allowed"):
        TranscriptionOptions(linear_solver=ls)  # type: ignore[arg-type]


def test_foreign_folder_message_has_no_none_source(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A ring experiment has no scenario file: the refusal said "of scenario 'sugiyama' (None)"."""
    out = str(tmp_path / "o")
    assert run_cli(["ring", "sugiyama", "--t-end-s", "2.5", "--out", out, "--no-plots"], capsys)[0] == 0
    rc, _, err = run_cli(["stability", "--law", "ovm", "--linear-only", "--no-plots", "--out", out], capsys)
    line = one_error(err)
    assert rc == 2 and "holds the results of 'aev-ocp ring' of scenario 'sugiyama';" in line and "None" not in line


# ----------------------------------------------------------------------------- a stopped study pool exits
HALF_WRITE = '''
import gc, os, struct, time
from multiprocessing.queues import SimpleQueue

def half_write():
    """In a pool worker: begin a result message on the pool's result pipe, then stall (killed mid-write)."""
    q = next(o for o in gc.get_objects() if isinstance(o, SimpleQueue))
    os.write(q._writer.fileno(), struct.pack("!i", 4000) + b"x" * 10)
    time.sleep(60)
'''
DRIVE = """
import multiprocessing as mp, sys, time
from concurrent.futures import ProcessPoolExecutor
sys.path.insert(0, sys.argv[1])
import halfmod
from aev_ocp.study.runner import _stop_pool

if __name__ == "__main__":
    ex = ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"))
    ex.submit(halfmod.half_write)
    time.sleep(2.5)  # the worker has begun its result
    _stop_pool(ex)
    print("stopped", flush=True)
"""


def test_a_pool_stopped_while_a_worker_writes_its_result_lets_the_process_exit(tmp_path: Path) -> None:
    """`study --time-limit` (or Ctrl-C) on the pool hung at exit about once in 8 on 2 loaded cores: a worker killed
    while sending its result left half a message in the result pipe, the pool's manager thread waited in recv() for
    ever, and the interpreter's exit joins that thread. Made deterministic here (a worker that writes half a
    message and stalls); the process must print 'stopped' and exit 0 within seconds."""
    import subprocess
    import sys

    (tmp_path / "halfmod.py").write_text(HALF_WRITE)
    (tmp_path / "drive.py").write_text(DRIVE)
    root = str(Path(__file__).resolve().parents[1])
    try:
        r = subprocess.run([sys.executable, "drive.py", root], cwd=tmp_path, capture_output=True, text=True, timeout=40)
    except subprocess.TimeoutExpired:
        pytest.fail("the process hung at exit after _stop_pool (the pool's manager thread was stuck in recv)")
    assert r.returncode == 0 and "stopped" in r.stdout, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "Bad file descriptor" not in r.stderr, r.stderr[-2000:]


ONE_TASK_STUDY = """\
name = "one_task"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.t_end" = 1.5
"platoon.followers" = 2
[[axes]]
key = "carfollowing.kappa"
values = [0.045]
[controllers]
laws = ["ovfl"]
"""


def test_time_limit_passing_as_the_last_task_ends_is_not_a_stop(tmp_path: Path) -> None:
    """A 1-task study whose 1 µs limit is past when its only task ends finished every task: it is complete (was
    TimeLimitStop '1 of 1 tasks stored', exit 1 from the command); a 2-point study with the same limit stops after
    its first task, as before."""
    from aev_ocp.study import run_study
    from aev_ocp.study.runner import TimeLimitStop

    f = tmp_path / "one.toml"
    f.write_text(ONE_TASK_STUDY)
    out = run_study(f, tmp_path / "o", executor="inprocess", report=False, time_limit_s=1e-6)
    assert out.n_tasks == 1 and out.n_failed == 0 and {r["controller"] for r in out.rows} == {"ovfl"}
    f.write_text(
        ONE_TASK_STUDY.replace("values = [0.045]", "values = [0.045, 0.065]").replace('"ovfl"]', '"proposed"]')
    )
    f.write_text(f.read_text().replace('reference = "ovfl"', 'reference = "proposed"'))
    with pytest.raises(TimeLimitStop, match="1 of 2 tasks stored"):
        run_study(f, tmp_path / "o2", executor="inprocess", report=False, time_limit_s=1e-6)

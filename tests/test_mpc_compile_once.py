"""Compile once, the MPC (issue 40 item 1): the vehicle's numbers (units, body, cell, thermal, limits), the traffic
formulation's SI parameters, the bounds and the cold-start law's coefficients are run-time inputs of the MPC's
generated C, so controllers that differ only in those values share one compiled library; each still follows its
own numbers: its steps equal those of the problem with its numbers written in, solved by the interpreted Python
twin of the compiled step (tests/rti_twin.py), which shares no compiled code with it.

Which libraries a controller asks the compile cache for is read by a spy on :func:`aev_ocp.compiled.compile_shared`
(as the step's and the NLP's builders call it), in the environment's cache: a library is named by a hash of its
generated source, compiler and flags, so two controllers that need two libraries ask for two paths whether the cache
is empty or warm (issue 40: an empty cache per file compiled the -O3 mpc_step, ~8 s of gcc, and §9's IPOPT NLP,
~4 s, in every run of the suite). That a library asked for twice is compiled once, and says so once, is checked on
the compile cache itself: tests/test_compile_once.py (a real cold compile, counted) and
tests/test_compiled_cache.py (concurrent processes, one 'compiling' line)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest
from rti_twin import install

import aev_ocp.compiled as B
from aev_ocp.errors import AevOcpWarning
from aev_ocp.mpc.controller import MPCController
from aev_ocp.mpc.settings import MPCSettings
from aev_ocp.ocp import following as F
from aev_ocp.ocp.formulation import DEFAULT_FORMULATION, problem_formulation, s9_formulation, same_problem
from aev_ocp.ocp.traffic import TrafficParams
from aev_ocp.params import EVParams, ThermalParams, Units, VehicleLimits, VehicleParams

pytestmark = pytest.mark.skipif(B.compiler() is None, reason="needs a C compiler")

S = MPCSettings(N=6, dt=0.2, solver="rti", codegen=True)


def _ev_a() -> EVParams:
    return EVParams()  # L = 10 m, U = 5 m/s, 1752 kg, the default limits


def _ev_b() -> EVParams:
    # other units, a lighter and draggier car, an other acceleration range: the same structure
    veh = dataclasses.replace(VehicleParams(), mass_kg=1390.0, drag_coefficient=0.31, efficiency=0.87)
    lim = dataclasses.replace(VehicleLimits(), a_min_mps2=-6.5, a_max_mps2=3.1)
    return EVParams(units=Units(15.0, 17.0), vehicle=veh, limits=lim)


def _inputs(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    z = np.array([1.3 - 0.02 * k, 0.9 + 0.015 * k, 1e-4 * k, 5e-5 * k, 0.8 - 1e-4 * k])
    return z, np.full(6, 0.95 - 0.01 * k), np.full(6, 0.94 - 0.01 * k)


def _run(c: MPCController, steps: int = 8) -> tuple[np.ndarray, np.ndarray]:
    a, X = [], []
    for k in range(steps):
        sol = c.solve(*_inputs(k))
        assert sol.success, sol.status
        a.append(sol.a[0])
        X.append(sol.X)
    return np.array(a), np.array(X)


def _numbers_in(ev: EVParams, formulation=DEFAULT_FORMULATION) -> MPCController:  # noqa: ANN001
    """The same MPC on the problem with the vehicle's numbers written in, stepped by the interpreted twin."""
    baked = problem_formulation(formulation.build(ev, S.dt))
    return install(MPCController(S.with_(codegen=False), ev, formulation=baked))


def _spy_builds(m: pytest.MonkeyPatch) -> list[tuple[str, str]]:
    """(stem, library file) of every library built or found in the compile cache from now on (under ``m``): the
    compile_shared of aev_ocp.compiled (the step's builds) and of aev_ocp.mpc.nlp (the NLP's), spied."""
    import aev_ocp.mpc.nlp as nlp

    got: list[tuple[str, str]] = []
    real = B.compile_shared

    def spy(source: str, stem: str, *a, **kw):  # noqa: ANN002, ANN003, ANN202
        built = real(source, stem, *a, **kw)
        assert built.path is not None, built.error
        got.append((stem, built.path.name))
        return built

    m.setattr(B, "compile_shared", spy)
    m.setattr(nlp, "compile_shared", spy)
    return got


@pytest.fixture(scope="module")
def first_of_s() -> tuple[list[tuple[str, str]], MPCController]:
    """The first controller of S built in this file, and the libraries it asked the compile cache for (shared by the
    tests that compare later controllers of the same structure with it)."""
    with pytest.MonkeyPatch.context() as m:
        got = _spy_builds(m)
        first = MPCController(S, _ev_a())
        return list(got), first


def _loaded(c: MPCController) -> str:
    """The file of the step library the controller loaded."""
    assert c.compiled_step is not None
    return Path(c.compiled_step.lib._name).name


@pytest.mark.slow  # 32 steps of the compiled library and of its interpreted twin
def test_two_vehicles_of_other_units_and_mass_share_one_library(first_of_s, monkeypatch) -> None:  # noqa: ANN001
    first, ca_ = first_of_s
    assert [stem for stem, _ in first] == ["mpc_step"]  # the first controller of S: its step library, nothing else
    got = _spy_builds(monkeypatch)
    cb = MPCController(S, _ev_b())
    assert got == first  # one library for both: the second vehicle asks for the same file
    assert _loaded(ca_) == _loaded(cb) == first[0][1]
    runs = {}
    for name, c, ev in (("a", ca_, _ev_a()), ("b", cb, _ev_b())):
        a, X = _run(c)
        a_ref, X_ref = _run(_numbers_in(ev))
        np.testing.assert_allclose(a, a_ref, rtol=0, atol=1e-9)  # the same results as with the numbers in
        np.testing.assert_allclose(X, X_ref, rtol=0, atol=1e-8)
        runs[name] = a
    assert np.abs(runs["a"] - runs["b"]).max() > 1e-3  # each follows its own numbers


def test_a_traffic_rti_controller_compiles_no_ipopt_nlp_it_never_runs(first_of_s, monkeypatch) -> None:  # noqa: ANN001
    """The cold IPOPT's NLP (library mpc_nlp_ipopt, ~0.65 MB of C) is generated and compiled only for a controller
    that can run it: the traffic formulation's rti path starts cold by RTI and never does, §9's interpreted rti path
    starts with a cold IPOPT and builds it with the controller (a first step that had to build it would blow its time
    budget). The first controller of S asked for mpc_step and nothing else: a second one asks for the same file, and
    its cold step for nothing at all (moved here from tests/test_compile_once.py, issue 40)."""
    first, _ = first_of_s
    assert [stem for stem, _ in first] == ["mpc_step"]  # the first controller of S: its step and no IPOPT NLP
    got = _spy_builds(monkeypatch)
    traffic = MPCController(S)
    assert got == first
    sol = traffic.solve(np.array([1.3, 0.9, 0.0, 0.0, 0.8]), np.full(6, 0.95), np.full(6, 0.95))
    assert sol.success and sol.path != "ipopt-cold"
    assert got == first  # a cold step of the traffic path builds no IPOPT
    # §9's rti path starts with a cold IPOPT: built with the controller (interpreted here: no library)
    s9 = MPCController(S.with_(codegen=False), formulation=s9_formulation())
    assert s9._cold_ipopt is not None and traffic._cold_ipopt is None
    assert got == first


@pytest.mark.slow  # two IPOPT controllers on the compiled NLP and two on the interpreted one
def test_s9_ipopt_nlp_is_one_library_for_two_vehicles(monkeypatch) -> None:  # noqa: ANN001
    got = _spy_builds(monkeypatch)
    s = MPCSettings(N=5, dt=0.1, solver="ipopt", codegen=True)
    f = s9_formulation()
    out = {}
    for name, ev in (("a", _ev_a()), ("b", _ev_b())):
        n0 = len(got)
        c = MPCController(s, ev, formulation=f)
        assert c.codegen_active
        out[name] = got[n0:]
        ref = MPCController(s.with_(codegen=False), ev, formulation=problem_formulation(f.build(ev, s.dt)))
        z, vm, vh = _inputs(1)
        sol, sol_ref = c.solve(z, vm[:5], vh[:5]), ref.solve(z, vm[:5], vh[:5])
        assert sol.success and sol_ref.success
        np.testing.assert_allclose(sol.X, sol_ref.X, rtol=0, atol=1e-7)  # IPOPT tolerance 1e-8
        out[name + "_a0"] = sol.a[0]
    # each vehicle's IPOPT (warm and cold) asks for the NLP's library and nothing else: one file for both
    assert out["a"] and out["b"] and {stem for stem, _ in out["a"] + out["b"]} == {"mpc_nlp_ipopt"}
    assert {lib for _, lib in out["a"] + out["b"]} == {out["a"][0][1]}
    assert abs(out["a_a0"] - out["b_a0"]) > 1e-3


@pytest.mark.parametrize(
    "formulation, ev",
    [
        (DEFAULT_FORMULATION, _ev_a()),
        (DEFAULT_FORMULATION, _ev_b()),
        (DEFAULT_FORMULATION.with_(traffic=TrafficParams(margin_weight=0.7, target_gap_m=5.5)), _ev_b()),
        (DEFAULT_FORMULATION, EVParams(limits=dataclasses.replace(VehicleLimits(), lag_s=0.4))),  # a_act state
        (
            DEFAULT_FORMULATION.with_(temperature=F.TemperatureTerms(temperature_state=True)),
            EVParams(thermal=ThermalParams(enabled=True)),
        ),
        (s9_formulation(), _ev_b()),
        (s9_formulation(objective="omega"), EVParams(units=Units(20.0, 22.0))),
    ],
)
def test_runtime_parameters_give_the_problem_with_the_numbers_in(formulation, ev) -> None:  # noqa: ANN001
    rt = formulation.mpc_problem(ev, 0.1)
    assert rt.np_ > formulation.build(ev, 0.1).np_  # the numbers are parameters
    assert "ev__units__length_m" in rt.meta["parameter_defaults"]
    assert same_problem(formulation.build(ev, 0.1), rt) == ""


def test_a_number_the_model_cannot_take_as_a_symbol_keeps_the_numbers_in(monkeypatch) -> None:
    """math.sin(grade) turns a symbol into NaN without an error: a field that stays a parameter by mistake is caught
    by the probe comparison, and the MPC falls back to the problem with the numbers in (with a warning)."""
    import aev_ocp.ocp.traffic as T

    monkeypatch.setattr(T, "EV_NUMBERS", ("vehicle.rotating_mass_kg",))  # the grade would become a parameter
    for _ in range(2):  # the second call reuses the kept problem and warns again
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            pr = DEFAULT_FORMULATION.mpc_problem(EVParams(), 0.1)
        assert any(isinstance(x.message, AevOcpWarning) and "numbers in" in str(x.message) for x in w)
    assert "ev__units__length_m" not in pr.meta["parameter_defaults"]
    assert same_problem(DEFAULT_FORMULATION.build(EVParams(), 0.1), pr) == ""


def test_the_mpc_problem_is_built_once_per_formulation_vehicle_step_and_ocv_form() -> None:
    """Equal (formulation, vehicle, dt, OCV form) give the one problem kept; another vehicle, step, formulation or OCV
    form gives its own (with its own numbers); after clear_mpc_problems the problem is built again, equal to the one before."""
    from aev_ocp.models.battery import piecewise_ocv
    from aev_ocp.ocp.formulation import clear_mpc_problems

    clear_mpc_problems()
    ev = _ev_b()
    pr = DEFAULT_FORMULATION.mpc_problem(ev, 0.13)
    assert DEFAULT_FORMULATION.mpc_problem(dataclasses.replace(ev), 0.13) is pr  # an equal vehicle
    heavier = dataclasses.replace(ev, vehicle=dataclasses.replace(ev.vehicle, mass_kg=1612.5))
    others = [
        DEFAULT_FORMULATION.mpc_problem(heavier, 0.13),
        DEFAULT_FORMULATION.mpc_problem(ev, 0.17),
        DEFAULT_FORMULATION.with_(traffic=TrafficParams(margin_weight=0.7)).mpc_problem(ev, 0.13),
    ]
    assert all(o is not pr for o in others)
    assert others[0].meta["parameter_defaults"]["ev__vehicle__mass_kg"] == 1612.5
    assert pr.meta["parameter_defaults"]["ev__vehicle__mass_kg"] == 1390.0
    with piecewise_ocv():
        pw = DEFAULT_FORMULATION.mpc_problem(ev, 0.13)
        assert pw is not pr and DEFAULT_FORMULATION.mpc_problem(ev, 0.13) is pw
    assert pw.ode.n_instructions() != pr.ode.n_instructions()  # comparisons in place of the B-spline's call
    clear_mpc_problems()
    again = DEFAULT_FORMULATION.mpc_problem(ev, 0.13)
    assert again is not pr and same_problem(pr, again) == "" and again.np_ == pr.np_


def test_parameters_of_names_every_float_and_keeps_the_numbers_asked_for() -> None:
    from aev_ocp.ocp.problem import ProblemBuilder
    from aev_ocp.params import ParameterError

    pb = ProblemBuilder("p")
    twin = pb.parameters_of(_ev_b(), "ev", ("vehicle.grade_rad", "limits"))
    d = pb._p_values
    assert d["ev__units__length_m"] == 15.0 and d["ev__vehicle__mass_kg"] == 1390.0
    assert "ev__vehicle__grade_rad" not in d and not any(k.startswith("ev__limits__") for k in d)
    assert isinstance(twin.vehicle.grade_rad, float) and twin.limits == _ev_b().limits  # kept as numbers
    assert not isinstance(twin.vehicle.mass_kg, float)  # a symbol
    with pytest.raises(ParameterError, match="not a finite number"):
        pb.parameter("bad", float("nan"))
    with pytest.raises(ParameterError, match="a parameter named 'ev__units__length_m' exists"):
        pb.parameter("ev__units__length_m", 1.0)


def test_a_user_parameter_with_a_value_is_its_default_in_the_mpc() -> None:
    """ProblemBuilder.parameter(name, value): the MPC uses the value unless parameter_values names the parameter."""
    s = MPCSettings(N=5, dt=0.1, solver="ipopt-cold", codegen=False)

    def problem(ev, dt):  # noqa: ANN001, ANN202
        pb = F.following_problem(ev, name="with_k")
        k = pb.parameter("k_extra", 0.37)
        pb.add_stage_cost(k * pb.u["a"] ** 2, "extra")
        return pb

    z, vm, vh = _inputs(2)
    runs = {}
    for name, pv in (("default", None), ("explicit", {"k_extra": 0.37}), ("other", {"k_extra": 3.0})):
        c = MPCController(s, EVParams(), problem=problem, parameter_values=pv)
        sol = c.solve(z, vm[:5], vh[:5])
        assert sol.success, sol.status
        runs[name] = sol.a
    assert np.array_equal(runs["default"], runs["explicit"])
    assert np.abs(runs["default"] - runs["other"]).max() > 1e-4


def test_controllers_of_one_problem_share_its_horizon_nlp_and_step_c_yet_keep_their_own_state(monkeypatch) -> None:  # noqa: ANN001
    """Equal (problem, settings, guess law) share one HorizonNLP and build the step's five functions once; each
    controller keeps its own compiled step and warm start: two run in turns on other inputs give, bit for bit, what
    each gives alone when built with nothing shared. Another vehicle, guess law or horizon, or a user problem, gets
    its own NLP."""
    import aev_ocp.mpc.cstep as cstep
    import aev_ocp.mpc.nlp as nlp
    from aev_ocp.models.carfollowing import Proposed

    def forget() -> None:
        nlp._HORIZONS.clear()
        cstep._DIGESTS.clear()

    built = []
    real = cstep.rti_functions
    monkeypatch.setattr(cstep, "rti_functions", lambda c: built.append(c) or real(c))
    forget()
    ev = _ev_b()
    c1 = MPCController(S, ev)
    c2 = MPCController(S, dataclasses.replace(ev))  # an equal vehicle: the one problem Formulation.mpc_problem keeps
    assert c2.nlp is c1.nlp and len(built) == 1
    assert c2.compiled_step is not None and c2.compiled_step is not c1.compiled_step
    # of the same structure (one step library, no compilation): another vehicle, guess law's numbers, iteration cap
    same = [
        MPCController(S, _ev_a()),
        MPCController(S, ev, guess_law=Proposed(kappa=0.045)),
        MPCController(S.with_(max_iter=150), ev),
    ]
    assert {_loaded(c) for c in same} == {_loaded(c1)}
    # a user problem (here the one with the numbers in, as _numbers_in builds it): never shared
    users = [MPCController(S, formulation=problem_formulation(DEFAULT_FORMULATION.build(ev, S.dt))) for _ in range(2)]
    assert len({id(c.nlp) for c in [c1, *same, *users]}) == 6
    assert _loaded(users[0]) == _loaded(users[1]) != _loaded(c1)  # its step's C holds the numbers

    def steps(c: MPCController, shift: int, k: int) -> tuple[float, np.ndarray]:
        z, vm, vh = _inputs(k + shift)
        sol = c.solve(z, vm, vh)
        assert sol.success, sol.status
        return sol.a[0], sol.X

    turns = [(steps(c1, 0, k), steps(c2, 3, k)) for k in range(6)]
    for shift, i in ((0, 0), (3, 1)):
        forget()
        alone = MPCController(S, dataclasses.replace(ev))
        assert alone.nlp is not c1.nlp
        for k in range(6):
            a, X = steps(alone, shift, k)
            assert a == turns[k][i][0] and np.array_equal(X, turns[k][i][1])
    for k in range(6):  # the user problem's own library: the same steps as the shared one's, numbers in
        a, X = steps(users[0], 0, k)
        assert abs(a - turns[k][0][0]) < 1e-9 and np.abs(X - turns[k][0][1]).max() < 1e-8

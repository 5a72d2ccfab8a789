"""Compile once, the MPC (issue 40 item 1): the vehicle's numbers (units, body, cell, thermal, limits), the traffic
formulation's SI parameters, the bounds and the cold-start law's coefficients are run-time inputs of the MPC's
generated C, so controllers that differ only in those values share one compiled library; each still follows its
own numbers: its steps equal those of the problem with its numbers written in, solved by the interpreted Python
twin of the compiled step (tests/rti_twin.py), which shares no compiled code with it. Compilations are counted
with :func:`aev_ocp.compiled.compilations`, never timed."""

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


@pytest.fixture(scope="module")
def step_cache(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str], MPCController]:
    """ONE empty compile cache for this file's tests that count the traffic step's compilations, and the first
    controller of S built into it: (the cache, what that first build compiled, the controller). Every later controller
    of the same structure, in any test of the file, must compile nothing (the compile-once invariant itself): the
    file compiles the mpc_step library (~8 s of gcc at the tuned flags) once instead of once per test."""
    cache = tmp_path_factory.mktemp("step_cache")
    with pytest.MonkeyPatch.context() as m:
        m.setenv("AEV_OCP_CACHE", str(cache))
        n0 = len(B.compilations())
        first = MPCController(S, _ev_a())
        return cache, B.compilations()[n0:], first


@pytest.mark.slow  # 32 steps of the compiled library and of its interpreted twin
def test_two_vehicles_of_other_units_and_mass_share_one_library(step_cache, monkeypatch) -> None:  # noqa: ANN001
    cache, first, ca_ = step_cache
    monkeypatch.setenv("AEV_OCP_CACHE", str(cache))
    assert first == ["mpc_step"]  # the first controller of S compiled its library into the empty cache
    n0 = len(B.compilations())
    cb = MPCController(S, _ev_b())
    assert B.compilations()[n0:] == []  # one library for both: the second vehicle compiles nothing
    assert ca_.compiled_step is not None and cb.compiled_step is not None
    assert list((cache / "mpc").glob("mpc_step_*.so")).__len__() == 1
    runs = {}
    for name, c, ev in (("a", ca_, _ev_a()), ("b", cb, _ev_b())):
        a, X = _run(c)
        a_ref, X_ref = _run(_numbers_in(ev))
        np.testing.assert_allclose(a, a_ref, rtol=0, atol=1e-9)  # the same results as with the numbers in
        np.testing.assert_allclose(X, X_ref, rtol=0, atol=1e-8)
        runs[name] = a
    assert np.abs(runs["a"] - runs["b"]).max() > 1e-3  # each follows its own numbers


def test_a_traffic_rti_controller_compiles_no_ipopt_nlp_it_never_runs(step_cache, monkeypatch) -> None:  # noqa: ANN001
    """The cold IPOPT's NLP (library mpc_nlp_ipopt, ~0.65 MB of C) is generated and compiled only for a controller
    that can run it: the traffic formulation's rti path starts cold by RTI and never does, §9's interpreted rti path
    starts with a cold IPOPT and builds it with the controller (a first step that had to build it would blow its time
    budget). In the file's cache, where the first controller of S compiled mpc_step and nothing else: a second one,
    and its cold step, compile nothing at all (moved here from tests/test_compile_once.py, issue 40: it compiled the
    same mpc_step library in a cache of its own)."""
    cache, first, _ = step_cache
    monkeypatch.setenv("AEV_OCP_CACHE", str(cache))
    assert first == ["mpc_step"]  # the first controller of S compiled its step and no IPOPT NLP
    n0 = len(B.compilations())
    traffic = MPCController(S)
    assert B.compilations()[n0:] == []
    sol = traffic.solve(np.array([1.3, 0.9, 0.0, 0.0, 0.8]), np.full(6, 0.95), np.full(6, 0.95))
    assert sol.success and sol.path != "ipopt-cold"
    assert B.compilations()[n0:] == []  # a cold step of the traffic path builds no IPOPT
    # §9's rti path starts with a cold IPOPT: built with the controller (interpreted here: no second compilation)
    s9 = MPCController(S.with_(codegen=False), formulation=s9_formulation())
    assert s9._cold_ipopt is not None and traffic._cold_ipopt is None


@pytest.mark.slow  # one IPOPT NLP library (~10 s of gcc)
def test_s9_ipopt_nlp_is_one_library_for_two_vehicles(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    s = MPCSettings(N=5, dt=0.1, solver="ipopt", codegen=True)
    f = s9_formulation()
    n0 = len(B.compilations())
    got = {}
    for name, ev in (("a", _ev_a()), ("b", _ev_b())):
        c = MPCController(s, ev, formulation=f)
        ref = MPCController(s.with_(codegen=False), ev, formulation=problem_formulation(f.build(ev, s.dt)))
        z, vm, vh = _inputs(1)
        sol, sol_ref = c.solve(z, vm[:5], vh[:5]), ref.solve(z, vm[:5], vh[:5])
        assert sol.success and sol_ref.success
        np.testing.assert_allclose(sol.X, sol_ref.X, rtol=0, atol=1e-7)  # IPOPT tolerance 1e-8
        got[name] = sol.a[0]
    assert B.compilations()[n0:] == ["mpc_nlp_ipopt"]
    assert abs(got["a"] - got["b"]) > 1e-3


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
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        pr = DEFAULT_FORMULATION.mpc_problem(EVParams(), 0.1)
    assert any(isinstance(x.message, AevOcpWarning) and "numbers in" in str(x.message) for x in w)
    assert "ev__units__length_m" not in pr.meta["parameter_defaults"]
    assert same_problem(DEFAULT_FORMULATION.build(EVParams(), 0.1), pr) == ""


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

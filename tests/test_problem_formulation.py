"""A user problem passed as ``problem=`` (aev_ocp/ocp/formulation.py): its derived items for every problem family
and every way of giving it (a builder, a built problem, a function): the family read from the builder's meta, the
cold start that family takes (the RTI from the law's rollout for traffic and custom problems, a cold IPOPT solve for
model guide §9's), its bounds (declared ones first, then the built-in's meta, else none), its name, cost key and
secondary costs; and the MPC built on it starting the way its family says."""

from __future__ import annotations

import math

import pytest

from aev_ocp.models import Proposed
from aev_ocp.mpc import MPCSettings
from aev_ocp.mpc.policy import MPCPolicy
from aev_ocp.ocp.following import OBJECTIVES, FollowingBounds, following_problem
from aev_ocp.ocp.formulation import problem_formulation, s9_formulation, traffic_formulation
from aev_ocp.ocp.problem import ProblemBuilder
from aev_ocp.ocp.traffic import TrafficParams, traffic_problem
from aev_ocp.params import EVParams, Units

EV = EVParams(units=Units(11.0, 6.0))  # model and SI differ
TP = TrafficParams(standstill_gap_m=2.6, time_headway_s=1.3, v_max_mps=27.0)
FB = FollowingBounds(h_min=0.31, v_max=2.3, a_min=-1.9, a_max=1.15)


def _custom(declared: bool = True) -> ProblemBuilder:
    """A problem of its own (no meta): the closed loop's states and control, declared bounds on h, v, a."""
    pb = ProblemBuilder("my_own", time_unit="model")
    h = pb.state("h", lb=0.27 if declared else -math.inf)
    v = pb.state("v", lb=0.0, ub=2.9) if declared else pb.state("v")
    for nm, rate in (("V1", -0.26), ("V2", -0.01), ("S", 0.0)):  # a cell at rest, relaxing
        x = pb.state(nm)
        pb.set_der(x, rate * x)
    a = pb.control("a", lb=-1.7, ub=0.95) if declared else pb.control("a")
    vl = pb.stage_parameter("v_mean")
    pb.stage_parameter("v_hat")
    pb.set_der(h, vl - v)
    pb.set_der(v, a)
    pb.add_stage_cost(0.37 * a**2 + 0.11 * (h - 1.3) ** 2)
    return pb


def _families():
    t = traffic_problem(EV, TP, 0.1, name="my_traffic")
    yield "traffic-builder", t, "traffic", "my_traffic", traffic_formulation(TP).bounds_model(EV).as_dict()
    yield "traffic-built", t.build(), "traffic", "my_traffic", traffic_formulation(TP).bounds_model(EV).as_dict()
    for obj in OBJECTIVES:
        s = following_problem(EV, FB, objective=obj, name=f"my_s9_{obj}")
        b = s9_formulation(bounds=FB, objective=obj).bounds_model(EV).as_dict()
        yield f"s9-{obj}-builder", s, "s9", f"my_s9_{obj}", b
        yield f"s9-{obj}-built", s.build(), "s9", f"my_s9_{obj}", b
    declared = {"h_min": 0.27, "v_min": 0.0, "v_max": 2.9, "a_min": -1.7, "a_max": 0.95}
    yield "custom-builder", _custom(), "custom", "my_own", declared
    yield "custom-built", _custom().build(), "custom", "my_own", declared
    none = dict.fromkeys(declared)
    yield "custom-undeclared", _custom(False), "custom", "my_own", {**none, "v_min": None}


FAMILIES = list(_families())


@pytest.mark.parametrize("label, problem, family, name, bounds", FAMILIES, ids=[f[0] for f in FAMILIES])
def test_every_family_derives_its_own_items(label, problem, family, name, bounds) -> None:
    f = problem_formulation(problem)
    assert f.kind == "problem" and f.family == family
    assert f.rti_cold_start is (family != "s9")  # only §9 starts by a cold IPOPT solve
    assert f.name == name and f.controller_name == f"mpc({name})"
    assert f.cost_key == "cost_problem" and f.other_costs == ("cost_s9",)
    got = f.bounds_model(EV).as_dict()
    assert got.keys() == bounds.keys()
    for k, v in bounds.items():
        assert (got[k] is None) if v is None else got[k] == pytest.approx(v, rel=1e-14), (k, got[k], v)
    lo, hi = f.accel_bounds(EV)
    assert lo == (bounds["a_min"] if bounds["a_min"] is not None else -math.inf)
    assert hi == (bounds["a_max"] if bounds["a_max"] is not None else math.inf)
    assert f.describe()["family"] == family


def test_a_function_problem_is_custom_until_built() -> None:
    """A function (ev, dt) -> problem states no family and no bounds before it is called (documented): the RTI's
    cold start from the law, no bounds; its problem on a grid is the function's."""
    f = problem_formulation(lambda ev, dt: traffic_problem(ev, TP, dt, name="fn_traffic"))
    assert f.family == "custom" and f.rti_cold_start
    assert set(f.bounds_model(EV).as_dict().values()) == {None}
    assert f.build(EV, 0.1).name == "fn_traffic"


def test_the_built_ins_differ_where_the_user_problem_does_not() -> None:
    """The traffic and §9 built-ins keep their kinds' keys (a problem= of the same family is still 'problem')."""
    t, s = traffic_formulation(TP), s9_formulation(bounds=FB)
    assert (t.family, t.rti_cold_start, t.cost_key, t.name) == ("traffic", True, "cost_traffic", "traffic")
    assert (s.family, s.rti_cold_start, s.cost_key, s.other_costs) == ("s9", False, "cost_s9", ())


@pytest.mark.parametrize("family", ["traffic", "s9"])
def test_the_mpc_on_a_user_problem_starts_as_its_family_says(family: str) -> None:
    pb = traffic_problem(EV, TP, 0.1, name="my_traffic") if family == "traffic" else following_problem(EV, FB)
    s = MPCSettings(N=5, solver="ipopt", codegen=False, predictor="oracle")
    pol = MPCPolicy(s, EV, Proposed(), "constant-velocity", problem=pb)
    assert pol.formulation.family == family
    assert pol.controller.rti_cold_start is (family == "traffic")

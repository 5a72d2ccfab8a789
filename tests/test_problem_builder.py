"""ProblemBuilder refuses every name given twice (variables, cost terms and outputs, path and terminal
constraints), replaces a cost term only when asked, checks terminal constraints like path constraints, and
maps states by name. Values are checked by evaluating the built CasADi Functions at distinct points."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aev_ocp.ocp.following import following_problem, term_names
from aev_ocp.ocp.problem import ProblemBuilder
from aev_ocp.params import EVParams, ParameterError


def _small() -> ProblemBuilder:
    pb = ProblemBuilder("toy")
    x = pb.state("x", -5.0, 5.0)
    y = pb.state("y")
    u = pb.control("u", -2.0, 3.0)
    pb.parameter("k")
    pb.set_der(x, y)
    pb.set_der(y, u)
    pb.add_stage_cost(x**2, "track")
    return pb


@pytest.mark.parametrize(
    "make",
    [
        lambda pb: pb.state("x"),
        lambda pb: pb.control("x"),
        lambda pb: pb.parameter("u"),
        lambda pb: pb.stage_parameter("k"),
        lambda pb: pb.state("k"),
    ],
)
def test_a_variable_name_is_used_once(make) -> None:
    pb = _small()
    with pytest.raises(ParameterError, match="exists already"):
        make(pb)
    assert list(pb.x) == ["x", "y"] and list(pb.u) == ["u"] and list(pb.p) == ["k"]  # nothing half-added


@pytest.mark.parametrize(
    "add",
    [
        lambda pb, e: pb.add_stage_cost(e, "track"),
        lambda pb, e: pb.add_integral_cost(e, "track"),
        lambda pb, e: pb.add_output("track", e),
    ],
)
def test_a_cost_term_or_output_name_is_used_once(add) -> None:
    pb = _small()
    with pytest.raises(ParameterError, match="'track' exists already; pass replace=True"):
        add(pb, pb.x["y"] ** 2)
    assert pb.stage_terms.keys() == {"track"} and not pb.integral_terms and not pb._outputs


def test_replace_true_replaces_the_term_and_only_it() -> None:
    pb = _small()
    pb.add_stage_cost(0.7 * pb.u["u"] ** 2, "effort")
    pb.add_stage_cost(2.9 * pb.x["y"] ** 2, "track", replace=True)
    prob = pb.build()
    x, u, p = [1.3, -0.4], [2.2], [0.6]
    assert float(prob.stage(x, u, [], p)) == pytest.approx(2.9 * 0.4**2 + 0.7 * 2.2**2, rel=1e-14)
    out = prob.outputs(x, u, [], p)
    names = [prob.outputs.name_out(i) for i in range(prob.outputs.n_out())]
    assert sorted(names) == ["effort", "track"]
    assert float(out[names.index("track")]) == pytest.approx(2.9 * 0.4**2, rel=1e-14)


def test_the_s9_accel_term_is_not_replaced_silently() -> None:
    """following_problem's w_a·a² is the term 'accel': a user term of that name is refused; with
    replace=True the stage cost is the other terms plus the new one (evaluated at distinct values)."""
    pb = following_problem(EVParams())
    a = pb.u["a"]
    with pytest.raises(ParameterError, match="stage cost term 'accel'"):
        pb.add_stage_cost(0.37 * a**2, "accel")
    before = pb.build()
    pb.add_stage_cost(0.37 * a**4, "accel", replace=True)
    after = pb.build()
    z = [1.7, 1.1, 0.013, 0.004, 0.62]
    u = [0.31] + [0.0] * (len(pb.u) - 1)
    w = [1.05, 1.02]
    wts = [1.3, 0.45, 0.8, 2.2]
    outs_b = dict(
        zip([before.outputs.name_out(i) for i in range(before.outputs.n_out())], before.outputs(z, u, w, wts))
    )
    others = sum(float(outs_b[nm]) for nm in term_names("heat") if nm != "accel")
    assert float(after.stage(z, u, w, wts)) == pytest.approx(others + 0.37 * 0.31**4, rel=1e-12)
    assert float(outs_b["accel"]) == pytest.approx(2.2 * 0.31**2, rel=1e-12)  # w_a a² before


def test_default_names_never_collide_with_given_ones() -> None:
    pb = _small()
    pb.add_stage_cost(pb.x["y"] ** 2, "stage0")
    pb.add_stage_cost(pb.u["u"] ** 2)  # would have been 'stage1' = ok, then:
    pb.add_stage_cost(pb.x["x"] ** 4)
    assert len(pb.stage_terms) == 4
    pb.subject_to(pb.x["x"], -1.0, 1.0, name="c1")
    pb.subject_to(pb.x["y"], -1.0, 1.0)
    pb.subject_to(pb.x["y"] + pb.x["x"], -1.0, 1.0)
    assert len({c[0] for c in pb._path}) == 3


@pytest.mark.parametrize("terminal", [False, True])
def test_terminal_and_path_constraints_are_checked_alike(terminal: bool) -> None:
    pb = _small()
    add = pb.subject_to_terminal if terminal else pb.subject_to
    kind = "terminal constraint" if terminal else "constraint"
    x = pb.x["x"]
    add(x, -1.0, 1.0, name="box")
    cases = [
        ((x, -1.0, 1.0, "box"), f"toy: {kind} 'box': a {kind} named 'box' exists already"),
        ((x, 2.5, 1.5, "inv"), f"toy: {kind} 'inv' has lb = 2.5 > ub = 1.5"),
        ((x, float("nan"), 1.0, "nan"), f"toy: {kind} 'nan': bounds must not be NaN"),
        ((x, "low", 1.0, "txt"), f"toy: {kind} 'txt': bounds must be numbers"),
        ((ca.vertcat(x, x), 0.0, 1.0, "vec"), f"toy: {kind} 'vec' must be a scalar expression"),
        ((x, 0.0, 1.0, "not a name"), f"toy: {kind} name 'not a name' must be an identifier"),
        ((ca.SX.sym("stray"), 0.0, 1.0, "free"), f"toy: {kind} 'free' depends on 'stray'"),
    ]
    for (e, lb, ub, name), msg in cases:
        with pytest.raises(ParameterError) as err:
            add(e, lb, ub, name=name)
        assert str(err.value).startswith(msg), str(err.value)
    assert len(pb._terminal if terminal else pb._path) == 1


def test_a_terminal_constraint_may_not_use_a_control() -> None:
    pb = _small()
    with pytest.raises(ParameterError, match="terminal constraint 'end' depends on 'u'.*states and parameters"):
        pb.subject_to_terminal(pb.u["u"] + pb.x["x"], 0.0, 0.0, name="end")
    pb.subject_to_terminal(pb.x["x"] - pb.p["k"], 0.0, 0.0, name="end")  # states and parameters: fine
    prob = pb.build()
    assert float(prob.terminal([0.9, -2.0], [0.25])) == pytest.approx(0.65, rel=1e-14)


def test_soft_constraint_names_are_checked_before_anything_is_added() -> None:
    pb = _small()
    pb.add_stage_cost(pb.u["u"] ** 2, "penalty_cap")
    n_u = len(pb.u)
    with pytest.raises(ParameterError, match="'penalty_cap' exists already"):
        pb.subject_to(pb.u["u"], ub=1.1, soft=5.7, name="cap")
    assert len(pb.u) == n_u and not pb._path


def test_states_are_mapped_by_name() -> None:
    pb = ProblemBuilder("order")
    names = ["S", "h", "V2", "v"]
    syms = [pb.state(n) for n in names]
    for s in syms:
        pb.set_der(s, 0.0)
    pb.add_stage_cost(sum(syms))
    prob = pb.build()
    assert prob.state_indices(["h", "v", "S"]) == [1, 3, 0]
    with pytest.raises(ParameterError, match="no state named 'V1'; its states are"):
        prob.state_indices(["h", "V1"])
    x = np.array([0.5, 1.5, 2.5, 3.5])
    assert list(x[prob.state_indices(["v", "h"])]) == [3.5, 1.5]


def test_bad_state_bounds_name_the_state() -> None:
    pb = ProblemBuilder("b")
    with pytest.raises(ParameterError, match="state 'h' has lb = 3.0 > ub = 2.0"):
        pb.state("h", 3.0, 2.0)
    assert "h" not in pb.x

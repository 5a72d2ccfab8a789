"""ProblemBuilder refuses every name given twice (variables, cost terms and outputs, path and terminal
constraints), replaces a cost term only when asked, checks terminal constraints like path constraints, and
maps states by name. Values are checked by evaluating the built CasADi Functions at distinct points."""

from __future__ import annotations

import math

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


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
def _toy() -> tuple[ProblemBuilder, ca.SX, ca.SX, ca.SX]:
    pb = ProblemBuilder("toy")
    x, u, p = pb.state("x"), pb.control("u"), pb.parameter("p")
    return pb, x, u, p


OUTSIDER = ca.SX.sym("x")  # same name as the builder's state, another symbol


def _lq_solver(N: int = 12):  # noqa: ANN202
    from aev_ocp import OCPSolver, TranscriptionOptions

    pb = ProblemBuilder("lq")
    x, u = pb.state("x"), pb.control("u", -1.5, 1.5)
    w = pb.stage_parameter("w")
    pb.set_der(x, u + w)
    pb.add_stage_cost(x**2 + 0.1 * u**2, "c")
    return OCPSolver(pb.build(), TranscriptionOptions(N=N))


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

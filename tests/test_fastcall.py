"""aev_ocp.fastcall: Functions called on bound buffers give CasADi's own numbers, bit for bit, against the plain call
with DM matrices, for every way an argument may be given; bad shapes and failing evaluations are named."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aev_ocp.fastcall import ColumnCall, column_call
from aev_ocp.models.battery_step import battery_step, step
from aev_ocp.models.leader import PaperLeader
from aev_ocp.params import EVParams

RNG = np.random.default_rng(20261204)


def _fn() -> ca.Function:
    """Two inputs of 3 and 1 rows, two outputs of 2 and 1 rows, every entry used differently (a wrong order shows)."""
    x, s = ca.SX.sym("x", 3), ca.SX.sym("s")
    y = ca.vertcat(x[0] * 1.7 + x[1] ** 2 - s, ca.sin(x[2]) * s + 0.3 * x[0])
    return ca.Function("f", [x, s], [y, x[2] - 2.9 * x[1] + s**3])


@pytest.mark.parametrize("n", [1, 3, 17])
def test_columns_equal_the_plain_call_bit_for_bit(n: int) -> None:
    f = _fn()
    X, S = RNG.normal(size=(3, n)), RNG.normal(size=n)
    want = [np.asarray(y) for y in f(X, S.reshape(1, -1))]
    got = ColumnCall(f)(X, S)
    for g, w in zip(got, want):
        assert g.shape == w.shape
        np.testing.assert_array_equal(g, w)
    # a shared column and a scalar broadcast to every column, as the plain call repeats them
    x0, s0 = RNG.normal(size=3), -0.37
    want = [np.asarray(y) for y in f(np.repeat(x0[:, None], n, axis=1), np.full((1, n), s0))]
    for g, w in zip(ColumnCall(f)(x0, np.full(n, s0)), want):
        np.testing.assert_array_equal(g, w)
    for g, w in zip(ColumnCall(f)(X, s0), [np.asarray(y) for y in f(X, np.full((1, n), s0))]):
        np.testing.assert_array_equal(g, w)


def test_sizes_are_kept_and_reused() -> None:
    c = ColumnCall(_fn(), sizes_kept=2)
    for n in (2, 5, 2, 7):
        c(RNG.normal(size=(3, n)), RNG.normal(size=n))
    assert list(c._maps) == [5, 7]  # the oldest size dropped
    assert column_call(c.fn) is column_call(c.fn) and column_call(_fn()) is not column_call(c.fn)


def test_bad_shapes_are_named() -> None:
    c = ColumnCall(_fn())
    with pytest.raises(ValueError, match="argument of 4 values for an input of 3 rows"):
        c(np.zeros(4), 1.0)
    with pytest.raises(ValueError, match=r"argument 0 has shape \(6,\)"):
        c(np.zeros(6), np.zeros(2))  # 3x2 would be ambiguous as a flat array: refused
    with pytest.raises(TypeError, match="takes 2 arguments"):
        c(np.zeros(3))
    m = ca.SX.sym("m", 2, 2)
    with pytest.raises(ValueError, match="input 0 is 2x2: must be a dense column"):
        ColumnCall(ca.Function("g", [m], [ca.trace(m)]))


def test_a_failing_evaluation_raises_the_functions_own_error() -> None:
    x = ca.MX.sym("x")
    f = ca.Function("checked", [x], [x.attachAssert(x > 0, "x must be positive here") * 2.3])
    c = ColumnCall(f)
    np.testing.assert_array_equal(c(np.array([0.4, 1.1]))[0], np.asarray(f(np.array([[0.4, 1.1]]))))
    with pytest.raises(RuntimeError, match="x must be positive here"):
        c(np.array([0.4, -1.1]))


def test_the_sites_give_the_plain_calls_numbers() -> None:
    lead = PaperLeader()
    t = np.linspace(0.0, 23.0, 101)
    np.testing.assert_array_equal(lead.speed_np(t), np.asarray(lead.speed_function(t.reshape(1, -1))).ravel())
    assert lead.speed_np(4.1)[0] == float(lead.speed_function(4.1))
    ev = EVParams()
    n = 4
    x = np.vstack([RNG.uniform(-0.01, 0.01, (2, n)), RNG.uniform(0.3, 0.9, (1, n)), np.zeros((4, n))])
    v0, a = RNG.uniform(0.5, 1.5, n), RNG.uniform(-0.4, 0.4, n)
    got = step(ev, x, v0, a, 0.1)
    want = battery_step(ev)(x, v0[None, :], a[None, :], 0.1)
    np.testing.assert_array_equal(got[0], np.asarray(want[0]))
    np.testing.assert_array_equal(got[1], np.asarray(want[1]).ravel())
    np.testing.assert_array_equal(got[2], np.asarray(want[2]).ravel())


def test_a_reused_id_is_not_taken_for_the_function_that_had_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """An entry whose Function is another object (a freed Function's id given to a new one) is rebuilt."""
    import aev_ocp.fastcall as fc

    f, g = _fn(), _fn()
    monkeypatch.setattr(fc, "_CALLS", {id(g): (f, ColumnCall(f))})
    assert column_call(g).fn is g


def test_scalar_is_the_plain_call_at_one_point_and_raises_its_error() -> None:
    from aev_ocp.models.carfollowing import IDM, Proposed

    for law in (Proposed(), IDM()):
        c = column_call(law.function)
        for h, v, vl in [(2.37, 1.61, 1.83), (0.41, 0.0, 0.77), (7.9, 2.2, 0.3)]:
            assert c.scalar(h, v, vl) == float(law.function(h, v, vl))  # first call builds, later ones reuse
            assert c.scalar(h, v, vl) == float(law.function(h, v, vl))
    x = ca.MX.sym("x")
    c = ColumnCall(ca.Function("checked", [x], [x.attachAssert(x > 0, "x must be positive here") * 2.3]))
    assert c.scalar(0.4) == 0.4 * 2.3
    with pytest.raises(RuntimeError, match="x must be positive here"):
        c.scalar(-0.4)


def test_remember_keeps_the_newest_entries_up_to_its_bound() -> None:
    """aev_ocp.params.remember, the bound of every per-process cache: on, inside and beyond the bound."""
    from aev_ocp.params import remember

    cache: dict[str, float] = {}
    assert remember(cache, "a", 1.5, 3) == 1.5
    remember(cache, "b", 2.5, 3)
    remember(cache, "c", 3.5, 3)
    assert list(cache) == ["a", "b", "c"]  # on the bound: nothing forgotten
    remember(cache, "d", 4.5, 3)
    assert list(cache) == ["b", "c", "d"]  # beyond it: the oldest goes
    remember(cache, "c", 7.5, 3)  # an existing key keeps its place and takes the new value
    assert cache == {"b": 2.5, "c": 7.5, "d": 4.5} and list(cache) == ["b", "c", "d"]

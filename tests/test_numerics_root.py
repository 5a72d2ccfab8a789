"""bracketed_root (aev_ocp.numerics): the run-time root finder of the safety bound and the contact search,
against closed-form roots over many random brackets."""

import math

import pytest
from hypothesis import given, settings, strategies as st

from aev_ocp.numerics import bracketed_root


@settings(max_examples=200, deadline=None)
@given(r=st.floats(-37.0, 53.0), lo=st.floats(0.013, 41.0), hi=st.floats(0.017, 29.0), p=st.sampled_from([1, 3, 5]))
def test_odd_power_root(r: float, lo: float, hi: float, p: int) -> None:
    x = bracketed_root(lambda t: (t - r) ** p * 0.73 + (t - r) * 1e-3, r - lo, r + hi, 1e-14)
    assert abs(x - r) <= 1e-9 * max(1.0, abs(r))


@pytest.mark.parametrize(
    "f,a,b,root",
    [
        (lambda t: math.cos(t) - t, 0.0, 1.3, 0.7390851332151607),
        (lambda t: math.exp(t) - 2.7e-6, -30.0, 4.0, math.log(2.7e-6)),
        (lambda t: t**3 - 2.0, 0.0, 3.0, 2.0 ** (1 / 3)),
    ],
)
def test_closed_forms(f, a, b, root) -> None:
    assert bracketed_root(f, a, b, 1e-15) == pytest.approx(root, abs=1e-13)


def test_same_sign_is_refused() -> None:
    with pytest.raises(ValueError, match="same sign"):
        bracketed_root(lambda t: t * t + 0.3, -1.0, 2.0)


@settings(max_examples=200, deadline=None)
@given(r=st.floats(-37.0, 53.0), lo=st.floats(0.013, 41.0), hi=st.floats(0.017, 29.0), up=st.booleans())
def test_side_b_returns_the_end_on_f_of_b_side(r: float, lo: float, hi: float, up: bool) -> None:
    """side="b": the end returned is on f(b)'s side of 0 (f < 0 or f ≥ 0), within the bracket tolerance of the root,
    whichever end has the smaller |f| (a curved f makes both ends end up close)."""
    s = 1.0 if up else -1.0
    f = lambda t: s * ((t - r) ** 3 * 0.61 + (t - r) * 2e-3)  # noqa: E731
    x = bracketed_root(f, r - lo, r + hi, 1e-12, side="b")
    assert (f(x) < 0.0) == (f(r + hi) < 0.0)
    assert abs(x - r) <= 1e-9 * max(1.0, abs(r))
    g = lambda t: -f(t)  # noqa: E731
    y = bracketed_root(g, r + hi, r - lo, 1e-12, side="b")  # b below the root
    assert (g(y) < 0.0) == (g(r - lo) < 0.0)
    assert abs(y - r) <= 1e-9 * max(1.0, abs(r))


def test_side_b_counts_zero_with_the_non_negative_side() -> None:
    """A step from −0.3 to 0 at t = 0.737: a zero is not a root but a value on the f ≥ 0 side, so the answer
    is at or just after the step; from the other end, just before it."""
    step = lambda t: 0.0 if t >= 0.737 else -0.3  # noqa: E731
    x = bracketed_root(step, 0.0, 2.3, 1e-13, side="b")
    assert 0.737 <= x <= 0.737 + 1e-12
    y = bracketed_root(step, 2.3, 0.0, 1e-13, side="b")
    assert 0.737 - 1e-12 <= y < 0.737
    with pytest.raises(ValueError, match="same sign"):
        bracketed_root(step, 0.9, 2.3, side="b")

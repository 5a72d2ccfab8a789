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

"""Seeds and intervals (aev_ocp.intervals) against SciPy and hand computations; the verdict on, inside and outside
zero."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.intervals import DEFAULT_SEEDS, Interval, compare, difference, summarize, t_quantile, verdict
from aev_ocp.params import ParameterError

pytestmark = pytest.mark.quick
stats = pytest.importorskip("scipy.stats")


@settings(max_examples=40, deadline=None)
@given(p=st.floats(0.51, 0.9995), df=st.floats(0.7, 300.0))
def test_t_quantile_against_scipy(p: float, df: float) -> None:
    assert t_quantile(p, df) == pytest.approx(float(stats.t.ppf(p, df)), rel=1e-9)
    assert t_quantile(1 - p, df) == pytest.approx(float(stats.t.ppf(1 - p, df)), rel=1e-9)


def test_t_interval_by_hand_and_against_scipy() -> None:
    x = [3.7, 4.15, 3.92, 4.41, 3.58, 4.06, 3.81, 4.27, 3.66, 4.12]
    iv = summarize(x)
    n, m, s = len(x), sum(x) / len(x), float(np.std(x, ddof=1))
    half = 2.262157162798205 * s / math.sqrt(n)  # t_{0.975, 9} (tables)
    assert (iv.mean, iv.lo, iv.hi, iv.n) == pytest.approx((m, m - half, m + half, n), rel=1e-10)
    lo, hi = stats.t.interval(0.95, n - 1, loc=m, scale=stats.sem(x))
    assert (iv.lo, iv.hi) == pytest.approx((lo, hi), rel=1e-10)


def test_bootstrap_interval_against_scipy() -> None:
    rng = np.random.default_rng(11)
    x = rng.gamma(2.3, 1.7, size=14)
    ours = summarize(x, method="bootstrap", resamples=40_000, seed=3)
    ref = stats.bootstrap((x,), np.mean, confidence_level=0.95, method="percentile", n_resamples=40_000, random_state=5)
    ci = ref.confidence_interval
    spread = float(ci.high - ci.low)
    assert ours.lo == pytest.approx(ci.low, abs=0.03 * spread)
    assert ours.hi == pytest.approx(ci.high, abs=0.03 * spread)
    assert ours.lo < float(np.mean(x)) < ours.hi


def test_welch_difference_against_scipy() -> None:
    a = [5.1, 4.8, 5.6, 5.3, 4.9, 5.2, 5.0, 5.5]
    b = [4.6, 4.9, 4.4, 4.7, 5.0, 4.5, 4.3, 4.8, 4.6, 4.9, 4.4]
    d = difference(a, b, paired=False)
    res = stats.ttest_ind(a, b, equal_var=False)
    ci = res.confidence_interval(0.95)
    assert (d.lo, d.hi) == pytest.approx((ci.low, ci.high), rel=1e-9)


def test_paired_difference_is_the_interval_of_the_differences() -> None:
    a = np.array([2.31, 2.05, 2.44, 2.18, 2.27, 2.39, 2.12, 2.21, 2.35, 2.09])
    b = a + np.array([0.11, 0.07, 0.13, 0.09, 0.12, 0.08, 0.1, 0.14, 0.06, 0.1])
    d = difference(a, b)
    ref = summarize(a - b)
    assert (d.mean, d.lo, d.hi) == (ref.mean, ref.lo, ref.hi)
    assert verdict(d) == "better" and verdict(d, lower_is_better=False) == "worse"


@pytest.mark.parametrize(
    "lo, hi, expected",
    [
        (-0.3, -0.01, "better"),  # wholly below zero: a lower
        (0.02, 0.4, "worse"),  # wholly above
        (-0.2, 0.3, "tie"),  # straddles zero
        (0.0, 0.5, "tie"),  # touches zero: not excluded
        (-0.5, 0.0, "tie"),
    ],
)
def test_verdict_on_inside_and_outside_zero(lo: float, hi: float, expected: str) -> None:
    assert verdict(Interval(0.5 * (lo + hi), lo, hi, 10, 0.95, "t")) == expected


def test_compare_row_and_bad_input() -> None:
    a = [1.02, 0.97, 1.05, 0.99, 1.01, 0.98, 1.03, 1.0, 0.96, 1.04]
    row = compare(a, [x + 0.001 * (-1) ** i for i, x in enumerate(a)])
    assert row["verdict"] == "tie"
    assert len(DEFAULT_SEEDS) >= 10
    with pytest.raises(ParameterError, match="at least 2"):
        summarize([1.3])
    with pytest.raises(ParameterError, match="finite"):
        summarize([1.3, float("nan")])
    with pytest.raises(ParameterError, match="as many"):
        difference([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(ParameterError, match="method"):
        summarize([1.0, 2.0], method="jackknife")  # type: ignore[arg-type]


_values = st.lists(st.floats(-50.0, 50.0, allow_nan=False), min_size=2, max_size=25)


@settings(max_examples=60, deadline=None)
@given(x=_values)
def test_t_interval_on_random_data_against_scipy(x: list[float]) -> None:
    spread = max(x) - min(x)
    if spread < 1e-6 * (1.0 + max(abs(v) for v in x)):  # (nearly) constant data: scipy's interval degenerates
        return
    iv = summarize(x)
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=float(np.mean(x)), scale=stats.sem(x))
    assert (iv.lo, iv.hi) == pytest.approx((lo, hi), rel=1e-8, abs=1e-9 * spread)
    assert iv.n == len(x)


@settings(max_examples=60, deadline=None)
@given(
    pairs=st.lists(
        st.tuples(st.floats(-50.0, 50.0, allow_nan=False), st.floats(-50.0, 50.0, allow_nan=False)),
        min_size=2,
        max_size=25,
    ),
    level=st.sampled_from([0.9, 0.95, 0.99]),
)
def test_paired_difference_on_random_data_against_scipy(pairs: list[tuple[float, float]], level: float) -> None:
    a = np.array([p[0] for p in pairs])
    b = np.array([p[1] for p in pairs])
    d = a - b
    if np.ptp(d) < 1e-6 * (1.0 + np.abs(d).max()):  # constant differences: a zero-width interval, scipy gives nan
        return
    ours = difference(a, b, paired=True, level=level)
    ci = stats.ttest_rel(a, b).confidence_interval(level)
    assert ours.mean == pytest.approx(float(np.mean(d)), rel=1e-12, abs=1e-12)
    assert (ours.lo, ours.hi) == pytest.approx((ci.low, ci.high), rel=1e-8, abs=1e-9 * float(np.ptp(d)))
    # the verdict follows the interval: 'tie' exactly when scipy's interval holds 0 (ends included)
    expected = "tie" if ci.low <= 0.0 <= ci.high else ("better" if ci.high < 0.0 else "worse")
    if min(abs(ci.low), abs(ci.high)) > 1e-9 * (1.0 + abs(ci.low) + abs(ci.high)):  # not on the boundary
        assert verdict(ours) == expected


def test_verdict_exactly_at_zero_and_for_larger_is_better() -> None:
    # the paired differences [-1, 1, ..., ] give an interval whose end is exactly 0 only by construction: build it
    touching_low = Interval(0.25, 0.0, 0.5, 10, 0.95, "t")  # lo == 0.0: zero is in the interval
    touching_high = Interval(-0.25, -0.5, 0.0, 10, 0.95, "t")
    assert verdict(touching_low) == verdict(touching_high) == "tie"
    assert verdict(touching_low, lower_is_better=False) == "tie"
    just_above = Interval(0.25, 5e-324, 0.5, 10, 0.95, "t")  # the smallest positive float: zero excluded
    just_below = Interval(-0.25, -0.5, -5e-324, 10, 0.95, "t")
    assert verdict(just_above) == "worse" and verdict(just_below) == "better"
    assert verdict(just_above, lower_is_better=False) == "better"
    assert verdict(just_below, lower_is_better=False) == "worse"

"""Forecasts a car can make, and how wrong they were (issue 8: realistic forecasts)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from aev_ocp.control import forecast_rms
from aev_ocp.mpc.predictors import (
    ConstantAccelerationPredictor,
    ConstantVelocityPredictor,
    DecayingAccelerationPredictor,
    Measurements,
    make_predictor,
)
from aev_ocp.numerics import least_squares_slope
from aev_ocp.params import ParameterError


def _meas(v0: float, a: float, n: int = 6, dt: float = 0.1) -> Measurements:
    t = dt * np.arange(n)
    return Measurements(t, v0 + a * t)


@pytest.mark.quick
@given(v0=st.floats(0.3, 2.1), a=st.floats(-0.9, 0.9), tau=st.floats(0.2, 4.0))
@settings(max_examples=60, deadline=None)
def test_decaying_acceleration_closed_form_and_consistent_position(v0: float, a: float, tau: float) -> None:
    """v̂ = v_k + â τ (1 − e^{−s/τ}) until it stops, x̂ its exact integral (checked by a fine trapezoid)."""
    assume(v0 + 0.5 * a > 0.02)  # measured speeds stay positive
    m = _meas(v0, a)
    vk = float(m.v[-1])
    x, v = DecayingAccelerationPredictor(tau, 4).predict(0.5, 0.1, 30, m)
    s = 0.1 * np.arange(31)
    v_ref = np.maximum(vk + a * tau * (1 - np.exp(-s / tau)), 0.0)
    if a < 0 and vk + a * tau < 0:  # once stopped, stays stopped
        s_stop = -tau * np.log1p(vk / (a * tau))
        v_ref = np.where(s >= s_stop, 0.0, v_ref)
    np.testing.assert_allclose(v, v_ref, atol=1e-9)
    fine = np.linspace(0, 3.0, 30001)
    vf = np.maximum(vk + a * tau * (1 - np.exp(-fine / tau)), 0.0)
    xf = np.concatenate([[0.0], np.cumsum(0.5 * (vf[1:] + vf[:-1]) * np.diff(fine))])
    np.testing.assert_allclose(x, np.interp(s, fine, xf), atol=2e-7)


@given(
    t0=st.floats(-50.0, 500.0),
    steps=st.lists(st.floats(0.013, 0.7), min_size=1, max_size=9),
    v=st.lists(st.floats(-3.0, 40.0), min_size=10, max_size=10),
)
@settings(max_examples=80, deadline=None)
def test_least_squares_slope_is_polyfits_slope(t0: float, steps: list[float], v: list[float]) -> None:
    """The closed-form slope equals NumPy's least-squares fit of a line (an SVD) on uneven samples."""
    t = t0 + np.concatenate([[0.0], np.cumsum(steps)])
    vv = np.asarray(v[: t.size])
    ref = float(np.polyfit(t - t[-1], vv, 1)[0])
    assert least_squares_slope(t, vv) == pytest.approx(ref, rel=1e-9, abs=1e-9 * (1.0 + np.ptp(vv) / np.ptp(t)))


def test_least_squares_slope_limits() -> None:
    """An exact line gives its slope; one sample or a single repeated time gives 0 (no slope to fit)."""
    t = np.array([3.1, 3.4, 3.5, 4.2])
    assert least_squares_slope(t, 0.37 - 1.9 * t) == pytest.approx(-1.9, rel=1e-12)
    assert least_squares_slope(t[:2], 0.37 - 1.9 * t[:2]) == pytest.approx(-1.9, rel=1e-12)  # two points: the line
    assert least_squares_slope(t[:1], [2.3]) == 0.0
    assert least_squares_slope(np.full(3, 7.3), [1.2, 2.5, 0.4]) == 0.0


def test_decaying_acceleration_between_constant_velocity_and_acceleration() -> None:
    m = _meas(1.3, 0.45)
    _, v_cv = ConstantVelocityPredictor().predict(0.5, 0.1, 20, m)
    _, v_ca = ConstantAccelerationPredictor(4).predict(0.5, 0.1, 20, m)
    _, v_short = DecayingAccelerationPredictor(1e-4, 4).predict(0.5, 0.1, 20, m)
    _, v_long = DecayingAccelerationPredictor(1e5, 4).predict(0.5, 0.1, 20, m)
    np.testing.assert_allclose(v_short, v_cv, atol=1e-4)
    np.testing.assert_allclose(v_long, v_ca, atol=1e-4)


def test_decaying_acceleration_time_constant_follows_the_units() -> None:
    p = make_predictor("decaying-acceleration", time_unit_s=0.8824)
    assert p.tau == pytest.approx(2.0 / 0.8824)
    with pytest.raises(ParameterError, match="tau"):
        DecayingAccelerationPredictor(-0.3)


def test_forecast_rms_is_zero_for_the_truth_and_closed_form_for_constant_velocity() -> None:
    """Leader v = 0.6 + 0.35 t sampled every 0.1: the truth has error 0; a constant-velocity forecast made
    at t_k misses by 0.35·j·dt at t_k + j·dt (inside the run)."""
    dt, K, N = 0.1, 25, 8
    t = dt * np.arange(K + 1)
    v = 0.6 + 0.35 * t
    truth = [0.6 + 0.35 * (k * dt + dt * np.arange(N + 1)) for k in range(K)]
    assert forecast_rms(t, v, dt, truth) < 1e-12
    cv = [np.full(N + 1, v[k]) for k in range(K)]
    errs = [0.35 * j * dt for k in range(K) for j in range(N + 1) if k + j <= K]
    assert forecast_rms(t, v, dt, cv) == pytest.approx(float(np.sqrt(np.mean(np.square(errs)))), rel=1e-12)
    assert np.isnan(forecast_rms(t, v, dt, [None] * K))


def test_decaying_acceleration_at_standstill_predicts_standstill() -> None:
    t = 0.1 * np.arange(5)
    x, v = DecayingAccelerationPredictor(1.1, 4).predict(
        0.4, 0.1, 12, Measurements(t, np.array([0.2, 0.1, 0.0, -1e-9, -2e-9]))
    )
    assert np.all(x == 0) and np.all(v == 0)


def test_closed_loop_reports_the_forecast_error_of_each_predictor() -> None:
    """The oracle's forecast is the truth (error 0 to round-off); a measured predictor's is not."""
    from aev_ocp.mpc import MPCSettings, run_single

    rms = {
        p: run_single(MPCSettings(N=15, predictor=p), t_end=1.5).solver_stats[0]["forecast_rms"]
        for p in ("oracle", "constant-velocity")
    }
    assert rms["oracle"] < 1e-9
    assert rms["constant-velocity"] > 1e-2

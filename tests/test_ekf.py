"""The EKF's step (aev_ocp/estimation/base.py, EstimationModel.ekf_step) against a linear Kalman filter written here
in NumPy on the model linearised at the same point (they must agree to round-off: the same Jacobians, the textbook
covariance update (I − KC)P instead of the Joseph form), and its covariance against the errors it makes: symmetric
positive definite, and the normalised estimation error squared (NEES) of the battery's states within its χ² band
over many seeded runs of the model driven by noise of exactly the covariances the filter assumes."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.stats import chi2

from aev_ocp.estimation.base import BATTERY, MOTION, NX, EstimationModel
from aev_ocp.estimation.kalman import ITERATIONS
from aev_ocp.estimation.sensors import Sensors
from aev_ocp.params import EVParams

EV = EVParams()
SENSORS = Sensors()
MODEL = EstimationModel(EV, SENSORS)
B, M = list(BATTERY), list(MOTION)


def _spd(rng: np.random.Generator, scales: np.ndarray) -> np.ndarray:
    """A random symmetric positive definite matrix with standard deviations ~ scales and correlations ~ 0.3."""
    n = scales.size
    G = rng.normal(size=(n, n))
    C = np.eye(n) + 0.3 * (G @ G.T) / n
    d = np.sqrt(np.diag(C))
    return (C / np.outer(d, d)) * np.outer(scales, scales)


def _state_and_cov(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    x = np.array([0.62, 3.1e-3, 1.7e-3, 17.3, 9.1, -0.41, 8.7, 1.07, 0.93, 1.11, 0.96, 1.04])
    P = np.zeros((NX, NX))
    P[np.ix_(B, B)] = _spd(rng, np.array([0.03, 2e-4, 1.5e-4, 0.05, 0.07, 0.06, 0.04, 0.05]))
    P[np.ix_(M, M)] = _spd(rng, np.array([0.4, 0.3, 0.5, 0.2]))
    return x, P


def _linear_kf(x, P, u0, u1, y, dt):
    """The Kalman filter of the model linearised at x (time update) and at the prediction (measurement update)."""
    um = np.array([u1[0], 0.5 * (u0[1] + u1[1])])
    xp, A, Bu = (np.asarray(v) for v in MODEL.F(x, um, dt))
    xp = xp.ravel()
    Q = MODEL.process_noise(dt, Bu)
    Pp = A @ P @ A.T + Q
    yh, C = (np.asarray(v) for v in MODEL.H(xp, u1))
    yh = yh.ravel()
    R = MODEL.R
    xn, Pn = xp.copy(), np.zeros((NX, NX))
    for idx, rows in ((B, [0]), (M, [1, 2, 3])):
        Pb = Pp[np.ix_(idx, idx)]
        Cb = C[np.ix_(rows, idx)]
        S = Cb @ Pb @ Cb.T + R[np.ix_(rows, rows)]
        K = Pb @ Cb.T @ np.linalg.inv(S)
        xn[idx] = xp[idx] + K @ (y[rows] - yh[rows])
        Pn[np.ix_(idx, idx)] = (np.eye(len(idx)) - K @ Cb) @ Pb
    return xn, Pn, Pp


@pytest.mark.parametrize("seed", [3, 17, 41])
def test_one_ekf_step_equals_the_linear_kalman_filter_to_round_off(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x, P = _state_and_cov(rng)
    dt = 0.23
    u0, u1 = np.array([7.9, 0.31]), np.array([11.3, -0.57])
    xp = np.asarray(MODEL.F(x, np.array([u1[0], 0.5 * (u0[1] + u1[1])]), dt)[0]).ravel()
    y_pred = np.asarray(MODEL.H(xp, u1)[0]).ravel()
    y = y_pred + np.array([1.3e-3, 0.31, -0.17, 0.09])  # an innovation of a few σ on every channel
    xr, Pr, Pp = _linear_kf(x, P, u0, u1, y, dt)
    xe, Pe = (np.asarray(v) for v in MODEL.ekf_step(1)(x, P, u0, u1, y, dt))
    xe = xe.ravel()
    np.testing.assert_allclose(xe, xr, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(Pe, Pr, rtol=1e-7, atol=1e-12 * np.abs(Pr).max())
    # the Joseph form keeps the covariance symmetric and positive definite, smaller than the prediction's
    np.testing.assert_allclose(Pe, Pe.T, rtol=0, atol=1e-15 * np.abs(Pe).max())
    for idx in (B, M):
        blk = Pe[np.ix_(idx, idx)]
        assert np.linalg.eigvalsh(blk).min() > 0
        assert np.linalg.eigvalsh(Pp[np.ix_(idx, idx)] - blk).min() > -1e-12 * np.abs(blk).max()
    assert not np.any(Pe[np.ix_(B, M)])  # the two parts stay uncoupled


def test_dt_zero_is_the_measurement_update_alone() -> None:
    rng = np.random.default_rng(5)
    x, P = _state_and_cov(rng)
    u = np.array([9.7, 0.2])
    y = np.asarray(MODEL.H(x, u)[0]).ravel() + np.array([-0.9e-3, 0.2, 0.1, -0.05])
    xr, Pr, Pp = _linear_kf(x, P, u, u, y, 0.0)
    np.testing.assert_allclose(Pp, P, rtol=0, atol=1e-18)  # no time update
    xe, Pe = (np.asarray(v) for v in MODEL.ekf_step(1)(x, P, u, u, y, 0.0))
    np.testing.assert_allclose(xe.ravel(), xr, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(Pe, Pr, rtol=1e-7, atol=1e-12 * np.abs(Pr).max())


def test_battery_nees_within_its_chi2_band_over_seeded_runs() -> None:
    """Truth: the filter's own model, x_{k+1} = F(x_k, u) + w, y = h(x) + v with w ~ N(0, Q), v ~ N(0, R) (the
    covariances the filter assumes), x_0 ~ N(x̂_0, P_0); 50 seeded runs of 30 steps of 0.2 s with a varying
    current. The mean NEES of the battery's 8 states over the runs is χ²(50·8)/50-distributed when the filter's
    covariance is right: every step's mean within the two-sided 99.9 % band up to 2 of 30 steps, and the mean
    over all steps within ±10 % of 8."""
    runs, steps, dt = 50, 30, 0.2
    step = MODEL.ekf_step(ITERATIONS)
    nb = len(B)
    nees = np.zeros((runs, steps))
    x_hat0 = np.array([0.58, 0.0, 0.0, 21.0, 9.3, 0.0, 9.1, 1.0, 1.0, 1.0, 1.0, 1.0])
    P0 = np.diag([0.01**2, 2e-4**2, 2e-4**2, 0.3, 0.3, 0.5, 0.3, *([0.02**2] * 5)])
    xs, us = ca.SX.sym("x", NX), ca.SX.sym("u", 2)
    xn_s, _, Bu_s = MODEL.F(xs, us, dt)
    truth = ca.Function("truth", [xs, us], [xn_s, MODEL.process_noise_sx(dt, Bu_s)])
    for r in range(runs):
        rng = np.random.default_rng(1000 + r)
        x_true = x_hat0 + np.linalg.cholesky(P0) @ rng.normal(size=NX)
        x, P = x_hat0.copy(), P0.copy()
        u_prev = np.array([6.3, 0.0])
        for k in range(steps):
            u = np.array([6.3 + 9.7 * np.sin(0.37 * k + 0.1 * r), 0.4 * np.cos(0.23 * k)])
            um = np.array([u[0], 0.5 * (u_prev[1] + u[1])])
            xn, Q = truth(x_true, um)
            Q = np.asarray(Q)
            Q = 0.5 * (Q + Q.T)
            x_true = np.asarray(xn).ravel() + np.linalg.cholesky(Q + 1e-30 * np.eye(NX)) @ rng.normal(size=NX)
            y = np.asarray(MODEL.H(x_true, u)[0]).ravel() + np.sqrt(np.diag(MODEL.R)) * rng.normal(size=4)
            xo, Po = step(x, P, u_prev, u, y, dt)
            x, P, u_prev = np.asarray(xo).ravel(), np.asarray(Po), u
            e = (x_true - x)[B]
            Pb = P[np.ix_(B, B)]
            nees[r, k] = float(e @ np.linalg.solve(Pb, e))
            assert np.linalg.eigvalsh(0.5 * (Pb + Pb.T)).min() > 0
    mean = nees.mean(axis=0)
    lo, hi = chi2.ppf(0.0005, runs * nb) / runs, chi2.ppf(0.9995, runs * nb) / runs
    outside = int(np.sum((mean < lo) | (mean > hi)))
    assert outside <= 2, (lo, hi, mean.round(2))
    assert abs(nees.mean() / nb - 1.0) < 0.1, nees.mean()

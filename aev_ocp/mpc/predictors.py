"""Leader (predecessor) forecasts for the MPC (model guide §9).

A predictor returns, on the horizon grid t_j = t_0 + j·dt (j = 0…N), the predicted position
x̂_l(t_j) relative to x̂_l(t_0) = 0 [model length] and speed v̂_l(t_j) [model speed]. The MPC uses
the interval-mean speed (x̂_l(t_{j+1}) − x̂_l(t_j))/dt in the gap dynamics and v̂_l(t_j) in the w_r
term (:func:`forecast_intervals`). Write your own by subclassing :class:`LeaderPredictor`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ..models.leader import LeaderProfile
from ..numerics import least_squares_slope
from ..params import ParameterError


@dataclass
class Measurements:
    """What the ego vehicle has measured of its predecessor up to now: sample times [model time] and
    speeds [model speed], oldest first (the last entry is the current time t_0)."""

    t: np.ndarray
    v: np.ndarray


class LeaderPredictor(ABC):
    """Interface of a forecast of the vehicle ahead."""

    name: str = "predictor"

    @abstractmethod
    def predict(self, t0: float, dt: float, N: int, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        """(x̂ (N+1,) [model length, x̂[0] = 0], v̂ (N+1,) [model speed]) at t0 + j·dt, j = 0…N."""


class OraclePredictor(LeaderPredictor):
    """The true future of a known leader profile (model guide §9 'oracle')."""

    name = "oracle"

    def __init__(self, profile: LeaderProfile) -> None:
        self.profile = profile

    def predict(self, t0: float, dt: float, N: int, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        t = t0 + dt * np.arange(N + 1)
        x = np.asarray(self.profile.position(t), float)
        return x - x[0], self.profile.speed_np(t)


class ConstantVelocityPredictor(LeaderPredictor):
    """v̂_l(t) = the last measured speed (model guide §9 'constant-velocity')."""

    name = "constant-velocity"

    def predict(self, t0: float, dt: float, N: int, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        tau = dt * np.arange(N + 1)
        v0 = float(meas.v[-1])
        return v0 * tau, np.full(N + 1, v0)


class ConstantAccelerationPredictor(LeaderPredictor):
    """v̂_l(t) = v_0 + â (t − t_0), â the least-squares slope of the last ``window`` measured speeds,
    stopped at v = 0 (a vehicle does not reverse) (model guide §9 'constant-acceleration')."""

    name = "constant-acceleration"

    def __init__(self, window: int = 5) -> None:
        if not isinstance(window, int) or window < 2:
            raise ParameterError(
                f"ConstantAccelerationPredictor.window = {window!r} is not allowed: must be an integer >= 2"
            )
        self.window = window

    def predict(self, t0: float, dt: float, N: int, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        tau = dt * np.arange(N + 1)
        v0 = float(meas.v[-1])
        acc = least_squares_slope(meas.t[-self.window :], meas.v[-self.window :])
        v = np.maximum(v0 + acc * tau, 0.0)
        x = v0 * tau + 0.5 * acc * tau**2
        if acc < 0 and v0 > 0:  # stops at tau_s = −v0/acc and stays
            ts = -v0 / acc
            x = np.where(tau > ts, v0 * ts + 0.5 * acc * ts**2, x)
        elif v0 <= 0 and acc <= 0:
            x = np.zeros_like(tau)
        return x, v


class DecayingAccelerationPredictor(LeaderPredictor):
    """The predecessor's acceleration fades: a(t) = â e^{−(t − t_0)/τ} with â the least-squares slope of
    the last ``window`` measured speeds, so v̂ = v_0 + â τ (1 − e^{−(t−t_0)/τ}), stopped at v = 0.

    Between constant velocity (τ → 0) and constant acceleration (τ → ∞): drivers hold an acceleration
    for a few seconds, not for a whole horizon. τ [model time]; :func:`make_predictor` sets it from
    DECAY_TIME_S = 2 s with the scenario's units (a typical duration of an acceleration phase in urban
    drive cycles; an assumption, stated in the README)."""

    name = "decaying-acceleration"

    def __init__(self, tau: float, window: int = 5) -> None:
        if not (isinstance(tau, (int, float)) and np.isfinite(tau) and tau > 0):
            raise ParameterError(f"DecayingAccelerationPredictor.tau = {tau!r} is not allowed: must be a number > 0")
        if not isinstance(window, int) or window < 2:
            raise ParameterError(
                f"DecayingAccelerationPredictor.window = {window!r} is not allowed: must be an integer >= 2"
            )
        self.tau, self.window = float(tau), window

    def predict(self, t0: float, dt: float, N: int, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        s = dt * np.arange(N + 1)
        v0 = max(float(meas.v[-1]), 0.0)  # a measured speed is never negative; noise is clipped
        acc = self._slope(meas)
        if v0 == 0.0 and acc <= 0.0:
            return np.zeros(N + 1), np.zeros(N + 1)
        tau = self.tau
        e = 1.0 - np.exp(-s / tau)
        v = v0 + acc * tau * e
        x = v0 * s + acc * tau * (s - tau * e)
        if acc < 0 and v0 + acc * tau < 0:  # stops at s_stop and stays
            s_stop = -tau * np.log1p(v0 / (acc * tau))
            e_stop = 1.0 - np.exp(-s_stop / tau)
            x_stop = v0 * s_stop + acc * tau * (s_stop - tau * e_stop)
            v = np.where(s >= s_stop, 0.0, v)
            x = np.where(s >= s_stop, x_stop, x)
        return x, np.maximum(v, 0.0)

    def _slope(self, meas: Measurements) -> float:
        return least_squares_slope(meas.t[-self.window :], meas.v[-self.window :])


DECAY_TIME_S = 2.0  # [s] default τ of the decaying-acceleration predictor (see its docstring)


def plan_forecast(speeds: np.ndarray, dt: float, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Forecast from a predecessor's MPC plan (cooperative): node speeds (M+1,) with piecewise-constant
    acceleration, so x̂ is exact: x̂_{j+1} = x̂_j + (v_j + v_{j+1})/2·dt. Held at the last speed beyond
    the plan's horizon."""
    v = np.asarray(speeds, float).ravel()
    if v.size < N + 1:
        v = np.concatenate([v, np.full(N + 1 - v.size, v[-1])])
    v = v[: N + 1]
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[:-1] + v[1:]) * dt)])
    return x, v


def forecast_intervals(x_hat: np.ndarray, v_hat: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Per interval: mean speed (x̂(t_{j+1}) − x̂(t_j))/dt and v̂(t_j), both (N,) (model guide §9)."""
    x_hat, v_hat = np.asarray(x_hat, float), np.asarray(v_hat, float)
    return np.diff(x_hat) / dt, v_hat[:-1]


def make_predictor(
    name: str, profile: LeaderProfile | None = None, window: int = 5, time_unit_s: float | None = None
) -> LeaderPredictor:
    """Predictor by name: 'oracle' (needs the true profile), 'constant-velocity', 'constant-acceleration',
    'decaying-acceleration' (τ = DECAY_TIME_S converted with ``time_unit_s`` = T [s], default 2 s at T = 2 s)."""
    if name == "decaying-acceleration":
        return DecayingAccelerationPredictor(DECAY_TIME_S / (time_unit_s or 2.0), window)
    if name == "oracle":
        if profile is None:
            raise ParameterError("predictor 'oracle' needs the true leader profile (only the first follower has one)")
        return OraclePredictor(profile)
    if name == "constant-velocity":
        return ConstantVelocityPredictor()
    if name == "constant-acceleration":
        return ConstantAccelerationPredictor(window)
    raise ParameterError(
        f"predictor = {name!r} is not allowed: must be 'oracle', 'constant-velocity', "
        "'constant-acceleration', 'decaying-acceleration' (or 'cooperative' for a follower "
        "behind an MPC vehicle)"
    )

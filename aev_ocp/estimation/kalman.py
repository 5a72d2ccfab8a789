"""An extended Kalman filter on :class:`~aev_ocp.estimation.base.EstimationModel` (SOC, V1, V2 from pack voltage and
current; gap, predecessor speed and acceleration from the radar and the own speed)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..params import EVParams
from .base import Estimate, EstimationModel, estimate_of
from .sensors import Measurement, Sensors


#: iterations of the measurement update (an iterated EKF; 1 = the plain EKF)
ITERATIONS = 5


class EKF:
    """Extended Kalman filter (SI). ``soc0``: the initial SOC guess (None: the OCV inverted at the first
    voltage); the inputs over an interval are the mean of the measurements at its ends; the estimate is the filtered state at the measurement time predicted forward by ``lead_delay_s``
    for the gap and the predecessor's motion (the radar's delay; the battery's is left, its states move slowly)."""

    name = "ekf"

    def __init__(self, ev: EVParams, sensors: Sensors, soc0: float | None = None, ocv_offset_V: float = 0.0) -> None:
        self.model = EstimationModel(ev, sensors, ocv_offset_V)
        self.soc0 = soc0
        self.lead_delay_s = sensors.delay("gap")
        self.x = np.zeros(6)
        self.P = np.eye(6)
        self.t_s = 0.0
        self.u = np.zeros(2)

    def reset(self, first: Measurement) -> Estimate:
        """x0, P0 from the first measurement (:meth:`EstimationModel.initial`), then its update."""
        self.x, self.P = self.model.initial(first, self.soc0)
        self.t_s, self.u = first.t_s, self.model.inputs(first)
        self._correct(first)
        return self.estimate()

    def predict(self, dt_s: float, u: np.ndarray | None = None) -> None:
        """The time update over dt_s [s] with the inputs ``u`` held (default those of the last measurement)."""
        xn, A, B = self.model.F(self.x, self.u if u is None else u, dt_s)
        A, B = np.asarray(A), np.asarray(B)
        self.x = np.asarray(xn).ravel()
        self.P = A @ self.P @ A.T + self.model.process_noise(dt_s, B)

    def _correct(self, y: Measurement) -> None:
        """The measurement update, iterated (Gauss–Newton on the OCV curve, :data:`ITERATIONS`): the OCV's slope
        changes tenfold between 70 and 80 % SOC, and one linearisation far from the truth collapses P_S."""
        u = self.model.inputs(y)
        xp, Pp, R, ym = self.x.copy(), self.P, self.model.R, self.model.outputs(y)
        xi = xp.copy()
        for _ in range(ITERATIONS):
            yh, C = self.model.H(xi, u)
            C = np.asarray(C)
            K = np.linalg.solve(C @ Pp @ C.T + R, C @ Pp).T
            xn = xp + K @ (ym - np.asarray(yh).ravel() - C @ (xp - xi))
            xn[0] = min(max(xn[0], 0.0), 1.0)
            done = abs(xn[0] - xi[0]) < 1e-6
            xi = xn
            if done:
                break
        IKC = np.eye(6) - K @ C
        self.x = xi
        self.P = IKC @ Pp @ IKC.T + K @ R @ K.T  # Joseph form: stays symmetric positive
        self.u = u

    def update(self, y: Measurement) -> Estimate:
        dt_s = y.t_s - self.t_s
        if dt_s > 0:  # the inputs over the interval: the mean of its two ends (trapezoidal coulomb counting)
            self.predict(dt_s, 0.5 * (self.u + self.model.inputs(y)))
        self.t_s = y.t_s
        self._correct(y)
        return self.estimate()

    def estimate(self) -> Estimate:
        """The current estimate, the gap and predecessor motion predicted over the radar's delay."""
        x, d = self.x.copy(), self.lead_delay_s
        if d > 0:
            x[3] += (x[4] - self.u[1]) * d + 0.5 * x[5] * d**2
            x[4] += x[5] * d
        return estimate_of(x, self.P)

    def describe(self) -> dict[str, Any]:
        return {"estimator": self.name, "soc0": self.soc0, "ocv_offset_V": self.model.ocv_offset_V,
                "states": "S, V1, V2, h, v_l, a_l", "measurements": "pack V, gap, predecessor speed",
                "inputs": "pack current, own speed"}

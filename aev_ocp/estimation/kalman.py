"""An extended Kalman filter on :class:`~aev_ocp.estimation.base.EstimationModel` (SOC, V1, V2 from pack voltage and
current; gap, predecessor speed and acceleration from the radar and the own speed)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..fastcall import BufferedCall
from ..params import EVParams
from .base import NX, STATE_NAMES, Estimate, EstimationModel, estimate_of
from .sensors import Measurement, Sensors


def bridge_delays(x: np.ndarray, a_cmd_mps2: float, lead_delay_s: float, speed_delay_s: float) -> np.ndarray:
    """The state x (at the measurements' time) predicted to now: the own speed over its delay with the applied
    acceleration, the gap and the predecessor's motion over the radar's delay (the battery's states move slowly and
    are left)."""
    x = np.array(x, float)
    d, ds = lead_delay_s, speed_delay_s
    if d > 0:
        x[3] += (x[4] - x[6]) * d + 0.5 * (x[5] - a_cmd_mps2) * d**2
        x[4] += x[5] * d
    if ds > 0:
        x[6] = max(x[6] + a_cmd_mps2 * ds, 0.0)
    return x


#: iterations of the measurement update (an iterated EKF; 1 = the plain EKF)
ITERATIONS = 3


class EKF:
    """Extended Kalman filter (SI). ``soc0``: the initial SOC guess (None: the OCV inverted at the first
    voltage); the inputs over an interval are the mean of the measurements at its ends; the estimate is the filtered
    state predicted over the sensors' delays (:func:`bridge_delays`)."""

    name = "ekf"

    def __init__(self, ev: EVParams, sensors: Sensors, soc0: float | None = None, ocv_offset_V: float = 0.0) -> None:
        self.model = EstimationModel(ev, sensors, ocv_offset_V)
        self.soc0 = soc0
        self.lead_delay_s = sensors.delay("gap")
        self.x = np.zeros(NX)
        self._P = np.eye(NX)  # the covariance, dense
        self.speed_delay_s = sensors.delay("speed")
        self.t_s = 0.0
        self.u = np.zeros(2)
        self._fn = self.model.ekf_step(ITERATIONS)  # the whole step: one CasADi call
        # ... on bound buffers (no DM conversion of its six arguments and two results per step); P⁺'s nonzeros go to
        # these places of the dense covariance (column-major)
        self._call: BufferedCall | None = None  # built on the first step
        rows, cols = self._fn.sparsity_out(1).get_triplet()
        self._p_places = np.asarray(cols, dtype=int) * NX + np.asarray(rows, dtype=int)

    def reset(self, first: Measurement) -> Estimate:
        """x0, P0 from the first measurement (:meth:`EstimationModel.initial`), then its update."""
        self.x, P0 = self.model.initial(first, self.soc0)
        self._P = np.array(P0, dtype=float).reshape(NX, NX)
        self.t_s, self.u = first.t_s, self.model.inputs(first)
        return self._step(first, 0.0)

    def _step(self, y: Measurement, dt_s: float) -> Estimate:
        u = self.model.inputs(y)
        b = self._call
        if b is None:
            b = self._call = BufferedCall(self._fn)
        values: tuple[Any, ...] = (self.x, self._P.ravel(order="F"), self.u, u, self.model.outputs(y), dt_s)
        for buf, value in zip(b.args, values):
            buf[:] = np.ravel(np.asarray(value, dtype=float))
        if b():
            P = np.zeros(NX * NX)
            P[self._p_places] = b.res[1]
            self.x, self._P = b.res[0].copy(), P.reshape(NX, NX, order="F")
        else:  # failed there: the call raises CasADi's own error (or, should it pass, gives its result)
            x, P_dm = self._fn(self.x, self._P, self.u, u, self.model.outputs(y), dt_s)
            self.x, self._P = np.asarray(x).ravel(), np.asarray(P_dm.full())
        self.u, self.t_s = u, y.t_s
        return self.estimate()

    @property
    def P(self) -> np.ndarray:
        """The filtered covariance (the order of :data:`~aev_ocp.estimation.base.STATE_NAMES`, SI²)."""
        return self._P.copy()

    def update(self, y: Measurement) -> Estimate:
        return self._step(y, max(y.t_s - self.t_s, 0.0))

    def estimate(self) -> Estimate:
        """The current estimate, predicted over the sensors' delays (:func:`bridge_delays`)."""
        return estimate_of(bridge_delays(self.x, self.u[1], self.lead_delay_s, self.speed_delay_s), self.P)

    def describe(self) -> dict[str, Any]:
        return {
            "estimator": self.name,
            "soc0": self.soc0,
            "ocv_offset_V": self.model.ocv_offset_V,
            "states": ", ".join(STATE_NAMES),
            "measurements": "pack V, gap, predecessor speed, own speed",
            "inputs": "pack current, applied acceleration",
        }

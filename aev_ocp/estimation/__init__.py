"""A closed loop as real as a car's: plant ≠ model (:mod:`.mismatch`), noisy, quantised, late measurements
(:mod:`.sensors`) and state estimation (:mod:`.kalman` EKF, :mod:`.mhe` MHE, the :class:`~.base.Estimator`
protocol for your own). :class:`aev_ocp.control.ClosedLoop` takes ``mismatch=``, ``sensors=`` and ``estimator=``."""

from .base import Estimate, EstimationModel, Estimator, soc_from_rest_voltage
from .kalman import EKF
from .mhe import MHE
from .mismatch import Mismatch
from .sensors import CHANNELS, Measurement, SensorModel, Sensors

__all__ = [
    "CHANNELS",
    "EKF",
    "MHE",
    "Estimate",
    "EstimationModel",
    "Estimator",
    "Measurement",
    "Mismatch",
    "SensorModel",
    "Sensors",
    "soc_from_rest_voltage",
]

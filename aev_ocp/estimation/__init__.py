"""A closed loop as real as a car's: plant ≠ model (:mod:`.mismatch`), noisy, quantised, late measurements
(:mod:`.sensors`) and state estimation (:mod:`.kalman` EKF, :mod:`.mhe` MHE, the :class:`~.base.Estimator`
protocol for your own). :class:`aev_ocp.control.ClosedLoop` takes ``mismatch=``, ``sensors=`` and ``estimator=``."""

from ..lazy import lazy_exports

#: name -> module that defines it (imported on first use: aev_ocp.lazy)
_EXPORTS = {
    "Estimate": "base",
    "EstimationModel": "base",
    "Estimator": "base",
    "soc_from_rest_voltage": "base",
    "EKF": "kalman",
    "MHE": "mhe",
    "Mismatch": "mismatch",
    "CHANNELS": "sensors",
    "Measurement": "sensors",
    "SensorModel": "sensors",
    "Sensors": "sensors",
}

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

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

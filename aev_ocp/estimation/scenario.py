"""The ``[mismatch]`` and ``[sensors]`` tables of scenario files (and so study axes over their keys).

::

    [mismatch]              # plant ≠ model (aev_ocp.estimation.mismatch.Mismatch): relative errors of the model
    mass_rel = 0.1          # ±10 % (distribution "uniform": drawn per vehicle; "fixed": exactly +10 %)
    drag_rel = 0.2
    R0_rel = 0.2
    distribution = "uniform"
    seed = 1

    [sensors]               # what a car measures (aev_ocp.estimation.sensors.Sensors; defaults: production sensors)
    noise_scale = 1.0       # every noise standard deviation times this (0: noiseless)
    delay_s = 0.1           # every channel's delay [s] (absent: each channel's own *_delay_s)
    estimator = "ekf"       # "ekf", "mhe" or "none" (then battery_states_observed must be true)
    soc0_error = 0.1        # the estimator starts from the cell's soc0 − this (absent: the OCV inverted)
    gap_noise_m = 0.2       # ... and any field of Sensors

Any law of the scenario then runs as a sampled law on the measurements at the MPC's step (a continuous law cannot
see sampled noise), and the MPC on its vehicle's model and the estimator's estimates.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ..params import field_checks
from .kalman import EKF
from .mhe import MHE
from .mismatch import Mismatch
from .sensors import Sensors

ESTIMATOR_NAMES = ("ekf", "mhe", "none")


@dataclass(frozen=True)
class SensorsConfig:
    """The validated [sensors] table: the Sensors, the estimator's name and its initial SOC error [-]."""

    sensors: Sensors
    estimator: str = "ekf"
    soc0_error: float | None = None


def _dataclass_from(r: Any, cls: type) -> Any:
    from ..scenarios.tables import ScenarioError

    checks = field_checks(cls)
    d = {f.name: r.declared(f.name, checks[f.name]) for f in fields(cls) if r.has(f.name)}
    try:
        return cls(**d)
    except ValueError as exc:
        raise ScenarioError(f"{r.file}: {r.path}: {exc}") from None


def validate_mismatch_table(r: Any) -> Mismatch:
    """Validator of ``[mismatch]`` (a TableReader): the fields of Mismatch."""
    m = _dataclass_from(r, Mismatch)
    r.finish(allowed_hint=[f.name for f in fields(Mismatch)])
    return m


def validate_sensors_table(r: Any) -> SensorsConfig:
    """Validator of ``[sensors]`` (a TableReader): the fields of Sensors, noise_scale, delay_s, estimator,
    soc0_error."""
    s = _dataclass_from(r, Sensors)
    scale = r.number("noise_scale", 1.0, ge=0)
    delay = r.number("delay_s", None, ge=0) if r.has("delay_s") else None
    est = r.string("estimator", "ekf", choices=list(ESTIMATOR_NAMES))
    soc_err = r.number("soc0_error", None, ge=-1, le=1) if r.has("soc0_error") else None
    r.finish(allowed_hint=[f.name for f in fields(Sensors)] + ["noise_scale", "delay_s", "estimator", "soc0_error"])
    s = s.scaled(scale, delay)
    if est == "none" and not s.battery_states_observed and s.degraded:
        raise r.error(
            "estimator",
            est,
            "needs sensors.battery_states_observed = true (V1, V2, SOC are not measured "
            'otherwise): choose "ekf" or "mhe"',
        )
    return SensorsConfig(s, est, soc_err)


def realism_kwargs(scenario: Any) -> dict[str, Any]:
    """ClosedLoop keyword arguments (mismatch, sensors, estimator) of a scenario's [mismatch] and [sensors] ({}
    without either)."""
    out: dict[str, Any] = {}
    mm = scenario.extra.get("mismatch")
    if mm is not None:
        out["mismatch"] = mm
    cfg = scenario.extra.get("sensors")
    if cfg is not None:
        out["sensors"] = cfg.sensors
        if cfg.estimator == "none":
            out["estimator"] = None
        else:
            cls = EKF if cfg.estimator == "ekf" else MHE
            soc0 = None if cfg.soc0_error is None else min(max(scenario.ev.cell.soc0 - cfg.soc0_error, 0.0), 1.0)
            out["estimator"] = lambda ev, s, off, i: cls(ev, s, soc0=soc0, ocv_offset_V=off)
    return out


def measurements_degraded(scenario: Any) -> bool:
    """True when the scenario's measurements are not the exact, instantaneous states (then its laws run sampled on
    them; a model mismatch alone leaves a law as it is: a law has no model)."""
    cfg = scenario.extra.get("sensors")
    return cfg is not None and bool(cfg.sensors.degraded)


def register() -> None:
    """Register the [mismatch] and [sensors] tables with the scenario loader."""
    from ..scenarios.sections import register_section

    register_section("mismatch", validate_mismatch_table)
    register_section("sensors", validate_sensors_table)


register()  # the scenario loader imports this module when a file has one of these tables

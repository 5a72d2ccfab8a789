"""Battery life per controller: a run's SOC and temperature, repeated as a stated daily schedule over years,
through NREL's BLAST-Lite (optional, import name ``blast``; install it as :data:`INSTALL_HINT` says).

The daily schedule (:class:`DailySchedule`, our statement, SI): the run's drive (its SOC and pack temperature
history, resampled at ``sample_s``) is driven ``len(trip_start_h)`` times a day starting at the stated hours;
between drives the pack rests at the ambient temperature and the SOC it ended with; at ``charge_start_h`` it
charges back to the day's starting SOC at a constant ``charge_C`` (C-rate) at the ambient temperature, then rests.
BLAST-Lite repeats that day until ``years`` have passed. Capacity q and resistance r are relative to new (1.0).

Which BLAST-Lite model stands for which cell (:data:`BLAST_MODELS`, by the cell file's chemistry):

* LFP → ``Lfp_Gr_SonyMurata3Ah_Battery``: LFP–graphite like the A123 ANR26650, and the same 26650
  high-power cylindrical format (Sony-Murata US26650FTC1, TUM data, Naumann et al.);
* NMC → ``Nmc811_GrSi_LGMJ1_4Ah_Battery``: the only high-energy NMC 18650 model (LG MJ1);
* NCA → ``Nca_Gr_Panasonic3Ah_Battery``: Panasonic NCR18650B, NCA–graphite 18650.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .params import ParameterError, spec, validate_fields

BLAST_MODELS = {
    "LFP": "Lfp_Gr_SonyMurata3Ah_Battery",
    "NMC": "Nmc811_GrSi_LGMJ1_4Ah_Battery",
    "NCA": "Nca_Gr_Panasonic3Ah_Battery",
}
#: The ``life`` extra (pyproject.toml) is blast-lite >= 1.1.1, which pins numpy < 2: pip then installs numpy 1.26
#: (Python 3.11 wheels; the toolkit needs numpy >= 1.24 and runs on both). To keep numpy 2 instead, install its
#: dependencies and then blast-lite without them (``pip install pandas h5pyd geopy && pip install --no-deps
#: blast-lite``): it runs on numpy 2 too (see _numpy_compat).
INSTALL_HINT = "battery life needs NREL's BLAST-Lite: pip install '.[life]' in the aev_ocp checkout"
REPORT_YEARS = (1.0, 5.0, 10.0)
END_OF_LIFE = 0.8  # 80 % of the new capacity: the usual EV end-of-life criterion (e.g. USABC)


@dataclass(frozen=True)
class DailySchedule:
    """A stated day of use, SI. trip_start_h: start hours of the drives [h]; charge_start_h [h]: plug in after the
    last drive; charge_C: constant charging C-rate [1/h]; sample_s: resampling of the drive [s]."""

    trip_start_h: tuple[float, ...] = (8.0, 17.5)  # two commutes a day (our statement of a typical day)
    charge_start_h: float = spec(22.0, ge=0, lt=24)  # overnight charging (our statement)
    charge_C: float = spec(0.2, gt=0)  # home AC charging of a ~56 kWh pack at ~11 kW (our statement)
    sample_s: float = spec(1.0, gt=0)  # 1 Hz: SOC and temperature change slowly (BLAST-Lite's own examples use ≥ 1 s)

    def __post_init__(self) -> None:
        validate_fields(self)
        hs = list(self.trip_start_h)
        if not hs or any(not (0 <= h < 24) for h in hs) or any(b <= a for a, b in zip(hs, hs[1:])):
            raise ParameterError(f"DailySchedule.trip_start_h = {hs!r} is not allowed: increasing hours in [0, 24)")
        if self.charge_start_h <= hs[-1]:
            raise ParameterError(
                f"DailySchedule.charge_start_h = {self.charge_start_h!r} is not allowed: must be "
                f"after the last trip ({hs[-1]:g} h)"
            )


def daily_profile(
    t_s: Sequence[float] | np.ndarray,
    soc: Sequence[float] | np.ndarray,
    T_K: Sequence[float] | np.ndarray,
    ambient_K: float,
    schedule: DailySchedule | None = None,
) -> dict[str, np.ndarray]:
    """One day (86 400 s) of SOC [-] and temperature [°C] under ``schedule`` from one drive (t_s [s], soc, T_K
    [K]); the BLAST-Lite input: {'Time_s', 'SOC', 'Temperature_C'}. ParameterError when the drives do not fit."""
    sch = schedule or DailySchedule()
    t, s, T = (np.asarray(x, float).ravel() for x in (t_s, soc, T_K))
    if not (t.size == s.size == T.size) or t.size < 2 or np.any(np.diff(t) <= 0):
        raise ParameterError("daily_profile: t_s, soc and T_K need the same length (>= 2) and increasing t_s")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(T))):
        raise ParameterError("daily_profile: the run has no finite SOC or temperature history (battery off?)")
    dur = t[-1] - t[0]
    grid = np.arange(0.0, dur, sch.sample_s)
    grid = np.append(grid, dur)
    ds, dT = np.interp(grid, t - t[0], s), np.interp(grid, t - t[0], T)
    drop = float(ds[0] - ds[-1])  # SOC used per drive
    times, socs, temps = [0.0], [float(ds[0])], [ambient_K]
    level = float(ds[0])
    for k, h in enumerate(sch.trip_start_h):
        start = h * 3600.0
        nxt = sch.trip_start_h[k + 1] * 3600.0 if k + 1 < len(sch.trip_start_h) else sch.charge_start_h * 3600.0
        if start + dur >= nxt or start <= times[-1]:
            raise ParameterError(f"daily_profile: a drive of {dur:g} s starting at {h:g} h does not fit the schedule")
        times += list(start + grid)
        socs += list(ds - ds[0] + level)
        temps += list(dT)
        level -= drop
        times.append(start + dur + sch.sample_s)  # back to the ambient after the drive (lumped: no cool-down model)
        socs.append(level)
        temps.append(ambient_K)
    t_charge = (ds[0] - level) / sch.charge_C * 3600.0  # constant current: SOC rises at charge_C per hour
    c0 = sch.charge_start_h * 3600.0
    if c0 + t_charge >= 86400.0:
        raise ParameterError(
            f"daily_profile: charging {ds[0] - level:.3g} of SOC at {sch.charge_C:g}C does not finish before midnight"
        )
    times += [c0, c0 + t_charge, 86400.0]
    socs += [level, float(ds[0]), float(ds[0])]
    temps += [ambient_K] * 3
    if np.any(np.array(socs) < 0):
        raise ParameterError("daily_profile: the day's drives empty the battery (SOC < 0)")
    return {"Time_s": np.array(times), "SOC": np.array(socs), "Temperature_C": np.array(temps) - 273.15}


def blast_available() -> bool:
    """Whether BLAST-Lite (import name ``blast``) is installed."""
    try:
        with warnings.catch_warnings():  # its h5pyd dependency warns about distutils on import
            warnings.simplefilter("ignore", DeprecationWarning)
            import blast  # noqa: F401
    except ImportError:
        return False
    return True


class _NumpyWithTrapz:
    """numpy as BLAST-Lite 1.1 expects it: ``np.trapz`` (removed in numpy 2.4) is ``np.trapezoid``, the same
    function under its new name; everything else is numpy itself."""

    @staticmethod
    def trapz(*args: Any, **kwargs: Any) -> Any:
        """np.trapezoid (looked up when called: numpy < 2, which has no trapezoid, never builds this shim)."""
        return np.trapezoid(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(np, name)


def _numpy_compat() -> None:
    """Give BLAST-Lite's modules (which pin numpy < 2 and call np.trapz) a numpy with trapz, without touching
    numpy itself."""
    if hasattr(np, "trapz"):
        return
    import sys

    shim = _NumpyWithTrapz()
    for name, mod in list(sys.modules.items()):
        if (name == "blast" or name.startswith("blast.")) and getattr(mod, "np", None) is np:
            mod.np = shim  # type: ignore[attr-defined]


def blast_model(chemistry: str) -> Any:
    """A fresh BLAST-Lite model for a cell chemistry ('LFP', 'NMC', 'NCA'); ParameterError naming how to install
    BLAST-Lite when it is missing."""
    if chemistry not in BLAST_MODELS:
        raise ParameterError(f"battery life: chemistry = {chemistry!r} is not allowed: one of {tuple(BLAST_MODELS)}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            from blast import models
    except ImportError:
        raise ParameterError(INSTALL_HINT) from None
    _numpy_compat()
    return getattr(models, BLAST_MODELS[chemistry])()


def _at(years: np.ndarray, y: np.ndarray, when: float) -> float:
    return float(np.interp(when, years, y)) if years[-1] >= when - 1e-9 else math.nan


def life_from_model(model: Any, years: float) -> dict[str, Any]:
    """Capacity and resistance after 1/5/10 years and years to 80 % of a BLAST-Lite model that has run."""
    yrs = np.asarray(model.stressors["t_days"], float) / 365.0
    q = np.asarray(model.outputs["q"], float)
    r = np.asarray(model.outputs["r"], float) if "r" in model.outputs else None
    out: dict[str, Any] = {"model": type(model).__name__, "years_simulated": float(yrs[-1])}
    for y in REPORT_YEARS:
        out[f"capacity_{y:g}y"] = _at(yrs, q, y)
        out[f"resistance_{y:g}y"] = _at(yrs, r, y) if r is not None else math.nan
    below = np.where(q < END_OF_LIFE)[0]
    if below.size:
        k = int(below[0])
        out["years_to_80pct"] = float(np.interp(END_OF_LIFE, [q[k], q[k - 1]], [yrs[k], yrs[k - 1]])) if k else 0.0
    else:
        out["years_to_80pct"] = math.inf  # not within the simulated years
    return out


def battery_life(profile: dict[str, np.ndarray], chemistry: str, years: float = 10.0) -> dict[str, Any]:
    """BLAST-Lite on one day's profile (:func:`daily_profile`) repeated for ``years``: capacity_{1,5,10}y and
    resistance_{1,5,10}y (relative to new), years_to_80pct (inf: not reached), the model's name."""
    if not (isinstance(years, (int, float)) and math.isfinite(years) and years > 0):
        raise ParameterError(f"battery life: years = {years!r} is not allowed: a finite number > 0")
    model = blast_model(chemistry)
    model.simulate_battery_life(profile, threshold_time=float(years))
    return life_from_model(model, years)


def life_of_run(
    result: Any, vehicle: int, chemistry: str, schedule: DailySchedule | None = None, years: float = 10.0
) -> dict[str, Any]:
    """Battery life of follower ``vehicle`` (0-based) of a SimulationResult with the thermal model on (its pack
    temperature; without it the pack is taken at the ambient of ``result.ev.thermal``)."""
    ev = result.ev
    t_s = np.asarray(ev.units.time_to_si(result.t), float)
    T = (
        result.temperature_K[:, vehicle]
        if result.temperature_K is not None
        else np.full(t_s.size, ev.thermal.ambient_K)
    )
    prof = daily_profile(t_s, result.S[:, vehicle], T, ev.thermal.ambient_K, schedule)
    return battery_life(prof, chemistry, years)

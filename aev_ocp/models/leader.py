"""Leader profiles (PROBLEM.md §2): the lead vehicle's speed and position as functions of time.

All quantities are in model units. ``speed(t)`` and ``accel(t)`` accept floats or CasADi
expressions; ``position(t)`` and ``speed_np``/``position_np`` are numeric. ``breakpoints`` lists
the times where the acceleration jumps, so an integrator can split its interval there exactly.
"""

from __future__ import annotations

import csv
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from typing import Any

import casadi as ca
import numpy as np

from ..params import ParameterError, Units

CYCLES = ("udds", "hwfet", "us06")


class LeaderProfile(ABC):
    """A lead vehicle's motion: speed(t), accel(t), position(t) in model units."""

    name: str = "leader"

    @property
    def breakpoints(self) -> tuple[float, ...]:
        """Times where accel(t) is discontinuous [model time]."""
        return ()

    @abstractmethod
    def speed(self, t: Any) -> Any:
        """Leader speed at t [model speed]; t may be a CasADi expression."""

    @abstractmethod
    def accel(self, t: Any) -> Any:
        """Leader acceleration at t [model acceleration]."""

    @abstractmethod
    def position(self, t: np.ndarray | float) -> np.ndarray:
        """Leader position at t relative to x_l(0) = 0 [model length], numeric."""

    @cached_property
    def speed_function(self) -> ca.Function:
        """speed(t) as a CasADi Function (built once)."""
        t = ca.SX.sym("t")
        return ca.Function(f"{self.name}_speed", [t], [self.speed(t)], ["t"], ["v_l"])

    @cached_property
    def _speed_maps(self) -> dict[int, ca.Function]:
        return {}

    def speed_np(self, t: np.ndarray | float) -> np.ndarray:
        """Numeric leader speed at the times t [model speed] (the mapped Function is built once per size)."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        f = self._speed_maps.get(tt.size)
        if f is None:
            f = self._speed_maps.setdefault(tt.size, self.speed_function.map(tt.size))
        return np.asarray(f(tt.reshape(1, -1))).ravel()

    def max_speed(self, t_end: float, n: int = 20001) -> float:
        """Maximum speed over [0, t_end] on a fine grid [model speed]."""
        return float(np.max(self.speed_np(np.linspace(0.0, t_end, n))))

    def describe(self) -> dict[str, Any]:
        """Name and settings, for reports."""
        return {"profile": self.name}


@dataclass(frozen=True)
class ConstantSpeed(LeaderProfile):
    """Leader at constant speed v (model units)."""

    v: float
    name = "constant"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.v) and self.v >= 0):
            raise ParameterError(f"ConstantSpeed.v = {self.v!r} is not allowed: must be a finite number >= 0")

    def speed(self, t: Any) -> Any:
        return self.v + 0.0 * t

    def accel(self, t: Any) -> Any:
        return 0.0 * t

    def position(self, t: np.ndarray | float) -> np.ndarray:
        return self.v * np.asarray(t, dtype=float)

    def describe(self) -> dict[str, Any]:
        return {"profile": self.name, "v": self.v}


@dataclass(frozen=True)
class PaperLeader(LeaderProfile):
    """The paper's fluctuating leader (paper eq. acc5):

    a_l(t) = −(amplitude)(sin(0.5πt) + cos(3.2πt)) on [0, t_end], 0 after; v_l(0) = v0.
    Speed and position are integrated in closed form.
    """

    v0: float = 1.7  # paper §5
    amplitude: float = 1.65 / 1.37  # paper eq. acc5
    t_end: float = 20.0  # paper eq. acc5
    w1: float = 0.5 * math.pi  # paper eq. acc5
    w2: float = 3.2 * math.pi  # paper eq. acc5
    name = "paper"

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return (self.t_end,)

    def _v_active(self, t: Any) -> Any:
        c = self.amplitude
        return self.v0 - c * ((1 - ca.cos(self.w1 * t)) / self.w1 + ca.sin(self.w2 * t) / self.w2)

    def _x_active(self, t: np.ndarray) -> np.ndarray:
        c = self.amplitude
        return (self.v0 * t - c * ((t - np.sin(self.w1 * t) / self.w1) / self.w1
                                   + (1 - np.cos(self.w2 * t)) / self.w2**2))

    def speed(self, t: Any) -> Any:
        return ca.if_else(t <= self.t_end, self._v_active(t), self._v_active(self.t_end))

    def accel(self, t: Any) -> Any:
        a = -self.amplitude * (ca.sin(self.w1 * t) + ca.cos(self.w2 * t))
        return ca.if_else(t <= self.t_end, a, 0.0)

    def position(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        te = self.t_end
        v_end = float(self._v_active(te))
        return np.where(t <= te, self._x_active(np.minimum(t, te)),
                        self._x_active(np.asarray(te)) + v_end * (t - te))

    def describe(self) -> dict[str, Any]:
        return {"profile": self.name, "v0": self.v0, "amplitude": self.amplitude, "t_end": self.t_end}


@dataclass(frozen=True)
class SpeedTrace(LeaderProfile):
    """A sampled speed trace, linearly interpolated; held at its last value after its end.

    It declares no breakpoints: its acceleration jumps at every knot, but the followers only see its
    (continuous) speed, so the integrators' step control handles the kinks instead of splitting there.

    times, speeds: model time and model speed (use :meth:`from_si` or :func:`drive_cycle` for SI data).
    """

    times: tuple[float, ...]
    speeds: tuple[float, ...]
    label: str = "trace"
    name = "trace"

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=float)
        v = np.asarray(self.speeds, dtype=float)
        if t.ndim != 1 or t.size < 2 or t.size != v.size:
            raise ParameterError("SpeedTrace: times and speeds must be 1-D of equal length >= 2")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise ParameterError("SpeedTrace: times and speeds must be finite")
        if t[0] != 0.0 or np.any(np.diff(t) <= 0):
            raise ParameterError("SpeedTrace.times must start at 0 and increase strictly")
        if np.any(v < 0):
            raise ParameterError(f"SpeedTrace.speeds has a negative value ({v.min():g}): must be >= 0")

    @classmethod
    def from_si(cls, times_s: np.ndarray, speeds_mps: np.ndarray, units: Units, label: str = "trace") -> "SpeedTrace":
        """Build from SI arrays [s], [m/s], converted with ``units``."""
        return cls(tuple(float(x) for x in units.time_from_si(np.asarray(times_s, float))),
                   tuple(float(x) for x in units.speed_from_si(np.asarray(speeds_mps, float))), label)

    @cached_property
    def _interp(self) -> ca.Function:
        t = np.asarray(self.times)
        v = np.asarray(self.speeds)
        # append a far knot so the speed is held (not extrapolated) after the trace ends
        return ca.interpolant(f"{self.label}_v", "linear", [np.append(t, t[-1] + 1e6)], np.append(v, v[-1]))

    @cached_property
    def _slopes(self) -> np.ndarray:
        return np.diff(self.speeds) / np.diff(self.times)

    @cached_property
    def _cumulative(self) -> np.ndarray:
        t, v = np.asarray(self.times), np.asarray(self.speeds)
        return np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])

    def speed(self, t: Any) -> Any:
        return self._interp(ca.fmax(t, 0.0))

    @cached_property
    def _accel_fn(self) -> ca.Function:
        tt = ca.SX.sym("t")
        return ca.Function(f"{self.label}_a", [tt], [ca.jacobian(self._interp(tt), tt)])

    def accel(self, t: Any) -> Any:
        return self._accel_fn(ca.fmax(t, 0.0))

    def position(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        times, v = np.asarray(self.times), np.asarray(self.speeds)
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 1)
        tau = t - times[k]
        slope = np.where(k < times.size - 1, np.append(self._slopes, 0.0)[k], 0.0)
        return self._cumulative[k] + v[k] * tau + 0.5 * slope * tau**2

    def describe(self) -> dict[str, Any]:
        return {"profile": self.name, "label": self.label, "duration": self.times[-1],
                "max_speed": max(self.speeds)}


def load_cycle_si(name: str) -> tuple[np.ndarray, np.ndarray]:
    """EPA cycle shipped with the package (see aev_ocp/data/README.md): times [s], speeds [m/s]."""
    key = name.lower()
    if key not in CYCLES:
        raise ParameterError(f"unknown drive cycle {name!r}: known cycles are {list(CYCLES)}")
    path = resources.files("aev_ocp") / "data" / "cycles" / f"{key}.csv"
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    return (np.array([float(r["time_s"]) for r in rows]), np.array([float(r["speed_mps"]) for r in rows]))


def drive_cycle(name: str, units: Units) -> SpeedTrace:
    """An EPA drive cycle (udds, hwfet, us06) as a SpeedTrace in ``units``."""
    t, v = load_cycle_si(name)
    return SpeedTrace.from_si(t, v, units, label=name.lower())


"""Leader profiles (model guide §2): the lead vehicle's speed and position as functions of time.

All quantities are in model units. ``speed(t)`` and ``accel(t)`` accept floats or CasADi
expressions; ``position(t)`` and ``speed_np``/``position_np`` are numeric. ``breakpoints`` lists
the times where the acceleration jumps, so an integrator can split its interval there exactly.
"""

from __future__ import annotations

import csv
import re
import stat
import math
from abc import ABC, abstractmethod
from array import array
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import casadi as ca
import numpy as np

from ..fastcall import column_call
from ..params import ParameterError, Units, exact_key, remember

CYCLES = ("udds", "hwfet", "us06")


#: :meth:`LeaderProfile.max_speed` of this process, by (the leader's exact key, t_end, n); the oldest forgotten first
_MAX_SPEEDS: dict[tuple[Any, ...], float] = {}
MAX_SPEEDS_KEPT = 256


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

    def speed_np(self, t: np.ndarray | float) -> np.ndarray:
        """Numeric leader speed at the times t [model speed] (on bound buffers: :func:`aev_ocp.fastcall.column_call`)."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        return column_call(self.speed_function)(tt.ravel())[0].ravel()

    def max_speed(self, t_end: float, n: int = 20001) -> float:
        """Maximum speed over [0, t_end] on a fine grid [model speed]; computed once per process for a leader of the
        same type and fields to the bit (:data:`_MAX_SPEEDS`: every load of a scenario checks its leader's)."""
        key = exact_key(self)
        if key is None:
            return self._max_speed(t_end, n)
        key = (key, float(t_end).hex(), int(n))
        if key not in _MAX_SPEEDS:
            return float(remember(_MAX_SPEEDS, key, self._max_speed(t_end, n), MAX_SPEEDS_KEPT))
        return _MAX_SPEEDS[key]

    def _max_speed(self, t_end: float, n: int) -> float:
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
        return self.v0 * t - c * (
            (t - np.sin(self.w1 * t) / self.w1) / self.w1 + (1 - np.cos(self.w2 * t)) / self.w2**2
        )

    def speed(self, t: Any) -> Any:
        return ca.if_else(t <= self.t_end, self._v_active(t), self._v_active(self.t_end))

    def accel(self, t: Any) -> Any:
        a = -self.amplitude * (ca.sin(self.w1 * t) + ca.cos(self.w2 * t))
        return ca.if_else(t <= self.t_end, a, 0.0)

    def position(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        te = self.t_end
        v_end = float(self._v_active(te))
        return np.where(t <= te, self._x_active(np.minimum(t, te)), self._x_active(np.asarray(te)) + v_end * (t - te))

    def describe(self) -> dict[str, Any]:
        return {"profile": self.name, "v0": self.v0, "amplitude": self.amplitude, "t_end": self.t_end}


@dataclass(frozen=True)
class BrakingLeader(LeaderProfile):
    """A lead vehicle at constant speed v0 until t_brake, then braking at a constant deceleration ``decel`` (≤ 0)
    until it stops, then standing (model units: speed, acceleration, time). Euro NCAP's car-to-car rear braking
    tests and a braking cut-in vehicle are of this kind; :meth:`from_si` takes m/s, m/s², s."""

    v0: float
    decel: float
    t_brake: float = 0.0
    name = "braking"

    def __post_init__(self) -> None:
        for nm, ok in (("v0", self.v0 >= 0), ("decel", self.decel <= 0), ("t_brake", self.t_brake >= 0)):
            x = getattr(self, nm)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and ok):
                rule = {"v0": ">= 0", "decel": "<= 0", "t_brake": ">= 0"}[nm]
                raise ParameterError(f"BrakingLeader.{nm} = {x!r} is not allowed: must be a finite number {rule}")

    @classmethod
    def from_si(cls, v0_mps: float, decel_mps2: float, t_brake_s: float, units: Units) -> "BrakingLeader":
        """From SI values [m/s], [m/s²], [s], converted with ``units``."""
        return cls(
            float(units.speed_from_si(v0_mps)),
            float(units.accel_from_si(decel_mps2)),
            float(units.time_from_si(t_brake_s)),
        )

    @property
    def t_stop(self) -> float:
        """When the leader stands [model time] (inf if it never brakes)."""
        if self.v0 == 0:
            return 0.0
        return self.t_brake + self.v0 / -self.decel if self.decel < 0 else math.inf

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return tuple(b for b in (self.t_brake, self.t_stop) if 0 < b < math.inf and self.v0 > 0 and self.decel < 0)

    def speed(self, t: Any) -> Any:
        return ca.fmax(self.v0 + self.decel * ca.fmax(t - self.t_brake, 0.0), 0.0)

    def accel(self, t: Any) -> Any:
        if self.decel == 0 or self.v0 == 0:
            return 0.0 * t
        return ca.if_else(ca.logic_and(t > self.t_brake, t < self.t_stop), self.decel, 0.0)

    def position(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        s = np.clip(t - self.t_brake, 0.0, None)
        if self.decel < 0:
            s = np.minimum(s, self.v0 / -self.decel)
        return self.v0 * np.minimum(t, self.t_brake) + self.v0 * s + 0.5 * self.decel * s * s

    def describe(self) -> dict[str, Any]:
        return {"profile": self.name, "v0": self.v0, "decel": self.decel, "t_brake": self.t_brake}


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
    #: set when a recording was read only as far as a run of this horizon [model time] needs (the rows after it
    #: were not read): a longer run would see the speed held at the last sample read instead of the recording
    read_for_t_end: float | None = field(default=None, repr=False, compare=False)
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
        if not t[-1] + 1e6 > t[-1] or t[-1] > 1e15:  # the far knot that holds the last speed must stay a new knot
            raise ParameterError(
                f"SpeedTrace.times ends at {t[-1]:.6g} model time: too long to hold (more than 1e15 model time units; "
                "a trace given in SI is converted with the scenario's units: choose units of everyday size, e.g. "
                "units.length_m = 10)"
            )
        if np.any(v < 0):
            raise ParameterError(f"SpeedTrace.speeds has a negative value ({v.min():g}): must be >= 0")

    @classmethod
    def from_si(
        cls,
        times_s: np.ndarray | Sequence[float],
        speeds_mps: np.ndarray | Sequence[float],
        units: Units,
        label: str = "trace",
    ) -> "SpeedTrace":
        """Build from SI arrays [s], [m/s], converted with ``units``."""
        return cls(
            tuple(float(x) for x in units.time_from_si(np.asarray(times_s, float))),
            tuple(float(x) for x in units.speed_from_si(np.asarray(speeds_mps, float))),
            label,
        )

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

    def max_speed(self, t_end: float, n: int = 20001) -> float:
        """Maximum speed over [0, t_end] in model speed, exact: a piecewise-linear speed peaks at a knot or at an
        end of the interval (``n``, the grid of the general method, is not needed)."""
        times, v = np.asarray(self.times), np.asarray(self.speeds)
        t_end = max(float(t_end), 0.0)  # speed() holds its first value before 0
        at_end = float(np.interp(t_end, times, v))  # and its last after the last knot
        return float(max(np.max(v[times <= t_end]), at_end))

    def describe(self) -> dict[str, Any]:
        return {"profile": self.name, "label": self.label, "duration": self.times[-1], "max_speed": max(self.speeds)}


# unit -> SI factor of the columns a trace file may use
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "min": 60.0}
SPEED_UNITS = {"m/s": 1.0, "km/h": 1.0 / 3.6, "mph": 0.44704, "ft/s": 0.3048}  # mph, ft: exact (NIST SP 811)
LENGTH_UNITS = {"m": 1.0, "km": 1000.0, "ft": 0.3048, "mi": 1609.344}
MAX_GAP_S = 10.0  # default largest sampling gap of a trace [s] (our choice: longer is a hole in the data)


_HEADER_NAME = re.compile(r"[\w .()/%+\-\[\]]{1,64}")  # what a column name of a CSV header looks like


def _column(header: list[str], name: str, what: str, where: str) -> int:
    if name not in header:
        if len(header) <= 50 and all(_HEADER_NAME.fullmatch(h) for h in header):
            raise ParameterError(f"{where}: {what} = {name!r} is not a column of the file; its columns are {header}")
        # never echo a first line that is no CSV header (a file given by mistake may hold anything)
        raise ParameterError(
            f"{where}: {what} = {name!r} is not a column of the file, and its first line does not "
            "look like a CSV header (comma-separated column names): is it a CSV trace file?"
        )
    return header.index(name)


def read_trace_csv(
    source: Any,
    *,
    time_column: str = "time",
    speed_column: str | None = None,
    position_column: str | None = None,
    time_unit: str = "s",
    speed_unit: str = "m/s",
    position_unit: str = "m",
    max_gap_s: float | None = MAX_GAP_S,
    filter_column: str | None = None,
    filter_value: Any = None,
    label: str | None = None,
    t_max_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A recorded trajectory from a CSV file (header row, then one row per sample): times [s] from 0 and
    speeds [m/s], validated.

    source: a path (or a package resource); time_column in ``time_unit`` (TIME_UNITS); either
    speed_column in ``speed_unit`` (SPEED_UNITS) or position_column in ``position_unit`` (LENGTH_UNITS;
    the speed is then its derivative, numpy.gradient, second order, exact for quadratic motion);
    filter_column/filter_value keep only the rows of one vehicle (NGSIM/highD files hold many).
    Times are shifted to start at 0. ParameterError names the file, the row (as a spreadsheet counts
    them: the header is row 1) and the column for a missing or non-finite value, a time that does not
    increase, a negative speed or a sampling gap larger than ``max_gap_s`` [s] (None: no check).
    t_max_s [s]: read only up to the first sample at or past t_max_s after the first one (what a run of that
    length needs); later rows are neither read nor checked (None: the whole file)."""
    name = label or str(getattr(source, "name", source))
    if (speed_column is None) == (position_column is None):
        raise ParameterError(f"trace {name}: give exactly one of speed_column and position_column")
    for what, unit, table in (
        ("time_unit", time_unit, TIME_UNITS),
        ("speed_unit", speed_unit, SPEED_UNITS),
        ("position_unit", position_unit, LENGTH_UNITS),
    ):
        if unit not in table:
            raise ParameterError(f"trace {name}: {what} = {unit!r} is not allowed: must be one of {list(table)}")
    if not hasattr(source, "open"):  # a str or os.PathLike path (a resource Traversable has .open)
        source = Path(source)
    if isinstance(source, Path):  # a FIFO or a device would hang or never end: only regular files
        try:
            if not stat.S_ISREG(source.stat().st_mode):
                raise ParameterError(f"trace {name}: not a regular file")
        except OSError as exc:
            raise ParameterError(f"trace {name}: cannot read the file ({exc.strerror or exc})") from None
    try:
        with source.open(newline="", encoding="utf-8-sig") as fh:  # utf-8-sig: a BOM (spreadsheet export) is fine
            try:
                return _trace_rows(
                    csv.reader(fh),
                    name,
                    time_column,
                    speed_column,
                    position_column,
                    time_unit,
                    speed_unit,
                    position_unit,
                    max_gap_s,
                    filter_column,
                    filter_value,
                    t_max_s,
                )
            except csv.Error as exc:  # e.g. a field longer than csv.field_size_limit() (128 KiB)
                raise ParameterError(f"trace {name}: not a valid CSV file ({exc})") from None
    except OSError as exc:
        raise ParameterError(f"trace {name}: cannot read the file ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise ParameterError(f"trace {name}: not a text (UTF-8) CSV file") from None


def _trace_rows(
    reader: Any,
    name: str,
    time_column: str,
    speed_column: str | None,
    position_column: str | None,
    time_unit: str,
    speed_unit: str,
    position_unit: str,
    max_gap_s: float | None,
    filter_column: str | None,
    filter_value: Any,
    t_max_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`read_trace_csv` on a csv.reader, row by row (memory: two float64 per kept sample), stopping after
    the first sample at or past ``t_max_s`` [s] from the first one."""
    first = next(reader, None)
    if first is None:
        raise ParameterError(f"trace {name}: the file is empty (expected a header row, then one row per sample)")
    header = [h.strip() for h in first]
    col_t = _column(header, time_column, "time_column", f"trace {name}")
    value_col, value_what = (
        (speed_column, "speed_column") if speed_column is not None else (position_column, "position_column")
    )
    col_v = _column(header, str(value_col), value_what, f"trace {name}")
    col_f = _column(header, filter_column, "filter_column", f"trace {name}") if filter_column is not None else None
    t_list = array("d")
    v_list = array("d")
    line_no = array("q")
    for k, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue  # blank line
        if col_f is not None and not _matches(row[col_f] if col_f < len(row) else "", filter_value):
            continue
        vals: list[float] = []
        for ci, cname in ((col_t, time_column), (col_v, value_col)):
            text = row[ci].strip() if ci < len(row) else ""
            try:
                num = float(text)
            except ValueError:
                num = math.nan
            if not math.isfinite(num):
                raise ParameterError(f"trace {name}, row {k}, column {cname!r}: {text!r} is not a finite number")
            vals.append(num)
        t_list.append(vals[0])
        v_list.append(vals[1])
        line_no.append(k)
        if t_max_s is not None and (vals[0] - t_list[0]) * TIME_UNITS[time_unit] >= t_max_s and len(t_list) >= 2:
            break  # the run needs no later sample
    what = f" with {filter_column} = {filter_value!r}" if filter_column is not None else ""
    if len(t_list) < 2:
        raise ParameterError(f"trace {name}: needs at least 2 samples{what}, found {len(t_list)}")
    t = (np.asarray(t_list) - t_list[0]) * TIME_UNITS[time_unit]  # shift first: epoch times in ms keep their digits
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        j = int(bad[0])
        raise ParameterError(
            f"trace {name}, row {line_no[j + 1]}, column {time_column!r}: time {t_list[j + 1]!r} does "
            f"not increase (row {line_no[j]} has {t_list[j]!r}); times must increase strictly"
        )
    if max_gap_s is not None and dt.max() > max_gap_s:
        j = int(np.argmax(dt))
        raise ParameterError(
            f"trace {name}, rows {line_no[j]}-{line_no[j + 1]}: a sampling gap of {dt[j]:.6g} s, "
            f"more than max_gap_s = {max_gap_s:g} s (a hole in the data; raise max_gap_s to accept it)"
        )
    if speed_column is not None:
        v = np.asarray(v_list) * SPEED_UNITS[speed_unit]
        col = speed_column
    else:
        x = np.asarray(v_list) * LENGTH_UNITS[position_unit]
        back = np.flatnonzero(np.diff(x) < 0)
        if back.size:  # the data's own fault: the vehicle moved backwards
            j = int(back[0])
            raise ParameterError(
                f"trace {name}, row {line_no[j + 1]}, column {position_column!r}: the position "
                f"decreases ({v_list[j]!r} -> {v_list[j + 1]!r}); a leader only drives forward"
            )
        v = np.gradient(x, t, edge_order=2) if t.size > 2 else np.full(2, (x[1] - x[0]) / dt[0])
        # non-decreasing positions: a negative derivative is the second-order formula overshooting where the
        # vehicle starts or stops (e.g. at rest, then accelerating), not a reverse: it is clipped to 0
        v = np.maximum(v, 0.0)
        col = f"{position_column} (speed = d/dt)"
    neg = np.flatnonzero(v < 0)
    if neg.size:
        j = int(neg[0])
        raise ParameterError(
            f"trace {name}, row {line_no[j]}, column {col!r}: speed {v[j]:.6g} m/s is negative; "
            "a leader only drives forward"
        )
    return t, v


def _matches(text: str, value: Any) -> bool:
    """Whether a CSV cell equals ``value`` (numbers compared as numbers: '12.0' matches 12)."""
    text = text.strip()
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            return float(text) == float(value)
        except ValueError:
            return False
    return text == str(value)


def load_cycle_si(name: str) -> tuple[np.ndarray, np.ndarray]:
    """EPA cycle shipped with the package (see aev_ocp/data/README.md): times [s], speeds [m/s] (new arrays on
    every call; the file is read and checked once per process)."""
    key = name.lower()
    if key not in CYCLES:
        raise ParameterError(f"unknown drive cycle {name!r}: known cycles are {list(CYCLES)}")
    t, v = _shipped_cycle(key)
    return t.copy(), v.copy()


@lru_cache(maxsize=None)
def _shipped_cycle(key: str) -> tuple[np.ndarray, np.ndarray]:
    """The shipped cycle ``key``'s arrays, read once (package data does not change while a process runs; every
    scenario of a drive cycle loads it, 6 ms a read)."""
    path = resources.files("aev_ocp") / "data" / "cycles" / f"{key}.csv"
    return read_trace_csv(path, time_column="time_s", speed_column="speed_mps", max_gap_s=None, label=f"{key}.csv")


def trace_leader(times_s: np.ndarray, speeds_mps: np.ndarray, units: Units, label: str) -> SpeedTrace:
    """A recorded or drive-cycle speed trace (SI) as the leader in ``units``: the one resampling of every
    trace (linear interpolation between samples, held after the end; :class:`SpeedTrace`)."""
    return SpeedTrace.from_si(times_s, speeds_mps, units, label=label)


def drive_cycle(name: str, units: Units) -> SpeedTrace:
    """An EPA drive cycle (udds, hwfet, us06) as a SpeedTrace in ``units``."""
    t, v = load_cycle_si(name)
    return trace_leader(t, v, units, name.lower())


def csv_trace(path: Any, units: Units, label: str | None = None, **columns: Any) -> SpeedTrace:
    """A leader that follows a recorded trajectory in a CSV file (see :func:`read_trace_csv` for
    ``columns``: time_column, speed_column or position_column, units, max_gap_s, filter), in ``units``."""
    t, v = read_trace_csv(path, label=label, **columns)
    return trace_leader(t, v, units, label or "trace")

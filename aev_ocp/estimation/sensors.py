"""What a car measures, and when: seeded noise, quantisation and a delay per channel, and a sample period.

Channels (SI, pack level): ``gap`` [m] and ``lead_speed`` [m/s] (radar), ``speed`` [m/s] (own speed from the
wheel-speed sensors), ``voltage`` [V] and ``current`` [A] (the pack's terminal voltage and current, BMS). The
battery's internal states V1, V2 and SOC are not measured unless ``battery_states_observed`` is set.

A measurement at controller time t of a channel with delay d and sample period T_s is the true value at the
latest sensor sample time t_m = ⌊(t − d)/T_s⌋·T_s (t_m = t − d when T_s = 0: a sample every controller step),
plus Gaussian noise of the channel's standard deviation, rounded to the channel's quantum. True values between
the closed loop's nodes are interpolated linearly (exact when the delay is a multiple of the controller step).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..params import ParameterError, spec, validate_fields

#: The channels, in this order everywhere (SI units in the field names below).
CHANNELS = ("gap", "speed", "lead_speed", "voltage", "current")
_UNIT = {"gap": "m", "speed": "mps", "lead_speed": "mps", "voltage": "V", "current": "A"}


@dataclass(frozen=True)
class Sensors:
    """Noise standard deviation, quantum (0: none) and delay of each channel, SI units; defaults: production
    sensors (sources beside each value). ``sample_period_s`` = 0 samples every controller step."""

    # radar gap: Continental ARS 408-21 datasheet, distance accuracy ±0.40 m far range (taken as 2σ) and the
    # 0.2 m resolution of its CAN object list
    gap_noise_m: float = spec(0.2, ge=0)
    gap_quantum_m: float = spec(0.2, ge=0)
    gap_delay_s: float = spec(0.1, ge=0)  # radar cycle ~72 ms (ARS 408-21) plus CAN transport: ~0.1 s
    # own speed from the ABS wheel-speed sensors: ~0.1 km/h repeatability of active wheel-speed sensors
    # (Bosch DF11 / Infineon TLE5041 class) plus tyre-radius slip noise -> 0.05 m/s; CAN resolution 0.01 m/s
    speed_noise_mps: float = spec(0.05, ge=0)
    speed_quantum_mps: float = spec(0.01, ge=0)
    speed_delay_s: float = spec(0.1, ge=0)  # CAN cycle of the ESC speed signal (10-20 ms) plus filtering
    # predecessor speed = own speed + radar range rate: ARS 408-21 velocity accuracy 0.1 km/h, resolution
    # 0.25 m/s in its CAN object list; with the own-speed noise above -> 0.1 m/s
    lead_speed_noise_mps: float = spec(0.1, ge=0)
    lead_speed_quantum_mps: float = spec(0.25, ge=0)
    lead_speed_delay_s: float = spec(0.1, ge=0)  # as the gap
    # pack voltage summed by the BMS from the cell voltages: Analog Devices LTC6811 total measurement error
    # ±1.2 mV per cell (taken as 1σ, independent over 106 cells in series: 1.2 mV·√106 = 12 mV, rounded up to
    # 20 mV); resolution 100 µV per cell (0.01 V for the pack). A common offset of every cell is not noise: it is
    # the OCV offset of aev_ocp.estimation.mismatch.Mismatch
    voltage_noise_V: float = spec(0.02, ge=0)
    voltage_quantum_V: float = spec(0.01, ge=0)
    voltage_delay_s: float = spec(0.1, ge=0)  # BMS cycle 10-100 ms plus CAN transport
    # pack current: Isabellenhütte IVT-S shunt sensor, ±0.1 % of reading plus offset; noise of a few tenths of
    # an ampere at traction currents of tens to hundreds of amperes -> 0.3 A; resolution 1 mA (0.01 A used)
    current_noise_A: float = spec(0.3, ge=0)
    current_quantum_A: float = spec(0.01, ge=0)
    current_delay_s: float = spec(0.1, ge=0)  # as the voltage
    sample_period_s: float = spec(0.0, ge=0)  # 0: a sample at every controller step
    battery_states_observed: bool = spec(False, kind="bool")  # True: V1, V2, SOC read exactly (no car can)
    seed: int = spec(0, kind="integer", ge=0)

    def __post_init__(self) -> None:
        validate_fields(self)

    @staticmethod
    def ideal() -> "Sensors":
        """Exact, instantaneous measurements of every state (the closed loop without sensors)."""
        zero = {
            f"{c}_{k}_{_UNIT[c]}" if k != "delay" else f"{c}_delay_s": 0.0
            for c in CHANNELS
            for k in ("noise", "quantum", "delay")
        }
        return Sensors(**zero, battery_states_observed=True)  # type: ignore[arg-type]

    def scaled(self, noise_factor: float = 1.0, delay_s: float | None = None) -> "Sensors":
        """Every noise standard deviation and quantum times ``noise_factor`` (0: exact values) and (if given) every
        delay set to ``delay_s`` [s]."""
        if not (math.isfinite(noise_factor) and noise_factor >= 0):
            raise ParameterError(f"Sensors.scaled: noise_factor = {noise_factor!r} must be a finite number >= 0")
        kw: dict[str, Any] = {
            f"{c}_{k}_{_UNIT[c]}": noise_factor * float(getattr(self, f"{c}_{k}_{_UNIT[c]}"))
            for c in CHANNELS
            for k in ("noise", "quantum")
        }
        if delay_s is not None:
            kw.update({f"{c}_delay_s": delay_s for c in CHANNELS})
        return replace(self, **kw)

    def noise(self, channel: str) -> float:
        """Standard deviation of ``channel``'s noise [SI]."""
        return float(getattr(self, f"{channel}_noise_{_UNIT[channel]}"))

    def quantum(self, channel: str) -> float:
        """Quantum of ``channel`` [SI] (0: not quantised)."""
        return float(getattr(self, f"{channel}_quantum_{_UNIT[channel]}"))

    def delay(self, channel: str) -> float:
        """Delay of ``channel`` [s]."""
        return float(getattr(self, f"{channel}_delay_s"))

    def variance(self, channel: str) -> float:
        """Variance of ``channel``'s measurement error [SI²]: noise² + quantum²/12 (uniform rounding error)."""
        return self.noise(channel) ** 2 + self.quantum(channel) ** 2 / 12.0

    @property
    def degraded(self) -> bool:
        """True unless every channel is exact and instantaneous and the battery states are observed."""
        return (
            not self.battery_states_observed
            or self.sample_period_s > 0
            or any(self.noise(c) or self.quantum(c) or self.delay(c) for c in CHANNELS)
        )


@dataclass(frozen=True)
class Measurement:
    """One vehicle's measurements at controller time ``t_s`` (SI; pack voltage and current, current > 0
    discharges). ``battery``: (V1 [V], V2 [V], SOC [-]) of the cell when the battery states are observed;
    ``accel_cmd_mps2``: the acceleration the vehicle applied over the last step (its own command, known exactly)."""

    t_s: float
    gap_m: float
    speed_mps: float
    lead_speed_mps: float
    voltage_V: float
    current_A: float
    battery: tuple[float, float, float] | None = None
    accel_cmd_mps2: float = 0.0


class SensorModel:
    """The sensors of ``n`` vehicles during one run: record the true channel values at the loop's nodes
    (:meth:`record`), then read what vehicle i measures at t (:meth:`measure`). Seeded per vehicle."""

    def __init__(self, sensors: Sensors, n: int) -> None:
        self.sensors, self.n = sensors, n
        self.t: list[float] = []
        self.true: list[np.ndarray] = []  # (n, 5) per node: the channels in CHANNELS order
        self.battery: list[np.ndarray] = []  # (n, 3) per node: V1, V2, S
        self.rng = [np.random.default_rng([sensors.seed, i]) for i in range(n)]
        self._held: dict[tuple[int, int, int], float] = {}  # (vehicle, channel, sample index) -> value

    def record(self, t_s: float, values: np.ndarray, battery: np.ndarray) -> None:
        """The true values (n, 5) [SI, CHANNELS order] and cell states (n, 3) at node time t_s."""
        self.t.append(float(t_s))
        self.true.append(np.asarray(values, float).reshape(self.n, len(CHANNELS)))
        self.battery.append(np.asarray(battery, float).reshape(self.n, 3))

    def _true_at(self, i: int, c: int, t: float) -> float:
        tt = self.t
        if t <= tt[0]:
            return float(self.true[0][i, c])
        k = min(bisect.bisect_right(tt, t) - 1, len(tt) - 1)
        if k == len(tt) - 1 or t <= tt[k]:
            return float(self.true[k][i, c])
        w = (t - tt[k]) / (tt[k + 1] - tt[k])
        return float((1 - w) * self.true[k][i, c] + w * self.true[k + 1][i, c])

    def measure(self, i: int, t_s: float, accel_cmd_mps2: float = 0.0) -> Measurement:
        """What vehicle ``i`` measures at t_s (after :meth:`record` of every node up to t_s); ``accel_cmd_mps2``: the
        acceleration it applied last [m/s²] (passed through)."""
        s, vals = self.sensors, []
        for c, name in enumerate(CHANNELS):
            tm = t_s - s.delay(name)
            m = int(math.floor(tm / s.sample_period_s + 1e-9)) if s.sample_period_s > 0 else len(self.t)
            key = (i, c, m)
            if s.sample_period_s > 0 and key in self._held:
                vals.append(self._held[key])
                continue
            if s.sample_period_s > 0:
                tm = m * s.sample_period_s
            x = self._true_at(i, c, max(tm, 0.0))
            sd, q = s.noise(name), s.quantum(name)
            if sd > 0:
                x += sd * float(self.rng[i].standard_normal())
            if q > 0:
                x = q * round(x / q)
            if s.sample_period_s > 0:
                self._held[key] = x
            vals.append(x)
        b = self.battery[-1][i]
        bat = (float(b[0]), float(b[1]), float(b[2])) if s.battery_states_observed else None
        return Measurement(t_s, vals[0], vals[1], vals[2], vals[3], vals[4], bat, float(accel_cmd_mps2))

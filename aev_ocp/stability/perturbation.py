"""Leaders that perturb a constant-speed equilibrium: a sinusoid or a speed dip (pulse), model units."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ..models.leader import LeaderProfile
from ..params import ParameterError

KINDS = ("sine", "pulse")


@dataclass(frozen=True)
class PerturbedLeader(LeaderProfile):
    """Constant speed v_star, perturbed from t_start on [model units].

    kind 'sine':  v_l = v* + A sin(ω (t − t_start)) for t ≥ t_start (ω = omega [rad/model time]);
    kind 'pulse': v_l = v* − A (1 − cos(2π τ/D))/2, τ = t − t_start ∈ [0, D] (D = duration): a smooth
    dip of depth A that returns to v*, like one slowdown of the paper's leader (D = 4 is the period of
    its slow component sin(0.5πt)).
    """

    v_star: float
    amplitude: float
    kind: str = "sine"
    omega: float = 0.5 * math.pi
    duration: float = 4.0
    t_start: float = 0.0
    name = "perturbed"

    def __post_init__(self) -> None:
        for attr in ("v_star", "amplitude", "omega", "duration", "t_start"):
            x = getattr(self, attr)
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x < 0:
                raise ParameterError(f"PerturbedLeader.{attr} = {x!r} is not allowed: must be a finite number >= 0")
        if self.kind not in KINDS:
            raise ParameterError(f"PerturbedLeader.kind = {self.kind!r} is not allowed: must be one of {KINDS}")
        if self.kind == "sine" and self.omega <= 0:
            raise ParameterError(f"PerturbedLeader.omega = {self.omega!r} is not allowed: must be > 0")
        if self.kind == "pulse" and self.duration <= 0:
            raise ParameterError(f"PerturbedLeader.duration = {self.duration!r} is not allowed: must be > 0")
        if self.amplitude > self.v_star:
            raise ParameterError(
                f"PerturbedLeader.amplitude = {self.amplitude!r} is not allowed: must be <= the "
                f"speed v* = {self.v_star!r} (the leader would drive backwards)"
            )

    @property
    def breakpoints(self) -> tuple[float, ...]:
        if self.kind == "sine":
            return (self.t_start,) if self.t_start > 0 else ()
        return tuple(t for t in (self.t_start, self.t_start + self.duration) if t > 0)

    def _tau(self, t: Any) -> Any:
        tau = ca.fmax(t - self.t_start, 0.0)
        return tau if self.kind == "sine" else ca.fmin(tau, self.duration)

    def speed(self, t: Any) -> Any:
        tau = self._tau(t)
        if self.kind == "sine":
            return self.v_star + self.amplitude * ca.sin(self.omega * tau)
        return self.v_star - 0.5 * self.amplitude * (1.0 - ca.cos(2.0 * math.pi * tau / self.duration))

    def accel(self, t: Any) -> Any:
        on = ca.logic_and(t >= self.t_start, True if self.kind == "sine" else t <= self.t_start + self.duration)
        tau = self._tau(t)
        if self.kind == "sine":
            a = self.amplitude * self.omega * ca.cos(self.omega * tau)
        else:
            w = 2.0 * math.pi / self.duration
            a = -0.5 * self.amplitude * w * ca.sin(w * tau)
        return ca.if_else(on, a, 0.0)

    def position(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        tau = np.maximum(t - self.t_start, 0.0)
        if self.kind == "sine":
            return self.v_star * t + self.amplitude * (1.0 - np.cos(self.omega * tau)) / self.omega
        tau = np.minimum(tau, self.duration)
        w = 2.0 * math.pi / self.duration
        return self.v_star * t - 0.5 * self.amplitude * (tau - np.sin(w * tau) / w)

    def describe(self) -> dict[str, Any]:
        return {
            "profile": self.name,
            "kind": self.kind,
            "v_star": self.v_star,
            "amplitude": self.amplitude,
            "omega": self.omega,
            "duration": self.duration,
            "t_start": self.t_start,
        }

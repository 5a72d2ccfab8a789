"""The closed-loop step core: one control instant of one vehicle, the same in every simulator.

Every closed loop of the toolkit — the platoon (:class:`aev_ocp.control.ClosedLoop`), the ring
(:class:`aev_ocp.ring.simulate.RingSimulator`) and SUMO (:func:`aev_ocp.sumo.run.run_sumo`) — hands each sampled
controller's answer to a :class:`VehicleStep`, which applies, in this order:

1. **the check**: the answer must be a :class:`Command` whose ``a`` is one finite real number (a NumPy scalar or
   one-element array is taken as a float); anything else (NaN, ±inf, None, a bare float, a wrong type) is a
   :class:`~aev_ocp.params.ParameterError` naming the controller, the vehicle and the time;
2. **conditioning** (:class:`CommandStages`): a first-order command filter of time constant τ [s], the exact
   zero-order-hold discretisation of τ ȧ = a_cmd − a over the step, ``a_k = a_{k−1} + (1 − e^(−dt/τ))
   (u_k − a_{k−1})``, then a jerk limit ``|a_k − a_{k−1}| ≤ j_max dt`` (a_{k−1}: the command the vehicle
   applied at the previous instant, 0 before the first: the vehicle cruises before t = 0);
3. **the safety layer**: ``min(a, safe)``, ``safe`` the braking-distance bound of
   :func:`aev_ocp.models.safety_bound.safe_acceleration_mps2` at the controller's own view (gap, speed, predecessor speed
   and its measured acceleration), so no stage after it can undo it;
4. **the actuator limits**: saturation to the vehicle's [a_min, a_max] (:class:`aev_ocp.params.VehicleLimits`;
   the plants saturate again inside their right-hand sides, which changes nothing: the same min/max);
5. **bookkeeping**: the controller's call time, solve statistics and the counts of the steps each stage changed
   (:meth:`VehicleStep.counts`), reported with the controller's statistics (:meth:`VehicleStep.stats`, the same
   keys in every loop) and its settings (:meth:`VehicleStep.settings`).

Each stage is declared per run in the vehicle's limits (``[limits]`` of a scenario, or
``EVParams(limits=VehicleLimits(...))``): ``command_filter_s``, ``command_jerk_max_mps3``, ``safety_layer``, or per
ClosedLoop (``stages=``). Left at None, the conditioning is :data:`PRODUCTION_ACC` for car-following laws under
realistic (degraded) sensors, as a production ACC conditions its commands, and off everywhere else: the paper's
runs (ideal measurements) are unconditioned and bit-identical to a loop without this module.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, Sequence, runtime_checkable

import numpy as np

from .estimation.base import Estimate
from .estimation.sensors import Measurement
from .params import ParameterError, Units, VehicleLimits, as_dict, spec, validate_fields
from .models.safety_bound import SafetyParams, safe_acceleration_mps2


class History:
    """A series of floats appended one at a time and read as a NumPy array of everything so far (the closed loops'
    measured times and speeds): :meth:`view` is a read-only view, O(1), where ``np.asarray(list)`` copied the whole
    history at every step (quadratic: 30 s of a 200 s reproduce section). Entries never change once
    appended, so a view taken earlier stays valid."""

    def __init__(self, capacity: int = 256) -> None:
        self._a = np.empty(max(1, int(capacity)))
        self.n = 0

    def append(self, value: float) -> None:
        """Add one value (the buffer doubles when full)."""
        if self.n == self._a.size:
            grown = np.empty(2 * self._a.size)
            grown[: self.n] = self._a
            self._a = grown
        self._a[self.n] = value
        self.n += 1

    def __len__(self) -> int:
        return self.n

    def view(self) -> np.ndarray:
        """The values so far (float64, oldest first), read-only."""
        v = self._a[: self.n]
        v.flags.writeable = False
        return v


@dataclass
class Observation:
    """What follower ``vehicle`` (0-based) knows at time t [model time]: its own state
    z = (h, v, V1, V2, S) (model units, V, -), the measured speeds of its predecessor at the
    sample times so far (oldest first, the last at t), the predecessor's latest plan of node speeds
    at t, t + dt, … when the predecessor publishes one (V2V), the command it applied last (after the
    vehicle's saturation), with an actuator lag its realised acceleration a_act and, with the thermal model
    (``[thermal] enabled``), its pack temperature T_K [K] (a temperature sensor: read exactly, with sensors too)
    and, where the simulator provides it, its follower's gap to it and speed (a rear radar; read exactly).

    With sensors (:class:`aev_ocp.estimation.sensors.Sensors`) z and meas_v are what the car knows, not the
    plant's state: h, v, the predecessor speeds and V1, V2, S from the estimator (each bridged over its
    sensor's delay)."""

    t: float
    dt: float
    vehicle: int
    z: np.ndarray
    meas_t: np.ndarray
    meas_v: np.ndarray
    predecessor_plan: np.ndarray | None = None
    a_prev: float = 0.0
    a_act: float | None = None  # the realised acceleration at t [model] when the vehicle has an actuator lag
    measurement: Measurement | None = None  # with sensors: the raw (noisy, late) measurement, SI
    estimate: Estimate | None = None  # with sensors and an estimator: its estimate, SI
    T_K: float | None = None  # the pack temperature at t [K] when the plant has the thermal model
    # the vehicle behind (a rear radar): (its gap to this vehicle, its speed) at t [model length, model speed];
    # None where no follower is measured (the last car of a platoon, a simulator that does not provide it)
    follower: np.ndarray | None = None
    # the legal speed limit of the vehicle's lane [model speed] (a map), where the simulator provides it
    speed_limit: float | None = None
    # the obstacle the gap h measures is the end of the vehicle's lane, not a vehicle (a map: the lane ends before
    # the route goes on, so the car must change lanes before it; its "predecessor speed" in meas_v is then 0)
    lane_end: bool = False
    # at the end of its lane: the speed a merge assistant advises [model speed], one that sees the target lane's
    # traffic (in SUMO the speed its lane-change model asks of the car to reach a gap); None where none is given
    merge_speed: float | None = None


@dataclass
class Command:
    """A controller's decision: acceleration a [model units] held over [t, t + dt]. ``ok`` False marks
    a fallback (counted); ``plan`` (node speeds from t on) is published to the follower behind."""

    a: float
    ok: bool = True
    status: str = "ok"
    solve_time_s: float = float("nan")
    iterations: int = 0
    plan: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Controller(Protocol):
    """A sampled controller: ``command`` is called every ``dt`` [model time] with an Observation."""

    name: str
    dt: float

    def reset(self) -> None:
        """Forget internal state (called before a run)."""

    def command(self, obs: Observation) -> Command:
        """The acceleration to hold over [obs.t, obs.t + dt]."""

    def describe(self) -> dict[str, Any]:
        """Settings, for reports."""


# A production ACC's command conditioning. The filter: a first-order lag of 0.5 s, the order of the command
# response Milanés & Shladover identified on a commercial ACC (Transp. Res. C 48 (2014) 285-300: first-order
# responses with time constants of about 0.5 s); issue 33 of this project measured its effect on the laws' heat
# margins. The jerk: ISO 15622 (ACC) and ISO 22179 (full-speed-range ACC) bound the average jerk over 1 s by
# 2.5 m/s³ at motorway speed and allow up to 5 m/s³ at low speed; the default takes the 5 m/s³, because 2.5 m/s³
# applied as a per-step limit leaves a law too little braking authority (one of four US06 runs of
# tests/test_estimation_robust.py collided with it, none with 5 m/s³; an ACC hands such braking to the AEB).
PRODUCTION_ACC_FILTER_S = 0.5
PRODUCTION_ACC_JERK_MPS3 = 5.0


@dataclass(frozen=True)
class CommandStages:
    """The stages between one vehicle's controller and its actuator, SI (resolved from its limits or given):
    ``filter_s`` the first-order command filter's time constant τ [s] (0: off), ``jerk_max_mps3`` the largest
    change of the command per second [m/s³] (0: off), ``safety`` the braking-distance layer's parameters (None:
    off)."""

    filter_s: float = spec(0.0, ge=0)
    jerk_max_mps3: float = spec(0.0, ge=0)
    safety: SafetyParams | None = spec(None, kind="instance", cls=SafetyParams, optional=True)

    def __post_init__(self) -> None:
        validate_fields(self)

    @property
    def active(self) -> bool:
        """Whether any stage can change a command."""
        return self.filter_s > 0 or self.jerk_max_mps3 > 0 or self.safety is not None

    def label(self) -> str:
        """One phrase naming the conditioning and the safety layer, for tables ('none' without any)."""
        parts = []
        if self.filter_s > 0:
            parts.append(f"filter {self.filter_s:g} s")
        if self.jerk_max_mps3 > 0:
            parts.append(f"jerk <= {self.jerk_max_mps3:g} m/s^3")
        if self.safety is not None:
            parts.append("safety layer")
        return ", ".join(parts) or "none"

    def describe(self) -> dict[str, Any]:
        """The stages as plain data (SI), for a result's metadata."""
        return {
            "conditioning": self.label(),
            "filter_s": self.filter_s,
            "jerk_max_mps3": self.jerk_max_mps3,
            "safety_layer": as_dict(self.safety) if self.safety is not None else None,
        }


NO_STAGES = CommandStages()
#: the conditioning of a production ACC (ISO 15622 jerk, a 0.5 s command filter; sources above)
PRODUCTION_ACC = CommandStages(PRODUCTION_ACC_FILTER_S, PRODUCTION_ACC_JERK_MPS3)


def stages_for(limits: VehicleLimits, *, law: bool, sensed: bool) -> CommandStages:
    """The stages a vehicle with ``limits`` runs: the declared filter and jerk limit, or (left at None) those of
    :data:`PRODUCTION_ACC` for a car-following law (``law``) under degraded sensors (``sensed``) and none otherwise;
    the safety layer when ``limits.safety_layer`` (its braking and bounds from the limits)."""
    auto = law and sensed
    f = limits.command_filter_s
    j = limits.command_jerk_max_mps3
    return CommandStages(
        float(PRODUCTION_ACC.filter_s if auto else 0.0) if f is None else float(f),
        float(PRODUCTION_ACC.jerk_max_mps3 if auto else 0.0) if j is None else float(j),
        SafetyParams.from_limits(limits) if limits.safety_layer else None,
    )


def check_command(cmd: Any, controller: str, vehicle: str, t: float, units: Units, where: str) -> Command:
    """``cmd`` if it is a Command with one finite real acceleration (a NumPy scalar or one-element array becomes
    a float); a ParameterError naming the loop, the controller, the vehicle, the time t [model] and the field
    otherwise (a NaN would be saturated into full braking, an inf into a_max, without a word)."""
    a = getattr(cmd, "a", None)
    if isinstance(cmd, Command) and not isinstance(a, (bool, np.bool_)):
        if isinstance(a, numbers.Real) and math.isfinite(a):
            return cmd
        if isinstance(a, np.ndarray) and a.size == 1 and a.dtype.kind in "iuf" and np.isfinite(a).all():
            return replace(cmd, a=float(a.reshape(())))  # what np.clip/np.minimum give on 0-d inputs
    got = f"Command(a = {a!r:.60})" if isinstance(cmd, Command) else f"{type(cmd).__name__} {cmd!r:.60}"
    raise ParameterError(
        f"{where}: controller {controller!r} of {vehicle} returned {got} at t = {t:g}: command() must return a "
        f"Command whose a is a finite acceleration [model units] (field Command.a; t = {float(units.time_to_si(t)):g} s)"
    )


#: the counters of :meth:`VehicleStep.counts`, as they appear in a controller's statistics
COUNT_NAMES = ("filtered_steps", "jerk_limited_steps", "safety_limited_steps", "saturated_steps")


def fallback_causes(status: Sequence[Any], ok: Sequence[bool]) -> dict[str, int]:
    """{cause: count} over the failed steps; a cause is a step's status up to its first ':'."""
    out: dict[str, int] = {}
    for st, k in zip(status, ok):
        if not k:
            c = str(st).split(":")[0].strip() or "unknown"
            out[c] = out.get(c, 0) + 1
    return out


def controller_stats(
    rec: dict[str, list[Any]], ctrl: Controller, counts: dict[str, int] | None = None, conditioning: str = "none"
) -> dict[str, Any]:
    """A sampled controller's statistics from its records (solve and call times [ms], iterations, fallbacks), the
    step core's counts (:meth:`VehicleStep.counts`) and its conditioning (:meth:`CommandStages.label`)."""
    counts = counts or {}
    ms = np.asarray(rec["solve"], float) * 1e3
    ms = ms[np.isfinite(ms)]
    cm = np.asarray(rec["call"], float) * 1e3
    it = np.asarray(rec["iters"], float)
    ok = ms.size > 0
    d = ctrl.describe()
    return {
        "solve_ms_median": float(np.median(ms)) if ok else float("nan"),
        "solve_ms_p95": float(np.percentile(ms, 95)) if ok else float("nan"),
        "solve_ms_max": float(ms.max()) if ok else float("nan"),
        "iterations_mean": float(it.mean()) if it.size else float("nan"),
        "iterations_max": int(it.max()) if it.size else 0,
        "fallbacks": int(sum(not k for k in rec["ok"])),
        # cause of each fallback: the status up to its first ':' ('QP failed', 'budget', 'path constraint',
        # 'exception', or the NLP solver's return status)
        "fallback_causes": fallback_causes(rec["status"], rec["ok"]),
        # QPs of the compiled step that ended at their acceptable level (every residual within 100x its
        # tolerance, ocp_qp.c's OCPQP_ACCEPTABLE) and were applied: 0 for every other controller
        "qp_acceptable": int(sum(int((i or {}).get("qp_acceptable", 0)) for i in rec["info"])),
        "solver_path": d.get("solver_path", d.get("controller", "")),
        "qp_solver": d.get("qp_in_use", ""),  # the MPC's QP solver that ran ('' for the others)
        "n_steps": len(rec["ok"]),
        # whole controller call: forecast, warm-start shift, parameters, solve, unpacking
        "call_ms_median": float(np.median(cm)) if cm.size else float("nan"),
        "call_ms_p95": float(np.percentile(cm, 95)) if cm.size else float("nan"),
        # how many commands each stage of the step core changed (conditioning, safety, limits)
        **{k: int(counts.get(k, 0)) for k in COUNT_NAMES},
        "conditioning": conditioning,  # e.g. 'filter 0.5 s, jerk <= 5 m/s^3', 'safety layer', 'none'
    }


class VehicleStep:
    """One vehicle's control instant (module docstring): check, conditioning, safety layer, actuator limits and
    bookkeeping, for any controller. ``units``: the model units of commands and observations; ``dt`` the control
    period [model time]; ``vehicle``: how messages name the vehicle ('vehicle 2', "vehicle 'ring.4'"); ``where``:
    the loop ('closed loop', 'ring', 'sumo')."""

    def __init__(
        self,
        controller: str,
        vehicle: str,
        units: Units,
        limits: VehicleLimits,
        stages: CommandStages,
        dt: float,
        where: str = "closed loop",
    ) -> None:
        self.controller, self.vehicle, self.where = controller, vehicle, where
        self.units, self.limits, self.stages, self.dt = units, limits, stages, float(dt)
        self.a_lo, self.a_hi = limits.accel_bounds_model(units)
        dt_s = float(units.time_to_si(dt))
        self.alpha = 1.0 - math.exp(-dt_s / stages.filter_s) if stages.filter_s > 0 else 1.0
        # the largest change of the command over one step [model acceleration]
        self.da_max = float(units.accel_from_si(stages.jerk_max_mps3 * dt_s)) if stages.jerk_max_mps3 > 0 else math.inf
        self.rec: dict[str, list[Any]] = {}
        self.reset()

    def reset(self) -> None:
        """Forget the previous command (0: cruising before t = 0) and zero the counters and records."""
        self.a_prev = 0.0
        self.n = {k: 0 for k in ("steps", *COUNT_NAMES)}
        self.rec = {k: [] for k in ("solve", "call", "iters", "ok", "status", "info")}

    # ------------------------------------------------------------------ one instant
    def command(self, ctrl: Controller, obs: Observation) -> tuple[Command, float]:
        """Call ``ctrl`` on ``obs``, check its answer, record its statistics and return (the checked Command, the
        acceleration the vehicle applies [model units] after every stage)."""
        tc = time.perf_counter()
        raw = ctrl.command(obs)
        self.rec["call"].append(time.perf_counter() - tc)
        cmd = check_command(raw, self.controller, self.vehicle, obs.t, self.units, self.where)
        for key, val in (
            ("solve", cmd.solve_time_s),
            ("iters", cmd.iterations),
            ("ok", cmd.ok),
            ("status", cmd.status),
            ("info", cmd.info),
        ):
            self.rec[key].append(val)
        return cmd, self.apply_obs(float(cmd.a), obs)

    def apply_obs(self, a: float, obs: Observation) -> float:
        """:meth:`apply` with the controller's view from an Observation (the predecessor's acceleration from its
        last two measured speeds)."""
        a_lead = 0.0
        if self.stages.safety is not None and len(obs.meas_v) >= 2 and obs.meas_t[-1] > obs.meas_t[-2]:
            a_lead = float((obs.meas_v[-1] - obs.meas_v[-2]) / (obs.meas_t[-1] - obs.meas_t[-2]))
        return self.apply(a, float(obs.z[0]), float(obs.z[1]), float(obs.meas_v[-1]), a_lead)

    def apply(self, a: float, h: float, v: float, v_lead: float, a_lead: float = 0.0) -> float:
        """The acceleration [model] the vehicle applies for a command ``a`` [model] at its view: gap h, speed v,
        predecessor speed v_lead and acceleration a_lead (model units): conditioning, safety layer, limits."""
        st = self.stages
        self.n["steps"] += 1
        if st.filter_s > 0:
            a = self.a_prev + self.alpha * (a - self.a_prev)
            self.n["filtered_steps"] += 1
        if st.jerk_max_mps3 > 0:
            lo, hi = self.a_prev - self.da_max, self.a_prev + self.da_max
            if a < lo or a > hi:
                a = min(max(a, lo), hi)
                self.n["jerk_limited_steps"] += 1
        if st.safety is not None:
            u = self.units
            safe = float(
                u.accel_from_si(
                    safe_acceleration_mps2(
                        float(u.length_to_si(h)),
                        float(u.speed_to_si(v)),
                        float(u.speed_to_si(v_lead)),
                        float(u.time_to_si(self.dt)),
                        st.safety,
                        float(u.accel_to_si(a_lead)),
                    )
                )
            )
            if safe < a:
                a = safe
                self.n["safety_limited_steps"] += 1
        if a < self.a_lo or a > self.a_hi:
            a = min(max(a, self.a_lo), self.a_hi)
            self.n["saturated_steps"] += 1
        self.a_prev = a
        return a

    def count_unstaged(self, saturated: bool) -> None:
        """Count one step of a command the loop saturates itself, no stage being active (SUMO's laws, evaluated
        for all its vehicles at once): as :meth:`apply` counts it."""
        self.n["steps"] += 1
        self.n["saturated_steps"] += int(saturated)

    # ------------------------------------------------------------------ reports
    def counts(self) -> dict[str, int]:
        """Steps and, per stage, how many commands it changed (the filter: every step it ran)."""
        return dict(self.n)

    def describe(self) -> dict[str, Any]:
        """The stages (SI) and the counts, for a result's metadata."""
        return {**self.stages.describe(), **self.counts()}

    def stats(self, ctrl: Controller) -> dict[str, Any]:
        """The statistics of ``ctrl``'s calls through this core (:func:`controller_stats`), for a result."""
        return controller_stats(self.rec, ctrl, self.counts(), self.stages.label())

    def settings(self, who: Any) -> dict[str, Any]:
        """The settings of ``who`` (the controller or law this core steps) naming its conditioning, for a result."""
        return {**who.describe(), "conditioning": self.stages.label()}

"""Controllers and the closed loop that drives them on the plant.

A follower runs either a car-following law (integrated continuously inside the plant) or a sampled
:class:`Controller`: anything with ``name``, ``dt``, ``reset()`` and ``command(obs) -> Command``.
The MPC (:class:`aev_ocp.mpc.policy.MPCPolicy`), a replayed control sequence
(:class:`ControlSequence`, e.g. OCP-D's optimum), a sampled law (:class:`SampledLaw`) and a
user's own controller (an ACC law, a learned policy) are all Controllers; any vehicle of any
scenario can run any of them. The closed loop (:class:`ClosedLoop`) hands each answer to the step core every
loop shares (:class:`aev_ocp.loop.VehicleStep`: the check, the declared conditioning and safety layer, the
vehicle's limits, the counts), applies the result as a zero-order hold over dt on the exact plant
(:class:`aev_ocp.plant.Plant`), with the plant's event rules, and returns the one result type
(:class:`aev_ocp.results.SimulationResult`). The protocol types (:class:`Controller`, :class:`Observation`,
:class:`Command`) live in :mod:`aev_ocp.loop` and are importable from here as before.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence, cast

import numpy as np

from .errors import AevOcpError
from .fastcall import column_call
from .estimation.base import Estimate, Estimator
from .estimation.kalman import EKF
from .estimation.mhe import MHE
from .estimation.mismatch import Mismatch
from .estimation.sensors import CHANNELS, Measurement, SensorModel, Sensors
from .loop import (
    CommandStages,
    Command,
    Controller,
    History,
    Observation,
    VehicleStep,
    controller_stats,
    stages_for,
)
from .models import battery
from .models.carfollowing import CarFollowingLaw, Proposed
from .models.leader import LeaderProfile
from .params import PAPER_ACCEL_BOUNDS_MODEL, EVParams, ParameterError, SimOptions, as_dict, check_argument
from .plant import Plant, PlatoonRun, ProgressFn, stack_samples
from .progress import TimeLimitReached
from .results import Event, SimulationResult


@dataclass(frozen=True)
class ControlSequence:
    """An open-loop command: a_k [model acceleration] held over [k dt, (k+1) dt] — e.g. OCP-D's optimal
    controls replayed through the exact plant so the lower bound gets every §10 metric."""

    a: tuple[float, ...]
    dt: float
    name: str = "open-loop"

    def __post_init__(self) -> None:
        a = np.asarray(self.a, float)
        if a.ndim != 1 or a.size < 1 or not np.all(np.isfinite(a)):
            raise ParameterError("ControlSequence.a must be a non-empty 1-D sequence of finite accelerations")
        if not (isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"ControlSequence.dt = {self.dt!r} is not allowed: must be > 0")

    def reset(self) -> None:
        """Nothing to forget."""

    def command(self, obs: Observation) -> Command:
        return Command(float(self.a[int(round(obs.t / self.dt))]))

    def describe(self) -> dict[str, Any]:
        return {"controller": self.name, "dt": self.dt, "steps": len(self.a)}


@dataclass(frozen=True)
class SampledLaw:
    """A car-following law evaluated every dt on the measurements and held (like a real ECU),
    clipped to [a_min, a_max] (model acceleration)."""

    law: CarFollowingLaw
    dt: float
    a_min: float = PAPER_ACCEL_BOUNDS_MODEL[0]  # model guide §9
    a_max: float = PAPER_ACCEL_BOUNDS_MODEL[1]  # model guide §9

    @property
    def name(self) -> str:
        return f"{self.law.name}@dt={self.dt:g}"

    def reset(self) -> None:
        """Nothing to forget."""

    def command(self, obs: Observation) -> Command:
        a = column_call(self.law.function).scalar(max(float(obs.z[0]), 1e-6), float(obs.z[1]), float(obs.meas_v[-1]))
        return Command(min(max(a if math.isfinite(a) else self.a_min, self.a_min), self.a_max))

    def describe(self) -> dict[str, Any]:
        return {"controller": self.name, **self.law.describe()}


EstimatorFactory = Callable[[EVParams, Sensors, float, int], Estimator]  # (model ev, sensors, OCV offset, vehicle)
#: the shipped estimators by name (:mod:`aev_ocp.estimation`)
ESTIMATORS: dict[str, EstimatorFactory] = {
    "ekf": lambda ev, s, off, i: EKF(ev, s, ocv_offset_V=off),
    "mhe": lambda ev, s, off, i: MHE(ev, s, ocv_offset_V=off),
}


# adapters from settings objects to Controllers (the MPC registers MPCSettings and MPCVehicle)
AdapterFn = Callable[[Any, int, "ClosedLoop"], Controller]
_ADAPTERS: dict[type, AdapterFn] = {}


def register_controller_adapter(cls: type, fn: AdapterFn) -> None:
    """Let :class:`ClosedLoop` accept objects of ``cls`` (e.g. MPCSettings) as controllers:
    ``fn(obj, vehicle_index, closed_loop) -> Controller``."""
    _ADAPTERS[cls] = fn


class _Anonymous:
    def describe(self) -> dict[str, Any]:
        return {}


def sampled_stat_names() -> frozenset[str]:
    """Every key a sampled controller's statistics add to its follower's metrics (:func:`aev_ocp.loop.controller_stats`, the forecast
    RMS, the estimation errors and the estimator's timings of :meth:`ClosedLoop.run`), so that a study can check
    a [report] metric name before anything runs."""
    rec: dict[str, list[Any]] = {k: [] for k in ("solve", "call", "iters", "ok", "status", "info")}
    est = estimation_errors(np.zeros((1, 5)), 1.0)
    extra = ("forecast_rms", "estimation", "estimator_ms_median", "estimator_plus_call_ms_median")
    return frozenset([*controller_stats(rec, cast(Controller, _Anonymous())), *extra, *(f"est_{k}" for k in est)])


@dataclass
class _Run:
    """The state of one :meth:`ClosedLoop.run` (model units): the sampled followers (``sampled``, indices), their
    commands at this instant (``a_cmd``) and as the plant applied them at the last node (``a_app``, saturated), the
    samples so far (``out``: t, x, quadratures, outputs), the step cores and their records, the measurements, the
    sensors and estimators, the leader's breakpoints, the estimators' timings [s] and errors, the events."""

    sampled: list[int]
    a_cmd: np.ndarray
    a_app: np.ndarray
    a_bounds: tuple[float, float]
    out: tuple[list, list, list, list]
    cores: dict[int, VehicleStep]
    rec: list[dict[str, list[Any]]]
    meas_t: History
    meas_v: list[History]
    sm: SensorModel | None
    ests: list[Estimator | None]
    bps: list[float]
    est_s: list[list[float]]  # the sensors' read-out and the estimator's update [s], per follower
    err: list[list[np.ndarray]]  # estimate − truth per step: S, V1, V2, h, v_l
    events: list[Event] = field(default_factory=list)
    applied: list[np.ndarray] = field(default_factory=list)  # a_app at every node


class ClosedLoop(PlatoonRun):
    """A platoon behind ``leader`` where each follower runs a law (continuous) or a Controller
    (sampled every dt, the same dt for all); build once (controllers and plant), then :meth:`run`.

    controllers[i]: a CarFollowingLaw, a Controller, or an object with a registered adapter
    (MPCSettings, MPCVehicle). fallback_law: the law an MPC applies when a solve fails (default the
    proposed law with the paper's α, β, κ); rtol/atol: plant CVODES tolerances.

    A car's view (docs/guide/realism.md): ``mismatch`` (:class:`~aev_ocp.estimation.mismatch.Mismatch`) gives each
    follower's controller and estimator a model that differs from the plant (``ev``); ``sensors``
    (:class:`~aev_ocp.estimation.sensors.Sensors`) makes the measurements noisy, quantised and late, with V1, V2, S
    unmeasured by default; ``estimator`` ('ekf', 'mhe', None, or a callable (model_ev, sensors, ocv_offset_V,
    vehicle) -> Estimator) turns them into the controllers' states. With degraded sensors every law runs as a
    :class:`SampledLaw` at the controllers' dt (``law_dt`` [model time] when no other controller is sampled),
    clipped to the vehicle's acceleration limits, on the same observations.

    ``stages`` (:class:`~aev_ocp.loop.CommandStages`, one for all or one per follower, None: the default) sets each
    sampled controller's command conditioning and safety layer; by default they come from the vehicle's limits
    (``VehicleLimits.command_filter_s``, ``command_jerk_max_mps3``, ``safety_layer``), the laws under realistic
    sensors getting a production ACC's conditioning (:data:`aev_ocp.loop.PRODUCTION_ACC`). A law whose stages are
    active runs as a :class:`SampledLaw` like under degraded sensors.

    ``plant``: a :class:`~aev_ocp.plant.Plant` to reuse instead of building one (a run changes nothing in it, so loops
    with other controllers on the same leader and vehicle can share it); it must be the plant this loop would build
    (the same leader, laws, vehicle and tolerances), else a :class:`ParameterError` names the field.
    """

    who = "closed loop"

    def __init__(
        self,
        leader: LeaderProfile,
        controllers: Sequence[Any],
        ev: EVParams | None = None,
        fallback_law: CarFollowingLaw | None = None,
        rtol: float = 1e-10,
        atol: float = 1e-10,
        *,
        mismatch: Mismatch | None = None,
        sensors: Sensors | None = None,
        estimator: str | EstimatorFactory | None = "ekf",
        law_dt: float = 0.1,
        stages: CommandStages | Sequence[CommandStages | None] | None = None,
        plant: Plant | None = None,
    ) -> None:
        check_argument("closed loop", "leader", leader, LeaderProfile)
        check_argument("closed loop", "plant", plant, (Plant, type(None)))
        check_argument("closed loop", "ev", ev, (EVParams, type(None)))
        check_argument("closed loop", "fallback_law", fallback_law, (CarFollowingLaw, type(None)))
        check_argument("closed loop", "mismatch", mismatch, (Mismatch, type(None)))
        check_argument("closed loop", "sensors", sensors, (Sensors, type(None)))
        if not (estimator is None or callable(estimator) or estimator in ESTIMATORS):
            raise ParameterError(
                f"closed loop: estimator = {estimator!r} is not allowed: must be one of "
                f"{sorted(ESTIMATORS)}, None or a callable (model_ev, sensors, ocv_offset_V, vehicle)"
            )
        if not (isinstance(law_dt, (int, float)) and math.isfinite(law_dt) and law_dt > 0):
            raise ParameterError(f"closed loop: law_dt = {law_dt!r} is not allowed: must be > 0")
        self.mismatch, self.sensors, self.estimator_spec = mismatch, sensors, estimator
        SimOptions(rtol=rtol, atol=atol)  # the plant's tolerances, validated like a scenario's [simulation]
        if len(controllers) < 1:
            raise ParameterError("ClosedLoop: the platoon needs at least one follower (controllers is empty)")
        self.leader, self.ev = leader, ev or EVParams()
        self.fallback_law = fallback_law or Proposed()
        self.n = len(controllers)
        # plant ≠ model: follower i's controller (and estimator) model; the plant is self.ev
        self.model_evs = [mismatch.model_ev(self.ev, i) if mismatch is not None else self.ev for i in range(self.n)]
        degraded = sensors is not None and sensors.degraded
        self.laws: list[CarFollowingLaw | None] = []
        self.ctrl: list[Controller | None] = []
        for i, c in enumerate(controllers):  # (an adapter may read what is set so far, e.g. model_ev)
            law, ctrl = self._resolve(c, i)
            self.laws.append(law)
            self.ctrl.append(ctrl)
        # realistic sensors (noise, quantisation or delay on a channel; not merely sampled): the laws get a
        # production ACC's conditioning by default
        realistic = sensors is not None and any(
            sensors.noise(c) or sensors.quantum(c) or sensors.delay(c) for c in CHANNELS
        )
        self.stages = self._stages(stages, realistic)
        dts = {c.dt for c in self.ctrl if c is not None}
        # a continuous law cannot see sampled measurements nor be conditioned: with degraded sensors or a declared
        # stage it runs as a sampled law (like an ECU)
        to_sample = [i for i, law in enumerate(self.laws) if law is not None and (degraded or self.stages[i].active)]
        if to_sample:
            dt_law = dts.copy().pop() if len(dts) == 1 else law_dt
            lo, hi = self.ev.limits.accel_bounds_model(self.ev.units)
            for i in to_sample:
                law = self.laws[i]
                assert law is not None
                self.ctrl[i], self.laws[i] = cast(Controller, SampledLaw(law, dt_law, lo, hi)), None
            dts = {c.dt for c in self.ctrl if c is not None}
        if not dts:
            raise ParameterError("ClosedLoop: no sampled controller; use aev_ocp.simulate for closed-form laws only")
        if len(dts) != 1:
            raise ParameterError(f"ClosedLoop: every sampled controller must use the same dt, got {sorted(dts)}")
        self.dt = dts.pop()
        self.rtol, self.atol = rtol, atol
        if plant is None:
            plant = Plant(leader, self.laws, self.ev, rtol=rtol, atol=atol)
        else:
            self._check_plant(plant)
        self.plant = plant
        self.battery = self.plant.battery

    def _check_plant(self, plant: Plant) -> None:
        """A plant given to reuse (built once, run by many loops: a run changes nothing in it) must be the one this
        loop would build: the same leader, laws (None for each sampled controller), vehicle, tolerances, battery and
        one output sample per interval."""
        want = {
            "leader": (plant.leader, self.leader),
            "laws": (plant.laws, self.laws),
            "ev": (plant.ev, self.ev),
            "rtol": (plant.rtol, self.rtol),
            "atol": (plant.atol, self.atol),
            "battery": (plant.battery, True),
            "samples": (plant.k, 1),
        }
        for name, (have, need) in want.items():
            if not (have is need or have == need):
                raise ParameterError(
                    f"closed loop: plant.{name} = {have!r} is not allowed: must be this loop's {need!r} "
                    "(a reused plant must be the one the loop would build)"
                )

    def _resolve(self, c: Any, i: int) -> tuple[CarFollowingLaw | None, Controller | None]:
        """(law, None) for a CarFollowingLaw, else (None, the Controller) of follower i's ``c`` (through its
        registered adapter), checked: the protocol and a finite dt > 0 [model time]."""
        if isinstance(c, CarFollowingLaw):
            return c, None
        adapter = next((fn for cls, fn in _ADAPTERS.items() if isinstance(c, cls)), None)
        c = adapter(c, i, self) if adapter is not None else c
        if not isinstance(c, Controller):
            raise ParameterError(
                f"ClosedLoop: controller of vehicle {i + 1} must be a CarFollowingLaw or a "
                f"Controller (name, dt, reset, command, describe), got {type(c).__name__}"
            )
        dt = getattr(c, "dt", None)
        if (
            isinstance(dt, (bool, np.bool_))
            or not isinstance(dt, numbers.Real)
            or not (math.isfinite(dt) and float(dt) > 0)
        ):
            raise ParameterError(
                f"ClosedLoop: controller {getattr(c, 'name', type(c).__name__)!r} of vehicle {i + 1}: dt = {dt!r} "
                "is not allowed: must be a finite sampling period > 0 [model time]"
            )
        return None, c

    def _stages(
        self, given: CommandStages | Sequence[CommandStages | None] | None, realistic: bool
    ) -> list[CommandStages]:
        """Each follower's loop stages: ``given`` (one for all, or one per follower, None: the default), else those
        its vehicle limits declare (:func:`aev_ocp.loop.stages_for`: the laws under realistic sensors get a
        production ACC's conditioning unless the limits say otherwise)."""
        if given is None or isinstance(given, CommandStages):
            per: list[CommandStages | None] = [given] * self.n
        else:
            per = list(given)
            if len(per) != self.n:
                raise ParameterError(
                    f"closed loop: stages needs one CommandStages (or None) per follower ({self.n}), got {len(per)}"
                )
        out = []
        for i, st in enumerate(per):
            check_argument("closed loop", f"stages[{i}]", st, (CommandStages, type(None)))
            is_law = self.laws[i] is not None or isinstance(self.ctrl[i], SampledLaw)
            out.append(st if st is not None else stages_for(self.ev.limits, law=is_law, sensed=realistic))
        return out

    def model_ev(self, vehicle: int) -> EVParams:
        """The EVParams follower ``vehicle`` (0-based)'s controller and estimator believe (the plant's without a
        mismatch)."""
        return self.model_evs[vehicle]

    def _estimators(self) -> list[Estimator | None]:
        """A fresh estimator per sampled follower (None without degraded sensors or with estimator=None)."""
        s, spec = self.sensors, self.estimator_spec
        if s is None or not s.degraded or spec is None:
            return [None] * self.n
        out: list[Estimator | None] = []
        for i, c in enumerate(self.ctrl):
            off = self.mismatch.draws(i)["ocv_offset_V"] if self.mismatch is not None else 0.0
            fac = ESTIMATORS[spec] if isinstance(spec, str) else spec
            est = fac(self.model_evs[i], s, off, i) if c is not None else None
            if est is not None and not isinstance(est, Estimator):
                raise ParameterError(
                    f"closed loop: the estimator of vehicle {i + 1} must have name, reset, update "
                    f"and describe, got {type(est).__name__}"
                )
            out.append(est)
        return out

    def _run(self, x0: np.ndarray, t_end: float, progress: ProgressFn | None) -> SimulationResult:
        """The closed loop from x0 over [0, t_end] (a multiple of dt); see :meth:`PlatoonRun.run`: at each control
        instant the measurements, every sampled controller through its step core, then the plant over dt."""
        K = self._steps(t_end)
        r = self._start(x0, t_end, K)
        k = 0
        while k < K and not r.events:
            tk = k * self.dt
            x = r.out[1][-1][:, -1]
            vl_k = float(self.leader.speed_np(tk)[0])
            self._measure(r, tk, x, vl_k)
            if not self._command_all(r, k, tk, x, vl_k):  # an estimator failed: nothing acts on its estimate
                break
            self._hold(r, k, K, tk, t_end)
            k += 1
            if progress is not None and not r.events:
                self._progress(r, tk, t_end, progress)
        return self._finish(r)

    def _steps(self, t_end: float) -> int:
        """The number of control steps K over [0, t_end] (a multiple of dt; a control sequence long enough)."""
        dt = self.dt
        K = int(round(t_end / dt))
        if K < 1 or abs(K * dt - t_end) > 1e-9 * max(1.0, t_end):
            raise ParameterError(f"closed loop: t_end = {t_end} must be a multiple of dt = {dt}")
        for i, c in enumerate(self.ctrl):
            if isinstance(c, ControlSequence) and len(c.a) < K:
                raise ParameterError(
                    f"closed loop: the control sequence of vehicle {i + 1} has {len(c.a)} values, {K} steps are needed"
                )
        return K

    def _start(self, x: np.ndarray, t_end: float, K: int) -> _Run:
        """A run's state at t = 0: the controllers reset, one step core each, the first sample and its check."""
        n, plant = self.n, self.plant
        for c in self.ctrl:
            if c is not None:
                c.reset()
        sampled = [i for i, c in enumerate(self.ctrl) if c is not None]
        q = np.zeros(plant.nq)
        a_cmd = np.zeros(len(sampled))
        y = plant.samples(np.array([0.0]), x[:, None], a_cmd)
        cores = {
            i: VehicleStep(c.name, f"vehicle {i + 1}", self.ev.units, self.ev.limits, self.stages[i], self.dt)
            for i, c in enumerate(self.ctrl)
            if c is not None
        }
        sensed = self.sensors is not None and self.sensors.degraded
        r = _Run(
            sampled=sampled,
            a_cmd=a_cmd,
            a_app=np.zeros(len(sampled)),
            a_bounds=self.ev.limits.accel_bounds_model(self.ev.units),
            out=([np.array([0.0])], [x[:, None]], [q[:, None]], [y]),
            cores=cores,
            rec=[cores[i].rec if i in cores else {} for i in range(n)],
            meas_t=History(K + 1),
            meas_v=[History(K + 1) for _ in range(n)],
            sm=SensorModel(self.sensors, n) if sensed and self.sensors is not None else None,
            ests=self._estimators(),
            bps=[b for b in self.leader.breakpoints if 0 < b < t_end],
            est_s=[[] for _ in range(n)],
            err=[[] for _ in range(n)],
        )
        ev0 = plant.check(np.array([0.0]), x[:, None], y)
        if ev0 is not None:
            r.events.append(ev0)
        return r

    def _measure(self, r: _Run, tk: float, x: np.ndarray, vl_k: float) -> None:
        """The measurements at t_k [model]: exact predecessor speeds, or every channel handed to the sensors."""
        n, u = self.n, self.ev.units
        r.meas_t.append(tk)
        if r.sm is None:
            for i in range(n):
                r.meas_v[i].append(vl_k if i == 0 else float(x[n + i - 1]))
        else:
            r.sm.record(
                u.time_to_si(tk),
                self._channels(x, vl_k, r.out[3][-1][:, -1]),
                np.column_stack([x[2 * n : 3 * n], x[3 * n : 4 * n], x[4 * n : 5 * n]]),
            )

    def _command_all(self, r: _Run, k: int, tk: float, x: np.ndarray, vl_k: float) -> bool:
        """Every sampled controller's command at t_k through its step core (checked, conditioned, safety layer,
        limits) into ``r.a_cmd``, front to back (a plan passes to the follower behind); False when an estimator
        failed (its 'estimation_failed' event recorded)."""
        plans: list[np.ndarray | None] = [None] * self.n
        for j, i in enumerate(r.sampled):
            ctrl = self.ctrl[i]
            assert ctrl is not None
            obs = self._observation(r, i, j, k, tk, x, vl_k, plans[i - 1] if i > 0 else None)
            if obs is None:
                return False
            cmd, r.a_cmd[j] = r.cores[i].command(ctrl, obs)
            plans[i] = cmd.plan
        return True

    def _observation(
        self, r: _Run, i: int, j: int, k: int, tk: float, x: np.ndarray, vl_k: float, plan: np.ndarray | None
    ) -> Observation | None:
        """What follower i (the j-th sampled) knows at t_k: its state, or with sensors the estimator's view (with
        the estimation error recorded); None when its estimator returned a non-finite state (an event)."""
        n, u, plant = self.n, self.ev.units, self.plant
        z = x[[i, n + i, 2 * n + i, 3 * n + i, 4 * n + i]]
        meas: Measurement | None = None
        e: Estimate | None = None
        if r.sm is not None:
            te = time.perf_counter()
            try:
                z, meas, e = self._sensed(r.sm, r.ests[i], i, k, tk, float(r.a_app[j]))
            except EstimateNotFinite as bad:
                r.events.append(Event("estimation_failed", tk, i, str(bad), float(u.time_to_si(tk))))
                return None
            r.est_s[i].append(time.perf_counter() - te)
            r.meas_v[i].append(float(u.speed_from_si(e.lead_speed_mps if e is not None else meas.lead_speed_mps)))
            if e is not None:
                r.err[i].append(self._estimate_error(e, x, i, vl_k))
        return Observation(
            tk,
            self.dt,
            i,
            z,
            r.meas_t.view(),
            r.meas_v[i].view(),
            plan,
            float(r.a_app[j]),
            None if plant.act_row is None else float(x[plant.act_row + i]),
            meas,
            e,
            float(x[5 * n + i]) if getattr(plant, "thermal", False) else None,
        )

    def _estimate_error(self, e: Estimate, x: np.ndarray, i: int, vl_k: float) -> np.ndarray:
        """Estimate − truth of follower i: S, V1, V2 [V], gap [m], predecessor speed [m/s]."""
        n, u = self.n, self.ev.units
        v_true = vl_k if i == 0 else float(x[n + i - 1])
        return np.array(
            [
                e.soc - x[4 * n + i],
                e.V1_V - x[2 * n + i],
                e.V2_V - x[3 * n + i],
                e.gap_m - u.length_to_si(x[i]),
                e.lead_speed_mps - u.speed_to_si(v_true),
            ]
        )

    def _hold(self, r: _Run, k: int, K: int, tk: float, t_end: float) -> None:
        """The new commands act from t_k on: check the demand they make right now, then integrate the plant over
        [t_k, t_k + dt] (cut at the leader's breakpoints), keeping only the node sample."""
        plant, out, x = self.plant, r.out, r.out[1][-1][:, -1]
        y0 = plant.samples(np.array([tk]), x[:, None], r.a_cmd)
        ev = plant.check(np.array([tk]), x[:, None], y0)
        if ev is not None:
            r.events.append(ev)
            return
        out[3][-1][:, -1] = y0[:, 0]  # the sample at t_k shows the applied command
        # what the vehicle really applies: the command after its limits (saturation, speed range) at t_k;
        # with an actuator lag the command after saturation (the realised a_act lags behind it)
        r.a_app = y0[r.sampled, 0].copy() if plant.act_row is None else np.clip(r.a_cmd, *r.a_bounds)
        r.applied.append(r.a_app.copy())
        t1 = tk + self.dt if k < K - 1 else t_end
        cuts = [tk] + [b for b in r.bps if tk < b < t1 - 1e-12] + [t1]
        before = len(out[0])
        for a0, b0 in zip(cuts[:-1], cuts[1:]):
            if not plant.advance(a0, b0, out[1][-1][:, -1], out[2][-1][:, -1], r.a_cmd, out, r.events):
                break
        if len(out[0]) - before > 1 and not r.events:  # keep only the node sample (sampled jerk is Δa/dt between nodes)
            for lst in out:
                last = lst[-1]
                del lst[before:]
                lst.append(last)

    def _progress(self, r: _Run, tk: float, t_end: float, progress: ProgressFn) -> None:
        """Report the time reached; a time limit stops the run cleanly (a partial result, flagged by its status)."""
        t_now = float(r.out[0][-1][-1]) if r.out[0][-1].size else tk
        try:
            progress(t_now, t_end)
        except TimeLimitReached as stop:
            r.events.append(
                Event(stop.kind, t_now, -1, f"{stop}; the run covers [0, {t_now:g}] of [0, {t_end:g}] (partial result)")
            )

    def _finish(self, r: _Run) -> SimulationResult:
        """The run's SimulationResult: the samples, each sampled controller's commands, statistics and settings."""
        n, dt, cores, rec = self.n, self.dt, r.cores, r.rec
        ts, xs, _, ys = samples = stack_samples(r.out)
        acc = ys[:n].T.copy()
        for j, i in enumerate(r.sampled):  # node k shows the command held from t_k on (the last node: the last one)
            if r.applied and self.plant.act_row is None:  # (with a lag the samples show the realised a_act itself)
                cmds = np.array([a[j] for a in r.applied])
                m = min(ts.size, cmds.size)
                acc[:m, i] = cmds[:m]
                acc[m:, i] = cmds[m - 1]
        names = [c.name if c is not None else law.name for c, law in zip(self.ctrl, self.laws)]  # type: ignore[union-attr]
        stats = [
            cores[i].stats(c) if c is not None and not isinstance(c, ControlSequence) else None
            for i, c in enumerate(self.ctrl)
        ]
        for i, st in enumerate(stats):
            if st is not None:
                self._add_realism_stats(st, r, i, ts, ys[3 * n] if i == 0 else xs[n + i - 1])
        steps = [
            {
                "solve_ms": (np.asarray(rec[i]["solve"], float) * 1e3).tolist(),
                "iterations": rec[i]["iters"],
                "status": rec[i]["status"],
                "call_ms": (np.asarray(rec[i]["call"]) * 1e3).tolist(),
                "ok": rec[i]["ok"],
            }
            if stats[i] is not None
            else None
            for i in range(n)
        ]
        settings = [  # a sampled controller's settings name its conditioning (aev_ocp.loop)
            cores[i].settings(c) if c is not None else law.describe()  # type: ignore[union-attr]
            for i, (c, law) in enumerate(zip(self.ctrl, self.laws))
        ]
        meta = {
            "dt": dt,
            "controllers": settings,
            "mpc_steps": steps,
            "fallback_law": self.fallback_law.describe(),
            # each sampled controller's conditioning and safety layer, with the steps each stage changed
            "command_stages": [cores[i].describe() if i in cores else None for i in range(n)],
            **self._realism(r.ests),
        }
        return self.plant.result(samples, r.events, names, meta, accel=acc, jerk_sampled=True, solver_stats=stats)

    def _add_realism_stats(self, st: dict[str, Any], r: _Run, i: int, ts: np.ndarray, v_pred: np.ndarray) -> None:
        """Follower i's forecast RMS against its predecessor's speed ``v_pred``, its estimation errors and the
        sensors' and estimator's timings (with degraded sensors), added to its statistics ``st``."""
        u, rec = self.ev.units, r.rec[i]
        st["forecast_rms"] = forecast_rms(ts, v_pred, self.dt, [info.get("v_hat") for info in rec["info"]])
        if r.err[i]:
            st["estimation"] = estimation_errors(np.array(r.err[i]), u.time_to_si(self.dt))
        if r.est_s[i]:  # the sensors' read-out and the estimator's update, and with the controller's call
            te_ms = np.asarray(r.est_s[i], float) * 1e3
            st["estimator_ms_median"] = float(np.median(te_ms))
            st["estimator_plus_call_ms_median"] = float(np.median(te_ms + np.asarray(rec["call"]) * 1e3))

    def _channels(self, x: np.ndarray, vl: float, y: np.ndarray) -> np.ndarray:
        """The true channel values (n, 5) [SI, CHANNELS order] at a node: gap, own speed, predecessor speed, pack
        voltage and current (the cell current of the last sample ``y``, i.e. of the command held up to the node)."""
        n, u, ev = self.n, self.ev.units, self.ev
        v_lead = np.concatenate([[vl], x[n : 2 * n - 1]])
        I = y[n : 2 * n]
        ocv = np.asarray(battery.ocv_function(ev.cell)(np.clip(x[4 * n : 5 * n], 0.0, 1.0).reshape(1, -1))).ravel()
        R_s = np.full(n, ev.cell.R_s_ohm)
        thermal = getattr(self.plant, "thermal", False)
        if thermal or ev.cell.rc_table is not None:  # R_s at each pack temperature (after S in x) and SOC
            R_s = np.array(
                [
                    float(
                        battery.cell_at(
                            ev.cell, float(x[5 * n + i]) if thermal else None, float(np.clip(x[4 * n + i], 0, 1))
                        ).R_s_ohm
                    )
                    for i in range(n)
                ]
            )
        vt = ocv - x[2 * n : 3 * n] - x[3 * n : 4 * n] - R_s * I  # battery.terminal_voltage, vectorised
        return np.column_stack(
            [
                u.length_to_si(x[:n]),
                u.speed_to_si(x[n : 2 * n]),
                u.speed_to_si(v_lead),
                ev.pack.n_series * vt,
                ev.pack.n_parallel * I,
            ]
        )

    def _sensed(
        self, sm: SensorModel, est: Estimator | None, i: int, k: int, tk: float, a_prev: float
    ) -> tuple[np.ndarray, Measurement, Estimate | None]:
        """(z [model], measurement, estimate) of follower i at step k: the estimator's gap, own speed and cell states
        (without an estimator: the measured gap, the measured own speed bridged over its delay with the acceleration
        applied last; the cell's states read exactly when observed)."""
        u = self.ev.units
        a_si = float(u.accel_to_si(a_prev)) if math.isfinite(a_prev) else 0.0
        m = sm.measure(i, u.time_to_si(tk), a_si)
        e: Estimate | None = None
        if est is not None:
            e = est.reset(m) if k == 0 else est.update(m)
            check_estimate(e, est, i, tk, u.time_to_si(tk), m.battery is None)
        if e is not None and math.isfinite(e.speed_mps):
            v = e.speed_mps
        else:
            v = max(m.speed_mps + a_si * sm.sensors.delay("speed"), 0.0)
        gap = e.gap_m if e is not None else m.gap_m
        if m.battery is not None:
            cell = m.battery
        elif e is not None:
            cell = (e.V1_V, e.V2_V, e.soc)
        else:
            raise ParameterError(
                "closed loop: the battery states are not observed (sensors.battery_states_observed "
                "= false) and no estimator is set: pass estimator='ekf' or 'mhe'"
            )
        z = np.array([max(float(u.length_from_si(gap)), 1e-6), float(u.speed_from_si(v)), *cell])
        return z, m, e

    def _realism(self, ests: Sequence[Estimator | None]) -> dict[str, Any]:
        """What the results state about plant ≠ model, sensors and estimators ({} without any)."""
        out: dict[str, Any] = {}
        if self.mismatch is not None:
            out["mismatch"] = self.mismatch.describe(self.ev, self.n)
        if self.sensors is not None:
            out["sensors"] = as_dict(self.sensors)
            out["estimators"] = [e.describe() if e is not None else None for e in ests]
        return out


class EstimateNotFinite(AevOcpError):
    """An estimator returned a NaN or infinite state (the loop stops with an 'estimation_failed' event)."""


def check_estimate(e: Any, est: Any, i: int, t: float, t_s: float, cell: bool) -> None:
    """Refuse what the estimator ``est`` of follower ``i`` returned at t [model] (t_s [s]): a ParameterError if it is
    not an Estimate, :class:`EstimateNotFinite` (naming the field) if its gap, predecessor speed or (``cell``: the
    battery is not measured) cell states are not finite numbers. A NaN gap would turn a law's command into NaN and
    that into full braking without a word."""
    name = getattr(est, "name", type(est).__name__)
    if not isinstance(e, Estimate):
        raise ParameterError(
            f"closed loop: estimator {name!r} of vehicle {i + 1} returned {type(e).__name__} {e!r:.60} at "
            f"t = {t_s:g} s: reset()/update() must return an aev_ocp.estimation.Estimate"
        )
    fields = ("gap_m", "lead_speed_mps") + (("soc", "V1_V", "V2_V") if cell else ())
    for f in fields:
        val = getattr(e, f)
        if not (isinstance(val, numbers.Real) and math.isfinite(val)):
            raise EstimateNotFinite(
                f"estimator {name!r} of vehicle {i + 1} returned Estimate.{f} = {val!r:.40} at t = {t_s:g} s "
                "(not a finite number): the run stops here instead of acting on it"
            )


def estimation_errors(err: np.ndarray, dt_s: float) -> dict[str, float]:
    """Summary of estimate − truth per step (columns S, V1, V2, gap, predecessor speed; the step dt_s [s]): RMS,
    the largest |SOC error| overall and after 60 s and the final one [% SOC], V1/V2 RMS [mV], gap [m] and speed [m/s] RMS."""
    t = dt_s * np.arange(err.shape[0])
    late = err[t >= 60.0, 0]
    rms = np.sqrt(np.mean(err**2, axis=0))
    return {
        "soc_err_rms_pct": 100 * float(rms[0]),
        "soc_err_final_pct": 100 * float(err[-1, 0]),
        "soc_err_max_pct": 100 * float(np.abs(err[:, 0]).max()),
        "soc_err_max_after_60s_pct": 100 * float(np.abs(late).max()) if late.size else float("nan"),
        "V1_err_rms_mV": 1e3 * float(rms[1]),
        "V2_err_rms_mV": 1e3 * float(rms[2]),
        "gap_err_rms_m": float(rms[3]),
        "lead_speed_err_rms_mps": float(rms[4]),
    }


def forecast_rms(t: np.ndarray, v_actual: np.ndarray, dt: float, forecasts: Sequence[np.ndarray | None]) -> float:
    """RMS error [model speed] of the forecasts v̂ made at t_k = k·dt for t_k + j·dt (j = 0, 1, …) against the
    speeds that happened (``v_actual`` sampled at t), over every forecast node inside the run; NaN when no
    controller published forecasts (Command.info["v_hat"])."""
    err: list[np.ndarray] = []
    for k, vh in enumerate(forecasts):
        if vh is None:
            continue
        tj = k * dt + dt * np.arange(len(vh))
        inside = tj <= t[-1] + 1e-9
        err.append(np.asarray(vh, float)[inside] - np.interp(tj[inside], t, v_actual))
    if not err:
        return float("nan")
    e = np.concatenate(err)
    return float(np.sqrt(np.mean(e**2)))


def run_closed_loop(
    leader: LeaderProfile,
    controllers: Sequence[Any],
    gaps0: Sequence[float],
    speeds0: Sequence[float],
    t_end: float,
    *,
    ev: EVParams | None = None,
    soc0: float | Sequence[float] | None = None,
    fallback_law: CarFollowingLaw | None = None,
    progress: ProgressFn | None = None,
    mismatch: Mismatch | None = None,
    sensors: Sensors | None = None,
    estimator: str | EstimatorFactory | None = "ekf",
) -> SimulationResult:
    """Build a :class:`ClosedLoop` and run it once (model units; see the class)."""
    return ClosedLoop(
        leader, controllers, ev, fallback_law, mismatch=mismatch, sensors=sensors, estimator=estimator
    ).run(gaps0, speeds0, t_end, soc0=soc0, progress=progress)

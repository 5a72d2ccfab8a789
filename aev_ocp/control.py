"""Controllers and the closed loop that drives them on the plant.

A follower runs either a car-following law (integrated continuously inside the plant) or a sampled
:class:`Controller`: anything with ``name``, ``dt``, ``reset()`` and ``command(obs) -> Command``.
The MPC (:class:`aev_ocp.mpc.policy.MPCPolicy`), a replayed control sequence
(:class:`ControlSequence`, e.g. OCP-D's optimum), a sampled law (:class:`SampledLaw`) and a
user's own controller (an ACC law, a learned policy) are all Controllers; any vehicle of any
scenario can run any of them. The closed loop (:class:`ClosedLoop`) applies each command as a
zero-order hold over dt on the exact plant (:class:`aev_ocp.plant.Plant`), with the plant's event
rules, and returns the one result type (:class:`aev_ocp.results.SimulationResult`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np

from .models.carfollowing import CarFollowingLaw, Proposed
from .models.leader import LeaderProfile
from .params import EVParams, ParameterError, SimOptions, check_argument
from .plant import Plant
from .progress import TimeLimitReached
from .results import Event, SimulationResult

ProgressFn = Callable[[float, float], None]


@dataclass
class Observation:
    """What follower ``vehicle`` (0-based) knows at time t [model time]: its own state
    z = (h, v, V1, V2, S) (model units, V, -), the measured speeds of its predecessor at the
    sample times so far (oldest first, the last at t), the predecessor's latest plan of node speeds
    at t, t + dt, … when the predecessor publishes one (V2V), the command it applied last (after the
    vehicle's saturation) and, with an actuator lag, its realised acceleration a_act."""

    t: float
    dt: float
    vehicle: int
    z: np.ndarray
    meas_t: np.ndarray
    meas_v: np.ndarray
    predecessor_plan: np.ndarray | None = None
    a_prev: float = 0.0
    a_act: float | None = None  # the realised acceleration at t [model] when the vehicle has an actuator lag


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
    a_min: float = -3.0  # model guide §9
    a_max: float = 2.0  # model guide §9

    @property
    def name(self) -> str:
        return f"{self.law.name}@dt={self.dt:g}"

    def reset(self) -> None:
        """Nothing to forget."""

    def command(self, obs: Observation) -> Command:
        a = float(self.law.function(max(obs.z[0], 1e-6), obs.z[1], obs.meas_v[-1]))
        return Command(min(max(a if math.isfinite(a) else self.a_min, self.a_min), self.a_max))

    def describe(self) -> dict[str, Any]:
        return {"controller": self.name, **self.law.describe()}


# adapters from settings objects to Controllers (the MPC registers MPCSettings and MPCVehicle)
AdapterFn = Callable[[Any, int, "ClosedLoop"], Controller]
_ADAPTERS: dict[type, AdapterFn] = {}


def register_controller_adapter(cls: type, fn: AdapterFn) -> None:
    """Let :class:`ClosedLoop` accept objects of ``cls`` (e.g. MPCSettings) as controllers:
    ``fn(obj, vehicle_index, closed_loop) -> Controller``."""
    _ADAPTERS[cls] = fn


def fallback_causes(status: Sequence[Any], ok: Sequence[bool]) -> dict[str, int]:
    """{cause: count} over the failed steps; a cause is a step's status up to its first ':'."""
    out: dict[str, int] = {}
    for st, k in zip(status, ok):
        if not k:
            c = str(st).split(":")[0].strip() or "unknown"
            out[c] = out.get(c, 0) + 1
    return out


def _stats(rec: dict[str, list[Any]], ctrl: Controller) -> dict[str, Any]:
    ms = np.asarray(rec["solve"], float) * 1e3
    ms = ms[np.isfinite(ms)]
    cm = np.asarray(rec["call"], float) * 1e3
    it = np.asarray(rec["iters"], float)
    ok = ms.size > 0
    d = ctrl.describe()
    return {"solve_ms_median": float(np.median(ms)) if ok else float("nan"),
            "solve_ms_p95": float(np.percentile(ms, 95)) if ok else float("nan"),
            "solve_ms_max": float(ms.max()) if ok else float("nan"),
            "iterations_mean": float(it.mean()) if it.size else float("nan"),
            "iterations_max": int(it.max()) if it.size else 0,
            "fallbacks": int(sum(not k for k in rec["ok"])),
            # cause of each fallback: the status up to its first ':' ('QP failed', 'budget', 'path constraint',
            # 'exception', or the NLP solver's return status)
            "fallback_causes": fallback_causes(rec["status"], rec["ok"]),
            "solver_path": d.get("solver_path", d.get("controller", "")),
            "qp_solver": d.get("qp_in_use", ""),  # the MPC's QP solver that ran ('' for the others)
            "n_steps": len(rec["ok"]),
            # whole controller call: forecast, warm-start shift, parameters, solve, unpacking
            "call_ms_median": float(np.median(cm)) if cm.size else float("nan"),
            "call_ms_p95": float(np.percentile(cm, 95)) if cm.size else float("nan")}


class ClosedLoop:
    """A platoon behind ``leader`` where each follower runs a law (continuous) or a Controller
    (sampled every dt, the same dt for all); build once (controllers and plant), then :meth:`run`.

    controllers[i]: a CarFollowingLaw, a Controller, or an object with a registered adapter
    (MPCSettings, MPCVehicle). fallback_law: the law an MPC applies when a solve fails (default the
    proposed law with the paper's α, β, κ); rtol/atol: plant CVODES tolerances.
    """

    def __init__(self, leader: LeaderProfile, controllers: Sequence[Any], ev: EVParams | None = None,
                 fallback_law: CarFollowingLaw | None = None, rtol: float = 1e-10, atol: float = 1e-10) -> None:
        check_argument("closed loop", "leader", leader, LeaderProfile)
        check_argument("closed loop", "ev", ev, (EVParams, type(None)))
        check_argument("closed loop", "fallback_law", fallback_law, (CarFollowingLaw, type(None)))
        SimOptions(rtol=rtol, atol=atol)  # the plant's tolerances, validated like a scenario's [simulation]
        if len(controllers) < 1:
            raise ParameterError("ClosedLoop: the platoon needs at least one follower (controllers is empty)")
        self.leader, self.ev = leader, ev or EVParams()
        self.fallback_law = fallback_law or Proposed()
        self.n = len(controllers)
        self.laws: list[CarFollowingLaw | None] = []
        self.ctrl: list[Controller | None] = []
        for i, c in enumerate(controllers):
            if isinstance(c, CarFollowingLaw):
                self.laws.append(c)
                self.ctrl.append(None)
                continue
            adapter = next((fn for cls, fn in _ADAPTERS.items() if isinstance(c, cls)), None)
            c = adapter(c, i, self) if adapter is not None else c
            if not isinstance(c, Controller):
                raise ParameterError(f"ClosedLoop: controller of vehicle {i + 1} must be a CarFollowingLaw or a "
                                     f"Controller (name, dt, reset, command, describe), got {type(c).__name__}")
            self.laws.append(None)
            self.ctrl.append(c)
        dts = {c.dt for c in self.ctrl if c is not None}
        if not dts:
            raise ParameterError("ClosedLoop: no sampled controller; use aev_ocp.simulate for closed-form laws only")
        if len(dts) != 1:
            raise ParameterError(f"ClosedLoop: every sampled controller must use the same dt, got {sorted(dts)}")
        self.dt = dts.pop()
        self.rtol, self.atol = rtol, atol
        self.plant = Plant(leader, self.laws, self.ev, rtol=rtol, atol=atol)

    def run(self, gaps0: Sequence[float], speeds0: Sequence[float], t_end: float, *,
            soc0: float | Sequence[float] | None = None, progress: ProgressFn | None = None) -> SimulationResult:
        """Closed loop over [0, t_end] (model time, a multiple of dt) from the initial gaps and speeds
        (model units), V1 = V2 = 0 and S = soc0 (default the cell's S(0)). ``progress(t, t_end)`` is called
        after every step; if it raises :class:`aev_ocp.progress.TimeLimitReached` the loop stops there and
        the result, covering [0, t], ends with an event of kind 'time_limit' (its status)."""
        n, dt, plant = self.n, self.dt, self.plant
        if not (isinstance(t_end, (int, float)) and math.isfinite(t_end) and t_end > 0):
            raise ParameterError(f"closed loop: t_end = {t_end!r} must be > 0")
        K = int(round(t_end / dt))
        if K < 1 or abs(K * dt - t_end) > 1e-9 * max(1.0, t_end):
            raise ParameterError(f"closed loop: t_end = {t_end} must be a multiple of dt = {dt}")
        for i, c in enumerate(self.ctrl):
            if isinstance(c, ControlSequence) and len(c.a) < K:
                raise ParameterError(f"closed loop: the control sequence of vehicle {i + 1} has {len(c.a)} "
                                     f"values, {K} steps are needed")
        x = plant.initial_state(gaps0, speeds0, soc0, "closed loop")
        for c in self.ctrl:
            if c is not None:
                c.reset()
        sampled = [i for i, c in enumerate(self.ctrl) if c is not None]
        q = np.zeros(plant.nq)
        a_cmd = np.zeros(len(sampled))
        a_app = np.zeros(len(sampled))  # the commands as the plant applied them (saturated) at the last node
        a_bounds = self.ev.limits.accel_bounds_model(self.ev.units)
        y = plant.samples(np.array([0.0]), x[:, None], a_cmd)
        out: tuple[list, list, list, list] = ([np.array([0.0])], [x[:, None]], [q[:, None]], [y])
        applied: list[np.ndarray] = []
        rec: list[dict[str, list[Any]]] = [{"solve": [], "call": [], "iters": [], "ok": [], "status": [], "info": []} for _ in range(n)]
        meas_t: list[float] = []
        meas_v: list[list[float]] = [[] for _ in range(n)]
        events: list[Event] = []
        bps = [b for b in self.leader.breakpoints if 0 < b < t_end]
        ev0 = plant.check(np.array([0.0]), x[:, None], y)
        if ev0 is not None:
            events.append(ev0)
        k = 0
        while k < K and not events:
            tk = k * dt
            x = out[1][-1][:, -1]
            vl_k = float(self.leader.speed_np(tk)[0])
            meas_t.append(tk)
            for i in range(n):
                meas_v[i].append(vl_k if i == 0 else float(x[n + i - 1]))
            plans: list[np.ndarray | None] = [None] * n
            for j, i in enumerate(sampled):
                ctrl = self.ctrl[i]
                assert ctrl is not None
                obs = Observation(tk, dt, i, x[[i, n + i, 2 * n + i, 3 * n + i, 4 * n + i]], np.asarray(meas_t),
                                  np.asarray(meas_v[i]), plans[i - 1] if i > 0 else None, float(a_app[j]),
                                  None if plant.act_row is None else float(x[plant.act_row + i]))
                tc = time.perf_counter()
                cmd = ctrl.command(obs)
                rec[i]["call"].append(time.perf_counter() - tc)
                for key, val in (("solve", cmd.solve_time_s), ("iters", cmd.iterations), ("ok", cmd.ok),
                                 ("status", cmd.status), ("info", cmd.info)):
                    rec[i][key].append(val)
                a_cmd[j] = cmd.a
                plans[i] = cmd.plan
            # the new commands act from t_k on: check the demand they make right now, then integrate
            y0 = plant.samples(np.array([tk]), x[:, None], a_cmd)
            ev = plant.check(np.array([tk]), x[:, None], y0)
            if ev is not None:
                events.append(ev)
                break
            out[3][-1][:, -1] = y0[:, 0]  # the sample at t_k shows the applied command
            # what the vehicle really applies: the command after its limits (saturation, speed range) at t_k;
            # with an actuator lag the command after saturation (the realised a_act lags behind it)
            a_app = y0[sampled, 0].copy() if plant.act_row is None else np.clip(a_cmd, *a_bounds)
            applied.append(a_app.copy())
            t1 = tk + dt if k < K - 1 else t_end
            cuts = [tk] + [b for b in bps if tk < b < t1 - 1e-12] + [t1]
            before = len(out[0])
            for a0, b0 in zip(cuts[:-1], cuts[1:]):
                if not plant.advance(a0, b0, out[1][-1][:, -1], out[2][-1][:, -1], a_cmd, out, events):
                    break
            if len(out[0]) - before > 1 and not events:  # keep only the node sample (sampled jerk is Δa/dt between nodes)
                for lst in out:
                    last = lst[-1]
                    del lst[before:]
                    lst.append(last)
            k += 1
            if progress is not None and not events:
                t_now = float(out[0][-1][-1]) if out[0][-1].size else tk
                try:
                    progress(t_now, t_end)
                except TimeLimitReached as stop:  # stop cleanly: a partial result, flagged by its status
                    events.append(Event(stop.kind, t_now, -1, f"{stop}; the run covers [0, {t_now:g}] of "
                                                              f"[0, {t_end:g}] (partial result)"))
        ts, xs, qs, ys = (np.concatenate(out[0]), np.hstack(out[1]), np.hstack(out[2]), np.hstack(out[3]))
        acc = ys[:n].T.copy()
        for j, i in enumerate(sampled):  # node k shows the command held from t_k on (the last node: the last one)
            if applied and plant.act_row is None:  # (with a lag the samples show the realised a_act itself)
                cmds = np.array([a[j] for a in applied])
                m = min(ts.size, cmds.size)
                acc[:m, i] = cmds[:m]
                acc[m:, i] = cmds[m - 1]
        names = [c.name if c is not None else law.name for c, law in zip(self.ctrl, self.laws)]  # type: ignore[union-attr]
        stats = [_stats(rec[i], c) if c is not None and not isinstance(c, ControlSequence) else None
                 for i, c in enumerate(self.ctrl)]
        for i, st in enumerate(stats):
            if st is not None:
                v_pred = ys[3 * n] if i == 0 else xs[n + i - 1]
                st["forecast_rms"] = forecast_rms(ts, v_pred, dt, [info.get("v_hat") for info in rec[i]["info"]])
        steps = [{"solve_ms": (np.asarray(rec[i]["solve"], float) * 1e3).tolist(), "iterations": rec[i]["iters"],
                  "status": rec[i]["status"], "call_ms": (np.asarray(rec[i]["call"]) * 1e3).tolist(),
                  "ok": rec[i]["ok"]} if stats[i] is not None else None for i in range(n)]
        settings = [c.describe() if c is not None else law.describe()  # type: ignore[union-attr]
                    for c, law in zip(self.ctrl, self.laws)]
        return plant.result(ts, xs, qs, ys, events, names,
                            {"dt": dt, "controllers": settings, "mpc_steps": steps,
                             "fallback_law": self.fallback_law.describe()},
                            accel=acc, jerk_sampled=True, solver_stats=stats)


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


def run_closed_loop(leader: LeaderProfile, controllers: Sequence[Any], gaps0: Sequence[float],
                    speeds0: Sequence[float], t_end: float, *, ev: EVParams | None = None,
                    soc0: float | Sequence[float] | None = None, fallback_law: CarFollowingLaw | None = None,
                    progress: ProgressFn | None = None) -> SimulationResult:
    """Build a :class:`ClosedLoop` and run it once (model units; see the class)."""
    return ClosedLoop(leader, controllers, ev, fallback_law).run(gaps0, speeds0, t_end, soc0=soc0, progress=progress)

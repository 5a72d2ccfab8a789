"""Closed-loop simulation of MPC followers (and closed-form-law followers) with the exact plant.

Plant (PROBLEM.md §9): the exact model — unsmoothed η switch, exact current map
(:func:`aev_ocp.simulate.cell_rates_function`) — of every follower, integrated by ONE CasADi CVODES
integrator over each control interval dt (normalised time: dx/ds = L·f(t0 + L s, x), parameters
(t0, L, a_cmd)). An MPC vehicle's acceleration is its applied control, constant over the interval;
a closed-form-law vehicle follows its law's continuous acceleration inside the same integrator.
The leader moves by its true profile; intervals are split at the leader's breakpoints. The same
quadratures as :mod:`aev_ocp.simulate` are integrated (ω = ∫ v g(a), pack ∫Q, ∫Q_irr, ∫(V(h) − v)²,
∫(v_l − v)², ∫ jerk² of the laws), so the §10 metrics are exact across control jumps.

Per step and MPC vehicle: solve wall time, iterations, status; a failed solve applies the proposed
closed-form law (α, β, κ of the scenario, measured predecessor speed v_l(t_k), clipped to the a
bounds) for that step and is counted as a fallback. Collision, negative speed, infeasible current
(E² < 4 R_s P_c) and S leaving [0, 1] are reported as Events and stop the run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from ..models import energy
from ..models.carfollowing import CarFollowingLaw, Proposed, optimal_velocity
from ..models.leader import LeaderProfile
from ..params import EVParams, ParameterError, as_dict
from ..results import Event, SimulationResult
from ..simulate import cell_rates_function
from .controller import MPCController, MPCSolution
from .predictors import (LeaderPredictor, Measurements, forecast_intervals, make_predictor, plan_forecast)
from .settings import MPCSettings

ProgressFn = Callable[[float, float], None]


@dataclass
class MPCVehicle:
    """An MPC follower: its settings and, optionally, its own predictor (default: settings.predictor;
    'cooperative' = the predecessor's last MPC plan)."""

    settings: MPCSettings = field(default_factory=MPCSettings)
    predictor: LeaderPredictor | str | None = None


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
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"ControlSequence.dt = {self.dt!r} is not allowed: must be > 0")


Controller = MPCVehicle | MPCSettings | CarFollowingLaw | ControlSequence


def _stats(times_s: list[float], iters: list[int], fallbacks: int, path: str, n: int,
           codegen: bool, call_s: list[float] | None = None) -> dict[str, Any]:
    ms = np.asarray(times_s, float) * 1e3
    cm = np.asarray(call_s if call_s is not None else [], float) * 1e3
    it = np.asarray(iters, float)
    ok = ms.size > 0
    return {"solve_ms_median": float(np.median(ms)) if ok else float("nan"),
            "solve_ms_p95": float(np.percentile(ms, 95)) if ok else float("nan"),
            "solve_ms_max": float(ms.max()) if ok else float("nan"),
            "iterations_mean": float(it.mean()) if ok else float("nan"),
            "iterations_max": int(it.max()) if ok else 0,
            "fallbacks": int(fallbacks), "solver_path": path + ("+codegen" if codegen else ""),
            "n_steps": int(n),
            # whole controller call (forecast excluded): warm-start shift, parameters, solve, unpacking
            "call_ms_median": float(np.median(cm)) if cm.size else float("nan"),
            "call_ms_p95": float(np.percentile(cm, 95)) if cm.size else float("nan")}


class ClosedLoop:
    """A platoon behind ``leader`` where each follower is an MPC (``MPCVehicle`` or ``MPCSettings``)
    or a closed-form law; build once (controllers and plant), then :meth:`run`.

    fallback_law: the law applied when an MPC solve fails (default the proposed law with the paper's
    α, β, κ); rtol/atol: plant CVODES tolerances.
    """

    def __init__(self, leader: LeaderProfile, controllers: Sequence[Controller], ev: EVParams | None = None,
                 fallback_law: CarFollowingLaw | None = None, rtol: float = 1e-10, atol: float = 1e-10) -> None:
        if len(controllers) < 1:
            raise ParameterError("ClosedLoop: the platoon needs at least one follower (controllers is empty)")
        self.leader, self.ev = leader, ev or EVParams()
        self.fallback_law = fallback_law or Proposed()
        self.n = len(controllers)
        self.kinds: list[str] = []
        self.vehicles: list[MPCVehicle | None] = []
        self.laws: list[CarFollowingLaw | None] = []
        self.sequences: list[ControlSequence | None] = []
        for i, c in enumerate(controllers):
            if isinstance(c, MPCSettings):
                c = MPCVehicle(c)
            self.vehicles.append(c if isinstance(c, MPCVehicle) else None)
            self.laws.append(c if isinstance(c, CarFollowingLaw) else None)
            self.sequences.append(c if isinstance(c, ControlSequence) else None)
            if not isinstance(c, (MPCVehicle, CarFollowingLaw, ControlSequence)):
                raise ParameterError(f"ClosedLoop: controller of vehicle {i + 1} must be MPCVehicle, MPCSettings, "
                                     f"ControlSequence or a CarFollowingLaw, got {type(c).__name__}")
        dts = {v.settings.dt for v in self.vehicles if v is not None} | {q.dt for q in self.sequences if q is not None}
        if not dts:
            raise ParameterError("ClosedLoop: no MPC follower or control sequence; use aev_ocp.simulate for "
                                 "closed-form laws only")
        if len(dts) != 1:
            raise ParameterError(f"ClosedLoop: every MPC follower and control sequence must use the same dt, "
                                 f"got {sorted(dts)}")
        self.dt = dts.pop()
        self.predictors: list[LeaderPredictor | str | None] = []
        for i in range(self.n):
            veh = self.vehicles[i]
            if veh is None:
                self.predictors.append(None)
                continue
            p = veh.predictor if veh.predictor is not None else veh.settings.predictor
            if isinstance(p, str):
                if p == "cooperative":
                    if i == 0 or self.vehicles[i - 1] is None:
                        raise ParameterError(f"vehicle {i + 1}: predictor 'cooperative' needs an MPC vehicle ahead")
                elif p == "oracle" and i > 0:
                    raise ParameterError(f"vehicle {i + 1}: predictor 'oracle' is only available to the first "
                                         "follower (use 'cooperative' behind an MPC vehicle, or a measured predictor)")
                else:
                    p = make_predictor(p, leader, veh.settings.predictor_window)
            self.predictors.append(p)
        self.ctrl: list[MPCController | None] = [
            MPCController(v.settings, self.ev, self.fallback_law) if v is not None else None for v in self.vehicles]
        self.rtol, self.atol = rtol, atol
        self._build_plant()

    def _build_plant(self) -> None:
        n, ev, T = self.n, self.ev, self.ev.units.time_s
        h, v = ca.SX.sym("h", n), ca.SX.sym("v", n)
        V1, V2, S = ca.SX.sym("V1", n), ca.SX.sym("V2", n), ca.SX.sym("S", n)
        s, p = ca.SX.sym("s"), ca.SX.sym("p", 2 + n)  # normalised time; (t0, L, a_cmd)
        t = p[0] + p[1] * s
        vl = self.leader.speed(t)
        v_lead = ca.vertcat(vl, v[:-1]) if n > 1 else vl
        a = ca.SX.zeros(n)
        for i in range(n):
            law = self.laws[i]
            a[i] = p[2 + i] if law is None else law.accel(h[i], v[i], v_lead[i])
        hdot = v_lead - v
        jerk = ca.jtimes(a, ca.vertcat(h, v), ca.vertcat(hdot, a)) + ca.jacobian(a, s) / p[1]
        cr = cell_rates_function(ev).map(n)(v.T, a.T, V1.T, V2.T, S.T)
        dV1, dV2, dS, qW, qirrW, I, disc = (c.T for c in cr)
        X = ca.vertcat(h, v, V1, V2, S)
        ode = ca.vertcat(hdot, a, T * dV1, T * dV2, T * dS)
        quad = ca.vertcat(v * energy.g_exact(a, ev.vehicle.efficiency), (optimal_velocity(h) - v) ** 2, hdot**2,
                          jerk**2, T * qW, T * qirrW)
        dae = {"x": X, "p": p, "t": s, "ode": p[1] * ode, "quad": p[1] * quad}
        self.plant = ca.integrator("mpc_plant", "cvodes", dae, 0.0, 1.0,
                                   {"abstol": self.atol, "reltol": self.rtol, "max_num_steps": 100000,
                                    "quad_err_con": True, "disable_internal_warnings": True,
                                    "show_eval_warnings": False})
        tt = ca.SX.sym("t")
        self.samples = ca.Function("mpc_samples", [tt, X, p], [ca.substitute(ca.vertcat(a, I, disc, vl), s, 0)])
        self._tsym = tt

    def _sample(self, t: float, x: np.ndarray, acmd: np.ndarray) -> np.ndarray:
        return np.asarray(self.samples(t, x, np.concatenate([[t, 1.0], acmd]))).ravel()

    def _forecast(self, i: int, tk: float, meas_t: list[float], meas_v: list[list[float]],
                  plans: list[np.ndarray | None], N: int) -> tuple[np.ndarray, np.ndarray]:
        p = self.predictors[i]
        if p == "cooperative":
            plan = plans[i - 1]
            if plan is not None:
                return forecast_intervals(*plan_forecast(plan, self.dt, N), self.dt)
            p = make_predictor("constant-velocity")  # predecessor fell back this step: no plan
        assert isinstance(p, LeaderPredictor)
        m = Measurements(np.asarray(meas_t), np.asarray(meas_v[i]))
        return forecast_intervals(*p.predict(tk, self.dt, N, m), self.dt)

    def run(self, gaps0: Sequence[float], speeds0: Sequence[float], t_end: float, *,
            soc0: float | Sequence[float] | None = None, progress: ProgressFn | None = None) -> SimulationResult:
        """Closed loop over [0, t_end] (model time, a multiple of dt) from the initial gaps and speeds
        (model units), V1 = V2 = 0 and S = soc0 (default the cell's S(0))."""
        n, dt = self.n, self.dt
        h0, v0 = np.asarray(gaps0, float).ravel(), np.asarray(speeds0, float).ravel()
        if h0.size != n or v0.size != n:
            raise ParameterError(f"closed loop: gaps0 and speeds0 need {n} values, got {h0.size} and {v0.size}")
        if not np.all(np.isfinite(h0)) or np.any(h0 <= 0):
            raise ParameterError(f"closed loop: initial gaps must be > 0, got {h0.tolist()}")
        if not np.all(np.isfinite(v0)) or np.any(v0 < 0):
            raise ParameterError(f"closed loop: initial speeds must be >= 0, got {v0.tolist()}")
        if not (isinstance(t_end, (int, float)) and math.isfinite(t_end) and t_end > 0):
            raise ParameterError(f"closed loop: t_end = {t_end!r} must be > 0")
        K = int(round(t_end / dt))
        if K < 1 or abs(K * dt - t_end) > 1e-9 * max(1.0, t_end):
            raise ParameterError(f"closed loop: t_end = {t_end} must be a multiple of dt = {dt}")
        for i, seq in enumerate(self.sequences):
            if seq is not None and len(seq.a) < K:
                raise ParameterError(f"closed loop: the control sequence of vehicle {i + 1} has {len(seq.a)} "
                                     f"values, {K} steps are needed")
        s0 = np.broadcast_to(np.asarray(self.ev.cell.soc0 if soc0 is None else soc0, float), (n,))
        x = np.concatenate([h0, v0, np.zeros(n), np.zeros(n), s0])
        q = np.zeros(6 * n)
        for c in self.ctrl:
            if c is not None:
                c.reset()
        bps = [b for b in self.leader.breakpoints if 0 < b < t_end]
        ts, xs, qs, acc, cur = [0.0], [x.copy()], [q.copy()], [], []
        meas_t: list[float] = []
        meas_v: list[list[float]] = [[] for _ in range(n)]
        solve_t: list[list[float]] = [[] for _ in range(n)]
        call_t: list[list[float]] = [[] for _ in range(n)]
        iters: list[list[int]] = [[] for _ in range(n)]
        status: list[list[str]] = [[] for _ in range(n)]
        fallbacks = [0] * n
        plans_last: list[np.ndarray | None] = [None] * n
        events: list[Event] = []
        a_cmd = np.zeros(n)
        ev = self._check(0.0, x, None)
        if ev is not None:
            events.append(ev)
        k = 0
        while k < K and not events:
            tk = k * dt
            vl_k = float(self.leader.speed_np(tk)[0])
            meas_t.append(tk)
            for i in range(n):
                meas_v[i].append(vl_k if i == 0 else float(x[n + i - 1]))
            plans: list[np.ndarray | None] = [None] * n
            for i in range(n):
                seq = self.sequences[i]
                if seq is not None:
                    a_cmd[i] = seq.a[k]
                ctrl = self.ctrl[i]
                if ctrl is None:
                    continue
                z = x[[i, n + i, 2 * n + i, 3 * n + i, 4 * n + i]]
                vm, vh = self._forecast(i, tk, meas_t, meas_v, plans, ctrl.settings.N)
                tc = time.perf_counter()
                sol: MPCSolution = ctrl.solve(z, vm, vh)
                call_t[i].append(time.perf_counter() - tc)
                solve_t[i].append(sol.solve_time_s)
                iters[i].append(sol.iterations)
                status[i].append(sol.status)
                if sol.success:
                    a_cmd[i] = sol.a[0]
                    plans[i] = sol.X[1]
                else:
                    b = ctrl.settings.bounds
                    af = float(self.fallback_law.function(max(z[0], 1e-6), z[1], meas_v[i][-1]))
                    a_cmd[i] = min(max(af if math.isfinite(af) else b.a_min, b.a_min), b.a_max)
                    fallbacks[i] += 1
            plans_last = plans
            y0 = self._sample(tk, x, a_cmd)
            cuts = [tk] + [b for b in bps if tk < b < tk + dt - 1e-12] + [tk + dt if k < K - 1 else t_end]
            ok = True
            for a0, b0 in zip(cuts[:-1], cuts[1:]):
                try:
                    out = self.plant(x0=x, p=np.concatenate([[a0, b0 - a0], a_cmd]))
                except RuntimeError as exc:
                    hmin = int(np.argmin(x[:n]))
                    near = " (near collision)" if x[hmin] < 0.05 else ""
                    events.append(Event("integration_failed", a0, hmin, f"CVODES failed on [{a0:.4f}, {b0:.4f}] "
                                        f"with gap h = {x[hmin]:.3g}{near} ({str(exc).splitlines()[0][:120]})"))
                    ok = False
                    break
                x = np.asarray(out["xf"]).ravel()
                q = q + np.asarray(out["qf"]).ravel()
            if not ok:
                break
            t1 = cuts[-1]
            y1 = self._sample(t1, x, a_cmd)
            acc.append(y0[:n])
            cur.append(y0[n:2 * n])
            ts.append(t1)
            xs.append(x.copy())
            qs.append(q.copy())
            ev = self._check(t1, x, (tk, xs[-2], y0, y1))
            if ev is not None:
                events.append(ev)
            k += 1
            if progress is not None:
                progress(t1, t_end)
        # samples at the last node: the last applied control (laws: their acceleration there)
        y_last = self._sample(ts[-1], xs[-1], a_cmd)
        acc.append(y_last[:n])
        cur.append(y_last[n:2 * n])
        return self._assemble(np.array(ts), np.array(xs), np.array(qs), np.array(acc), np.array(cur), events,
                              solve_t, iters, status, fallbacks, plans_last, call_t)

    def _check(self, t1: float, x: np.ndarray, prev: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None) -> Event | None:
        n = self.n
        h, v, S = x[:n], x[n:2 * n], x[4 * n:5 * n]
        t0 = prev[0] if prev is not None else t1

        def tcross(a0: float, a1: float) -> float:
            return t0 + (t1 - t0) * a0 / (a0 - a1) if a0 > 0 >= a1 and a0 != a1 else t1

        for i in range(n):
            if h[i] <= 0:
                return Event("collision", tcross(prev[1][i], h[i]) if prev else t1, i, f"gap h reached 0 (h = {h[i]:.4g})")
            if v[i] < -1e-9:
                return Event("negative_speed", tcross(prev[1][n + i], v[i]) if prev else t1, i,
                             f"speed became negative (v = {v[i]:.4g})")
            if prev is not None:
                d0, d1 = prev[2][2 * n + i], prev[3][2 * n + i]
                if min(d0, d1) < 0:
                    return Event("infeasible_current", t0 if d0 < 0 else t1, i,
                                 "cell cannot deliver the power demand (E² < 4 R_s P_c)")
            if not 0.0 <= S[i] <= 1.0:
                return Event("soc_out_of_range", t1, i, f"state of charge left [0, 1] (S = {S[i]:.4g})")
        return None

    def _assemble(self, t: np.ndarray, X: np.ndarray, Q: np.ndarray, A: np.ndarray, I: np.ndarray,
                  events: list[Event], solve_t: list[list[float]], iters: list[list[int]], status: list[list[str]],
                  fallbacks: list[int], plans: list[np.ndarray | None],
                  call_t: list[list[float]] | None = None) -> SimulationResult:
        n = self.n
        cols = lambda M, j: M[:, j * n:(j + 1) * n]  # noqa: E731
        names, stats, steps = [], [], []
        for i in range(n):
            c = self.ctrl[i]
            if c is None:
                seq = self.sequences[i]
                names.append(seq.name if seq is not None else self.laws[i].name)  # type: ignore[union-attr]
                stats.append(None)
                steps.append(None)
                continue
            s = c.settings
            names.append(f"mpc(w_Q={s.weights.w_Q:g})")
            ct = call_t[i] if call_t is not None else None
            stats.append(_stats(solve_t[i], iters[i], fallbacks[i], s.solver, len(solve_t[i]), c.codegen_active,
                                ct))
            steps.append({"solve_ms": (np.asarray(solve_t[i]) * 1e3).tolist(), "iterations": iters[i],
                          "status": status[i], "call_ms": (np.asarray(ct or []) * 1e3).tolist()})
        settings = []
        for i in range(n):
            v = self.vehicles[i]
            if self.sequences[i] is not None:
                settings.append({"controller": self.sequences[i].name, "dt": self.dt})  # type: ignore[union-attr]
            elif v is None:
                settings.append(self.laws[i].describe())  # type: ignore[union-attr]
            else:
                d = as_dict(v.settings)
                p = self.predictors[i]
                d["predictor"] = p if isinstance(p, str) else getattr(p, "name", type(p).__name__)
                settings.append(d)
        return SimulationResult(
            t=t, leader_speed=self.leader.speed_np(t), leader_position=np.asarray(self.leader.position(t), float),
            gap=cols(X, 0), speed=cols(X, 1), accel=A, V1=cols(X, 2), V2=cols(X, 3), S=cols(X, 4), current_A=I,
            omega=cols(Q, 0), int_ovm_err2=cols(Q, 1), int_rel_speed2=cols(Q, 2), int_jerk2=cols(Q, 3),
            heat_J=cols(Q, 4), heat_irr_J=cols(Q, 5), controllers=names, ev=self.ev, events=events,
            jerk_sampled=True, solver_stats=stats,
            meta={"plant": "cvodes, exact eta switch", "rtol": self.rtol, "atol": self.atol, "dt": self.dt,
                  "leader": self.leader.describe(), "controllers": settings, "mpc_steps": steps,
                  "fallback_law": self.fallback_law.describe()})


def run_closed_loop(leader: LeaderProfile, controllers: Sequence[Controller], gaps0: Sequence[float],
                    speeds0: Sequence[float], t_end: float, *, ev: EVParams | None = None,
                    soc0: float | Sequence[float] | None = None, fallback_law: CarFollowingLaw | None = None,
                    progress: ProgressFn | None = None) -> SimulationResult:
    """Build a :class:`ClosedLoop` and run it once (model units; see the class)."""
    return ClosedLoop(leader, controllers, ev, fallback_law).run(gaps0, speeds0, t_end, soc0=soc0, progress=progress)


def run_single(settings: MPCSettings | None = None, leader: LeaderProfile | None = None, h0: float = 0.3,
               v0: float = 1.87, t_end: float = 70.0, ev: EVParams | None = None,
               fallback_law: CarFollowingLaw | None = None) -> SimulationResult:
    """One MPC follower (defaults: the canonical MPC scenario of PROBLEM.md §9)."""
    from ..models.leader import PaperLeader

    return run_closed_loop(leader or PaperLeader(), [settings or MPCSettings()], [h0], [v0], t_end, ev=ev,
                           fallback_law=fallback_law)

"""Platoon simulation with closed-form car-following laws and each vehicle's battery in the loop.

The platoon's ODE is one CasADi SX expression integrated by CVODES. State per follower:
gap h, speed v (model units), and the cell's V1, V2 [V], S [-]; quadratures per follower: the
paper's ω, pack ∫Q and ∫Q_irr [J], and the integrals of squared tracking errors and jerk.

Time is normalised inside the integrator (dx/ds = L·f(t0 + L s, x), s ∈ [0, 1], parameters
p = (t0, L)), so ONE integrator Function serves every interval: the timeline is split exactly at
the leader's breakpoints (e.g. the paper leader's t = 20) and into chunks between them, and after
each chunk the samples are checked for collision (h ≤ 0), negative speed, an infeasible current
demand (E² < 4 R_s P_c) and S leaving [0, 1]. The first such event stops the run and is reported
with its time and vehicle — nothing is integrated through.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from .models import battery, energy
from .models.carfollowing import CarFollowingLaw, optimal_velocity
from .models.leader import LeaderProfile
from .models.powertrain import cell_current_from_motion
from .params import EVParams, ParameterError
from .results import Event, SimulationResult

ProgressFn = Callable[[float, float], None]


@dataclass(frozen=True)
class SimOptions:
    """Integration settings. dt_out: largest sample spacing [model time]; rtol/atol: CVODES
    tolerances; chunk: nominal length between event checks [model time]."""

    dt_out: float = 0.01
    rtol: float = 1e-10
    atol: float = 1e-10
    chunk: float = 5.0
    max_num_steps: int = 200_000

    def __post_init__(self) -> None:
        for name in ("dt_out", "rtol", "atol", "chunk"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"SimOptions.{name} = {v!r} is not allowed: must be a finite number > 0")


def cell_rates(v: Any, a: Any, V1: Any, V2: Any, S: Any, ev: EVParams) -> dict[str, Any]:
    """Battery side of one vehicle for model speed v and acceleration a (exact η switch).

    Returns dV1, dV2 [V/s], dS [1/s], heat_W and heat_irr_W (pack [W]), I [A], disc [V²].
    """
    u = ev.units
    # S is clamped to the OCV table's range and the discriminant floored at 1e-12 V² inside the
    # right-hand side only, so that the integrator stays finite up to an event; the simulator checks
    # the true S and discriminant at every sample and stops at the first violation.
    S_in = ca.fmin(ca.fmax(S, 0.0), 1.0)
    cm = cell_current_from_motion(u.speed_to_si(v), u.accel_to_si(a), V1, V2, S_in, ev)
    I = 2.0 * cm["P_c"] / (cm["E"] + ca.sqrt(ca.fmax(cm["disc"], 1e-12)))
    dV1, dV2, dS = battery.cell_derivatives(V1, V2, I, ev.cell)
    n = ev.pack.n_cells
    return {"dV1": dV1, "dV2": dV2, "dS": dS, "I": I, "disc": cm["disc"],
            "heat_W": n * battery.heat_Q(V1, V2, I, ev.cell),
            "heat_irr_W": n * battery.heat_irreversible(V1, V2, I, ev.cell)}


def cell_rates_function(ev: EVParams) -> ca.Function:
    """:func:`cell_rates` as a scalar SX Function (v, a, V1, V2, S) -> (dV1, dV2, dS, heat_W, heat_irr_W, I, disc)."""
    v, a, V1, V2, S = (ca.SX.sym(n) for n in ("v", "a", "V1", "V2", "S"))
    r = cell_rates(v, a, V1, V2, S, ev)
    names = ["dV1", "dV2", "dS", "heat_W", "heat_irr_W", "I", "disc"]
    return ca.Function("cell_rates", [v, a, V1, V2, S], [r[k] for k in names],
                       ["v", "a", "V1", "V2", "S"], names)


def _segments(t_end: float, breakpoints: Sequence[float], chunk: float) -> list[tuple[float, float]]:
    """Intervals covering [0, t_end], split exactly at breakpoints and into pieces of length ≤ chunk."""
    cuts = [0.0] + sorted(b for b in breakpoints if 0.0 < b < t_end) + [t_end]
    out: list[tuple[float, float]] = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        m = max(1, math.ceil((b - a) / chunk - 1e-9))
        edges = np.linspace(a, b, m + 1)
        out.extend(zip(edges[:-1].tolist(), edges[1:].tolist()))
    return out


class PlatoonSimulator:
    """A platoon behind ``leader`` with one law per follower; build once, run many initial conditions.

    Vehicle i (0-based) follows vehicle i − 1; vehicle 0 follows the leader.
    """

    def __init__(self, leader: LeaderProfile, laws: Sequence[CarFollowingLaw], ev: EVParams | None = None,
                 options: SimOptions | None = None, battery: bool = True) -> None:
        if len(laws) < 1:
            raise ParameterError("simulate: the platoon needs at least one follower (laws is empty)")
        self.leader, self.laws = leader, list(laws)
        self.ev = ev or EVParams()
        self.opts = options or SimOptions()
        self.battery = battery
        self.n = len(self.laws)
        self.k = max(1, math.ceil(self.opts.chunk / self.opts.dt_out - 1e-9))
        self._build()

    # ------------------------------------------------------------------ symbolic model
    def _accel_expr(self, h: ca.SX, v: ca.SX, v_lead: ca.SX) -> ca.SX:
        """Accelerations of all followers, vectorised over groups of followers with the same law."""
        a = ca.SX.zeros(self.n)
        groups: dict[CarFollowingLaw, list[int]] = {}
        for i, law in enumerate(self.laws):
            groups.setdefault(law, []).append(i)
        for law, idx in groups.items():
            a[idx] = law.accel(h[idx], v[idx], v_lead[idx])
        return a

    def _build(self) -> None:
        n, ev, T = self.n, self.ev, self.ev.units.time_s
        h, v = ca.SX.sym("h", n), ca.SX.sym("v", n)
        s, p = ca.SX.sym("s"), ca.SX.sym("p", 2)  # normalised time, (t0, L)
        t = p[0] + p[1] * s
        vl = self.leader.speed(t)
        v_lead = ca.vertcat(vl, v[:-1]) if n > 1 else vl
        a = self._accel_expr(h, v, v_lead)
        hdot = v_lead - v
        # jerk = da/dt by the chain rule (forward AD), including the leader's explicit time dependence
        jerk = (ca.jtimes(a, ca.vertcat(h, v), ca.vertcat(hdot, a)) + ca.jacobian(a, s) / p[1])
        eta = ev.vehicle.efficiency
        x = [h, v]
        ode = [hdot, a]
        quad = [v * energy.g_exact(a, eta), (optimal_velocity(h) - v) ** 2, hdot**2, jerk**2]
        if self.battery:
            V1, V2, S = ca.SX.sym("V1", n), ca.SX.sym("V2", n), ca.SX.sym("S", n)
            cr = cell_rates_function(ev).map(n)(v.T, a.T, V1.T, V2.T, S.T)
            dV1, dV2, dS, qW, qirrW, I, disc = (c.T for c in cr)
            x += [V1, V2, S]
            ode += [T * dV1, T * dV2, T * dS]
            quad += [T * qW, T * qirrW]
        else:
            I = disc = ca.SX.zeros(n)
        X, Qd = ca.vertcat(*x), ca.vertcat(*quad)
        dae = {"x": X, "p": p, "t": s, "ode": p[1] * ca.vertcat(*ode), "quad": p[1] * Qd}
        grid = np.linspace(0.0, 1.0, self.k + 1)[1:].tolist()
        iopts = {"abstol": self.opts.atol, "reltol": self.opts.rtol, "max_num_steps": self.opts.max_num_steps,
                 "quad_err_con": True, "disable_internal_warnings": True,
                 "show_eval_warnings": False}
        self.integrator = ca.integrator("platoon", "cvodes", dae, 0.0, grid, iopts)
        tt = ca.SX.sym("t")
        sample = ca.Function("samples", [tt, X], [ca.substitute(ca.vertcat(a, I, disc, vl), ca.vertcat(s, p),
                                                                 ca.vertcat(0, tt, 1))])
        self.samples = sample.map(self.k + 1)
        self.nx = X.numel()

    # ------------------------------------------------------------------ running
    def run(self, gaps0: Sequence[float], speeds0: Sequence[float], t_end: float, *,
            soc0: float | Sequence[float] | None = None, progress: ProgressFn | None = None) -> SimulationResult:
        """Integrate from the initial gaps/speeds (model units) over [0, t_end] (model time)."""
        n = self.n
        h0, v0 = np.asarray(gaps0, float).ravel(), np.asarray(speeds0, float).ravel()
        if h0.size != n or v0.size != n:
            raise ParameterError(f"simulate: gaps0 and speeds0 need {n} values (one per follower), "
                                 f"got {h0.size} and {v0.size}")
        if not np.all(np.isfinite(h0)) or np.any(h0 <= 0):
            i = int(np.argmin(np.where(np.isfinite(h0), h0, -np.inf)))
            raise ParameterError(f"simulate: initial gap of vehicle {i + 1} is {h0[i]!r}: must be > 0")
        if not np.all(np.isfinite(v0)) or np.any(v0 < 0):
            i = int(np.argmin(np.where(np.isfinite(v0), v0, -np.inf)))
            raise ParameterError(f"simulate: initial speed of vehicle {i + 1} is {v0[i]!r}: must be >= 0")
        if not (math.isfinite(t_end) and t_end > 0):
            raise ParameterError(f"simulate: t_end = {t_end!r} is not allowed: must be > 0")
        x0 = [h0, v0]
        if self.battery:
            s0 = np.broadcast_to(np.asarray(self.ev.cell.soc0 if soc0 is None else soc0, float), (n,))
            x0 += [np.zeros(n), np.zeros(n), np.array(s0)]
        x = np.concatenate(x0)
        nq = self.integrator.size1_out("qf")
        q = np.zeros(nq)
        ts, xs, qs, ys = [np.array([0.0])], [x[:, None]], [q[:, None]], []
        events: list[Event] = []
        y0 = np.asarray(self.samples(np.zeros(self.k + 1), np.repeat(x[:, None], self.k + 1, axis=1)))[:, :1]
        ys.append(y0)
        ev0 = self._check(np.array([0.0]), x[:, None], y0)
        if ev0:
            events.append(ev0)
        else:
            for a, b in _segments(t_end, self.leader.breakpoints, self.opts.chunk):
                ok = self._advance(a, b, x, q, ts, xs, qs, ys, events, depth=0)
                x, q = xs[-1][:, -1], qs[-1][:, -1]
                if progress is not None:
                    progress(min(b, ts[-1][-1]), t_end)
                if not ok:
                    break
        return self._assemble(np.concatenate(ts), np.hstack(xs), np.hstack(qs), np.hstack(ys), events)

    def _advance(self, a: float, b: float, x: np.ndarray, q: np.ndarray, ts: list, xs: list, qs: list,
                 ys: list, events: list[Event], depth: int) -> bool:
        """Integrate [a, b] from (x, q); on a solver failure, subdivide to locate it. False = stop."""
        try:
            out = self.integrator(x0=x, p=[a, b - a])
        except RuntimeError as exc:
            if depth < 3:
                for lo, hi in zip(np.linspace(a, b, 11)[:-1], np.linspace(a, b, 11)[1:]):
                    if not self._advance(float(lo), float(hi), xs[-1][:, -1], qs[-1][:, -1], ts, xs, qs, ys,
                                         events, depth + 1):
                        return False
                return True
            h = x[: self.n]
            i = int(np.argmin(h))
            kind = "collision" if h[i] < 0.05 else "integration_failed"
            events.append(Event(kind, a, i, f"CVODES failed on [{a:.4f}, {b:.4f}] with gap h = {h[i]:.3g} "
                                f"(CasADi: {str(exc).splitlines()[0][:120]})"))
            return False
        tk = a + (b - a) * np.linspace(0.0, 1.0, self.k + 1)[1:]
        xk = np.asarray(out["xf"])
        qk = q[:, None] + np.asarray(out["qf"])
        yk = np.asarray(self.samples(np.append(tk, tk[-1]), np.hstack([xk, xk[:, -1:]])))[:, :-1]
        prev = (ts[-1][-1], xs[-1][:, -1:], ys[-1][:, -1:])
        event = self._check(tk, xk, yk, prev)
        if event is not None:
            keep = tk < event.time
            ts.append(tk[keep]); xs.append(xk[:, keep]); qs.append(qk[:, keep]); ys.append(yk[:, keep])
            events.append(event)
            return False
        ts.append(tk); xs.append(xk); qs.append(qk); ys.append(yk)
        return True

    def _check(self, tk: np.ndarray, xk: np.ndarray, yk: np.ndarray,
               prev: tuple[float, np.ndarray, np.ndarray] | None = None) -> Event | None:
        """First violation among the samples, with its time interpolated from the previous sample."""
        n = self.n
        h, v = xk[:n], xk[n:2 * n]
        checks = [("collision", h, 0.0, "gap h reached 0"),
                  ("negative_speed", v, -1e-9, "speed became negative")]
        if self.battery:
            S, disc = xk[4 * n:5 * n], yk[2 * n:3 * n]
            checks += [("infeasible_current", disc, 0.0, "cell cannot deliver the power demand (E² < 4 R_s P_c)"),
                       ("soc_out_of_range", S, 0.0, "state of charge fell below 0"),
                       ("soc_out_of_range", 1.0 - S, 0.0, "state of charge rose above 1")]
        first: Event | None = None
        for kind, arr, floor, msg in checks:
            bad = arr <= floor if kind == "collision" else arr < floor
            if not bad.any():
                continue
            cols = np.where(bad.any(axis=0))[0]
            j = int(cols[0])
            i = int(np.where(bad[:, j])[0][0])
            t_ev = float(tk[j])
            if j > 0 or prev is not None:
                t_prev = float(tk[j - 1]) if j > 0 else prev[0]
                prev_val = {"collision": lambda: (xk[:n, j - 1] if j > 0 else prev[1][:n, 0])[i],
                            "negative_speed": lambda: (xk[n:2 * n, j - 1] if j > 0 else prev[1][n:2 * n, 0])[i]}
                if kind in prev_val:
                    a0, a1 = prev_val[kind]() - floor, arr[i, j] - floor
                    if a0 > 0 > a1 or (a0 > 0 and a1 == 0):
                        t_ev = t_prev + (t_ev - t_prev) * a0 / (a0 - a1)
            if first is None or t_ev < first.time:
                first = Event(kind, t_ev, i, f"{msg} (value {arr[i, j]:.4g} at t = {tk[j]:.4f})")
        return first

    def _assemble(self, t: np.ndarray, X: np.ndarray, Qc: np.ndarray, Y: np.ndarray,
                  events: list[Event]) -> SimulationResult:
        n, K = self.n, t.size
        nan = np.full((K, n), np.nan)
        rows = lambda M, j: M[j * n:(j + 1) * n].T  # noqa: E731
        bat = self.battery
        return SimulationResult(
            t=t, leader_speed=Y[3 * n], leader_position=np.asarray(self.leader.position(t), float),
            gap=rows(X, 0), speed=rows(X, 1), accel=rows(Y, 0),
            V1=rows(X, 2) if bat else nan, V2=rows(X, 3) if bat else nan, S=rows(X, 4) if bat else nan,
            current_A=rows(Y, 1) if bat else nan,
            omega=rows(Qc, 0), int_ovm_err2=rows(Qc, 1), int_rel_speed2=rows(Qc, 2), int_jerk2=rows(Qc, 3),
            heat_J=rows(Qc, 4) if bat else nan, heat_irr_J=rows(Qc, 5) if bat else nan,
            controllers=[law.name for law in self.laws], ev=self.ev, events=events,
            solver_stats=[None] * n,
            meta={"integrator": "cvodes", "rtol": self.opts.rtol, "atol": self.opts.atol,
                  "dt_out": self.opts.dt_out, "leader": self.leader.describe(),
                  "laws": [law.describe() for law in self.laws]})


def simulate_platoon(leader: LeaderProfile, laws: Sequence[CarFollowingLaw], gaps0: Sequence[float],
                     speeds0: Sequence[float], t_end: float, *, ev: EVParams | None = None,
                     soc0: float | Sequence[float] | None = None, dt_out: float = 0.01, rtol: float = 1e-10,
                     atol: float = 1e-10, battery: bool = True, progress: ProgressFn | None = None) -> SimulationResult:
    """Simulate followers behind ``leader`` (model units) over [0, t_end]; see :class:`PlatoonSimulator`."""
    sim = PlatoonSimulator(leader, laws, ev, SimOptions(dt_out=dt_out, rtol=rtol, atol=atol), battery=battery)
    return sim.run(gaps0, speeds0, t_end, soc0=soc0, progress=progress)

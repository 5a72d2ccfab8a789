"""The plant: the exact model of a platoon, and ONE table of event rules used by every closed loop.

Every run of the toolkit (closed-form laws in :mod:`aev_ocp.simulate`, the MPC and any
:class:`~aev_ocp.control.Controller` in :mod:`aev_ocp.control`, the OCP-D replay) integrates this
model and stops at the events of :data:`EVENT_RULES`. The compiled cascade (``aev_ocp/c/cascade.c``)
gets its thresholds and event codes from the same table (:func:`event_header`).

Model (model guide §2, §5–§7): per follower the gap h and speed v (model units) and the cell's
V1, V2 [V], S [-] (and, with ``ev.thermal.enabled``, the pack temperature T [K] of
:mod:`aev_ocp.models.thermal`, after S); the exact η switch and the exact current map (:func:`aev_ocp.models.ego.battery_side`).
A follower's acceleration is either its car-following law, evaluated continuously inside the
integrator, or a commanded acceleration held constant over a sample interval (zero-order hold).
Quadratures per follower (per model time unit): ω = ∫ v g(a), ∫(V(h) − v)², ∫(v_l − v)², ∫jerk²,
pack ∫Q and ∫Q_irr [J], and, when every follower drives a law, last the battery energy ∫P_b dt [J] (output only),
so the §10 metrics are exact across control jumps.

Vehicle limits (``ev.limits``, :mod:`aev_ocp.models.actuator`) act on every controller alike, inside the
right-hand side: the law's or the command's acceleration is saturated to [a_min, a_max], passes through the
actuator state a_act (appended to x after the battery states) when a lag or jerk limit is set, and is cut
at v_max and at standstill; a_act(0) = 0. ``enabled = False`` builds exactly the model without limits.

Events are located on the integrator: the first sample where a rule fires brackets it, and a safeguarded
regula falsi (:func:`aev_ocp.numerics.bracketed_root`) on a one-point CVODES integration from the sample before
finds the time to 1e-12 (relative) and returns the state where the rule fires;
the run ends with that sample (a collision: h ≤ 0 there; the event carries the time in s and the impact
speed v − v_l in m/s). A controller that publishes its own hard floor (``describe()["bounds_model"]["h_min"]``)
and goes below it gives the run status 'violated' and one warning (:func:`floor_violations`).
"""

from __future__ import annotations

import math
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Sequence

import casadi as ca
import numpy as np

from .fastcall import BufferedCall
from .models import energy
from .models.actuator import actuator_rate, saturate, speed_cut
from .models.carfollowing import CarFollowingLaw, optimal_velocity
from .models.ego import battery_side
from .models.leader import LeaderProfile
from .models.powertrain import battery_power_W
from .models.vehicle import wheel_power_W
from .numerics import BOUND_TOLERANCE, bracketed_root
from .params import EVParams, ParameterError, Units
from .results import VIOLATED, Event, SimulationResult

# A controller's plan may violate a bound by at most this much (NLP units: model speed for v) and
# still be applied; the plant's negative-speed rule uses the same number, so a plan accepted within
# tolerance never stops the plant (model guide §9: "negative speed in the plant is reported"); the floor and the
# metrics' bound counts use the same number (aev_ocp.numerics.BOUND_TOLERANCE).
PLAN_TOLERANCE = BOUND_TOLERANCE
#: CVODES options of the plant's integrator: Adams–Moulton with functional iteration, for the non-stiff platoon ODE
#: (:class:`Plant`; an interval they fail on is retried with CVODES's default BDF and Newton iteration)
NONSTIFF: dict[str, str] = {"linear_multistep_method": "adams", "nonlinear_solver_iteration": "functional"}


@dataclass(frozen=True)
class EventRule:
    """An event: the run stops when ``sign·value − offset`` drops below 0 (``≤ 0`` when ``strict``),
    ``value`` being the sampled quantity ``quantity`` ('h', 'v', 'disc' or 'S') of a follower."""

    code: int  # the code the compiled cascade reports (1…5; 6 = integration failed)
    kind: str  # Event.kind
    quantity: str
    sign: float
    offset: float
    strict: bool
    message: str

    def margin(self, value: Any) -> Any:
        """sign·value − offset: the distance to the event (event when < 0, or ≤ 0 if strict)."""
        return self.sign * value - self.offset

    def violated(self, value: Any) -> Any:
        """True where the rule fires."""
        m = self.margin(value)
        return m <= 0 if self.strict else m < 0


EVENT_RULES: tuple[EventRule, ...] = (
    EventRule(1, "collision", "h", 1.0, 0.0, True, "gap h reached 0"),
    EventRule(2, "negative_speed", "v", 1.0, -PLAN_TOLERANCE, False, "speed became negative"),
    EventRule(
        3, "infeasible_current", "disc", 1.0, 0.0, False, "cell cannot deliver the power demand (E² < 4 R_s P_c)"
    ),
    EventRule(4, "soc_out_of_range", "S", 1.0, 0.0, False, "state of charge fell below 0"),
    EventRule(5, "soc_out_of_range", "S", -1.0, -1.0, False, "state of charge rose above 1"),
)
INTEGRATION_FAILED = 6  # code of a failed integration (not a physical event)
BATTERY_QUANTITIES = ("disc", "S")


def event_header() -> str:
    """C macros of the event table for the compiled cascade: AEV_EV<code>_SIGN, AEV_EV<code>_OFFSET and
    AEV_EV_FAILED (rule k fires when SIGN·value − OFFSET < 0; ≤ 0 for the collision, code 1)."""
    lines = []
    for r in EVENT_RULES:
        key = f"AEV_EV{r.code}"
        lines.append(f"#define {key}_SIGN ({r.sign!r})\n#define {key}_OFFSET ({r.offset!r})\n")
    lines.append(f"#define AEV_EV_FAILED {INTEGRATION_FAILED}\n")
    return "".join(lines)


def rule_of_code(code: int) -> EventRule:
    """The rule of a compiled-cascade event code."""
    return next(r for r in EVENT_RULES if r.code == code)


def _to_micro(x: float) -> float:
    """``x`` rounded to 1e-6 (a located contact's gap is 0 to the locator's 1e-12 s times the closing speed: its
    round-off, e.g. -3.9e-16 m, is not news in a message), without a negative zero."""
    return round(x * 1e6) / 1e6 + 0.0


def event_at(
    rule: EventRule, time: float, vehicle: int, units: Units, h: float, v: float, v_lead: float, value: float
) -> Event:
    """The Event of ``rule`` located at ``time`` [model] for follower ``vehicle``, with its gap h, speed v, its
    predecessor's speed v_lead (model units) and the rule's quantity ``value`` there; the message is SI first,
    the model value in parentheses (a collision: the impact speed v − v_l and the gap at contact)."""
    t_s = float(units.time_to_si(time))
    if rule.kind == "collision":
        dv = v - v_lead
        dv_mps = float(units.speed_to_si(dv))
        return Event(
            rule.kind,
            time,
            vehicle,
            f"impact speed {dv_mps:.3g} m/s ({dv:.4g} model), gap at contact "
            f"{_to_micro(float(units.length_to_si(h))):.3g} m ({_to_micro(h):.3g} model)",
            time_s=t_s,
            impact_speed_mps=dv_mps,
        )
    if rule.quantity == "v":
        what = f"speed {float(units.speed_to_si(v)):.3g} m/s ({v:.4g} model)"
    elif rule.quantity == "S":
        what = f"S = {value:.6g}"
    else:
        what = f"E² − 4 R_s P_c = {value:.4g} V²"
    return Event(rule.kind, time, vehicle, f"{rule.message}: {what}", time_s=t_s)


def event_from_code(code: int, time: float, vehicle: int, value: float) -> Event:
    """The Event of a compiled-cascade code (message from the table), when no state at the event is known."""
    rule = rule_of_code(code)
    return Event(
        rule.kind, time, vehicle, f"{rule.message} (value {value:.4g} at the step ending after t = {time:.4f})"
    )


def warn_floor_violations(violations: Sequence[Event], controllers: Sequence[str], stacklevel: int = 2) -> None:
    """One warning line per floor violation (:func:`floor_violations`), naming the vehicle's controller;
    ``stacklevel`` as :func:`warnings.warn`'s, counted from the caller of this function."""
    for e in violations:
        warnings.warn(
            f"{controllers[e.vehicle]} (vehicle {e.vehicle + 1}) violated its gap floor: {e}",
            RuntimeWarning,
            stacklevel=stacklevel + 1,
        )


def floor_violations(t: np.ndarray, gap: np.ndarray, controllers: Sequence[Any], units: Units) -> list[Event]:
    """One 'violated' Event per follower whose gap went below its controller's own hard floor (the
    ``bounds_model`` → ``h_min`` of its ``describe()``, model units) by more than :data:`PLAN_TOLERANCE` (the
    tolerance its plans are accepted with): at the first such sample, with the smallest gap and how many samples
    were below (SI first)."""
    out: list[Event] = []
    for i, d in enumerate(controllers):
        own = d.get("bounds_model") if isinstance(d, dict) else None
        if not own or own.get("h_min") is None or i >= gap.shape[1]:
            continue
        h_min = float(own["h_min"])
        below = np.where(gap[1:, i] < h_min - PLAN_TOLERANCE)[0] + 1
        if below.size == 0:
            continue
        k, lo = int(below[0]), float(np.min(gap[:, i]))
        L = units.length_to_si
        out.append(
            Event(
                VIOLATED,
                float(t[k]),
                i,
                f"gap below the controller's hard floor {float(L(h_min)):.3g} m "
                f"({h_min:.4g} model) in {below.size} samples, smallest {float(L(lo)):.3g} m ({lo:.4g} model)",
                time_s=float(units.time_to_si(t[k])),
            )
        )
    return out


#: kind of the event of a cell current beyond its limit (CellParams.max_current_A): recorded, never stopping the run
CURRENT_LIMIT = "current_limit"


def current_limit_events(t: np.ndarray, current_A: np.ndarray, ev: EVParams) -> list[Event]:
    """One rule for every plant (platoon, ring, SUMO): a cell current beyond ±``ev.cell.max_current_A`` (the cell's
    20C limit) is an event, one per vehicle that exceeds it: at its first sample beyond the limit, with the largest
    |I| [A] and how many samples were beyond. The plant does not saturate the current (it is what the power demand
    needs) and the run goes on; the event goes to :attr:`~aev_ocp.results.SimulationResult.violations`, so the run's
    status is 'violated', not 'ok'. Only for vehicles with limits (``ev.limits.enabled``): the paper's unlimited
    model reports its 20C excursions in its own tables. t (K,) [model time], current_A (K, n) [A]."""
    if not ev.limits.enabled:
        return []
    I_max = ev.cell.max_current_A
    I = np.asarray(current_A, float)
    if I.ndim != 2:
        return []
    out: list[Event] = []
    for i in range(I.shape[1]):
        beyond = np.flatnonzero(np.abs(I[:, i]) > I_max * (1 + 1e-9))
        if beyond.size == 0:
            continue
        k, peak = int(beyond[0]), float(np.max(np.abs(I[beyond, i])))
        out.append(
            Event(
                CURRENT_LIMIT,
                float(t[k]),
                i,
                f"cell current beyond its limit {I_max:g} A: largest |I| = {peak:.4g} A, {beyond.size} samples beyond",
                time_s=float(ev.units.time_to_si(t[k])),
            )
        )
    return out


class Plant:
    """The exact platoon model behind ``leader`` integrated by ONE CasADi CVODES integrator.

    laws[i] is follower i's car-following law (continuous) or None (commanded acceleration, held
    over each call of :meth:`advance`). The integrator works in normalised time s ∈ [0, 1] with
    parameters (t0, L, a_cmd) (dx/ds = L·f(t0 + L s, x)), so ONE Function serves every interval;
    ``samples`` output points are returned per interval (equally spaced). battery=False integrates
    h and v only (and ω, the tracking errors and jerk).
    """

    def __init__(
        self,
        leader: LeaderProfile,
        laws: Sequence[CarFollowingLaw | None],
        ev: EVParams | None = None,
        *,
        battery: bool = True,
        rtol: float = 1e-10,
        atol: float = 1e-10,
        max_num_steps: int = 200_000,
        samples: int = 1,
    ) -> None:
        if len(laws) < 1:
            raise ParameterError("plant: the platoon needs at least one follower")
        self.leader, self.laws, self.ev = leader, list(laws), ev or EVParams()
        self.n, self.battery, self.k = len(self.laws), battery, int(samples)
        self.commanded = [i for i, law in enumerate(self.laws) if law is None]
        self.rtol, self.atol = rtol, atol
        self._build(max_num_steps)

    def _accelerations(self, h: ca.SX, v: ca.SX, v_lead: ca.SX, a_cmd: ca.SX) -> ca.SX:
        """Commanded accelerations of all followers (their laws, or a_cmd), vectorised over groups with the same
        law, before the vehicle's limits."""
        a = ca.SX.zeros(self.n)
        groups: dict[CarFollowingLaw, list[int]] = {}
        for i, law in enumerate(self.laws):
            if law is not None:
                groups.setdefault(law, []).append(i)
        for law, idx in groups.items():
            a[idx] = law.accel(h[idx], v[idx], v_lead[idx])
        for j, i in enumerate(self.commanded):
            a[i] = a_cmd[j]
        return a

    def _build(self, max_num_steps: int) -> None:
        n, ev, T = self.n, self.ev, self.ev.units.time_s
        h, v = ca.SX.sym("h", n), ca.SX.sym("v", n)
        s, p = ca.SX.sym("s"), ca.SX.sym("p", 2 + len(self.commanded))  # normalised time; (t0, L, a_cmd)
        t = p[0] + p[1] * s
        vl = self.leader.speed(t)
        v_lead = ca.vertcat(vl, v[:-1]) if n > 1 else vl
        a = self._accelerations(h, v, v_lead, p[2:])
        hdot = v_lead - v
        lim = ev.limits
        act: ca.SX | None = None
        dact: Any = None
        if lim.enabled:  # the vehicle's limits (aev_ocp.models.actuator); off: the paper's laws, the same graph
            a_sat = saturate(a, lim, ev.units)
            if lim.has_actuator_state:
                act = ca.SX.sym("a_act", n)
                dact = actuator_rate(a_sat, act, lim, ev.units)
                a_sat = act
            a = speed_cut(a_sat, v, lim, ev.units)
        # jerk = da/dt by the chain rule (forward AD), including the leader's explicit time dependence
        if act is None or dact is None:
            jerk = ca.jtimes(a, ca.vertcat(h, v), ca.vertcat(hdot, a)) + ca.jacobian(a, s) / p[1]
        else:
            jerk = ca.jtimes(a, ca.vertcat(h, v, act), ca.vertcat(hdot, a, dact)) + ca.jacobian(a, s) / p[1]
        x, ode = [h, v], [hdot, a]
        quad = [v * energy.g_exact(a, ev.vehicle.efficiency), (optimal_velocity(h) - v) ** 2, hdot**2, jerk**2]
        self.thermal = self.battery and ev.thermal.enabled
        if self.battery:
            V1, V2, S = ca.SX.sym("V1", n), ca.SX.sym("V2", n), ca.SX.sym("S", n)
            Tk = ca.SX.sym("T", n) if self.thermal else None  # pack temperature [K] (after S, before a_act)
            b = battery_side(v, a, V1, V2, S, ev, T_K=Tk)
            x += [V1, V2, S]
            ode += [T * b["dV1"], T * b["dV2"], T * b["dS"]]
            if Tk is not None:
                x.append(Tk)
                ode.append(T * b["dT"])
            quad += [T * b["Q_pack"], T * b["Q_irr_pack"]]
            I, disc = b["I"], b["disc"]
        else:
            I = disc = ca.SX.zeros(n)
        # battery energy ∫P_b dt [J per model time unit], last: output only (nothing reads it back). Laws only: with
        # commanded vehicles (the MPC, any Controller) CVODES's error norm would see one more quadrature and move its
        # steps by ~1e-10, enough to tip a closed loop's QP solves (tests/test_mpc.py's qrqp path fell back once at
        # h(0) + 1e-9 before qrqp's min_lam was set, aev_ocp.mpc.rti.QRQP_MIN_LAM); there the command is held over each sample interval and aev_ocp.metrics integrates the exact
        # P_b(v, a_held) on the samples
        self.energy_quad: int | None = None  # its block in the quadratures (SimulationResult.battery_energy_J)
        if not self.commanded:
            quad.append(T * battery_power_integrand(v, a, ev, b if self.battery else None))
            self.energy_quad = len(quad) - 1
        self.act_row: int | None = None  # first row of the actuator states a_act in x (after the battery's)
        if act is not None:
            self.act_row = sum(int(xx.numel()) for xx in x)
            x.append(act)
            ode.append(dact)
        X = ca.vertcat(*x)
        dae = {"x": X, "p": p, "t": s, "ode": p[1] * ca.vertcat(*ode), "quad": p[1] * ca.vertcat(*quad)}
        grid = np.linspace(0.0, 1.0, self.k + 1)[1:].tolist()
        self._dae = dae
        # CVODES's Adams–Moulton method with functional (fixed-point) iteration: the platoon's ODE is not stiff
        # (car-following time constants of seconds, the cell's RC pairs of tens to thousands of seconds), and at
        # rtol 1e-10 Adams (orders up to 12) takes fewer and cheaper steps than BDF (up to 5) with Newton: 2-3x less
        # time per interval, as close to a 1e-13 reference (a few 1e-9 or less; benchmarks/bench_plant.py). Where it fails (a stiff
        # moment, such as a gap closing to zero under a 1/h² law) the interval is retried on BDF with Newton, the
        # method CVODES recommends for stiff problems (:attr:`stiff`), before it is subdivided.
        self._stiff_opts: dict[str, Any] = {
            "abstol": self.atol,
            "reltol": self.rtol,
            "max_num_steps": max_num_steps,
            "quad_err_con": True,
            "disable_internal_warnings": True,
            "show_eval_warnings": False,
        }
        self._int_opts: dict[str, Any] = {**self._stiff_opts, **NONSTIFF}
        self.integrator = ca.integrator("plant", "cvodes", dae, 0.0, grid, self._int_opts)
        self._stiff: ca.Function | None = None  # BDF with Newton on the same grid (built on the first failure)
        self._stiff_step: BufferedCall | None = None
        self.stiff_retries = 0  # intervals the non-stiff method failed on and BDF integrated
        self._one: ca.Function | None = None  # one output point: locates events (built on first use)
        self._one_stiff: ca.Function | None = None  # the same with BDF and Newton (built on its first failure)
        tt, ac = ca.SX.sym("t"), ca.SX.sym("a_cmd", len(self.commanded))
        y = ca.substitute(ca.vertcat(a, I, disc, vl), ca.vertcat(s, p), ca.vertcat(0, tt, 1, ac))
        self._samples = ca.Function("plant_samples", [tt, X, ac], [y])
        self._sample_maps: dict[int, BufferedCall] = {}
        self._step: BufferedCall | None = None  # the integrator on bound buffers (built on first use)
        self._grid = np.linspace(0.0, 1.0, self.k + 1)[1:]  # the output points in normalised time (s ∈ (0, 1])
        self._io = tuple(self.integrator.index_in(k) for k in ("x0", "p")) + tuple(
            self.integrator.index_out(k) for k in ("xf", "qf")
        )  # where x0, p, xf and qf sit among the integrator's inputs and outputs
        self.nx, self.nq = X.numel(), len(quad) * n

    # ---------------------------------------------------------------- state
    def initial_state(
        self,
        gaps0: Sequence[float],
        speeds0: Sequence[float],
        soc0: float | Sequence[float] | None = None,
        what: str = "plant",
    ) -> np.ndarray:
        """x(0) of this plant (see :func:`initial_state`)."""
        return initial_state(self.n, self.ev, self.battery, gaps0, speeds0, soc0, what)

    def samples(self, t: np.ndarray, X: np.ndarray, a_cmd: np.ndarray | None = None) -> np.ndarray:
        """(a, I, disc, v_l) stacked by quantity ((3n + 1), K) at the times t (K,) and states X (nx, K)."""
        t = np.atleast_1d(np.asarray(t, float))
        ac = (
            np.zeros((len(self.commanded), t.size))
            if a_cmd is None
            else np.repeat(np.asarray(a_cmd, float).reshape(-1, 1), t.size, axis=1)
        )
        f = self._sample_maps.get(t.size)
        if f is None:  # built once per sample count
            f = self._sample_maps[t.size] = BufferedCall(self._samples.map(t.size))
        f.args[0][:] = t
        f.args[1][:] = np.asarray(X, float).ravel(order="F")
        if ac.size:
            f.args[2][:] = ac.ravel(order="F")
        if not f():
            return np.asarray(f.fn(t.reshape(1, -1), X, ac))
        return f.res[0].reshape(-1, t.size, order="F").copy()

    # ---------------------------------------------------------------- integration
    def advance(
        self,
        a: float,
        b: float,
        x: np.ndarray,
        q: np.ndarray,
        a_cmd: np.ndarray | None,
        out: tuple[list, list, list, list],
        events: list[Event],
        depth: int = 0,
    ) -> bool:
        """Integrate [a, b] from (x, q) with the commands a_cmd held, append the samples to
        out = (ts, xs, qs, ys) and check the event rules. On a solver failure the interval is
        subdivided (3 levels) to locate it. Returns False when the run must stop."""
        ts, xs, qs, ys = out
        ac = np.zeros(0) if a_cmd is None else np.asarray(a_cmd, float)
        f = self._step
        if f is None:
            f = self._step = BufferedCall(self.integrator)
        ix, ip, jx, jq = self._io
        f.args[ix][:] = x
        f.args[ip][0], f.args[ip][1] = a, b - a
        f.args[ip][2:] = ac
        try:
            if not f():  # failed with the non-stiff method: the same interval on BDF with Newton
                f = self._stiff_buffers(x, a, b, ac)
                self.stiff_retries += 1
            if f():  # the same evaluation as the call below, on the bound buffers
                fx, fq = f.res[jx], f.res[jq]
                res = {"xf": fx.reshape(self.nx, -1, order="F").copy(), "qf": fq.reshape(self.nq, -1, order="F").copy()}
            else:  # failed there too: the call raises CasADi's own error (or, should it pass, gives its result)
                res = f.fn(x0=x, p=np.concatenate([[a, b - a], ac]))
        except RuntimeError as exc:
            if depth < 3:
                for lo, hi in zip(np.linspace(a, b, 11)[:-1], np.linspace(a, b, 11)[1:]):
                    if not self.advance(
                        float(lo), float(hi), xs[-1][:, -1], qs[-1][:, -1], a_cmd, out, events, depth + 1
                    ):
                        return False
                return True
            hh = x[: self.n]
            i = int(np.argmin(hh))
            near = " (near collision)" if hh[i] < 0.05 else ""
            events.append(
                Event(
                    "integration_failed",
                    a,
                    i,
                    f"CVODES failed on [{a:.4f}, {b:.4f}] with gap "
                    f"h = {hh[i]:.3g}{near} (CasADi: {str(exc).splitlines()[0][:120]})",
                )
            )
            return False
        tk = a + (b - a) * self._grid
        xk = np.asarray(res["xf"]).reshape(self.nx, -1)
        qk = q[:, None] + np.asarray(res["qf"]).reshape(self.nq, -1)
        yk = self.samples(tk, xk, a_cmd)
        hit = self._first(tk, xk, yk, (ts[-1][-1], xs[-1][:, -1], ys[-1][:, -1]))
        if hit is not None:
            rule, i, j, t_lin = hit
            keep = np.arange(tk.size) < j
            ts.append(tk[keep])
            xs.append(xk[:, keep])
            qs.append(qk[:, keep])
            ys.append(yk[:, keep])  # noqa: E702
            # locate the event on the integrator: from the last sample before it, a root of the rule's margin
            if j > 0:
                t0, x0, q0 = float(tk[j - 1]), xk[:, j - 1], qk[:, j - 1]
            else:  # the interval's start (a, x, q)
                t0, x0, q0 = a, np.asarray(x, float), np.asarray(q, float)
            te, xe, qe, ye = self._locate(rule, i, t0, x0, q0, float(tk[j]), xk[:, j], qk[:, j], yk[:, j], a_cmd)
            ts.append(np.array([te]))
            xs.append(xe[:, None])
            qs.append(qe[:, None])
            ys.append(ye[:, None])  # noqa: E702
            events.append(self._event(rule, te, i, xe, ye))
            return False
        ts.append(tk)
        xs.append(xk)
        qs.append(qk)
        ys.append(yk)  # noqa: E702
        return True

    @property
    def stiff(self) -> ca.Function:
        """The plant's integrator with CVODES's BDF method and Newton iteration (same grid and tolerances): what an
        interval falls back to when the non-stiff Adams method fails on it."""
        if self._stiff is None:
            self._stiff = ca.integrator("plant_stiff", "cvodes", self._dae, 0.0, self._grid.tolist(), self._stiff_opts)
        return self._stiff

    def _stiff_buffers(self, x: np.ndarray, a: float, b: float, ac: np.ndarray) -> BufferedCall:
        """:attr:`stiff` on bound buffers holding the interval [a, b] from x with the commands ac."""
        g = self._stiff_step
        if g is None:
            g = self._stiff_step = BufferedCall(self.stiff)
        ix, ip = self._io[:2]
        g.args[ix][:] = x
        g.args[ip][0], g.args[ip][1] = a, b - a
        g.args[ip][2:] = ac
        return g

    def _one_step(
        self, t0: float, t1: float, x0: np.ndarray, q0: np.ndarray, a_cmd: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, q, y) at t1 integrated from (x0, q0) at t0 with the commands held (one output point; BDF with Newton
        where the non-stiff method fails)."""
        if self._one is None:
            self._one = ca.integrator("plant_one", "cvodes", self._dae, 0.0, [1.0], self._int_opts)
        ac = np.zeros(0) if a_cmd is None else np.asarray(a_cmd, float)
        p = np.concatenate([[t0, t1 - t0], ac])
        try:
            res = self._one(x0=x0, p=p)
        except RuntimeError:
            if self._one_stiff is None:
                self._one_stiff = ca.integrator("plant_one_stiff", "cvodes", self._dae, 0.0, [1.0], self._stiff_opts)
            res = self._one_stiff(x0=x0, p=p)
        x = np.asarray(res["xf"]).ravel()
        q = q0 + np.asarray(res["qf"]).ravel()
        return x, q, self.samples(np.array([t1]), x[:, None], a_cmd)[:, 0]

    def _locate(
        self,
        rule: EventRule,
        i: int,
        t0: float,
        x0: np.ndarray,
        q0: np.ndarray,
        t1: float,
        x1: np.ndarray,
        q1: np.ndarray,
        y1: np.ndarray,
        a_cmd: np.ndarray | None,
    ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """The first time in (t0, t1] where ``rule`` fires for vehicle i, by :func:`~aev_ocp.numerics.bracketed_root`
        (Illinois regula falsi) on the integrator from the state (x0, q0) at t0, to |Δt| ≤ 1e-12 max(1, |t|):
        (t, x, q, y) at the end of the last bracket where the rule fires (a collision: h ≤ 0). (t1, x1, q1, y1) is
        a sample where it fires."""
        y0 = self.samples(np.array([t0]), x0[:, None], a_cmd)[:, 0]
        if not float(self._margin(rule, i, x0, y0)) > 0:
            return t1, x1, q1, y1
        at = {t0: (x0, q0, y0), t1: (x1, q1, y1)}  # (x, q, y) of every time tried

        def signed_margin(t: float) -> float:
            # the margin with the firing side on bracketed_root's side="b": m < 0 fires, or m ≤ 0 (strict): −m ≥ 0
            if t not in at:
                at[t] = self._one_step(t0, t, x0, q0, a_cmd)
            m = float(self._margin(rule, i, at[t][0], at[t][2]))
            return -m if rule.strict else m

        te = bracketed_root(signed_margin, t0, t1, 1e-12, 100, side="b")
        return (te, *at[te])

    def _margin(self, rule: EventRule, i: int, x: np.ndarray, y: np.ndarray) -> Any:
        """The rule's margin for vehicle i at one state x and output y."""
        return rule.margin(self._rows(rule.quantity, x[:, None], y[:, None])[i, 0])

    def _rows(self, quantity: str, M: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """The rows of ``quantity`` ('h', 'v', 'disc', 'S') of states M and outputs Y (one column per sample)."""
        n = self.n
        return {
            "h": M[:n],
            "v": M[n : 2 * n],
            "disc": Y[2 * n : 3 * n],
            "S": M[4 * n : 5 * n] if self.battery else M[:0],
        }[quantity]

    def _event(self, rule: EventRule, t: float, i: int, x: np.ndarray, y: np.ndarray) -> Event:
        """The Event of ``rule`` for vehicle i at the state x, output y at time t (SI message)."""
        n = self.n
        v_lead = float(y[3 * n]) if i == 0 else float(x[n + i - 1])
        return event_at(
            rule,
            t,
            i,
            self.ev.units,
            float(x[i]),
            float(x[n + i]),
            v_lead,
            float(self._rows(rule.quantity, x[:, None], y[:, None])[i, 0]),
        )

    def _first(
        self, tk: np.ndarray, xk: np.ndarray, yk: np.ndarray, prev: tuple[float, np.ndarray, np.ndarray] | None = None
    ) -> tuple[EventRule, int, int, float] | None:
        """(rule, vehicle, sample index, time) of the first violation of :data:`EVENT_RULES` among the samples
        (tk, xk, yk), its time linearly interpolated from the previous sample ``prev = (t, x, y)`` where there is
        one (:meth:`advance` then locates it on the integrator)."""
        first: tuple[EventRule, int, int, float] | None = None
        for rule in EVENT_RULES:
            if rule.quantity in BATTERY_QUANTITIES and not self.battery:
                continue
            cur = self._rows(rule.quantity, xk, yk)
            bad = rule.violated(cur)
            if not bad.any():
                continue
            j = int(np.where(bad.any(axis=0))[0][0])
            i = int(np.where(bad[:, j])[0][0])
            t_ev = float(tk[j])
            if j > 0:
                t_prev, m0 = float(tk[j - 1]), rule.margin(cur[i, j - 1])
            elif prev is not None:
                t_prev, m0 = prev[0], rule.margin(self._rows(rule.quantity, prev[1][:, None], prev[2][:, None])[i, 0])
            else:
                t_prev, m0 = t_ev, None
            if m0 is not None and m0 > 0:
                t_ev = t_prev + (t_ev - t_prev) * m0 / (m0 - rule.margin(cur[i, j]))
            if first is None or t_ev < first[3]:
                first = (rule, i, j, t_ev)
        return first

    def check(
        self, tk: np.ndarray, xk: np.ndarray, yk: np.ndarray, prev: tuple[float, np.ndarray, np.ndarray] | None = None
    ) -> Event | None:
        """First violation of :data:`EVENT_RULES` among the samples (tk, xk, yk) as an Event (at the sample; a
        run located inside an interval by :meth:`advance` gets the exact time instead)."""
        hit = self._first(tk, xk, yk, prev)
        if hit is None:
            return None
        rule, i, j, t_ev = hit
        return self._event(rule, float(tk[j]) if prev is None else t_ev, i, xk[:, j], yk[:, j])

    # ---------------------------------------------------------------- results
    def result(
        self, samples: Samples, events: list[Event], controllers: list[str], meta: dict[str, Any], **kw: Any
    ) -> SimulationResult:
        """The run of ``samples`` = (t, X, Qc, Y) (:func:`stack_samples`) as a :class:`SimulationResult` (see
        :func:`assemble_result`)."""
        return assemble_result(
            self.leader,
            self.ev,
            self.battery,
            *samples,
            events,
            controllers,
            {"plant": "cvodes, exact eta switch", "rtol": self.rtol, "atol": self.atol, **meta},
            energy_quad=self.energy_quad,
            **kw,
        )


#: ``progress(t, t_end)`` [model time], called as a run goes on
ProgressFn = Callable[[float, float], None]


class PlatoonRun(ABC):
    """A platoon built once and run from many initial conditions (:class:`~aev_ocp.simulate.PlatoonSimulator`,
    :class:`~aev_ocp.control.ClosedLoop`): :meth:`run` checks t_end and the initial state, then the subclass's
    :meth:`_run` runs from it."""

    who: ClassVar[str]  # the name error messages start with
    n: int  # followers
    ev: EVParams  # the plant's vehicle
    battery: bool  # whether the state carries the cell (V1, V2, S)

    def run(
        self,
        gaps0: Sequence[float],
        speeds0: Sequence[float],
        t_end: float,
        *,
        soc0: float | Sequence[float] | None = None,
        progress: ProgressFn | None = None,
    ) -> SimulationResult:
        """Run over [0, t_end] (model time) from the initial gaps and speeds (model units), V1 = V2 = 0 and
        S = soc0 (default the cell's S(0)). ``progress(t, t_end)`` is called as the run goes on (in a closed loop
        after every step: if it raises :class:`aev_ocp.progress.TimeLimitReached` the loop stops there and the
        result, covering [0, t], ends with an event of kind 'time_limit', its status)."""
        if not (isinstance(t_end, (int, float)) and math.isfinite(t_end) and t_end > 0):
            raise ParameterError(f"{self.who}: t_end = {t_end!r} is not allowed: must be > 0")
        x0 = initial_state(self.n, self.ev, self.battery, gaps0, speeds0, soc0, self.who)
        return self._run(x0, t_end, progress)

    @abstractmethod
    def _run(self, x0: np.ndarray, t_end: float, progress: ProgressFn | None) -> SimulationResult:
        """The run from the checked initial state x0 (see :meth:`run`)."""


#: A run's samples as :meth:`Plant.result` takes them: times t (K,) [model], states X (nx, K), quadratures Qc (nq, K)
#: and outputs Y = (a, I, disc, v_l) stacked by quantity ((3n + 1), K).
Samples = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def stack_samples(out: tuple[list, list, list, list]) -> Samples:
    """The pieces :meth:`Plant.advance` appended to ``out`` = (ts, xs, qs, ys) as one (t, X, Qc, Y)."""
    return np.concatenate(out[0]), np.hstack(out[1]), np.hstack(out[2]), np.hstack(out[3])


def initial_state(
    n: int,
    ev: EVParams,
    battery: bool,
    gaps0: Sequence[float],
    speeds0: Sequence[float],
    soc0: float | Sequence[float] | None = None,
    what: str = "plant",
) -> np.ndarray:
    """x(0) = (h, v[, V1 = 0, V2 = 0, S][, a_act = 0]) stacked by quantity, validated: gaps > 0, speeds ≥ 0,
    S(0) ∈ [0, 1] (default the cell's soc0); errors name the vehicle and the value."""
    h0, v0 = np.asarray(gaps0, float).ravel(), np.asarray(speeds0, float).ravel()
    if h0.size != n or v0.size != n:
        raise ParameterError(
            f"{what}: gaps0 and speeds0 need {n} values (one per follower), got {h0.size} and {v0.size}"
        )
    if not np.all(np.isfinite(h0)) or np.any(h0 <= 0):
        i = int(np.argmin(np.where(np.isfinite(h0), h0, -np.inf)))
        raise ParameterError(f"{what}: initial gap of vehicle {i + 1} is {h0[i]!r}: must be > 0")
    if not np.all(np.isfinite(v0)) or np.any(v0 < 0):
        i = int(np.argmin(np.where(np.isfinite(v0), v0, -np.inf)))
        raise ParameterError(f"{what}: initial speed of vehicle {i + 1} is {v0[i]!r}: must be >= 0")
    x = [h0, v0]
    if battery:
        try:
            s0 = np.broadcast_to(np.asarray(ev.cell.soc0 if soc0 is None else soc0, float), (n,))
        except (TypeError, ValueError):
            raise ParameterError(
                f"{what}: soc0 = {soc0!r} is not allowed: one number or {n} numbers in [0, 1]"
            ) from None
        if not np.all(np.isfinite(s0)) or np.any((s0 < 0) | (s0 > 1)):
            raise ParameterError(f"{what}: soc0 = {np.asarray(s0).tolist()!r} is not allowed: must be in [0, 1]")
        x += [np.zeros(n), np.zeros(n), np.array(s0, float)]
        if ev.thermal.enabled:  # the pack temperature T(0) [K] (ThermalParams.T0_K, default the ambient)
            x.append(np.full(n, ev.thermal.initial_K))
    if ev.limits.has_actuator_state:  # a_act(0) = 0: every vehicle cruises (no acceleration) before t = 0
        x.append(np.zeros(n))
    return np.concatenate(x)


def battery_power_integrand(v: Any, a: Any, ev: EVParams, side: dict[str, Any] | None = None) -> Any:
    """Battery power P_b [W] of the vehicle's exact powertrain at model speed v and acceleration a: the
    battery side's own P_b (``side``, :func:`aev_ocp.models.ego.battery_side`) when the plant has one, else
    P_b(P_w(v, a)) of :func:`aev_ocp.models.powertrain.battery_power_W`. The plants integrate it as their last
    quadrature (battery energy ∫P_b dt)."""
    if side is not None:
        return side["P_b"]
    u = ev.units
    return battery_power_W(wheel_power_W(u.speed_to_si(v), u.accel_to_si(a), ev.vehicle), ev.vehicle)


def assemble_result(
    leader: LeaderProfile,
    ev: EVParams,
    battery: bool,
    t: np.ndarray,
    X: np.ndarray,
    Qc: np.ndarray,
    Y: np.ndarray,
    events: list[Event],
    controllers: list[str],
    meta: dict[str, Any],
    *,
    accel: np.ndarray | None = None,
    jerk_sampled: bool = False,
    solver_stats: list[Any] | None = None,
    energy_quad: int | None = None,
) -> SimulationResult:
    """A run as a :class:`SimulationResult`: X (states), Qc (quadratures) and Y = (a, I, disc, v_l)
    stacked by quantity with one column per sample time t; ``accel`` (K, n) overrides the sampled
    accelerations (e.g. with a controller's applied ones); ``energy_quad``: the block of Qc holding the
    battery energy ∫P_b dt [J] (None: the plant did not integrate it)."""
    n, K = len(controllers), t.size
    nan = np.full((K, n), np.nan)
    rows = lambda M, j: M[j * n : (j + 1) * n].T  # noqa: E731
    # a run that went below a controller's own hard floor gets status 'violated' and one warning line
    violations = floor_violations(t, rows(X, 0), meta.get("controllers") or [], ev.units)
    if not events:  # (an event that stopped the run is reported on its own)
        warn_floor_violations(violations, controllers, stacklevel=3)
    return SimulationResult(
        t=t,
        leader_speed=Y[3 * n],
        leader_position=np.asarray(leader.position(t), float),
        gap=rows(X, 0),
        speed=rows(X, 1),
        accel=rows(Y, 0) if accel is None else accel,
        V1=rows(X, 2) if battery else nan,
        V2=rows(X, 3) if battery else nan,
        S=rows(X, 4) if battery else nan,
        current_A=rows(Y, 1) if battery else nan,
        omega=rows(Qc, 0),
        int_ovm_err2=rows(Qc, 1),
        int_rel_speed2=rows(Qc, 2),
        int_jerk2=rows(Qc, 3),
        heat_J=rows(Qc, 4) if battery else nan,
        heat_irr_J=rows(Qc, 5) if battery else nan,
        temperature_K=rows(X, 5) if battery and ev.thermal.enabled else None,
        battery_energy_J=rows(Qc, energy_quad) if energy_quad is not None else None,
        controllers=controllers,
        ev=ev,
        events=events,
        jerk_sampled=jerk_sampled,
        solver_stats=solver_stats if solver_stats is not None else [None] * n,
        meta={"leader": leader.describe(), **meta},
        violations=violations + (current_limit_events(t, rows(Y, 1), ev) if battery else []),
    )

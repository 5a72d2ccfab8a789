"""Platoon simulation with closed-form car-following laws and each vehicle's battery in the loop.

State per follower: gap h, speed v (model units), and the cell's V1, V2 [V], S [-]; cumulative
integrals per follower: the paper's ω, pack ∫Q and ∫Q_irr [J], and the integrals of squared
tracking errors and jerk. Two interchangeable integrators (SimOptions.method):

* "cascade" (default when a C compiler works): vehicle i depends only on vehicle i − 1, so the
  platoon is integrated vehicle by vehicle in compiled code (CasADi-generated C for each law and the
  leader plus a small Dormand–Prince 5(4) driver, compiled once with gcc and cached by content hash).
  Each vehicle gets its own adaptive steps (cost ~linear in the platoon size, each integration only
  resolves its own kinks); its leader's speed and acceleration are the predecessor's quartic dense
  output, accurate to the tolerance. ω is computed exactly as A·Δ(v²/2) + B·TV(v²/2) (g = A u + B|u|),
  so the kink of g at v̇ = 0 costs no steps; steps end at gap extrema (v_l = v), where the proposed
  law's ε term switches sharply, so the error estimate sees that feature instead of stepping over it.
  Events are checked after every step and located on the dense output (bisection).
  The C driver is ``aev_ocp/c/cascade.c``; a failed build falls back to CVODES with a warning.
* "cvodes": the platoon as one :class:`aev_ocp.plant.Plant` (one CVODES integrator, the same plant as
  every closed loop); after each chunk the samples are checked.

Both split the timeline exactly at the leader's breakpoints (e.g. the paper leader's t = 20) and
stop at the first event of :data:`aev_ocp.plant.EVENT_RULES` (collision, negative speed, infeasible
current demand, S leaving [0, 1]), reported with its time and vehicle — nothing is integrated
through (in the cascade, later vehicles are integrated only up to the earliest event so far).
"""

from __future__ import annotations

import copy
import ctypes
import dataclasses
import math
import threading
import warnings
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from . import interrupts
from .compiled import dense_outputs, driver_source, exact_tuned_flags, load_fastest
from .models import energy
from .models.actuator import actuator_rate, saturate, speed_cut
from .models.carfollowing import CarFollowingLaw, optimal_velocity
from .models.ego import battery_side
from .models.leader import LeaderProfile, SpeedTrace
from .limits import check_simulation_size
from .progress import check_deadline
from .params import METHODS, EVParams, ParameterError, SimOptions, check_argument, exact_key
from .plant import (
    battery_power_integrand,
    INTEGRATION_FAILED,
    Plant,
    PlatoonRun,
    ProgressFn,
    assemble_result,
    event_at,
    event_header,
    rule_of_code,
    stack_samples,
)
from .results import Event, SimulationResult

__all__ = ["METHODS", "PlatoonSimulator", "SimOptions", "simulate_platoon"]
_FALLBACK_WARNED: set[str] = set()
#: The cascade's step limit per vehicle is SimOptions.max_num_steps per STEP_LIMIT_SPAN of model time (at least one
#: span), not a fixed total that cuts a long trip short: the shipped cycles take 15-40 accepted steps per model time
#: unit (udds_platoon 23-26k over 1552, us06_platoon 13.5-14k over 660, hwfet_platoon 14-17.6k over 867, rtol 1e-10,
#: measured), so 200 000 per 1000 units is a 5-13x margin; a car creeping to a standstill behind a stopped leader
#: (stiff, β/h²) took about 50 per unit.
STEP_LIMIT_SPAN = 1000.0
#: The compiled integrator's statistics per vehicle (aevsim_run in cascade.c: accepted steps, rejected steps, right-hand
#: side evaluations), in a run's solver_stats and so in its metrics.
INTEGRATOR_STATS = ("nsteps", "nrejected", "nfev")


def cascade_step_limit(max_num_steps: int, t_end: float) -> int:
    """Steps (accepted + rejected) one vehicle of the cascade may take from 0 to ``t_end`` (model time)."""
    return int(max_num_steps) * max(1, math.ceil(t_end / STEP_LIMIT_SPAN))


def _law_template(law: CarFollowingLaw) -> tuple[Any, Callable[[ca.SX], CarFollowingLaw], list[float]]:
    """(key, make, values): laws with the same key share one compiled right-hand side; ``make(p)`` is the
    law with its float coefficients replaced by the entries of the runtime parameter vector p, ``values``
    their numbers. Dataclass laws whose accel works on symbolic coefficients get this; any other law
    (or one whose accel needs numbers) is compiled with its coefficients as constants (key = the law)."""
    if dataclasses.is_dataclass(law):
        fixed = getattr(law, "compile_constants", ())  # compiled as constants (part of the key), e.g. a law's scales
        names = [
            f.name
            for f in dataclasses.fields(law)
            if isinstance(getattr(law, f.name), float)
            and not isinstance(getattr(law, f.name), bool)
            and f.name not in fixed
        ]
        if names:

            def make(p: ca.SX, _law: CarFollowingLaw = law, _names: tuple[str, ...] = tuple(names)) -> CarFollowingLaw:
                twin = copy.copy(_law)
                for j, nm in enumerate(_names):
                    object.__setattr__(twin, nm, p[j])  # bypasses the frozen dataclass; validation ran on law
                return twin

            values = [float(getattr(law, nm)) for nm in names]
            try:  # symbolic coefficients must give the same law (math.sqrt of an SX, say, gives NaN silently)
                h, v, vl, p = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl"), ca.SX.sym("p", len(names))
                f = ca.Function("probe", [h, v, vl, p], [make(p).accel(h, v, vl)])
                pts = ((1.3, 0.9, 1.1), (2.7, 1.6, 1.45), (0.6, 0.2, 0.35))
                ok = all(
                    abs(float(f(*pt, values)) - float(law.accel(*pt))) <= 1e-12 * (1 + abs(float(law.accel(*pt))))
                    for pt in pts
                )
            except (TypeError, ValueError, RuntimeError, ParameterError):
                ok = False
            if ok:
                rest = tuple((f.name, getattr(law, f.name)) for f in dataclasses.fields(law) if f.name not in names)
                return (type(law), tuple(names), rest), make, values
    return law, (lambda p, _law=law: _law), []


def _law_templates(
    laws: Sequence[CarFollowingLaw],
) -> list[tuple[Any, Callable[[ca.SX], CarFollowingLaw], list[float]]]:
    """:func:`_law_template` of every law, probed once per distinct law (a platoon of 10 000 equal followers: once,
    not 10 000 times, which took longer than simulating them)."""
    seen: dict[Any, tuple[Any, Callable[[ca.SX], CarFollowingLaw], list[float]]] = {}
    out = []
    for law in laws:
        key = exact_key(law)
        if key is None:
            out.append(_law_template(law))
            continue
        if key not in seen:
            seen[key] = _law_template(law)
        out.append(seen[key])
    return out


def _float_paths(obj: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """The attribute paths of every float field of a (nested) dataclass ``obj``, depth first (bools and ints are
    not floats here: they shape the model, so they stay compiled in)."""
    out: list[tuple[str, ...]] = []
    for f in dataclasses.fields(obj):
        x = getattr(obj, f.name)
        if isinstance(x, float):
            out.append(prefix + (f.name,))
        elif dataclasses.is_dataclass(x) and not isinstance(x, type):
            out.extend(_float_paths(x, prefix + (f.name,)))
    return out


def _with_symbols(obj: Any, paths: Sequence[tuple[str, ...]], p: Any) -> Any:
    """A copy of the dataclass ``obj`` with the float at ``paths[j]`` replaced by ``p[j]`` (copies bypass the frozen
    dataclass and its validation, which ran on ``obj``)."""
    twin = copy.copy(obj)
    groups: dict[str, list[tuple[int, tuple[str, ...]]]] = {}
    for j, path in enumerate(paths):
        groups.setdefault(path[0], []).append((j, path[1:]))
    for name, items in groups.items():
        if len(items) == 1 and not items[0][1]:
            object.__setattr__(twin, name, p[items[0][0]])
        else:
            sub = _with_symbols(getattr(obj, name), [rest for _, rest in items], [p[j] for j, _ in items])
            object.__setattr__(twin, name, sub)
    return twin


def _outputs(f: ca.Function, values: Any, points: Sequence[Any]) -> list[np.ndarray] | None:
    """``f``'s outputs at every probe point (columns), the last input the runtime parameters ``values`` at each: one
    call of ``f`` mapped over the points (the same operations per point as a call per point; issue 40); None when
    ``f`` cannot be evaluated there."""
    try:
        k = len(points)
        args = [np.column_stack([np.asarray(pt[i], float).ravel() for pt in points]) for i in range(len(points[0]))]
        args.append(np.repeat(np.asarray(values, float).reshape(-1, 1), k, axis=1))
        return [np.asarray(r, float) for r in f.map(k).call(args)]
    except (TypeError, ValueError, RuntimeError, NotImplementedError, ParameterError):
        return None


def _same_outputs(a: list[np.ndarray] | None, b: list[np.ndarray] | None) -> bool:
    """Both evaluated, and equal bit for bit (NaN where NaN)."""
    if a is None or b is None or len(a) != len(b):
        return False
    return all(x.shape == y.shape and np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))


def _same_function(baked: ca.Function, symbolic: ca.Function, values: Any, points: Sequence[Any]) -> bool:
    """``symbolic`` evaluates bit for bit like ``baked`` (same inputs; the last one, the runtime parameters
    ``values``, is unused by ``baked``) at every probe point, NaN where it is NaN: the parameters replaced the
    compiled-in numbers without changing the model or its rounding (a parameter that changes how CasADi folds
    the constants, e.g. a product of several of them, fails this and stays compiled in: the paper's numbers
    stay bit-identical)."""
    return _same_outputs(_outputs(baked, values, points), _outputs(symbolic, values, points))


#: Lengths a recorded leader's table is padded to (a power of two from this one on): one compiled library serves
#: every trace up to that length (the shipped EPA cycles: 601-1370 samples, one table length).
TRACE_TABLE_MIN = 2048


def _trace_table(leader: SpeedTrace) -> tuple[np.ndarray, np.ndarray]:
    """(grid, speeds) of a speed trace as its interpolant holds them (the far knot 1e6 after the end holds the
    last speed), padded with knots further out at the same speed to TRACE_TABLE_MIN · 2^k entries: on
    [0, end + 1e6] the interpolated speed and its slope are those of the trace, bit for bit."""
    t, v = np.asarray(leader.times, float), np.asarray(leader.speeds, float)
    g, s = np.append(t, t[-1] + 1e6), np.append(v, v[-1])
    n = TRACE_TABLE_MIN
    while n < g.size:
        n *= 2
    pad = n - g.size
    return np.concatenate([g, g[-1] + np.arange(1.0, pad + 1.0)]), np.concatenate([s, np.full(pad, s[-1])])


def _leader_template(leader: LeaderProfile) -> tuple[ca.Function, np.ndarray]:
    """The leader as a compiled-source-independent function ``aevsim_leader(t, q) -> (v_l, dv_l/dt)`` and the
    runtime parameters q of this leader: a speed trace's padded table (:func:`_trace_table`), or the float fields
    of a dataclass profile (constant speed, the paper's leader, braking). Any other profile, or one whose speed
    needs numbers, is compiled with its numbers in (q empty)."""
    t = ca.SX.sym("t")

    def fn(v: Any, q: Any) -> ca.Function:
        return ca.Function("aevsim_leader", [t, q], [ca.vertcat(v, ca.jacobian(v, t))])

    vb = leader.speed(t)
    q0 = ca.SX.sym("q", 0)
    probes = [(0.0,), (0.37,), (3.3,), (17.9,), (25.1,), (180.4,)]
    if isinstance(leader, SpeedTrace):
        g, s = _trace_table(leader)
        q = ca.SX.sym("q", 2 * g.size)
        interp = ca.interpolant("aevsim_trace", "linear", [g.size], 1)
        f = fn(interp(ca.fmax(t, 0.0), q[: g.size], q[g.size :]), q)
        values = np.concatenate([g, s])
        probes += [(float(x),) for x in leader.times[:: max(1, len(leader.times) // 7)]]
        if _same_function(fn(vb, q), f, values, probes):
            return f, values
    elif dataclasses.is_dataclass(leader):
        paths = _float_paths(leader)
        q = ca.SX.sym("q", len(paths))
        values = np.array([float(_get(leader, pth)) for pth in paths])
        try:
            f = fn(_with_symbols(leader, paths, q).speed(t), q)
        except (TypeError, ValueError, RuntimeError, NotImplementedError, ParameterError):
            f = None
        if f is not None and _same_function(fn(vb, q), f, values, probes):
            return f, values
    return fn(vb, q0), np.zeros(0)


def ev_probe_points(battery: bool, actuator: bool) -> list[tuple[list[float], list[float]]]:
    """The fixed points (u = (v_l, a_l), x) at which a follower's right-hand side with the vehicle's fields as runtime
    parameters must equal the compiled-in one (:meth:`PlatoonSimulator._probe_ev_paths`): four chosen, 60 drawn from
    a fixed seed (the choice must not depend on the run); x: h and v, then V1, V2 and S with the battery, then a_act
    with an actuator state [model units, volts]."""
    x = [1.3, 0.9] + ([3.55e-3, 1.2e-3, 0.63] if battery else [])
    x2 = [2.4, 1.35] + ([-2.1e-3, 4.0e-4, 0.38] if battery else [])
    if actuator:
        x, x2 = x + [0.07], x2 + [-0.11]
    probes = [([1.1, 0.23], x), ([0.4, -0.61], x2), ([1.62, 0.05], x2), ([0.2, 0.9], x)]
    rng = np.random.default_rng(40)
    for _ in range(60):
        xr = [rng.uniform(0.2, 3.0), rng.uniform(0.0, 2.0)]
        if battery:
            xr += [rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01), rng.uniform(0.1, 0.9)]
        if actuator:
            xr.append(rng.uniform(-0.5, 0.5))
        probes.append(([rng.uniform(0.0, 2.0), rng.uniform(-1.0, 1.0)], xr))
    return probes


#: The vehicle fields that are runtime parameters of the cascade, per model structure (found by probing once per
#: process: :meth:`PlatoonSimulator._probe_ev_paths`).
_EV_PATHS: dict[Any, tuple[tuple[str, ...], ...]] = {}


def _skeleton(obj: Any) -> Any:
    """A dataclass's non-float content (nested): the part of a vehicle's parameters that shapes its model."""
    return (type(obj),) + tuple(
        (
            f.name,
            _skeleton(x)
            if dataclasses.is_dataclass(x) and not isinstance(x, type)
            else (None if isinstance(x, float) else x),
        )
        for f in dataclasses.fields(obj)
        for x in (getattr(obj, f.name),)
    )


def _get(obj: Any, path: tuple[str, ...]) -> Any:
    for name in path:
        obj = getattr(obj, name)
    return obj


def _interruptible_call(fn: Callable[..., int], args: tuple[Any, ...], cancel: ctypes.c_int) -> int:
    """Call a compiled run (ctypes releases the GIL) in a helper thread while this thread waits in short
    slices, so Ctrl-C/SIGTERM and a passed time limit (:func:`aev_ocp.progress.check_deadline`: ``--time-limit``)
    are handled within about 0.05 s instead of when the whole run returns (also a Ctrl-C that CasADi swallowed
    while the run was built: :func:`aev_ocp.interrupts.check`): on any exception here the
    C code is told to stop through ``cancel`` and waited for (it writes into ``args``' arrays), then the exception
    propagates. Returns the C return code. The wait is an Event, not ``Thread.join``: a join interrupted by a
    signal handler's exception marks a running thread as stopped (CPython 3.11), and would return at once."""
    box: dict[str, Any] = {}
    finished = threading.Event()

    def work() -> None:
        try:
            box["rc"] = fn(*args)
        except BaseException as e:  # noqa: BLE001 - handed to the calling thread below
            box["error"] = e
        finally:
            finished.set()

    check_deadline()  # a Ctrl-C that CasADi swallowed while the run was built (its SWIG layer does), a passed limit
    cancel.value = 0
    threading.Thread(target=work, name="aev-cascade", daemon=True).start()
    try:
        while not finished.wait(0.05):
            check_deadline()
    except BaseException:
        cancel.value = 1
        while not finished.is_set():  # the C code stops within one step; a second Ctrl-C must not cut this wait
            try:
                finished.wait(0.05)
            except BaseException:  # noqa: BLE001 - the first interrupt is the one raised below
                pass
        raise
    if "error" in box:
        raise box["error"]
    return int(box["rc"])


def _compile_shared(source: str) -> tuple[ctypes.CDLL | None, str]:
    """Compile and load the cascade's C source (cached, see :mod:`aev_ocp.compiled`); (None, why) on failure."""
    # tuned first (-O3, native CPU, no contraction: the same bits, ~35 % less CPU at 300 followers), else plain
    return load_fastest(source, "aevsim", "simulate", (exact_tuned_flags(), ()))


def _segments(t_end: float, breakpoints: Sequence[float], chunk: float) -> list[tuple[float, float]]:
    """Intervals covering [0, t_end], split exactly at breakpoints and into pieces of length ≤ chunk."""
    cuts = [0.0] + sorted(b for b in breakpoints if 0.0 < b < t_end) + [t_end]
    out: list[tuple[float, float]] = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        m = max(1, math.ceil((b - a) / chunk - 1e-9))
        edges = np.linspace(a, b, m + 1)
        out.extend(zip(edges[:-1].tolist(), edges[1:].tolist()))
    return out


class PlatoonSimulator(PlatoonRun):
    """A platoon behind ``leader`` with one law per follower; build once, run many initial conditions.

    Vehicle i (0-based) follows vehicle i − 1; vehicle 0 follows the leader.
    """

    who = "simulate"

    def __init__(
        self,
        leader: LeaderProfile,
        laws: Sequence[CarFollowingLaw],
        ev: EVParams | None = None,
        options: SimOptions | None = None,
        battery: bool = True,
    ) -> None:
        check_argument("simulate", "leader", leader, LeaderProfile)
        check_argument("simulate", "ev", ev, (EVParams, type(None)))
        check_argument("simulate", "options", options, (SimOptions, type(None)))
        if isinstance(laws, (str, bytes)) or not hasattr(laws, "__len__"):
            raise TypeError(f"simulate: laws must be a sequence of CarFollowingLaw, got {type(laws).__name__}")
        for i, law in enumerate(laws):
            check_argument("simulate", f"laws[{i}]", law, CarFollowingLaw)
        if len(laws) < 1:
            raise ParameterError("simulate: the platoon needs at least one follower (laws is empty)")
        self.leader, self.laws = leader, list(laws)
        self.ev = ev or EVParams()
        self.opts = options or SimOptions()
        self.battery = battery
        self.n = len(self.laws)
        self.k = max(1, math.ceil(self.opts.chunk / self.opts.dt_out - 1e-9))
        self._lib: ctypes.CDLL | None = None
        self._build_error = ""
        thermal = battery and self.ev.thermal.enabled
        if thermal and self.opts.method == "cascade":  # the compiled cascade has no temperature state
            raise ParameterError(
                "SimOptions.method = 'cascade' does not integrate the thermal model "
                "(thermal.enabled = true); use method='cvodes' or 'auto'"
            )
        if self.opts.method in ("auto", "cascade") and not thermal:  # thermal runs: the CVODES plant
            self._build_cascade()
            if self._lib is None and self.opts.method == "cascade":
                raise ParameterError(
                    "SimOptions.method = 'cascade' needs a working C compiler (gcc/cc): "
                    f"{self._build_error}; use method='cvodes' or 'auto'"
                )
            if self._lib is None and self._build_error not in _FALLBACK_WARNED:  # say it, once per cause
                # (a failed build was already reported by aev_ocp.compiled; this says what happens next)
                _FALLBACK_WARNED.add(self._build_error)
                warnings.warn(
                    f"simulate: the compiled cascade is unavailable ({self._build_error}); "
                    "integrating with CVODES instead (slower, same results)",
                    RuntimeWarning,
                    stacklevel=3,
                )
        self.method = "cascade" if self._lib is not None else "cvodes"
        if self.method == "cvodes":
            self.plant = Plant(
                self.leader,
                self.laws,
                self.ev,
                battery=battery,
                rtol=self.opts.rtol,
                atol=self.opts.atol,
                max_num_steps=self.opts.max_num_steps,
                samples=self.k,
            )

    # ------------------------------------------------------------------ compiled cascade
    def _vehicle_function(self, law: CarFollowingLaw, k: int, p: ca.SX, ev: Any = None) -> ca.Function:
        """One follower's right-hand side: (u = (v_l, a_l), x, p) -> (dz = (ẋ, quadrature integrands), y = (a, I, disc)),
        p the runtime parameters (the law's coefficients, see :func:`_law_template`, then the vehicle's, see
        :meth:`_ev_template`); ``ev``: the vehicle's parameters as used in the expressions (default
        ``self.ev``: its numbers compiled in); the model's structure (limits on, actuator state, battery) is
        always read from ``self.ev``.

        x = (h, v[, V1, V2, S]) in model units and volts; quadrature integrands per model time unit:
        ω, (V(h) − v)², (v_l − v)², jerk²[, pack Q and Q_irr], P_b (the last three in J per model time unit)."""
        ev = self.ev if ev is None else ev
        T, eta = ev.units.time_s, ev.vehicle.efficiency
        u = ca.SX.sym("u", 2)
        vl, al = u[0], u[1]
        h, v = ca.SX.sym("h"), ca.SX.sym("v")
        a = law.accel(h, v, vl)
        hdot = vl - v
        lim = ev.limits
        act: ca.SX | None = None
        dact: Any = None
        if self.ev.limits.enabled:  # the vehicle's limits, as in aev_ocp.plant.Plant (off: the same graph as before)
            a_sat = saturate(a, lim, ev.units)
            if self.ev.limits.has_actuator_state:
                act = ca.SX.sym("a_act")
                dact = actuator_rate(a_sat, act, lim, ev.units)
                a_sat = act
            a = speed_cut(a_sat, v, lim, ev.units)
        jerk = ca.jacobian(a, h) * hdot + ca.jacobian(a, v) * a + ca.jacobian(a, vl) * al
        if act is not None and dact is not None:
            jerk = jerk + ca.jacobian(a, act) * dact
        x, ode = [h, v], [hdot, a]
        quad = [v * energy.g_exact(a, eta), (optimal_velocity(h) - v) ** 2, hdot**2, jerk**2]
        b: dict[str, Any] | None = None
        if self.battery:
            V1, V2, S = ca.SX.sym("V1"), ca.SX.sym("V2"), ca.SX.sym("S")
            b = battery_side(v, a, V1, V2, S, ev)
            x += [V1, V2, S]
            ode += [T * b["dV1"], T * b["dV2"], T * b["dS"]]
            quad += [T * b["Q_pack"], T * b["Q_irr_pack"]]
            y = [a, b["I"], b["disc"]]
        else:
            y = [a, ca.SX(0), ca.SX(0)]
        # battery energy ∫P_b dt [J per model time unit], last and outside the error norm (cascade.c
        # AEV_NQ_OUT): an output only, so the steps, the states and the other integrals are those without it
        quad.append(T * battery_power_integrand(v, a, ev, b))
        if act is not None:  # the actuator state last (after the battery's), as in the plant
            x.append(act)
            ode.append(dact)
        return ca.Function(f"aevsim_law{k}", [u, ca.vertcat(*x), p], [ca.vertcat(*ode, *quad), ca.vertcat(*y)])

    def _ev_template(
        self, make: Callable[[Any], CarFollowingLaw], law_values: np.ndarray, n_par: int
    ) -> tuple[Callable[[Any], Any], np.ndarray]:
        """(ev(q), values): the vehicle's parameters with float fields (mass, drag, the cell's coefficients, the
        units, …) replaced by the runtime parameters q, and their numbers, so one compiled library serves every
        vehicle and scenario of the same structure. A field whose symbolic value does not give the same
        right-hand side at probe points (the model turns it into a number, e.g. ``float(...)``) stays compiled
        in: the fields chosen are found once per structure (:data:`_EV_PATHS`)."""
        skeleton = (self.battery, _skeleton(self.ev), _law_template(self.laws[0])[0])
        paths = _EV_PATHS.get(skeleton)
        if paths is None:
            paths = _EV_PATHS[skeleton] = self._probe_ev_paths(make, law_values, n_par)
        values = np.array([float(_get(self.ev, pth)) for pth in paths])
        return (lambda q: _with_symbols(self.ev, paths, q)), values

    def _probe_ev_paths(
        self, make: Callable[[Any], CarFollowingLaw], law_values: np.ndarray, n_par: int
    ) -> tuple[tuple[str, ...], ...]:
        """The float fields of ``self.ev`` that may be runtime parameters (see :meth:`_ev_template`): all of them
        if that gives the compiled-in right-hand side at probe points, else each top-level group (units,
        vehicle, cell, …) that does as a whole (a group that fails stays compiled in)."""
        every = _float_paths(self.ev)
        probes = ev_probe_points(self.battery, self.ev.limits.has_actuator_state)
        law = np.concatenate([law_values, np.zeros(n_par - law_values.size)])
        # one parameter vector for every candidate set (the law's, then up to all the vehicle's fields; a set uses
        # the first entries, the rest are unused): the compiled-in right-hand side is built and evaluated once
        p = ca.SX.sym("p", n_par + len(every))
        try:
            unused = np.zeros(len(every))  # the compiled-in function reads the law's entries only
            baked = _outputs(self._vehicle_function(make(p[:n_par]), 0, p), np.concatenate([law, unused]), probes)
        except (TypeError, ValueError, RuntimeError, NotImplementedError, ParameterError, AttributeError):
            baked = None
        if baked is None:
            return ()

        def ok(paths: Sequence[tuple[str, ...]]) -> bool:
            if not paths:
                return False
            ev_values = [float(_get(self.ev, pth)) for pth in paths]
            values = np.concatenate([law, ev_values, np.zeros(len(every) - len(paths))])
            try:
                ev = _with_symbols(self.ev, paths, p[n_par : n_par + len(paths)])
                symbolic = self._vehicle_function(make(p[:n_par]), 0, p, ev)
            except (TypeError, ValueError, RuntimeError, NotImplementedError, ParameterError, AttributeError):
                return False
            return _same_outputs(baked, _outputs(symbolic, values, probes))

        if ok(every):
            return tuple(every)
        chosen: list[tuple[str, ...]] = []
        for group in dict.fromkeys(pth[0] for pth in every):
            members = [pth for pth in every if pth[0] == group]
            chosen += members if ok(members) else []
        return tuple(chosen) if ok(chosen) else ()

    def _build_cascade(self) -> None:
        """Generate C for each distinct law and the leader, append the cascade driver, compile, load."""
        # one compiled right-hand side per law *template*: the coefficients of dataclass laws are runtime
        # parameters, so a sweep of κ, α, … reuses the compiled library
        self._law_of: list[int] = []
        distinct: dict[Any, int] = {}
        templates = _law_templates(self.laws)
        n_par = max(1, *(len(t[2]) for t in templates))
        self._params = np.zeros((self.n, n_par))
        first: dict[int, tuple[Any, ...]] = {}
        for i, (key, make, values) in enumerate(templates):
            k = distinct.setdefault(key, len(distinct))
            first.setdefault(k, (make, len(values)))
            self._law_of.append(k)
            self._params[i, : len(values)] = values
        self._nx = (5 if self.battery else 2) + int(self.ev.limits.has_actuator_state)
        ev_sym, ev_values = self._ev_template(first[0][0], self._params[0, : first[0][1]], n_par)
        p = ca.SX.sym("p", n_par + ev_values.size)
        self._params = np.hstack([self._params, np.tile(ev_values, (self.n, 1))])
        pe = p[n_par:]
        funcs = [
            self._vehicle_function(make(p[:n_par]), k, p, ev_sym(pe) if ev_values.size else None)
            for k, (make, _) in first.items()
        ]
        leader_fn, self._leader_values = _leader_template(self.leader)
        funcs.append(leader_fn)
        funcs = [dense_outputs(f) for f in funcs]  # the driver reads every output as a dense vector
        self._nq = 7 if self.battery else 5  # the last: battery energy ∫P_b, outside the error norm
        cg = ca.CodeGenerator("aevsim_rhs.c", {"with_header": False})
        for f in funcs:
            cg.add(f)
        sizes = {
            "SZ_ARG": max(3, *(f.sz_arg() for f in funcs)),
            "SZ_RES": max(2, *(f.sz_res() for f in funcs)),
            "SZ_IW": max(f.sz_iw() for f in funcs),
            "SZ_W": max(f.sz_w() for f in funcs),
        }
        head = "".join(f"#define {k} {v}\n" for k, v in sizes.items())
        eta = self.ev.vehicle.efficiency
        # the g split A, B (cascade.c), then the leader's parameters: run-time inputs, not compiled in
        self._globals = np.concatenate([[0.5 * (1 / eta + eta), 0.5 * (1 / eta - eta)], self._leader_values])
        head += f"#define NX {self._nx}\n#define NQ {self._nq}\n#define NY 3\n#define BATTERY {int(self.battery)}\n"
        head += f"#define AEV_NP {n_par + ev_values.size}\n"
        # with vehicle limits the jerk integrand jumps at every saturation corner (0 ↔ the law's rate of change);
        # the error test then cannot pass on ∫jerk² (steps underflow): it is integrated, not error-controlled
        head += f"#define AEV_JERK_UNCONTROLLED {int(self.ev.limits.enabled)}\n"
        head += "#define AEV_NQ_OUT 1\n"  # the battery energy: integrated on the steps, not error-controlled
        head += (
            "#define AEV_LAW_SWITCH "
            + " ".join(f"case {k}: return aevsim_law{k}(c->arg, c->res, c->iw, c->w, 0);" for k in range(len(distinct)))
            + "\n"
        )
        head += event_header()
        driver = driver_source("cascade.c")
        source = cg.dump() + "\n" + head + driver
        lib, self._build_error = _compile_shared(source)
        if lib is None:
            return
        fn = lib.aevsim_run
        dp, ip, lp = (np.ctypeslib.ndpointer(dtype=d, flags="C_CONTIGUOUS") for d in (np.float64, np.int32, np.int64))
        fn.argtypes = [
            ctypes.c_int,
            ip,
            dp,
            dp,
            ctypes.c_int,
            dp,
            ctypes.c_int,
            dp,
            ctypes.c_double,
            ctypes.c_double,
            ctypes.c_int64,
            dp,
            ip,
            ip,
            dp,
            dp,
            lp,
            dp,
            dp,
        ]
        fn.restype = ctypes.c_int
        self._lib, self._run_c = lib, fn

    def _sample_times(self, t_end: float) -> np.ndarray:
        """The sample grid [model time]: the same chunks of ≤ dt_out as the CVODES path."""
        ts = [0.0]
        for a, b in _segments(t_end, self.leader.breakpoints, self.opts.chunk):
            ts.extend((a + (b - a) * np.linspace(0.0, 1.0, self.k + 1)[1:]).tolist())
        return np.asarray(ts)

    def _run_cascade(self, x0: np.ndarray, t_end: float, progress: ProgressFn | None) -> SimulationResult:
        """Integrate vehicle by vehicle in compiled code; stop everything at the first event."""
        n, nx, nq = self.n, self._nx, self._nq
        ncol = nx + nq + 3
        ts = self._sample_times(t_end)
        K = ts.size
        stops = np.asarray(sorted({b for b in self.leader.breakpoints if 0.0 < b < t_end} | {t_end}), float)
        # the samples by (quantity, vehicle) x time as cascade.c writes them (row c·n + i = column c of vehicle i), and
        # the leader's speed in the last row: the result's arrays are views of this one table (no transpose, no copy)
        table = np.empty((ncol * n + 1, K))
        out = table[: ncol * n]
        x0v = np.ascontiguousarray(x0.reshape(nx, n).T)
        nsamp, kind, ev_time, ev_val, stats, last = self._call_c(n, x0v, stops, ts, out)
        events: list[Event] = []
        hit = np.where(kind > 0)[0]
        keep = K
        end_col: np.ndarray | None = None  # the platoon's state at a located event: the run's last sample
        if hit.size:
            i = int(hit[np.argmin(ev_time[hit])])  # first in time; ties -> the vehicle nearest the leader
            t_ev = float(ev_time[i])
            if kind[i] == INTEGRATION_FAILED:
                h = float(ev_val[i])
                events.append(
                    Event(
                        "integration_failed",
                        t_ev,
                        i,
                        f"the integrator failed at t = {t_ev:.4f} with gap h = {h:.3g}"
                        + (" (near collision)" if h < 0.05 else "")
                        + f" (step size underflow, or more than {cascade_step_limit(self.opts.max_num_steps, t_end)}"
                        " steps for this vehicle: loosen simulation.rtol/atol)",
                    )
                )
            else:
                # vehicles from i on ended at t_ev (i at its event on the dense output, those behind at their last
                # step); the vehicles ahead went on, so they are integrated again to end exactly at t_ev (their steps
                # before it are the same, so are their samples)
                rows = last.copy()
                if i > 0 and t_ev > 0:
                    out2 = np.empty((ncol * i, 2))
                    stops2 = np.asarray(sorted({b for b in stops if b < t_ev} | {t_ev}), float)
                    self._call_c(i, np.ascontiguousarray(x0v[:i]), stops2, np.array([0.0, t_ev]), out2)
                    rows[:i, :ncol] = out2[:, 1].reshape(ncol, i).T
                end_col = rows[:, :ncol].T.reshape(-1)  # row c·n + i = column c of vehicle i
                rule = rule_of_code(int(kind[i]))
                events.append(
                    event_at(
                        rule,
                        t_ev,
                        i,
                        self.ev.units,
                        float(rows[i, 0]),
                        float(rows[i, 1]),
                        float(rows[i, ncol]) if i == 0 else float(rows[i - 1, 1]),
                        float(
                            {
                                "h": rows[i, 0],
                                "v": rows[i, 1],
                                "S": rows[i, 4] if self.battery else math.nan,
                                "disc": rows[i, nx + nq + 2],
                            }[rule.quantity]
                        ),
                    )
                )
            keep = max(1, int(np.searchsorted(ts, t_ev, side="left")))
        if progress is not None:
            progress(float(ts[keep - 1]), t_end)
        tk = ts[:keep]
        if keep < K:  # a run stopped early: its samples alone (the result does not hold on to the whole table)
            table = np.ascontiguousarray(table[:, :keep])
        if end_col is not None and t_ev > tk[-1]:
            tk, table = np.append(tk, t_ev), np.hstack([table, np.append(end_col, 0.0)[:, None]])
            keep += 1
        table[ncol * n] = np.ravel(self.leader.speed_np(tk))  # the leader caches its mapped Function per size
        Z, Y = table[: ncol * n], table[(nx + nq) * n :]
        return assemble_result(
            self.leader,
            self.ev,
            self.battery,
            tk,
            Z[: nx * n],
            Z[nx * n : (nx + nq) * n],
            Y,
            events,
            [law.name for law in self.laws],
            self._meta("cascade-dopri5"),
            solver_stats=[{k: int(x) for k, x in zip(INTEGRATOR_STATS, s)} for s in stats],
            energy_quad=nq - 1,
        )

    def _call_c(
        self, n: int, x0v: np.ndarray, stops: np.ndarray, ts: np.ndarray, out: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        """Run the compiled cascade for the first n vehicles from x0v (n, nx) with samples at ts into ``out``
        ((nx + nq + 3)·n rows, one per quantity and vehicle, × ts.size, C order: see aevsim_run in cascade.c):
        (nsamp, kind, ev_time, ev_val, stats, last)."""
        ncol = self._nx + self._nq + 3
        nsamp, kind = np.zeros(n, np.int32), np.zeros(n, np.int32)
        ev_time, ev_val, stats = np.zeros(n), np.zeros(n), np.zeros((n, 3), np.int64)
        last = np.zeros((n, ncol + 1))
        args = (
            n,
            np.asarray(self._law_of[:n], np.int32),
            np.ascontiguousarray(self._params[:n]),
            x0v,
            stops.size,
            stops,
            ts.size,
            ts,
            self.opts.rtol,
            self.opts.atol,
            cascade_step_limit(self.opts.max_num_steps, float(ts[-1])),
            out,
            nsamp,
            kind,
            ev_time,
            ev_val,
            stats,
            last,
            self._globals,
        )
        assert self._lib is not None  # _call_c runs only on the cascade path, after a successful build
        rc = _interruptible_call(self._run_c, args, ctypes.c_int.in_dll(self._lib, "aevsim_cancel"))
        if rc == 2:  # stopped through aevsim_cancel by another thread's interrupt of the same library
            raise interrupts.Interrupted("the compiled cascade was cancelled")
        if rc != 0:
            raise MemoryError("simulate: the cascade integrator ran out of memory")
        return nsamp, kind, ev_time, ev_val, stats, last

    def _meta(self, integrator: str) -> dict[str, object]:
        return {
            "integrator": integrator,
            "rtol": self.opts.rtol,
            "atol": self.opts.atol,
            "dt_out": self.opts.dt_out,
            "laws": [law.describe() for law in self.laws],
        }

    # ------------------------------------------------------------------ running
    def _run(self, x0: np.ndarray, t_end: float, progress: ProgressFn | None) -> SimulationResult:
        """Integrate from x0 over [0, t_end] (model time); see :meth:`PlatoonRun.run`."""
        check_simulation_size(self.n, t_end, self.opts.dt_out)
        x = x0
        if self.method == "cascade":
            return self._run_cascade(x, t_end, progress)
        plant = self.plant
        q = np.zeros(plant.nq)
        y0 = plant.samples(np.array([0.0]), x[:, None])
        out: tuple[list, list, list, list] = ([np.array([0.0])], [x[:, None]], [q[:, None]], [y0])
        events: list[Event] = []
        ev0 = plant.check(np.array([0.0]), x[:, None], y0)
        if ev0:
            events.append(ev0)
        else:
            for a, b in _segments(t_end, self.leader.breakpoints, self.opts.chunk):
                check_deadline()  # Ctrl-C or a passed time limit (aev_ocp.progress.time_limited): between chunks
                ok = plant.advance(a, b, out[1][-1][:, -1], out[2][-1][:, -1], None, out, events)
                if progress is not None:
                    progress(min(b, out[0][-1][-1] if out[0][-1].size else a), t_end)
                if not ok:
                    break
        return plant.result(stack_samples(out), events, [law.name for law in self.laws], self._meta("cvodes"))


def simulate_platoon(
    leader: LeaderProfile,
    laws: Sequence[CarFollowingLaw],
    gaps0: Sequence[float],
    speeds0: Sequence[float],
    t_end: float,
    *,
    ev: EVParams | None = None,
    soc0: float | Sequence[float] | None = None,
    dt_out: float = 0.01,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    battery: bool = True,
    progress: ProgressFn | None = None,
    method: str = "auto",
) -> SimulationResult:
    """Simulate followers behind ``leader`` (model units) over [0, t_end]; see :class:`PlatoonSimulator`.
    method: "auto" (compiled cascade when a C compiler works, else CVODES), "cascade" or "cvodes"."""
    sim = PlatoonSimulator(
        leader, laws, ev, SimOptions(dt_out=dt_out, rtol=rtol, atol=atol, method=method), battery=battery
    )
    return sim.run(gaps0, speeds0, t_end, soc0=soc0, progress=progress)

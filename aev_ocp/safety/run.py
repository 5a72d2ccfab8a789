"""Run the safety suite: every case (:mod:`.cases`) for every controller, bare and under the safety layer, at the
ideal and the declared actuator, with the case's avoidability label at each.

Controllers (:data:`CONTROLLERS`): the MPC on the shipped defaults (``MPCSettings()``: the traffic formulation, the
decaying-acceleration forecast; *as shipped it already limits every command by its own braking-distance filter*),
``mpc-margin`` (the same with the soft time-gap / TTC margin of :class:`~aev_ocp.ocp.traffic.TrafficParams` on),
``wave-mpc`` (the ring's wave-damping MPC, :class:`~aev_ocp.mpc.wave.WaveMPC` with its default WaveParams, the
suite's MPC settings and a measured forecast; like the MPC it filters every command by its braking distance),
the proposed law and OVFL as published (the paper's coefficients, continuous, inside the plant, saturated to the
vehicle's [a_min, a_max]) and IDM with Treiber & Kesting's SI parameters (:func:`treiber_idm`). A name with the
suffix ``+layer`` runs that controller under the braking-distance safety layer
(:meth:`aev_ocp.mpc.safe_fallback.SafeFallback.for_vehicle`, min(controller, safe), sampled every dt = 0.1 model =
88 ms) with the actuator's worst-case delay in its reaction time (:func:`layer_changes`: the lag and the jerk
limit). Each run is the existing closed loop (:class:`ClosedLoop`) or simulator (:func:`simulate_platoon`, CVODES)
on the exact plant; nothing here integrates.

Per case, actuator and controller (SI): collision time [s] and impact speed [m/s] (the plant's located contact
event), min gap [m] (≤ 0 at contact), min time-to-collision [s], the time gap h/v [s] while following (v ≥
:data:`FOLLOW_MIN_SPEED_MPS`) at its 5/50/95 % quantiles, peak deceleration [m/s²], peak jerk [m/s³] (sampled:
Δa/Δt between samples, without the intervals that touch a standstill: the plant's step to a = 0 when a car stops
is not a jerk the controller commands), floor violations (samples with gap < the 2 m floor, the contact counted as
one, and the time spent there [s]).

Cases are independent: with ``workers`` > 1 they run on a process pool (one case per task, each worker builds its
MPCs once; within a case every sampled controller at one actuator runs on one plant, built once), with the study runner's worker guard (:mod:`aev_ocp.study.runner`). A sampled MPC asked for both bare
and under the layer (the default's ``mpc`` and ``mpc+layer``) runs under the layer first; when the layer changed
none of its commands, that run is the bare run too (the same controller, reset, saw the same observations and sent
the same commands), and the bare MPC is not run again: in the whole suite this holds in 82 of 98 case × actuator
pairs. ``progress`` gets one line per case as it ends (``case k/n name``, n the number of cases); the warnings the
case's runs raised (e.g. a gap below the MPC's own floor) follow that line, re-issued in this process with the
case's name, also when the case ran in a worker.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..control import ClosedLoop, Command, Observation
from ..limits import check_suite_size
from ..models.carfollowing import IDM, OVFL, CarFollowingLaw, Proposed
from ..models.leader import BrakingLeader
from ..mpc.policy import MPCPolicy
from ..mpc.predictors import make_predictor
from ..mpc.settings import MPCSettings
from ..ocp.formulation import Formulation, traffic_formulation
from ..ocp.traffic import TrafficParams
from ..params import EVParams, ParameterError, Units, VehicleLimits
from ..plant import Plant, warn_floor_violations
from ..results import SimulationResult, require_pandas, summary_html, summary_text
from ..simulate import simulate_platoon
from .cases import ACTUATORS, CASE_UNITS, Actuator, SafetyCase, suite_cases
from ..mpc.safe_fallback import SafeFallback
from ..models.braking import AVOIDABLE, BrakingBound, braking_bound

BASES = ("mpc", "mpc-margin", "wave-mpc", "proposed", "ovfl", "idm")
MPC_BASES = ("mpc", "mpc-margin", "wave-mpc")  # the sampled MPCs (their own dt, built once per process)
LAYER = "+layer"
CONTROLLERS = BASES + tuple(b + LAYER for b in BASES)
#: The suite's default: every law and the MPC bare and with the layer, and the MPC with its margin under the layer.
DEFAULT_CONTROLLERS = (
    "mpc",
    "proposed",
    "ovfl",
    "idm",
    "mpc+layer",
    "proposed+layer",
    "ovfl+layer",
    "idm+layer",
    "mpc-margin+layer",
    "wave-mpc+layer",
)
DEFAULT_ACTUATORS = ("ideal", "declared")
LAW_DT_OUT = 0.01  # output spacing of the laws' runs [model time] (8.8 ms at the case units)
LAYER_DT = 0.1  # the layer's (and the MPC's) sampling period [model time] (88 ms at the case units)
FOLLOW_MIN_SPEED_MPS = 2.0  # time gaps are taken while the ego drives at ≥ 2 m/s (below, h/v → ∞ at a stop)
STANDSTILL_MPS = 0.05  # a sample at or below this speed is a standstill (peak jerk leaves its intervals out)
#: The soft margin of 'mpc-margin' (TrafficParams: w_m [W/kg per m²]; T_m = 1.8 s and TTC_m = 4 s by default).
MARGIN_WEIGHT = 1.0
#: The suite's IDM: a = 1.0 m/s², b = 1.5 m/s², s0 = 2 m, δ = 4 as in Treiber & Kesting, Traffic Flow Dynamics
#: (Springer 2013), Table 11.2 (the :class:`IDM` class's defaults); v0 is the case's speed. The time gap is the suite's
#: own choice, T = 1.5 s, not that table's 1.0 s: a more cautious human reference for cases that brake hard at
#: motorway speed (a stated choice, not a fit); the ring and the platoon use the class's 1.0 s.
TREIBER_IDM_SI = {"a_mps2": 1.0, "b_mps2": 1.5, "T_s": 1.5, "s0_m": 2.0}


def treiber_idm(v0_mps: float, units: Units) -> IDM:
    """The IDM with Treiber & Kesting's SI parameters (:data:`TREIBER_IDM_SI`) and desired speed v0_mps [m/s],
    in the model units of ``units`` (the SI :class:`IDM` given ``units``: the same numbers as converting each
    parameter)."""
    if not (math.isfinite(v0_mps) and v0_mps > 0):
        raise ParameterError(f"treiber_idm: v0_mps = {v0_mps!r} is not allowed: must be a finite speed > 0")
    p = TREIBER_IDM_SI
    law = IDM(a_mps2=p["a_mps2"], b_mps2=p["b_mps2"], v0_mps=float(v0_mps), s0_m=p["s0_m"], T_s=p["T_s"])
    return dataclasses.replace(law, model_units=units)


#: The length and speed scales of the suite's OV-type laws [m, m/s] (law parameters, not the suite's units)
LAW_SCALE_M, LAW_SCALE_MPS = 15.0, 17.0


def _law(
    name: str, case: SafetyCase, units: Units, overrides: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()
) -> CarFollowingLaw:
    """The law by name (the plant saturates it to the vehicle's limits like every other controller), its fields
    replaced by ``overrides`` ((law, ((field, value), ...)), ...; SI for the IDM, an OV-type law's coefficients and
    scales; e.g. a tuned set, :mod:`aev_ocp.tuning.safety`)."""
    own: dict[str, Any] = dict(dict(overrides).get(name, ()))
    if name == "idm":
        return dataclasses.replace(treiber_idm(case.v_ego_mps, units), **own)
    # the OV-type laws at SI scales of their own (the drive-cycle scenarios' 15 m / 17 m/s, where the suite's numbers
    # were first measured), evaluated in whatever units the suite runs: a change of CASE_UNITS changes nothing in SI
    law: CarFollowingLaw = (
        Proposed(h_scale_m=LAW_SCALE_M, v_scale_mps=LAW_SCALE_MPS)
        if name == "proposed"
        else OVFL(h_scale_m=LAW_SCALE_M, v_scale_mps=LAW_SCALE_MPS)
    )
    return dataclasses.replace(law, **own).in_units(units)


def worst_delay_s(lim: VehicleLimits, b_mps2: float) -> float:
    """How much later [s] than an ideal actuator the realised acceleration, from a_max, delivers the braking −b:
    ∫ (a(t) + b) dt / b with a(t) the actuator's response to the command −b (:mod:`aev_ocp.models.actuator`).
    Lag τ alone: τ D/b with D = a_max + b; with the jerk limit J (J τ < D): the ramp at J down to D = J τ, then
    the lag, ((D − J τ)²/(2 J) + τ D)/b."""
    if not lim.enabled or not lim.has_actuator_state:
        return 0.0
    tau, d = lim.actuator_tau_s, lim.a_max_mps2 + b_mps2
    J = lim.jerk_max_mps3
    area = tau * d if J is None or d <= J * tau else (d - J * tau) ** 2 / (2.0 * J) + tau * d
    return area / b_mps2


def layer_changes(ev: EVParams) -> dict[str, Any]:
    """The :class:`SafetyParams` changes that make the layer's reaction time cover the vehicle's actuator: the
    fallback adds the lag's τ D/b itself (:func:`aev_ocp.mpc.safe_fallback.effective_reaction_s`); this adds the jerk
    limit's (D − J τ)²/(2 J b) and the plant's τ when only a jerk limit is set."""
    lim = ev.limits
    if not (lim.enabled and lim.has_actuator_state):
        return {}
    from ..models.safety_bound import SafetyParams

    base = SafetyParams.from_limits(lim)
    b = base.ego_brake_mps2
    extra = worst_delay_s(lim, b) - lim.actuator_tau_s * (lim.a_max_mps2 + b) / b
    return {"lag_s": lim.actuator_tau_s, "reaction_time_s": base.reaction_time_s + max(extra, 0.0)}


class LayeredController:
    """A sampled controller under the safety layer: its command limited by ``layer`` (min(command, safe)).
    ``changed_steps`` counts the commands the layer returned different from the controller's (lowered by the safe
    bound or raised to no reversal over the step), since :meth:`reset`: with none, the run is the bare controller's."""

    def __init__(self, inner: Any, layer: SafeFallback) -> None:
        self.inner, self.layer = inner, layer
        self.dt = inner.dt
        self.name = f"{inner.name}{LAYER}"
        self.changed_steps = 0

    def reset(self) -> None:
        self.inner.reset()
        self.layer.reset()
        self.changed_steps = 0

    def command(self, obs: Observation) -> Command:
        c = self.inner.command(obs)
        a = self.layer.limit(obs, c.a)
        self.changed_steps += int(a != c.a)
        return dataclasses.replace(c, a=a)

    def describe(self) -> dict[str, Any]:
        return {**self.inner.describe(), "layer": self.layer.describe()}


@dataclass
class CaseRow:
    """One case × actuator × controller, SI (module docstring)."""

    family: str
    case: str
    controller: str
    actuator: str
    layer: bool
    label: str
    bound_min_gap_m: float
    status: str
    collision: bool
    collision_time_s: float
    impact_speed_mps: float
    min_gap_m: float
    min_ttc_s: float
    time_gap_p05_s: float
    time_gap_p50_s: float
    time_gap_p95_s: float
    peak_decel_mps2: float
    peak_jerk_mps3: float
    floor_violation_samples: int
    floor_violation_s: float
    v_ego_mps: float
    gap0_m: float
    v_lead_mps: float
    a_lead_mps2: float
    source: str = ""
    fallbacks: int = 0
    safety_limited_steps: int = 0
    wall_s: float = 0.0
    message: str = ""

    @property
    def failed(self) -> bool:
        """A collision or a floor violation in an avoidable case."""
        return self.label == AVOIDABLE and (self.collision or self.floor_violation_samples > 0)


def min_ttc_s(gap_m: np.ndarray, v_ego_mps: np.ndarray, v_lead_mps: np.ndarray) -> float:
    """The smallest time-to-collision [s] over the samples: gap / (v_ego − v_lead) where the ego closes in
    (v_ego > v_lead), inf where it never does."""
    closing = np.asarray(v_ego_mps, float) - np.asarray(v_lead_mps, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 1e-9, np.asarray(gap_m, float) / closing, np.inf)
    return float(np.min(ttc)) if ttc.size else math.inf


def time_gap_quantiles_s(
    gap_m: np.ndarray, v_ego_mps: np.ndarray, qs: Sequence[float] = (0.05, 0.5, 0.95)
) -> list[float]:
    """Quantiles [s] of the time gap h/v over the samples where the ego follows (v ≥ FOLLOW_MIN_SPEED_MPS); NaN
    when it never does."""
    v = np.asarray(v_ego_mps, float)
    on = v >= FOLLOW_MIN_SPEED_MPS
    if not np.any(on):
        return [math.nan] * len(qs)
    tg = np.asarray(gap_m, float)[on] / v[on]
    return [float(x) for x in np.quantile(tg, list(qs))]


def peak_jerk_mps3(t_s: np.ndarray, a_mps2: np.ndarray, v_mps: np.ndarray) -> float:
    """max |Δa/Δt| [m/s³] between samples, leaving out every interval with an end at a standstill (v ≤
    STANDSTILL_MPS): the plant's cut to a = 0 when the car stops is not a commanded jerk."""
    t, a, v = (np.asarray(x, float) for x in (t_s, a_mps2, v_mps))
    if a.size < 2:
        return 0.0
    dt = np.diff(t)
    moving = (v[:-1] > STANDSTILL_MPS) & (v[1:] > STANDSTILL_MPS) & (dt > 0)
    if not np.any(moving):
        return 0.0
    return float(np.max(np.abs(np.diff(a))[moving] / dt[moving]))


def _row(
    case: SafetyCase,
    ctrl: str,
    act: str,
    r: SimulationResult,
    ev: EVParams,
    bound: BrakingBound,
    wall: float,
    floor_m: float,
) -> CaseRow:
    u = ev.units
    t_s = u.time_to_si(r.t)
    h = u.length_to_si(r.gap[:, 0])
    v = u.speed_to_si(r.speed[:, 0])
    vl = u.speed_to_si(r.leader_speed)
    a = u.accel_to_si(r.accel[:, 0])
    coll = r.status == "collision"
    t_c = v_imp = math.nan
    min_gap = float(np.min(h))
    if coll:  # the plant located the contact (event detection): the run ends there, with gap <= 0
        ev0 = r.events[0]
        t_c = float(ev0.time_s) if ev0.time_s is not None else float(u.time_to_si(ev0.time))
        v_imp = float(ev0.impact_speed_mps) if ev0.impact_speed_mps is not None else float(v[-1] - vl[-1])
        min_gap = min(min_gap, 0.0)
    dts = np.diff(t_s)
    below = h < floor_m - 1e-9
    viol_s = float(np.sum(dts[below[:-1]])) if h.size > 1 else 0.0
    n_below = int(np.sum(below)) + int(coll)  # the contact itself is below the floor (it is not a sample of r)
    if coll and math.isfinite(t_c):
        viol_s += max(0.0, t_c - float(t_s[-1])) if below[-1] else 0.0
    st = (r.solver_stats or [None])[0] or {}
    desc = (r.meta.get("controllers") or [{}])[0] or {}
    lay = desc.get("layer") or (desc if ctrl.endswith(LAYER) else {})
    limited = int((lay.get("limited_steps") if isinstance(lay, dict) else 0) or 0)
    tg = time_gap_quantiles_s(h, v)
    return CaseRow(
        case.family,
        case.name,
        ctrl,
        act,
        ctrl.endswith(LAYER),
        bound.label,
        bound.min_gap_m,
        r.status,
        coll,
        t_c,
        v_imp,
        min_gap,
        min_ttc_s(h, v, vl),
        tg[0],
        tg[1],
        tg[2],
        float(max(0.0, -np.min(a))),
        peak_jerk_mps3(t_s, a, v),
        n_below,
        viol_s,
        case.v_ego_mps,
        case.gap_m,
        case.v_lead_mps,
        case.a_lead_mps2,
        case.source,
        int(st.get("fallbacks", 0) or 0),
        limited,
        wall,
        str(r.events[0]) if r.events else "",
    )


def case_bound(case: SafetyCase, actuator: Actuator, a_min_mps2: float, floor_m: float) -> BrakingBound:
    """The case's avoidability bound with ``actuator`` (its lag τ as the plant runs it and its jerk limit)."""
    return braking_bound(
        case.v_ego_mps,
        case.gap_m,
        case.v_lead_mps,
        case.a_lead_mps2,
        t_brake_s=case.t_brake_s,
        a_min_mps2=a_min_mps2,
        lag_s=actuator.tau_s,
        floor_m=floor_m,
        jerk_max_mps3=actuator.jerk_max_mps3,
    )


@dataclass(frozen=True)
class _Setup:
    """What every task needs (picklable): controllers, actuators, the base vehicle, MPC settings, formulation."""

    controllers: tuple[str, ...]
    actuators: tuple[str, ...]
    ev: EVParams
    settings: MPCSettings
    formulation: Formulation
    keep_runs: bool
    law_overrides: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()


_POLICIES: dict[tuple[Any, ...], MPCPolicy] = {}  # per process: built once, reset by every run


def _policy_key(setup: _Setup, ev: EVParams, margin: bool) -> tuple[Any, ...]:
    return (repr(setup.settings), repr(setup.formulation), repr(ev), margin)


def _policy(setup: _Setup, ev: EVParams, margin: bool) -> MPCPolicy:
    key = _policy_key(setup, ev, margin)
    pol = _POLICIES.get(key)
    if pol is None:
        s, u = setup.settings, ev.units
        form = setup.formulation
        if margin:
            tp = form.traffic if form.kind == "traffic" else TrafficParams()
            form = traffic_formulation(
                TrafficParams(**{**vars(tp), "margin_weight": MARGIN_WEIGHT}), form.smooth, form.temperature
            )
        pred = s.predictor if s.predictor != "oracle" else "decaying-acceleration"
        pol = MPCPolicy(s, ev, Proposed(), make_predictor(pred, None, s.predictor_window, u.time_s), formulation=form)
        _POLICIES[key] = pol
    return pol


_WAVE: dict[tuple[Any, ...], MPCPolicy] = {}  # the wave MPCs, per process (kept apart: not the suite's 'mpc')


def _wave_policy(setup: _Setup, ev: EVParams) -> MPCPolicy:
    """The wave-damping MPC for ``ev`` (built once per process; every run resets it)."""
    from ..mpc.wave import WaveMPC

    key = (repr(setup.settings), repr(ev))
    pol = _WAVE.get(key)
    if pol is None:
        s = setup.settings
        pred = s.predictor if s.predictor not in ("oracle", "cooperative") else "decaying-acceleration"
        pol = _WAVE[key] = WaveMPC(ev, Proposed(), settings=s, predictor=pred)
    return pol


def _floor_and_a_min(ev: EVParams, formulation: Formulation) -> tuple[float, float]:
    u, lim = ev.units, ev.limits
    fb = formulation.bounds_model(ev)
    floor_m = float(u.length_to_si(fb.h_min)) if fb.h_min is not None else 0.0
    a_min = lim.a_min_mps2 if (lim.enabled or fb.a_min is None) else float(u.accel_to_si(fb.a_min))
    return floor_m, a_min


def _run_one(
    name: str,
    layered: bool,
    case: SafetyCase,
    setup: _Setup,
    ev: EVParams,
    leader: BrakingLeader,
    plants: dict[Any, Plant] | None = None,
) -> tuple[SimulationResult, Any]:
    """One run of controller ``name`` (under the layer if ``layered``) on ``case`` with the vehicle ``ev``: (the
    result, the sampled controller that ran, None for a bare law on the simulator). ``plants``: the closed loops'
    plant for (leader, ev), built by the first sampled run and reused by the others (every sampled controller runs
    on the same plant: one commanded vehicle behind ``leader``; a run leaves it as it was)."""

    def loop(c: Any) -> SimulationResult:
        key = (id(leader), id(ev))
        cl = ClosedLoop(leader, [c], ev, plant=None if plants is None else plants.get(key))
        if plants is not None:
            plants[key] = cl.plant
        return cl.run([h0], [v0], t_end)

    u = ev.units
    h0, v0 = float(u.length_from_si(case.gap_m)), float(u.speed_from_si(case.v_ego_mps))
    dt = LAYER_DT if name not in MPC_BASES else setup.settings.dt
    t_end = dt * max(1, round(float(u.time_from_si(case.t_end_s)) / dt))
    if name in MPC_BASES:
        inner: Any = _wave_policy(setup, ev) if name == "wave-mpc" else _policy(setup, ev, name == "mpc-margin")
        c = LayeredController(inner, SafeFallback.for_vehicle(None, ev, dt, **layer_changes(ev))) if layered else inner
        return loop(c), c
    law = _law(name, case, u, setup.law_overrides)
    if layered:
        c = SafeFallback.for_vehicle(law, ev, dt, **layer_changes(ev))
        return loop(c), c
    return simulate_platoon(leader, [law], [h0], [v0], t_end, ev=ev, dt_out=LAW_DT_OUT, method="cvodes"), None


def _bare_of(r: SimulationResult, layered: LayeredController) -> SimulationResult:
    """The bare controller's run, taken from its run under the layer when the layer changed none of its commands
    (``layered.changed_steps == 0``): the same controller (reset before each run) saw the same observations and
    sent the same commands, so the plant ran the same; only the name and the settings (without the layer's) differ,
    which this sets as the bare run does, and it says the bare run's warning of a gap below the controller's own
    floor (:func:`aev_ocp.plant.assemble_result`) under the bare name (tests/test_safety.py compares the two)."""
    meta = dict(r.meta)
    ctrl = [dict(d) if isinstance(d, dict) else d for d in meta.get("controllers") or []]
    if ctrl and isinstance(ctrl[0], dict):
        ctrl[0].pop("layer", None)
    meta["controllers"] = ctrl
    name = layered.inner.name
    if not r.events:
        warn_floor_violations(r.violations, [name])
    return dataclasses.replace(r, controllers=[name], meta=meta)


def _run_case(case: SafetyCase, setup: _Setup) -> tuple[list[CaseRow], dict[str, SimulationResult], list[Any]]:
    """Every actuator × controller of one case (a pool task: picklable in and out), and the warnings its runs
    raised ((category, message), to be shown under the case's progress line). A sampled MPC requested bare and
    under the layer runs under the layer first; its bare run is that run when the layer changed no command."""
    rows: list[CaseRow] = []
    runs: dict[str, SimulationResult] = {}
    base = setup.ev
    leader = BrakingLeader.from_si(case.v_lead_mps, case.a_lead_mps2, case.t_brake_s, base.units)
    shared = [b for b in MPC_BASES if b in setup.controllers and b + LAYER in setup.controllers]
    with warnings.catch_warnings(record=True) as caught:
        for act_name in setup.actuators:
            act = ACTUATORS[act_name]
            ev = EVParams(base.units, base.vehicle, base.cell, base.pack, act.limits(base.limits), base.thermal)
            floor_m, a_min = _floor_and_a_min(ev, setup.formulation)
            bound = case_bound(case, act, a_min, floor_m)
            done: dict[str, tuple[SimulationResult, Any, float]] = {}
            plants: dict[Any, Plant] = {}  # this actuator's closed-loop plant, built once
            for ctrl in [b + LAYER for b in shared] + list(setup.controllers):
                if ctrl in done:
                    continue
                name, layered = (ctrl[: -len(LAYER)], True) if ctrl.endswith(LAYER) else (ctrl, False)
                tic = time.perf_counter()
                lay = done.get(ctrl + LAYER) if name in shared else None
                if lay is not None and lay[1].changed_steps == 0:
                    done[ctrl] = (_bare_of(lay[0], lay[1]), lay[1].inner, time.perf_counter() - tic)
                else:
                    r, c = _run_one(name, layered, case, setup, ev, leader, plants)
                    done[ctrl] = (r, c, time.perf_counter() - tic)
            for ctrl in setup.controllers:
                r, _, wall = done[ctrl]
                rows.append(_row(case, ctrl, act_name, r, ev, bound, wall, floor_m))
                if setup.keep_runs:
                    runs[f"{act_name}/{ctrl}"] = r
    return rows, runs, [_warning_of(w) for w in caught]


def _warning_of(w: warnings.WarningMessage) -> tuple[type[Warning], str]:
    """(category, message) of a caught warning, the category one a parent process can unpickle (else UserWarning)."""
    cat = w.category
    mod = sys.modules.get(getattr(cat, "__module__", ""))
    ok = isinstance(cat, type) and issubclass(cat, Warning) and getattr(mod, cat.__qualname__, None) is cat
    return (cat if ok else UserWarning), str(w.message)


@dataclass
class SuiteOutput:
    """Rows of one suite run, its settings and the trajectories (case -> "actuator/controller" -> SimulationResult;
    empty for cases run on the process pool)."""

    rows: list[CaseRow]
    settings: dict[str, Any]
    runs: dict[str, dict[str, SimulationResult]]
    cases: list[SafetyCase]

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        ctrls = list(dict.fromkeys(r.controller for r in self.rows))
        fields: list[tuple[str, Any]] = []
        for c in ctrls:
            mine = [r for r in self.rows if r.controller == c]
            coll = sum(r.collision for r in mine)
            fields.append(
                (
                    c,
                    f"{len(self.failures(c))} failed of {len(mine)} cases, {coll} collisions, "
                    f"min gap {min(r.min_gap_m for r in mine):.3g} m",
                )
            )
        return f"SuiteOutput: {len(self.cases)} safety cases × {len(ctrls)} controllers", fields

    def __repr__(self) -> str:
        """A few lines: per controller the failures, collisions and smallest gap [m] (over the actuators)."""
        title, fields = self._repr_fields()
        return summary_text(title, [f"{k}: {v}" for k, v in fields])

    def _repr_html_(self) -> str:
        title, fields = self._repr_fields()
        keys = ("case", "actuator", "controller", "label", "status", "min_gap_m", "bound_min_gap_m")
        return summary_html(title, fields, [{k: getattr(r, k) for k in keys} for r in self.rows])

    def to_dataframe(self) -> Any:
        """One row per case × actuator × controller (the :class:`CaseRow` fields, SI). Needs pandas
        (``pip install 'aev_ocp[pandas]'``)."""
        from dataclasses import asdict

        return require_pandas("SuiteOutput.to_dataframe()").DataFrame([asdict(r) for r in self.rows])

    def plot(self, family: str | None = None) -> Any:
        """The figure of one family of cases (default the first the run has): min gap [m] per case and
        controller against the bound (:func:`aev_ocp.safety.plots.family_figure`); a matplotlib Figure."""
        from .plots import family_figure

        fams = list(dict.fromkeys(c.family for c in self.cases))
        fam = family if family is not None else (fams[0] if fams else "")
        fig = family_figure(self, fam)
        if fig is None:
            raise ValueError(f"SuiteOutput.plot: family = {family!r} has no case in this run; its families are {fams}")
        return fig

    def failures(self, controller: str = "mpc", actuator: str | None = None) -> list[CaseRow]:
        """Rows of ``controller`` (at ``actuator``; None: at any) that collided or dipped below the floor in an
        avoidable case."""
        return [
            r
            for r in self.rows
            if r.controller == controller and r.failed and (actuator is None or r.actuator == actuator)
        ]

    def avoidable_collisions(self, controller: str, actuator: str | None = None) -> list[CaseRow]:
        """Rows of ``controller`` (at ``actuator``; None: at any) with a collision in an avoidable case."""
        return [r for r in self.failures(controller, actuator) if r.collision]


def _pool_task(args: tuple[SafetyCase, _Setup]) -> tuple[list[CaseRow], dict[str, SimulationResult], list[Any]]:
    return _run_case(*args)


def _run_pool(
    cases: list[SafetyCase], setup: _Setup, workers: int, done: Callable[[int, list[CaseRow], list[Any]], None]
) -> list[list[CaseRow]]:
    """The cases on a process pool of ``workers`` (spawned, each ending itself with this process: the study
    runner's guard); results in case order, ``done`` called as each case ends (its rows and warnings)."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from .. import interrupts
    from ..study.runner import _end_with, _export_path

    _export_path()
    out: list[list[CaseRow]] = [[] for _ in cases]
    ex = ProcessPoolExecutor(
        max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_end_with, initargs=(os.getpid(),)
    )
    try:
        with interrupts.deferred(), interrupts.sigint_blocked():
            # the longest runs first, so that no worker is left with one long case at the end
            order = sorted(range(len(cases)), key=lambda k: -cases[k].t_end_s)
            futs = {ex.submit(_pool_task, (cases[k], setup)): k for k in order}
        pending = set(futs)
        while pending:
            finished, pending = wait(pending, timeout=0.25, return_when=FIRST_COMPLETED)
            for f in finished:
                k = futs[f]
                out[k], _, caught = f.result()
                done(k, out[k], caught)
    except BaseException:
        interrupts.stop_pool(ex)
        raise
    ex.shutdown(wait=True)
    return out


def run_suite(
    cases: Sequence[SafetyCase] | None = None,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    *,
    actuators: Sequence[str] = DEFAULT_ACTUATORS,
    ev: EVParams | None = None,
    settings: MPCSettings | None = None,
    formulation: Formulation | None = None,
    quick: bool = False,
    workers: int | None = 1,
    progress: Callable[[str], None] | None = None,
    law_overrides: dict[str, dict[str, float]] | None = None,
) -> SuiteOutput:
    """Every case × actuator × controller (module docstring). controllers: names of :data:`CONTROLLERS`;
    actuators: names of :data:`aev_ocp.safety.cases.ACTUATORS` ('ideal', 'declared'); ev: units, vehicle and its
    a bounds (default the cases' units L = 15 m, U = 17 m/s, :class:`VehicleLimits`' defaults; each actuator sets
    the lag and the jerk limit); settings: the MPC's solver options (default MPCSettings()); formulation: the MPC's
    problem (default the traffic formulation), whose floor the cases are labelled against; workers: processes
    (1: in this process, keeping the trajectories; None: one per core); law_overrides: {law: {field: value}} replacing
    the suite's laws' fields (default none: the laws above)."""
    for c in controllers:
        if c not in CONTROLLERS:
            raise ParameterError(f"safety suite: controller {c!r} is not allowed: must be one of {CONTROLLERS}")
    for a in actuators:
        if a not in ACTUATORS:
            raise ParameterError(f"safety suite: actuator {a!r} is not allowed: must be one of {tuple(ACTUATORS)}")
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 1):
        raise ParameterError(f"safety suite: workers = {workers!r} is not allowed: must be an integer >= 1 or None")
    cases = list(cases) if cases is not None else suite_cases(quick)
    ev = ev or EVParams(units=CASE_UNITS)
    settings = settings or MPCSettings()
    formulation = formulation or traffic_formulation()
    n_workers = min(workers or os.cpu_count() or 1, max(len(cases), 1))
    u = ev.units
    check_suite_size(  # $AEV_OCP_MAX_MEMORY_GB, before any case runs (the runs are sampled every LAW_DT_OUT at most)
        [float(u.time_from_si(c.t_end_s)) for c in cases],
        len(controllers) * len(actuators),
        LAW_DT_OUT,
        n_workers == 1,
        n_workers,
    )
    for name, fields in (law_overrides or {}).items():
        if name not in ("proposed", "ovfl", "idm") or not cases:
            raise ParameterError(f"safety suite: law_overrides names {name!r}: must be one of proposed, ovfl, idm")
        try:
            _law(name, cases[0], u, ((name, tuple(fields.items())),))
        except (TypeError, ParameterError) as exc:
            raise ParameterError(f"safety suite: law_overrides[{name!r}] = {fields!r} is not allowed: {exc}") from None
    own = tuple(
        sorted((k, tuple(sorted((f, float(x)) for f, x in v.items()))) for k, v in (law_overrides or {}).items())
    )
    setup = _Setup(tuple(controllers), tuple(actuators), ev, settings, formulation, n_workers == 1, own)
    rows: list[CaseRow] = []
    runs: dict[str, dict[str, SimulationResult]] = {}
    n_done = 0

    def done(k: int, _rows: list[CaseRow], caught: list[tuple[type[Warning], str]]) -> None:
        """The case's progress line, then the warnings its runs raised (under its line, on a pool too)."""
        nonlocal n_done
        n_done += 1
        if progress is not None:
            progress(f"case {n_done}/{len(cases)} {cases[k].name}")
        for cat, msg in caught:
            warnings.warn(f"safety case {cases[k].name}: {msg}", cat, stacklevel=2)

    if n_workers == 1:
        for k, case in enumerate(cases):
            rs, runs[case.name], caught = _run_case(case, setup)
            rows += rs
            done(k, rs, caught)
    else:
        for rs in _run_pool(cases, setup, n_workers, done):
            rows += rs
    floor_m, a_min = _floor_and_a_min(ev, formulation)
    pol = next(iter(_POLICIES.values()), None) if n_workers == 1 else None  # the MPC's settings, when built here
    st = {
        "units": {"length_m": ev.units.length_m, "speed_mps": ev.units.speed_mps},
        "limits": vars(ev.limits),
        "actuators": {
            a: {
                "lag_s": ACTUATORS[a].lag_s,
                "tau_s": ACTUATORS[a].tau_s,
                "jerk_max_mps3": ACTUATORS[a].jerk_max_mps3,
                "source": ACTUATORS[a].source,
            }
            for a in actuators
        },
        "floor_m": floor_m,
        "bound_a_min_mps2": a_min,
        "controllers": list(controllers),
        "layer_dt_s": float(ev.units.time_to_si(LAYER_DT)),
        "mpc": pol.describe() if pol is not None else None,
        "margin": {
            "weight": MARGIN_WEIGHT,
            "time_gap_s": TrafficParams().margin_time_gap_s,
            "ttc_s": TrafficParams().margin_ttc_s,
        },
        "idm_si": dict(TREIBER_IDM_SI),
        "law_overrides": {k: dict(v) for k, v in own},
        "quick": quick,
        "workers": n_workers,
    }
    return SuiteOutput(rows, st, runs, cases)

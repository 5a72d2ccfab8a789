"""Run the safety suite: every case (:mod:`.cases`) for every controller, with its avoidability label.

Controllers: the MPC on the shipped defaults (``MPCSettings()``: the traffic formulation, the decaying-acceleration
forecast, its safe fallback and safety filter), the proposed law and OVFL (continuous, inside the plant, saturated
to the vehicle's [a_min, a_max]), optionally IDM. Each run is the existing closed loop (:class:`ClosedLoop`) or
simulator (:func:`simulate_platoon`) on the exact plant; nothing here integrates.

Per case and controller (SI): collision time [s] and impact speed [m/s] (the plant's located contact event), min gap [m]
(≤ 0 at contact), min TTC [s], peak deceleration [m/s²], peak jerk [m/s³] (sampled: Δa/Δt between samples),
floor violations (samples with gap < the 2 m floor, the contact counted as one, and the time spent there [s]).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..control import ClosedLoop
from ..models.carfollowing import IDM, OVFL, CarFollowingLaw, Proposed
from ..models.leader import BrakingLeader
from ..mpc.policy import MPCPolicy
from ..mpc.predictors import make_predictor
from ..mpc.settings import MPCSettings
from ..ocp.formulation import Formulation, traffic_formulation
from ..params import EVParams, ParameterError
from ..results import SimulationResult, require_pandas, summary_html, summary_text
from ..simulate import simulate_platoon
from .cases import CASE_UNITS, SafetyCase, suite_cases
from .kinematics import AVOIDABLE, braking_bound

CONTROLLERS = ("mpc", "proposed", "ovfl", "idm")
DEFAULT_CONTROLLERS = ("mpc", "proposed", "ovfl")
LAW_DT_OUT = 0.01  # output spacing of the laws' runs [model time] (8.8 ms at the case units)


def _law(name: str) -> CarFollowingLaw:
    """The law by name; the plant saturates it to the vehicle's limits like every other controller."""
    law: CarFollowingLaw = {"proposed": Proposed(), "ovfl": OVFL(), "idm": IDM()}[name]
    return law


@dataclass
class CaseRow:
    """One case × controller, SI (module docstring)."""

    family: str
    case: str
    controller: str
    label: str
    bound_min_gap_m: float
    status: str
    collision: bool
    collision_time_s: float
    impact_speed_mps: float
    min_gap_m: float
    min_ttc_s: float
    peak_decel_mps2: float
    peak_jerk_mps3: float
    floor_violation_samples: int
    floor_violation_s: float
    v_ego_mps: float
    gap0_m: float
    v_lead_mps: float
    a_lead_mps2: float
    fallbacks: int = 0
    safety_limited_steps: int = 0
    wall_s: float = 0.0
    message: str = ""

    @property
    def failed(self) -> bool:
        """A collision or a floor violation in an avoidable case."""
        return self.label == AVOIDABLE and (self.collision or self.floor_violation_samples > 0)


def _row(
    case: SafetyCase, ctrl: str, r: SimulationResult, ev: EVParams, bound: Any, wall: float, floor_m: float
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
    closing = v - vl
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 1e-9, h / closing, np.inf)
    dts = np.diff(t_s)
    jerk = np.abs(np.diff(a)) / np.where(dts > 0, dts, np.inf) if a.size > 1 else np.zeros(1)
    below = h < floor_m - 1e-9
    viol_s = float(np.sum(dts[below[:-1]])) if h.size > 1 else 0.0
    n_below = int(np.sum(below)) + int(coll)  # the contact itself is below the floor (it is not a sample of r)
    if coll and math.isfinite(t_c):
        viol_s += max(0.0, t_c - float(t_s[-1])) if below[-1] else 0.0
    st = (r.solver_stats or [None])[0] or {}
    desc = (r.meta.get("controllers") or [{}])[0] or {}
    return CaseRow(
        case.family,
        case.name,
        ctrl,
        bound.label,
        bound.min_gap_m,
        r.status,
        coll,
        t_c,
        v_imp,
        min_gap,
        float(np.min(ttc)) if ttc.size else math.inf,
        float(max(0.0, -np.min(a))),
        float(np.max(jerk)) if jerk.size else 0.0,
        n_below,
        viol_s,
        case.v_ego_mps,
        case.gap_m,
        case.v_lead_mps,
        case.a_lead_mps2,
        int(st.get("fallbacks", 0) or 0),
        int((desc.get("safety") or {}).get("limited_steps", 0) or 0),
        wall,
        str(r.events[0]) if r.events else "",
    )


@dataclass
class SuiteOutput:
    """Rows of one suite run, its settings and the trajectories (case -> controller -> SimulationResult)."""

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
        """A few lines: per controller the failures, collisions and smallest gap [m]."""
        title, fields = self._repr_fields()
        return summary_text(title, [f"{k}: {v}" for k, v in fields])

    def _repr_html_(self) -> str:
        title, fields = self._repr_fields()
        return summary_html(
            title,
            fields,
            [
                {k: getattr(r, k) for k in ("case", "controller", "label", "status", "min_gap_m", "bound_min_gap_m")}
                for r in self.rows
            ],
        )

    def to_dataframe(self) -> Any:
        """One row per case × controller (the :class:`CaseRow` fields, SI). Needs pandas
        (``pip install 'aev_ocp[pandas]'``)."""
        from dataclasses import asdict

        return require_pandas("SuiteOutput.to_dataframe()").DataFrame([asdict(r) for r in self.rows])

    def failures(self, controller: str = "mpc") -> list[CaseRow]:
        """Rows of ``controller`` that collided or dipped below the floor in an avoidable case."""
        return [r for r in self.rows if r.controller == controller and r.failed]


def run_suite(
    cases: Sequence[SafetyCase] | None = None,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    *,
    ev: EVParams | None = None,
    settings: MPCSettings | None = None,
    formulation: Formulation | None = None,
    quick: bool = False,
    progress: Callable[[str], None] | None = None,
) -> SuiteOutput:
    """Every case × controller (module docstring). ev: units and vehicle limits (default the cases' units L = 15 m,
    U = 17 m/s with the default :class:`VehicleLimits`); settings: the MPC's solver options (default MPCSettings());
    formulation: the MPC's problem (default the traffic formulation), whose floor the cases are labelled against."""
    for c in controllers:
        if c not in CONTROLLERS:
            raise ParameterError(f"safety suite: controller {c!r} is not allowed: must be one of {CONTROLLERS}")
    cases = list(cases) if cases is not None else suite_cases(quick)
    ev = ev or EVParams(units=CASE_UNITS)
    settings = settings or MPCSettings()
    formulation = formulation or traffic_formulation()
    u, lim = ev.units, ev.limits
    fb = formulation.bounds_model(ev)
    floor_m = float(u.length_to_si(fb.h_min)) if fb.h_min is not None else 0.0
    if lim.enabled or fb.a_min is None:
        a_min = lim.a_min_mps2
    else:
        a_min = float(u.accel_to_si(fb.a_min))
    lag = lim.lag_s if lim.enabled else 0.0
    policy: MPCPolicy | None = None
    if "mpc" in controllers:  # built once, reset by every run (the same policy ClosedLoop would build)
        pred = settings.predictor if settings.predictor != "oracle" else "decaying-acceleration"
        policy = MPCPolicy(
            settings,
            ev,
            Proposed(),
            make_predictor(pred, None, settings.predictor_window, u.time_s),
            formulation=formulation,
        )
    rows: list[CaseRow] = []
    runs: dict[str, dict[str, SimulationResult]] = {}
    for k, case in enumerate(cases):
        bound = braking_bound(
            case.v_ego_mps,
            case.gap_m,
            case.v_lead_mps,
            case.a_lead_mps2,
            t_brake_s=case.t_brake_s,
            a_min_mps2=a_min,
            lag_s=lag,
            floor_m=floor_m,
        )
        leader = BrakingLeader.from_si(case.v_lead_mps, case.a_lead_mps2, case.t_brake_s, u)
        h0, v0 = float(u.length_from_si(case.gap_m)), float(u.speed_from_si(case.v_ego_mps))
        runs[case.name] = {}
        for ctrl in controllers:
            tic = time.perf_counter()
            if ctrl == "mpc":
                assert policy is not None
                dt = settings.dt
                t_end = dt * max(1, round(float(u.time_from_si(case.t_end_s)) / dt))
                r = ClosedLoop(leader, [policy], ev).run([h0], [v0], t_end)
            else:
                r = simulate_platoon(
                    leader, [_law(ctrl)], [h0], [v0], float(u.time_from_si(case.t_end_s)), ev=ev, dt_out=LAW_DT_OUT
                )
            row = _row(case, ctrl, r, ev, bound, time.perf_counter() - tic, floor_m)
            rows.append(row)
            runs[case.name][ctrl] = r
        if progress is not None:
            progress(f"case {k + 1}/{len(cases)} {case.name}")
    st = {
        "units": {"length_m": u.length_m, "speed_mps": u.speed_mps},
        "limits": vars(lim) if hasattr(lim, "__dict__") else {},
        "floor_m": floor_m,
        "bound_a_min_mps2": a_min,
        "bound_lag_s": lag,
        "controllers": list(controllers),
        "mpc": policy.describe() if policy is not None else None,
        "quick": quick,
    }
    return SuiteOutput(rows, st, runs, cases)

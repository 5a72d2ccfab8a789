"""The drive-cycle tuning's parts: what is tuned (:data:`TUNING_TABLE`), the training and held-out
cases, a parameter set in a scenario, the scoring of a run, the optimiser (:class:`Tuner`) and the study-layer
evaluator (:class:`Evaluator`). :func:`aev_ocp.tuning.cycles.run_tuning` puts them together.

What is tuned, per controller, is declared once in :data:`TUNING_TABLE`: SI parameters with bounds and their physical
meaning. A trial is one parameter set; it is scored by running it on every training scenario, each run a task of the
study layer (:func:`aev_ocp.study.runner.execute`: in this process, on the process pool or on Dask; results kept in
the hash-keyed store ``<out>/points/``, so a rerun with the same seed resumes). The budget is counted in trials and
in closed-loop evaluations (trials × training scenarios): the same for every controller.

Objective: the follower's battery energy per distance [kWh/100 km], mean over the training scenarios. Constraints
(:data:`LIMITS`, each a number that must stay ≤ 0): no run may end on an event (collision, infeasible current) or
fail and the gap stays ≥ ``min_gap_m``; on the drive cycles also the time-to-collision ≥ ``min_ttc_s``, the RMS jerk
≤ ``rms_jerk_max_mps3`` and the mean time gap while moving ≤ ``mean_time_gap_max_s`` (energy must not be bought by
falling behind the leader). Infeasible trials are handled by optuna's constrained TPE (``constraints_func``: every
feasible trial ranks above every infeasible one, infeasible ones by their summed violation); the tuned set is the best
feasible trial, the default counting as trial 0 (so the tuned set is never worse than the default on the training
set). A trial whose run failed scores :data:`PENALTY_KWH_PER_100KM`.

Training set (:func:`training_cases`): the first 120 s of UDDS (to the leader's next stop) and of HWFET, one
follower behind a measured (non-oracle) leader: the MPC forecasts with the decaying-acceleration predictor, as the
robustness study does. Held-out (:func:`heldout_cases`): the first 120 s of US06 (to the leader's next stop) and four
safety-suite cases (:mod:`aev_ocp.safety.cases`: two braking leads, a cut-in, a lane end; their initial state and
lead, in the drive-cycle scenario's vehicle without the suite's actuator lag). The ring has its own task set
(:mod:`aev_ocp.tuning.ring`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..params import ParameterError, echo

# ----------------------------------------------------------------------------- the table of what is tuned


@dataclass(frozen=True)
class Param:
    """One tuned parameter: ``name`` (SI, unit in the name), bounds ``lo`` < ``hi`` in that unit, ``log`` (sampled
    on a log scale), ``meaning`` (its physical meaning, for the table)."""

    name: str
    lo: float
    hi: float
    meaning: str
    log: bool = False

    def __post_init__(self) -> None:
        for nm in ("lo", "hi"):
            x = getattr(self, nm)
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise ParameterError(f"tuning bounds of {self.name}: {nm} = {echo(x)} is not allowed: must be a number")
        if not self.lo < self.hi:
            raise ParameterError(
                f"tuning bounds of {self.name}: lo = {echo(self.lo)} must be below hi = {echo(self.hi)}"
            )
        if self.log and self.lo <= 0:
            raise ParameterError(
                f"tuning bounds of {self.name}: lo = {echo(self.lo)} must be > 0 (the parameter is sampled on a log "
                "scale)"
            )


@dataclass(frozen=True)
class Space:
    """What is tuned for one controller: its ``label``, study-controller ``kind`` ('law' or 'mpc'), the ``law`` a
    law controller runs, and its parameters."""

    label: str
    kind: str
    law: str
    params: tuple[Param, ...]

    def param(self, name: str) -> Param:
        """The parameter ``name``; ParameterError naming the controller and the known parameters otherwise."""
        for p in self.params:
            if p.name == name:
                return p
        raise ParameterError(
            f"tuning: controller {self.label!r} has no tuned parameter {name!r}: its parameters are "
            f"{[p.name for p in self.params]}"
        )


_SCALES = (
    Param("h_scale_m", 8.0, 40.0, "the OV function's length scale ℓ: sets the equilibrium gap, ℓ V⁻¹(v/u)"),
    Param("v_scale_mps", 13.0, 30.0, "the OV function's speed scale u: V∞·u is the law's top speed"),
)
#: The tuned parameters of each controller, SI, with bounds (our choice: around the shipped defaults, wide enough to
#: move the equilibrium gap by a factor of about 3 and the response rates by about 10).
TUNING_TABLE: dict[str, Space] = {
    "proposed": Space(
        "proposed",
        "law",
        "proposed",
        (
            Param(
                "kappa_per_m", 1e-4, 2e-2, "weight of the κ term κ/ℓ (the deceleration against a closing speed)", True
            ),
            Param("eps_m2ps2", 1e-5, 1.0, "smoothing ε u² of the κ term at zero relative speed", True),
            *_SCALES,
        ),
    ),
    "ovfl": Space(
        "ovfl",
        "law",
        "ovfl",
        (
            Param("alpha_per_s", 0.3, 5.0, "relaxation rate α u/ℓ towards the optimal velocity", True),
            Param("beta_m2ps", 50.0, 3000.0, "follow-the-leader gain β ℓ u on (v_l − v)/h²", True),
            *_SCALES,
        ),
    ),
    "idm": Space(
        "idm",
        "law",
        "idm",
        (
            Param("T_s", 0.8, 3.0, "desired time gap T"),
            Param("a_mps2", 0.3, 3.0, "maximum acceleration a"),
            Param("b_mps2", 0.5, 4.0, "comfortable deceleration b"),
        ),
    ),
    "mpc": Space(
        "mpc",
        "mpc",
        "",
        (
            Param("accel_weight", 0.5, 60.0, "w_a [W/kg per (m/s²)²]: cost of acceleration (currents)", True),
            Param("gap_weight", 0.002, 0.2, "w_g [W/kg per m²]: cost of the gap's distance from h_des(v)", True),
            Param("target_time_gap_s", 1.0, 3.5, "T_des: time gap of the desired gap h_des = s_0 + T_des v"),
        ),
    ),
}

#: The constraints of a feasible trial (module docstring); our choices: a 1 m gap (every case) and a 1.5 s
#: time-to-collision (drive cycles) are margins no controller should use up in ordinary driving (1.5 s: the usual
#: critical-TTC threshold of traffic-conflict studies); an RMS jerk of 2 m/s³ is about twice the default laws' on the
#: training segments (0.7–1.0 m/s³); a mean time gap of 3.5 s while moving lies above every controller's default on
#: the training segments (the MPC's 3.0 s on UDDS, its target 2.5 s) and keeps a follower in the queue.
LIMITS = {"min_gap_m": 1.0, "min_ttc_s": 1.5, "rms_jerk_max_mps3": 2.0, "mean_time_gap_max_s": 3.5}
#: The objective of a trial with a failed run [kWh/100 km] (no car uses this much: 100 is a heavy truck's).
PENALTY_KWH_PER_100KM = 1000.0
#: Speed above which a follower counts as moving for its time gap [m/s] (our choice: walking pace).
MOVING_MPS = 1.0


def check_spaces(
    controllers: Sequence[str], bounds: Mapping[str, Mapping[str, tuple[float, float]]] | None = None
) -> list[Space]:
    """The :class:`Space` of each controller, with ``bounds`` ({controller: {param: (lo, hi)}}) replacing the table's;
    ParameterError naming the controller or the parameter when either is unknown or a bound is bad."""
    if isinstance(controllers, str) or not controllers:
        raise ParameterError(
            f"tuning: controllers = {echo(controllers)} is not allowed: must be a non-empty list of "
            f"{sorted(TUNING_TABLE)}"
        )
    out: list[Space] = []
    for c in controllers:
        if c not in TUNING_TABLE:
            raise ParameterError(f"tuning: unknown controller {c!r}: known are {sorted(TUNING_TABLE)}")
        if c in [s.label for s in out]:
            raise ParameterError(f"tuning: controller {c!r} is given twice")
        out.append(TUNING_TABLE[c])
    for c, table in (bounds or {}).items():
        if c not in TUNING_TABLE:
            raise ParameterError(f"tuning bounds: unknown controller {c!r}: known are {sorted(TUNING_TABLE)}")
        if c not in controllers:
            raise ParameterError(f"tuning bounds: controller {c!r} is not tuned in this run ({list(controllers)})")
        k = [s.label for s in out].index(c)
        space = out[k]
        params = list(space.params)
        for name, lohi in table.items():
            p = space.param(name)
            try:
                lo, hi = (float(x) for x in lohi)
            except (TypeError, ValueError):
                raise ParameterError(
                    f"tuning bounds of {c}.{name}: {echo(lohi)} is not allowed: must be (lo, hi)"
                ) from None
            Param(f"{c}.{name}", lo, hi, p.meaning, p.log)  # validated here: its errors name controller.param
            params[params.index(p)] = Param(name, lo, hi, p.meaning, p.log)
        out[k] = replace(space, params=tuple(params))
    return out


def check_budget(budget: Any, name: str = "budget") -> int:
    """``budget`` (trials per controller) as an int ≥ 1; ParameterError naming it otherwise."""
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
        raise ParameterError(f"tuning: {name} = {echo(budget)} is not allowed: must be an integer >= 1 (trials)")
    return int(budget)


# ----------------------------------------------------------------------------- scenarios


@dataclass(frozen=True)
class Case:
    """A scenario of the training or held-out set: ``name``, ``split`` ('train' | 'held-out'), ``kind`` ('cycle' |
    'safety'), its scenario ``document`` and ``file``, and its leader's position ``leader_x_m`` [m] at
    ``leader_t_s`` [s] and the follower's initial gap ``gap0_m`` [m] (for the time gap)."""

    name: str
    split: str
    kind: str
    document: dict[str, Any]
    file: str
    leader_t_s: tuple[float, ...] = field(repr=False)
    leader_x_m: tuple[float, ...] = field(repr=False)
    gap0_m: float = 0.0


#: The training segments: (shipped scenario, first seconds, end at the leader's next stop).
TRAIN_SEGMENTS = (("mpc_udds_single", 120.0, True), ("mpc_hwfet_single", 120.0, False))
#: The held-out segments and safety-suite cases (names of :func:`aev_ocp.safety.cases.suite_cases`).
HELDOUT_SEGMENTS = (("mpc_us06_single", 120.0, True),)
HELDOUT_SAFETY = (
    "CCRb_50kmh_12m_-6mps2",
    "CCRb_100kmh_40m_-6mps2",
    "cutin_100kmh_lead100kmh_15m_-6mps2",
    "laneend_100kmh_60m",
)
#: The scenario the safety cases run in (its vehicle, units, [mpc] forecast), as the suite's cases (CASE_UNITS).
SAFETY_BASE = "mpc_udds_single"


def _case(name: str, split: str, kind: str, doc: dict[str, Any], file: str) -> Case:
    from ..study.points import parse_scenario_quiet

    sc = parse_scenario_quiet(doc, file)
    u = sc.units
    t = np.arange(0.0, sc.t_end + 1e-12, u.time_from_si(0.05))
    x = np.asarray(sc.leader.position(t), float).ravel()
    return Case(
        name,
        split,
        kind,
        doc,
        file,
        tuple(float(v) for v in u.time_to_si(t)),
        tuple(float(v) for v in u.length_to_si(x - x[0])),
        float(u.length_to_si(sc.gaps0[0])),
    )


def _whole_steps(sc: Any, t: float) -> float:
    dt = sc.extra["mpc"].settings.dt
    return math.ceil(t / dt - 1e-9) * dt


def cycle_case(scenario: str, segment_s: float, end_at_rest: bool, split: str) -> Case:
    """The first ``segment_s`` [s] of a shipped one-follower MPC scenario (``end_at_rest``: on to the leader's next
    stop, :func:`aev_ocp.mpc.cycles.leader_rest_end`), cut at whole MPC steps, every run a single controller."""
    from ..mpc.cycles import leader_rest_end
    from ..overrides import apply_to_document
    from ..scenarios import find_scenario
    from ..scenarios.files import read_scenario_doc
    from ..study.points import parse_scenario_quiet

    path = find_scenario(scenario)
    doc = read_scenario_doc(path, str(path))
    sc = parse_scenario_quiet(doc, str(path))
    t = sc.units.time_from_si(segment_s)
    rest = leader_rest_end(sc, t) if end_at_rest else None
    t_end = min(_whole_steps(sc, rest if rest is not None else t), sc.t_end)
    doc = apply_to_document(doc, {"simulation.t_end": t_end, "compare": None}, str(path))
    name = f"{scenario.removeprefix('mpc_').removesuffix('_single')}_{sc.units.time_to_si(t_end):.0f}s"
    return _case(name, split, "cycle", doc, str(path))


def safety_case(case_name: str, split: str = "held-out") -> Case:
    """A safety-suite case (:func:`aev_ocp.safety.cases.suite_cases`) as a scenario document: the lead as an array
    leader (its speed, braking at its deceleration until it stops), the ego at its speed and gap, in
    :data:`SAFETY_BASE`'s vehicle, units and [mpc]."""
    from ..overrides import apply_to_document
    from ..safety.cases import suite_cases
    from ..scenarios import find_scenario
    from ..scenarios.files import read_scenario_doc
    from ..study.points import parse_scenario_quiet

    cases = {c.name: c for c in suite_cases()}
    if case_name not in cases:
        raise ParameterError(f"tuning: unknown safety case {case_name!r}: known are {sorted(cases)}")
    c = cases[case_name]
    path = find_scenario(SAFETY_BASE)
    doc = read_scenario_doc(path, str(path))
    if c.a_lead_mps2 < 0 and c.v_lead_mps > 0:
        t_stop = c.t_brake_s + c.v_lead_mps / -c.a_lead_mps2
        times = (
            [0.0, t_stop, max(c.t_end_s, t_stop) + 1.0]
            if c.t_brake_s == 0
            else [0.0, c.t_brake_s, t_stop, c.t_end_s + 1.0]
        )
        speeds = [c.v_lead_mps, 0.0, 0.0] if c.t_brake_s == 0 else [c.v_lead_mps, c.v_lead_mps, 0.0, 0.0]
    else:
        times, speeds = [0.0, c.t_end_s + 1.0], [c.v_lead_mps, c.v_lead_mps]
    doc = apply_to_document(
        doc,
        {
            "compare": None,
            "leader.kind": "array",
            "leader.times_s": times,
            "leader.speeds_mps": speeds,
            "platoon.gap0_first_m": c.gap_m,
            "platoon.speed0_mps": c.v_ego_mps,
        },
        str(path),
    )
    sc = parse_scenario_quiet(doc, str(path))
    doc = apply_to_document(doc, {"simulation.t_end": _whole_steps(sc, sc.units.time_from_si(c.t_end_s))}, str(path))
    return _case(case_name, split, "safety", doc, str(path))


def training_cases() -> list[Case]:
    """The training set (module docstring)."""
    return [cycle_case(s, t, r, "train") for s, t, r in TRAIN_SEGMENTS]


def heldout_cases() -> list[Case]:
    """The held-out set (module docstring)."""
    return [cycle_case(s, t, r, "held-out") for s, t, r in HELDOUT_SEGMENTS] + [safety_case(n) for n in HELDOUT_SAFETY]


# ----------------------------------------------------------------------------- a parameter set in a scenario

#: OV-type laws' SI coefficients and their dimensionless field (as the scenario's [carfollowing] converts them).
_OV_FIELDS = {"alpha_per_s": "alpha", "beta_m2ps": "beta", "kappa_per_m": "kappa", "eps_m2ps2": "eps"}


def default_values(space: Space, doc: dict[str, Any], file: str) -> dict[str, float]:
    """The controller's tuned parameters as scenario ``doc`` sets them, SI."""
    from ..study.points import parse_scenario_quiet

    sc = parse_scenario_quiet(doc, file)
    if space.kind == "mpc":
        tp = sc.extra["mpc"].formulation.traffic
        return {p.name: float(getattr(tp, p.name)) for p in space.params}
    law = sc.law(space.law)
    si = law.si_coefficients() if hasattr(law, "si_coefficients") else {}
    return {p.name: float(si[p.name]) if p.name in si else float(getattr(law, p.name)) for p in space.params}


def scenario_overrides(space: Space, values: Mapping[str, float], doc: dict[str, Any], file: str) -> dict[str, Any]:
    """Dotted-key overrides that set ``values`` (SI, a subset of the space's parameters) in scenario ``doc``: law
    controllers get ``platoon.law`` and their sub-table ``carfollowing.<law>.*`` (an OV-type law's untuned
    coefficients kept at the document's SI values when its scales change), the MPC its ``mpc.*`` keys."""
    for k in values:
        space.param(k)  # unknown names are refused, by name
    out: dict[str, Any] = {"compare": None}
    if space.kind == "mpc":
        out.update({f"mpc.{k}": float(v) for k, v in values.items()})
        return out
    out["platoon.law"] = space.law
    from ..study.points import parse_scenario_quiet

    law = parse_scenario_quiet(doc, file).law(space.law)
    if not hasattr(law, "si_coefficients"):  # SI fields of their own (IDM)
        out.update({f"carfollowing.{space.law}.{k}": float(v) for k, v in values.items()})
        return out
    si = {**law.si_coefficients(), **{k: float(v) for k, v in values.items()}}
    ell, u = si["h_scale_m"], si["v_scale_mps"]
    from ..scenarios.followers import SI_COEFFICIENTS

    sub = {"h_scale_m": ell, "v_scale_mps": u}
    for key, (coeff, convert) in SI_COEFFICIENTS.items():
        if key in si:
            sub[coeff] = convert(si[key], ell, u)
    out.update({f"carfollowing.{space.law}.{k}": v for k, v in sub.items()})
    return out


def case_document(space: Space, values: Mapping[str, float] | None, case: Case) -> dict[str, Any]:
    """The case's document run by the controller of ``space`` with ``values`` (None: its defaults)."""
    from ..overrides import apply_to_document

    ov = scenario_overrides(space, values or {}, case.document, case.file)
    return apply_to_document(case.document, ov, case.file)


# ----------------------------------------------------------------------------- scoring a run


def time_gaps_s(profile: Mapping[str, Any], case: Case) -> np.ndarray:
    """The follower's time gaps [s] while it moves (≥ :data:`MOVING_MPS`): at each kept sample, how long ago the
    leader was where the follower is (from the run's compact profile, :func:`aev_ocp.truncation.cumulative_profile`)."""
    d = np.asarray(profile.get("distance_m", []), float)
    t = np.asarray(profile.get("t_s", []), float)
    if d.size < 3:
        return np.empty(0)
    xl, first = np.unique(np.asarray(case.leader_x_m, float), return_index=True)
    tl = np.asarray(case.leader_t_s, float)[first]
    xf = d - case.gap0_m
    speed = np.gradient(d, t)
    ok = (speed >= MOVING_MPS) & (xf >= xl[0]) & (xf <= xl[-1])
    return t[ok] - np.interp(xf[ok], xl, tl)


def run_summary(result: Mapping[str, Any], case: Case) -> dict[str, Any]:
    """The numbers of one closed-loop run (a study task's result) that tuning reads, SI."""
    m = (result.get("metrics") or [{}])[0]
    prof = (result.get("profiles") or [{}])[0]
    tau = time_gaps_s(prof, case) if prof else np.empty(0)
    nan = math.nan
    return {
        "status": result.get("status", "error"),
        "message": result.get("message", ""),
        "battery_energy_kWh_per_100km": float(m.get("battery_energy_kWh_per_100km", nan)),
        "min_gap_m": float(m.get("min_gap_m", nan)),
        "min_ttc_s": float(m.get("min_ttc_s", nan)),
        "rms_jerk_mps3": float(m.get("rms_jerk_mps3", nan)),
        "min_time_gap_s": float(tau.min()) if tau.size else nan,
        "mean_time_gap_s": float(tau.mean()) if tau.size else nan,
        "distance_m": float(m.get("distance_m", nan)),
    }


CONSTRAINTS = ("events", "gap", "ttc", "jerk", "time_gap")


def _nz(x: float) -> float:
    return 0.0 if not math.isfinite(x) else x


def score(runs: Sequence[Mapping[str, Any]], cases: Sequence[Case]) -> tuple[float, list[float]]:
    """(objective [kWh/100 km], constraints (:data:`CONSTRAINTS`, each feasible when ≤ 0)) of one parameter set's runs
    on ``cases`` (module docstring). Events and the gap count on every case; the TTC, the jerk and the time gap on
    the drive cycles only (a safety case is an emergency: hard braking and a short TTC are its point)."""
    bad = sum(1 for r in runs if r["status"] != "ok")
    e = [r["battery_energy_kWh_per_100km"] for r, c in zip(runs, cases) if c.kind == "cycle"]
    obj = float(np.mean(e)) if e and bad == 0 and all(math.isfinite(x) for x in e) else PENALTY_KWH_PER_100KM
    cyc = [r for r, c in zip(runs, cases) if c.kind == "cycle"]
    cons = [
        float(bad),
        max([_nz(LIMITS["min_gap_m"] - r["min_gap_m"]) for r in runs] or [0.0]),
        max([_nz(LIMITS["min_ttc_s"] - r["min_ttc_s"]) for r in cyc] or [0.0]),
        max([_nz(r["rms_jerk_mps3"] - LIMITS["rms_jerk_max_mps3"]) for r in cyc] or [0.0]),
        max([_nz(r["mean_time_gap_s"] - LIMITS["mean_time_gap_max_s"]) for r in cyc] or [0.0]),
    ]
    return obj, cons


def feasible(constraints: Sequence[float]) -> bool:
    """Whether every constraint holds (≤ 0)."""
    return all(c <= 0.0 for c in constraints)


# ----------------------------------------------------------------------------- the optimiser


@dataclass
class TrialRecord:
    """One trial: its number (0 = the default), parameter values (SI), objective and constraints."""

    number: int
    values: dict[str, float]
    objective: float
    constraints: list[float]

    @property
    def feasible(self) -> bool:
        """Whether every constraint holds."""
        return feasible(self.constraints)


class Tuner:
    """Ask/tell around optuna's TPE sampler (fixed ``seed``, constrained: ``constraints_func``) for one controller's
    ``params``, ``budget`` trials, the first being ``default`` (clipped into the bounds)."""

    def __init__(self, params: Sequence[Param], default: Mapping[str, float], budget: int, seed: int = 1) -> None:
        import logging
        import warnings

        import optuna

        self.budget = check_budget(budget)
        self.params = tuple(params)
        optuna.logging.set_verbosity(logging.WARNING)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # multivariate TPE is marked experimental
            sampler = optuna.samplers.TPESampler(
                seed=seed,
                n_startup_trials=max(1, min(10, self.budget // 2)),  # our choice: half the budget random, ≤ 10
                multivariate=True,
                constraints_func=lambda ft: ft.user_attrs["constraints"],
            )
        self.study = optuna.create_study(direction="minimize", sampler=sampler)
        self.dists: dict[str, Any] = {
            p.name: optuna.distributions.FloatDistribution(p.lo, p.hi, log=p.log) for p in self.params
        }
        self.default = {p.name: float(min(max(default[p.name], p.lo), p.hi)) for p in self.params}
        self.study.enqueue_trial(self.default)
        self.records: list[TrialRecord] = []
        self._pending: list[Any] = []

    @property
    def remaining(self) -> int:
        """Trials not yet asked for."""
        return self.budget - len(self.records) - len(self._pending)

    def ask(self, k: int) -> list[dict[str, float]]:
        """Up to ``k`` new parameter sets (fewer when the budget runs out)."""
        import warnings

        out = []
        for _ in range(min(k, self.remaining)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t = self.study.ask(self.dists)
            self._pending.append(t)
            out.append({p.name: float(t.params[p.name]) for p in self.params})
        return out

    def tell(self, scores: Sequence[tuple[float, Sequence[float]]]) -> None:
        """The (objective, constraints) of the sets of the last :meth:`ask`, in its order."""
        if len(scores) != len(self._pending):
            raise ParameterError(f"Tuner.tell: {len(scores)} scores for {len(self._pending)} asked sets")
        for t, (obj, cons) in zip(self._pending, scores):
            t.set_user_attr("constraints", [float(c) for c in cons])
            self.study.tell(t, float(obj))
            self.records.append(
                TrialRecord(t.number, {p.name: float(t.params[p.name]) for p in self.params}, float(obj), list(cons))
            )
        self._pending = []

    def best(self) -> TrialRecord | None:
        """The feasible trial of lowest objective (the earliest on a tie), or None when none is feasible."""
        ok = [r for r in self.records if r.feasible]
        return min(ok, key=lambda r: (r.objective, r.number)) if ok else None


def tune_rounds(
    spaces: Sequence[Space],
    tuners: Mapping[str, Tuner],
    batch: int,
    run_sets: Callable[[list[tuple[Space, dict[str, float]]], int], Sequence[Sequence[Mapping[str, Any]]]],
    score_runs: Callable[[Sequence[Mapping[str, Any]]], tuple[float, Sequence[float]]],
) -> int:
    """Spend every tuner's budget in rounds: each asks for up to ``batch`` sets per controller, ``run_sets(pairs,
    round)`` runs all of them together (one result list per (space, set) pair, in order) and ``score_runs`` scores
    each set's runs for its tuner. Returns the number of rounds."""
    rnd = 0
    while any(t.remaining > 0 for t in tuners.values()):
        asked = {s.label: tuners[s.label].ask(batch) for s in spaces}
        runs = run_sets([(s, v) for s in spaces for v in asked[s.label]], rnd)
        k = 0
        for s in spaces:
            n = len(asked[s.label])
            tuners[s.label].tell([score_runs(r) for r in runs[k : k + n]])
            k += n
        rnd += 1
    return rnd


def optimise(
    params: Sequence[Param],
    default: Mapping[str, float],
    budget: int,
    evaluate: Callable[[list[dict[str, float]]], list[tuple[float, Sequence[float]]]],
    seed: int = 1,
    batch: int = 4,
) -> Tuner:
    """Tune ``params`` from ``default`` with ``budget`` trials, ``batch`` at a time: ``evaluate(sets)`` returns one
    (objective, constraints) per set. Returns the finished :class:`Tuner` (records, best)."""
    t = Tuner(params, default, budget, seed)
    batch = check_budget(batch, "batch")
    while t.remaining > 0:
        sets = t.ask(batch)
        t.tell(evaluate(sets))
    return t


# ----------------------------------------------------------------------------- through the study layer


def _controller(space: Space) -> Any:
    from ..study.model import Controller

    return Controller(space.label, space.kind, space.law if space.kind == "law" else "mpc")


def _task(space: Space, values: Mapping[str, float] | None, case: Case, index: int) -> Any:
    from ..study.model import Point
    from ..study.tasks import make_task

    doc = case_document(space, values, case)
    return make_task(Point(index, case.name, dict(values or {}), doc, case.file), _controller(space))


@dataclass
class Evaluator:
    """Runs parameter sets on cases as study tasks (:func:`aev_ocp.study.runner.execute`, results in the store
    ``<folder>/points/``) and counts the closed-loop evaluations asked for per controller. ``task_of(space, values,
    case, index)`` makes a case's task and ``summary_of(result, case)`` reads its result (default: the drive-cycle
    cases' :func:`_task` and :func:`run_summary`; the ring's own in :mod:`aev_ocp.tuning.ring`)."""

    folder: Path
    executor: str = "pool"
    workers: int | None = None
    scheduler: str | None = None
    progress_stream: Any = None
    counts: dict[str, int] = field(default_factory=dict)
    task_of: Callable[[Space, Mapping[str, float] | None, Any, int], Any] | None = None
    summary_of: Callable[[Mapping[str, Any], Any], dict[str, Any]] | None = None

    def run(
        self, jobs: Sequence[tuple[Space, Mapping[str, float] | None, Sequence[Any]]], name: str = "tune"
    ) -> list[list[dict[str, Any]]]:
        """For each job (space, values or None for the defaults, cases): its runs' summaries, in case order; all
        jobs' tasks are executed together (one study execution)."""
        from ..study.runner import Store, execute

        task_of = self.task_of or _task
        summary_of = self.summary_of or run_summary
        tasks: list[Any] = []
        for space, values, cases in jobs:
            for case in cases:
                tasks.append(task_of(space, values, case, len(tasks)))
            self.counts[space.label] = self.counts.get(space.label, 0) + len(cases)
        results = execute(
            tasks,
            Store(self.folder),
            executor=self.executor,
            workers=self.workers,
            scheduler=self.scheduler,
            name=name,
            progress_stream=self.progress_stream,
        )
        out: list[list[dict[str, Any]]] = [[] for _ in jobs]
        k = 0
        for j, (_, _, cases) in enumerate(jobs):
            for case in cases:
                out[j].append(summary_of(results[tasks[k].key], case))
                k += 1
        return out


@dataclass
class TuningOutput:
    """What :func:`run_tuning` wrote: the folder, its files, the summary rows and the per-run rows."""

    folder: Path
    files: list[Path]
    summary: list[dict[str, Any]]
    runs: list[dict[str, Any]]
    result: dict[str, Any]


#: Files of a tuning folder.
FILES = ("tuning.md", "tuning.csv", "runs.csv", "trials.csv", "tuning.json")


def _fmt(x: Any, d: int = 3) -> str:
    if isinstance(x, float):
        if not math.isfinite(x):
            return "–" if math.isnan(x) else ("∞" if x > 0 else "−∞")
        return f"{x:.{d}g}"
    return str(x)


def _aggregate(runs: Sequence[Mapping[str, Any]], cases: Sequence[Case]) -> dict[str, Any]:
    """Summary of runs on cases: mean battery energy over the drive cycles, feasible runs, worst of each constraint."""
    cyc = [r["battery_energy_kWh_per_100km"] for r, c in zip(runs, cases) if c.kind == "cycle"]
    ok = [feasible(score([r], [c])[1]) for r, c in zip(runs, cases)]
    cons = score(runs, cases)[1]
    return {
        "battery_energy_kWh_per_100km": float(np.mean(cyc)) if cyc and all(map(math.isfinite, cyc)) else math.nan,
        "feasible_runs": sum(ok),
        "runs": len(runs),
        "collisions_or_events": int(cons[0]),
        "min_gap_m": min((r["min_gap_m"] for r in runs), default=math.nan),
        "min_ttc_s": min((r["min_ttc_s"] for r in runs), default=math.nan),
        "max_rms_jerk_mps3": max((r["rms_jerk_mps3"] for r in runs), default=math.nan),
        "max_mean_time_gap_s": max(
            (r["mean_time_gap_s"] for r, c in zip(runs, cases) if c.kind == "cycle"), default=math.nan
        ),
    }

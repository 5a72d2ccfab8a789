"""MPC beside the closed-form laws (and the OCP-D lower bound) on the same leader: one comparison used
by ``aev-ocp mpc`` and by the ``reproduce`` report section.

Like with like (issue 20): every run is costed with the running formulation's own cost (``Formulation.cost_key``)
on the MPC's grid; OCP-D solves the same formulation, on the MPC's grid whenever it fits
(:data:`aev_ocp.ocp.oracle.ORACLE_BOUND_MAX_INTERVALS`; :func:`aev_ocp.ocp.oracle.solve_and_replay`), and its
column is a *bound* only when it is that optimum on that grid and its cost is at most every whole run's (checked); otherwise it is labelled 'reference'. Violations count against the
running formulation's bounds for every column. Another formulation's cost (the §9 cost of a traffic MPC) is only in a
secondary table. Equal-distance and equal-time views (:func:`aev_ocp.truncation.equal_views`) rank runs of
different length."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import interrupts
from ..ocp.checks import GAP_RTOL as SMOOTHING_GAP_RTOL
from ..ocp.formulation import Formulation, ModelBounds, s9_formulation
from ..ocp.oracle import (
    DEFAULT_TIME_LIMIT_S,
    OBJECTIVE_NAMES,
    bound_role,
    ocpd_scenario,
    solve_and_replay,
    stage_cost_of_result,
)
from ..ocp.problem import OCPProblem
from ..ocp.traffic_cost import cost_traffic_of_result, problem_cost_of_result
from ..limits import MPC_BYTES_PER_INTERVAL, memory_limit_bytes
from ..metrics import comparability
from ..params import ParameterError
from ..progress import Progress
from ..results import SimulationResult, fmt_value, require_pandas, summary_html, summary_text, write_json
from ..simulate import simulate_platoon
from ..truncation import VIEW_KEYS, equal_views
from .scenario import MPCConfig, closed_loop_from_scenario
from .settings import MPCSettings

#: every comparison table shows these first (issue 8): runs of different distance or duration (> 1 %) or
#: ended by an event are flagged 'comparable = False' and their column is marked, never ranked as complete
COMPARABILITY_ROWS = [
    "comparable",
    "distance_m",
    "distance_diff_pct",
    "duration_s",
    "duration_diff_pct",
    "battery_energy_kWh_per_100km",
    "heat_pack_J_per_km",
    "charge_throughput_Ah_per_km",
    "omega_model_per_km",
    "omega_J_per_kg_per_km",
    "min_ttc_s",
]
METRIC_ROWS = COMPARABILITY_ROWS + [
    "battery_energy_J",
    "omega_model",
    "omega_J_per_kg",
    "heat_pack_J",
    "heat_irr_pack_J",
    "delta_soc",
    "min_gap_model",
    "min_gap_m",
    "min_speed_model",
    "min_speed_mps",  # each model-unit metric with its SI twin (aev_ocp.metrics.SI_METRICS)
    "rms_ovm_error_model",
    "rms_ovm_error_mps",
    "rms_rel_speed_model",
    "rms_rel_speed_mps",
    "rms_jerk_model",
    "rms_jerk_mps3",
    "max_abs_current_A",
    "gap_violations",
    "speed_violations",
    "collisions",
    "infeasible_current",
    "cost_traffic",
    "cost_s9",
    "cost_problem",
    "cost_s9_exact",
    "smoothing_gap_pct",
    "forecast_rms",
    "solve_ms_median",
    "solve_ms_p95",
    "solve_ms_max",
    "iterations_mean",
    "iterations_max",
    "fallbacks",
    "fallback_causes",
    "solver_path",
]
#: rows of the §9 cost beside another formulation's run (a secondary table: never a verdict)
S9_ROWS = ("cost_s9", "cost_s9_exact", "smoothing_gap_pct")


MAX_CLOSED_LOOP_STEPS = 10**6  # each step is one NLP solve: 10^6 steps are hours even on the fastest path


def check_mpc_scenario(
    scenario: Any, settings: MPCSettings, laws: tuple[str, ...] = (), t_end_option: str | None = None
) -> None:
    """Refuse, before anything runs, an MPC comparison that cannot be solved or would not fit in memory.

    Raises ScenarioError naming the file and key: MPC vehicles that do not exist, h_min above an MPC
    vehicle's initial gap or its initial speed outside [v_min, v_max] (infeasible from the first step),
    unknown or repeated comparison laws, a horizon or a number of steps too large for memory or time, a horizon
    that is not a whole number of MPC steps (``t_end_option`` names the option that set it, e.g. '--t-end').
    """
    from ..models.carfollowing import LAW_REGISTRY
    from ..scenarios import ScenarioError, check_run_size
    from .scenario import check_mpc_setup

    file = str(scenario.source or scenario.name)
    check_mpc_setup(scenario, None, settings)  # vehicles exist; h_min and v bounds vs the initial state
    n = scenario.n_followers
    for k, name in enumerate(laws):
        if not isinstance(name, str) or name.lower() not in LAW_REGISTRY:
            raise ScenarioError(f"--laws: {name!r} is not a car-following law; known: {sorted(LAW_REGISTRY)}")
        if name.lower() in [x.lower() for x in laws[:k]]:
            raise ScenarioError(f"--laws: {name!r} is given twice")
    need = MPC_BYTES_PER_INTERVAL * settings.N
    if need > memory_limit_bytes():
        raise ScenarioError(
            f"{file}: mpc.N = {settings.N} is not allowed: the NLP would need about "
            f"{need / 1e9:.3g} GB, more than the limit of {memory_limit_bytes() / 1e9:.3g} GB "
            f"($AEV_OCP_MAX_MEMORY_GB); use at most "
            f"{int(memory_limit_bytes() // MPC_BYTES_PER_INTERVAL)}"
        )
    steps = scenario.t_end / settings.dt
    if steps > MAX_CLOSED_LOOP_STEPS:
        raise ScenarioError(
            f"{file}: simulation.t_end = {scenario.t_end:g} is not allowed for MPC: "
            f"{steps:.3g} closed-loop steps of mpc.dt = {settings.dt:g}, more than "
            f"{MAX_CLOSED_LOOP_STEPS}; lower simulation.t_end or raise mpc.dt"
        )
    check_run_size(n, scenario.t_end, min(scenario.dt_out, settings.dt), file)
    k = round(scenario.t_end / settings.dt)
    if k < 1 or abs(k * settings.dt - scenario.t_end) > 1e-9 * max(1.0, scenario.t_end):  # as ClosedLoop.run
        T = scenario.units.time_s
        what = t_end_option or f"{file}: simulation.t_end"
        raise ScenarioError(
            f"{what} = {scenario.t_end * T:g} s ({scenario.t_end:g} model time) is not allowed: the closed loop "
            f"advances in steps of mpc.dt = {settings.dt * T:g} s ({settings.dt:g} model time); give a multiple "
            f"of it, e.g. {max(1, k) * settings.dt * T:g} s"
        )


def _progress(say: Callable[[str], None], label: str) -> Callable[[float, float], None]:
    """A progress callback: checks for Ctrl-C/SIGTERM at every step, reports every 25 %."""
    last = [-1]

    def cb(t: float, t_end: float) -> None:
        interrupts.check()
        q = int(4 * t / t_end) if t_end > 0 else 4
        if q != last[0]:
            last[0] = q
            say(f"{label}: t = {t:.4g} / {t_end:g} ({25 * q}%)")

    return cb


@dataclass
class Comparison:
    """Runs on one scenario: {label: SimulationResult}, per-run per-vehicle metrics (with the §9 cost
    'cost_s9' of each follower's sampled trajectory), and the OCP-D lower bound (single follower)."""

    results: dict[str, SimulationResult]
    metrics: dict[str, list[dict[str, Any]]]
    ocpd: dict[str, Any] | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    formulation: Formulation = field(default_factory=s9_formulation)
    #: per follower: the equal-distance and equal-time views (:func:`aev_ocp.truncation.equal_views`)
    views: list[dict[str, Any]] = field(default_factory=list)

    def _repr_rows(self) -> list[dict[str, Any]]:
        return [
            {
                "run": label,
                "vehicle": m.get("vehicle"),
                "status": m.get("status"),
                "battery_energy_kWh_per_100km": m.get("battery_energy_kWh_per_100km"),
                "omega_J_per_kg": m.get("omega_J_per_kg"),
                "heat_pack_J": m.get("heat_pack_J"),
                "min_gap_m": m.get("min_gap_m"),
                "cost_s9": m.get("cost_s9"),
            }
            for label, ms in self.metrics.items()
            for m in ms[:2]
        ]

    def _repr_title(self) -> str:
        n = max((r.n_vehicles for r in self.results.values()), default=0)
        return f"Comparison ({self.formulation.kind} formulation): {', '.join(self.results)} on {n} follower(s)"

    def __repr__(self) -> str:
        """A few lines: per run (first two vehicles) the status, battery energy [kWh/100 km], the paper's ω [J/kg],
        pack ∫Q [J], min gap [m], §9 cost."""
        lines = [
            f"{r['run']} vehicle {r['vehicle']}: {r['status']}, battery energy "
            f"{fmt_value(r['battery_energy_kWh_per_100km'])} kWh/100 km, ω {fmt_value(r['omega_J_per_kg'])} J/kg, "
            f"pack ∫Q {fmt_value(r['heat_pack_J'])} J, min gap {fmt_value(r['min_gap_m'])} m, "
            f"cost {fmt_value(r['cost_s9'])}"
            for r in self._repr_rows()
        ]
        if self.ocpd:
            lines.append(
                f"OCP-D: {self.ocpd.get('status')}, cost {fmt_value(self.ocpd.get('cost_s9'))} "
                f"({self.ocpd.get('role', 'bound')})"
            )
        lines += [f"warning: {w}" for w in self.warnings[:2]]
        return summary_text(self._repr_title(), lines)

    def _repr_html_(self) -> str:
        fields: list[tuple[str, Any]] = [(f"{k} time [s]", v) for k, v in self.timings_s.items()]
        if self.ocpd:
            fields.append(("OCP-D cost", self.ocpd.get("cost_s9")))
        return summary_html(self._repr_title(), fields, self._repr_rows())

    def to_dataframe(self) -> Any:
        """Every run's per-vehicle metrics, one row per run × vehicle (column ``run``). Needs pandas
        (``pip install 'aev_ocp[pandas]'``)."""
        pd = require_pandas("Comparison.to_dataframe()")
        return pd.DataFrame([{"run": label, **m} for label, ms in self.metrics.items() for m in ms])


def _cost_s9(r: SimulationResult, i: int, s: MPCSettings, f: Formulation, exact: bool = False) -> float:
    """§9 cost Σ ℓ(z_k, a_k)·dt on the dt grid (laws: sampled at the grid), with the optimiser's smoothed
    η switch (as the MPC and OCP-D see it) or, ``exact``, the plant's exact switch; §9's weights and objective
    (the formulation's when it is §9, else model guide §9's defaults)."""
    g = f if f.kind == "s9" else s9_formulation(smooth=f.smooth)
    return stage_cost_of_result(r, i, s.dt, g.weights, None if exact else g.smooth, g.objective)


def _own_cost(r: SimulationResult, i: int, s: MPCSettings, f: Formulation, pr: OCPProblem, p: list[float]) -> float:
    """The running formulation's own cost of follower i's run on the MPC's dt grid: §9's Σ ℓ·dt, the traffic
    objective (:func:`aev_ocp.ocp.traffic_cost.cost_traffic_of_result`) or a user problem's objective."""
    if f.kind == "s9":
        return _cost_s9(r, i, s, f)
    if f.kind == "traffic":
        return cost_traffic_of_result(r, i, s.dt, pr)["total"]
    return problem_cost_of_result(r, i, s.dt, pr, np.asarray(p, float))["total"]


def own_cost(r: SimulationResult, i: int, s: MPCSettings, f: Formulation, ev: Any) -> float:
    """The formulation ``f``'s own cost of follower i's run ``r`` on the MPC's grid (settings ``s``), as the MPC
    comparison reports it (``f.cost_key``); NaN when the run did not cover its horizon (an event)."""
    if r.events:
        return float("nan")
    pr = f.build(ev, s.dt)
    return _own_cost(r, i, s, f, pr, f.parameter_vector(list(pr.meta.get("parameter_names", []))))


def _violations(r: SimulationResult, i: int, b: ModelBounds) -> tuple[int, int]:
    """(gap, speed) violations of follower i's samples after t_0 against the bounds ``b`` [model units]."""
    h, v = r.gap[1:, i], r.speed[1:, i]
    gap = int(np.sum(h < b.h_min - 1e-9)) if b.h_min is not None else 0
    vmax = b.v_max if b.v_max is not None else np.inf
    return gap, int(np.sum((v < -1e-9) | (v > vmax + 1e-9)))


def run_comparison(
    scenario: Any,
    settings: MPCSettings | None = None,
    laws: tuple[str, ...] = ("proposed", "ovfl"),
    with_ocpd: bool = True,
    log: Callable[[str], None] | None = None,
    progress: Progress | None = None,
    formulation: Formulation | None = None,
) -> Comparison:
    """MPC closed loop on ``scenario`` (its [mpc] table's settings and formulation, or ``settings`` /
    ``formulation``) beside each law in ``laws`` (whole platoon on that law, same leader and initial state) and
    OCP-D of the same formulation for a single follower (module docstring: bound or reference).
    progress: reports the MPC loop (step k/N, ETA) and holds its time limit: the loop then stops with
    status 'time_limit' (a partial result) and OCP-D is skipped."""
    cfg: MPCConfig = scenario.extra.get("mpc") or MPCConfig(MPCSettings())
    s = settings or cfg.settings
    f = formulation or cfg.formulation
    say = log or (lambda m: None)
    out: dict[str, SimulationResult] = {}
    tim: dict[str, float] = {}
    t0 = time.perf_counter()
    say(f"MPC closed loop ({s.solver}{'+codegen' if s.codegen else ''}, N = {s.N}) on {scenario.name}")
    out["mpc"] = closed_loop_from_scenario(scenario, cfg, s, f).run(
        list(scenario.gaps0),
        list(scenario.speeds0),
        scenario.t_end,
        progress=(progress.closed_loop(s.dt) if progress else _progress(say, "mpc")),
    )
    tim["mpc"] = time.perf_counter() - t0
    for name in laws:
        t0 = time.perf_counter()
        law = scenario.law(name)
        out[name] = simulate_platoon(
            scenario.leader,
            [law] * scenario.n_followers,
            list(scenario.gaps0),
            list(scenario.speeds0),
            scenario.t_end,
            ev=scenario.ev,
            rtol=scenario.rtol,
            atol=scenario.atol,
            dt_out=min(scenario.dt_out, s.dt),
            progress=_progress(lambda m: None, name),
        )
        tim[name] = time.perf_counter() - t0
    metrics = {}
    warn: list[str] = []
    key = f.cost_key
    # the MPC's own problem (built as the controller builds it) and its parameters, for its cost on its grid
    pr = f.build(scenario.ev, s.dt)
    pvec = f.parameter_vector(list(pr.meta.get("parameter_names", [])))
    b = f.bounds_model(scenario.ev)
    for lab, r in out.items():
        ms = r.metrics()
        whole = _covers(r, scenario.t_end)
        if not whole:
            warn.append(
                f"run {lab} stopped early ({_run_status(r)}): its costs ({key}, cost_s9) cover only "
                "part of the horizon and are not reported"
            )
        for i, m in enumerate(ms):
            try:
                m[key] = _own_cost(r, i, s, f, pr, pvec) if whole else float("nan")
            except ParameterError as exc:  # a user problem whose controls a run does not fix
                m[key] = float("nan")
                if lab == "mpc" and i == 0:
                    warn.append(f"{key} is not reported: {exc}")
            m["cost_s9"], m["cost_s9_exact"] = (
                (_cost_s9(r, i, s, f), _cost_s9(r, i, s, f, exact=True)) if whole else (float("nan"), float("nan"))
            )
            m["smoothing_gap_pct"] = (
                100 * (m["cost_s9"] / m["cost_s9_exact"] - 1) if m["cost_s9_exact"] else float("nan")
            )
            # like with like: every column's violations against the running formulation's bounds
            m["gap_violations"], m["speed_violations"] = _violations(r, i, b)
            st = (r.solver_stats or [None] * len(ms))[i]
            if st:
                m["forecast_rms"] = st.get("forecast_rms", float("nan"))
            if lab == "mpc" and f.kind == "s9" and abs(m["smoothing_gap_pct"]) > 100 * SMOOTHING_GAP_RTOL:
                warn.append(
                    f"vehicle {i + 1}: the MPC's §9 cost is {m['cost_s9']:.6g} with its smoothed η switch "
                    f"but {m['cost_s9_exact']:.6g} on the exact model ({m['smoothing_gap_pct']:+.2f} %): "
                    "the optimiser may exploit the smoothing (narrow mpc.smoothing_width_W)"
                )
        metrics[lab] = ms
    _flag_comparability(metrics)
    ocpd = None
    if with_ocpd and scenario.n_followers == 1 and progress is not None and progress.expired():
        warn.append("OCP-D skipped: the time limit has passed")
    elif with_ocpd and scenario.n_followers == 1:
        t0 = time.perf_counter()
        # OCP-D of the MPC's own formulation on the MPC's grid (a bound); only a run too long for that
        # (> ORACLE_BOUND_MAX_INTERVALS) gets the coarser 1 s grid (a reference; meta 'grid_dt')
        grid = ocpd_scenario(scenario, s.dt, f)
        say(f"OCP-D of the MPC's formulation (whole scenario, IPOPT, N = {grid.N}, dt = {grid.dt:.4g})")
        # IPOPT's wall-time limit: what is left of the run's time limit (at most the OCP-D default)
        left = progress.remaining_s() if progress is not None else math.inf
        sr = solve_and_replay(
            scenario,
            s.dt,
            f,
            time_limit_s=min(DEFAULT_TIME_LIMIT_S, max(left, 1e-3)),
            progress=say,
            replay_progress=_progress(say, "ocp-d replay"),
        )
        scn, res, coarse = sr.scenario, sr.result, sr.coarse
        tim["ocpd"] = time.perf_counter() - t0
        # a failed or time-limited solve bounds nothing: no cost is reported for it
        ocpd = {
            "success": res.success,
            "status": res.status,
            key: res.objective if res.success else float("nan"),
            "grid_dt": scn.dt,
            "formulation": f.name,
            "objective": {"traffic": "traffic objective (the MPC's)", "s9": "model guide §9 cost"}.get(
                f.kind, f"the MPC's problem {f.name!r}"
            ),
            "objective_definition": OBJECTIVE_NAMES[f.kind],
            "N": scn.N,
            "solve_time_s": res.wall_time_s,
            "iterations": res.iterations,
            "role": "reference",
        }
        if sr.replay is not None:
            # the optimal controls replayed open loop through the same exact plant: every §10 metric
            r = sr.replay
            m = r.metrics()[0]
            whole = _covers(r, scenario.t_end)
            if not whole:
                warn.append(f"the OCP-D replay stopped early ({_run_status(r)}): its replayed costs are not reported")
            # the same costs on the exact plant's trajectory
            m["cost_s9_replayed"] = _cost_s9(r, 0, s, f) if whole else float("nan")
            if f.kind != "s9":
                try:
                    m[f"{key}_replayed"] = _own_cost(r, 0, s, f, pr, pvec) if whole else float("nan")
                except ParameterError:
                    m[f"{key}_replayed"] = float("nan")
            m["gap_violations"], m["speed_violations"] = _violations(r, 0, b)
            ocpd.update({k: v for k, v in m.items() if k not in ("vehicle", "controller")})
            ocpd[key] = res.objective
            if f.kind != "s9":  # §9's cost of the optimum's replay: a secondary number, not a bound
                ocpd["cost_s9"] = m["cost_s9_replayed"]
            if coarse:  # a coarser grid's optimum bounds nothing on the MPC's grid
                ocpd[f"{key}_grid"], ocpd[key] = res.objective, m[f"{key}_replayed"]
                warn.append(
                    f"OCP-D was solved on a coarser grid (dt = {scn.dt:.4g}, the MPC's {s.dt:g}): its {key} "
                    f"is its controls replayed and costed on the MPC's grid, a reference, not a lower bound "
                    f"(its own grid's optimum: {res.objective:.6g})"
                )
            else:
                ocpd["role"], why = bound_role(float(res.objective), metrics, key)
                if why:
                    warn.append(why)
            ref = (metrics.get("proposed") or metrics["mpc"])[0]
            ocpd.update({k: v for k, v in comparability(m, ref).items()})
            out["ocp-d"] = r
    for w in warn:
        say(f"warning: {w}")
    views = [equal_views(out, i) for i in range(scenario.n_followers)]
    return Comparison(out, metrics, ocpd, tim, warn, f, views)


def _covers(r: SimulationResult, t_end: float) -> bool:
    """The run reached t_end [model time] without an event (its costs cover the whole horizon)."""
    return not r.events and r.t[-1] >= t_end - 1e-9 * max(1.0, abs(t_end))


def _flag_comparability(metrics: dict[str, list[dict[str, Any]]]) -> None:
    """Add comparability (distance, duration within 1 %, no event) of every run's vehicle i against the
    proposed law's vehicle i (else the MPC's) to its metrics, in place (:func:`aev_ocp.metrics.comparability`)."""
    ref_lab = "proposed" if "proposed" in metrics else "mpc"
    for lab, ms in metrics.items():
        for i, m in enumerate(ms):
            ref = metrics[ref_lab][i] if i < len(metrics[ref_lab]) else None
            m.update(comparability(m, ref))


def _fmt(x: Any) -> str:
    if isinstance(x, (bool, np.bool_)):
        return str(x)
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        return f"{x:.5g}" if np.isfinite(x) else "—"
    return "—" if x is None else str(x)


def _run_status(r: SimulationResult) -> str:
    """'ok', or where the run stopped: 'collision at t = 12.3 (vehicle 2)'."""
    if not r.events:
        return (
            "ok"
            if not r.violations
            else "violated (" + ", ".join(f"vehicle {e.vehicle + 1}" for e in r.violations) + ")"
        )
    e = r.events[0]
    when = f"{e.time_s:.4g} s ({e.time:.4g} model)" if e.time_s is not None else f"{e.time:.4g}"
    return f"{e.kind} at t = {when}" + (f" (vehicle {e.vehicle + 1})" if e.vehicle >= 0 else "")


def _render(head: list[str], rows: list[list[str]], markdown: bool) -> str:
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        return "\n".join(lines)
    w = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    return "\n".join(
        "  ".join(str(x).ljust(wi) if j == 0 else str(x).rjust(wi) for j, (x, wi) in enumerate(zip(r, w)))
        for r in [head] + rows
    )


def _ocpd_label(c: Comparison) -> str:
    """'ocp-d (bound)' only for the same formulation's optimum on the MPC's grid that is ≤ every run's cost."""
    return f"ocp-d ({(c.ocpd or {}).get('role', 'reference')})"


def _floor_note(c: Comparison, vehicle: int) -> str:
    """'h < 2 m' : what gap_violations count (the running formulation's floor, in SI)."""
    r = c.results.get("mpc")
    ctrls = (r.meta.get("controllers") or []) if r is not None else []
    b = ctrls[vehicle].get("bounds_model") if vehicle < len(ctrls) and isinstance(ctrls[vehicle], dict) else None
    if r is None or not b or b.get("h_min") is None:
        return ""
    return f" (h < {float(r.units.length_to_si(b['h_min'])):.3g} m)"


def comparison_table(c: Comparison, vehicle: int = 0, markdown: bool = False, views: bool = True) -> str:
    """Every §10 metric of follower ``vehicle`` side by side (MPC, laws, OCP-D of the same formulation: 'bound' or
    'reference'), the running formulation's own cost as the only cost row; then, labelled, another formulation's
    cost (model guide §9's beside a traffic MPC: no verdict) and the equal-distance and equal-time views."""
    f = c.formulation
    labs = list(c.metrics)
    with_d = bool(c.ocpd) and vehicle == 0
    cols = labs + (["ocp-d"] if with_d else [])
    other = [k for k in S9_ROWS if f.kind != "s9"]
    own_cost_rows = {"cost_traffic", "cost_s9", "cost_problem"} - {f.cost_key}
    rows, secondary = [], []
    for key in METRIC_ROWS:
        vals = [c.metrics[lab][vehicle].get(key) for lab in labs]
        if with_d:
            vals.append(c.ocpd.get(key) if c.ocpd else None)
        if all(v is None for v in vals):
            continue
        name = key + (_floor_note(c, vehicle) if key == "gap_violations" else "")
        if key in other:
            secondary.append([key] + [_fmt(v) for v in vals])
        elif key not in own_cost_rows:
            rows.append([name] + [_fmt(v) for v in vals])
    status = [_run_status(c.results[lab]) if lab in c.results else "—" for lab in labs]
    flag = [c.metrics[lab][vehicle].get("comparable", True) for lab in labs]
    if with_d:
        status.append(_run_status(c.results["ocp-d"]) if "ocp-d" in c.results else (c.ocpd or {}).get("status", "—"))
        flag.append(bool((c.ocpd or {}).get("comparable", False)))
    heads = [_ocpd_label(c) if col == "ocp-d" else col for col in cols]
    heads = [col if ok else f"{col} (NOT COMPARABLE)" for col, ok in zip(heads, flag)]
    rows.insert(0, ["status"] + status)
    text = [
        f"Whole runs (formulation {f.name}; its own cost {f.cost_key}; ranked only when comparable):",
        _render(["metric"] + heads, rows, markdown),
    ]
    if secondary:
        # OCP-D optimises this formulation's cost, not the other one: no 'bound' label in this table
        other_heads = ["ocp-d" if col == "ocp-d" else h for col, h in zip(cols, heads)]
        text += [
            "",
            "Another formulation's cost (model guide §9's; neither this MPC nor its OCP-D optimises it: no verdict):",
            _render(["metric"] + other_heads, secondary, markdown),
        ]
    if views and vehicle < len(c.views):
        text += ["", views_table(c.views[vehicle], markdown)]
    return "\n".join(text)


def views_table(v: dict[str, Any], markdown: bool = False) -> str:
    """The equal-distance and equal-time views of one follower (:func:`aev_ocp.truncation.equal_views`), each
    run evaluated up to the cut and ranked by pack ∫Q/km (1 = lowest)."""
    out = []
    for view, cut, unit in (("distance", "cut_m", "m"), ("time", "cut_s", "s")):
        runs = v.get(view, {}).get("runs") or {}
        if not runs:
            continue
        what = "shortest common distance" if view == "distance" else "common time"
        out.append(
            f"Equal {view}: every run up to the {what}, {v[view][cut]:.6g} {unit} (all comparable; runs ended "
            "by an event left out):"
        )
        labs = list(runs)
        rows = [[k] + [_fmt(runs[lab][k]) for lab in labs] for k in (*VIEW_KEYS, "rank")]
        out += [_render(["metric"] + labs, rows, markdown), ""]
    return "\n".join(out).rstrip()


def write_outputs(c: Comparison, out: Path) -> list[Path]:
    """results.json, trajectories CSV and plots of a comparison into ``out``."""
    from ..plots import plot_trajectories
    from .plots import plot_overlay, plot_solve_times

    out.mkdir(parents=True, exist_ok=True)
    r = c.results["mpc"]
    files = [
        write_json(
            out / "results.json",
            {
                "scenario": r.meta.get("leader"),
                "status": r.status,
                "events": [vars(e) for e in r.events],
                "metrics": c.metrics,
                "runs": {
                    lab: {"status": res.status, "events": [vars(e) for e in res.events]}
                    for lab, res in c.results.items()
                },
                "ocp_d": c.ocpd,
                "timings_s": c.timings_s,
                "warnings": c.warnings,
                "formulation": c.formulation.describe(),
                "equal_views": c.views,
                "mpc_settings": r.meta.get("controllers"),
                "mpc_steps": r.meta.get("mpc_steps"),
            },
        )
    ]
    files.append(r.to_csv(out / "trajectories_mpc.csv"))
    for png, plot in (
        (out / "mpc_trajectories.png", plot_trajectories),
        (out / "mpc_solve_times.png", plot_solve_times),
    ):
        plot(r, png)
        files.append(png)
    for i in range(r.n_vehicles):
        plot_overlay(c.results, png := out / f"overlay_vehicle{i + 1}.png", vehicle=i)
        files.append(png)
        if i >= 1 and r.n_vehicles > 3 and i != r.n_vehicles - 1:
            continue
    return files


def write_comparison(c: Comparison, out: Path, settings: dict[str, Any]) -> None:
    """:func:`write_outputs` and the saved runs (manifest.json with ``settings`` and the comparison's OCP-D, metrics,
    timings and warnings; trajectories.npz) that ``aev_ocp.load(out)`` reads."""
    from ..saved import save_output

    write_outputs(c, out)
    save_output(
        out,
        "mpc",
        c.results,
        primary="mpc",
        settings=settings,
        extra={"ocp_d": c.ocpd, "comparison_metrics": c.metrics, "timings_s": c.timings_s, "warnings": c.warnings},
    )


def mpc_section(out_dir: Any, progress: Callable[[str], None]) -> str:
    """Reproduce section: the canonical MPC (model guide §9) beside the proposed law and OVFL (and OCP-D)."""
    from ..scenarios import find_scenario, load_scenario

    out = Path(out_dir) / "mpc"
    progress("MPC: canonical scenario (mpc_paper_single)")
    sc = load_scenario(find_scenario("mpc_paper_single"))
    c = run_comparison(sc, log=progress)
    progress("MPC: writing tables and plots")
    from ..saved import settings_of

    write_comparison(c, out, settings_of(sc))  # aev_ocp.load(".../mpc")
    st = c.metrics["mpc"][0]
    lines = [
        "## MPC with the battery in the loop (model guide §9)",
        "",
        f"Canonical scenario: one follower behind the Table 1 leader, h(0) = 0.3, v(0) = 1.87, oracle "
        f"forecast, N = 40, dt = 0.1, w = (1, 1, 1, 0.1), t ∈ [0, {sc.t_end:g}]. Exact plant (CVODES, "
        f"unsmoothed η switch). Solver path {st.get('solver_path')} (QP {st.get('qp_solver') or '—'}): median {st.get('solve_ms_median', float('nan')):.2f} ms, "
        f"p95 {st.get('solve_ms_p95', float('nan')):.2f} ms, max {st.get('solve_ms_max', float('nan')):.2f} ms per "
        f"step, {st.get('fallbacks')} fallbacks. `cost_s9` is Σ ℓ(z_k, a_k)·dt of §9 on the dt grid "
        "(smoothed η, as in OCP-D); OCP-D is the lower bound of that cost. `cost_s9_exact` is the same "
        "cost with the exact η switch; `smoothing_gap_pct` their difference (a warning above 0.5 %).",
        "",
        comparison_table(c, 0, markdown=True),
        "",
        "![MPC and the laws: gap, speed, acceleration, current, SOC](mpc/overlay_vehicle1.png)",
        "",
        "![MPC trajectories](mpc/mpc_trajectories.png)",
        "",
        "![MPC solve time per step](mpc/mpc_solve_times.png)",
        "",
        'The runs load back with `aev_ocp.load("mpc")` (the MPC) and `aev_ocp.load_all("mpc")` (every run).',
        "",
    ]
    if c.ocpd and c.ocpd.get("success"):
        gap = 100 * (st["cost_s9"] / c.ocpd["cost_s9"] - 1)
        what = "lower bound" if c.ocpd.get("role") == "bound" else "reference (not a bound, see the warnings)"
        lines.append(f"MPC's §9 cost is {gap:.3f} % above the OCP-D {what}.")
    lines += [f"**Warning:** {w}" for w in c.warnings]
    return "\n".join(lines) + "\n"


REPRODUCE_SECTIONS = [("mpc", mpc_section, 15)]  # 3 runs x 4 progress lines + OCP-D + replay + writing

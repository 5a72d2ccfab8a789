"""Run the MPC beside the closed-form laws (and the OCP-D lower bound) on the same leader: :func:`run_comparison`
returns a :class:`Comparison`, which ``aev-ocp mpc``, the drive-cycle comparison and the ``reproduce`` section
(:mod:`aev_ocp.mpc.report`: tables, files) share. The orchestration stands here, in the application layer, apart
from the controller it runs.

Like with like: every run is costed with the running formulation's own cost (``Formulation.cost_key``)
on the MPC's grid; OCP-D solves the same formulation, on the MPC's grid whenever it fits
(:data:`aev_ocp.ocp.oracle.ORACLE_BOUND_MAX_INTERVALS`; :func:`aev_ocp.ocp.oracle.solve_and_replay`), and its
column is a *bound* only when it is that optimum on that grid and its cost is at most every whole run's (checked);
otherwise it is labelled 'reference'. Violations count against the running formulation's bounds for every column."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .. import interrupts
from ..metrics import bound_violations, comparability
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
from ..params import ParameterError
from ..progress import Progress
from ..results import SimulationResult, fmt_value, require_pandas, summary_html, summary_text
from ..simulate import simulate_platoon
from ..truncation import equal_views
from .scenario import MPCConfig, closed_loop_from_scenario
from .settings import MPCSettings


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
    """(gap, speed) violations of follower i's samples after t_0 against the bounds ``b`` [model units]
    (:func:`aev_ocp.metrics.bound_violations`)."""
    h_min = b.h_min if b.h_min is not None else -math.inf
    return bound_violations(r.gap[1:, i], r.speed[1:, i], h_min, b.v_max if b.v_max is not None else math.inf)


def _run_all(
    scenario: Any,
    cfg: MPCConfig,
    s: MPCSettings,
    f: Formulation,
    laws: tuple[str, ...],
    say: Callable[[str], None],
    progress: Progress | None,
) -> tuple[dict[str, SimulationResult], dict[str, float]]:
    """The MPC closed loop and each law's platoon on the scenario: {label: result}, {label: wall time [s]}."""
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
    return out, tim


@dataclass
class _Costing:
    """How every run is costed: the running formulation ``f`` on the MPC's grid (settings ``s``), its problem
    ``pr`` (built as the controller builds it) with parameters ``pvec``, its bounds ``b`` [model units]."""

    s: MPCSettings
    f: Formulation
    pr: OCPProblem
    pvec: list[float]
    b: ModelBounds

    @classmethod
    def of(cls, scenario: Any, s: MPCSettings, f: Formulation) -> "_Costing":
        pr = f.build(scenario.ev, s.dt)
        return cls(s, f, pr, f.parameter_vector(list(pr.meta.get("parameter_names", []))), f.bounds_model(scenario.ev))


def _cost_vehicle(
    m: dict[str, Any], r: SimulationResult, i: int, lab: str, whole: bool, n: int, c: _Costing, warn: list[str]
) -> None:
    """Follower i's costs (own, §9 smoothed and exact), violations and forecast error into its metrics ``m``."""
    s, f, key = c.s, c.f, c.f.cost_key
    try:
        m[key] = _own_cost(r, i, s, f, c.pr, c.pvec) if whole else float("nan")
    except ParameterError as exc:  # a user problem whose controls a run does not fix
        m[key] = float("nan")
        if lab == "mpc" and i == 0:
            warn.append(f"{key} is not reported: {exc}")
    m["cost_s9"], m["cost_s9_exact"] = (
        (_cost_s9(r, i, s, f), _cost_s9(r, i, s, f, exact=True)) if whole else (float("nan"), float("nan"))
    )
    m["smoothing_gap_pct"] = 100 * (m["cost_s9"] / m["cost_s9_exact"] - 1) if m["cost_s9_exact"] else float("nan")
    # like with like: every column's violations against the running formulation's bounds
    m["gap_violations"], m["speed_violations"] = _violations(r, i, c.b)
    st = (r.solver_stats or [None] * n)[i]
    if st:
        m["forecast_rms"] = st.get("forecast_rms", float("nan"))
    if lab == "mpc" and f.kind == "s9" and abs(m["smoothing_gap_pct"]) > 100 * SMOOTHING_GAP_RTOL:
        warn.append(
            f"vehicle {i + 1}: the MPC's §9 cost is {m['cost_s9']:.6g} with its smoothed η switch "
            f"but {m['cost_s9_exact']:.6g} on the exact model ({m['smoothing_gap_pct']:+.2f} %): "
            "the optimiser may exploit the smoothing (narrow mpc.smoothing_width_W)"
        )


def _run_metrics(
    out: dict[str, SimulationResult], t_end: float, c: _Costing, warn: list[str]
) -> dict[str, list[dict[str, Any]]]:
    """Every run's per-vehicle §10 metrics with the costs of :func:`_cost_vehicle`, flagged for comparability."""
    metrics = {}
    key = c.f.cost_key
    for lab, r in out.items():
        ms = r.metrics()
        whole = _covers(r, t_end)
        if not whole:
            warn.append(
                f"run {lab} stopped early ({_run_status(r)}): its costs ({key}, cost_s9) cover only "
                "part of the horizon and are not reported"
            )
        for i, m in enumerate(ms):
            _cost_vehicle(m, r, i, lab, whole, len(ms), c, warn)
        metrics[lab] = ms
    _flag_comparability(metrics)
    return metrics


def _ocpd_head(res: Any, grid_dt: float, N: int, f: Formulation) -> dict[str, Any]:
    """OCP-D's entry before its replay: a failed or time-limited solve bounds nothing (no cost reported)."""
    return {
        "success": res.success,
        "status": res.status,
        f.cost_key: res.objective if res.success else float("nan"),
        "grid_dt": grid_dt,
        "formulation": f.name,
        "objective": {"traffic": "traffic objective (the MPC's)", "s9": "model guide §9 cost"}.get(
            f.kind, f"the MPC's problem {f.name!r}"
        ),
        "objective_definition": OBJECTIVE_NAMES[f.kind],
        "N": N,
        "solve_time_s": res.wall_time_s,
        "iterations": res.iterations,
        "role": "reference",
    }


def _ocpd_replay(
    ocpd: dict[str, Any],
    sr: Any,
    t_end: float,
    c: _Costing,
    metrics: dict[str, list[dict[str, Any]]],
    warn: list[str],
) -> SimulationResult:
    """The optimal controls replayed open loop through the same exact plant: every §10 metric and the costs on
    the replay into ``ocpd``, its role (bound or reference); returns the replay."""
    s, f, key = c.s, c.f, c.f.cost_key
    scn, res, coarse = sr.scenario, sr.result, sr.coarse
    r = sr.replay
    m = r.metrics()[0]
    whole = _covers(r, t_end)
    if not whole:
        warn.append(f"the OCP-D replay stopped early ({_run_status(r)}): its replayed costs are not reported")
    # the same costs on the exact plant's trajectory
    m["cost_s9_replayed"] = _cost_s9(r, 0, s, f) if whole else float("nan")
    if f.kind != "s9":
        try:
            m[f"{key}_replayed"] = _own_cost(r, 0, s, f, c.pr, c.pvec) if whole else float("nan")
        except ParameterError:
            m[f"{key}_replayed"] = float("nan")
    m["gap_violations"], m["speed_violations"] = _violations(r, 0, c.b)
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
    return r


def _run_ocpd(
    scenario: Any,
    c: _Costing,
    metrics: dict[str, list[dict[str, Any]]],
    out: dict[str, SimulationResult],
    tim: dict[str, float],
    warn: list[str],
    say: Callable[[str], None],
    progress: Progress | None,
) -> dict[str, Any]:
    """OCP-D of the MPC's own formulation on the MPC's grid (a bound); only a run too long for that
    (> ORACLE_BOUND_MAX_INTERVALS) gets the coarser 1 s grid (a reference; 'grid_dt'). Its replay goes into
    ``out['ocp-d']``, its time into ``tim['ocpd']``."""
    t0 = time.perf_counter()
    s, f = c.s, c.f
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
    tim["ocpd"] = time.perf_counter() - t0
    ocpd = _ocpd_head(sr.result, sr.scenario.dt, sr.scenario.N, f)
    if sr.replay is not None:
        out["ocp-d"] = _ocpd_replay(ocpd, sr, scenario.t_end, c, metrics, warn)
    return ocpd


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
    out, tim = _run_all(scenario, cfg, s, f, laws, say, progress)
    warn: list[str] = []
    costing = _Costing.of(scenario, s, f)
    metrics = _run_metrics(out, scenario.t_end, costing, warn)
    ocpd = None
    if with_ocpd and scenario.n_followers == 1 and progress is not None and progress.expired():
        warn.append("OCP-D skipped: the time limit has passed")
    elif with_ocpd and scenario.n_followers == 1:
        ocpd = _run_ocpd(scenario, costing, metrics, out, tim, warn, say, progress)
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

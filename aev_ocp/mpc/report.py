"""MPC beside the closed-form laws (and the OCP-D lower bound) on the same leader: one comparison used
by ``aev-ocp mpc`` and by the ``reproduce`` report section."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import interrupts
from ..ocp.checks import GAP_RTOL as SMOOTHING_GAP_RTOL
from ..ocp.oracle import (DEFAULT_TIME_LIMIT_S, OBJECTIVE_NAMES, OracleSolver, oracle_grid_dt, scenario_oracle,
                          stage_cost_of_result)
from ..ocp.problem import OCPProblem
from ..ocp.traffic_cost import cost_traffic_of_result
from ..control import ClosedLoop, Command, ControlSequence, Observation
from ..metrics import comparability
from ..progress import Progress
from ..results import SimulationResult, write_json
from ..simulate import simulate_platoon
from .controller import default_problem
from .scenario import MPCConfig, closed_loop_from_scenario
from .settings import MPCSettings

#: every comparison table shows these first (issue 8): runs of different distance or duration (> 1 %) or
#: ended by an event are flagged 'comparable = False' and their column is marked, never ranked as complete
COMPARABILITY_ROWS = ["comparable", "distance_m", "distance_diff_pct", "duration_s", "duration_diff_pct",
                      "heat_pack_J_per_km", "omega_model_per_km", "omega_J_per_kg_per_km", "min_ttc_s"]
METRIC_ROWS = COMPARABILITY_ROWS + ["omega_model", "omega_J_per_kg", "heat_pack_J", "heat_irr_pack_J", "delta_soc", "min_gap_model",
               "min_gap_m", "min_speed_model", "rms_ovm_error_model", "rms_rel_speed_model", "rms_jerk_model",
               "max_abs_current_A", "gap_violations", "speed_violations", "collisions", "infeasible_current",
               "cost_traffic", "cost_s9", "cost_s9_exact", "smoothing_gap_pct", "forecast_rms", "solve_ms_median", "solve_ms_p95", "solve_ms_max", "iterations_mean", "iterations_max",
               "fallbacks", "fallback_causes", "solver_path"]


# Memory of building and solving the horizon-N NLP [bytes per interval]: 0.88-1.29 MB measured by
# benchmarks/bench_limits.py (peak RSS of MPCController construction + one solve, ipopt and rti, N = 40 ... 1600).
MPC_BYTES_PER_INTERVAL = 1_000_000
MAX_CLOSED_LOOP_STEPS = 10**6  # each step is one NLP solve: 10^6 steps are hours even on the fastest path


def check_mpc_scenario(scenario: Any, settings: MPCSettings, laws: tuple[str, ...] = ()) -> None:
    """Refuse, before anything runs, an MPC comparison that cannot be solved or would not fit in memory.

    Raises ScenarioError naming the file and key: MPC vehicles that do not exist, h_min above an MPC
    vehicle's initial gap or its initial speed outside [v_min, v_max] (infeasible from the first step),
    unknown or repeated comparison laws, a horizon or a number of steps too large for memory or time.
    """
    from ..models.carfollowing import LAW_REGISTRY
    from ..scenarios import ScenarioError, check_run_size, memory_limit_bytes
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
        raise ScenarioError(f"{file}: mpc.N = {settings.N} is not allowed: the NLP would need about "
                            f"{need / 1e9:.3g} GB, more than the limit of {memory_limit_bytes() / 1e9:.3g} GB "
                            f"($AEV_OCP_MAX_MEMORY_GB); use at most "
                            f"{int(memory_limit_bytes() // MPC_BYTES_PER_INTERVAL)}")
    steps = scenario.t_end / settings.dt
    if steps > MAX_CLOSED_LOOP_STEPS:
        raise ScenarioError(f"{file}: simulation.t_end = {scenario.t_end:g} is not allowed for MPC: "
                            f"{steps:.3g} closed-loop steps of mpc.dt = {settings.dt:g}, more than "
                            f"{MAX_CLOSED_LOOP_STEPS}; lower simulation.t_end or raise mpc.dt")
    check_run_size(n, scenario.t_end, min(scenario.dt_out, settings.dt), file)


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


def _cost_s9(r: SimulationResult, i: int, s: MPCSettings, exact: bool = False) -> float:
    """§9 cost Σ ℓ(z_k, a_k)·dt on the dt grid (laws: sampled at the grid), with the optimiser's smoothed
    η switch (as the MPC and OCP-D see it) or, ``exact``, the plant's exact switch."""
    return stage_cost_of_result(r, i, s.dt, s.weights, None if exact else s.smooth, s.objective)


def _cost_traffic(r: SimulationResult, i: int, s: MPCSettings, pr: OCPProblem | None) -> float | None:
    """The traffic objective of follower i's run on the MPC's dt grid (:func:`aev_ocp.ocp.traffic_cost.
    cost_traffic_of_result`, the MPC's own problem ``pr``), or None for the §9 formulation (pr None)."""
    return None if pr is None else cost_traffic_of_result(r, i, s.dt, pr)["total"]


def _on_grid(a: np.ndarray, dt_c: float, dt: float, t_end: float) -> np.ndarray:
    """Commands held for dt_c [model time] as a sequence on the grid of step dt: each dt interval takes the
    command of the dt_c interval holding its midpoint (a switch moves by at most dt/2). A traffic OCP-D on the
    coarse grid is replayed so (not interpolated between its nodes, which would smooth its jerk away)."""
    K = int(round(t_end / dt))
    return a[np.minimum(((np.arange(K) + 0.5) * dt // dt_c).astype(int), a.size - 1)]


class _HeldPlan(ControlSequence):
    """A command sequence on the MPC's grid that never commands a reverse (a_k ≥ −v_k/dt, the MPC fallback's
    rule, and a_k ≥ 0 at a stop): a coarse OCP-D's commands moved to the MPC's grid (:func:`_on_grid`) may brake up to dt/2 longer
    than planned at a stop, which made the exact plant's speed negative (UDDS-300 s at t = 153)."""

    def command(self, obs: Observation) -> Command:
        a, v = float(self.a[int(round(obs.t / self.dt))]), float(obs.z[1])
        # at a stop (v < 1e-9) no braking at all: −v/dt there would shrink v geometrically towards 0 without
        # reaching it (2e-137 at t = 1171 of the whole UDDS, where CVODES failed)
        return Command(max(a, 0.0) if v < 1e-9 else max(a, -v / self.dt))


def run_comparison(scenario: Any, settings: MPCSettings | None = None, laws: tuple[str, ...] = ("proposed", "ovfl"),
                   with_ocpd: bool = True, log: Callable[[str], None] | None = None,
                   progress: Progress | None = None) -> Comparison:
    """MPC closed loop on ``scenario`` (its [mpc] table, or ``settings``) beside each law in ``laws``
    (whole platoon on that law, same leader and initial state) and OCP-D for a single follower.
    progress: reports the MPC loop (step k/N, ETA) and holds its time limit: the loop then stops with
    status 'time_limit' (a partial result) and OCP-D is skipped."""
    cfg: MPCConfig = scenario.extra.get("mpc") or MPCConfig(MPCSettings())
    s = settings or cfg.settings
    say = log or (lambda m: None)
    out: dict[str, SimulationResult] = {}
    tim: dict[str, float] = {}
    t0 = time.perf_counter()
    say(f"MPC closed loop ({s.solver}{'+codegen' if s.codegen else ''}, N = {s.N}) on {scenario.name}")
    out["mpc"] = closed_loop_from_scenario(scenario, cfg, s).run(list(scenario.gaps0), list(scenario.speeds0),
                                                                 scenario.t_end,
                                                                 progress=(progress.closed_loop(s.dt) if progress
                                                                           else _progress(say, "mpc")))
    tim["mpc"] = time.perf_counter() - t0
    for name in laws:
        t0 = time.perf_counter()
        law = scenario.law(name)
        out[name] = simulate_platoon(scenario.leader, [law] * scenario.n_followers, list(scenario.gaps0),
                                     list(scenario.speeds0), scenario.t_end, ev=scenario.ev, rtol=scenario.rtol,
                                     atol=scenario.atol, dt_out=min(scenario.dt_out, s.dt),
                                     progress=_progress(lambda m: None, name))
        tim[name] = time.perf_counter() - t0
    metrics = {}
    warn: list[str] = []
    traffic = s.formulation == "traffic"
    # the MPC's own problem (built as the controller builds it), for cost_traffic on its grid
    pr = default_problem(scenario.ev, s).build() if traffic else None
    for lab, r in out.items():
        ms = r.metrics()
        whole = _covers(r, scenario.t_end)
        if not whole:
            warn.append(f"run {lab} stopped early ({_run_status(r)}): its costs (cost_s9, cost_traffic) cover only "
                        "part of the horizon and are not reported")
        for i, m in enumerate(ms):
            if traffic:
                m["cost_traffic"] = _cost_traffic(r, i, s, pr) if whole else float("nan")
            m["cost_s9"], m["cost_s9_exact"] = ((_cost_s9(r, i, s), _cost_s9(r, i, s, exact=True)) if whole
                                                else (float("nan"), float("nan")))
            m["smoothing_gap_pct"] = 100 * (m["cost_s9"] / m["cost_s9_exact"] - 1) if m["cost_s9_exact"] else float("nan")
            st = (r.solver_stats or [None] * len(ms))[i]
            if st:
                m["forecast_rms"] = st.get("forecast_rms", float("nan"))
            if lab == "mpc" and abs(m["smoothing_gap_pct"]) > 100 * SMOOTHING_GAP_RTOL:
                warn.append(f"vehicle {i + 1}: the MPC's §9 cost is {m['cost_s9']:.6g} with its smoothed η switch "
                            f"but {m['cost_s9_exact']:.6g} on the exact model ({m['smoothing_gap_pct']:+.2f} %): "
                            "the optimiser may exploit the smoothing (narrow mpc.smoothing_width_W)")
        metrics[lab] = ms
    _flag_comparability(metrics)
    ocpd = None
    if with_ocpd and scenario.n_followers == 1 and progress is not None and progress.expired():
        warn.append("OCP-D skipped: the time limit has passed")
    elif with_ocpd and scenario.n_followers == 1:
        t0 = time.perf_counter()
        # a long run (e.g. a whole drive cycle) gets the coarser 1 s grid (oracle_grid_dt, meta 'grid_dt');
        # a traffic MPC gets the OCP-D of its own problem (the jerk term on the OCP-D grid step)
        scn = scenario_oracle(scenario, oracle_grid_dt(scenario.t_end, s.dt, scenario.units), s.weights, s.bounds,
                              s.smooth, s.objective, formulation="traffic" if traffic else "s9", traffic=s.traffic)
        say(f"OCP-D lower bound (whole scenario, IPOPT, N = {scn.N}, dt = {scn.dt:.4g})")
        # IPOPT's wall-time limit: what is left of the run's time limit (at most the OCP-D default)
        left = progress.remaining_s() if progress is not None else math.inf
        res = OracleSolver(scn, progress=say, time_limit_s=min(DEFAULT_TIME_LIMIT_S, max(left, 1e-3))).solve()
        interrupts.check()  # IPOPT turns Ctrl-C into a failed solve
        tim["ocpd"] = time.perf_counter() - t0
        # a failed or time-limited solve bounds nothing: no cost is reported for it
        key = "cost_traffic" if traffic else "cost_s9"
        ocpd = {"success": res.success, "status": res.status, key: res.objective if res.success else float("nan"),
                "grid_dt": scn.dt, "objective": "traffic objective (the MPC's)" if traffic else "PROBLEM.md §9 cost"}
        if traffic:
            ocpd.update({"objective_definition": OBJECTIVE_NAMES[scn.formulation], "N": scn.N,
                         "solve_time_s": res.wall_time_s, "iterations": res.iterations})
        if res.success:
            # replay the optimal controls open loop through the same exact plant: every §10 metric
            say("OCP-D: replaying its controls through the exact plant")
            a_opt = np.asarray(res.controls["a"], float).ravel()
            coarse = abs(scn.dt - s.dt) > 1e-9 * s.dt
            seq = (_HeldPlan(tuple(_on_grid(a_opt, scn.dt, s.dt, scenario.t_end)), s.dt, "ocp-d")
                   if traffic and coarse else ControlSequence(tuple(a_opt), scn.dt, "ocp-d"))
            r = ClosedLoop(scenario.leader, [seq], scenario.ev).run(list(scenario.gaps0), list(scenario.speeds0),
                                                                   scenario.t_end, progress=_progress(say, "ocp-d replay"))
            m = r.metrics()[0]
            whole = _covers(r, scenario.t_end)
            if not whole:
                warn.append(f"the OCP-D replay stopped early ({_run_status(r)}): its replayed costs are not reported")
            # the same cost on the exact plant's trajectory
            m["cost_s9_replayed"] = _cost_s9(r, 0, s) if whole else float("nan")
            if traffic:
                m["cost_traffic_replayed"] = _cost_traffic(r, 0, s, pr) if whole else float("nan")
            ocpd.update({k: v for k, v in m.items() if k not in ("vehicle", "controller")})
            ocpd[key] = res.objective
            if traffic:  # §9's cost of the traffic optimum's replay: a number beside the others, not a bound
                ocpd["cost_s9"] = m["cost_s9_replayed"]
            if coarse:  # a coarser grid's optimum bounds nothing on the MPC's grid
                ocpd[f"{key}_grid"], ocpd[key] = res.objective, m[f"{key}_replayed"]
                warn.append(f"OCP-D was solved on a coarser grid (dt = {scn.dt:.4g}, the MPC's {s.dt:g}): its {key} "
                            f"is its controls replayed and costed on the MPC's grid, a reference, not a lower bound "
                            f"(its own grid's optimum: {res.objective:.6g})")
            ref = (metrics.get("proposed") or metrics["mpc"])[0]
            ocpd.update({k: v for k, v in comparability(m, ref).items()})
            out["ocp-d"] = r
    for w in warn:
        say(f"warning: {w}")
    return Comparison(out, metrics, ocpd, tim, warn)


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
        return "ok" if not r.violations else "violated (" + ", ".join(f"vehicle {e.vehicle + 1}" for e in r.violations) + ")"
    e = r.events[0]
    when = f"{e.time_s:.4g} s ({e.time:.4g} model)" if e.time_s is not None else f"{e.time:.4g}"
    return f"{e.kind} at t = {when}" + (f" (vehicle {e.vehicle + 1})" if e.vehicle >= 0 else "")


def comparison_table(c: Comparison, vehicle: int = 0, markdown: bool = False) -> str:
    """Every §10 metric of follower ``vehicle`` side by side (MPC, laws, OCP-D)."""
    labs = list(c.metrics)
    cols = labs + (["ocp-d"] if c.ocpd and vehicle == 0 else [])
    rows = []
    for key in METRIC_ROWS:
        vals = [c.metrics[lab][vehicle].get(key) for lab in labs]
        if "ocp-d" in cols:
            vals.append(c.ocpd.get(key) if c.ocpd else None)
        if all(v is None for v in vals):
            continue
        rows.append([key] + [_fmt(v) for v in vals])
    status = [_run_status(c.results[lab]) if lab in c.results else "—" for lab in labs]
    flag = [c.metrics[lab][vehicle].get("comparable", True) for lab in labs]
    if "ocp-d" in cols:
        status.append(_run_status(c.results["ocp-d"]) if "ocp-d" in c.results else (c.ocpd or {}).get("status", "—"))
        flag.append(bool((c.ocpd or {}).get("comparable", False)))
    cols = [col if ok else f"{col} (NOT COMPARABLE)" for col, ok in zip(cols, flag)]
    rows.insert(0, ["status"] + status)
    head = ["metric"] + cols
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        return "\n".join(lines)
    w = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    return "\n".join("  ".join(str(x).ljust(wi) if j == 0 else str(x).rjust(wi) for j, (x, wi) in enumerate(zip(r, w)))
                     for r in [head] + rows)


def write_outputs(c: Comparison, out: Path) -> list[Path]:
    """results.json, trajectories CSV and plots of a comparison into ``out``."""
    from ..plots import plot_trajectories
    from .plots import plot_overlay, plot_solve_times

    out.mkdir(parents=True, exist_ok=True)
    r = c.results["mpc"]
    files = [write_json(out / "results.json", {"scenario": r.meta.get("leader"), "status": r.status,
                                               "events": [vars(e) for e in r.events], "metrics": c.metrics,
                                               "runs": {lab: {"status": res.status,
                                                              "events": [vars(e) for e in res.events]}
                                                        for lab, res in c.results.items()},
                                               "ocp_d": c.ocpd, "timings_s": c.timings_s, "warnings": c.warnings,
                                               "mpc_settings": r.meta.get("controllers"),
                                               "mpc_steps": r.meta.get("mpc_steps")})]
    files.append(r.to_csv(out / "trajectories_mpc.csv"))
    files.append(plot_trajectories(r, out / "mpc_trajectories.png"))
    files.append(plot_solve_times(r, out / "mpc_solve_times.png"))
    for i in range(r.n_vehicles):
        files.append(plot_overlay(c.results, out / f"overlay_vehicle{i + 1}.png", vehicle=i))
        if i >= 1 and r.n_vehicles > 3 and i != r.n_vehicles - 1:
            continue
    return files


def mpc_section(out_dir: Any, progress: Callable[[str], None]) -> str:
    """Reproduce section: the canonical MPC (PROBLEM.md §9) beside the proposed law and OVFL (and OCP-D)."""
    from ..scenarios import find_scenario, load_scenario

    out = Path(out_dir) / "mpc"
    progress("MPC: canonical scenario (mpc_paper_single)")
    sc = load_scenario(find_scenario("mpc_paper_single"))
    c = run_comparison(sc, log=progress)
    progress("MPC: writing tables and plots")
    write_outputs(c, out)
    st = c.metrics["mpc"][0]
    lines = ["## MPC with the battery in the loop (PROBLEM.md §9)", "",
             f"Canonical scenario: one follower behind the Table 1 leader, h(0) = 0.3, v(0) = 1.87, oracle "
             f"forecast, N = 40, dt = 0.1, w = (1, 1, 1, 0.1), t ∈ [0, {sc.t_end:g}]. Exact plant (CVODES, "
             f"unsmoothed η switch). Solver path {st.get('solver_path')} (QP {st.get('qp_solver') or '—'}): median {st.get('solve_ms_median', float('nan')):.2f} ms, "
             f"p95 {st.get('solve_ms_p95', float('nan')):.2f} ms, max {st.get('solve_ms_max', float('nan')):.2f} ms per "
             f"step, {st.get('fallbacks')} fallbacks. `cost_s9` is Σ ℓ(z_k, a_k)·dt of §9 on the dt grid "
             "(smoothed η, as in OCP-D); OCP-D is the lower bound of that cost. `cost_s9_exact` is the same "
             "cost with the exact η switch; `smoothing_gap_pct` their difference (a warning above 0.5 %).", "",
             comparison_table(c, 0, markdown=True), "",
             "Plots: `mpc/overlay_vehicle1.png` (trajectories, current, SOC), `mpc/mpc_solve_times.png`.", ""]
    if c.ocpd and c.ocpd.get("success"):
        gap = 100 * (st["cost_s9"] / c.ocpd["cost_s9"] - 1)
        lines.append(f"MPC's §9 cost is {gap:.3f} % above the OCP-D lower bound.")
    lines += [f"**Warning:** {w}" for w in c.warnings]
    return "\n".join(lines) + "\n"

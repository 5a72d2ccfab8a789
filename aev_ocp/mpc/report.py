"""The MPC comparison's tables, files and ``reproduce`` section (:func:`aev_ocp.mpc.run.run_comparison` runs
it). The running formulation's own cost is the only cost row; another formulation's cost (the §9
cost of a traffic MPC) is only in a secondary table. Equal-distance and equal-time views
(:func:`aev_ocp.truncation.equal_views`) rank runs of different length."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..limits import MPC_BYTES_PER_INTERVAL, memory_limit_bytes
from ..results import write_json
from ..truncation import VIEW_KEYS
from .run import Comparison, _run_status, run_comparison
from .settings import MPCSettings

#: every comparison table shows these first: runs of different distance or duration (> 1 %) or
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
    "qp_acceptable",
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


def _fmt(x: Any) -> str:
    if isinstance(x, (bool, np.bool_)):
        return str(x)
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        return f"{x:.5g}" if np.isfinite(x) else "—"
    return "—" if x is None else str(x)


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


def write_outputs(c: Comparison, out: Path, plots: bool = True) -> list[Path]:
    """results.json, trajectories CSV and (``plots``) the PNG plots of a comparison into ``out``."""
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
    if not plots:
        return files
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


def write_comparison(c: Comparison, out: Path, settings: dict[str, Any], plots: bool = True) -> None:
    """:func:`write_outputs` (the PNG plots if ``plots``) and the saved runs (manifest.json with ``settings`` and the
    comparison's OCP-D, metrics, timings and warnings; trajectories.npz) that ``aev_ocp.load(out)`` reads."""
    from ..saved import save_output

    write_outputs(c, out, plots)
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

    from ..report_sections import SectionContext

    out = Path(out_dir) / "mpc"
    progress("MPC: canonical scenario (mpc_paper_single)")
    sc = load_scenario(find_scenario("mpc_paper_single"))
    cap = SectionContext.of(progress).config.scenario_t_end_max  # a reduced configuration's horizon cap
    if cap is not None and sc.t_end > cap:
        sc = sc.replace(t_end=cap)
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

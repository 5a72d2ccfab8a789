"""Report section "MPC on drive cycles" (``aev-ocp reproduce``): one follower behind UDDS, HWFET, US06
and the paper's leader, MPC with each forecast beside the proposed law and OVFL, and the UDDS platoon
with every follower on MPC. Rows from :mod:`aev_ocp.mpc.cycles`; written as CSV, JSON and Markdown."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from ..report import csv_text, fmt, markdown_table, write_text
from ..results import write_json
from .cycles import (
    COLUMNS,
    CYCLE_SCENARIOS,
    PREDICTORS,
    REFERENCE,
    STOP_HOLD_S,
    cycle_rows,
    cycle_scenario,
    platoon_rows,
    rank_rows,
    run_cycle,
)

#: Segment of each cycle run in ``reproduce`` [s]: the first 120 s, extended to the leader's first
#: 20-s stop after it (cycles.STOP_HOLD_S: UDDS 145 s; HWFET and US06 have no such stop: whole, 765 s and
#: 600 s; the paper leader: whole, 140 s) so every run ends at rest and distances are comparable (a cut at
#: 120 s left the MPC, which keeps a 2.5 s time gap, 1.25 % behind the laws on HWFET). The whole UDDS
#: (1369 s) stays with the scenarios (``aev-ocp mpc mpc_udds_single``) and benchmarks/bench_mpc_cycles.py.
SEGMENT_S = 120.0
#: Segment of the 5-follower UDDS platoon in ``reproduce`` [s] (five MPC solves per step), extended to the
#: leader's first 20-s stop after it (145 s).
PLATOON_SEGMENT_S = 60.0
#: Solver path of the section: real-time iteration, the whole step compiled with the Riccati interior-point
#: QP ('auto' = 'riccati' on the rti path) — the fast path of the shipped MPC scenarios (mpc_paper_single:
#: closed-loop cost within 0.001 % of the IPOPT path's, benchmarks/bench_mpc.py). Only the path is set: the
#: formulation is MPCSettings()'s default.
SOLVER_PATH: dict[str, Any] = {"solver": "rti", "qp_solver": "auto", "codegen": True}
#: Progress lines the section reports (declared to the reproduce Progress counter).
#: Of the default reproduce, which runs one forecast per cycle (``reproduce --full`` runs both: its other forecast's
#: lines are sub-steps, the denominator stays).
STEPS = 4 * 1 * 6 + 6 + 1  # 6 lines per MPC run (start + every 25 %), the platoon run, writing


def _prefixed(progress: Callable[[str], None], prefix: str) -> Callable[[str], None]:
    return lambda m: progress(prefix + m)


def _capped(sc: Any, t_end_max: float | None) -> Any:
    return sc if t_end_max is None or sc.t_end <= t_end_max else sc.replace(t_end=t_end_max)


def section_settings() -> Any:
    """MPCSettings() with the section's solver path (:data:`SOLVER_PATH`)."""
    from .settings import MPCSettings

    return MPCSettings().with_(**SOLVER_PATH)


def _cell(key: str, v: Any) -> str:
    if key == "comparable":
        return "yes" if v else "**no**"
    if key in ("rank", "rank_eq_distance", "rank_eq_time"):
        return "not ranked" if v is None else str(v)
    if isinstance(v, str):
        return v or "—"
    if isinstance(v, float) and math.isinf(v):
        return "∞"
    return fmt(v)


#: Markdown headers of the main table (units in brackets).
HEADERS: dict[str, str] = {
    "cycle": "cycle",
    "vehicle": "follower",
    "controller": "controller",
    "predictor": "forecast",
    "status": "run",
    "battery_energy_kWh_per_100km": "battery energy [kWh/100 km]",
    "heat_pack_J_per_km": "pack ∫Q [J/km]",
    "charge_throughput_Ah_per_km": "charge throughput [Ah/km]",
    "omega_J_per_kg_per_km": "ω, the paper's measure [J/kg/km]",
    "distance_m": "distance [m]",
    "duration_s": "duration [s]",
    "min_gap_m": "min gap [m]",
    "min_ttc_s": "min TTC [s]",
    "rms_jerk_model": "RMS jerk [model]",
    "fallbacks": "fallbacks",
    "solve_ms_p50": "solve p50 [ms]",
    "solve_ms_p99": "solve p99 [ms]",
    "forecast_rms": "forecast RMS [model]",
    "distance_diff_pct": "Δdistance [%]",
    "duration_diff_pct": "Δduration [%]",
    "comparable": "comparable",
    "flags": "flags",
    "rank": "rank (∫Q/km)",
    "eq_distance_m": "equal distance [m]",
    "heat_pack_J_per_km_eq_distance": "∫Q/km to equal distance [J/km]",
    "rank_eq_distance": "rank (equal distance)",
    "eq_time_s": "equal time [s]",
    "heat_pack_J_per_km_eq_time": "∫Q/km to equal time [J/km]",
    "rank_eq_time": "rank (equal time)",
}
#: Columns of the Markdown table: all of :data:`COLUMNS` (the CSV/JSON) but the vehicle, the status (in flags) and the
#: run lengths and their differences (summarised by 'comparable' and the equal-distance/-time columns).
_MD_LEFT_OUT = (
    "vehicle",
    "status",
    "duration_s",
    "distance_diff_pct",
    "duration_diff_pct",
    "eq_distance_m",
    "eq_time_s",
)
MD_COLUMNS: tuple[str, ...] = tuple(c for c in COLUMNS if c not in _MD_LEFT_OUT)


def write_tables(
    rows: Sequence[dict[str, Any]], platoon: Sequence[dict[str, Any]], out: Path, meta: dict[str, Any]
) -> tuple[str, list[Path]]:
    """cycles.csv, cycles.json (rows, platoon rows, meta) and cycles.md into ``out``; returns the Markdown
    table of ``rows`` and the files."""
    out.mkdir(parents=True, exist_ok=True)
    md = markdown_table([HEADERS[k] for k in MD_COLUMNS], [[_cell(k, r[k]) for k in MD_COLUMNS] for r in rows])
    files = [
        write_text(out / "cycles.csv", csv_text(list(COLUMNS), [[r[k] for k in COLUMNS] for r in rows])),
        write_json(out / "cycles.json", {"rows": list(rows), "platoon": list(platoon), "meta": meta}),
        write_text(out / "cycles.md", md),
    ]
    return md, files


def platoon_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """Per-follower pack ∫Q of the MPC platoon vs the proposed law."""
    head = [
        "follower",
        "pack ∫Q MPC [J]",
        "pack ∫Q proposed [J]",
        "MPC [J/km]",
        "proposed [J/km]",
        "change [%]",
        "fallbacks",
        "min gap MPC [m]",
        "distance vs proposed [%]",
        "comparable",
    ]
    body = [
        [
            str(r["vehicle"]),
            fmt(r["heat_pack_J_mpc"]),
            fmt(r["heat_pack_J_ref"]),
            fmt(r["heat_pack_J_per_km_mpc"]),
            fmt(r["heat_pack_J_per_km_ref"]),
            (f"{r['change_pct']:+.2f}" if r["comparable"] else "not ranked"),
            fmt(r["fallbacks"]),
            fmt(r["min_gap_m"]),
            f"{r['distance_diff_pct']:+.2f}",
            _cell("comparable", r["comparable"]),
        ]
        for r in rows
    ]
    return markdown_table(head, body)


def verdicts(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Per cycle: the comparable controller with the lowest pack ∫Q/km and how MPC compares with the
    proposed law (comparable rows only; a cycle with non-comparable MPC rows says so)."""
    lines = []
    for cyc in dict.fromkeys(r["cycle"] for r in rows):
        rs = [r for r in rows if r["cycle"] == cyc]
        best = [r for r in rs if r["rank"] == 1]
        ref = next((r for r in rs if r["controller"] == REFERENCE and r["comparable"]), None)
        parts = []
        for r in rs:
            if r["controller"] != "mpc":
                continue
            if not r["comparable"] or ref is None:
                parts.append(f"MPC/{r['predictor']} not comparable ({r['flags']}), not ranked")
            else:
                d = 100.0 * (r["heat_pack_J_per_km"] / ref["heat_pack_J_per_km"] - 1.0)
                parts.append(f"MPC/{r['predictor']} {d:+.1f} % pack ∫Q/km vs the proposed law")
        name = lambda r: "MPC" if r["controller"] == "mpc" else r["controller"]  # noqa: E731
        lead = (
            (
                f"lowest pack ∫Q/km among comparable runs: {name(best[0])}"
                + (f"/{best[0]['predictor']}" if best[0]["predictor"] != "—" else "")
            )
            if best
            else "no comparable run"
        )
        eq = [r for r in rs if r.get("rank_eq_distance") == 1]
        eq_line = (
            f" Equal distance (every run up to {rs[0]['eq_distance_m']:.6g} m): lowest pack ∫Q/km "
            f"{name(eq[0])}" + (f"/{eq[0]['predictor']}" if eq[0]["predictor"] != "—" else "") + "."
            if eq and math.isfinite(float(rs[0].get("eq_distance_m", math.nan)))
            else ""
        )
        lines.append(f"- **{cyc}**: {lead}; " + "; ".join(parts) + "." + eq_line)
    return lines


def _save_cycle(runs: dict[tuple[str, Any], Any], folder: Path, sc: Any, title: str) -> str:
    """Save one cycle's runs (loadable: labels ``mpc+<forecast>`` and the laws' names) and their overlay figure
    ``overlay.png`` into ``folder``; returns the Markdown image line (path relative to the report)."""
    from ..saved import FIGURE_MAX_SAMPLES, save_output, settings_of
    from .plots import plot_overlay

    labelled = {(name if pred is None else f"{name}+{pred}"): r for (name, pred), r in runs.items()}
    primary = next((k for k in labelled if k.startswith("mpc")), None)
    save_output(
        folder,
        "mpc" if primary else "simulate",
        labelled,
        primary=primary,
        settings=settings_of(sc),
        max_samples=FIGURE_MAX_SAMPLES,  # for the figures (metrics: every sample)
    )
    plot_overlay(labelled, folder / "overlay.png", vehicle=0)
    rel = f"{folder.parent.name}/{folder.name}/overlay.png"
    return f"![{title}]({rel})"


def _segment_text(segment_s: float | None, seg_s: dict[str, float], t_end_max: float | None) -> str:
    """What part of each cycle ran: whole, or the first segment_s [s] extended to rest (each cycle's length)."""
    seg_txt = (
        "whole cycles"
        if segment_s is None
        else f"the first {segment_s:g} s of each cycle, extended to the first moment the leader has stood still "
        f"for {STOP_HOLD_S:g} s (or to the cycle's end) so that every run ends at rest: "
        + ", ".join(f"{c} {t:.0f} s" for c, t in seg_s.items())
    )
    if t_end_max is not None:
        seg_txt += f", capped at t = {t_end_max:g} model time units (reduced configuration)"
    return seg_txt


def _cycle_lines(
    cycles: Sequence[str],
    predictors: Sequence[str],
    s: Any,
    seg_txt: str,
    elapsed: float,
    md: str,
    rows: list[dict[str, Any]],
) -> list[str]:
    """The section's head, the single-follower table and the verdicts."""
    n_bad = sum(not r["comparable"] for r in rows)
    return [
        "## MPC on drive cycles",
        "",
        f"One follower from rest, 0.8 L behind the leader (scenarios {', '.join(CYCLE_SCENARIOS[c] for c in cycles)}), "
        f"over {seg_txt} (reproduce runs a segment to stay usable: the section took {elapsed:.0f} s here; the whole "
        "cycles run with `aev-ocp mpc mpc_udds_single` etc. and benchmarks/bench_mpc_cycles.py). MPC: the "
        f"MPCSettings() default formulation on the solver path {s.solver}"
        f"{'+codegen' if s.codegen else ''} (qp {s.qp}), N = {s.N}, dt = {s.dt:g}, with a measured forecast "
        f"({', '.join(predictors)}; no oracle); the laws do not forecast (—). Exact plant (CVODES). "
        "Per-km values divide by the follower's own distance. Solve p50/p99: per-step MPC solve time.",
        "",
        f"**Comparable results.** A row whose distance or duration differs from the proposed law's by more than "
        f"1 % or whose run ended by an event is marked **no** with the reason and is not ranked nor used in a "
        f"verdict ({n_bad} such rows here). Rank: pack ∫Q/km among the comparable rows of the cycle.",
        "",
        md,
        "Verdicts (comparable rows only):",
        "",
    ] + verdicts(rows)


def _platoon_lines(sc: Any, pred: str, plat: list[dict[str, Any]], figures: list[str]) -> list[str]:
    """The UDDS platoon's table (and why a follower may not be comparable), the figures and the files."""
    lines = [
        "",
        f"UDDS platoon (mpc_udds_platoon, first {sc.t_end * sc.units.time_s:.4g} s): five followers all on MPC (follower 1 "
        f"{pred}, the others their predecessor's plan) vs all five on the proposed law, per follower:",
        "",
        platoon_markdown(plat),
    ]
    if not all(r["comparable"] for r in plat):
        lines += [
            "A follower marked **no** ends the segment with a distance more than 1 % off its proposed-law "
            "counterpart's (column 'distance vs proposed'): the MPC followers stop with their standstill gaps (2 m floor, 4 m target, "
            "aev_ocp/ocp/traffic.py) while the laws creep towards h = V⁻¹(0) = 0, and the difference adds up "
            "along the platoon. Over the whole cycle it is a small fraction of the distance: "
            "`python benchmarks/bench_mpc_cycles.py --full --cycles udds --platoon`.",
            "",
        ]
    lines += ["Gap, speed, acceleration, current and SOC of follower 1 under every controller, per cycle:", ""]
    lines += [f + "\n" for f in figures]
    lines += [
        "Files: `mpc_cycles/cycles.csv`, `mpc_cycles/cycles.json` (every column, the platoon rows, run wall "
        'times), `mpc_cycles/cycles.md`; each cycle\'s runs load back with `aev_ocp.load_all("mpc_cycles/<cycle>")` '
        "(run labels `mpc+<forecast>` and the laws' names).",
        "",
    ]
    return lines


def cycles_section(
    out_dir: Any,
    progress: Callable[[str], None],
    segment_s: float | None = SEGMENT_S,
    platoon_segment_s: float | None = PLATOON_SEGMENT_S,
    cycles: Sequence[str] = tuple(CYCLE_SCENARIOS),
    predictors: Sequence[str] = PREDICTORS,
    settings: Any = None,
    t_end_max: float | None = None,
) -> str:
    """The section: runs, tables (``out_dir``/mpc_cycles/cycles.{csv,json,md}) and Markdown text.
    segment_s / platoon_segment_s: first seconds of each cycle / of the platoon run (None: whole);
    t_end_max: a further cap on every run's horizon [model time] (reduced reproduce configurations)."""
    out = Path(out_dir) / "mpc_cycles"
    s = settings if settings is not None else section_settings()
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    figures: list[str] = []  # Markdown image lines, one per cycle
    wall: dict[str, dict[str, float]] = {}
    seg_model: dict[str, float] = {}
    seg_s: dict[str, float] = {}  # the same segments in seconds (each cycle's own units)
    for cyc in cycles:
        sc = _capped(cycle_scenario(cyc, segment_s, end_at_rest=True), t_end_max)
        seg_model[cyc], seg_s[cyc] = sc.t_end, sc.units.time_to_si(sc.t_end)
        runs, wall[cyc] = run_cycle(sc, predictors, settings=s, log=_prefixed(progress, f"MPC cycles, {cyc}: "))
        rows += cycle_rows(cyc, runs, vehicles=[0])
        figures.append(_save_cycle(runs, out / cyc, sc, f"{cyc}: every controller"))
    rank_rows(rows)
    sc = _capped(cycle_scenario("udds", platoon_segment_s, platoon=True, end_at_rest=True), t_end_max)
    seg_model["udds_platoon"] = sc.t_end
    pred = sc.extra["mpc"].settings.predictor
    runs, wall["udds_platoon"] = run_cycle(
        sc, (pred,), laws=(REFERENCE,), settings=s, log=_prefixed(progress, "MPC cycles, UDDS platoon: ")
    )
    figures.append(_save_cycle(runs, out / "udds_platoon", sc, "UDDS platoon, follower 1"))
    plat = platoon_rows(runs, ("mpc", pred))
    elapsed = time.perf_counter() - t0
    progress("MPC cycles: writing tables")
    seg_txt = _segment_text(segment_s, seg_s, t_end_max)
    meta = {
        "segment_s": segment_s,
        "platoon_segment_s": platoon_segment_s,
        "t_end_model": seg_model,
        "settings": dataclasses.asdict(s),
        "wall_time_s": wall,
        "section_wall_time_s": elapsed,
        "platoon_predictor": pred,
    }
    md, _ = write_tables(rows, plat, out, meta)
    lines = _cycle_lines(cycles, predictors, s, seg_txt, elapsed, md, rows) + _platoon_lines(sc, pred, plat, figures)
    return "\n".join(lines)


#: The single-follower cycles of a reduced reproduce configuration (scenario_t_end_max set: a smoke run), beside the
#: UDDS platoon; the default and full reproductions run every cycle of CYCLE_SCENARIOS (issue 40: 2.3 s of a test's CPU)
REDUCED_CYCLES = ("udds",)
#: Progress lines of one single-follower cycle per forecast: the run's start and every 25 % of it
LINES_PER_RUN = 6


def _reproduce_section(out_dir: Any, progress: Callable[[str], None]) -> str:
    """The section as ``reproduce`` runs it: a reduced configuration's scenario_t_end_max [model time]
    caps every segment (e.g. ReproduceConfig.quick(): 10 time units) and runs the cycles of :data:`REDUCED_CYCLES`
    only (one progress line for each line of a cycle left out: the counter does not jump); the MPC runs with the
    default forecast only unless ``config.extended`` (``reproduce --full``: every forecast of :data:`PREDICTORS`)."""
    from ..report_sections import SectionContext

    cfg = SectionContext.of(progress).config
    # reduced by default (aev_ocp.reproduce.REDUCED_BY_DEFAULT): the MPC with its default forecast only; --full: all
    preds = PREDICTORS if cfg.extended else (section_settings().predictor,)
    if cfg.scenario_t_end_max is None:
        return cycles_section(out_dir, progress, predictors=preds)
    for _ in range((len(CYCLE_SCENARIOS) - len(REDUCED_CYCLES)) * len(preds) * LINES_PER_RUN):
        progress("MPC cycles: reduced configuration")
    return cycles_section(out_dir, progress, predictors=preds, t_end_max=cfg.scenario_t_end_max, cycles=REDUCED_CYCLES)


REPRODUCE_SECTIONS = [("mpc-cycles", _reproduce_section, STEPS)]  # listed in aev_ocp.reproduce.SECTION_PROVIDERS

"""Report section "battery life" (``aev-ocp reproduce``): the proposed law, OVFL and the MPC on the EPA cycles
at a hot and a cold ambient with the lumped pack thermal model on, and the capacity and resistance each
controller's drive leaves after 1/5/10 years of a stated daily schedule (:mod:`aev_ocp.life`, NREL BLAST-Lite).

Cheap by construction: one follower, the first :data:`SEGMENT_S` seconds of each cycle; without BLAST-Lite the
section still reports the temperatures and says in one line how to install it.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Callable

from .life import BLAST_MODELS, INSTALL_HINT, DailySchedule, blast_available, life_of_run
from .report import csv_text, fmt, markdown_table, write_text
from .results import write_json

#: Segment of each cycle [s] (the issue's "keep it cheap": 300 s).
SEGMENT_S = 300.0
#: Ambient temperatures [K]: hot 35 °C and cold 10 °C (the cycling range of BLAST-Lite's LFP model is 20-40 °C;
#: 10 °C is extrapolated by its Arrhenius terms, said in the section).
AMBIENTS_K = {"hot": 308.15, "cold": 283.15}
CYCLES = ("udds", "hwfet", "us06")
LAWS = ("proposed", "ovfl")
YEARS = 10.0
STEPS = len(CYCLES) * len(AMBIENTS_K) + 1


def life_rows(
    cycles: tuple[str, ...] = CYCLES,
    ambients_K: dict[str, float] | None = None,
    segment_s: float = SEGMENT_S,
    years: float = YEARS,
    schedule: DailySchedule | None = None,
    log: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """One row per cycle × ambient × controller: pack heat, temperature metrics and (with BLAST-Lite) the battery
    life of the drive repeated by ``schedule``."""
    from .metrics import vehicle_metrics
    from .mpc.cycles import cycle_scenario, run_cycle
    from .mpc.cycles_section import section_settings

    amb = ambients_K or AMBIENTS_K
    rows: list[dict[str, Any]] = []
    with_life = blast_available()
    for cyc in cycles:
        base = cycle_scenario(cyc, segment_s)
        chem = _chemistry(base.ev.cell)
        for label, T_amb in amb.items():
            if log:
                log(f"battery life: {cyc}, {label} ambient")
            sc = base.with_overrides({"thermal.enabled": True, "thermal.ambient_K": T_amb})
            s = section_settings()
            runs, _ = run_cycle(sc, (s.predictor,), laws=LAWS, settings=s)
            for (ctrl, _pred), r in runs.items():
                m = vehicle_metrics(r, 0)
                row: dict[str, Any] = {
                    "cycle": cyc,
                    "ambient": label,
                    "ambient_K": T_amb,
                    "controller": ctrl,
                    "status": r.status,
                    "duration_s": m["duration_s"],
                    "distance_m": m["distance_m"],
                    "battery_energy_kWh_per_100km": m["battery_energy_kWh_per_100km"],
                    "heat_pack_J_per_km": m["heat_pack_J_per_km"],
                    "charge_throughput_Ah_per_km": m["charge_throughput_Ah_per_km"],
                    "heat_irr_pack_J": m["heat_irr_pack_J"],
                    "peak_temperature_K": m["peak_temperature_K"],
                    "mean_temperature_K": m["mean_temperature_K"],
                    "time_above_T_max_s": m["time_above_T_max_s"],
                    "chemistry": chem,
                }
                if with_life:
                    row.update(life_of_run(r, 0, chem, schedule, years))
                rows.append(row)
    return rows


def _chemistry(cell: Any) -> str:
    """The chemistry of the shipped cell file whose values the scenario's cell has (LFP for the A123 defaults)."""
    from .cells import load_cell_file, shipped_cells

    for name in shipped_cells():
        cf = load_cell_file(name)
        same = all(
            getattr(cf.cell, k) == getattr(cell, k)
            for k in ("capacity_Ah", "R_s_ohm", "R1_ohm", "C1_F", "R2_ohm", "C2_F")
        )
        if same:
            return str(cf.chemistry)
    return "LFP"  # the default cell is the A123 (LFP)


COLUMNS = (
    "cycle",
    "ambient",
    "controller",
    "battery_energy_kWh_per_100km",
    "heat_pack_J_per_km",
    "charge_throughput_Ah_per_km",
    "peak_temperature_K",
    "mean_temperature_K",
    "capacity_1y",
    "capacity_5y",
    "capacity_10y",
    "resistance_10y",
    "years_to_80pct",
)


#: Capacities (relative to new) closer than this across controllers are reported as no measurable difference: the
#: table prints 4 significant digits, and BLAST-Lite's fits are no better than a tenth of a percent.
CAPACITY_RESOLUTION = 1e-3


def life_claims(rows: list[dict[str, Any]], years: float) -> list[str]:
    """One line per cycle and ambient: whether the controllers' capacity after ``years`` differs measurably
    (spread > :data:`CAPACITY_RESOLUTION`), else 'no measurable difference'; empty without life columns."""
    key = f"capacity_{years:g}y"
    lines = []
    for cyc, amb in dict.fromkeys((r["cycle"], r["ambient"]) for r in rows):
        vals = {
            r["controller"]: float(r[key])
            for r in rows
            if r["cycle"] == cyc and r["ambient"] == amb and isinstance(r.get(key), float) and math.isfinite(r[key])
        }
        if len(vals) < 2:
            continue
        spread = max(vals.values()) - min(vals.values())
        verdict = (
            "no measurable difference between the controllers"
            if spread <= CAPACITY_RESOLUTION
            else f"the controllers differ by {100 * spread:.2g} % of capacity"
        )
        lines.append(f"- {cyc.upper()}, {amb}: capacity after {years:g} years {verdict} (spread {spread:.2g}).")
    return lines


def _fmt(v: Any) -> str:
    if isinstance(v, float) and math.isinf(v):
        return f"> {YEARS:g}"
    return v if isinstance(v, str) else fmt(v)


def life_section(
    out_dir: Any,
    progress: Callable[[str], None],
    *,
    segment_s: float = SEGMENT_S,
    years: float = YEARS,
    cycles: tuple[str, ...] = CYCLES,
) -> str:
    """Run :func:`life_rows`, write battery_life/{life.csv, life.json, life.md}, return the Markdown."""
    out = Path(out_dir) / "battery_life"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sch = DailySchedule()
    rows = life_rows(cycles, segment_s=segment_s, years=years, schedule=sch, log=progress)
    progress("battery life: writing tables")
    cols = [c for c in COLUMNS if any(c in r for r in rows)]
    table = markdown_table(cols, [[_fmt(r.get(c, math.nan)) for c in cols] for r in rows])
    write_text(out / "life.csv", csv_text(cols, [[r.get(c, "") for c in cols] for r in rows]))
    write_json(
        out / "life.json",
        {
            "rows": rows,
            "schedule": vars(sch),
            "segment_s": segment_s,
            "years": years,
            "blast_models": BLAST_MODELS,
            "wall_time_s": time.perf_counter() - t0,
        },
    )
    write_text(out / "life.md", table)
    lines = [
        "## Battery life",
        "",
        f"One follower over the first {segment_s:g} s of {', '.join(c.upper() for c in cycles)} with the lumped pack thermal model on "
        f"(aev_ocp/models/thermal.py; ambient hot {AMBIENTS_K['hot']:g} K, cold {AMBIENTS_K['cold']:g} K, "
        "T(0) = ambient), the proposed law, OVFL and the MPC (the cycles section's solver path). Capacity and "
        "resistance are relative to new, from NREL's BLAST-Lite "
        f"({', '.join(f'{k}: {v}' for k, v in BLAST_MODELS.items())}) fed the drive's SOC and pack temperature, "
        f"repeated as a daily schedule: drives at {', '.join(f'{h:g} h' for h in sch.trip_start_h)}, rest at the "
        f"ambient, charging back at {sch.charge_C:g}C from {sch.charge_start_h:g} h; {years:g} years. "
        "Years to 80 %: '> 10' when not reached. At 10 °C BLAST-Lite's LFP model extrapolates (its cycling "
        "data span 20-40 °C).",
        "",
    ]
    if not blast_available():
        lines += [INSTALL_HINT + " (the life columns are left out).", ""]
    claims = life_claims(rows, years)
    lines += [table, ""] + (claims + [""] if claims else [])
    lines += ["Files: `battery_life/life.csv`, `battery_life/life.json`, `battery_life/life.md`.", ""]
    return "\n".join(lines)


def _reproduce_section(out_dir: Any, progress: Callable[[str], None]) -> str:
    """The section as ``reproduce`` runs it: a reduced configuration (scenario_t_end_max set) runs US06 only, a
    20 s segment and 1 year."""
    from .report_sections import SectionContext

    cfg = SectionContext.of(progress).config
    if cfg.scenario_t_end_max is None:
        return life_section(out_dir, progress)
    for _ in range((len(CYCLES) - 1) * len(AMBIENTS_K)):  # the progress lines of the cycles left out
        progress("battery life: reduced configuration")
    return life_section(out_dir, progress, segment_s=20.0, years=1.0, cycles=("us06",))


REPRODUCE_SECTIONS = [
    ("battery-life", _reproduce_section, STEPS)
]  # listed in aev_ocp.report_sections.SECTION_PROVIDERS

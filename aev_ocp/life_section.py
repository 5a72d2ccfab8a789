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
from typing import Any, Callable, Sequence

import numpy as np

from .intervals import Interval, difference
from .intervals import verdict as interval_verdict
from .life import BLAST_MODELS, INSTALL_HINT, DailySchedule, blast_available, daily_profile, life_of_run
from .params import ParameterError
from .report import csv_text, fmt, markdown_table, write_text
from .results import write_json

#: Segment of each cycle [s] (the issue's "keep it cheap": 300 s).
SEGMENT_S = 300.0
#: Ambient temperatures [K]: hot 35 °C and cold 10 °C (the cycling range of BLAST-Lite's LFP model is 20-40 °C;
#: 10 °C is extrapolated by its Arrhenius terms, said in the section).
AMBIENTS_K = {"hot": 308.15, "cold": 283.15}
CYCLES = ("udds", "hwfet", "us06")
REDUCED_CYCLES = ("udds", "us06")  # reproduce's default (issue 40: CPU): the urban and the aggressive cycle
LAWS = ("proposed", "ovfl")
YEARS = 10.0
STEPS = len(CYCLES) * len(AMBIENTS_K) + 1


def real_cells() -> tuple[str, ...]:
    """The shipped cells identified from PyBaMM (their cell file has an ``[identification]`` table), sorted."""
    from .cells import load_cell_file, shipped_cells

    return tuple(sorted(n for n in shipped_cells() if load_cell_file(n).identification))


def cell_pack(base_ev: Any, cell: Any) -> dict[str, int]:
    """The pack of ``cell`` that matches the scenario's pack (``base_ev``): the same capacity [Ah]
    (n_parallel = round(N_p·Q_ref / Q_cell)) and the same voltage at SOC 0.5 (n_series = round(N_s·OCV_ref(0.5) /
    OCV_cell(0.5))), so every cell drives the same car with about the same pack energy and current."""
    from .models.battery import ocv_table

    ref, pack = base_ev.cell, base_ev.pack
    ocv = lambda c: float(np.interp(0.5, *ocv_table(c)))  # noqa: E731  (the OCV table, linear between points)
    return {
        "n_parallel": max(1, round(pack.n_parallel * ref.capacity_Ah / cell.capacity_Ah)),
        "n_series": max(1, round(pack.n_series * ocv(ref) / ocv(cell))),
    }


def depth_of_discharge(result: Any, vehicle: int, schedule: DailySchedule | None = None) -> float:
    """Depth of discharge [-] of the daily schedule built from follower ``vehicle``'s run: max − min of the day's
    SOC profile that BLAST-Lite is fed (:func:`aev_ocp.life.daily_profile`: the drive repeated at each trip start,
    each starting where the previous ended, then charged back). With n trips, a drive's SOC drop d = S(0) − S(end)
    and its excursions S_max, S_min: DoD = (n − 1)·d + S_max − S_min (up to the resampling at ``sample_s``)."""
    ev = result.ev
    t_s = np.asarray(ev.units.time_to_si(result.t), float)
    soc = np.asarray(result.S[:, vehicle], float)
    prof = daily_profile(t_s, soc, np.full(t_s.size, ev.thermal.ambient_K), ev.thermal.ambient_K, schedule)
    return float(np.max(prof["SOC"]) - np.min(prof["SOC"]))


def life_rows(
    cycles: tuple[str, ...] = CYCLES,
    ambients_K: dict[str, float] | None = None,
    segment_s: float = SEGMENT_S,
    years: float = YEARS,
    schedule: DailySchedule | None = None,
    log: Callable[[str], None] | None = None,
    cells: Sequence[str] | str | None = None,
    mpc: bool = True,
) -> list[dict[str, Any]]:
    """One row per cycle × ambient × controller: pack heat, temperature metrics and (with BLAST-Lite) the battery
    life of the drive repeated by ``schedule``.

    ``cells``: None (default) runs the scenario's own cell (the A123 defaults) as before; a sequence of shipped
    cell names (or ``"real"``: :func:`real_cells`, the PyBaMM-identified ones) runs each cell, in a pack sized by
    :func:`cell_pack`, with its own chemistry's BLAST-Lite model (:data:`aev_ocp.life.BLAST_MODELS`); those rows also
    carry ``cell``, ``chemistry``, ``charge_throughput_Ah`` (the pack's ∫|I| dt over the run [Ah]) and
    ``depth_of_discharge`` (:func:`depth_of_discharge`, the daily schedule's SOC swing [-]). ``mpc = False``: the laws
    only (the same runs as beside the MPC; no MPC build, which is compiled once per pack)."""
    from .cells import load_cell_file
    from .metrics import charge_throughput_Ah, vehicle_metrics
    from .mpc.cycles import cycle_scenario, run_cycle
    from .mpc.cycles_section import section_settings

    amb = ambients_K or AMBIENTS_K
    names: list[str | None]
    if cells is None:
        names = [None]
    else:
        names = list(real_cells() if cells == "real" else ([cells] if isinstance(cells, str) else cells))
        if not names:
            raise ParameterError("life_rows: cells = [] is not allowed: give shipped cell names, 'real' or None")
    files = {n: load_cell_file(n) for n in names if n is not None}  # CellFileError naming an unknown cell
    sch = schedule or DailySchedule()
    rows: list[dict[str, Any]] = []
    with_life = blast_available()
    for cyc in cycles:
        base = cycle_scenario(cyc, segment_s)
        for name in names:
            if name is None:
                chem, cell_sc = _chemistry(base.ev.cell), base
            else:
                cf = files[name]
                pack = cell_pack(base.ev, cf.cell)
                chem = str(cf.chemistry)
                cell_sc = base.with_overrides(
                    {"cell.name": name, "pack.n_parallel": pack["n_parallel"], "pack.n_series": pack["n_series"]}
                )
            for label, T_amb in amb.items():
                if log:
                    log(f"battery life: {cyc}, {label} ambient" + (f", cell {name}" if name else ""))
                sc = cell_sc.with_overrides({"thermal.enabled": True, "thermal.ambient_K": T_amb})
                s = section_settings()
                runs = run_cycle(sc, (s.predictor,), laws=LAWS, settings=s)[0] if mpc else _law_runs(sc, s)
                for (ctrl, _pred), r in runs.items():
                    m = vehicle_metrics(r, 0)
                    row: dict[str, Any] = {"cell": name} if name is not None else {}
                    row |= {
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
                    if name is not None:
                        row["n_series"], row["n_parallel"] = sc.ev.pack.n_series, sc.ev.pack.n_parallel
                        row["charge_throughput_Ah"] = charge_throughput_Ah(r, 0)
                        row["depth_of_discharge"] = depth_of_discharge(r, 0, sch)
                    if with_life:
                        row.update(life_of_run(r, 0, chem, sch, years))
                    rows.append(row)
    return rows


def _law_runs(sc: Any, s: Any) -> dict[tuple[str, str | None], Any]:
    """The runs of :data:`LAWS` on scenario ``sc`` exactly as :func:`aev_ocp.mpc.cycles.run_cycle` makes them beside
    the MPC (settings ``s``: output step min(dt_out, s.dt))."""
    from .simulate import simulate_platoon

    return {
        (name, None): simulate_platoon(
            sc.leader,
            [sc.law(name)] * sc.n_followers,
            list(sc.gaps0),
            list(sc.speeds0),
            sc.t_end,
            ev=sc.ev,
            rtol=sc.rtol,
            atol=sc.atol,
            dt_out=min(sc.dt_out, s.dt),
        )
        for name in LAWS
    }


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
    "cell",
    "cycle",
    "ambient",
    "controller",
    "battery_energy_kWh_per_100km",
    "heat_pack_J_per_km",
    "charge_throughput_Ah_per_km",
    "peak_temperature_K",
    "mean_temperature_K",
    "charge_throughput_Ah",
    "depth_of_discharge",
    "capacity_1y",
    "capacity_5y",
    "capacity_10y",
    "resistance_10y",
    "years_to_80pct",
)


#: The resolution of a capacity (relative to new): each controller's capacity is known to ± half of it. The table
#: prints 4 significant digits, and BLAST-Lite's fits are no better than a tenth of a percent.
CAPACITY_RESOLUTION = 1e-3


def capacity_difference(a: Sequence[float], b: Sequence[float], resolution: float = CAPACITY_RESOLUTION) -> Interval:
    """The interval of capacity a − b (relative to new) of two controllers (:mod:`aev_ocp.intervals`): one value each
    (BLAST-Lite is deterministic) gives a − b ± ``resolution`` (each capacity ± resolution/2, so the interval holds 0
    exactly when the two capacities' intervals overlap); values over seeds (as many for a as for b, at least 2) give
    the paired t interval of the difference, widened by the same resolution."""
    if len(a) >= 2 and len(a) == len(b):
        d = difference(a, b, paired=True)
        return Interval(d.mean, d.lo - resolution, d.hi + resolution, d.n, d.level, d.method + "+resolution")
    if len(a) != 1 or len(b) != 1:
        raise ParameterError(
            f"capacity_difference: one capacity per controller, or as many (>= 2, one per seed) for both; "
            f"got {len(a)} and {len(b)}"
        )
    m = float(a[0]) - float(b[0])
    return Interval(m, m - resolution, m + resolution, 1, 1.0, "resolution")


def life_claims(rows: list[dict[str, Any]], years: float) -> list[str]:
    """One line per (cell,) cycle and ambient: 'no measurable difference' when every two controllers' capacity
    intervals after ``years`` overlap (:func:`capacity_difference` holds 0: :func:`aev_ocp.intervals.verdict` is
    'tie'), else how far apart the two furthest are (in % of capacity); per-cell rows (:func:`life_rows` with
    ``cells``) add each controller's charge throughput [Ah] and depth of discharge. Empty without life columns."""
    key = f"capacity_{years:g}y"
    lines = []
    for cell, cyc, amb in dict.fromkeys((r.get("cell"), r["cycle"], r["ambient"]) for r in rows):
        group = [
            r
            for r in rows
            if r.get("cell") == cell
            and r["cycle"] == cyc
            and r["ambient"] == amb
            and isinstance(r.get(key), float)
            and math.isfinite(r[key])
        ]
        vals: dict[str, list[float]] = {}
        for r in group:
            vals.setdefault(r["controller"], []).append(float(r[key]))
        if len(vals) < 2:
            continue
        names = list(vals)
        diffs = [capacity_difference(vals[x], vals[y]) for i, x in enumerate(names) for y in names[i + 1 :]]
        spread = max(abs(d.mean) for d in diffs)
        overlap = all(interval_verdict(d) == "tie" for d in diffs)
        verdict = (
            "no measurable difference between the controllers (intervals overlap; "
            if overlap
            else f"the controllers differ by {100 * spread:.2g} % of capacity ("
        )
        head = f"{cell} ({group[0].get('chemistry')}), " if cell is not None else ""
        line = (
            f"- {head}{cyc.upper()}, {amb}: capacity after {years:g} years {verdict}spread {spread:.2g}, "
            f"each ± {CAPACITY_RESOLUTION / 2:g})"
        )
        if cell is not None:
            line += "; " + ", ".join(
                f"{r['controller']}: {fmt(r['charge_throughput_Ah'])} Ah, DoD {fmt(r['depth_of_discharge'])}"
                for r in group
            )
        lines.append(line + ".")
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
    cells: Sequence[str] | str | None = None,
) -> str:
    """Run :func:`life_rows`, write battery_life/{life.csv, life.json, life.md}, return the Markdown. ``cells``:
    as :func:`life_rows` (None: the scenario's cell; ``"real"``: every PyBaMM-identified cell)."""
    out = Path(out_dir) / "battery_life"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sch = DailySchedule()
    rows = life_rows(cycles, segment_s=segment_s, years=years, schedule=sch, log=progress, cells=cells)
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
    if cells is not None:
        packs = dict.fromkeys(f"{r['cell']} ({r['chemistry']}, {r['n_series']}s{r['n_parallel']}p)" for r in rows)
        lines += [
            f"Cells: {', '.join(packs)}; each in a pack of the scenario's capacity and voltage at SOC 0.5 "
            "(aev_ocp.life_section.cell_pack) with its own chemistry's BLAST-Lite model. charge_throughput_Ah: the "
            "pack's ∫|I| dt over the drive; depth_of_discharge: the SOC swing of the daily schedule.",
            "",
        ]
    if not blast_available():
        lines += [INSTALL_HINT + " (the life columns are left out).", ""]
    claims = life_claims(rows, years)
    lines += [table, ""] + (claims + [""] if claims else [])
    lines += ["Files: `battery_life/life.csv`, `battery_life/life.json`, `battery_life/life.md`.", ""]
    return "\n".join(lines)


def _reproduce_section(out_dir: Any, progress: Callable[[str], None]) -> str:
    """The section as ``reproduce`` runs it: by default :data:`REDUCED_CYCLES` (``config.extended``, ``reproduce
    --full``: every cycle of :data:`CYCLES`); a reduced configuration (scenario_t_end_max set) runs US06 only, a
    20 s segment and 1 year."""
    from .report_sections import SectionContext

    cfg = SectionContext.of(progress).config
    if cfg.scenario_t_end_max is None:
        if cfg.extended:
            return life_section(out_dir, progress)
        for _ in range((len(CYCLES) - len(REDUCED_CYCLES)) * len(AMBIENTS_K)):  # the cycles left out
            progress("battery life: reduced by default (reproduce --full runs every cycle)")
        return life_section(out_dir, progress, cycles=REDUCED_CYCLES)
    for _ in range((len(CYCLES) - 1) * len(AMBIENTS_K)):  # the progress lines of the cycles left out
        progress("battery life: reduced configuration")
    return life_section(out_dir, progress, segment_s=20.0, years=1.0, cycles=("us06",))


REPRODUCE_SECTIONS = [("battery-life", _reproduce_section, STEPS)]  # listed in aev_ocp.reproduce.SECTION_PROVIDERS

"""Saving, loading, plotting and reporting SUMO runs (the toolkit's saved-run format, kind ``sumo``).

The folder holds ``manifest.json`` + ``trajectories.npz`` (:mod:`aev_ocp.saved`: one run per vehicle, labelled by
its SUMO id), ``metrics.csv`` (the usual metrics of every vehicle, SI first), ``fleet.json`` (fleet totals and the
fleet's events), one space-time diagram per route (``spacetime_<route>.png``; the ring: one) and ``report.md``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..metrics import si_first
from ..results import save_figure_atomic, to_jsonable, write_atomic, write_json
from ..saved import LoadError, _damaged, load_all, read_manifest, save_output
from .plots import plot_space_time, space_time_groups  # noqa: F401 (re-exported)
from .run import FLEET_EVENT_KINDS, SumoRun

FILES = ("manifest.json", "trajectories.npz", "metrics.csv", "fleet.json", "report.md")


def _label(vid: str) -> str:
    return vid.replace("/", "_")


def save_sumo(run: SumoRun, out: str | Path) -> list[Path]:
    """Write the run into ``out`` (see the module docstring); returns the files written (figures not included)."""
    out = Path(out)
    runs = {_label(v): r for v, r in run.vehicles.items()}
    primary = next((_label(v) for v, c in run.controlled.items() if c), next(iter(runs), None))
    sc = run.scenario
    extra = {
        "sumo": {
            "name": run.name,
            "controlled": {_label(k): v for k, v in run.controlled.items()},
            "events": run.events,
            "t_end_s": run.t_end_s,
            "step_s": run.step_s,
            "steps": run.steps,
            "wall_s": run.wall_s,
            "controller_s": run.controller_s,
            "interrupted": run.interrupted,
            "offsets_m": {_label(k): v for k, v in run.offsets_m.items()},
            "ring_length_m": run.ring_length_m,
            "fleet": run.fleet_totals(),
        }
    }
    settings = {"scenario": sc.name, "source": str(sc.source) if sc.source else None, "document": sc.document}
    files = save_output(out, "sumo", runs, primary=primary, settings=settings, extra=extra)
    files.append(write_metrics_csv(run, out / "metrics.csv"))
    files.append(write_json(out / "fleet.json", {"fleet": run.fleet_totals(), "events": run.events}))
    return files


def write_metrics_csv(run: SumoRun, path: Path) -> Path:
    """Per-vehicle metrics, one row per vehicle (SI columns first)."""
    rows = run.metrics()
    keys: list[str] = []
    for m in rows:
        keys += [k for k, v in m.items() if k not in keys and not isinstance(v, (dict, list))]
    lead = ["sumo_id", "controlled", "controller", "route", "status"]
    cols = lead + si_first([k for k in keys if k not in lead])
    buf = io.StringIO()
    w = csv.DictWriter(buf, cols, extrasaction="ignore")
    w.writeheader()
    for m in rows:
        w.writerow({k: to_jsonable(m.get(k)) for k in cols})
    return write_atomic(path, buf.getvalue())


def load_sumo(path: str | Path) -> SumoRun:
    """A saved SUMO run back as a :class:`SumoRun` (its scenario re-validated from the saved document); anything a
    damaged or foreign folder raises is one :class:`~aev_ocp.saved.LoadError` naming it."""
    return _damaged(path, lambda: _load_sumo(path))


def _load_sumo(path: str | Path) -> SumoRun:
    from .scenario import parse_sumo_scenario

    m, folder = read_manifest(path)
    if m.get("kind") != "sumo":
        raise LoadError(f"{folder}: kind = {m.get('kind')!r}, not a SUMO run")
    s = m["sumo"]
    runs = load_all(folder)
    src = m["settings"].get("source")
    # relative paths of the document ([cell] file, net_file, ...) start from the scenario file's folder, as in the run
    sc = parse_sumo_scenario(m["settings"]["document"], str(src or folder), Path(src) if src else None)
    return SumoRun(
        s["name"],
        sc,
        runs,
        {k: bool(v) for k, v in s["controlled"].items()},
        s["events"],
        float(s["t_end_s"]),
        float(s["step_s"]),
        int(s["steps"]),
        float(s["wall_s"]),
        float(s["controller_s"]),
        {k: float(v) for k, v in s["offsets_m"].items()},
        s.get("ring_length_m"),
        bool(s.get("interrupted", False)),
    )


# ----------------------------------------------------------------------------- space-time diagrams
def save_space_time(run: SumoRun, out: Path) -> list[Path]:
    """Write ``spacetime_<panel>.png`` files; returns their paths."""
    import matplotlib.pyplot as plt

    paths = []
    for key, fig in plot_space_time(run).items():
        paths.append(save_figure_atomic(fig, out / f"spacetime_{re.sub(r'[^A-Za-z0-9._-]', '_', key)}.png", dpi=110))
        plt.close(fig)
    return paths


# ----------------------------------------------------------------------------- report
def _fmt(x: Any) -> str:
    if isinstance(x, bool) or x is None:
        return str(x)
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, float):
        return "–" if not math.isfinite(x) else f"{x:.4g}"
    return str(x)


def report_markdown(run: SumoRun, figures: list[Path] | None = None) -> str:
    """The run's Markdown report: setup, fleet totals, the controlled vehicles' metrics, events, figures."""
    s = run.scenario.spec
    ft = run.fleet_totals()
    where = s.network or str(s.config_file or s.net_file)
    lines = [
        f"# SUMO run: {run.name}",
        "",
        f"Network: {where}; {run.t_end_s:g} s simulated at steps of {run.step_s:g} s in {run.wall_s:.3g} s "
        f"wall-clock ({run.realtime_factor:.3g}× real time; controllers {run.controller_s:.3g} s). "
        f"Controller of the toolkit's vehicles: {s.controller}; SUMO speed mode {s.speed_mode}; "
        f"share {s.share:g}"
        + (f", ids {list(s.ids)}" if s.ids else "")
        + (f", types {list(s.vtypes)}" if s.vtypes else "")
        + ".",
        "",
    ]
    if run.interrupted:
        lines += ["**Interrupted**: the run covers only the simulated time above.", ""]
    cols = [
        "vehicles",
        "distance_km",
        "battery_energy_kWh_per_100km",
        "heat_pack_J_per_km",
        "charge_throughput_Ah_per_km",
        "omega_mass_kJ_per_km",
        "mean_speed_mps",
        "speed_std_mps",
        "braking_events_per_veh_km",
        "min_gap_m",
        "collisions",
        "teleports",
        *(f"{k}_events" for k in FLEET_EVENT_KINDS),
    ]
    lines += [f"Status: **{run.status}**.", ""]
    lines += ["## Fleet totals", "", "| group | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for g in ("all", "controlled", "sumo"):
        lines.append(f"| {g} | " + " | ".join(_fmt(ft[g][c]) for c in cols) + " |")
    lines += [
        "",
        f"Throughput: {_fmt(ft['throughput_veh_per_h'])} veh/h ({ft['throughput_from']}). "
        f"Vehicles that left the network: {ft['left_network']}. Battery energy: ∫P_b dt at the pack terminals "
        f"(powertrain: {run.scenario.ev.vehicle.powertrain}), pack heat and charge throughput from the 2-RC cell on "
        "the realised motion; omega_mass: the paper's measure ω × vehicle mass (inertial, road load excluded), "
        "not battery energy.",
        "",
    ]
    rows = [m for m in run.metrics() if m["controlled"]]
    if rows:
        mc = [
            "sumo_id",
            "status",
            "distance_m",
            "battery_energy_kWh_per_100km",
            "heat_pack_J_per_km",
            "charge_throughput_Ah_per_km",
            "omega_J_per_kg_per_km",
            "min_gap_m",
            "min_ttc_s",
            "rms_jerk_mps3",
            "mean_speed_mps",
        ]
        lines += ["## Vehicles driven by the toolkit", "", "| " + " | ".join(mc) + " |", "|---" * len(mc) + "|"]
        for m in rows[:40]:
            lines.append("| " + " | ".join(_fmt(m.get(c)) for c in mc) + " |")
        if len(rows) > 40:
            lines.append(f"\n({len(rows) - 40} more in metrics.csv)")
        lines.append("")
    ev = [e for e in run.events if e["kind"] != "left_network"]
    lines += ["## Events", ""]
    lines += [
        f"- {e['kind']} at {_fmt(e['t_s'])} s: {e.get('vehicle')}"
        + (f" hit {e['victim']} at {e['impact_speed_mps']:.3g} m/s" if e["kind"] == "collision" else "")
        + (f" ({_fmt(e['value'])})" if "value" in e else "")
        for e in ev[:50]
    ] or ["None (no collision, no teleport, no emergency stop, no lane-end stop, no current beyond the limit)."]
    lines.append("")
    if figures:
        lines += ["## Space-time diagrams", ""] + [f"![{p.stem}]({p.name})" for p in figures] + [""]
    return "\n".join(lines)


def write_report(run: SumoRun, out: Path, figures: list[Path] | None = None) -> Path:
    """``report.md`` in ``out``."""
    return write_atomic(out / "report.md", report_markdown(run, figures))


def sweep_markdown(rows: list[dict[str, Any]], name: str) -> str:
    """The sweep's table (share × controller) as Markdown."""
    cols = [
        "share",
        "controller",
        "status",
        "vehicles",
        "controlled",
        "battery_energy_kWh_per_100km",
        "battery_energy_ctrl_kWh_per_100km",
        "battery_energy_sumo_kWh_per_100km",
        "heat_pack_J_per_km",
        "charge_throughput_Ah_per_km",
        "mean_speed_mps",
        "throughput_veh_per_h",
        "speed_std_mps",
        "braking_events_per_veh_km",
        "min_gap_m",
        "collisions",
        "teleports",
        *(f"{k}_events" for k in FLEET_EVENT_KINDS),
        "realtime_factor",
    ]
    lines = [
        f"# SUMO sweep: {name}",
        "",
        "Fleet totals per point (all vehicles; ctrl = driven by the toolkit, sumo = SUMO's drivers).",
        "",
        "| " + " | ".join(cols) + " |",
        "|---" * len(cols) + "|",
    ]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def sweep_row(share: float, controller: str, run: SumoRun | None, error: str = "") -> dict[str, Any]:
    """One row of the sweep table from a run (None: the point failed with ``error``)."""
    if run is None:
        return {"share": share, "controller": controller, "status": "error", "message": error}
    ft = run.fleet_totals()
    return {
        "share": share,
        "controller": controller,
        "status": run.status,  # 'ok' only without any event (collisions, teleports, emergency stops, ...)
        "vehicles": ft["all"]["vehicles"],
        "controlled": ft["controlled"]["vehicles"],
        "battery_energy_kWh_per_100km": ft["all"]["battery_energy_kWh_per_100km"],
        "battery_energy_ctrl_kWh_per_100km": ft["controlled"]["battery_energy_kWh_per_100km"],
        "battery_energy_sumo_kWh_per_100km": ft["sumo"]["battery_energy_kWh_per_100km"],
        "heat_pack_J_per_km": ft["all"]["heat_pack_J_per_km"],
        "charge_throughput_Ah_per_km": ft["all"]["charge_throughput_Ah_per_km"],
        "mean_speed_mps": ft["all"]["mean_speed_mps"],
        "throughput_veh_per_h": ft["throughput_veh_per_h"],  # ring: density x mean speed; open: leaving per hour
        "travel_time_per_lap_s": ft["travel_time_per_lap_s"],
        "speed_std_mps": ft["all"]["speed_std_mps"],  # over every vehicle's SUMO steps
        "braking_events_per_veh_km": ft["all"]["braking_events_per_veh_km"],  # a < -1 m/s² held >= 0.5 s
        "min_gap_m": ft["all"]["min_gap_m"],
        "collisions": ft["all"]["collisions"],
        "teleports": ft["all"]["teleports"],
        **{f"{k}_events": ft["all"][f"{k}_events"] for k in FLEET_EVENT_KINDS},
        "realtime_factor": ft["realtime_factor"],
    }


def write_sweep(rows: list[dict[str, Any]], out: Path, name: str) -> list[Path]:
    """``sweep.csv``, ``sweep.json`` and ``sweep.md`` in ``out``."""
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, keys)
    w.writeheader()
    for r in rows:
        w.writerow({k: to_jsonable(r.get(k)) for k in keys})
    return [
        write_atomic(out / "sweep.csv", buf.getvalue()),
        write_json(out / "sweep.json", {"rows": rows}),
        write_atomic(out / "sweep.md", sweep_markdown(rows, name)),
    ]


def read_json(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8"))

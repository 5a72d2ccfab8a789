"""The "Ring roads" section of ``aev-ocp reproduce``: Sugiyama et al. 2008 (a jam with no bottleneck, beside the
linear theory's growth rate and the growth measured in simulation) and Stern et al. 2018 (the same ring with one
AEV under each AEV controller: table against the all-human ring, space-time diagrams). The runs of the shipped
scenarios ``ring_sugiyama`` and ``ring_stern`` (600 s each; about 10 s in all on a quiet machine, the MPC run the
longest); a reduced configuration (``ReproduceConfig.quick``) runs 120 s.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

from .report import markdown_table
from .report_sections import SectionContext
from .ring.run import STABLE_LENGTH_M, RingExperiment, relative_to, run_ring_scenario
from .ring.scenario import build_ring, load_ring_scenario
from .stability.ring import measured_growth, ring_stability

QUICK_T_END_S = 120.0
#: samples stored per saved run (the loadable copy in ring/, for figures: every k-th sample and the last; 600 s
#: runs at 0.5 s keep about every 3rd, 1.5 s apart, so reproduce's output stays under 60 MB). The fleet metrics
#: in ring/ring.json come from every sample; a run of QUICK_T_END_S (241 samples) is stored whole.
RING_STORED_SAMPLES = 400
#: Sub-folder of the report's folder with the section's runs (``aev_ocp.load("ring")``).
RING_FOLDER = "ring"


def _pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:+.0f} %"


def _g(x: Any, fmt: str = ".4g") -> str:
    return format(x, fmt) if isinstance(x, (int, float)) and math.isfinite(x) else str(x)


SUGIYAMA_HEAD = [
    "ring [m]",
    "veh/km",
    "uniform speed [m/s]",
    "predicted growth [1/s]",
    "measured growth [1/s]",
    "speed std [m/s]",
    "stopped",
    "wave speed [m/s]",
    "outcome",
]
STERN_HEAD = [
    "AEV controller",
    "speed std [m/s]",
    "Δ",
    "braking events",
    "battery energy [kWh/100 km]",
    "Δ",
    "pack heat [J/km]",
    "Δ",
    "collisions",
    "fallbacks",
    "call [ms]",
]


def _sugiyama_run(sc: Any, t_end: float | None) -> tuple[RingExperiment, list[Any], dict[str, Any]]:
    """One Sugiyama ring: the run, its table row and its ring.json entry (linear growth rate beside the measured)."""
    run = run_ring_scenario(sc, t_end_s=t_end)[0]
    ring, _ = build_ring(sc, None)
    law = ring.vehicles[0]
    rs = ring_stability(law, ring.n, ring.length_m, ring.vehicle_length_m, ring.ev)
    meas = measured_growth(law, ring.n, ring.length_m, ring.vehicle_length_m, ring.ev)
    f = run.fleet
    row = [
        f"{ring.length_m:g}",
        f"{ring.density_per_km:.4g}",
        f"{rs.v_star_mps:.3g}",
        f"{rs.growth_rate_per_s:.4g} (k = {rs.most_unstable_k})",
        f"{meas['measured_per_s']:.4g}",
        _g(f["speed_std_mps"], ".3g"),
        f["vehicles_stopped"],
        _g(f["wave_speed_mps"], ".3g"),
        "jam" if f["vehicles_stopped"] > 0 else "no jam",
    ]
    doc = {
        "length_m": ring.length_m,
        "density_per_km": ring.density_per_km,
        "predicted_growth_per_s": rs.growth_rate_per_s,
        "most_unstable_k": rs.most_unstable_k,
        "measured": meas,
        "fleet": f,
    }
    return run, row, doc


def _sugiyama_markdown(sug: Any, t_end: float | None, rows: list[list[Any]]) -> list[str]:
    return [
        "## Ring roads: phantom jams and one AEV (Sugiyama, Stern)\n\n",
        "Every vehicle carries the EV and battery model; human drivers follow the IDM (Treiber et al. 2000) with "
        f"seeded acceleration noise ({sug.spec.noise_mps2:g} m/s², held {sug.spec.noise_dt_s:g} s), vehicles "
        f"{sug.spec.vehicle_length_m:g} m; fleet metrics over the second half of each run "
        f"({'600' if t_end is None else _g(t_end)} s). Scenarios: `ring_sugiyama`, `ring_stern` "
        "(`aev-ocp ring ring_stern`).\n\n",
        "### Sugiyama: 22 human drivers\n\n",
        "The linear theory's growth rate of uniform flow (largest Re λ over the ring's modes, from the law's exact "
        "partials) beside the growth of a small perturbation of that mode measured in the compiled ring; then the "
        "noisy run.\n\n",
        markdown_table(SUGIYAMA_HEAD, rows),
        "\n",
    ]


def _stern_row(r: RingExperiment, base: dict[str, Any] | None) -> list[Any]:
    """One AEV controller's row against the all-human ring's fleet metrics ``base`` (None: it is that ring)."""
    f = r.fleet
    rel = relative_to(base, f) if base is not None else {}
    return [
        r.label,
        _g(f["speed_std_mps"], ".3g"),
        _pct(rel.get("speed_std_mps", math.nan)),
        f["braking_events"],
        _g(f["battery_energy_kWh_per_100km"], ".4g"),
        _pct(rel.get("battery_energy_J_per_km", math.nan)),
        _g(f["heat_pack_J_per_km"], ".4g"),
        _pct(rel.get("heat_pack_J_per_km", math.nan)),
        f["collisions"],
        f.get("fallbacks", "–"),
        _g(f.get("call_ms_median", math.nan), ".3g") if "call_ms_median" in f else "–",
    ]


def _stern_markdown(srows: list[list[Any]], png: Path) -> list[str]:
    return [
        "### Stern: one AEV (vehicle 1) among 21 human drivers\n\n",
        "Each row against the all-human ring (Δ: relative change). Battery energy: ∫P_b dt per distance of the "
        "whole fleet; heat: pack heat ∫Q per km of the fleet; braking events: entries into a < −1 m/s²; the MPC "
        "forecasts its predecessor from its own measurements (decaying acceleration), with the traffic "
        "formulation's 2 m floor and its safety filter; call: median controller call [ms].\n\n",
        markdown_table(STERN_HEAD, srows),
        f"\n![space-time diagrams of the ring runs]({png.name})\n\n"
        f"Files: {RING_FOLDER}/ring.json (the Sugiyama entries under 'sugiyama', every run's label and fleet "
        f"metrics under 'runs', SI), ring_space_time.png; every run (trajectories of every vehicle) loads back with "
        f'`aev_ocp.load("{RING_FOLDER}")` (a RingOutput; `.plot()` draws the diagrams).\n',
    ]


def _save_runs(
    folder: Path, sugiyama: list[RingExperiment], stern: list[RingExperiment], doc_sug: list[dict[str, Any]]
) -> None:
    """The section's runs, loadable: ``folder``/ring.json (the Sugiyama entries, and every run's label and fleet
    metrics under 'runs'), trajectories.npz and manifest.json (kind 'ring'), so ``aev_ocp.load(folder)`` returns
    a RingOutput. The Sugiyama runs are labelled by their ring's length ('sugiyama 230 m'); the Stern runs keep
    their controller's label. (The report's own folder holds the safety suite's manifest: hence a folder.)"""
    from .ring.outputs import save_ring_output

    named = [replace(r, label=f"sugiyama {r.result.ring.length_m:g} m") for r in sugiyama]
    doc = {"experiment": "reproduce: Sugiyama and Stern", "sugiyama": doc_sug}
    save_ring_output(folder, named + list(stern), doc, max_samples=RING_STORED_SAMPLES)


def ring_section(out_dir: Path, progress: Callable[[str], None]) -> str:
    """Run the Sugiyama and Stern rings, write ring_space_time.png and the runs (``out_dir``/ring: ring.json,
    trajectories, manifest) into ``out_dir``; Markdown."""
    from .ring.plots import space_time_panels

    ctx = SectionContext.of(progress)
    t_end = None if ctx.config.is_full else QUICK_T_END_S
    out_dir.mkdir(parents=True, exist_ok=True)
    # --- Sugiyama: the jam at 230 m, none at STABLE_LENGTH_M, with the linear theory beside the measured
    ctx("ring: Sugiyama (22 human drivers, 230 m and 600 m)")
    sug = load_ring_scenario("ring_sugiyama")
    stable = replace(sug, name=sug.name + "_stable", spec=replace(sug.spec, length_m=STABLE_LENGTH_M))
    sug_runs = [_sugiyama_run(sc, t_end) for sc in (sug, stable)]
    rows, doc_sug = [r[1] for r in sug_runs], [r[2] for r in sug_runs]
    md = _sugiyama_markdown(sug, t_end, rows)
    # --- Stern: the same ring with one AEV under each controller
    st = load_ring_scenario("ring_stern")
    ctx(f"ring: Stern (one AEV under {len(st.spec.controllers)} controllers)")
    runs = run_ring_scenario(st, t_end_s=t_end)
    srows = [_stern_row(r, runs[0].fleet if r is not runs[0] else None) for r in runs]
    ctx("ring: space-time diagrams")
    png = out_dir / "ring_space_time.png"
    space_time_panels([(r.label, r.result) for r in runs], png, t_from_s=float(runs[0].fleet["window_s"][0]))
    _save_runs(out_dir / RING_FOLDER, [r[0] for r in sug_runs], runs, doc_sug)  # ring/ring.json: the one copy
    return "".join(md + _stern_markdown(srows, png))


REPRODUCE_SECTIONS = [("ring", ring_section, 3)]  # listed in aev_ocp.reproduce.SECTION_PROVIDERS

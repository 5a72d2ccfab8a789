"""SUMO coupling speed (issue 24 targets): 100 vehicles on closed-form laws faster than 50× real time with one SUMO
per core (two processes at once on 2 cores), and the MPC's extra cost per controlled vehicle and step no more than its
own call time.

1. laws: a 1100 m single-lane ring with 100 cars, every car on the proposed law (and on IDM), 120 s simulated; run
   alone and as two processes at once. Real-time factor = simulated s / wall s of the SUMO loop.
2. MPC: the 230 m ring with 22 cars, k of them on the MPC (the traffic formulation, N = 20, every 0.2 s), the rest on
   SUMO's drivers, 30 s; the same run with those k cars on the proposed law. The MPC's extra wall time per call beyond
   its own call time = (wall_mpc − wall_law − Σ MPC call time) / calls (the NLP build is timed apart: build_s).

Prints a table and writes results/bench_sumo.json.

``--wave`` instead runs the wave-damping MPC (SUMO's named ``wave-mpc``: each scenario's ``[sumo.wave]`` over the
WaveParams defaults, planning every 0.2 s as on the toolkit's ring) in SUMO's Krauss ring (``sumo_ring``, one car of
22: share 0.05), SUMO's IDM ring (``sumo_ring_idm``, the toolkit's Treiber IDM drivers, one car of 22) and the merge
(``sumo_merge``, the scenario's share 0.2) over seeds (default 100–109), against SUMO's drivers alone, the same share on FollowerStopper (each
scenario's ``desired_speed_mps``) and on the paper's law; every controlled car under the safety layer
(``[limits] safety_layer = true``) and keeping its lane's speed limit (``[sumo] speed_limits = true``), through the
study layer (:func:`aev_ocp.study.traffic.sumo_tasks`, :func:`aev_ocp.study.traffic_study.run_traffic_study`: the
metrics' means with 95 % t intervals and the paired verdicts against share 0). Writes results/bench_sumo_wave.json
(``--record``: also tests/data/bench_sumo_wave.json, which tests/test_wave_mpc.py and tests/test_sumo_wave.py tie to
the guide's tables).

``--wave-params JSON`` sets WaveParams fields (SI, over the scenario's own ``[sumo.wave]``) of every wave-MPC run:
they are written into the copied scenarios' ``[sumo.wave]`` (checked there as a scenario file's, before any run).
``--variant-params JSON`` runs a second wave MPC (its fields over the first's) on the same seeds, a study of its own in ``<out>/<name>-variant``,
and prints per scenario the paired comparison variant − base (:func:`variant_comparison`: per seed, and the mean
with its 95 % t interval and verdict, of the speed std, mean speed, throughput and battery energy per 100 km, and
both runs' events). ``--scenarios`` runs only some of the three, ``--controllers`` only some of the controllers
(SUMO's drivers alone always run: the table's baseline), e.g. a screening run of two wave MPCs:

    python benchmarks/bench_sumo.py [--quick]
    python benchmarks/bench_sumo.py --wave [--seeds 100 ... 109] [--workers 1] [--record]
    python benchmarks/bench_sumo.py --wave --scenarios sumo_ring_idm --controllers wave-mpc --seeds 100 101 \
        --wave-params '{"target_gap_m": 6.0}' --variant-params '{"buffer_time_s": 8.0}' --out results/screen
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LAW_CHILD = """
import json, sys
from aev_ocp.sumo.scenario import parse_sumo_scenario
from aev_ocp.sumo.run import run_sumo
law, t_end = sys.argv[1], float(sys.argv[2])
doc = {"units": {"length_m": 2.5}, "sumo": {"network": "ring", "t_end_s": t_end, "share": 1.0, "controller": law,
       "ring": {"length_m": 1100.0, "vehicles": 100, "perturbation_m": 1.0, "speed0_mps": 5.0}}}
r = run_sumo(parse_sumo_scenario(doc))
print(json.dumps({"law": law, "vehicles": len(r.vehicles), "t_end_s": r.t_end_s, "wall_s": r.wall_s,
                  "controller_s": r.controller_s, "realtime_factor": r.realtime_factor}))
"""

MPC_CHILD = """
import json, sys
from aev_ocp.sumo.scenario import parse_sumo_scenario
from aev_ocp.sumo.run import run_sumo
k, t_end = int(sys.argv[1]), float(sys.argv[2])
ids = [f"ring.{3 + 5 * i}" for i in range(k)]
out = {}
for ctrl in ("proposed", "mpc"):
    doc = {"units": {"length_m": 2.5}, "mpc": {"N": 20, "dt": 0.4},
           "sumo": {"network": "ring", "t_end_s": t_end, "ids": ids, "controller": ctrl,
                    "ring": {"speed0_mps": 4.0, "perturbation_m": 1.0}}}
    r = run_sumo(parse_sumo_scenario(doc))
    stats = [r.vehicles[i].solver_stats[0] for i in ids]
    out[ctrl] = {"wall_s": r.wall_s, "build_s": r.build_s, "controller_s": r.controller_s,
                 "calls": sum(s["n_steps"] for s in stats if s),
                 "call_s_total": sum(r.vehicles[i].meta.get("call_s_total", 0.0) for i in ids),
                 "solve_ms_median": [s["solve_ms_median"] for s in stats if s],
                 "call_ms_median": [s["call_ms_median"] for s in stats if s],
                 "fallbacks": sum(s["fallbacks"] for s in stats if s)}
print(json.dumps(out))
"""


def _child(code: str, *args: str) -> dict:
    p = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT, check=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def _children(code: str, argsets: list[tuple[str, ...]]) -> list[dict]:
    procs = [
        subprocess.Popen([sys.executable, "-c", code, *a], stdout=subprocess.PIPE, text=True, cwd=ROOT) for a in argsets
    ]
    return [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]


WAVE_CONTROLLER = "wave-mpc"
#: the controllers of the wave study (each at the scenario's share; share 0: SUMO's drivers alone)
WAVE_CONTROLLERS = ["proposed", "followerstopper", WAVE_CONTROLLER]
#: the shipped SUMO scenario and the share of its cars the toolkit drives in the wave study
WAVE_POINTS = {"sumo_ring": 0.05, "sumo_ring_idm": 0.05, "sumo_merge": 0.2}
#: the fleet's events counted per run (a run with one is 'failed' in the table and left out of its means)
WAVE_EVENTS = ("lane_end_stop_events", "emergency_braking_events", "collisions", "teleports")
VARIANT = "wave-mpc-variant"  # --variant-params: the second wave MPC of the paired comparison
#: the metrics of the paired comparison variant − base, each with whether a lower value is better
VARIANT_METRICS = {
    "speed_std_mps": True,
    "mean_speed_mps": False,
    "throughput_veh_per_h": False,
    "battery_energy_kWh_per_100km": True,
}
#: the columns of the wave study's tables (aev_ocp.sumo.cli.SEED_METRICS plus the closest gap)
WAVE_METRICS = (
    "throughput_veh_per_h",
    "mean_speed_mps",
    "speed_std_mps",
    "braking_events_per_veh_km",
    "battery_energy_kWh_per_100km",
    "min_gap_m",
)


def _toml_value(x: object) -> str:
    """A scalar of a JSON object as a TOML value (numbers, true/false, strings; a non-finite number as TOML's)."""
    if isinstance(x, float) and not math.isfinite(x):
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return json.dumps(x)


def scenario_copy(name: str, folder: Path, wave: dict | None = None) -> Path:
    """The shipped scenario ``name`` written into ``folder`` with every controlled car under the safety layer and
    keeping the lanes' limits, and as its ``[sumo.wave]`` the shipped file's own (if any) with ``wave`` (WaveParams
    fields) over it (none when both are empty); loaded once, so that a bad field stops the study before any run
    (SystemExit naming the file and the field)."""
    from aev_ocp.scenarios import ScenarioError
    from aev_ocp.sumo.scenario import load_sumo_scenario

    src = ROOT / "aev_ocp" / "sumo" / "scenarios" / f"{name}.toml"
    text = src.read_text(encoding="utf-8")
    if "[limits]" in text or "speed_limits" in text or text.count("\n[sumo]\n") != 1:
        raise SystemExit(f"{src}: has its own [limits] or speed_limits, or no single [sumo] table")
    shipped = tomllib.loads(text).get("sumo", {}).get("wave", {})
    if shipped:  # the file's own table goes; its fields come back below, under ``wave``'s
        table = re.search(r"^\[sumo\.wave\][^\n]*\n(?:(?!\[)[^\n]*\n?)*", text, flags=re.M)
        if table is None or "[sumo.wave]" in text[table.end() :]:
            raise SystemExit(f"{src}: its [sumo.wave] table is not one plain table")
        text = text[: table.start()] + text[table.end() :]
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    text = text.replace("\n[sumo]\n", "\n[sumo]\nspeed_limits = true\n")
    fields = {**shipped, **(wave or {})}
    if fields:
        text = text.rstrip("\n") + "\n\n[sumo.wave]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in fields.items())
    path.write_text(text + "\n[limits]\nsafety_layer = true\n", encoding="utf-8")
    try:
        load_sumo_scenario(path)
    except ScenarioError as exc:
        raise SystemExit(f"bench_sumo.py: {exc}") from None
    return path


def _per_seed(tasks: list, results: dict) -> list[dict]:
    """One row per run: share, controller, seed, status, wall time, message, the metrics and the events."""
    per_seed = []
    for t in tasks:
        r = results.get(t.key) or {"status": "missing", "metrics": []}
        m = r["metrics"][0] if r.get("metrics") else {}
        v = t.spec["values"]
        row = {
            "share": v["share"],
            "controller": t.controller,
            "seed": v["seed"],
            "status": r["status"],
            "wall_s": r.get("wall_s"),
        }
        per_seed.append(
            {**row, "message": r.get("message", ""), **{k: m.get(k) for k in (*WAVE_METRICS, *WAVE_EVENTS)}}
        )
    return per_seed


def wave_study(
    seeds: list[int],
    out: Path,
    workers: int = 1,
    scenarios: list[str] | None = None,
    controllers: list[str] | None = None,
    wave: dict | None = None,
    variant: dict | None = None,
) -> dict:
    """The wave MPC in SUMO's ring and merge (module docstring): {scenario: {share, seeds, rows (the study's table
    rows), per_seed (share, controller, seed, status, metrics), markdown, and with ``variant`` the paired
    comparison}}. ``scenarios`` / ``controllers``: some of WAVE_POINTS / WAVE_CONTROLLERS (default all); ``wave``:
    WaveParams fields of the wave-MPC runs; ``variant``: a second wave MPC's fields over ``wave``'s."""
    from aev_ocp.ring.field import table_markdown
    from aev_ocp.study.traffic import sumo_tasks
    from aev_ocp.study.traffic_study import run_traffic_study

    names = [n for n in WAVE_POINTS if scenarios is None or n in scenarios]
    ctrls = [c for c in WAVE_CONTROLLERS if controllers is None or c in controllers]
    var_wave = {**(wave or {}), **variant} if variant is not None else None
    paths = {n: scenario_copy(n, out / n, wave) for n in names}  # every file checked before the first run
    var_paths = {n: scenario_copy(n, out / f"{n}-variant", var_wave) for n in names} if var_wave is not None else {}
    doc: dict = {}
    for name in names:
        share, folder = WAVE_POINTS[name], out / name
        tasks = sumo_tasks(paths[name], [0.0, share], ctrls, seeds)
        results, rows = run_traffic_study(tasks, folder, workers=workers, name=f"wave MPC in {name}")
        for r in rows:
            r["scenario"] = name  # not the path of this checkout's copy
        per_seed = _per_seed(tasks, results)
        md = table_markdown(rows, [m for m in WAVE_METRICS if rows and m in rows[0]])
        events = {  # each run's events summed over its seeds (failed runs included)
            r["run"]: {
                k: sum(int(p[k] or 0) for p in per_seed if f"{p['share']} {p['controller']}" == r["run"])
                for k in WAVE_EVENTS
            }
            for r in rows
        }
        doc[name] = {
            "share": share,
            "seeds": seeds,
            "rows": rows,
            "per_seed": per_seed,
            "events": events,
            "markdown": md,
        }
        print(f"\n{name} (share {share:g}), seeds {seeds[0]}-{seeds[-1]}, means [95 % t interval] and paired verdicts:")
        print(md)
        print("events over the seeds:", json.dumps(events))
        if var_wave is not None:
            vtasks = sumo_tasks(var_paths[name], [share], [WAVE_CONTROLLER], seeds)
            vname = f"wave MPC variant in {name}"
            vresults, _ = run_traffic_study(vtasks, out / f"{name}-variant", workers=workers, name=vname)
            vper_seed = [{**p, "controller": VARIANT} for p in _per_seed(vtasks, vresults)]
            doc[name]["variant"] = {
                "wave_params": var_wave,
                "per_seed": vper_seed,
                "comparison": variant_comparison(name, per_seed, vper_seed, seeds),
            }
    return doc


def _events(p: dict) -> str:
    """A run's events as 'kind n, ...' (its nonzero WAVE_EVENTS counts; '-' for none)."""
    return ", ".join(f"{k.removesuffix('_events')} {int(p[k])}" for k in WAVE_EVENTS if p.get(k)) or "-"


def variant_comparison(name: str, base: list[dict], variant: list[dict], seeds: list[int]) -> dict:
    """``--variant-params``: the variant's runs − the base wave MPC's, paired by seed (aev_ocp.intervals: the mean
    of the per-seed differences with its 95 % t interval, and a verdict only when it excludes 0), for each of
    VARIANT_METRICS, over the seeds where both runs have numbers (a run with an event is kept: its status is shown;
    a run that failed to run is left out, named); and both runs' events. Printed and returned."""
    from aev_ocp.intervals import difference, verdict

    b = {p["seed"]: p for p in base if p["controller"] == WAVE_CONTROLLER}
    v = {p["seed"]: p for p in variant}
    both = [s for s in seeds if s in b and s in v and all(x[s][m] is not None for x in (b, v) for m in VARIANT_METRICS)]
    out: dict = {"seeds": both, "left_out": [s for s in seeds if s not in both], "per_seed": [], "difference": {}}
    for s in both:
        row = {"seed": s, "status": [b[s]["status"], v[s]["status"]], "events": [_events(b[s]), _events(v[s])]}
        out["per_seed"].append({**row, **{m: v[s][m] - b[s][m] for m in VARIANT_METRICS}})
    for m, lower in VARIANT_METRICS.items():
        d = difference([v[s][m] for s in both], [b[s][m] for s in both]) if len(both) > 1 else None
        out["difference"][m] = None if d is None else {**d.as_dict(), "verdict": verdict(d, lower)}
    out["events"] = {
        c: {k: sum(int(x[s][k] or 0) for s in seeds if s in x) for k in WAVE_EVENTS}
        for c, x in ((WAVE_CONTROLLER, b), (VARIANT, v))
    }
    print(f"\n{name}: variant − base wave MPC, paired by seed (95 % t intervals; verdict for the variant):")
    print(
        "| seed | status base / variant | "
        + " | ".join(f"Δ {m}" for m in VARIANT_METRICS)
        + " | events base / variant |"
    )
    print("|" + "---|" * (len(VARIANT_METRICS) + 3))
    for r in out["per_seed"]:
        cells = " | ".join(f"{r[m]:+.4g}" for m in VARIANT_METRICS)
        print(f"| {r['seed']} | {' / '.join(r['status'])} | {cells} | {' / '.join(r['events'])} |")
    cells = " | ".join(
        "n < 2" if d is None else f"{d['mean']:+.4g} [{d['lo']:+.4g}, {d['hi']:+.4g}] {d['verdict']}"
        for d in out["difference"].values()
    )
    print(f"| mean | {len(both)} seeds | {cells} | |")
    if out["left_out"]:
        print("left out (a run without numbers):", out["left_out"])
    print("events over the seeds:", json.dumps(out["events"]))
    return out


def _json_object(ap: argparse.ArgumentParser, flag: str, text: str | None) -> dict | None:
    """``text`` parsed as a JSON object of scalars (WaveParams fields), None when not given; else ap.error naming
    ``flag``."""
    if text is None:
        return None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        ap.error(f"{flag} {text!r}: not JSON ({exc})")
    if not isinstance(obj, dict):
        ap.error(f"{flag} {text!r}: must be a JSON object of WaveParams fields, e.g. '{{\"target_gap_m\": 6.0}}'")
    nested = [k for k, x in obj.items() if isinstance(x, (dict, list)) or x is None]
    if nested:
        ap.error(f"{flag}: {nested[0]!r} must be a number (a [sumo.wave] field; no sub-tables, as [ring.wave])")
    return obj


def main_wave(argv: list[str]) -> None:
    """``--wave``: the wave-MPC study (module docstring)."""
    import os

    ap = argparse.ArgumentParser(description="the wave MPC in SUMO's ring and merge over seeds")
    ap.add_argument("--wave", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(100, 110)))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_sumo_wave"))
    ap.add_argument("--record", action="store_true", help="also write tests/data/bench_sumo_wave.json")
    ap.add_argument("--scenarios", nargs="+", choices=list(WAVE_POINTS), default=None, help="default: all three")
    ap.add_argument(
        "--controllers", nargs="+", choices=WAVE_CONTROLLERS, default=None, help="default: all (SUMO alone always runs)"
    )
    ap.add_argument(
        "--wave-params", default=None, help="WaveParams fields as JSON over each scenario's own [sumo.wave]"
    )
    ap.add_argument(
        "--variant-params", default=None, help="a second wave MPC's WaveParams fields as JSON over --wave-params'"
    )
    a = ap.parse_args(argv)
    wave = _json_object(ap, "--wave-params", a.wave_params)
    variant = _json_object(ap, "--variant-params", a.variant_params)
    if (wave is not None or variant is not None) and a.controllers is not None and WAVE_CONTROLLER not in a.controllers:
        ap.error(
            f"--wave-params and --variant-params set the wave MPC's fields: --controllers must include {WAVE_CONTROLLER}"
        )
    if a.record and (a.scenarios is not None or a.controllers is not None):
        ap.error("--record writes the guide's full study: not with --scenarios or --controllers")
    load = os.getloadavg()[0]
    # each run's wall time in its per_seed row (a rerun resumes)
    doc = wave_study(a.seeds, Path(a.out), a.workers, a.scenarios, a.controllers, wave, variant)
    doc = {"controller": WAVE_CONTROLLER, "load_1min_at_start": load, **doc}
    for key, value in (("wave_params", wave), ("variant_params", variant)):
        if value is not None:  # (the default study's JSON as before)
            doc[key] = value
    outs = [Path(a.out) / "bench_sumo_wave.json"]
    if a.record:
        outs.append(ROOT / "tests" / "data" / "bench_sumo_wave.json")
    for p in outs:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=1, default=float) + "\n")
        tmp.replace(p)  # atomic
        print(f"wrote {p}")


def main() -> None:
    if "--wave" in sys.argv:
        main_wave(sys.argv[1:])
        return
    quick = "--quick" in sys.argv
    t_law = "30" if quick else "120"
    rows = []
    for law in ("proposed", "idm"):
        r = _child(LAW_CHILD, law, t_law)
        rows.append({"case": f"100 cars, {law}, 1 process", **r})
    for r in _children(LAW_CHILD, [("proposed", t_law), ("proposed", t_law)]):
        rows.append({"case": "100 cars, proposed, 2 processes at once", **r})
    print(f"{'case':45} {'sim s':>6} {'wall s':>7} {'ctrl s':>7} {'x real time':>12}")
    for r in rows:
        print(
            f"{r['case']:45} {r['t_end_s']:6.0f} {r['wall_s']:7.2f} {r['controller_s']:7.2f} {r['realtime_factor']:12.1f}"
        )
    mpc_rows = []
    for k in (1,) if quick else (1, 3):
        m = _child(MPC_CHILD, str(k), "10" if quick else "30")
        law, mpc = m["proposed"], m["mpc"]
        calls = max(mpc["calls"], 1)
        extra_ms = 1e3 * (mpc["wall_s"] - mpc["build_s"] - law["wall_s"]) / calls  # what the MPC added per call
        own_ms = 1e3 * mpc["call_s_total"] / calls  # its own call (forecast, solve, unpacking), mean
        mpc_rows.append(
            {
                "mpc_vehicles": k,
                "calls": mpc["calls"],
                "wall_law_s": law["wall_s"],
                "wall_mpc_s": mpc["wall_s"],
                "build_s": mpc["build_s"],
                "controller_s": mpc["controller_s"],
                "solve_ms_median": mpc["solve_ms_median"],
                "call_ms_median": mpc["call_ms_median"],
                "fallbacks": mpc["fallbacks"],
                "added_wall_ms_per_call": extra_ms,
                "own_call_ms_mean": own_ms,
                "within_target": extra_ms <= own_ms * 1.1 + 0.05,
            }
        )
    print(
        f"\n{'MPC cars':>8} {'calls':>6} {'wall law s':>10} {'wall MPC s':>10} {'build s':>8} {'ctrl s':>7} "
        f"{'solve ms (median)':>17} {'own call ms':>12} {'added ms/call':>14}"
    )
    for r in mpc_rows:
        print(
            f"{r['mpc_vehicles']:8d} {r['calls']:6d} {r['wall_law_s']:10.2f} {r['wall_mpc_s']:10.2f} "
            f"{r['build_s']:8.2f} {r['controller_s']:7.2f} {max(r['solve_ms_median']):17.3f} "
            f"{r['own_call_ms_mean']:12.3f} {r['added_wall_ms_per_call']:14.3f}"
        )
    out = ROOT / "results" / "bench_sumo.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"laws": rows, "mpc": mpc_rows, "quick": quick}, indent=2) + "\n")
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()

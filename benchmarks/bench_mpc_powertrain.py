"""The MPC against the laws on the EPA cycles with the paper's constant η and with FASTSim's Model 3 powertrain map
(issue 35, item 5): does the MPC's advantage survive a real powertrain?

For each cycle (the shipped single-follower scenarios, cut at the first rest after ``--segment-s``,
:func:`aev_ocp.mpc.cycles.cycle_scenario`) and each powertrain — ``constant`` (the scenario's vehicle, η = 0.8) and
``map`` (``VehicleParams.model3()``: the map, 250 W auxiliary load, wheel inertia; the MPC's prediction model uses the
smooth map) — one follower runs under the default MPC (decaying-acceleration forecast), the proposed law and OVFL.
Prints battery energy [kWh/100 km], pack heat [J/km] and charge throughput [Ah/km] per run and the MPC's change
against each law, and writes benchmarks/bench_mpc_powertrain.json.

``--ring``: instead, the ring's Stern experiment (``ring_stern``: all human, then vehicle 1 under each AEV
controller; fleet metrics over the second half of 600 s) with the scenario's vehicle (η = 0.8) and with
``VehicleParams.model3()``: each controller's change of the fleet's battery energy against the all-human ring;
writes benchmarks/bench_mpc_powertrain_ring.json. The numbers of the guide's "What changed with the validated
powertrain" (docs/guide/powertrain.md) are these two runs; ``--record`` also writes each JSON to tests/data/, where
tests/test_energy_names.py checks that the guide quotes them.
Usage: python benchmarks/bench_mpc_powertrain.py [--segment-s 300] [--cycles udds hwfet us06] [--ring] [--record]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

from aev_ocp.mpc.cycles import cycle_rows, cycle_scenario, run_cycle
from aev_ocp.params import VehicleParams
from aev_ocp.results import write_json

KEYS = ("battery_energy_kWh_per_100km", "heat_pack_J_per_km", "charge_throughput_Ah_per_km")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segment-s", type=float, default=300.0)
    ap.add_argument("--cycles", nargs="+", default=["udds", "hwfet", "us06"])
    ap.add_argument("--ring", action="store_true", help="the ring's Stern experiment with both powertrains instead")
    ap.add_argument("--record", action="store_true", help="also write the JSON to tests/data/ (the guide's numbers)")
    ap.add_argument(
        "--ring-controllers",
        nargs="+",
        default=None,
        help="--ring: these AEV controllers only (default: the scenario's)",
    )
    args = ap.parse_args()
    if args.ring:
        ring_main(args.record, args.ring_controllers)
        return
    rows: list[dict[str, Any]] = []
    for cyc in args.cycles:
        for pt in ("constant", "map"):
            sc = cycle_scenario(cyc, segment_s=args.segment_s, end_at_rest=True)
            if pt == "map":
                sc = sc.replace(ev=dataclasses.replace(sc.ev, vehicle=VehicleParams.model3()))
            t0 = time.perf_counter()
            runs, _ = run_cycle(sc, predictors=("decaying-acceleration",))
            by = {r["controller"]: r for r in cycle_rows(cyc, runs)}
            m = by["mpc"]
            row = {"cycle": cyc, "powertrain": pt, "duration_s": m["duration_s"], "comparable": m["comparable"]}
            for ctrl in ("mpc", "proposed", "ovfl"):
                row.update({f"{ctrl}_{k}": by[ctrl][k] for k in KEYS})
            for law in ("proposed", "ovfl"):
                row.update({f"mpc_vs_{law}_{k}_pct": 100 * (m[k] / by[law][k] - 1) for k in KEYS})
            row["wall_s"] = time.perf_counter() - t0
            rows.append(row)
            print(
                f"{cyc:6s} {pt:8s} {m['duration_s']:6.0f} s  battery energy MPC {m[KEYS[0]]:.3f} proposed "
                f"{by['proposed'][KEYS[0]]:.3f} OVFL {by['ovfl'][KEYS[0]]:.3f} kWh/100 km "
                f"({row['mpc_vs_proposed_' + KEYS[0] + '_pct']:+.2f} %, {row['mpc_vs_ovfl_' + KEYS[0] + '_pct']:+.2f} %); "
                f"pack heat {row['mpc_vs_proposed_' + KEYS[1] + '_pct']:+.1f} % / "
                f"{row['mpc_vs_ovfl_' + KEYS[1] + '_pct']:+.1f} %; throughput "
                f"{row['mpc_vs_proposed_' + KEYS[2] + '_pct']:+.1f} %; comparable {m['comparable']}",
                flush=True,
            )
    _write(Path(__file__).with_suffix(".json").name, {"segment_s": args.segment_s, "rows": rows}, args.record)


def _write(name: str, data: dict[str, Any], record: bool) -> None:
    """The JSON beside this script, and with ``record`` in tests/data/ too (written atomically)."""
    here = Path(__file__).parent
    for folder in (here, here.parent / "tests" / "data") if record else (here,):
        write_json(folder / name, data)


def ring_main(record: bool = False, controllers: list[str] | None = None) -> None:
    """The Stern ring with the paper's η and with the Model 3 powertrain: battery energy per km of the fleet and
    each AEV controller's change against the all-human ring (``change_battery_energy_J_per_km``)."""
    from aev_ocp.ring.run import run_ring_scenario
    from aev_ocp.ring.scenario import load_ring_scenario

    rows: list[dict[str, Any]] = []
    base = load_ring_scenario("ring_stern")
    if controllers:
        base = dataclasses.replace(base, spec=dataclasses.replace(base.spec, controllers=tuple(controllers)))
    for pt in ("constant", "map"):
        sc = (
            base
            if pt == "constant"
            else dataclasses.replace(base, ev=dataclasses.replace(base.ev, vehicle=VehicleParams.model3()))
        )
        t0 = time.perf_counter()
        for e in run_ring_scenario(sc):
            f = e.fleet
            row = {
                "powertrain": pt,
                "run": e.label,
                "battery_energy_kWh_per_100km": f["battery_energy_kWh_per_100km"],
                "change_battery_energy_pct": 100 * f.get("change_battery_energy_J_per_km", float("nan")),
                "speed_std_mps": f["speed_std_mps"],
            }
            rows.append(row)
            print(
                f"ring {pt:8s} {e.label:24s} battery energy {row['battery_energy_kWh_per_100km']:.3f} kWh/100 km "
                f"({row['change_battery_energy_pct']:+.1f} % against all human)",
                flush=True,
            )
        print(f"  ({time.perf_counter() - t0:.0f} s wall)", flush=True)
    _write("bench_mpc_powertrain_ring.json", {"rows": rows}, record)


if __name__ == "__main__":
    main()

"""Follow a recorded trajectory: a platoon behind one vehicle of an NGSIM-style CSV file.

examples/data/ngsim_style_follow.toml declares the leader as ``[leader] kind = "trace"``: the file,
its time column (ms), its speed column (ft/s) and the vehicle to keep (``filter_column`` /
``filter_value``). The trace is validated (increasing times, finite values, no negative speed, no gap
above ``max_gap_s``) and resampled as the shipped drive cycles are. The same leader can be built from
the position column (its derivative); both are compared here. The CSV's values are synthetic, with
NGSIM's columns. Run: python examples/follow_csv_trace.py [--quick] [--out DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from aev_ocp.models.leader import csv_trace
from aev_ocp.scenarios import load_scenario

HERE = Path(__file__).resolve().parent
SCENARIO = HERE / "data" / "ngsim_style_follow.toml"


def main(quick: bool = False, out: str | None = None) -> dict[str, object]:
    """Simulate the scenario (quick: the first 4 model time units); returns metrics and the largest
    difference between the speed-column and position-column leaders [m/s]."""
    sc = load_scenario(SCENARIO)
    if quick:
        sc = sc.with_overrides({"simulation.t_end": 4.0})
    # the same vehicle's positions [ft], differentiated: agrees with its recorded speed to the rounding
    from_pos = csv_trace(
        HERE / "data" / "ngsim_style_trace.csv",
        sc.units,
        time_column="Global_Time",
        time_unit="ms",
        position_column="Local_Y",
        position_unit="ft",
        filter_column="Vehicle_ID",
        filter_value=1042,
    )
    t = np.linspace(0.0, sc.t_end, 2001)
    dv = float(np.max(np.abs(from_pos.speed_np(t) - sc.leader.speed_np(t)))) * sc.units.speed_mps
    results = sc.run()
    print(
        f"leader: {sc.leader.times[-1] * sc.units.time_s:g} s of vehicle 1042, top speed "
        f"{max(sc.leader.speeds) * sc.units.speed_mps:.3g} m/s; speed column vs d/dt(position column): "
        f"max difference {dv:.2g} m/s"
    )
    print(f"{'law':>10} {'vehicle':>8} {'ω [J/kg]':>10} {'pack ∫Q [J]':>12} {'min gap [m]':>12}")
    metrics = {}
    for label, r in results.items():
        metrics[label] = r.metrics()
        for m in metrics[label]:
            print(
                f"{label:>10} {m['vehicle']:>8} {m['omega_J_per_kg']:>10.4g} {m['heat_pack_J']:>12.5g} "
                f"{m['min_gap_m']:>12.4g}"
            )
    if out is not None:
        from aev_ocp.saved import save_output, settings_of

        save_output(out, "simulate", results, settings=settings_of(sc, quick=quick))
        print(f"wrote {out}/manifest.json and trajectories.npz (aev_ocp.load('{out}'))")
    return {"metrics": metrics, "position_speed_diff_mps": dv, "status": {k: r.status for k, r in results.items()}}


if __name__ == "__main__":
    args = sys.argv[1:]
    main(quick="--quick" in args, out=args[args.index("--out") + 1] if "--out" in args else None)

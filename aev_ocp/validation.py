"""Validation of the replay against NREL FASTSim 3.1 (the optional extra ``[validation]``): FASTSim's own run of
its 2022 Tesla Model 3 RWD on the same speed traces as :func:`aev_ocp.replay`, and the table of the guide
(docs/guide/powertrain.md).

FASTSim's battery energy is its ReversibleEnergyStorage's electrical output, ∫ pwr_out_electrical dt: the power at
the pack's terminals, the toolkit's P_b (FASTSim's chemical energy adds its own constant pack efficiency, 0.985,
which the toolkit's 2-RC cell replaces).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .models.leader import CYCLES, load_cycle_si
from .params import EVParams
from .trace_replay import J_PER_KWH, default_ev, replay

#: FASTSim's vehicle file of the 2022 Tesla Model 3 RWD (a resource of the fastsim package).
FASTSIM_VEHICLE = "2022 Tesla Model 3 RWD thrml.yaml"
#: The agreement the replay with the map powertrain must reach [-] (within 2 %).
TOLERANCE = 0.02


def _fastsim() -> Any:
    try:
        import fastsim
    except ImportError as exc:  # the optional extra
        raise ImportError("the FASTSim validation needs NREL FASTSim 3.1: pip install 'aev_ocp[validation]'") from exc
    return fastsim


def fastsim_vehicle() -> dict[str, Any]:
    """FASTSim's Model 3 RWD as a dict (its vehicle file)."""
    return dict(_fastsim().Vehicle.from_resource(FASTSIM_VEHICLE).to_dict())


def fastsim_run(cycle: str) -> dict[str, float]:
    """FASTSim 3.1's own run of its Model 3 RWD on the shipped cycle ``cycle``: distance_m, battery_energy_J
    (electrical, at the pack terminals), aux_J, friction_brake_J and battery_energy_kWh_per_100km."""
    fs = _fastsim()
    t, v = load_cycle_si(cycle)
    veh = fs.Vehicle.from_resource(FASTSIM_VEHICLE)
    cyc = fs.Cycle.from_dict(
        {"time_seconds": np.asarray(t).tolist(), "speed_meters_per_second": np.asarray(v).tolist()}
    )
    sd = fs.SimDrive(veh, cyc)
    sd.run()
    d = sd.to_dict()["veh"]
    hist = d["history"]
    res = d["pt_type"]["BEV"]["res"]["history"]
    dist = float(hist["dist_meters"][-1])
    e = float(res["energy_out_electrical_joules"][-1])
    return {
        "distance_m": dist,
        "battery_energy_J": e,
        "aux_J": float(res["energy_aux_joules"][-1]),
        "friction_brake_J": float(hist["energy_brake_joules"][-1]),
        "battery_energy_kWh_per_100km": e / dist * 1e5 / J_PER_KWH,
    }


def comparison_rows(cycles: tuple[str, ...] = CYCLES) -> list[dict[str, Any]]:
    """One row per cycle: FASTSim's battery energy [kWh/100 km] beside the replay's with the map powertrain
    (FASTSim's vehicle as FASTSim runs it, :func:`aev_ocp.trace_replay.default_ev`), with the paper's η = 0.8 on the
    same vehicle, and with the paper's η on the toolkit's default vehicle (no auxiliary load, no wheel inertia,
    ρ = 1.225 kg/m³), and their relative errors [%]."""
    rows = []
    for c in cycles:
        fs = fastsim_run(c)["battery_energy_kWh_per_100km"]
        m = replay(c).summary()["battery_energy_kWh_per_100km"]
        k = replay(c, powertrain="constant").summary()["battery_energy_kWh_per_100km"]
        p = replay(c, ev=EVParams()).summary()["battery_energy_kWh_per_100km"]
        rows.append(
            {
                "cycle": c,
                "fastsim_kWh_per_100km": fs,
                "map_kWh_per_100km": m,
                "map_error_pct": 100 * (m / fs - 1),
                "eta_kWh_per_100km": k,
                "eta_error_pct": 100 * (k / fs - 1),
                "paper_vehicle_kWh_per_100km": p,
                "paper_vehicle_error_pct": 100 * (p / fs - 1),
            }
        )
    return rows


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """The guide's table of :func:`comparison_rows`."""
    lines = [
        "| cycle | FASTSim 3.1 [kWh/100 km] | replay, map [kWh/100 km] | error | replay, η = 0.8 [kWh/100 km] | error "
        "| η = 0.8, toolkit defaults [kWh/100 km] | error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['cycle'].upper()} | {r['fastsim_kWh_per_100km']:.3f} | {r['map_kWh_per_100km']:.3f} | "
            f"{r['map_error_pct']:+.2f} % | {r['eta_kWh_per_100km']:.3f} | {r['eta_error_pct']:+.1f} % | "
            f"{r['paper_vehicle_kWh_per_100km']:.3f} | {r['paper_vehicle_error_pct']:+.1f} % |"
        )
    return "\n".join(lines)


__all__ = ["comparison_rows", "default_ev", "fastsim_run", "fastsim_vehicle", "markdown_table", "TOLERANCE"]

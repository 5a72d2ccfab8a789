"""Write your own car-following law and run it beside the paper's laws.

A law is a frozen dataclass with an ``accel(h, v, v_l)`` written in CasADi-compatible arithmetic (it is
called with CasADi symbols, so the simulator, the string-stability analysis and the MPC fallback all
get an exact CasADi expression). ``register_law`` makes it available to scenario files by name.

Here: OVFL whose acceleration is saturated smoothly at ±a_cap (a comfort limit), a = a_cap·tanh(f/a_cap),
behind the EPA UDDS cycle. Run: python examples/own_law.py [--quick] [--out DIR]
Writes DIR/own_law.json (ω, pack heat, min gap per law) and DIR/own_law_space_time.png.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca

from aev_ocp.models.carfollowing import CarFollowingLaw, make_law, ovfl_accel, register_law
from aev_ocp.models.leader import drive_cycle
from aev_ocp.params import EVParams, Units
from aev_ocp.plots import plot_space_time
from aev_ocp.simulate import simulate_platoon


@dataclass(frozen=True)
class GentleOVFL(CarFollowingLaw):
    """OVFL saturated smoothly at ±a_cap: v̇ = a_cap·tanh(f_OVFL/a_cap) [model units]."""

    alpha: float = 2.0  # paper §2
    beta: float = 3.0  # paper §2
    a_cap: float = 0.1  # model acceleration: 1.9 m/s² at L = 15 m, U = 17 m/s (U²/L = 19.3 m/s²), a comfort limit
    name = "gentle_ovfl"
    _nonnegative = ("alpha", "beta")
    _positive = ("a_cap",)

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return self.a_cap * ca.tanh(ovfl_accel(h, v, v_l, self.alpha, self.beta) / self.a_cap)


register_law("gentle_ovfl", GentleOVFL)  # scenario files can now say law = "gentle_ovfl"


def main(quick: bool = False, out: Path = Path("results/examples/own_law")) -> dict[str, dict[str, float]]:
    units = Units(length_m=15.0, speed_mps=17.0)  # as scenario udds_platoon
    ev = EVParams(units=units)
    leader = drive_cycle("udds", units)
    t_end = 60.0 if quick else 1500.0  # model time (53 s or 22 min)
    n = 4
    summary: dict[str, dict[str, float]] = {}
    for name in ("gentle_ovfl", "ovfl", "proposed"):
        law = make_law(name)
        r = simulate_platoon(leader, [law] * n, [0.8] * n, [0.0] * n, t_end, ev=ev, dt_out=0.1)
        ms = r.metrics()
        summary[name] = {
            "status": r.status,
            "omega_J_per_kg": sum(m["omega_J_per_kg"] for m in ms),
            "heat_pack_J": sum(m["heat_pack_J"] for m in ms),
            "min_gap_m": min(m["min_gap_m"] for m in ms),
            "max_abs_accel_mps2": max(float(units.accel_to_si(abs(r.accel).max())), 0.0),
        }
        if name == "gentle_ovfl":
            plot_space_time(r, out / "own_law_space_time.png", title=f"{n} GentleOVFL followers behind UDDS")
        print(
            f"{name:>12}: status {r.status}, Σω = {summary[name]['omega_J_per_kg']:.1f} J/kg, "
            f"pack heat {summary[name]['heat_pack_J']:.0f} J, min gap {summary[name]['min_gap_m']:.2f} m, "
            f"max |a| {summary[name]['max_abs_accel_mps2']:.2f} m/s²"
        )
    out.mkdir(parents=True, exist_ok=True)
    (out / "own_law.json").write_text(json.dumps(summary, indent=1))
    return summary


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a short horizon (for the test suite)")
    ap.add_argument("--out", type=Path, default=Path("results/examples/own_law"))
    a = ap.parse_args()
    main(a.quick, a.out)

"""Add your own terms to the MPC (and to OCP-D, which is built from the same problem).

The §9 problem is a ProblemBuilder: add a constraint, a cost term or a state with one line each,
then give it to the MPC (or to OCPSolver for the whole-horizon optimum). Here: a time-headway
constraint h ≥ h_min + T_h·v, soft with an exact L1 penalty (never infeasible), and a cost on
speeds above a limit. The baseline is model guide §9's formulation itself (``s9_formulation()``: the
MPC's default is the traffic formulation), and the user problem becomes the MPC's formulation: its
bounds, name, cold start and cost follow it. Run: python examples/custom_mpc_term.py [--quick]
"""

from __future__ import annotations

import sys
from typing import Any

import casadi as ca

from aev_ocp.models import PaperLeader
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.ocp import following_problem
from aev_ocp.ocp.formulation import Formulation, s9_formulation
from aev_ocp.params import EVParams

T_HEADWAY = 1.5  # model time (3 s at L = 10 m, U = 5 m/s): a conservative ACC time gap
V_LIMIT = 1.9  # model speed (9.5 m/s)


def headway_problem(ev: EVParams, s9: Formulation) -> object:
    """The §9 problem (of the §9 formulation ``s9``) plus a soft time-headway constraint and a speed-limit cost."""
    pb = following_problem(ev, s9.bounds, s9.smooth, s9.objective, name="mpc_headway")
    h, v = pb.x["h"], pb.x["v"]
    pb.subject_to(h - T_HEADWAY * v, lb=s9.bounds.h_min, soft=50.0, name="headway")
    pb.add_stage_cost(10.0 * ca.fmax(v - V_LIMIT, 0) ** 2, name="speed_limit")
    return pb


def main(quick: bool = False) -> dict[str, dict[str, Any]]:
    ev, s9 = EVParams(), s9_formulation()
    s = MPCSettings(N=40, predictor="oracle")  # solver options only; §9's forecast, as its scenarios
    t_end = 6.0 if quick else 70.0
    runs = {
        "mpc (§9)": MPCVehicle(s, formulation=s9),
        "mpc (§9) + headway": MPCVehicle(s, problem=headway_problem(ev, s9)),
    }
    out = {}
    for name, veh in runs.items():
        r = run_closed_loop(PaperLeader(), [veh], [0.3], [1.87], t_end, ev=ev)
        margin = (r.gap[:, 0] - T_HEADWAY * r.speed[:, 0])[r.t >= t_end / 2].min()
        d = r.meta["controllers"][0]
        out[name] = {
            "margin": float(margin),
            "controller": r.controllers[0],
            "problem": d["problem"],
            "formulation": d["formulation"]["kind"],
            "family": d["formulation"]["family"],
            "bounds_model": d["bounds_model"],
            "status": r.status,
        }
        print(
            f"{name:>18}: status {r.status}, min (h - T_h v) over the second half = {margin:.3f} "
            f"(h_min = {d['bounds_model']['h_min']:g}, v_max = {d['bounds_model']['v_max']:g}), pack heat "
            f"{r.metrics()[0]['heat_pack_J']:.0f} J; controller {r.controllers[0]}, problem {d['problem']} "
            f"(formulation {d['formulation']['kind']}, family {d['formulation']['family']})"
        )
    return out


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)

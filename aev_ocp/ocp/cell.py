"""Cell-level OCPs (model guide §8 OCP-A and OCP-B): states of the 2-RC cell, control = cell current.

Time is in seconds, current in A (I > 0 discharges), voltages in V, Q in W per cell.
"""

from __future__ import annotations

import casadi as ca

from ..models import battery
from ..params import CellParams
from .transcription import OCPProblem


def cell_problem(cell: CellParams, q_nonneg: bool, energy_state: bool = False, name: str = "ocp_a") -> OCPProblem:
    """The 2-RC cell as an OCP: minimise ∫Q dt (paper eq. opt_prob), |I| ≤ I_max, S ∈ [0, 1].

    q_nonneg: add the paper's path constraint Q ≥ 0 at the nodes and collocation points.
    energy_state: add state E [J] with dE/dt = I·V_T (OCP-B) and the terminal constraint
    E(t_f) = E_req, E_req being the global parameter p[0] [J].
    """
    V1, V2, S, E = ca.SX.sym("V1"), ca.SX.sym("V2"), ca.SX.sym("S"), ca.SX.sym("E")
    I = ca.SX.sym("I")
    xs = [V1, V2, S] + ([E] if energy_state else [])
    x = ca.vertcat(*xs)
    w = ca.SX.sym("w", 0)
    p = ca.SX.sym("p", 1 if energy_state else 0)
    dV1, dV2, dS = battery.cell_derivatives(V1, V2, I, cell)
    VT = battery.terminal_voltage(S, V1, V2, I, cell)
    rhs = [dV1, dV2, dS] + ([I * VT] if energy_state else [])
    Q = battery.heat_Q(V1, V2, I, cell)
    args = [x, I, w, p]
    names = ["x", "u", "w", "p"]
    ode = ca.Function(f"{name}_ode", args, [ca.vertcat(*rhs)], names, ["xdot"])
    lagrange = ca.Function(f"{name}_Q", args, [Q], names, ["Q"])
    outputs = ca.Function(
        f"{name}_out",
        args,
        [I, Q, battery.heat_irreversible(V1, V2, I, cell), VT, battery.stored_energy_J(V1, V2, cell)],
        names,
        ["I", "Q", "Q_irr", "V_T", "W_rc"],
    )
    pr = OCPProblem(
        name=name,
        state_names=["V1", "V2", "S"] + (["E"] if energy_state else []),
        control_names=["I"],
        ode=ode,
        lagrange=lagrange,
        outputs=outputs,
        x_lb=[-ca.inf, -ca.inf, 0.0] + ([-ca.inf] if energy_state else []),  # S ∈ [0, 1] (paper eq. opt_prob)
        x_ub=[ca.inf, ca.inf, 1.0] + ([ca.inf] if energy_state else []),
        u_lb=[-cell.max_current_A],
        u_ub=[cell.max_current_A],  # |I| ≤ 20C (model guide §8)
        x_scale=[0.01, 0.01, 1.0] + ([1000.0] if energy_state else []),
        u_scale=[10.0],
        time_unit="s",
    )
    if q_nonneg:
        pr.path = ca.Function(f"{name}_Qpath", args, [Q], names, ["Q"])
        pr.path_lb, pr.path_ub = [0.0], [ca.inf]
        pr.path_at_collocation = True
    if energy_state:
        xN, pT = ca.SX.sym("xN", 4), ca.SX.sym("pT", 1)
        pr.terminal = ca.Function(f"{name}_energy", [xN, pT], [(xN[3] - pT[0]) / 1000.0])  # kJ scaling
        pr.terminal_lb, pr.terminal_ub = [0.0], [0.0]
    return pr

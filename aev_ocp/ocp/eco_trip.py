"""OCP-C: eco-trip (PROBLEM.md §8). Vehicle + pack, SI units, time in seconds.

State (x [m], v [m/s], V1 [V], V2 [V], S [-]); control a [m/s²] piecewise constant. Cover D [m]
in t_f [s] from v0 to vf, minimising pack ∫Q dt (objective 'heat', reported in kJ) or the
paper's ω = ∫ v g̃(a) dt with the smoothed g (objective 'energy', J/kg). Bounds on v and a;
|I| ≤ I_max and current-map feasibility disc ≥ 0 at the start of every interval. The η switch is
smoothed (powertrain.battery_power_smooth_W, PROBLEM.md §7).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..models import battery, energy
from ..models.powertrain import cell_current_from_motion
from ..params import EVParams, ParameterError, PowertrainOptions
from .result import OCPResult
from .transcription import OCPProblem, OCPSolver, TranscriptionOptions

OBJECTIVES = ("heat", "energy")


@dataclass(frozen=True)
class EcoTrip:
    """Trip data (SI). Defaults are our choice (PROBLEM.md §8 gives none): 1 km in 100 s from rest
    to rest; v ≤ 30 m/s; −3 ≤ a ≤ 2 m/s² (comfortable driving); S(0) = 0.8 (PROBLEM.md §6)."""

    distance_m: float = 1000.0
    t_f_s: float = 100.0
    v0_mps: float = 0.0
    vf_mps: float = 0.0
    v_max_mps: float = 30.0
    a_min_mps2: float = -3.0
    a_max_mps2: float = 2.0
    S0: float = 0.8  # PROBLEM.md §6
    objective: str = "heat"
    ev: EVParams = field(default_factory=EVParams)
    smooth: PowertrainOptions = field(default_factory=PowertrainOptions)  # PROBLEM.md §7
    g_width_mps2: float = 0.025  # smoothing width of g: 0.01 model acceleration at default units

    def __post_init__(self) -> None:
        for nm in ("distance_m", "t_f_s", "v_max_mps", "a_max_mps2", "g_width_mps2"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"EcoTrip.{nm} = {v!r} is not allowed: must be a finite number > 0")
        for nm in ("v0_mps", "vf_mps"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= self.v_max_mps):
                raise ParameterError(f"EcoTrip.{nm} = {v!r} is not allowed: must be in [0, v_max_mps]")
        if not (math.isfinite(self.a_min_mps2) and self.a_min_mps2 < 0):
            raise ParameterError(f"EcoTrip.a_min_mps2 = {self.a_min_mps2!r} is not allowed: must be < 0")
        if not 0 <= self.S0 <= 1:
            raise ParameterError(f"EcoTrip.S0 = {self.S0!r} is not allowed: must be in [0, 1]")
        if self.objective not in OBJECTIVES:
            raise ParameterError(f"EcoTrip.objective = {self.objective!r} is not allowed: must be one of {OBJECTIVES}")


def eco_problem(trip: EcoTrip) -> OCPProblem:
    """OCP-C as an OCPProblem; global parameter p = (D [m], vf [m/s])."""
    ev = trip.ev
    x, a, w, p = ca.SX.sym("x", 5), ca.SX.sym("a"), ca.SX.sym("w", 0), ca.SX.sym("p", 2)
    cm = cell_current_from_motion(x[1], a, x[2], x[3], x[4], ev, smooth=trip.smooth)
    I = cm["I"]
    dV1, dV2, dS = battery.cell_derivatives(x[2], x[3], I, ev.cell)
    Q = battery.heat_Q(x[2], x[3], I, ev.cell)
    n = ev.pack.n_cells
    omega_rate = x[1] * energy.g_smooth(a, ev.vehicle.efficiency, trip.g_width_mps2)
    cost = n * Q / 1000.0 if trip.objective == "heat" else omega_rate
    args, names = [x, a, w, p], ["x", "u", "w", "p"]
    xN, pT = ca.SX.sym("xN", 5), ca.SX.sym("pT", 2)
    Imax = ev.cell.max_current_A
    return OCPProblem(
        name="ocp_c", state_names=["x", "v", "V1", "V2", "S"], control_names=["a"],
        ode=ca.Function("eco_ode", args, [ca.vertcat(x[1], a, dV1, dV2, dS)], names, ["xdot"]),
        lagrange=ca.Function("eco_cost", args, [cost], names, ["l"]),
        path=ca.Function("eco_path", args, [ca.vertcat(I, cm["disc"])], names, ["c"]),
        path_lb=[-Imax, 0.0], path_ub=[Imax, ca.inf],
        terminal=ca.Function("eco_term", [xN, pT], [ca.vertcat((xN[0] - pT[0]) / 100.0, xN[1] - pT[1])]),
        terminal_lb=[0.0, 0.0], terminal_ub=[0.0, 0.0],
        outputs=ca.Function("eco_out", args, [I, Q, n * Q, cm["P_w"], cm["P_b"], cm["disc"], omega_rate],
                            names, ["I", "Q", "Q_pack_W", "P_w_W", "P_b_W", "disc", "omega_rate"]),
        x_lb=[-ca.inf, 0.0, -ca.inf, -ca.inf, 0.0], x_ub=[ca.inf, trip.v_max_mps, ca.inf, ca.inf, 1.0],
        u_lb=[trip.a_min_mps2], u_ub=[trip.a_max_mps2],
        x_scale=[max(trip.distance_m, 1.0), 10.0, 0.01, 0.01, 1.0], u_scale=[1.0], time_unit="s")


class EcoTripSolver:
    """OCP-C built once (objective and vehicle fixed); :meth:`solve` re-solves for new D, t_f, v0, vf, S0."""

    def __init__(self, trip: EcoTrip | None = None, method: str = "ms", N: int = 200, **opts: object) -> None:
        self.trip = trip or EcoTrip()
        self.solver = OCPSolver(eco_problem(self.trip), TranscriptionOptions(method=method, N=N, **opts))

    def solve(self, trip: EcoTrip | None = None, warm: bool = False) -> OCPResult:
        """Solve for ``trip`` (same objective/vehicle as at construction; default: that trip)."""
        tr = trip or self.trip
        if tr.objective != self.trip.objective or tr.ev != self.trip.ev or tr.smooth != self.trip.smooth:
            raise ParameterError("EcoTripSolver.solve: objective, ev and smooth must match the built solver")
        N = self.solver.options.N
        t = np.linspace(0.0, tr.t_f_s, N + 1)
        # initial guess: v(t) = v0 + (vf − v0) t/t_f + c sin²(πt/t_f), with c fixing the distance
        base = 0.5 * (tr.v0_mps + tr.vf_mps) * tr.t_f_s
        c = 2 * (tr.distance_m - base) / tr.t_f_s
        v = tr.v0_mps + (tr.vf_mps - tr.v0_mps) * t / tr.t_f_s + c * np.sin(np.pi * t / tr.t_f_s) ** 2
        v = np.clip(v, 0, tr.v_max_mps)
        xg = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        X = np.vstack([xg, v, np.zeros(N + 1), np.zeros(N + 1), np.full(N + 1, tr.S0)])
        U = np.clip(np.diff(v) / np.diff(t), tr.a_min_mps2, tr.a_max_mps2).reshape(1, -1)
        name = "pack integral of Q dt [kJ]" if tr.objective == "heat" else "omega = integral v g~(a) dt [J/kg]"
        res = self.solver.solve([0.0, tr.v0_mps, 0.0, 0.0, tr.S0], tr.t_f_s, p=[tr.distance_m, tr.vf_mps],
                                guess=None if warm else (X, U), warm=warm, objective_name=name)
        if not res.success and res.status in ("infeasible", "restoration_failed"):
            res.message += (f"; {tr.distance_m:g} m in {tr.t_f_s:g} s (mean {tr.distance_m / tr.t_f_s:.3g} m/s, "
                            f"v_max {tr.v_max_mps:g} m/s, a in [{tr.a_min_mps2:g}, {tr.a_max_mps2:g}] m/s²)")
        res.meta.update({"trip": {k: getattr(tr, k) for k in ("distance_m", "t_f_s", "v0_mps", "vf_mps",
                                                              "v_max_mps", "a_min_mps2", "a_max_mps2", "S0",
                                                              "objective")}})
        if res.success:
            res.meta.update(resimulate_exact(tr, res.controls["a"], res.t))
        return res


def resimulate_exact(trip: EcoTrip, a_mps2: np.ndarray, t_s: np.ndarray) -> dict[str, float]:
    """Metrics of a piecewise-constant acceleration profile under the EXACT model (PROBLEM.md §10).

    The vehicle and cell are re-integrated by CVODES, interval by interval with that interval's own
    control, with the exact η switch and the exact g: pack ∫Q and ∫Q_irr [J], ω [J/kg] and the final
    distance [m], speed [m/s] and S. A trapezoid on node samples would mix the controls of adjacent
    intervals (the optimiser's outputs at node k use a_k), which is what this replaces.
    """
    ev = trip.ev
    x, a = ca.SX.sym("x", 5), ca.SX.sym("a")
    cm = cell_current_from_motion(x[1], a, x[2], x[3], x[4], ev)
    I = cm["I"]
    dV1, dV2, dS = battery.cell_derivatives(x[2], x[3], I, ev.cell)
    n = ev.pack.n_cells
    quad = ca.vertcat(n * battery.heat_Q(x[2], x[3], I, ev.cell), n * battery.heat_irreversible(x[2], x[3], I, ev.cell),
                      x[1] * energy.g_exact(a, ev.vehicle.efficiency))
    dt = ca.SX.sym("dt")
    dae = {"x": x, "p": ca.vertcat(a, dt), "ode": dt * ca.vertcat(x[1], a, dV1, dV2, dS), "quad": dt * quad}
    F = ca.integrator("eco_exact", "cvodes", dae, 0.0, 1.0, {"abstol": 1e-10, "reltol": 1e-10})
    a_k = np.asarray(a_mps2, float).ravel()
    h = np.diff(np.asarray(t_s, float))
    xk = np.array([0.0, trip.v0_mps, 0.0, 0.0, trip.S0])
    q = np.zeros(3)
    for ak, hk in zip(a_k, h):
        out = F(x0=xk, p=[ak, hk])
        xk = np.asarray(out["xf"]).ravel()
        q += np.asarray(out["qf"]).ravel()
    return {"pack_heat_J": float(q[0]), "pack_heat_irr_J": float(q[1]), "omega_J_per_kg": float(q[2]),
            "exact_final_distance_m": float(xk[0]), "exact_final_speed_mps": float(xk[1]), "exact_final_soc": float(xk[4])}

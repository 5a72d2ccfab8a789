"""OCP-B: the optimal cell-current profile (model guide §8).

Deliver E_req [J] at the terminals over [0, t_f] (∫ I V_T dt = E_req) with minimum ∫Q dt, and
compare with a constant current and a constant power delivering the same energy, both simulated
with the same cell model (CVODES): the constant current is found by root finding on
E(t_f; I_c) = E_req; constant power P = E_req/t_f takes at each instant the physical root of
P = I (E − R_s I) (model guide §7).

OCP-B has no smoothing (the cell model is smooth), so its smoothing-gap check measures the
transcription alone: the NLP's ∫Q against CVODES along the optimal piecewise-constant current.
When a demand is infeasible, the message quotes the true bound: the maximum energy the cell can
deliver within |I| ≤ I_max and S ∈ [0, 1] over t_f, from a max-energy solve (:func:`max_energy_problem`).
"""

from __future__ import annotations

import math
from typing import Any, Callable

import casadi as ca
import numpy as np

from ..models import battery
from ..models.powertrain import current_discriminant
from ..params import CellParams, ParameterError
from .cell import cell_problem
from .checks import GAP_RTOL, record_refinement, record_smoothing_gap, resimulate_cell_current
from ..ocp_result import OCPResult
from .transcription import OCPProblem, OCPSolver, TranscriptionOptions

E_REQ_J = 3000.0  # default demand: 50 W average per cell over 60 s (≈ 15 A, 6.5C); our choice
T_F_S = 60.0  # same horizon as OCP-A (model guide §8)
SOC0 = 0.5  # same initial SOC as OCP-A (model guide §8)


def _cell_sim(cell: CellParams, mode: str) -> ca.Function:
    """Integrator over [0, 1] in normalised time s = t/t_f: parameter (value, t_f); mode 'current' or
    'power'. State (V1, V2, S); quadratures (∫Q, ∫Q_irr, ∫I V_T, max-violation proxies)."""
    x = ca.SX.sym("x", 3)
    prm = ca.SX.sym("prm", 2)
    val, tf = prm[0], prm[1]
    if mode == "current":
        I = val
        disc = ca.SX(1.0)
    else:
        E = battery.ocv(x[2], cell) - x[0] - x[1]
        disc = current_discriminant(val, E, cell)
        # physical root of P = I (E − R_s I) (model guide §7); sqrt floored at 1e-12 V² so that an
        # infeasible demand is recorded by the disc quadrature instead of producing NaN Jacobians
        I = 2.0 * val / (E + ca.sqrt(ca.fmax(disc, 1e-12)))
    dV1, dV2, dS = battery.cell_derivatives(x[0], x[1], I, cell)
    VT = battery.terminal_voltage(x[2], x[0], x[1], I, cell)
    quad = ca.vertcat(
        battery.heat_Q(x[0], x[1], I, cell),
        battery.heat_irreversible(x[0], x[1], I, cell),
        I * VT,
        ca.fmax(-disc, 0),
        ca.fmax(ca.fabs(I) - cell.max_current_A, 0),
    )
    dae = {"x": x, "p": prm, "ode": tf * ca.vertcat(dV1, dV2, dS), "quad": tf * quad}
    if mode == "current":
        return ca.integrator("cell_current", "cvodes", dae, 0.0, 1.0, {"abstol": 1e-12, "reltol": 1e-10})
    # fixed-step RK4 (4000 steps): the power mode has a kink where the demand becomes infeasible,
    # which an adaptive integrator cannot step across quietly; its quadratures record the violation
    return ca.integrator("cell_power", "rk", dae, 0.0, 1.0, {"number_of_finite_elements": 4000})


def _root(f: Callable[[float], float], lo: float, hi: float, tol: float = 1e-10, it: int = 100) -> float:
    """Bracketed root of f on [lo, hi] (Illinois false position); raises ValueError if not bracketed."""
    flo, fhi = f(lo), f(hi)
    if flo * fhi > 0:
        raise ValueError("root not bracketed")
    side = 0
    for _ in range(it):
        x = (lo * fhi - hi * flo) / (fhi - flo)
        fx = f(x)
        if abs(fx) < tol or hi - lo < tol:
            return x
        if fx * fhi > 0:
            hi, fhi = x, fx
            if side == -1:
                flo /= 2
            side = -1
        else:
            lo, flo = x, fx
            if side == 1:
                fhi /= 2
            side = 1
    return x


def reference_profiles(
    E_req: float, t_f: float, S0: float = SOC0, cell: CellParams | None = None
) -> dict[str, dict[str, Any]]:
    """Constant current and constant power delivering E_req [J] over t_f [s] from rest at S0.

    Returns {'constant_current': {...}, 'constant_power': {...}} with heat_J (∫Q), heat_irr_J,
    energy_J (∫I V_T, check), current_A / power_W, feasible (bool) and why."""
    cell = cell or CellParams()
    x0 = [0.0, 0.0, S0]
    out: dict[str, dict[str, Any]] = {}
    Fi = _cell_sim(cell, "current")

    def energy_at(I: float) -> float:
        return float(Fi(x0=x0, p=[I, t_f])["qf"][2]) - E_req

    try:
        Ic = _root(energy_at, 0.0, cell.max_current_A, tol=1e-9 * max(E_req, 1.0))
        r = Fi(x0=x0, p=[Ic, t_f])
        q = np.asarray(r["qf"]).ravel()
        xf = np.asarray(r["xf"]).ravel()
        ok = 0.0 <= xf[2] <= 1.0
        out["constant_current"] = {
            "current_A": Ic,
            "heat_J": q[0],
            "heat_irr_J": q[1],
            "energy_J": q[2],
            "feasible": ok,
            "why": "" if ok else "S leaves [0, 1]",
        }
    except ValueError:
        out["constant_current"] = {
            "current_A": math.nan,
            "heat_J": math.nan,
            "heat_irr_J": math.nan,
            "energy_J": math.nan,
            "feasible": False,
            "why": f"no constant current within ±{cell.max_current_A} A delivers E_req",
        }
    Fp = _cell_sim(cell, "power")
    P = E_req / t_f
    try:
        r = Fp(x0=x0, p=[P, t_f])
        q = np.asarray(r["qf"]).ravel()
        ok = q[3] <= 0 and q[4] <= 0
        why = (
            ""
            if ok
            else (
                "the cell cannot deliver the power (E² < 4 R_s P)"
                if q[3] > 0
                else f"the current exceeds {cell.max_current_A} A"
            )
        )
        nan = math.nan
        out["constant_power"] = {
            "power_W": P,
            "heat_J": q[0] if ok else nan,
            "heat_irr_J": q[1] if ok else nan,
            "energy_J": q[2] if ok else nan,
            "feasible": bool(ok),
            "why": why,
        }
    except RuntimeError as exc:
        out["constant_power"] = {
            "power_W": P,
            "heat_J": math.nan,
            "heat_irr_J": math.nan,
            "energy_J": math.nan,
            "feasible": False,
            "why": f"integration failed: {str(exc).splitlines()[-1]}",
        }
    return out


def max_energy_problem(cell: CellParams) -> OCPProblem:
    """The cell OCP with objective −∫ I V_T dt [J] (maximise the energy delivered at the terminals)
    under the same limits as OCP-B (|I| ≤ I_max, S ∈ [0, 1]) and no energy constraint."""
    pr = cell_problem(cell, False, energy_state=False, name="ocp_b_max_energy")
    x, I, w, p = ca.SX.sym("x", 3), ca.SX.sym("I"), ca.SX.sym("w", 0), ca.SX.sym("p", 0)
    VT = battery.terminal_voltage(x[2], x[0], x[1], I, cell)
    pr.lagrange = ca.Function("ocp_b_minus_energy", [x, I, w, p], [-I * VT], ["x", "u", "w", "p"], ["l"])
    return pr


class CurrentProfileSolver:
    """OCP-B built once for N intervals; solve(E_req, t_f, S0) re-solves (t_f and E_req are NLP
    parameters, so no rebuild)."""

    def __init__(self, method: str = "ms", N: int = 200, cell: CellParams | None = None, **opts: Any) -> None:
        self.cell = cell or CellParams()
        self.method, self.opts = method, dict(opts)
        self.solver = OCPSolver(
            cell_problem(self.cell, False, energy_state=True, name="ocp_b"),
            TranscriptionOptions(method=method, N=N, **opts),
        )
        self._max_solver: OCPSolver | None = None

    def max_energy(self, t_f: float = T_F_S, S0: float = SOC0) -> dict[str, Any]:
        """The most energy [J per cell] any current profile within |I| ≤ I_max, S ∈ [0, 1] delivers
        over t_f [s] from rest at S0: the max-energy solve's current re-simulated exactly (CVODES),
        next to constant I_max (the closed-form candidate). Keys: max_energy_J, status,
        constant_Imax_energy_J, current_A (the maximising profile)."""
        if self._max_solver is None:
            self._max_solver = OCPSolver(max_energy_problem(self.cell), self.solver.options)
        N = self.solver.options.N
        Imax = self.cell.max_current_A
        guess = (np.vstack([np.zeros((2, N + 1)), np.full(N + 1, S0)]), np.full((1, N), Imax))
        res = self._max_solver.solve([0.0, 0.0, S0], t_f, guess=guess, objective_name="-integral I V_T dt [J]")
        const = resimulate_cell_current(self.cell, res.t, np.full(N, Imax), [0.0, 0.0, S0])
        out: dict[str, Any] = {
            "status": res.status,
            "constant_Imax_energy_J": const["energy_J"] if 0 <= const["S_end"] <= 1 else math.nan,
        }
        if res.success:
            exact = resimulate_cell_current(self.cell, res.t, res.controls["I"], [0.0, 0.0, S0])
            out.update({"max_energy_J": exact["energy_J"], "current_A": res.controls["I"]})
        else:
            out.update({"max_energy_J": out["constant_Imax_energy_J"], "current_A": np.full(N, Imax)})
        return out

    def solve(
        self,
        E_req: float = E_REQ_J,
        t_f: float = T_F_S,
        S0: float = SOC0,
        warm: bool = False,
        gap_rtol: float = GAP_RTOL,
    ) -> OCPResult:
        """Minimise ∫Q delivering E_req [J] in t_f [s] from rest at S0. A successful result carries the
        exact re-simulation (meta 'exact': heat, energy) and the smoothing-gap record."""
        if not (isinstance(E_req, (int, float)) and math.isfinite(E_req)):
            raise ParameterError(f"OCP-B: E_req = {E_req!r} is not allowed: must be a finite number [J]")
        if not 0 <= S0 <= 1:
            raise ParameterError(f"OCP-B: S0 = {S0!r} is not allowed: must be in [0, 1]")
        N = self.solver.options.N
        guess = None
        if not warm:
            I0 = float(np.clip(E_req / (t_f * 3.2), -self.cell.max_current_A, self.cell.max_current_A))
            X = np.zeros((4, N + 1))
            X[2] = S0 - I0 * np.linspace(0, t_f, N + 1) / (3600 * self.cell.capacity_Ah)
            X[3] = np.linspace(0, E_req, N + 1)
            guess = (X, np.full((1, N), I0))
        res = self.solver.solve(
            [0.0, 0.0, S0, 0.0], t_f, p=[E_req], guess=guess, warm=warm, objective_name="integral of Q dt [J per cell]"
        )
        if not res.success and res.status in ("infeasible", "restoration_failed"):
            bound = self.max_energy(t_f, S0)
            res.meta["max_energy"] = {k: v for k, v in bound.items() if k != "current_A"}
            Em = bound["max_energy_J"]
            verdict = "exceeds" if E_req > Em else "is within"
            res.message += (
                f"; E_req = {E_req:g} J in {t_f:g} s ({E_req / t_f:.4g} W per cell) {verdict} the most "
                f"any profile with |I| ≤ {self.cell.max_current_A:g} A delivers: {Em:.6g} J "
                f"({Em / t_f:.4g} W; max-energy solve {bound['status']}, constant "
                f"{self.cell.max_current_A:g} A: {bound['constant_Imax_energy_J']:.6g} J)"
            )
        res.meta.update({"E_req_J": E_req})
        if res.success:
            exact = resimulate_cell_current(self.cell, res.t, res.controls["I"], [0.0, 0.0, S0])
            res.meta["exact"] = exact
            record_smoothing_gap(res, exact["heat_J"], "no smoothing; CVODES re-simulation", gap_rtol, atol=1e-9)
        return res

    def refine(self, res: OCPResult, S0: float = SOC0) -> dict[str, Any]:
        """Solve ``res``'s (E_req, t_f) again with 2N intervals; record the change in res.meta['refinement']."""
        # a one-off solve: one mapped interval Function (mx_map) keeps its build time independent of 2N
        fine = CurrentProfileSolver(self.method, 2 * self.solver.options.N, self.cell, **{**self.opts, "mx_map": True})
        return record_refinement(res, fine.solve(res.meta["E_req_J"], float(res.meta["t_f"]), S0))


def compare_profiles(
    E_req: float = E_REQ_J, t_f: float = T_F_S, S0: float = SOC0, solver: CurrentProfileSolver | None = None
) -> dict[str, Any]:
    """Optimal profile vs constant current vs constant power for one (E_req, t_f)."""
    solver = solver or CurrentProfileSolver()
    res = solver.solve(E_req, t_f, S0)
    ref = reference_profiles(E_req, t_f, S0, solver.cell)
    row: dict[str, Any] = {
        "E_req_J": E_req,
        "t_f_s": t_f,
        "status": res.status,
        "iterations": res.iterations,
        "optimal_heat_J": res.objective,
        "constant_current_heat_J": ref["constant_current"]["heat_J"],
        "constant_power_heat_J": ref["constant_power"]["heat_J"],
        "constant_current_A": ref["constant_current"]["current_A"],
        "constant_power_W": ref["constant_power"]["power_W"],
    }
    row["exact_heat_J"] = res.objective_exact
    row["warnings"] = list(res.warnings)
    if "max_energy" in res.meta:
        row["max_energy_J"] = res.meta["max_energy"]["max_energy_J"]
    if not res.success:
        row["optimal_heat_J"] = math.nan  # not a solution: see status
    else:
        row["saving_vs_cc_pct"] = 100 * (1 - res.objective / row["constant_current_heat_J"])
        row["saving_vs_cp_pct"] = 100 * (1 - res.objective / row["constant_power_heat_J"])
    return {"row": row, "result": res, "references": ref}

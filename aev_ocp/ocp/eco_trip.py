"""OCP-C: eco-trip (model guide §8). Vehicle + pack, SI units, time in seconds.

State (x [m], v [m/s], V1 [V], V2 [V], S [-]); control a [m/s²] piecewise constant. Cover D [m]
in t_f [s] from v0 to vf, minimising pack ∫Q dt (objective 'heat', reported in kJ) or the
paper's inertial measure ω = ∫ v g(a) dt (objective 'omega', J/kg; old name 'energy' accepted with a
FutureWarning; ω is not battery energy). Bounds on v and a; |I| ≤ I_max and
current-map feasibility disc ≥ 0 at the start of every interval.

Exact where it can be. For v ≥ 0, v·g(a) = max(v·a/η, η·v·a): a maximum of two
functions linear in a. Minimising ∫ v g(a) dt is therefore the same as minimising ∫ s dt over an
extra control s (the epigraph slack) with s ≥ v̄·a/η and s ≥ η·v̄·a, smooth and without a width
parameter. With a piecewise constant, v is linear on each interval and ∫_k v g(a_k) dt =
g(a_k)·v̄_k·h with the interval-mean speed v̄_k = v_k + a_k h/2 ≥ 0, so the slack constraints use
v̄_k and the NLP objective Σ s_k h IS the exact ω of the applied profile (omega_form 'epigraph',
the default). The smoothed g̃ of the earlier versions stays available as omega_form 'smooth' (its
optimiser creeps at ±0.015 m/s² where g̃ < g: 24.14 J/kg in the NLP, 25.07 exact).

No exact reformulation exists for the η switch inside the heat objective: P_b = max(P_w/η, η P_w)
is convex in P_w, but it enters Q through the nonlinear current map I(P_c, E) and the RC states,
so ∫Q is not a maximum of smooth pieces and an epigraph slack would not be tight. The heat
objective keeps the smoothed switch of model guide §7; the smoothing-gap check
(:func:`aev_ocp.ocp.checks.record_smoothing_gap`) compares it with the exact re-simulation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import casadi as ca
import numpy as np

from ..models import battery, energy
from ..models.powertrain import cell_current_from_motion
from ..numerics import integrate_held
from ..params import EVParams, ParameterError, PowertrainOptions
from .following import RENAMED_OBJECTIVES, objective_name
from .checks import GAP_RTOL, multistart, record_refinement, record_smoothing_gap
from ..ocp_result import OCPResult
from .transcription import OCPProblem, OCPSolver, TranscriptionOptions

OBJECTIVES = ("heat", "omega")  # pack ∫Q dt; the paper's ω (old name "energy": following.RENAMED_OBJECTIVES)
OMEGA_FORMS = ("epigraph", "smooth")
# initial guesses (speed profiles): 'sine' v0 → vf plus c·sin²(πt/t_f); 'trapezoid' ramps over the first
# and last quarter; 'constant' D/t_f after t = 0; 'bang' the closed-form ω optimum (bang–cruise–bang)
GUESSES = ("sine", "trapezoid", "constant", "bang")


@dataclass(frozen=True)
class EcoTrip:
    """Trip data (SI). Defaults are our choice (model guide §8 gives none): 1 km in 100 s from rest
    to rest; v ≤ 30 m/s; −3 ≤ a ≤ 2 m/s² (comfortable driving); S(0) = 0.8 (model guide §6).
    omega_form: 'epigraph' (exact, default) or 'smooth' (g̃ of width g_width_mps2, kept to show the
    smoothing gap)."""

    distance_m: float = 1000.0
    t_f_s: float = 100.0
    v0_mps: float = 0.0
    vf_mps: float = 0.0
    v_max_mps: float = 30.0
    a_min_mps2: float = -3.0
    a_max_mps2: float = 2.0
    S0: float = 0.8  # model guide §6
    objective: str = "heat"
    ev: EVParams = field(default_factory=EVParams)
    smooth: PowertrainOptions = field(default_factory=PowertrainOptions)  # model guide §7
    g_width_mps2: float = 0.025  # smoothing width of g ('smooth' only): 0.01 model acceleration at default units
    omega_form: str = "epigraph"  # issue 13: exact epigraph reformulation of ∫ v g(a) dt

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
        if self.objective in RENAMED_OBJECTIVES:
            object.__setattr__(self, "objective", objective_name(self.objective, "EcoTrip.objective"))
        if self.objective not in OBJECTIVES:
            raise ParameterError(f"EcoTrip.objective = {self.objective!r} is not allowed: must be one of {OBJECTIVES}")
        if self.omega_form not in OMEGA_FORMS:
            raise ParameterError(
                f"EcoTrip.omega_form = {self.omega_form!r} is not allowed: must be one of {OMEGA_FORMS}"
            )

    @property
    def epigraph(self) -> bool:
        """True when the problem carries the epigraph slack s (objective 'omega', form 'epigraph')."""
        return self.objective == "omega" and self.omega_form == "epigraph"


def eco_problem(trip: EcoTrip) -> OCPProblem:
    """OCP-C as an OCPProblem; global parameter p = (D [m], vf [m/s], h [s]) with h = t_f/N the
    interval length (used by the epigraph constraints' interval-mean speed). Controls: a [m/s²],
    plus the epigraph slack s [W/kg] when ``trip.epigraph``."""
    ev = trip.ev
    eta = ev.vehicle.efficiency
    nu = 2 if trip.epigraph else 1
    x, u, w, p = ca.SX.sym("x", 5), ca.SX.sym("u", nu), ca.SX.sym("w", 0), ca.SX.sym("p", 3)
    a = u[0]
    cm = cell_current_from_motion(x[1], a, x[2], x[3], x[4], ev, smooth=trip.smooth)
    I = cm["I"]
    dV1, dV2, dS = battery.cell_derivatives(x[2], x[3], I, ev.cell)
    Q = battery.heat_Q(x[2], x[3], I, ev.cell)
    n = ev.pack.n_cells
    path = [I, cm["disc"]]
    path_lb, path_ub = [-ev.cell.max_current_A, 0.0], [ev.cell.max_current_A, ca.inf]
    if trip.objective == "heat":
        cost, omega_rate = n * Q / 1000.0, x[1] * energy.g_smooth(a, eta, trip.g_width_mps2)
    elif trip.epigraph:
        v_mean = x[1] + a * p[2] / 2  # interval-mean speed: v is linear on the interval
        cost = omega_rate = u[1]
        path += [u[1] - v_mean * a / eta, u[1] - eta * v_mean * a]  # s ≥ v̄a/η, s ≥ ηv̄a
        path_lb += [0.0, 0.0]
        path_ub += [ca.inf, ca.inf]
    else:
        cost = omega_rate = x[1] * energy.g_smooth(a, eta, trip.g_width_mps2)
    args, names = [x, u, w, p], ["x", "u", "w", "p"]
    xN, pT = ca.SX.sym("xN", 5), ca.SX.sym("pT", 3)
    return OCPProblem(
        name="ocp_c",
        state_names=["x", "v", "V1", "V2", "S"],
        control_names=["a", "s"][:nu],
        ode=ca.Function("eco_ode", args, [ca.vertcat(x[1], a, dV1, dV2, dS)], names, ["xdot"]),
        lagrange=ca.Function("eco_cost", args, [cost], names, ["l"]),
        path=ca.Function("eco_path", args, [ca.vertcat(*path)], names, ["c"]),
        path_lb=path_lb,
        path_ub=path_ub,
        terminal=ca.Function("eco_term", [xN, pT], [ca.vertcat((xN[0] - pT[0]) / 100.0, xN[1] - pT[1])]),
        terminal_lb=[0.0, 0.0],
        terminal_ub=[0.0, 0.0],
        outputs=ca.Function(
            "eco_out",
            args,
            [I, Q, n * Q, cm["P_w"], cm["P_b"], cm["disc"], omega_rate],
            names,
            ["I", "Q", "Q_pack_W", "P_w_W", "P_b_W", "disc", "omega_rate"],
        ),
        x_lb=[-ca.inf, 0.0, -ca.inf, -ca.inf, 0.0],
        x_ub=[ca.inf, trip.v_max_mps, ca.inf, ca.inf, 1.0],
        u_lb=[trip.a_min_mps2, -ca.inf][:nu],
        u_ub=[trip.a_max_mps2, ca.inf][:nu],
        x_scale=[max(trip.distance_m, 1.0), 10.0, 0.01, 0.01, 1.0],
        u_scale=[1.0, 10.0][:nu],
        time_unit="s",
    )


def bang_cruise_bang(trip: EcoTrip) -> tuple[float, float, float] | None:
    """The continuous-time closed-form ω optimum: accelerate at a_max from v0 to the cruise speed V,
    cruise, brake at a_min to vf. V solves D = V t_f − (V − v0)²/(2 a_max) − (V − vf)²/(2 |a_min|).
    Returns (V [m/s], t1 [s] end of acceleration, t2 [s] start of braking), or None when no such
    profile fits (V < max(v0, vf) or V > v_max or t1 > t2). For v0 = vf = 0 its ω is
    (1/η − η) V²/2 [J/kg] (ω only pays for changes of kinetic energy)."""
    A, B = trip.a_max_mps2, -trip.a_min_mps2
    T, D, v0, vf = trip.t_f_s, trip.distance_m, trip.v0_mps, trip.vf_mps
    # quadratic in V: −(1/2A + 1/2B) V² + (T + v0/A + vf/B) V − (v0²/2A + vf²/2B) − D = 0
    qa = -(1 / (2 * A) + 1 / (2 * B))
    qb = T + v0 / A + vf / B
    qc = -(v0**2 / (2 * A) + vf**2 / (2 * B)) - D
    disc = qb**2 - 4 * qa * qc
    if disc < 0:
        return None
    V = (-qb + math.sqrt(disc)) / (2 * qa)  # the smaller root (qa < 0)
    t1, t2 = (V - v0) / A, T - (V - vf) / B
    if V < max(v0, vf) or V > trip.v_max_mps or t1 > t2:
        return None
    return V, t1, t2


def guess_speed(trip: EcoTrip, t: np.ndarray, kind: str) -> np.ndarray:
    """Speed profile of the named initial guess (GUESSES) at the nodes t [s], clipped to [0, v_max]."""
    T, D, v0, vf = trip.t_f_s, trip.distance_m, trip.v0_mps, trip.vf_mps
    if kind == "bang":
        bcb = bang_cruise_bang(trip)
        if bcb is None:
            kind = "sine"
        else:
            V, t1, t2 = bcb
            v = np.minimum.reduce([v0 + trip.a_max_mps2 * t, np.full_like(t, V), vf - trip.a_min_mps2 * (T - t)])
    if kind == "trapezoid":
        V = (D - T * (v0 + vf) / 8) / (0.75 * T)
        v = np.interp(t, [0, T / 4, 3 * T / 4, T], [v0, V, V, vf])
    elif kind == "constant":
        v = np.full_like(t, D / T)
        v[0], v[-1] = v0, vf
    elif kind == "sine":
        # v(t) = v0 + (vf − v0) t/t_f + c sin²(πt/t_f), with c fixing the distance
        c = 2 * (D - 0.5 * (v0 + vf) * T) / T
        v = v0 + (vf - v0) * t / T + c * np.sin(np.pi * t / T) ** 2
    elif kind != "bang":
        raise ParameterError(f"eco-trip initial guess {kind!r} is not allowed: must be one of {GUESSES}")
    return np.clip(v, 0, trip.v_max_mps)


class EcoTripSolver:
    """OCP-C built once (objective and vehicle fixed); :meth:`solve` re-solves for new D, t_f, v0, vf, S0."""

    def __init__(self, trip: EcoTrip | None = None, method: str = "ms", N: int = 200, **opts: Any) -> None:
        self.trip = trip or EcoTrip()
        self.method, self.opts = method, dict(opts)
        self.solver = OCPSolver(eco_problem(self.trip), TranscriptionOptions(method=method, N=N, **opts))

    def _guess(self, tr: EcoTrip, kind: str) -> tuple[np.ndarray, np.ndarray]:
        N = self.solver.options.N
        t = np.linspace(0.0, tr.t_f_s, N + 1)
        v = guess_speed(tr, t, kind)
        xg = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        X = np.vstack([xg, v, np.zeros(N + 1), np.zeros(N + 1), np.full(N + 1, tr.S0)])
        a = np.clip(np.diff(v) / np.diff(t), tr.a_min_mps2, tr.a_max_mps2)
        if not tr.epigraph:
            return X, a.reshape(1, -1)
        eta = tr.ev.vehicle.efficiency
        vbar = 0.5 * (v[1:] + v[:-1])
        return X, np.vstack([a, np.maximum(vbar * a / eta, eta * vbar * a)])

    def solve(
        self, trip: EcoTrip | None = None, warm: bool = False, guess: str = "sine", gap_rtol: float = GAP_RTOL
    ) -> OCPResult:
        """Solve for ``trip`` (same objective/vehicle as at construction; default: that trip) from the
        initial guess ``guess`` (GUESSES; ignored when warm). A successful result carries the exact
        re-simulation (:func:`resimulate_exact`) in meta, ``objective_exact`` and a warning when the
        NLP objective and its exact re-evaluation differ by more than ``gap_rtol``."""
        tr = trip or self.trip
        if (tr.objective, tr.ev, tr.smooth, tr.omega_form, tr.g_width_mps2) != (
            self.trip.objective,
            self.trip.ev,
            self.trip.smooth,
            self.trip.omega_form,
            self.trip.g_width_mps2,
        ):
            raise ParameterError(
                "EcoTripSolver.solve: objective, ev, smooth, omega_form and g_width_mps2 must match the built solver"
            )
        if guess not in GUESSES:
            raise ParameterError(f"eco-trip initial guess {guess!r} is not allowed: must be one of {GUESSES}")
        N = self.solver.options.N
        if tr.objective == "heat":
            name = "pack integral of Q dt [kJ]"
        elif tr.epigraph:
            name = "omega = integral v g(a) dt [J/kg] (exact epigraph)"
        else:
            name = "omega = integral v g~(a) dt [J/kg] (smoothed g)"
        res = self.solver.solve(
            [0.0, tr.v0_mps, 0.0, 0.0, tr.S0],
            tr.t_f_s,
            p=[tr.distance_m, tr.vf_mps, tr.t_f_s / N],
            guess=None if warm else self._guess(tr, guess),
            warm=warm,
            objective_name=name,
        )
        if not res.success and res.status in ("infeasible", "restoration_failed"):
            res.message += (
                f"; {tr.distance_m:g} m in {tr.t_f_s:g} s (mean {tr.distance_m / tr.t_f_s:.3g} m/s, "
                f"v_max {tr.v_max_mps:g} m/s, a in [{tr.a_min_mps2:g}, {tr.a_max_mps2:g}] m/s²)"
            )
        res.meta.update(
            {
                "trip": {
                    k: getattr(tr, k)
                    for k in (
                        "distance_m",
                        "t_f_s",
                        "v0_mps",
                        "vf_mps",
                        "v_max_mps",
                        "a_min_mps2",
                        "a_max_mps2",
                        "S0",
                        "objective",
                        "omega_form",
                    )
                },
                "guess": "warm" if warm else guess,
            }
        )
        if res.success:
            res.meta.update(resimulate_exact(tr, res.controls["a"], res.t))
            if tr.objective == "heat":
                record_smoothing_gap(res, res.meta["pack_heat_J"] / 1000.0, "exact η switch, CVODES", gap_rtol)
            else:
                record_smoothing_gap(res, res.meta["omega_J_per_kg"], "exact g, CVODES", gap_rtol)
        return res

    def solve_multistart(
        self, trip: EcoTrip | None = None, guesses: Sequence[str] = GUESSES, gap_rtol: float = GAP_RTOL
    ) -> OCPResult:
        """Solve from each initial guess and keep the lowest NLP objective (spread in meta['multistart'])."""
        return multistart(lambda g: self.solve(trip, guess=g, gap_rtol=gap_rtol), guesses)[0]

    def refine(self, res: OCPResult, trip: EcoTrip | None = None, guess: str | None = None) -> dict[str, Any]:
        """Solve again with 2N intervals (same trip, same initial guess kind) and record in
        ``res.meta['refinement']`` how the objective changes."""
        # a one-off solve: one mapped interval Function (mx_map) keeps its build time independent of 2N
        fine = EcoTripSolver(self.trip, self.method, 2 * self.solver.options.N, **{**self.opts, "mx_map": True})
        kind = guess or str(res.meta.get("guess", "sine"))
        return record_refinement(res, fine.solve(trip, guess=kind if kind in GUESSES else "sine"))


def resimulate_exact(trip: EcoTrip, a_mps2: np.ndarray, t_s: np.ndarray) -> dict[str, float]:
    """Metrics of a piecewise-constant acceleration profile under the EXACT model (model guide §10).

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
    quad = ca.vertcat(
        n * battery.heat_Q(x[2], x[3], I, ev.cell),
        n * battery.heat_irreversible(x[2], x[3], I, ev.cell),
        x[1] * energy.g_exact(a, ev.vehicle.efficiency),
    )
    dt = ca.SX.sym("dt")
    dae = {"x": x, "p": ca.vertcat(a, dt), "ode": dt * ca.vertcat(x[1], a, dV1, dV2, dS), "quad": dt * quad}
    F = ca.integrator("eco_exact", "cvodes", dae, 0.0, 1.0, {"abstol": 1e-10, "reltol": 1e-10})
    a_k = np.asarray(a_mps2, float).ravel()
    h = np.diff(np.asarray(t_s, float))
    xk, q = integrate_held(F, [0.0, trip.v0_mps, 0.0, 0.0, trip.S0], a_k, h)
    return {
        "pack_heat_J": float(q[0]),
        "pack_heat_irr_J": float(q[1]),
        "omega_J_per_kg": float(q[2]),
        "exact_final_distance_m": float(xk[0]),
        "exact_final_speed_mps": float(xk[1]),
        "exact_final_soc": float(xk[4]),
    }

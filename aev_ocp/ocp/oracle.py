"""OCP-D: oracle following (model guide §8 OCP-D with the cost and constraints of §9).

The leader's whole trajectory is known; the ego state z = (h, v, V1, V2, S) and the piecewise-constant
acceleration a are optimised over the whole scenario. This is the lower bound that the MPC and the
closed-form laws are measured against (compare with :func:`stage_cost_of_trajectory`).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from .. import interrupts
from ..control import ClosedLoop, Command, ControlSequence, Observation
from ..models.carfollowing import CarFollowingLaw, Proposed
from ..models.leader import LeaderProfile, PaperLeader, drive_cycle
from ..params import EVParams, ParameterError, PowertrainOptions, Units, VehicleLimits
from ..models.ego import following_ode
from ..numerics import rk4
from ..results import SimulationResult
from .following import FollowingWeights, following_stage_terms, term_names, weight_vector
from .formulation import Formulation, s9_formulation
from .problem import OCPProblem
from ..ocp_result import OCPResult
from .traffic_cost import auxiliary_controls, cost_traffic_of_trajectory
from .transcription import OCPSolver, TranscriptionOptions

#: Default wall-time limit of one OCP-D solve [s]: the whole UDDS on the 1 s grid takes ~5 s
#: (benchmarks/bench_ocp.py), so this only stops a run that has gone wrong; IPOPT's max_wall_time.
DEFAULT_TIME_LIMIT_S = 600.0
#: Seconds between two OCP-D progress lines on stderr while IPOPT iterates.
PROGRESS_EVERY_S = 3.0
#: Largest OCP-D grid solved on the caller's dt; beyond it :func:`oracle_grid_dt` coarsens to the 1 s
#: grid of the drive cycles. Measured on 2 shared cores (benchmarks/bench_ocp.py --udds-only): whole UDDS
#: at 1 s, N = 1369: 31 IPOPT iterations, 5-10 s, 0.1 GB; at the MPC's dt = 0.1 (0.088 s), N = 15 516:
#: 62 iterations, 127 s, 0.53 GB (was 15-28 min and 7.5 GB expanded to SX with second-order corrections).
#: The two optima differ (28.13 vs 29.20 on UDDS): Σ ℓ(z_k)·dt samples ℓ at each interval's start, so
#: compare costs on one grid only (the MPC comparison replays OCP-D's controls and costs them on dt).
ORACLE_MAX_INTERVALS = 2000
#: The coarse OCP-D grid [s]: the EPA cycles are sampled at 1 s (aev_ocp/data/cycles).
COARSE_GRID_S = 1.0
#: What OCP-D minimises, by formulation (OCPResult.objective_name, results.json ocp_d.objective).
OBJECTIVE_NAMES = {
    "s9": "sum_k l(z_k, a_k) dt (model guide §9)",
    "traffic": "traffic objective (aev_ocp/ocp/traffic.py, the MPC's): sum_k l(x_k, u_k) dt + terminal [J/kg]",
    "problem": "the user problem's objective: sum_k l(x_k, u_k) dt + terminal",
}


@dataclass(frozen=True)
class OracleScenario:
    """One follower behind a known leader. Model units: t_end, dt (model time), h0, v0 (model);
    V10, V20 [V]; S0 [-]; ``formulation``: the problem (:class:`aev_ocp.ocp.formulation.Formulation`, default
    model guide §9's; the traffic formulation's jerk term uses dt; own state a_prev(0) = 0). Defaults: the
    canonical scenario of model guide §9, except ``ev``'s vehicle limits (on here; :func:`canonical_scenario`
    switches them off, as scenarios/mpc_paper_single.toml does)."""

    leader: LeaderProfile = field(default_factory=PaperLeader)  # model guide §9: Table 1 leader
    t_end: float = 70.0  # model guide §9: 700 steps, t ∈ [0, 70]
    dt: float = 0.1  # model guide §9
    h0: float = 0.3  # model guide §9
    v0: float = 1.87  # model guide §9 (1.1 × 1.7)
    V10: float = 0.0  # model guide §9
    V20: float = 0.0  # model guide §9
    S0: float = 0.8  # model guide §9 / §6
    ev: EVParams = field(default_factory=EVParams)
    name: str = "canonical"
    formulation: Formulation = field(default_factory=s9_formulation)  # model guide §9

    def __post_init__(self) -> None:
        for nm in ("t_end", "dt"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"OracleScenario.{nm} = {v!r} is not allowed: must be a finite number > 0")
        n = self.t_end / self.dt
        if abs(n - round(n)) > 1e-6:
            raise ParameterError(f"OracleScenario.dt = {self.dt} must divide t_end = {self.t_end}")
        if not 0.0 <= self.S0 <= 1.0:
            raise ParameterError(f"OracleScenario.S0 = {self.S0!r} is not allowed: must be in [0, 1]")
        if not (math.isfinite(self.h0) and self.h0 > 0):
            raise ParameterError(f"OracleScenario.h0 = {self.h0!r} is not allowed: must be > 0")
        if not isinstance(self.formulation, Formulation):
            raise ParameterError(
                f"OracleScenario.formulation = {self.formulation!r} is not allowed: must be a "
                "Formulation (aev_ocp.ocp.formulation: s9_formulation(), traffic_formulation(), ...)"
            )

    @property
    def N(self) -> int:
        """Number of intervals t_end/dt."""
        return int(round(self.t_end / self.dt))

    @property
    def z0(self) -> list[float]:
        """Initial state (h, v, V1, V2, S)."""
        return [self.h0, self.v0, self.V10, self.V20, self.S0]

    def x0_of(self, pr: OCPProblem) -> list[float]:
        """The problem's initial state: z0, then its own states from the formulation's initial_values (default 0;
        a_prev = 0 is the closed loop's first ``Observation.a_prev``: no command before t = 0)."""
        own = list(pr.state_names[5:])
        return self.z0 + [float(self.formulation.initial_values.get(k, 0.0)) for k in own]

    @property
    def smooth(self) -> PowertrainOptions:
        """The formulation's η-switch smoothing (model guide §7)."""
        return self.formulation.smooth

    @property
    def weights(self) -> FollowingWeights:
        """The formulation's §9 weights."""
        return self.formulation.weights

    @property
    def objective(self) -> str:
        """The formulation's §9 objective ('heat' or 'omega', the paper's ω)."""
        return self.formulation.objective


def canonical_scenario() -> OracleScenario:
    """model guide §9 canonical scenario: Table 1 leader, h(0) = 0.3, v(0) = 1.87, S(0) = 0.8, N = 700, the
    paper's laws as printed (no vehicle limits: ``VehicleLimits(enabled=False)``) — the scenario of
    scenarios/mpc_paper_single.toml, whose costs the guides quote (tests/test_ocp_oracle.py checks the equality)."""
    return OracleScenario(ev=EVParams(limits=VehicleLimits(enabled=False)), name="canonical")


def drive_cycle_scenario(
    cycle: str = "udds",
    duration_s: float = 600.0,
    speed_unit_mps: float = 13.0,
    dt_s: float = 1.0,
    h0: float = 0.5,
    v0: float = 0.0,
) -> OracleScenario:
    """Follower behind an EPA cycle (first ``duration_s`` seconds). U = 13 m/s so that V∞·U = 25.5 m/s
    exceeds UDDS top speed 25.35 m/s (model guide §1); L = 10 m; dt_s = 1 s (the cycles are
    sampled at 1 s). h0, v0 in model units (UDDS starts at rest)."""
    units = Units(10.0, speed_unit_mps)
    leader = drive_cycle(cycle, units)
    t_end = units.time_from_si(duration_s)
    dt = units.time_from_si(dt_s)
    return OracleScenario(
        leader=leader,
        t_end=t_end,
        dt=t_end / round(t_end / dt),
        h0=h0,
        v0=v0,
        ev=EVParams(units=units),
        name=f"{cycle}_{duration_s:g}s",
    )


def leader_forecast(leader: LeaderProfile, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Oracle forecast on node times t (N+1): interval-mean speed (x_l(t_{k+1}) − x_l(t_k))/dt_k and
    v_l(t_k), both (N,) [model speed] (model guide §9)."""
    x = np.asarray(leader.position(t), float)
    return np.diff(x) / np.diff(t), leader.speed_np(t[:-1])


def oracle_problem(scn: OracleScenario) -> OCPProblem:
    """OCP-D over the whole scenario: the formulation's problem on the grid step scn.dt
    (:meth:`aev_ocp.ocp.formulation.Formulation.oracle_problem`; §9: the weights are its parameter p)."""
    return scn.formulation.oracle_problem(scn.ev, scn.dt)


def oracle_parameters(scn: OracleScenario, pr: OCPProblem | None = None) -> list[float]:
    """The global parameter p of :func:`oracle_problem` by name (§9's weights; a user problem's values)."""
    pr = pr or oracle_problem(scn)
    return scn.formulation.parameter_vector(list(pr.meta.get("parameter_names", [])))


def _step_function(scn: OracleScenario, policy: str, law: CarFollowingLaw | None, substeps: int) -> ca.Function:
    """One interval of the smoothed-η model (RK4) under a policy: 'law' (a_k = law(h_k, v_k, v_l(t_k)))
    or 'copy' (a_k drives v to the leader's next node speed); a_k clipped to the a bounds."""
    z, w = ca.SX.sym("z", 5), ca.SX.sym("w", 3)  # w = (v̄_l, v_l(t_k), v_l(t_{k+1}))
    if policy == "law" and law is not None:
        a_raw = law.accel(ca.fmax(z[0], 1e-3), z[1], w[1])
    else:
        a_raw = (w[2] - z[1]) / scn.dt
    b = scn.formulation.bounds_model(scn.ev)
    a = ca.fmin(ca.fmax(a_raw, b.a_min if b.a_min is not None else -ca.inf), b.a_max if b.a_max is not None else ca.inf)
    x, _ = rk4(lambda y: following_ode(y, a, w[0], scn.ev, scn.smooth), z, scn.dt, substeps)
    h_floor = b.h_min if b.h_min is not None else 0.0
    x = ca.vertcat(ca.fmax(x[0], h_floor), ca.fmax(x[1], 0.0), x[2:])  # keep the guess in bounds
    return ca.Function("guess_step", [z, w], [x, a])


def rollout_guess(
    scn: OracleScenario, law: CarFollowingLaw | None = None, substeps: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Initial guess for OCP-D: the closed-form ``law`` sampled per dt (a_k held over the interval),
    or, when law is None or α·dt ≥ 1 (the sampled law would oscillate), a speed copy of the leader.
    Returns X (5, N+1), U (1, N)."""
    alpha = getattr(law, "alpha", 0.0)
    policy = "law" if law is not None and alpha * scn.dt < 1.0 else "copy"
    step = _step_function(scn, policy, law, substeps)
    t = np.linspace(0.0, scn.t_end, scn.N + 1)
    vm, vh = leader_forecast(scn.leader, t)
    vnext = scn.leader.speed_np(t[1:])
    Xn, U = step.mapaccum(scn.N)(ca.DM(scn.z0), np.vstack([vm, vh, vnext]))
    return np.hstack([np.asarray(scn.z0, float).reshape(5, 1), np.asarray(Xn)]), np.asarray(U)


class _IterationReporter(ca.Callback):
    """IPOPT iteration callback of OCP-D: counts iterations and, every ``every_s`` seconds, reports
    iteration k / max_iter, objective, largest constraint violation (NLP scaling) and elapsed time."""

    def __init__(
        self, nx: int, ng: int, max_iter: int, bounds: tuple[np.ndarray, ...], time_limit_s: float | None
    ) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.max_iter, self.bounds, self.time_limit_s = nx, ng, max_iter, bounds, time_limit_s
        self.say: Callable[[str], None] | None = None
        self.every_s = PROGRESS_EVERY_S
        self.reset()
        self.construct("ocp_d_progress", {})

    def reset(self) -> None:
        """Start of a solve: iteration count and clock back to zero."""
        self.k, self.t0, self.last = -1, time.perf_counter(), -math.inf
        self.lines: list[dict[str, float]] = []

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        n = ca.nlpsol_out(i)
        if n == "f":
            return ca.Sparsity.scalar()
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: Sequence[ca.DM]) -> list[Any]:
        self.k += 1  # IPOPT calls back at iteration 0 (the initial point) and after every iteration
        now = time.perf_counter() - self.t0
        if self.say is not None and now - self.last >= self.every_s:
            self.last = now
            lbx, ubx, lbg, ubg = self.bounds
            x, g = np.asarray(arg[0]).ravel(), np.asarray(arg[2]).ravel()
            viol = max(
                float(np.max(np.maximum(lbx - x, x - ubx), initial=0.0)),
                float(np.max(np.maximum(lbg - g, g - ubg), initial=0.0)),
            )
            f = float(arg[1])
            self.lines.append({"iteration": self.k, "objective": f, "infeasibility": viol, "elapsed_s": now})
            left = (
                f", time limit {self.time_limit_s:g} s: at most {max(self.time_limit_s - now, 0.0):.0f} s left"
                if self.time_limit_s is not None
                else ""
            )
            self.say(
                f"OCP-D: iteration {self.k} / {self.max_iter}, objective {f:.6g}, infeasibility {viol:.2g}, "
                f"{now:.1f} s elapsed{left}"
            )
        return [0]


class _OracleOCPSolver(OCPSolver):
    """OCPSolver with IPOPT's wall-time limit and the progress callback (built with the solver)."""

    def __init__(self, problem: OCPProblem, options: TranscriptionOptions, time_limit_s: float | None) -> None:
        self.time_limit_s = time_limit_s
        self.reporter: _IterationReporter | None = None
        super().__init__(problem, options)

    def _ipopt_opts(self, warm: bool) -> dict[str, Any]:
        opts = super()._ipopt_opts(warm)
        # no second-order corrections: on drive cycles they made IPOPT crawl at tiny steps with the dual
        # infeasibility stuck (whole HWFET at 1 s: iteration limit 1000 reached, 106 s; US06 191
        # iterations; UDDS 60 time units at dt = 0.1: 112) where without them it converges to the same
        # optimum (objectives equal to 1e-10) in 45, 52 and 14 iterations; canonical and whole UDDS unchanged
        opts["ipopt"]["max_soc"] = 0
        if "slack_gap" in self.problem.control_names:
            # IPOPT relaxes every bound by 1e-8 (bound_relax_factor): the traffic problem's slack then sits at
            # −1e-8 wherever its constraints are inactive, each interval earning −ρ_safe·1e-8·L·T·dt, so the
            # NLP objective fell 4.5e-5 below the cost of its own trajectory (UDDS 20 time units): none here
            opts["ipopt"]["bound_relax_factor"] = 0.0
        if self.time_limit_s is not None:
            opts["ipopt"]["max_wall_time"] = float(self.time_limit_s)
        if self.reporter is None:
            self.reporter = _IterationReporter(
                self._nlp["x"].numel(),
                self._nlp["g"].numel(),
                self.options.max_iter,
                (self._lbx, self._ubx, self._lbg, self._ubg),
                self.time_limit_s,
            )
        opts["iteration_callback"] = self.reporter
        return opts


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


class OracleSolver:
    """OCP-D built once for a scenario's grid (N, dt); :meth:`solve` re-solves (warm) for new
    initial states or leaders on the same grid.

    mx_map: keep the NLP as MX calls of one mapped interval Function (default; build 0.3 s and 0.1 GB
    for the whole UDDS at 1 s instead of 6 s and 0.66 GB expanded to SX, same optimum, benchmarks/bench_ocp.py).
    time_limit_s: IPOPT's wall-time limit [s] (None: none); a solve stopped there has status 'time_limit'
    and a message that says so. progress: called with one line every ``progress_every_s`` seconds
    while IPOPT iterates, and once before and after (True: print on stderr; None/False: silent).
    """

    def __init__(
        self,
        scn: OracleScenario,
        method: str = "ms",
        rk4_substeps: int = 1,
        degree: int = 3,
        scheme: str = "radau",
        tol: float = 1e-8,
        mx_map: bool = True,
        time_limit_s: float | None = DEFAULT_TIME_LIMIT_S,
        progress: Callable[[str], None] | bool | None = None,
        progress_every_s: float = PROGRESS_EVERY_S,
        max_iter: int = 1000,
    ) -> None:
        if time_limit_s is not None and not (
            isinstance(time_limit_s, (int, float)) and math.isfinite(time_limit_s) and time_limit_s > 0
        ):
            raise ParameterError(f"OCP-D: time limit = {time_limit_s!r} s is not allowed: must be a finite number > 0")
        if not (isinstance(progress_every_s, (int, float)) and progress_every_s >= 0):
            raise ParameterError(f"OCP-D: progress_every_s = {progress_every_s!r} is not allowed: must be >= 0")
        self.scn = scn
        self.time_limit_s = time_limit_s
        self.solver = _OracleOCPSolver(
            oracle_problem(scn),
            TranscriptionOptions(
                method=method,
                N=scn.N,
                rk4_substeps=rk4_substeps,
                degree=degree,
                scheme=scheme,
                tol=tol,
                mx_map=mx_map,
                max_iter=max_iter,
            ),
            time_limit_s,
        )
        rep = self.solver.reporter
        assert rep is not None
        rep.say = _stderr if progress is True else (progress or None)
        rep.every_s = float(progress_every_s)

    @property
    def build_time_s(self) -> float:
        """Time to build the NLP and IPOPT [s]."""
        return self.solver.build_time_s

    @property
    def progress_lines(self) -> list[dict[str, float]]:
        """What the last solve reported: iteration, objective, infeasibility, elapsed_s per line."""
        return list(self.solver.reporter.lines) if self.solver.reporter is not None else []

    def solve(
        self, scn: OracleScenario | None = None, warm: bool = False, guess_law: CarFollowingLaw | None = None
    ) -> OCPResult:
        """Solve for ``scn`` (default: the scenario given at construction; must have the same N).
        Initial guess: :func:`rollout_guess` with the proposed law (or the previous solution if warm).
        A solve stopped by the time limit returns status 'time_limit' (success False) with the message
        'OCP-D stopped at the time limit of X s after k iterations; the last iterate is not optimal'."""
        scn = scn or self.scn
        if scn.N != self.scn.N:
            raise ParameterError(f"OracleSolver: scenario has N = {scn.N}, solver was built for N = {self.scn.N}")
        t = np.linspace(0.0, scn.t_end, scn.N + 1)
        vm, vh = leader_forecast(scn.leader, t)
        guess = None
        if not warm:
            X, U = rollout_guess(scn, guess_law or Proposed())
            pr = self.solver.problem
            if list(pr.state_names[5:]) == ["a_prev"]:  # a_prev = the previous a
                X = np.vstack([X, np.concatenate([[0.0], U[0]])])
            if pr.nu > 1:  # epigraph and slack controls (omega_rate, slack_gap, slack_<name>) at their optimum
                P = np.repeat(np.asarray(oracle_parameters(scn, pr), float).reshape(-1, 1), scn.N, axis=1)
                U = np.asarray(
                    auxiliary_controls(pr, require_traffic=False).map(scn.N)(X[:, :-1], U, np.vstack([vm, vh]), P)
                )
            guess = (X, U)
        rep = self.solver.reporter
        if rep is not None:
            rep.reset()
            if rep.say is not None:
                lim = f", time limit {self.time_limit_s:g} s" if self.time_limit_s is not None else ""
                rep.say(f"OCP-D: {scn.name}, N = {scn.N} intervals of dt = {scn.dt:.4g} (model time), IPOPT{lim}")
        pr = self.solver.problem
        pvec = oracle_parameters(scn, pr)
        res = self.solver.solve(
            scn.x0_of(pr),
            scn.t_end,
            p=pvec,
            w=np.vstack([vm, vh]),
            guess=guess,
            warm=warm,
            objective_name=OBJECTIVE_NAMES[scn.formulation.kind],
        )
        if res.status == "time_limit":
            res.message = (
                f"OCP-D stopped at the time limit of {self.time_limit_s:g} s after {res.iterations} "
                "iterations; the last iterate is not optimal"
            )
            res.warnings.append(res.message)
        if rep is not None and rep.say is not None:
            rep.say(
                f"OCP-D: {res.status} after {res.iterations} iterations, {res.wall_time_s:.1f} s"
                + ("" if res.success else f" ({res.message})")
            )
        res.meta.update(
            {
                "scenario": scn.name,
                "dt": scn.dt,
                "leader_speed_mean": vm,
                "leader_speed_hat": vh,
                "time_limit_s": self.time_limit_s,
                "formulation": scn.formulation.kind,
                "units": {"length_m": scn.ev.units.length_m, "speed_mps": scn.ev.units.speed_mps},
            }
        )
        f = scn.formulation
        if res.success and f.kind != "s9":  # its own objective, re-evaluated on its trajectory
            z = np.vstack([res.states[k] for k in ("h", "v", "V1", "V2", "S")])
            try:
                res.meta["cost_terms"] = cost_traffic_of_trajectory(
                    pr,
                    t,
                    z,
                    res.controls["a"],
                    np.vstack([vm, vh]),
                    p=np.asarray(pvec),
                    require_traffic=f.kind == "traffic",
                )
            except ParameterError:  # a user problem whose controls are not fixed by (x, a)
                pass
        elif res.success:
            res.meta["cost_terms"] = stage_cost_of_trajectory(
                t,
                res.states["h"],
                res.states["v"],
                res.states["V1"],
                res.states["V2"],
                res.states["S"],
                res.controls["a"],
                vh,
                f.weights,
                scn.ev,
                f.smooth,
                f.objective,
            )
        return res


def oracle_grid_dt(t_end: float, dt: float, units: Units, max_intervals: int = ORACLE_MAX_INTERVALS) -> float:
    """The OCP-D grid step [model time] for a run over [0, t_end] whose controller uses ``dt``: ``dt``
    itself when t_end/dt ≤ max_intervals; else the drive cycles' 1 s grid (COARSE_GRID_S), and
    t_end/max_intervals if even that is too fine. Adjusted to divide t_end. A coarser grid makes OCP-D
    the best control held for dt_c (an upper bound of the fine-grid optimum): callers say so."""
    if not (math.isfinite(t_end) and math.isfinite(dt) and t_end > 0 and dt > 0):
        raise ParameterError(f"OCP-D: t_end = {t_end!r} and dt = {dt!r} must be finite numbers > 0")
    step = dt
    if t_end / dt > max_intervals:
        step = max(dt, units.time_from_si(COARSE_GRID_S))
        if t_end / step > max_intervals:
            step = t_end / max_intervals
    return t_end / max(1, round(t_end / step))


def scenario_oracle(sc: Any, dt: float, formulation: Formulation | None = None) -> OracleScenario:
    """OCP-D of a loaded scenario (:class:`aev_ocp.scenarios.Scenario`): its leader, t_end,
    vehicle/pack and follower 1's h(0), v(0), S(0), on the grid of step ``dt`` [model time] (adjusted to
    divide t_end), solving ``formulation`` (default model guide §9's; pass the MPC's for its bound)."""
    n = max(1, round(sc.t_end / dt))
    return OracleScenario(
        leader=sc.leader,
        t_end=sc.t_end,
        dt=sc.t_end / n,
        h0=sc.gaps0[0],
        v0=sc.speeds0[0],
        S0=sc.ev.cell.soc0,
        ev=sc.ev,
        name=sc.name,
        formulation=formulation or s9_formulation(),
    )


#: OCP-D is solved on the controller's own grid (a bound) up to this many intervals; beyond, on the coarse 1 s
#: grid (a reference): the memory check of OCP-D. Measured (this machine, 2 shared cores): the traffic OCP-D of
#: the whole UDDS on the MPC's grid (15 516 intervals of 0.088 s) took 33 IPOPT iterations, 36 s and 0.73 GB peak
#: memory.
ORACLE_BOUND_MAX_INTERVALS = 20000


def on_grid(a: np.ndarray, dt_c: float, dt: float, t_end: float) -> np.ndarray:
    """Commands held for dt_c [model time] as a sequence on the grid of step dt: each dt interval takes the
    command of the dt_c interval holding its midpoint (a switch moves by at most dt/2). A traffic OCP-D on the
    coarse grid is replayed so (not interpolated between its nodes, which would smooth its jerk away)."""
    K = int(round(t_end / dt))
    return a[np.minimum(((np.arange(K) + 0.5) * dt // dt_c).astype(int), a.size - 1)]


class HeldPlan(ControlSequence):
    """A command sequence on the MPC's grid that never commands a reverse (a_k ≥ −v_k/dt, the MPC fallback's
    rule, and a_k ≥ 0 at a stop): a coarse OCP-D's commands moved to the MPC's grid (:func:`on_grid`) may brake
    up to dt/2 longer than planned at a stop, which made the exact plant's speed negative (UDDS-300 s at t = 153)."""

    def command(self, obs: Observation) -> Command:
        a, v = float(self.a[int(round(obs.t / self.dt))]), float(obs.z[1])
        # at a stop (v < 1e-9) no braking at all: −v/dt there would shrink v geometrically towards 0 without
        # reaching it (2e-137 at t = 1171 of the whole UDDS, where CVODES failed)
        return Command(max(a, 0.0) if v < 1e-9 else max(a, -v / self.dt))


def replay(
    res: OCPResult,
    scn: OracleScenario,
    hold_dt: float | None = None,
    progress: Callable[[float, float], None] | None = None,
) -> SimulationResult:
    """OCP-D's optimal controls ``res`` (solved for ``scn``) replayed open loop through the exact plant
    (aev_ocp.control.ClosedLoop: CVODES, exact η switch, the vehicle's limits) from scn's initial state: held
    over scn.dt, or, ``hold_dt`` [model time] given, moved to the grid of that step (:func:`on_grid`,
    :class:`HeldPlan`: never a reverse command; a coarse traffic OCP-D, whose jerk is costed on the MPC's grid)."""
    a_opt = np.asarray(res.controls["a"], float).ravel()
    seq = (
        HeldPlan(tuple(on_grid(a_opt, scn.dt, hold_dt, scn.t_end)), hold_dt, "ocp-d")
        if hold_dt is not None
        else ControlSequence(tuple(a_opt), scn.dt, "ocp-d")
    )
    return ClosedLoop(scn.leader, [seq], scn.ev).run([scn.h0], [scn.v0], scn.t_end, soc0=scn.S0, progress=progress)


@dataclass
class SolvedAndReplayed:
    """OCP-D of a scenario's follower solved (``result``, on the grid of ``scenario``) and its optimal controls
    replayed through the exact plant on the controller's grid (``replay``; None when the solve failed).
    ``coarse``: solved on a coarser grid than the controller's dt (a reference, never a bound on that grid)."""

    scenario: OracleScenario
    result: OCPResult
    replay: SimulationResult | None
    coarse: bool


def ocpd_scenario(sc: Any, dt: float, formulation: Formulation, max_intervals: int | None = None) -> OracleScenario:
    """The OCP-D of :func:`solve_and_replay`: ``formulation`` over the loaded scenario ``sc`` on the grid of step
    ``dt`` [model time], or the coarse grid when that has more than ``max_intervals`` (default
    :data:`ORACLE_BOUND_MAX_INTERVALS`) intervals."""
    n_max = ORACLE_BOUND_MAX_INTERVALS if max_intervals is None else max_intervals
    return scenario_oracle(sc, oracle_grid_dt(sc.t_end, dt, sc.units, max_intervals=n_max), formulation)


#: A bound's cost may exceed a run's by this fraction (the exact plant vs the optimiser's RK4 and smoothed η
#: switch; measured: 5e-7 on OCP-D's own replay); more and the OCP-D column is a 'reference', with a warning.
BOUND_RTOL = 1e-4


def bound_role(cost: float, metrics: dict[str, list[dict[str, Any]]], key: str) -> tuple[str, str]:
    """('bound', '') when the OCP-D optimum ``cost`` (same formulation, the MPC's grid) is at most every whole
    run's ``key`` cost of follower 1 (``metrics``: {run label: [follower metrics]}, within BOUND_RTOL), else
    ('reference', the warning naming the run). The check of ``aev-ocp mpc`` and of a study's OCP-D row."""
    for lab, ms in metrics.items():
        c = ms[0].get(key)
        if c is None or not math.isfinite(float(c)) or not math.isfinite(cost):
            continue
        if cost > float(c) + BOUND_RTOL * abs(float(c)):
            return "reference", (
                f"OCP-D's {key} {cost:.6g} exceeds run {lab}'s {float(c):.6g}: it is not a lower "
                "bound of it and is labelled 'reference'"
            )
    return ("bound", "") if math.isfinite(cost) else ("reference", "")


def solve_and_replay(
    sc: Any,
    dt: float,
    formulation: Formulation,
    *,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    progress: Callable[[str], None] | None = None,
    replay_progress: Callable[[float, float], None] | None = None,
    max_intervals: int | None = None,
) -> SolvedAndReplayed:
    """OCP-D of ``formulation`` over a loaded scenario ``sc`` (its leader, horizon and follower 1) on the
    controller's grid of step ``dt`` [model time] — or, a run longer than ``max_intervals`` (default
    :data:`ORACLE_BOUND_MAX_INTERVALS`) intervals (the memory check), on the coarse 1 s grid
    (:func:`oracle_grid_dt`) — then the optimum replayed through the exact plant on
    the grid of step dt (:func:`replay`; a coarse §9 optimum is held over its own grid). The one OCP-D
    solve-and-replay of ``aev-ocp mpc``, studies and
    ``reproduce``. ``time_limit_s``: IPOPT's wall-time limit [s]; ``progress``: IPOPT's progress lines;
    ``replay_progress``: the replay's (t, t_end)."""
    scn = ocpd_scenario(sc, dt, formulation, max_intervals)
    res = OracleSolver(scn, progress=progress, time_limit_s=time_limit_s).solve()
    interrupts.check()  # IPOPT turns Ctrl-C into a failed solve
    coarse = abs(scn.dt - dt) > 1e-9 * dt
    if not res.success:
        return SolvedAndReplayed(scn, res, None, coarse)
    if progress is not None:
        progress("OCP-D: replaying its controls through the exact plant")
    hold = dt if coarse and formulation.kind == "traffic" else None
    return SolvedAndReplayed(scn, res, replay(res, scn, hold, replay_progress), coarse)


def stage_cost_of_trajectory(
    t: np.ndarray,
    h: np.ndarray,
    v: np.ndarray,
    V1: np.ndarray,
    V2: np.ndarray,
    S: np.ndarray,
    a: np.ndarray,
    v_l_hat: np.ndarray,
    weights: FollowingWeights | None = None,
    ev: EVParams | None = None,
    smooth: PowertrainOptions | None = PowertrainOptions(),
    objective: str = "heat",
) -> dict[str, float]:
    """The §9 cost Σ_k ℓ(z_k, a_k)·dt_k of a sampled trajectory, for comparing any controller with
    the OCP-D lower bound.

    t: node times t_0 … t_N [model time] (N+1); h, v [model], V1, V2 [V], S [-]: states at the nodes
    (at least the first N are used); a: acceleration held on [t_k, t_{k+1}) [model] (N); v_l_hat:
    leader speed v_l(t_k) at the start of each interval [model] (N). weights/ev: as in the OCP
    (defaults model guide §9). smooth: η-switch smoothing used in Q_pack (default the optimiser's,
    model guide §7; None = exact switch). Returns total and the four weighted terms, each Σ·dt.
    """
    weights, ev = weights or FollowingWeights(), ev or EVParams()
    t = np.asarray(t, float).ravel()
    N = t.size - 1
    a = np.asarray(a, float).ravel()
    vl = np.asarray(v_l_hat, float).ravel()
    if N < 1 or a.size != N or vl.size != N:
        raise ParameterError(
            f"stage_cost_of_trajectory: t has {t.size} nodes, so a and v_l_hat need {N} "
            f"values (got a: {a.size}, v_l_hat: {vl.size})"
        )
    Z = []
    for nm, arr in (("h", h), ("v", v), ("V1", V1), ("V2", V2), ("S", S)):
        arr = np.asarray(arr, float).ravel()
        if arr.size < N:
            raise ParameterError(f"stage_cost_of_trajectory: {nm} has {arr.size} values, need at least {N}")
        Z.append(arr[:N])
    z, u, vh = ca.SX.sym("z", 5), ca.SX.sym("a"), ca.SX.sym("vh")
    terms = following_stage_terms(z, u, vh, ev, smooth, objective)
    names = term_names(objective)
    wt = weight_vector(weights)
    f = ca.Function("ell_terms", [z, u, vh], [ca.vertcat(*[w * terms[nm] for w, nm in zip(wt, names)])]).map(N)
    vals = np.asarray(f(np.vstack(Z), a.reshape(1, -1), vl.reshape(1, -1)))
    dt = np.diff(t)
    out = {nm: float(vals[i] @ dt) for i, nm in enumerate(names)}
    out["total"] = float(sum(out[nm] for nm in names))
    return out


def solve_oracle(scn: OracleScenario | None = None, method: str = "ms", **kw: Any) -> OCPResult:
    """Build and solve OCP-D once (default: canonical scenario)."""
    return OracleSolver(scn or canonical_scenario(), method=method, **kw).solve()


def stage_cost_of_result(
    r: Any,
    i: int,
    dt: float,
    weights: FollowingWeights | None = None,
    smooth: PowertrainOptions | None = PowertrainOptions(),
    objective: str = "heat",
) -> float:
    """The §9 cost of follower i of a :class:`aev_ocp.results.SimulationResult`, on the grid of step dt
    [model time] from the result's first time: states, a_k and the w_r term's v̂_l(t_k) (its leader's
    speed) are the result's samples interpolated at the nodes (exact where the nodes are samples)."""
    K = int(round((r.t[-1] - r.t[0]) / dt))
    tg = np.linspace(r.t[0], r.t[0] + K * dt, K + 1)
    f = lambda y: np.interp(tg, r.t, y)  # noqa: E731
    vl = r.leader_speed if i == 0 else r.speed[:, i - 1]
    return stage_cost_of_trajectory(
        tg,
        f(r.gap[:, i]),
        f(r.speed[:, i]),
        f(r.V1[:, i]),
        f(r.V2[:, i]),
        f(r.S[:, i]),
        f(r.accel[:, i])[:-1],
        f(vl)[:-1],
        weights,
        r.ev,
        smooth,
        objective,
    )["total"]

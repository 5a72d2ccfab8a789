"""MPC solver settings (model guide §9), validated in one place (the problem: :mod:`aev_ocp.ocp.formulation`).

Every option lives in :class:`MPCSettings`, a frozen dataclass whose fields declare their type and
range (:func:`aev_ocp.params.spec`); the ``[mpc]`` scenario table reads those declarations. An invalid value raises
:class:`aev_ocp.params.ParameterError` naming the option (``MPCSettings.N = 0 is not allowed: ...``).
Model units throughout (model guide §1): ``dt`` in model time units (0.1 = 0.2 s at the default units).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

from ..params import ParameterError, spec, validate_fields

#: Solver paths. 'ipopt': warm-started IPOPT (default). 'sqp': sqpmethod (exact Hessian, qpsol
#: ``qp_solver``) warm-started from the shifted previous solution after a cold IPOPT first solve.
#: (FATROP was tried: CasADi 3.8.2's interface raised 'fatrop inf' on this NLP, so it is not offered.)
#: 'ipopt-cold': IPOPT from the closed-form-law guess at every step (the benchmark baseline).
#: 'rti': real-time iteration — ``rti_iterations`` (default 1) full SQP steps per control step from the
#: shifted previous solution: one QP (exact Lagrangian Hessian, linearised constraints) built by a
#: stage-wise (optionally C-compiled) function and solved by ``qp_solver`` through ``ca.conic``; no
#: line search. The applied control's path constraints (current, map) are checked on the exact model.
#: The 'rti' path never calls IPOPT: its first step and the step after a failure start from the
#: closed-form law rolled out over the horizon (``rti_cold_iterations`` SQP steps), so no step takes seconds.
SOLVER_PATHS = ("ipopt", "sqp", "ipopt-cold", "rti")
#: The 'rti' path's QP Hessian: 'projected' (default): the exact Lagrangian Hessian's diagonal blocks
#: projected onto the PD cone (eigenvalues raised to a floor), so every QP is convex; 'exact': as computed
#: (the §9 scenarios state it, so their numbers stay as published; an indefinite block can then stall HPIPM;
#: with qp_solver 'riccati' a QP that fails with the exact Hessian is re-solved once with the projected blocks,
#: as the interior point needs a convex QP).
RTI_HESSIANS = ("projected", "exact")
#: QP solvers. 'riccati': aev_ocp's own structure-exploiting interior point (aev_ocp/c/ocp_qp.c, Riccati
#: recursion over the stages), the 'rti' path only; the whole step is then one compiled C library, the one
#: `aev-ocp mpc-export` writes (mpc/cstep.py; compiled whatever ``codegen`` says: ocp_qp.c is C). The others are
#: CasADi's ca.conic / qpsol plugins (the 'rti' path's Python step, mpc/rti.py). 'auto' (default): 'riccati' on
#: the 'rti' path with codegen, 'hpipm' without codegen and on the 'sqp' path (MPCSettings.qp).
QP_SOLVERS = ("auto", "riccati", "qrqp", "osqp", "hpipm", "qpoases", "proxqp")
#: What bounds one MPC step (``MPCSettings.budget``). 'counted' (default, simulation): iteration limits alone
#: (rti_cold_iterations / rti_iterations SQP steps, the QP solver's own iteration cap, IPOPT's and sqpmethod's
#: max_iter), so a run's result never depends on how busy the machine is; the wall time is measured and reported,
#: never used to decide. 'wall' (real time: hardware-in-the-loop, a controller on a car): additionally a step of the
#: 'rti' path longer than ``max_step_ms`` is not applied (cause 'budget'), and IPOPT stops at ``max_cpu_time_s``.
BUDGETS = ("counted", "wall")
PREDICTOR_NAMES = ("oracle", "constant-velocity", "constant-acceleration", "decaying-acceleration", "cooperative")


@dataclass(frozen=True)
class MPCSettings:
    """Solver options of the receding-horizon controller (which problem it solves is a
    :class:`aev_ocp.ocp.formulation.Formulation`, given beside these: ``MPCVehicle(settings, formulation=...)``;
    the default is the traffic formulation).

    budget: what bounds a step (BUDGETS): 'counted' (default: a simulation's result never depends on the
    machine's load) bounds it by iteration counts only (rti_cold_iterations, rti_iterations, the QP solver's
    iteration cap, max_iter); 'wall' (real time, hardware-in-the-loop) adds the wall clock: max_step_ms and
    max_cpu_time_s then decide too. The wall time of every step is measured and reported either way;
    max_step_ms: wall-clock budget of one step [ms], with budget 'wall' only
    (the 'rti' paths: a step that takes longer is not applied: the fallback is, cause 'budget', and the
    late plan warm-starts the next step; the 'ipopt' and 'sqp' paths are bounded by max_cpu_time_s, IPOPT's
    wall-time limit); rti_cold_iterations: SQP steps of the 'rti' path when it starts cold;
    rti_hessian: 'projected' or 'exact' (RTI_HESSIANS);
    N: horizon intervals; dt: interval length [model time];
    rk4_substeps: RK4 steps per interval in the prediction model; solver: one of SOLVER_PATHS;
    qp_solver: QP solver of the 'sqp' and 'rti' paths; rti_iterations: SQP iterations per step of the
    'rti' path (1 = real-time iteration; fewer when the step falls below tol); codegen: compile the
    NLP functions to C with gcc
    (falls back to the interpreted path with a warning when no compiler is found); tol: optimality
    tolerance; max_iter: iteration limit per solve; max_cpu_time_s: IPOPT's wall-time limit per solve [s]
    (its ``max_wall_time``; with budget 'wall' only);
    predictor: leader forecast (PREDICTOR_NAMES); predictor_window: measured samples used by the
    constant-acceleration predictor; verbose: solver console output (silent by default).
    """

    N: int = spec(25, kind="integer", ge=1)  # our choice (§9: 40, stated by its scenarios): with the traffic
    # formulation's terminal cost 40 intervals saved nothing (UDDS-300 s: 2247 vs 2249 J/km) and cost ~60 % more time
    dt: float = spec(0.1, gt=0)  # model guide §9 (0.2 s at L = 10 m, U = 5 m/s)
    rk4_substeps: int = spec(1, kind="integer", ge=1)
    solver: str = spec("rti", kind="choice", choices=SOLVER_PATHS)  # real-time iteration (issue 8: ≤ 2 ms/step)
    qp_solver: str = spec("auto", kind="choice", choices=QP_SOLVERS)  # issue 12: riccati on the rti path
    codegen: bool = spec(True, kind="bool")  # C-compiled QP data (falls back to interpreted without gcc)
    tol: float = spec(1e-8, gt=0)
    max_iter: int = spec(200, kind="integer", ge=1)
    rti_iterations: int = spec(1, kind="integer", ge=1)
    rti_cold_iterations: int = spec(5, kind="integer", ge=1)  # our choice: converges the law's rollout
    rti_hessian: str = spec("projected", kind="choice", choices=RTI_HESSIANS)
    # 'counted': two runs of the same code under different load gave different tables while the wall clock decided
    budget: str = spec("counted", kind="choice", choices=BUDGETS)
    max_step_ms: float = spec(100.0, gt=0)  # our choice: 10x the p99 target; budget 'wall' only (class docstring)
    max_cpu_time_s: float = spec(10.0, gt=0)  # budget 'wall' only
    # a forecast a car can make: the leader's measured speed and acceleration, the acceleration fading with
    # tau = 2 s (our choice: the best measured-only predictor on the drive cycles, benchmarks/bench_mpc_cycles.py);
    # model guide §9's canonical problem uses the oracle, which its scenarios state
    predictor: str = spec("decaying-acceleration", kind="choice", choices=PREDICTOR_NAMES)
    predictor_window: int = spec(5, kind="integer", ge=2)
    verbose: bool = spec(False, kind="bool")

    def __post_init__(self) -> None:
        validate_fields(self)
        if self.qp_solver == "riccati" and self.solver == "sqp":
            raise ParameterError(
                "MPCSettings.qp_solver = 'riccati' is the 'rti' path's QP solver (aev_ocp/c/ocp_qp.c); "
                "the 'sqp' path (CasADi's sqpmethod) takes a CasADi QP solver: set qp_solver to one "
                f"of {[q for q in QP_SOLVERS if q != 'riccati']}"
            )

    @property
    def qp(self) -> str:
        """The QP solver in use: ``qp_solver``, with 'auto' resolved ('riccati' on the 'rti' path with codegen: the
        compiled step; else 'hpipm')."""
        if self.qp_solver != "auto":
            return self.qp_solver
        return "riccati" if self.solver == "rti" and self.codegen else "hpipm"

    def over_budget(self, dt_wall_s: float) -> bool:
        """Whether a step that took ``dt_wall_s`` [s] of wall time is late, i.e. not applied (cause 'budget'): only
        with budget 'wall' and longer than ``max_step_ms``; with budget 'counted' never (iteration limits bound
        the step, the clock decides nothing)."""
        return self.budget == "wall" and dt_wall_s * 1e3 > self.max_step_ms

    @property
    def horizon(self) -> float:
        """Prediction horizon N·dt [model time]."""
        return self.N * self.dt

    def with_(self, **changes: Any) -> "MPCSettings":
        """A validated copy with some options changed."""
        moved = sorted(set(changes) & MOVED_TO_FORMULATION)
        if moved:
            raise ParameterError(
                f"MPCSettings.{moved[0]} is not a solver option: the problem's parameters live in a "
                "Formulation (aev_ocp.ocp.formulation: s9_formulation(...), traffic_formulation(...))"
            )
        return replace(self, **changes)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MPCSettings":
        """Build from a flat dict of MPCSettings fields. Unknown keys raise ParameterError naming the key
        (the formulation's keys: :func:`aev_ocp.ocp.formulation.formulation_from_dict`)."""
        own = {f.name for f in fields(cls)}
        bad = [k for k in d if k not in own]
        if bad:
            raise ParameterError(f"MPC option {bad[0]!r} is unknown: known options are {sorted(own)}")
        return cls(**d)


#: Former MPCSettings fields that describe the problem, now a Formulation's (a clear error instead of a TypeError).
MOVED_TO_FORMULATION = {"formulation", "traffic", "weights", "bounds", "objective", "smooth"}

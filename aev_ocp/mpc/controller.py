"""The receding-horizon controller of model guide §9, built ONCE as a parametric NLP from an
:class:`~aev_ocp.ocp.problem.OCPProblem` — by default the §9 problem of
:func:`aev_ocp.ocp.following.following_problem`, the same description OCP-D is built from — and
discretised by the same interval function as the whole-horizon transcription
(:func:`aev_ocp.ocp.transcription.interval_function`, multiple shooting, RK4):

    min Σ_k s_k J_k(z_k, u_k)  (J_k = stage cost·dt + integral cost over interval k) + terminal cost
    s.t. z_{k+1} = F(z_k, u_k, w_k, p), path constraints at nodes 0…N−1, simple bounds at 1…N.

NLP parameters (nothing is rebuilt between solves or weight sweeps): the per-interval stage
parameters w_k (the forecast), the problem's parameters p (for §9 the four weights) and per-interval
stage weights s_k (default 1). The measured initial state is fixed by equal simple bounds. Decision
variables are ordered (z_0, u_0, z_1, u_1, …, z_N) and constraints stage by stage, so the KKT system
is banded and HPIPM detects the OCP structure.

Formulations (:class:`aev_ocp.ocp.formulation.Formulation`, one object for the problem and what follows from
it): 'traffic' (default, :mod:`aev_ocp.ocp.traffic`), 's9' (model guide §9) or a user problem. The 'rti' path
(:mod:`aev_ocp.mpc.rti`) projects each diagonal block of the exact Lagrangian Hessian onto the PD cone
(``rti_hessian = 'projected'``), handles terminal costs, starts cold by RTI iterations from the closed-form law's
rollout (traffic; §9 keeps its cold IPOPT first step), and, in real time only (``budget = 'wall'``), discards a step
that took longer than ``max_step_ms`` (status 'budget: …', the policy applies its fallback); in simulation (``budget =
'counted'``, the default) iteration limits alone bound a step, so no result depends on the machine's load. Every
failed step's status starts with its cause ('QP failed', 'budget', 'path constraint', 'exception', or the NLP
solver's status; :mod:`aev_ocp.mpc.fallback`).

The controller's parts, one module each: the horizon NLP and its NLP solvers (:mod:`aev_ocp.mpc.nlp`), the
real-time iteration (:mod:`aev_ocp.mpc.rti`), failed and late steps (:mod:`aev_ocp.mpc.fallback`), what a solve
returns (:mod:`aev_ocp.mpc.solution`); this module builds them from the formulation and runs a step.

A problem used in the closed loop keeps the §9 layout in front: states (h, v, V1, V2, S) (measured),
control a, stage parameters (v̄_l, v̂_l) (the forecast). Further states are the controller's own
(initialised from ``initial_values`` and then from its previous plan), further controls (e.g. the
slacks of soft constraints) start at 0, further stage or global parameters take ``parameter_values``.
"""

from __future__ import annotations

import contextlib
import time
import warnings
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ..models.battery import piecewise_ocv
from ..models.carfollowing import CarFollowingLaw, Proposed
from ..models.ego import STATE_NAMES
from ..ocp.following import PACK_TEMPERATURE_KEY, WEIGHT_NAMES, FollowingWeights, weight_vector
from ..ocp.formulation import DEFAULT_FORMULATION, Formulation, problem_formulation
from ..ocp.problem import OCPProblem, ProblemBuilder
from ..params import EVParams, ParameterError
from ..plant import PLAN_TOLERANCE
from .fallback import budget_status, cold_start_falls_back_to_ipopt, failed_solution
from .nlp import HorizonNLP, shared_horizon_nlp
from .cstep import CompiledStep
from .nlp import rti_stage_functions
from .rti import HPIPM_INF_TRAFFIC, RTI_HESSIAN_FLOOR, RTIStep, check_rti_qp, project_pd, qp_options, solve_compiled
from .settings import MPCSettings
from .solution import MPCSolution

__all__ = [
    "MPCController",
    "MPCSolution",
    "ParameterLayout",
    "NZ",
    "RTI_HESSIAN_FLOOR",
    "HPIPM_INF_TRAFFIC",
    "default_problem",
    "resolve_formulation",
]

NZ = len(STATE_NAMES)  # measured states (h, v, V1, V2, S) at the front of every MPC problem
_project_pd = project_pd  # (the names these had here before the split)
_qp_options = qp_options


@dataclass(frozen=True)
class ParameterLayout:
    """How a controller fills the NLP parameter vector beyond the forecast: ``n_weights`` §9 weights first (from
    the formulation, or a solve's ``weights``), then the values ``p_extra`` of the problem's further parameters;
    ``w_extra``: the values of further stage parameters (every interval); ``x_own0``: the own states' initial
    values (beyond the measured (h, v, V1, V2, S))."""

    n_weights: int
    p_extra: np.ndarray
    w_extra: np.ndarray
    x_own0: np.ndarray


def default_problem(
    ev: EVParams, s: MPCSettings, formulation: Formulation | None = None
) -> OCPProblem | ProblemBuilder:
    """The MPC problem of a formulation (default: the traffic formulation) on the settings' interval dt."""
    return (formulation or DEFAULT_FORMULATION).builder(ev, s.dt)


def resolve_formulation(
    formulation: Formulation | None,
    problem: OCPProblem | ProblemBuilder | None,
    parameter_values: dict[str, float] | None = None,
    initial_values: dict[str, float] | None = None,
) -> Formulation:
    """The one formulation of an MPC: ``formulation``, or a user ``problem`` made one (every derived item then
    follows the problem), or the default (traffic). Both at once is a ParameterError."""
    if problem is not None:
        if formulation is not None:
            raise ParameterError(
                "MPC: give problem= or formulation=, not both (a user problem is its own "
                "formulation: aev_ocp.ocp.formulation.problem_formulation(problem))"
            )
        return problem_formulation(problem, parameter_values, initial_values)
    f = formulation or DEFAULT_FORMULATION
    if not isinstance(f, Formulation):
        raise ParameterError(f"MPC: formulation must be a Formulation, got {type(f).__name__}")
    if (parameter_values or initial_values) and f.kind == "problem":
        f = f.with_(
            parameter_values={**f.parameter_values, **(parameter_values or {})},
            initial_values={**f.initial_values, **(initial_values or {})},
        )
    elif parameter_values or initial_values:
        raise ParameterError(
            f"MPC: parameter_values/initial_values are for a user problem, not the {f.name} formulation"
        )
    return f


class MPCController:
    """The MPC for one vehicle: build once, then :meth:`solve` at every step (warm-started).

    ``formulation``: the problem and everything derived from it (:class:`aev_ocp.ocp.formulation.Formulation`;
    default the traffic formulation); ``problem``: a user :class:`OCPProblem` or :class:`ProblemBuilder`
    instead (it becomes the formulation); ``guess_law``: closed-form law rolled out over the
    horizon as the cold-start guess (default the paper's proposed law); ``parameter_values`` /
    ``initial_values``: values of a user problem's extra parameters / own states by name; ``export_only``: a
    controller built to be exported, whose cold IPOPT is built on its first solve, if any, not with it.
    """

    def __init__(
        self,
        settings: MPCSettings | None = None,
        ev: EVParams | None = None,
        guess_law: CarFollowingLaw | None = None,
        problem: OCPProblem | ProblemBuilder | None = None,
        parameter_values: dict[str, float] | None = None,
        initial_values: dict[str, float] | None = None,
        formulation: Formulation | None = None,
        *,
        export_only: bool = False,
    ) -> None:
        self.settings = settings or MPCSettings()
        #: built to be exported (:func:`aev_ocp.mpc.export.export_controller_settings`): its cold IPOPT, which an export
        #: never runs, is built on its first use instead of with the controller (~1 s at N = 40)
        self.export_only = export_only
        if not isinstance(self.settings, MPCSettings):
            raise ParameterError(f"MPCController: settings must be an MPCSettings, got {type(settings).__name__}")
        self.ev = ev or EVParams()
        self.guess_law = guess_law or Proposed()
        s = self.settings
        self.formulation = f = resolve_formulation(formulation, problem, parameter_values, initial_values)
        # rti: a built-in problem with the OCV as comparisons (same values, cheaper Hessians: models/battery.py)
        with piecewise_ocv() if s.solver == "rti" and f.kind != "problem" else contextlib.nullcontext():
            # where C is generated (codegen, or the rti path's compiled step), the vehicle's numbers are parameters
            # of the NLP, not constants of the C: one library per structure (issue 40); interpreted paths keep them
            # as numbers (nothing to share, and the expressions CasADi folds stay as they were)
            compiled = s.codegen or s.solver == "rti"
            self.problem = f.mpc_problem(self.ev, s.dt) if compiled else f.build(self.ev, s.dt)
        self.layout = self._check_layout(dict(f.parameter_values), dict(f.initial_values))
        self.codegen_active = False
        #: the compiled whole step (export.CStep) of the rti path with qp_solver 'riccati' (None otherwise)
        self.compiled_step: Any = None
        #: the Python real-time iteration (rti.RTIStep) of the rti path with a ca.conic QP solver
        self.rti: RTIStep | None = None
        #: the QP solver that runs ('riccati', a ca.conic/qpsol plugin, or '' for the IPOPT paths)
        self.qp_in_use = self.settings.qp if self.settings.solver in ("rti", "sqp") else ""
        # the 'rti' path starts cold by RTI from the law's rollout; §9 (and a problem built from it) keeps
        # its cold IPOPT first step (model guide §9 numbers unchanged): the formulation says which
        self.rti_cold_start = f.rti_cold_start
        t0 = time.perf_counter()
        # a built-in formulation's compiled-path problem is the one Formulation.mpc_problem keeps: controllers of
        # equal settings and guess law share its horizon NLP (and the step's generated C); a user problem, or one
        # built with the numbers in (a fresh object per controller), gets its own
        shared = compiled and f.kind != "problem"
        self.nlp = (
            shared_horizon_nlp(self.problem, s, self.guess_law)
            if shared
            else HorizonNLP(self.problem, s, self.guess_law)
        )
        self._build_solvers()
        self.build_time_s = time.perf_counter() - t0
        #: the warm start of the next solve (x, lam_x, lam_g, X1: the plan's node 1), None: the next solve is cold
        self.warm: dict[str, np.ndarray] | None = None

    def _check_layout(self, pvals: dict[str, float], xinit: dict[str, float]) -> ParameterLayout:
        """The closed-loop layout (see the module docstring) and the values of extra names."""
        pr = self.problem
        if tuple(pr.state_names[:NZ]) != STATE_NAMES or pr.control_names[0] != "a" or pr.nw < 2:
            raise ParameterError(
                f"MPCController: problem {pr.name!r} must start with states {STATE_NAMES}, "
                "control 'a' and stage parameters (v_l_mean, v_l_hat)"
            )
        if self.settings.solver == "rti" and pr.terminal is not None:
            raise ParameterError(
                "MPCSettings.solver = 'rti' does not handle terminal constraints (terminal costs "
                "are fine; make the constraint a soft terminal cost): use 'ipopt' or 'sqp'"
            )
        pnames = list(pr.meta.get("parameter_names", WEIGHT_NAMES[: pr.np_]))
        wnames = list(pr.meta.get("stage_parameter_names", ["v_l_mean", "v_l_hat"]))
        n_weights = sum(1 for k in pnames[: len(WEIGHT_NAMES)] if k in WEIGHT_NAMES)
        extra_p, extra_w = pnames[n_weights:], wnames[2:]
        # parameters with a default (a built-in problem's vehicle numbers: ProblemBuilder.parameter's value)
        pvals = {**pr.meta.get("parameter_defaults", {}), **pvals}
        unknown = sorted(set(pvals) - set(extra_p) - set(extra_w))
        missing = [k for k in extra_p + extra_w if k not in pvals]
        if unknown or missing:
            raise ParameterError(
                f"MPCController: parameter_values must give exactly {extra_p + extra_w}"
                f"{'; unknown ' + str(unknown) if unknown else ''}"
                f"{'; missing ' + str(missing) if missing else ''}"
            )
        own = list(pr.state_names[NZ:])
        bad = sorted(set(xinit) - set(own))
        if bad:
            raise ParameterError(f"MPCController: initial_values names unknown states {bad}; own states are {own}")
        # the pack temperature [K] starts from the thermal model's T(0) unless measured (the policy's own)
        Tn = self.temperature_state_name
        start = {Tn: self.ev.thermal.initial_K} if Tn is not None else {}
        return ParameterLayout(
            n_weights,
            np.array([float(pvals[k]) for k in extra_p]),
            np.array([float(pvals[k]) for k in extra_w]),
            np.array([float(xinit.get(k, start.get(k, 0.0))) for k in own]),
        )

    @property
    def temperature_state_name(self) -> str | None:
        """The own state that is the pack temperature [K] (marked by ocp.following.add_temperature_state, e.g.
        TemperatureTerms.temperature_state), or None: a state merely named 'T' is not taken for it."""
        name = (self.problem.meta or {}).get(PACK_TEMPERATURE_KEY)
        return name if name in self.problem.state_names[NZ:] else None

    @property
    def has_temperature(self) -> bool:
        """The prediction model carries the pack temperature [K] (TemperatureTerms.temperature_state)."""
        return self.temperature_state_name is not None

    # ------------------------------------------------------------------ the horizon NLP's interface
    @property
    def nx(self) -> int:
        """States of the problem (the measured five, then the controller's own)."""
        return self.nlp.nx

    @property
    def nu(self) -> int:
        """Controls of the problem (a first)."""
        return self.nlp.nu

    @property
    def nv(self) -> int:
        """Length of the NLP vector."""
        return self.nlp.nv

    @property
    def ng(self) -> int:
        """Constraint rows of the NLP."""
        return self.nlp.ng

    @property
    def np_(self) -> int:
        """Length of the NLP parameter vector."""
        return self.nlp.np_

    @property
    def x_scale(self) -> np.ndarray:
        """State scaling (NLP variable = state / x_scale)."""
        return self.nlp.x_scale

    @property
    def u_scale(self) -> np.ndarray:
        """Control scaling."""
        return self.nlp.u_scale

    @property
    def F(self) -> ca.Function:
        """The interval function of the transcription (scaled)."""
        return self.nlp.F

    @property
    def step(self) -> ca.Function:
        """One interval of the prediction model (z, u, w, p) -> z_next [model units]."""
        return self.nlp.step

    def rti_stage_functions(self) -> tuple[ca.Function, ca.Function]:
        """The QP of one SQP step, stage by stage (:func:`aev_ocp.mpc.rti.rti_stage_functions`)."""
        return rti_stage_functions(self.nlp)

    def constant_parameters(self) -> np.ndarray:
        """The problem's parameters p as the controller sets them (the formulation's §9 weights, then the
        further parameters' values)."""
        return np.concatenate([weight_vector(self.formulation.weights)[: self.layout.n_weights], self.layout.p_extra])

    # ------------------------------------------------------------------ solvers
    def _build_solvers(self) -> None:
        s, nlp = self.settings, self.nlp
        self._cold_ipopt: ca.Function | None = None
        self._fast: ca.Function | None = None
        if s.solver == "ipopt":
            self._fast, compiled = nlp.ipopt("mpc_ipopt_warm", warm=True)
            self.codegen_active |= compiled
        elif s.solver == "sqp":
            qp_opts = qp_options(s.qp)
            if s.qp == "osqp":
                qp_opts["warm_start_primal"] = True
            self._fast, compiled = nlp.sqp(qp_opts)
            self.codegen_active |= compiled
        elif s.solver == "rti":
            self._build_rti()
        # 'ipopt-cold': the cold IPOPT at every step
        if not self.export_only and not (s.solver == "rti" and (self.rti_cold_start or self.compiled_step is not None)):
            # the cold IPOPT is built with the controller only where a cold start runs it: the rti path of a
            # formulation that starts cold by RTI (traffic) never does (its failed steps start cold by RTI again),
            # and §9's compiled step starts cold by itself, handing over to the cold IPOPT only after a cold start
            # that failed (then it is built on that first use, :attr:`_cold`, before the step's clock starts), so
            # neither generates nor compiles its NLP up front (issue 40: one mpc_nlp_ipopt library fewer each)
            self._cold_ipopt, compiled = nlp.ipopt("mpc_ipopt_cold", warm=False)
            self.codegen_active |= compiled

    def _build_rti(self) -> None:
        """The rti path: with qp_solver 'riccati' the compiled whole step (the exported C, mpc/export.py,
        ocp_qp.c), whatever ``codegen`` says (ocp_qp.c is C anyway); else, or when it cannot be built (no C
        compiler), :class:`aev_ocp.mpc.rti.RTIStep` with a ca.conic QP solver (HPIPM for 'riccati')."""
        s = self.settings
        check_rti_qp(s.qp, self.formulation.family)
        qp_plugin = s.qp
        if s.qp_solver == "auto" and self.has_temperature:
            # the compiled Riccati interior point (absolute tolerances 1e-10) fails on the QPs of an active
            # temperature limit (UDDS, first 120 s, limit 0.5 mK above the ambient: 828 of 1360 steps 'QP failed');
            # HPIPM through ca.conic solves every one of them, so 'auto' picks it when T is a state
            qp_plugin = "hpipm"
        elif s.qp == "riccati":
            self.compiled_step = CompiledStep.build(self)
            if self.compiled_step is not None:
                self.codegen_active = True
                return
            warnings.warn(
                "qp_solver 'riccati' is unavailable: the compiled step could not be built; the rti path "
                "uses HPIPM through ca.conic instead",
                RuntimeWarning,
                stacklevel=4,
            )
            qp_plugin = "hpipm"
        self.qp_in_use = qp_plugin
        self.rti = RTIStep(
            self.nlp, qp_plugin, HPIPM_INF_TRAFFIC if self.formulation.family == "traffic" else None, s.codegen
        )
        self.codegen_active |= self.rti.codegen_active

    # ------------------------------------------------------------------ helpers
    def _params(self, w: np.ndarray, weights: FollowingWeights | None, stage_weights: np.ndarray | None) -> np.ndarray:
        """NLP parameter vector: stage parameters per interval (forecast, then the user's), the problem's
        parameters (the §9 weights, then the user's) and the stage weights."""
        N, lay = self.settings.N, self.layout
        wt = weight_vector(weights or self.formulation.weights)[: lay.n_weights]
        sw = np.ones(N) if stage_weights is None else np.asarray(stage_weights, float).ravel()
        if sw.size != N or not np.all(np.isfinite(sw)) or np.any(sw < 0):
            raise ParameterError(f"MPC stage_weights must be {N} finite numbers >= 0")
        W = np.vstack([w, np.repeat(lay.w_extra.reshape(-1, 1), N, axis=1)]) if lay.w_extra.size else w
        return np.concatenate([W.ravel(order="F"), wt, lay.p_extra, sw])

    def guess(self, z0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Cold-start primal guess (scaled NLP vector): the closed-form law rolled out over the horizon."""
        return self.nlp.guess(z0, p)

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X (nx, N+1), a (N,), U (nu, N)) in physical units from the scaled NLP vector."""
        return self.nlp.unpack(x)

    def reset(self) -> None:
        """Forget the warm start (the next solve starts cold from the closed-form-law guess)."""
        self.warm = None

    # ------------------------------------------------------------------ solving
    def initial_state(self, z0: np.ndarray, own: dict[str, float] | None = None) -> np.ndarray:
        """The full initial state: the measured (h, v, V1, V2, S) and the controller's own states
        (``own`` by name, else the previous plan's node 1 when warm, else ``initial_values``)."""
        z0 = np.asarray(z0, float).ravel()
        if z0.size == self.nx:
            return z0
        if z0.size != NZ:
            raise ParameterError(f"MPC: z0 must be {NZ} (h, v, V1, V2, S) or {self.nx} values, got {z0.size}")
        if self.nx == NZ:
            return z0
        x_own = (self.layout.x_own0 if self.warm is None else self.warm["X1"][NZ:]).copy()
        names = list(self.problem.state_names[NZ:])
        for k, val in (own or {}).items():
            if k in names:
                x_own[names.index(k)] = float(val)
        return np.concatenate([z0, x_own])

    def solve(
        self,
        z0: np.ndarray,
        v_mean: np.ndarray,
        v_hat: np.ndarray,
        *,
        weights: FollowingWeights | None = None,
        stage_weights: np.ndarray | None = None,
        own: dict[str, float] | None = None,
    ) -> MPCSolution:
        """Solve from the measured state z0 = (h, v, V1, V2, S) with the forecast per interval:
        v_mean (N,) interval-mean leader speed and v_hat (N,) leader speed at the interval starts
        [model speed]. ``weights`` overrides the formulation's §9 weights for this solve (no rebuild).
        ``own``: values of the controller's own states by name (see :meth:`initial_state`).
        Never raises on solver failure: returns success=False with a status."""
        s = self.settings
        N, nx = s.N, self.nx
        z0 = self.initial_state(z0, own)
        if not np.all(np.isfinite(z0)):
            raise ParameterError(f"MPC: z0 must be finite (h, v, V1, V2, S), got {z0!r}")
        vm_, vh_ = np.asarray(v_mean, float).ravel(), np.asarray(v_hat, float).ravel()
        if vm_.size != N or vh_.size != N or not (np.all(np.isfinite(vm_)) and np.all(np.isfinite(vh_))):
            raise ParameterError(
                f"MPC: the leader forecast (v_mean, v_hat) must be N = {N} finite values each, "
                f"got {vm_.size} and {vh_.size}"
            )
        p = self._params(np.vstack([vm_, vh_]), weights, stage_weights)
        if self.compiled_step is not None:
            was_cold = self.warm is None
            sol = solve_compiled(self, z0, p)
            if not cold_start_falls_back_to_ipopt(sol.success, was_cold, self.rti_cold_start, self.warm is not None):
                return sol  # a failed cold start of §9's compiled step falls back to the cold IPOPT below
        warm = self.warm is not None and s.solver != "ipopt-cold"
        if self.rti is not None and not warm and self.rti_cold_start:
            # cold real-time iteration from the closed-form law's rollout (never a cold IPOPT)
            lbx, ubx = self.nlp.lbx.copy(), self.nlp.ubx.copy()
            lbx[:nx] = ubx[:nx] = z0 / self.x_scale
            cold = {"x0": self.guess(z0, p), "lam_g0": np.zeros(self.ng), "lam_x0": np.zeros(self.nv)}
            return self.rti.solve(self, cold, p, lbx, ubx, s.rti_cold_iterations)
        lbx, ubx = self.nlp.lbx.copy(), self.nlp.ubx.copy()
        lbx[:nx] = ubx[:nx] = z0 / self.x_scale
        solver: ca.Function
        if warm:
            assert self.warm is not None
            args = self.nlp.shift(self.warm, z0, p)
            if self.rti is not None:
                return self.rti.solve(self, args, p, lbx, ubx, s.rti_iterations)
            assert self._fast is not None  # built for 'ipopt' and 'sqp', the other warm paths
            solver, path = self._fast, s.solver
        else:
            args = {"x0": self.guess(z0, p)}
            solver, path = self._cold, "ipopt-cold"
        t0 = time.perf_counter()
        try:
            out = solver(p=p, lbx=lbx, ubx=ubx, lbg=self.nlp.lbg, ubg=self.nlp.ubg, **args)
            err = None
        except RuntimeError as exc:  # e.g. NaN in a function evaluation that the solver did not catch
            out, err = None, str(exc).splitlines()[0][:200]
        dt_wall = time.perf_counter() - t0
        if out is None:
            return self.failed(f"exception: {err}", 0, dt_wall, float("inf"), path)
        st = solver.stats()
        x, g = np.asarray(out["x"]).ravel(), np.asarray(out["g"]).ravel()
        viol = self.nlp.violation(x, g, lbx, ubx)
        status = str(st.get("return_status", st.get("unified_return_status", "")))
        success = bool(st.get("success", False)) and viol < PLAN_TOLERANCE and bool(np.all(np.isfinite(x)))
        iters = int(
            st.get(
                "iter_count",
                st.get("iterations", {}).get("iter", [0])[-1] if isinstance(st.get("iterations"), dict) else 0,
            )
        )
        X, a, U = self.unpack(x)
        self.warm = (
            {
                "x": x,
                "lam_x": np.asarray(out["lam_x"]).ravel(),
                "lam_g": np.asarray(out["lam_g"]).ravel(),
                "X1": X[:, 1],
            }
            if success
            else None
        )
        if self.compiled_step is not None and self.warm is not None:
            self.compiled_step.set_warm(self.warm["x"], self.warm["lam_g"], self.warm["lam_x"])
        return MPCSolution(
            success,
            status,
            iters,
            dt_wall,
            X,
            a,
            float(out["f"]),
            viol,
            path,
            {"t_wall_solver": float(st.get("t_wall_total", float("nan")))},
            U,
        )

    @property
    def _cold(self) -> ca.Function:
        """The cold IPOPT (built with the controller where a cold start runs it; else on first use)."""
        if self._cold_ipopt is None:
            self._cold_ipopt, compiled = self.nlp.ipopt("mpc_ipopt_cold", warm=False)
            self.codegen_active |= compiled
        return self._cold_ipopt

    # ------------------------------------------------------------------ failed and late steps
    def late(self, warm: dict[str, Any], iters: int, dt_wall: float, viol: float, path: str) -> MPCSolution:
        """A valid plan that took longer than ``max_step_ms`` (``budget = 'wall'`` only, ``MPCSettings.over_budget``):
        a failure with cause 'budget' (the policy applies its fallback), but the plan (``warm``: the warm start it
        leaves) stays the next step's warm start, so one late step (e.g. a cold start) does not make every following
        step cold, and late, too."""
        sol = self.failed(budget_status(dt_wall, self.settings.max_step_ms), iters, dt_wall, viol, path)
        self.warm = warm
        return sol

    def failed(self, status: str, iters: int, dt_wall: float, viol: float, path: str) -> MPCSolution:
        """A failed step (its status starts with its cause); the next solve starts cold."""
        self.warm = None
        return failed_solution(status, iters, dt_wall, viol, path, self.nx, self.nu, self.settings.N)

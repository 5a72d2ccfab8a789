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
it): 'traffic' (default, :mod:`aev_ocp.ocp.traffic`), 's9' (model guide §9) or a user problem. The 'rti' path projects each diagonal block of the exact Lagrangian Hessian onto the PD
cone (``rti_hessian = 'projected'``, :meth:`MPCController.regularised_hessian`), handles terminal costs,
starts cold by RTI iterations from the closed-form law's rollout (traffic; §9 keeps its cold IPOPT first
step), and discards a step that took longer than ``max_step_ms`` (status 'budget: …', the policy applies
its fallback). Every failed step's status starts with its cause ('QP failed', 'budget', 'path
constraint', 'exception', or the NLP solver's status).

A problem used in the closed loop keeps the §9 layout in front: states (h, v, V1, V2, S) (measured),
control a, stage parameters (v̄_l, v̂_l) (the forecast). Further states are the controller's own
(initialised from ``initial_values`` and then from its previous plan), further controls (e.g. the
slacks of soft constraints) start at 0, further stage or global parameters take ``parameter_values``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from ..compiled import compile_shared, compiler
from ..models.battery import piecewise_ocv
from ..models.carfollowing import CarFollowingLaw, Proposed
from ..models.ego import STATE_NAMES
from ..numerics import rk4
from ..ocp.following import WEIGHT_NAMES, FollowingWeights, weight_vector
from ..ocp.formulation import DEFAULT_FORMULATION, Formulation, problem_formulation
from ..ocp.problem import OCPProblem, ProblemBuilder
from ..ocp.transcription import TranscriptionOptions, interval_function, with_discrete_update
from ..params import EVParams, ParameterError
from ..plant import PLAN_TOLERANCE
from .settings import MPCSettings

NZ = len(STATE_NAMES)  # measured states (h, v, V1, V2, S) at the front of every MPC problem


@dataclass
class MPCSolution:
    """One solve: success, status, iterations, wall time [s] of the solver call, the plan
    X (nx, N+1) and a (N,) [model units] (all controls: U (nu, N)), cost (NLP objective), max
    constraint violation (NLP units)."""

    success: bool
    status: str
    iterations: int
    solve_time_s: float
    X: np.ndarray
    a: np.ndarray
    cost: float
    violation: float
    path: str
    stats: dict[str, Any] = field(default_factory=dict)
    U: np.ndarray | None = None


_SQP_EXTRA: dict[str, Any] = {}
_PLUGIN_GEN_OPTS: dict[str, dict[str, Any]] = {"sqpmethod": {"print_header": False, "qpsol": "qrqp",
                                                             "qpsol_options": {"print_info": False, "print_header": False, "print_iter": False}}}


#: HPIPM's stand-in for an infinite bound in the traffic formulation's QPs (CasADi's default 1e8 next to
#: O(1…1e3) scaled variables stalls HPIPM at its iteration limit (status 1) on the slack and epigraph
#: controls, which have no upper bound; measured: 100 iterations without convergence vs 14).
HPIPM_INF_TRAFFIC = 1e5


def _qp_options(qp_solver: str, hpipm_inf: float | None = None) -> dict[str, Any]:
    """Silent, tight options of a QP solver (the 'sqp' path's qpsol and the 'rti' path's conic)."""
    opts: dict[str, Any] = {"error_on_fail": False}
    if qp_solver == "hpipm" and hpipm_inf is not None:
        opts["inf"] = hpipm_inf
    if qp_solver == "qrqp":
        opts.update({"print_iter": False, "print_header": False, "print_info": False})
    elif qp_solver == "osqp":
        opts["osqp"] = {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True, "max_iter": 20000}
    elif qp_solver == "hpipm":
        opts["hpipm"] = {"iter_max": 100, "warm_start": 0}
    elif qp_solver == "qpoases":
        opts.update({"printLevel": "none", "sparse": True})
    return opts


#: Eigenvalue floor of the RTI Hessian's diagonal blocks, relative to (1 + the block's max |λ|) (our choice:
#: far below the curvature of every cost term, so PD blocks are unchanged and the step is undamped).
RTI_HESSIAN_FLOOR = 1e-8


def _project_pd(B: np.ndarray) -> np.ndarray:
    """Symmetric matrices B (k, n, n) with eigenvalues raised to RTI_HESSIAN_FLOOR·(1 + max|λ|); blocks
    that are PD with margin are returned unchanged (only the others are rebuilt from their eigenpairs)."""
    B = 0.5 * (B + B.transpose(0, 2, 1))
    lam, Q = np.linalg.eigh(B)
    floor = RTI_HESSIAN_FLOOR * (1.0 + np.abs(lam).max(axis=1, keepdims=True))
    bad = np.any(lam < floor, axis=1)
    if np.any(bad):
        lb, Qb = np.maximum(lam[bad], floor[bad]), Q[bad]
        B[bad] = (Qb * lb[:, None, :]) @ Qb.transpose(0, 2, 1)
    return B


def default_problem(ev: EVParams, s: MPCSettings, formulation: Formulation | None = None) -> OCPProblem | ProblemBuilder:
    """The MPC problem of a formulation (default: the traffic formulation) on the settings' interval dt."""
    return (formulation or DEFAULT_FORMULATION).builder(ev, s.dt)


def resolve_formulation(formulation: Formulation | None, problem: OCPProblem | ProblemBuilder | None,
                        parameter_values: dict[str, float] | None = None,
                        initial_values: dict[str, float] | None = None) -> Formulation:
    """The one formulation of an MPC: ``formulation``, or a user ``problem`` made one (every derived item then
    follows the problem), or the default (traffic). Both at once is a ParameterError."""
    if problem is not None:
        if formulation is not None:
            raise ParameterError("MPC: give problem= or formulation=, not both (a user problem is its own "
                                 "formulation: aev_ocp.ocp.formulation.problem_formulation(problem))")
        return problem_formulation(problem, parameter_values, initial_values)
    f = formulation or DEFAULT_FORMULATION
    if not isinstance(f, Formulation):
        raise ParameterError(f"MPC: formulation must be a Formulation, got {type(f).__name__}")
    if (parameter_values or initial_values) and f.kind == "problem":
        f = f.with_(parameter_values={**f.parameter_values, **(parameter_values or {})},
                    initial_values={**f.initial_values, **(initial_values or {})})
    elif parameter_values or initial_values:
        raise ParameterError(f"MPC: parameter_values/initial_values are for a user problem, not the {f.name} formulation")
    return f


class MPCController:
    """The MPC for one vehicle: build once, then :meth:`solve` at every step (warm-started).

    ``formulation``: the problem and everything derived from it (:class:`aev_ocp.ocp.formulation.Formulation`;
    default the traffic formulation); ``problem``: a user :class:`OCPProblem` or :class:`ProblemBuilder`
    instead (it becomes the formulation); ``guess_law``: closed-form law rolled out over the
    horizon as the cold-start guess (default the paper's proposed law); ``parameter_values`` /
    ``initial_values``: values of a user problem's extra parameters / own states by name.
    """

    def __init__(self, settings: MPCSettings | None = None, ev: EVParams | None = None,
                 guess_law: CarFollowingLaw | None = None, problem: OCPProblem | ProblemBuilder | None = None,
                 parameter_values: dict[str, float] | None = None,
                 initial_values: dict[str, float] | None = None, formulation: Formulation | None = None) -> None:
        self.settings = settings or MPCSettings()
        if not isinstance(self.settings, MPCSettings):
            raise ParameterError(f"MPCController: settings must be an MPCSettings, got {type(settings).__name__}")
        self.ev = ev or EVParams()
        self.guess_law = guess_law or Proposed()
        s = self.settings
        self.formulation = f = resolve_formulation(formulation, problem, parameter_values, initial_values)
        # rti: a built-in problem with the OCV as comparisons (same values, cheaper Hessians: models/battery.py)
        with piecewise_ocv() if s.solver == "rti" and f.kind != "problem" else contextlib.nullcontext():
            built = f.builder(self.ev, s.dt)
            self.problem = built.build() if isinstance(built, ProblemBuilder) else built
        self._check_layout(dict(f.parameter_values), dict(f.initial_values))
        self.codegen_active = False
        self._cstep: Any = None  # the compiled whole step (export.CStep) of the rti path with qp_solver 'riccati'
        self._riccati: Any = None  # (QP-data Function, ocpqp.OcpQP) of the rti path with 'riccati' without codegen
        #: the QP solver that runs ('riccati', a ca.conic/qpsol plugin, or '' for the IPOPT paths)
        self.qp_in_use = self.settings.qp if self.settings.solver in ("rti", "sqp") else ""
        # the 'rti' path starts cold by RTI from the law's rollout; §9 (and a problem built from it) keeps
        # its cold IPOPT first step (model guide §9 numbers unchanged): the formulation says which
        self._rti_cold = f.rti_cold_start
        t0 = time.perf_counter()
        self._build_model()
        self._build_nlp()
        self._build_solvers()
        self.build_time_s = time.perf_counter() - t0
        self._warm: dict[str, np.ndarray] | None = None

    def _check_layout(self, pvals: dict[str, float], xinit: dict[str, float]) -> None:
        """The closed-loop layout (see the module docstring) and the values of extra names."""
        pr = self.problem
        if tuple(pr.state_names[:NZ]) != STATE_NAMES or pr.control_names[0] != "a" or pr.nw < 2:
            raise ParameterError(f"MPCController: problem {pr.name!r} must start with states {STATE_NAMES}, "
                                 "control 'a' and stage parameters (v_l_mean, v_l_hat)")
        if self.settings.solver == "rti" and pr.terminal is not None:
            raise ParameterError("MPCSettings.solver = 'rti' does not handle terminal constraints (terminal costs "
                                 "are fine; make the constraint a soft terminal cost): use 'ipopt' or 'sqp'")
        pnames = list(pr.meta.get("parameter_names", WEIGHT_NAMES[:pr.np_]))
        wnames = list(pr.meta.get("stage_parameter_names", ["v_l_mean", "v_l_hat"]))
        self._n_weights = sum(1 for k in pnames[:len(WEIGHT_NAMES)] if k in WEIGHT_NAMES)
        extra_p, extra_w = pnames[self._n_weights:], wnames[2:]
        unknown = sorted(set(pvals) - set(extra_p) - set(extra_w))
        missing = [k for k in extra_p + extra_w if k not in pvals]
        if unknown or missing:
            raise ParameterError(f"MPCController: parameter_values must give exactly {extra_p + extra_w}"
                                 f"{'; unknown ' + str(unknown) if unknown else ''}"
                                 f"{'; missing ' + str(missing) if missing else ''}")
        self._p_extra = np.array([float(pvals[k]) for k in extra_p])
        self._w_extra = np.array([float(pvals[k]) for k in extra_w])
        own = list(pr.state_names[NZ:])
        bad = sorted(set(xinit) - set(own))
        if bad:
            raise ParameterError(f"MPCController: initial_values names unknown states {bad}; own states are {own}")
        self._x_own0 = np.array([float(xinit.get(k, 0.0)) for k in own])

    # ------------------------------------------------------------------ model
    def _build_model(self) -> None:
        s, pr = self.settings, self.problem
        nx, nu, nw, npar = pr.nx, pr.nu, pr.nw, pr.np_
        self.nx, self.nu = nx, nu
        self.x_scale = np.asarray(pr.x_scale if pr.x_scale is not None else np.ones(nx), float)
        self.u_scale = np.asarray(pr.u_scale if pr.u_scale is not None else np.ones(nu), float)
        z, u, w, p = ca.SX.sym("z", nx), ca.SX.sym("u", nu), ca.SX.sym("w", nw), ca.SX.sym("p", npar)
        zn, _ = rk4(lambda x: pr.ode(x, u, w, p), z, s.dt, s.rk4_substeps)
        zn = with_discrete_update(pr, zn, z, u, w, p)
        self.step = ca.Function("mpc_step", [z, u, w, p], [zn], ["z", "u", "w", "p"], ["z_next"])
        self.F = interval_function(pr, TranscriptionOptions(method="ms", N=s.N, rk4_substeps=s.rk4_substeps))
        xl = np.asarray(pr.x_lb if pr.x_lb is not None else -np.inf * np.ones(nx), float)
        xu = np.asarray(pr.x_ub if pr.x_ub is not None else np.inf * np.ones(nx), float)
        ul = np.asarray(pr.u_lb if pr.u_lb is not None else -np.inf * np.ones(nu), float)
        uu = np.asarray(pr.u_ub if pr.u_ub is not None else np.inf * np.ones(nu), float)
        self._xb, self._ub = (xl, xu), (ul, uu)
        # cold-start guess: the closed-form law per interval (other controls 0), clipped, rolled out by
        # the same step, states clipped to their bounds
        ag = ca.fmin(ca.fmax(self.guess_law.accel(ca.fmax(z[0], 1e-2), z[1], w[1]), ul[0]), uu[0])
        ug = ca.vertcat(ag, ca.fmin(ca.fmax(ca.DM.zeros(nu - 1), ul[1:]), uu[1:])) if nu > 1 else ag
        zg = self.step(z, ug, w, p)
        zg = ca.fmin(ca.fmax(zg, ca.DM(np.where(np.isfinite(xl), xl, -1e20))), ca.DM(np.where(np.isfinite(xu), xu, 1e20)))
        self._rollout = ca.Function("mpc_rollout", [z, w, p], [zg, ug]).mapaccum(s.N)

    # ------------------------------------------------------------------ NLP
    def _stage_inputs(self, V: Any, P: Any) -> tuple[Any, ...]:
        """(X_k (nx, N), U_k (nu, N), X_{k+1} (nx, N), W (nw, N), p, SW (1, N)) of the scaled NLP."""
        pr, N = self.problem, self.settings.N
        nx, nb = pr.nx, pr.nx + pr.nu
        B = ca.reshape(V[:nb * N], nb, N)
        Xn = ca.horzcat(B[:nx, 1:], V[nb * N:]) if N > 1 else V[nb * N:]
        nwN = pr.nw * N
        return (B[:nx, :], B[nx:, :], Xn, ca.reshape(P[:nwN], pr.nw, N), P[nwN:nwN + pr.np_], P[nwN + pr.np_:].T)

    def _build_nlp(self) -> None:
        s, pr = self.settings, self.problem
        N, nx, nu = s.N, pr.nx, pr.nu
        nb = nx + nu
        xs = ca.DM(self.x_scale)
        V = ca.MX.sym("V", nb * N + nx)
        P = ca.MX.sym("p", pr.nw * N + pr.np_ + N)  # stage parameters per interval, p, stage weights
        Xk, Uk, Xn, W, PP, SW = self._stage_inputs(V, P)
        eq, path, J = self.F.map(N, "serial")(Xk, Uk, ca.MX(0, N), Xn, W, ca.repmat(PP, 1, N), s.dt)
        f, g = ca.sum2(J * SW), [ca.vec(ca.vertcat(eq, path))]
        lbg_k = np.concatenate([np.zeros(nx), np.asarray(pr.path_lb, float)])
        ubg_k = np.concatenate([np.zeros(nx), np.asarray(pr.path_ub, float)])
        lbg, ubg = [np.tile(lbg_k, N)], [np.tile(ubg_k, N)]
        xN = V[nb * N:] * xs
        if pr.terminal_cost is not None:
            f = f + pr.terminal_cost(xN, PP)
        if pr.terminal is not None:
            g.append(pr.terminal(xN, PP))
            lbg.append(np.asarray(pr.terminal_lb, float))
            ubg.append(np.asarray(pr.terminal_ub, float))
        self._nlp = {"x": V, "p": P, "f": f, "g": ca.vertcat(*g)}
        self._lbg, self._ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._ng_stage = lbg_k.size
        (xl, xu), (ul, uu) = self._xb, self._ub
        xl_s, xu_s = xl / self.x_scale, xu / self.x_scale
        self._lbx = np.concatenate([np.tile(np.concatenate([xl_s, ul / self.u_scale]), N), xl_s])
        self._ubx = np.concatenate([np.tile(np.concatenate([xu_s, uu / self.u_scale]), N), xu_s])
        self.nv, self.ng, self.np_ = V.numel(), self._lbg.size, P.numel()

    def _compile(self, plugin: str) -> str | None:
        """C code of the NLP functions (objective, constraints, their Jacobians and the Lagrangian
        Hessian) of nlpsol ``plugin``, compiled once (see :meth:`_compile_c`)."""
        gen = ca.nlpsol("mpc_nlp", plugin, self._nlp, {**_PLUGIN_GEN_OPTS.get(plugin, {})})
        return self._compile_c(f"mpc_nlp_{plugin}", lambda: gen.generate_dependencies("mpc_nlp.c"), "mpc_nlp.c")

    def _compile_c(self, stem: str, generate: Any, cfile: str) -> str | None:
        """Run ``generate()`` (writes ``cfile`` into the current folder) in a temporary folder and
        compile the C file into the private cache (:func:`aev_ocp.compiled.compile_shared`, keyed by
        the source's hash). Returns the shared library's path, or None (with a warning) when no
        compiler works."""
        if compiler() is None:
            warnings.warn("MPC codegen requested but no C compiler (gcc) was found: using the "
                          "interpreted CasADi functions instead", RuntimeWarning, stacklevel=5)
            return None
        try:
            with tempfile.TemporaryDirectory() as tmp:
                cwd = os.getcwd()
                os.chdir(tmp)
                try:
                    generate()
                finally:
                    os.chdir(cwd)
                src = Path(tmp, cfile).read_text()
        except (OSError, RuntimeError) as exc:
            warnings.warn(f"MPC codegen failed ({type(exc).__name__}: {str(exc)[:200]}): using the "
                          "interpreted CasADi functions instead", RuntimeWarning, stacklevel=5)
            return None
        built = compile_shared(src, stem, "mpc")
        if built.path is None:
            warnings.warn(f"MPC codegen failed ({built.error}): using the interpreted CasADi functions instead",
                          RuntimeWarning, stacklevel=5)
            return None
        return str(built.path)

    def _nlpsol(self, name: str, plugin: str, opts: dict[str, Any]) -> ca.Function:
        """nlpsol on the compiled library of the NLP functions when codegen is on (and works),
        else on the symbolic NLP expanded to SX."""
        base = {"print_time": False, "error_on_fail": False}
        if self.settings.codegen:
            lib = self._compile(plugin)
            if lib is not None:
                self.codegen_active = True
                return ca.nlpsol(name, plugin, lib, {**base, **opts})
        return ca.nlpsol(name, plugin, self._nlp, {**base, "expand": True, **opts})

    def _ipopt(self, name: str, warm: bool) -> ca.Function:
        s = self.settings
        ip: dict[str, Any] = {"print_level": 5 if s.verbose else 0, "sb": "yes", "tol": s.tol,
                              "max_iter": s.max_iter, "max_wall_time": s.max_cpu_time_s,
                              "linear_solver": "mumps", "hessian_approximation": "exact",
                              "nlp_scaling_method": "none" if warm else "gradient-based"}
        if warm:
            ip.update({"warm_start_init_point": "yes", "warm_start_bound_push": 1e-9,
                       "warm_start_mult_bound_push": 1e-9, "warm_start_slack_bound_push": 1e-9,
                       "mu_init": 1e-5, "mu_strategy": "monotone", "nlp_scaling_method": "gradient-based"})
        return self._nlpsol(name, "ipopt", {"ipopt": ip})

    def _build_solvers(self) -> None:
        s = self.settings
        self._cold = self._ipopt("mpc_ipopt_cold", warm=False)
        self._fast: ca.Function | None = None
        if s.solver == "ipopt":
            self._fast = self._ipopt("mpc_ipopt_warm", warm=True)
        elif s.solver == "sqp":
            qp_opts = _qp_options(s.qp)
            if s.qp == "osqp":
                qp_opts["warm_start_primal"] = True
            opts = {"qpsol": s.qp, "qpsol_options": qp_opts,
                    "hessian_approximation": "exact", "max_iter": s.max_iter, "tol_pr": s.tol * 100,
                    "tol_du": s.tol * 100, "print_header": s.verbose, "print_iteration": s.verbose,
                    "print_status": s.verbose, "min_step_size": 1e-12, **_SQP_EXTRA}
            self._fast = self._nlpsol("mpc_sqp", "sqpmethod", opts)
        elif s.solver == "rti":
            self._build_rti()
        # 'ipopt-cold': the cold IPOPT at every step

    def rti_stage_functions(self) -> tuple[ca.Function, ca.Function]:
        """The QP of one SQP step, stage by stage (SX, shared by :meth:`_build_rti` and the exported step's
        ``aev_cg_qpdata``): ``mpc_rti_stage(z_k, u_k, z_{k+1}, w_k, p, stage weight, λ_k) -> (H_k, q_k, J_k, g_k,
        cost_k)``: the Lagrangian Hessian block ∇²(cost + λ_kᵀc_k) in (z_k, u_k), the cost gradient, the
        Jacobian of c_k = (interval end state; path constraints) and c_k − (z_{k+1}; 0); and
        ``mpc_rti_terminal(x_N scaled, p) -> (H_N, q_N, terminal cost)``, the Mayer term's."""
        s, pr = self.settings, self.problem
        nx, nu, ngs = pr.nx, pr.nu, self._ng_stage
        zk, uk = ca.SX.sym("zk", nx), ca.SX.sym("uk", nu)
        zn, w, pp = ca.SX.sym("zn", nx), ca.SX.sym("w", pr.nw), ca.SX.sym("p", pr.np_)
        sw, lk = ca.SX.sym("sw"), ca.SX.sym("lk", ngs)
        u = ca.vertcat(zk, uk)
        eq, path, J = self.F(zk, uk, ca.SX(0, 1), ca.SX.zeros(nx), w, pp, s.dt)
        ck = ca.vertcat(eq, path)  # g_k + (z_{k+1}; 0): the interval's end state and the path constraints
        cost = sw * J
        Hk = ca.densify(ca.hessian(cost + ca.dot(lk, ck), u)[0])
        Jk = ca.densify(ca.jacobian(ck, u))
        gk = ck - ca.vertcat(zn, ca.SX.zeros(ngs - nx))
        stage = ca.Function("mpc_rti_stage", [zk, uk, zn, w, pp, sw, lk], [Hk, ca.gradient(cost, u), Jk, gk, cost])
        # terminal cost (Mayer) on the scaled x_N: its Hessian block and gradient
        xNs, pT = ca.SX.sym("xN", nx), ca.SX.sym("pT", pr.np_)
        mayer = pr.terminal_cost(xNs * ca.DM(self.x_scale), pT) if pr.terminal_cost is not None else ca.SX(0)
        term = ca.Function("mpc_rti_terminal", [xNs, pT], [ca.densify(ca.hessian(mayer, xNs)[0]),
                                                           ca.gradient(mayer, xNs), mayer])
        return stage, term

    def _build_rti(self) -> None:
        """The QP of one SQP step at a primal-dual point (x, λ_g) of the scaled NLP, stage by stage:
        H = ∇²_x(f + λ_gᵀg) (block diagonal: the stage (z_k, u_k) blocks; gap_k is linear in
        z_{k+1}), ∇f, A = ∂g/∂x (banded), g's bound offsets and the step bounds; one mapped stage
        function, compiled to C when codegen is on. The QP (step dx, new multipliers) is solved by
        ``ca.conic`` (HPIPM detects the OCP structure from the sparsity), or, with qp_solver 'riccati', by
        aev_ocp/c/ocp_qp.c: with codegen the whole step is one compiled library (export.CompiledStep, the C of
        ``aev-ocp mpc-export``), else its Python twin (:meth:`_riccati_step`, the QP data in stage blocks)."""
        s, pr = self.settings, self.problem
        if s.qp == "qrqp" and self.formulation.family == "traffic":
            raise ParameterError("MPCSettings.qp_solver = 'qrqp' cannot take the traffic formulation: its energy "
                                 "epigraph control enters the cost linearly and qrqp needs curvature in every "
                                 "control; use qp_solver = 'riccati' or 'hpipm'")
        qp_plugin = s.qp
        if s.qp == "riccati":
            from .export import CompiledStep, riccati_solver

            if s.codegen:  # the whole step compiled: the exported C (mpc/export.py, ocp_qp.c)
                self._cstep = CompiledStep.build(self)
                if self._cstep is not None:
                    self.codegen_active = True
                    return
            # no codegen, or the whole step could not be built: the QP data interpreted (or compiled below),
            # the QP solved by ocp_qp.c through ctypes (_solve_rti); HPIPM only if ocp_qp.c cannot be built
            self._riccati = riccati_solver(self)
            qp_plugin = "hpipm"  # the conic below: used only when ocp_qp.c could not be built (self._riccati None)
        self.qp_in_use = "riccati" if self._riccati is not None else qp_plugin
        N, nx, nu, ngs = s.N, pr.nx, pr.nu, self._ng_stage
        nb = nx + nu
        stage, term = self.rti_stage_functions()
        V, P = ca.MX.sym("x", self.nv), ca.MX.sym("p", self.np_)
        LAM, LBX, UBX = ca.MX.sym("lam_g", self.ng), ca.MX.sym("lbx", self.nv), ca.MX.sym("ubx", self.nv)
        Xk, Uk, Xn, W, PP, SW = self._stage_inputs(V, P)
        Hs, Qs, Js, Gs, Cs = stage.map(N, "serial")(Xk, Uk, Xn, W, ca.repmat(PP, 1, N), SW, ca.reshape(LAM, ngs, N))
        HN, qN, cN = term(V[nb * N:], PP)
        H = ca.diagcat(*([ca.DM.ones(ca.Sparsity.dense(nb, nb))] * N), ca.DM.ones(ca.Sparsity.dense(nx, nx)))
        E = ca.DM(self.ng, self.nv)  # −I of gap_k in z_{k+1}
        for k in range(N):
            for i in range(nx):
                E[k * ngs + i, (k + 1) * nb + i] = -1.0
        A = ca.horzcat(ca.diagcat(*ca.horzsplit(Js, nb)), ca.MX(self.ng, nx)) + ca.sparsify(E)
        g = ca.vec(Gs)
        # the exact Hessian comes out as its dense diagonal blocks (hblk: the N stage blocks side by side,
        # hN: the terminal block); :meth:`_regularised_hessian` projects each onto the PD cone
        qpdata = ca.Function("mpc_rti_qp_data", [V, P, LAM, LBX, UBX],
                             [Hs, HN, ca.vertcat(ca.vec(Qs), qN), A, ca.DM(self._lbg) - g,
                              ca.DM(self._ubg) - g, LBX - V, UBX - V, ca.sum2(Cs) + cN, g],
                             ["x", "p", "lam_g", "lbx", "ubx"],
                             ["hblk", "hN", "g", "a", "lba", "uba", "lbdx", "ubdx", "f", "gx"])
        self._H_sp = H.sparsity()
        # objective and constraints only (cost and nonlinear violation of the returned plan)
        fg = ca.Function("mpc_rti_fg", [self._nlp["x"], self._nlp["p"]], [self._nlp["f"], self._nlp["g"]],
                         ["x", "p"], ["f", "g"])
        # path constraints of the applied control at node 0 (where the state is the measurement)
        path0 = self.F(V[:nx], V[nx:nb], ca.MX(0, 1), ca.MX.zeros(nx), W[:, 0], PP, s.dt)[1]
        p0 = ca.Function("mpc_rti_path0", [V, P], [path0])
        self._rti_data, self._rti_fg, self._rti_path0 = qpdata, fg, p0
        if s.codegen:
            def generate() -> None:
                cg = ca.CodeGenerator("mpc_rti.c")
                cg.add(qpdata)
                cg.add(fg)
                cg.add(p0)
                cg.generate()

            lib = self._compile_c("mpc_rti", generate, "mpc_rti.c")
            if lib is not None:
                self.codegen_active = True
                self._rti_data = ca.external("mpc_rti_qp_data", lib)
                self._rti_fg = ca.external("mpc_rti_fg", lib)
                self._rti_path0 = ca.external("mpc_rti_path0", lib)
        if not self.codegen_active:
            self._rti_data, self._rti_fg, self._rti_path0 = qpdata.expand(), fg.expand(), p0.expand()
        self._rti_qp = ca.conic("mpc_rti_qp", qp_plugin, {"h": H.sparsity(), "a": A.sparsity()},
                                _qp_options(qp_plugin, HPIPM_INF_TRAFFIC if self.formulation.family == "traffic" else None))
        self._rti_path0_lb = np.asarray(pr.path_lb, float)
        self._rti_path0_ub = np.asarray(pr.path_ub, float)

    # ------------------------------------------------------------------ helpers
    def _params(self, w: np.ndarray, weights: FollowingWeights | None, stage_weights: np.ndarray | None) -> np.ndarray:
        """NLP parameter vector: stage parameters per interval (forecast, then the user's), the problem's
        parameters (the §9 weights, then the user's) and the stage weights."""
        N = self.settings.N
        wt = weight_vector(weights or self.formulation.weights)[:self._n_weights]
        sw = np.ones(N) if stage_weights is None else np.asarray(stage_weights, float).ravel()
        if sw.size != N or not np.all(np.isfinite(sw)) or np.any(sw < 0):
            raise ParameterError(f"MPC stage_weights must be {N} finite numbers >= 0")
        W = np.vstack([w, np.repeat(self._w_extra.reshape(-1, 1), N, axis=1)]) if self._w_extra.size else w
        return np.concatenate([W.ravel(order="F"), wt, self._p_extra, sw])

    def _w_and_p(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(W (nw, N), p) back from the NLP parameter vector."""
        pr, N = self.problem, self.settings.N
        return p[:pr.nw * N].reshape(N, pr.nw).T, p[pr.nw * N:pr.nw * N + pr.np_]

    def guess(self, z0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Cold-start primal guess (scaled NLP vector): the closed-form law rolled out over the horizon."""
        W, pp = self._w_and_p(p)
        Zn, U = self._rollout(ca.DM(z0), W, np.repeat(pp.reshape(-1, 1), self.settings.N, axis=1))
        Z = np.hstack([np.asarray(z0, float).reshape(self.nx, 1), np.asarray(Zn)]) / self.x_scale[:, None]
        U = np.asarray(U).reshape(self.nu, -1) / self.u_scale[:, None]
        return np.concatenate([np.vstack([Z[:, :-1], U]).ravel(order="F"), Z[:, -1]])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X (nx, N+1), a (N,), U (nu, N)) in physical units from the scaled NLP vector."""
        N, nx, nb = self.settings.N, self.nx, self.nx + self.nu
        blocks = x[:nb * N].reshape(N, nb).T
        X = np.hstack([blocks[:nx], x[nb * N:].reshape(nx, 1)]) * self.x_scale[:, None]
        U = blocks[nx:] * self.u_scale[:, None]
        return X, U[0].copy(), U

    def _shift(self, z0: np.ndarray, p: np.ndarray) -> dict[str, np.ndarray]:
        """Warm start from the previous solution shifted by one interval: (z_1, u_1, …, z_N, u_{N−1},
        F(z_N, u_{N−1})), z_0 replaced by the measurement; multipliers shifted the same way."""
        prev = self._warm
        assert prev is not None
        N, nx, nb, ngs = self.settings.N, self.nx, self.nx + self.nu, self._ng_stage

        def shift_v(v: np.ndarray, new_last: np.ndarray) -> np.ndarray:
            blocks = v[:nb * N].reshape(N, nb)
            nbk = np.vstack([blocks[1:], np.concatenate([v[nb * N:], blocks[-1, nx:]])])
            return np.concatenate([nbk.ravel(), new_last])

        x = prev["x"]
        W, pp = self._w_and_p(p)
        zN = x[nb * N:] * self.x_scale
        uN = x[nb * N - self.nu:nb * N] * self.u_scale
        z_ext = np.asarray(self.step(zN, uN, W[:, -1], pp)).ravel() / self.x_scale
        z_ext = np.clip(z_ext, self._lbx[-nx:], self._ubx[-nx:])
        x0 = shift_v(x, z_ext)
        x0[:nx] = z0 / self.x_scale
        lam_x = prev["lam_x"]
        lg = prev["lam_g"]
        g_st = lg[:N * ngs].reshape(N, ngs)
        lg = np.concatenate([np.vstack([g_st[1:], g_st[-1:]]).ravel(), lg[N * ngs:]])
        return {"x0": x0, "lam_x0": shift_v(lam_x, lam_x[nb * N:]), "lam_g0": lg}

    def _violation(self, x: np.ndarray, g: np.ndarray, lbx: np.ndarray, ubx: np.ndarray) -> float:
        vg = np.maximum(np.maximum(self._lbg - g, g - self._ubg), 0.0)
        vx = np.maximum(np.maximum(lbx - x, x - ubx), 0.0)
        return float(max(vg.max(initial=0.0), vx.max(initial=0.0)))

    def reset(self) -> None:
        """Forget the warm start (the next solve starts cold from the closed-form-law guess)."""
        self._warm = None

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
        x_own = (self._x_own0 if self._warm is None else self._warm["X1"][NZ:]).copy()
        names = list(self.problem.state_names[NZ:])
        for k, val in (own or {}).items():
            if k in names:
                x_own[names.index(k)] = float(val)
        return np.concatenate([z0, x_own])

    def solve(self, z0: np.ndarray, v_mean: np.ndarray, v_hat: np.ndarray, *,
              weights: FollowingWeights | None = None, stage_weights: np.ndarray | None = None,
              own: dict[str, float] | None = None) -> MPCSolution:
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
            raise ParameterError(f"MPC: the leader forecast (v_mean, v_hat) must be N = {N} finite values each, "
                                 f"got {vm_.size} and {vh_.size}")
        p = self._params(np.vstack([vm_, vh_]), weights, stage_weights)
        if self._cstep is not None:
            was_cold = self._warm is None
            sol = self._solve_cstep(z0, p)
            if sol.success or not was_cold or self._rti_cold or self._warm is not None:
                # (a late cold start, cause 'budget', left its plan as the warm start: the next step is warm)
                return sol  # a failed cold start of §9's compiled step falls back to the cold IPOPT below
        warm = self._warm is not None and s.solver != "ipopt-cold"
        if s.solver == "rti" and not warm and self._rti_cold and self._cstep is None:
            # cold real-time iteration from the closed-form law's rollout (never a cold IPOPT)
            lbx, ubx = self._lbx.copy(), self._ubx.copy()
            lbx[:nx] = ubx[:nx] = z0 / self.x_scale
            cold = {"x0": self.guess(z0, p), "lam_g0": np.zeros(self.ng), "lam_x0": np.zeros(self.nv)}
            return self._solve_rti(cold, p, lbx, ubx, s.rti_cold_iterations)
        lbx, ubx = self._lbx.copy(), self._ubx.copy()
        lbx[:nx] = ubx[:nx] = z0 / self.x_scale
        solver: ca.Function
        if warm:
            args = self._shift(z0, p)
            if s.solver == "rti":
                return self._solve_rti(args, p, lbx, ubx, s.rti_iterations)
            assert self._fast is not None  # built for 'ipopt' and 'sqp', the other warm paths
            solver, path = self._fast, s.solver
        else:
            args = {"x0": self.guess(z0, p)}
            solver, path = self._cold, "ipopt-cold"
        t0 = time.perf_counter()
        try:
            out = solver(p=p, lbx=lbx, ubx=ubx, lbg=self._lbg, ubg=self._ubg, **args)
            err = None
        except RuntimeError as exc:  # e.g. NaN in a function evaluation that the solver did not catch
            out, err = None, str(exc).splitlines()[0][:200]
        dt_wall = time.perf_counter() - t0
        if out is None:
            return self._failed(f"exception: {err}", 0, dt_wall, float("inf"), path)
        st = solver.stats()
        x, g = np.asarray(out["x"]).ravel(), np.asarray(out["g"]).ravel()
        viol = self._violation(x, g, lbx, ubx)
        status = str(st.get("return_status", st.get("unified_return_status", "")))
        success = bool(st.get("success", False)) and viol < PLAN_TOLERANCE and bool(np.all(np.isfinite(x)))
        iters = int(st.get("iter_count", st.get("iterations", {}).get("iter", [0])[-1]
                           if isinstance(st.get("iterations"), dict) else 0))
        X, a, U = self.unpack(x)
        self._warm = ({"x": x, "lam_x": np.asarray(out["lam_x"]).ravel(), "lam_g": np.asarray(out["lam_g"]).ravel(),
                       "X1": X[:, 1]} if success else None)
        if self._cstep is not None and self._warm is not None:
            self._cstep.set_warm(self._warm["x"], self._warm["lam_g"], self._warm["lam_x"])
        return MPCSolution(success, status, iters, dt_wall, X, a, float(out["f"]), viol, path,
                           {"t_wall_solver": float(st.get("t_wall_total", float("nan")))}, U)

    def _late(self, warm: dict[str, Any], iters: int, dt_wall: float, viol: float, path: str) -> MPCSolution:
        """A valid plan that took longer than ``max_step_ms``: a failure with cause 'budget' (the policy
        applies its fallback), but the plan (``warm``: the warm start it leaves) stays the next step's warm
        start, so one late step (e.g. a cold start) does not make every following step cold, and late, too."""
        sol = self._failed(f"budget: the step took {dt_wall * 1e3:.3g} ms > max_step_ms = "
                           f"{self.settings.max_step_ms:g}", iters, dt_wall, viol, path)
        self._warm = warm
        return sol

    def _failed(self, status: str, iters: int, dt_wall: float, viol: float, path: str) -> MPCSolution:
        N = self.settings.N
        self._warm = None
        return MPCSolution(False, status, iters, dt_wall, np.full((self.nx, N + 1), np.nan), np.full(N, np.nan),
                           float("nan"), viol, path, {}, np.full((self.nu, N), np.nan))

    def regularised_hessian(self, hblk: Any, hN: Any, project: bool = True) -> ca.DM:
        """The RTI QP's Hessian from the exact Lagrangian Hessian's diagonal blocks (``hblk`` (nb, nb·N):
        the stage blocks side by side, ``hN`` (nx, nx): the terminal block), each projected onto the
        positive-definite cone: symmetric eigendecomposition, eigenvalues below
        ``RTI_HESSIAN_FLOOR·(1 + max|λ|)`` raised to that floor (a no-op where the block is safely PD).
        Block-wise projection makes the whole (block-diagonal) Hessian, hence every reduced Hessian, PD.
        ``project=False``: the exact blocks, assembled."""
        N, nx, nb = self.settings.N, self.nx, self.nx + self.nu
        B = np.asarray(hblk, float).reshape(nb, N, nb).transpose(1, 0, 2)  # (N, nb, nb): block k = hblk[:, k·nb:(k+1)·nb]
        HN = np.asarray(hN, float).reshape(1, nx, nx)
        # column-major nonzeros of the dense diagonal blocks (the sparsity of self._H_sp)
        if project:
            B, HN = _project_pd(B), _project_pd(HN)
        nz = np.concatenate([B.transpose(0, 2, 1).ravel(), HN[0].T.ravel()])
        return ca.DM(self._H_sp, nz)

    def _solve_rti(self, args: dict[str, np.ndarray], p: np.ndarray, lbx: np.ndarray,
                   ubx: np.ndarray, iterations: int) -> MPCSolution:
        """Up to ``iterations`` full SQP steps from ``args`` (the shifted previous solution, or the cold
        guess) (see :meth:`_build_rti`), each QP with the block-wise PD-projected exact Hessian
        (:meth:`regularised_hessian`). Success: every QP solved, a finite step, the applied control's
        path constraints (node 0, where the state is the measurement) hold within
        :data:`aev_ocp.plant.PLAN_TOLERANCE`, and the step took at most ``max_step_ms``
        (else the cause 'budget'). A failure's status starts with its cause: 'QP failed', 'exception',
        'path constraint', 'budget'."""
        s = self.settings
        data, qp = self._rti_data, self._rti_qp
        t0 = time.perf_counter()
        x, lam_g, lam_x = args["x0"], args["lam_g0"], args["lam_x0"]
        ok, status, it, step = True, "", 0, float("inf")
        try:
            while it < iterations:
                if self._riccati is not None:
                    dx, lam_g, lam_x, qst = self._riccati_step(x, p, lam_g)
                    ok_qp = qst == ""
                else:
                    d = data(x, p, lam_g, lbx, ubx)
                    H = self.regularised_hessian(d[0], d[1], project=s.rti_hessian == "projected")
                    out = qp(h=H, g=d[2], a=d[3], lba=d[4], uba=d[5], lbx=d[6], ubx=d[7])
                    st = qp.stats()
                    dx = np.asarray(out["x"]).ravel()
                    ok_qp, qst = bool(st.get("success", False)), str(st.get("return_status", ""))
                    if ok_qp:
                        lam_g, lam_x = np.asarray(out["lam_a"]).ravel(), np.asarray(out["lam_x"]).ravel()
                it += 1
                if not ok_qp or not np.all(np.isfinite(dx)):
                    ok, status = False, f"QP failed: {qst}"
                    break
                x = x + dx
                step = float(np.abs(dx).max())
                if step <= s.tol:
                    break
            c0 = np.asarray(self._rti_path0(x, p)).ravel() if ok else None
        except RuntimeError as exc:
            ok, status, c0 = False, f"exception: {str(exc).splitlines()[0][:200]}", None
        dt_wall = time.perf_counter() - t0
        viol0 = float("inf")
        if c0 is not None:
            viol0 = float(np.maximum(np.maximum(self._rti_path0_lb - c0, c0 - self._rti_path0_ub), 0).max(initial=0))
            if not np.isfinite(viol0) or viol0 > PLAN_TOLERANCE:
                ok, status = False, f"path constraint: the applied control violates them by {viol0:.3g}"
        if ok and dt_wall * 1e3 > s.max_step_ms:
            X_late = self.unpack(x)[0]
            return self._late({"x": x, "lam_x": lam_x, "lam_g": lam_g, "X1": X_late[:, 1]}, it, dt_wall, viol0, "rti")
        if not ok:
            return self._failed(status, it, dt_wall, viol0, "rti")
        # plan, cost and the nonlinear constraint violation of the plan (the RTI plan is feasible only
        # to first order; reported, not required)
        f, g = self._rti_fg(x, p)
        viol = self._violation(x, np.asarray(g).ravel(), lbx, ubx)
        X, a, U = self.unpack(x)
        self._warm = {"x": x, "lam_x": lam_x, "lam_g": lam_g, "X1": X[:, 1]}
        return MPCSolution(True, "RTI_Step" if step > s.tol else "RTI_Converged", it, dt_wall, X, a,
                           float(f), viol, "rti", {"step_inf": step, "node0_violation": viol0}, U)

    def _riccati_step(self, x: np.ndarray, p: np.ndarray, lam_g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        """One SQP step's QP in the stage layout (export.qp_data_function, interpreted), the Hessian blocks
        projected in NumPy (rti_hessian 'projected'), solved by ocp_qp.c (ocpqp.OcpQP): (dx, lam_g, lam_x,
        '' or the QP solver's status name) — the Python twin of the compiled step's sqp_step."""
        fdata, qp = self._riccati
        N, nx, nb, ngs = self.settings.N, self.nx, self.nx + self.nu, self._ng_stage
        H, g, E, e, C, lc, uc, lbw, ubw = (np.asarray(v, float).ravel() for v in fdata(x, p, lam_g))

        def projected(H: np.ndarray) -> np.ndarray:
            B = _project_pd(H[:N * nb * nb].reshape(N, nb, nb).transpose(0, 2, 1))
            HN = _project_pd(H[N * nb * nb:].reshape(1, nx, nx).transpose(0, 2, 1))
            return np.concatenate([B.transpose(0, 2, 1).ravel(), HN.transpose(0, 2, 1).ravel()])

        exact = self.settings.rti_hessian == "exact"
        r = qp.solve(H if exact else projected(H), g, E, e, C, lc, uc, lbw, ubw, np.zeros(nx))
        if exact and r.status in (1, 2):  # MAX_ITER, FACTORIZATION: not convex enough (as mpc_step.c)
            r = qp.solve(projected(H), g, E, e, C, lc, uc, lbw, ubw, np.zeros(nx))
        if r.status != 0:
            return r.w, lam_g, np.zeros(self.nv), f"ocp_qp {r.status_name}"
        lg = np.concatenate([r.pi.reshape(N, nx), r.lam_c.reshape(N, ngs - nx)], axis=1).ravel()
        return r.w, lg, r.lam_w, ""

    def _solve_cstep(self, z0: np.ndarray, p: np.ndarray) -> MPCSolution:
        """One step of the compiled whole RTI step (:class:`aev_ocp.mpc.export.CStep`, the same C as
        ``aev-ocp mpc-export``): a cold start (SQP from the guess) when there is no warm start."""
        from .export import STATUS

        cs = self._cstep
        if self._warm is None:
            cs.reset()
        t0 = time.perf_counter()
        st = cs.step_full(z0, p)
        dt_wall = time.perf_counter() - t0
        x, lam_g, lam_x, info = cs.solution()
        if st != 0:
            from .ocpqp import STATUS as QP_STATUS

            why = STATUS.get(st, f"status {st}")
            if st == 1:  # the QP solver's own status (ocp_qp.h)
                why = f"{why} {QP_STATUS.get(info.qp_status, info.qp_status)}"
            return self._failed(why, info.iterations, dt_wall, info.node0_violation, "rti")
        X, a, U = self.unpack(x)
        warm = {"x": x.copy(), "X1": X[:, 1]}  # (the library keeps its own warm start)
        if dt_wall * 1e3 > self.settings.max_step_ms:
            return self._late(warm, info.iterations, dt_wall, info.node0_violation, "rti")
        self._warm = warm
        return MPCSolution(True, "RTI_Step" if info.step_inf > self.settings.tol else "RTI_Converged",
                           info.iterations, dt_wall, X, a, info.cost, info.violation, "rti",
                           {"step_inf": info.step_inf, "node0_violation": info.node0_violation,
                            "cold_start": bool(info.cold)}, U)

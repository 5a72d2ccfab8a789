"""The receding-horizon controller of PROBLEM.md §9, built ONCE as a parametric NLP.

State z = (h, v, V1, V2, S) (model units; V1, V2 [V]; S [-]), control a held constant over each
interval of length dt [model time]. The stage cost, dynamics and path constraints come from
:mod:`aev_ocp.ocp.following` (the one place that defines them, shared with OCP-D):

    min Σ_k s_k ℓ(z_k, a_k)·dt,  ℓ = w_Q Q_pack/(1 kW) + w_V (V(h) − v)² + w_r (v̂_l − v)² + w_a a²
    s.t. z_{k+1} = F(z_k, a_k, v̄_l,k) (RK4 of the smoothed model, interval-mean leader speed v̄_l,k),
         h ≥ 0.2, 0 ≤ v ≤ 2, S ∈ [0, 1] at nodes 1…N;  −3 ≤ a ≤ 2;  |I| ≤ 46 A, disc ≥ 0 at nodes 0…N−1.

NLP parameters (so that nothing is rebuilt between solves or weight sweeps): the measured initial
state, the forecast (v̄_l,k, v̂_l(t_k)) per interval, the four weights and per-interval stage weights
s_k (default 1; lets a user shape the cost along the horizon, e.g. to end it at a scenario's end).
Decision variables are ordered (z_0, a_0, z_1, a_1, …, z_N) and constraints stage by stage, so the
KKT system is banded and HPIPM can detect the OCP structure.
"""

from __future__ import annotations

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
from ..models.carfollowing import CarFollowingLaw, Proposed
from ..ocp.following import (FollowingWeights, following_ode, following_path_constraints,
                             following_stage_terms, following_state_bounds)
from ..params import EVParams, ParameterError
from .settings import MPCSettings

NX = 5
X_SCALE = np.array([1.0, 1.0, 0.01, 0.01, 1.0])  # nominal magnitudes of h, v, V1 [V], V2 [V], S
TERM_NAMES = ("energy", "ovm", "relative", "accel")
_UNIT_WEIGHTS = FollowingWeights(1.0, 1.0, 1.0, 1.0)


@dataclass
class MPCSolution:
    """One solve: success, status, iterations, wall time [s] of the solver call, the plan
    X (5, N+1) and a (N,) [model units], cost (NLP objective), max constraint violation."""

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


_SQP_EXTRA: dict[str, Any] = {}
_PLUGIN_GEN_OPTS: dict[str, dict[str, Any]] = {"sqpmethod": {"print_header": False, "qpsol": "qrqp",
                                                             "qpsol_options": {"print_info": False, "print_header": False, "print_iter": False}}}


def _qp_options(qp_solver: str) -> dict[str, Any]:
    """Silent, tight options of a QP solver (the 'sqp' path's qpsol and the 'rti' path's conic)."""
    opts: dict[str, Any] = {"error_on_fail": False}
    if qp_solver == "qrqp":
        opts.update({"print_iter": False, "print_header": False, "print_info": False})
    elif qp_solver == "osqp":
        opts["osqp"] = {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True, "max_iter": 20000}
    elif qp_solver == "hpipm":
        opts["hpipm"] = {"iter_max": 100, "warm_start": 0}
    elif qp_solver == "qpoases":
        opts.update({"printLevel": "none", "sparse": True})
    return opts


class MPCController:
    """The §9 MPC for one vehicle: build once, then :meth:`solve` at every step (warm-started).

    ``guess_law``: closed-form law rolled out over the horizon as the cold-start guess (default the
    paper's proposed law).
    """

    def __init__(self, settings: MPCSettings | None = None, ev: EVParams | None = None,
                 guess_law: CarFollowingLaw | None = None) -> None:
        self.settings = settings or MPCSettings()
        if not isinstance(self.settings, MPCSettings):
            raise ParameterError(f"MPCController: settings must be an MPCSettings, got {type(settings).__name__}")
        self.ev = ev or EVParams()
        self.guess_law = guess_law or Proposed()
        self.codegen_active = False
        t0 = time.perf_counter()
        self._build_model()
        self._build_nlp()
        self._build_solvers()
        self.build_time_s = time.perf_counter() - t0
        self._warm: dict[str, np.ndarray] | None = None

    # ------------------------------------------------------------------ model
    def _build_model(self) -> None:
        s, ev = self.settings, self.ev
        z, a, w = ca.SX.sym("z", NX), ca.SX.sym("a"), ca.SX.sym("w", 2)  # w = (v̄_l interval mean, v̂_l(t_k))
        M = s.rk4_substeps
        h = s.dt / M

        def f(x: Any) -> Any:
            return following_ode(x, a, w[0], ev, s.smooth)

        x = z
        for _ in range(M):
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        terms = following_stage_terms(z, a, w[1], _UNIT_WEIGHTS, ev, s.smooth, s.objective)
        c, self._path_lb, self._path_ub = following_path_constraints(z, a, ev, s.smooth)
        self.step = ca.Function("mpc_step", [z, a, w], [x], ["z", "a", "w"], ["z_next"])
        self.terms = ca.Function("mpc_terms", [z, a, w], [ca.vertcat(*[terms[k] for k in TERM_NAMES])],
                                 ["z", "a", "w"], ["terms"])
        self.path = ca.Function("mpc_path", [z, a], [c], ["z", "a"], ["c"])
        # cold-start guess: the closed-form law per interval, clipped, rolled out by the same step
        b = s.bounds
        ag = ca.fmin(ca.fmax(self.guess_law.accel(ca.fmax(z[0], 1e-2), z[1], w[1]), b.a_min), b.a_max)
        zn = self.step(z, ag, w)
        zn = ca.vertcat(ca.fmax(zn[0], b.h_min), ca.fmin(ca.fmax(zn[1], b.v_min), b.v_max), zn[2:])
        self._rollout = ca.Function("mpc_rollout", [z, w], [zn, ag]).mapaccum(s.N)

    # ------------------------------------------------------------------ NLP
    def _build_nlp(self) -> None:
        s = self.settings
        N, nb = s.N, NX + 1
        xs = ca.DM(X_SCALE)
        # one stage on scaled variables: [gap_k; path_k] and its cost share s_k ℓ(z_k, a_k)·dt
        zk, ak, zn = ca.SX.sym("zk", NX), ca.SX.sym("ak"), ca.SX.sym("zn", NX)
        w, wt, sw = ca.SX.sym("w", 2), ca.SX.sym("wt", 4), ca.SX.sym("sw")
        gap = (self.step(zk * xs, ak, w) - zn * xs) / xs
        stage = ca.Function("mpc_stage", [zk, ak, zn, w, wt, sw],
                            [ca.vertcat(gap, self.path(zk * xs, ak)),
                             sw * s.dt * ca.dot(wt, self.terms(zk * xs, ak, w))])
        # decision vector (z_0, a_0, z_1, a_1, …, z_N), scaled; z_0 is fixed by equal simple bounds
        # (set per solve); constraints stage by stage [gap_0, path_0, gap_1, …] with
        # gap_k = F(z_k, a_k) − z_{k+1} (the layout HPIPM detects)
        V = ca.MX.sym("V", nb * N + NX)
        B = ca.reshape(V[:nb * N], nb, N)
        Xn = ca.horzcat(B[:NX, 1:], V[nb * N:]) if N > 1 else V[nb * N:]
        P = ca.MX.sym("p", 2 * N + 4 + N)  # forecast (v̄_l, v̂_l) per interval, weights, stage weights
        W, WT, SW = ca.reshape(P[:2 * N], 2, N), P[2 * N:2 * N + 4], P[2 * N + 4:]
        G, Js = stage.map(N, "serial")(B[:NX, :], B[NX, :], Xn, W, ca.repmat(WT, 1, N), SW.T)
        self._nlp = {"x": V, "p": P, "f": ca.sum2(Js), "g": ca.vec(G)}
        lbg_k = np.concatenate([np.zeros(NX), np.asarray(self._path_lb, float)])
        ubg_k = np.concatenate([np.zeros(NX), np.asarray(self._path_ub, float)])
        self._lbg, self._ubg = np.tile(lbg_k, N), np.tile(ubg_k, N)
        self._ng_stage = lbg_k.size
        xl, xu = following_state_bounds(s.bounds)
        xl, xu = np.asarray(xl, float) / X_SCALE, np.asarray(xu, float) / X_SCALE
        lbx = np.tile(np.concatenate([xl, [s.bounds.a_min]]), N)
        ubx = np.tile(np.concatenate([xu, [s.bounds.a_max]]), N)
        self._lbx, self._ubx = np.concatenate([lbx, xl]), np.concatenate([ubx, xu])
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
            qp_opts = _qp_options(s.qp_solver)
            if s.qp_solver == "osqp":
                qp_opts["warm_start_primal"] = True
            opts = {"qpsol": s.qp_solver, "qpsol_options": qp_opts,
                    "hessian_approximation": "exact", "max_iter": s.max_iter, "tol_pr": s.tol * 100,
                    "tol_du": s.tol * 100, "print_header": s.verbose, "print_iteration": s.verbose,
                    "print_status": s.verbose, "min_step_size": 1e-12, **_SQP_EXTRA}
            self._fast = self._nlpsol("mpc_sqp", "sqpmethod", opts)
        elif s.solver == "rti":
            self._build_rti()
        # 'ipopt-cold': the cold IPOPT at every step

    def _build_rti(self) -> None:
        """The QP of one SQP step at a primal-dual point (x, λ_g) of the scaled NLP, stage by stage:
        H = ∇²_x(f + λ_gᵀg) (block diagonal: the stage (z_k, a_k) blocks; gap_k is linear in
        z_{k+1}), ∇f, A = ∂g/∂x (banded), g's bound offsets and the step bounds; one mapped stage
        function, compiled to C when codegen is on. The QP (step dx, new multipliers) is solved by
        ``ca.conic`` (HPIPM detects the OCP structure from the sparsity)."""
        s = self.settings
        N, nb, ngs = s.N, NX + 1, self._ng_stage
        xs = ca.DM(X_SCALE)
        zk, ak, zn = ca.SX.sym("zk", NX), ca.SX.sym("ak"), ca.SX.sym("zn", NX)
        w, wt, sw, lk = ca.SX.sym("w", 2), ca.SX.sym("wt", 4), ca.SX.sym("sw"), ca.SX.sym("lk", ngs)
        u = ca.vertcat(zk, ak)
        ck = ca.vertcat(self.step(zk * xs, ak, w) / xs, self.path(zk * xs, ak))  # g_k + (z_{k+1}; 0)
        cost = sw * s.dt * ca.dot(wt, self.terms(zk * xs, ak, w))
        Hk = ca.densify(ca.hessian(cost + ca.dot(lk, ck), u)[0])
        Jk = ca.densify(ca.jacobian(ck, u))
        gk = ck - ca.vertcat(zn, ca.SX.zeros(ngs - NX))
        stage = ca.Function("mpc_rti_stage", [zk, ak, zn, w, wt, sw, lk],
                            [Hk, ca.gradient(cost, u), Jk, gk, cost])
        V, P = ca.MX.sym("x", self.nv), ca.MX.sym("p", self.np_)
        LAM, LBX, UBX = ca.MX.sym("lam_g", self.ng), ca.MX.sym("lbx", self.nv), ca.MX.sym("ubx", self.nv)
        B = ca.reshape(V[:nb * N], nb, N)
        Xn = ca.horzcat(B[:NX, 1:], V[nb * N:]) if N > 1 else V[nb * N:]
        W, WT, SW = ca.reshape(P[:2 * N], 2, N), P[2 * N:2 * N + 4], P[2 * N + 4:]
        Hs, Qs, Js, Gs, Cs = stage.map(N, "serial")(B[:NX, :], B[NX, :], Xn, W, ca.repmat(WT, 1, N), SW.T,
                                                     ca.reshape(LAM, ngs, N))
        H = ca.diagcat(*ca.horzsplit(Hs, nb), ca.MX(NX, NX))
        E = ca.DM(self.ng, self.nv)  # −I of gap_k in z_{k+1}
        for k in range(N):
            for i in range(NX):
                E[k * ngs + i, (k + 1) * nb + i] = -1.0
        A = ca.horzcat(ca.diagcat(*ca.horzsplit(Js, nb)), ca.MX(self.ng, NX)) + ca.sparsify(E)
        g = ca.vec(Gs)
        qpdata = ca.Function("mpc_rti_qp_data", [V, P, LAM, LBX, UBX],
                             [H, ca.vertcat(ca.vec(Qs), ca.MX.zeros(NX)), A, ca.DM(self._lbg) - g,
                              ca.DM(self._ubg) - g, LBX - V, UBX - V, ca.sum2(Cs), g],
                             ["x", "p", "lam_g", "lbx", "ubx"],
                             ["h", "g", "a", "lba", "uba", "lbdx", "ubdx", "f", "gx"])
        # objective and constraints only (cost and nonlinear violation of the returned plan)
        fg = ca.Function("mpc_rti_fg", [self._nlp["x"], self._nlp["p"]], [self._nlp["f"], self._nlp["g"]],
                         ["x", "p"], ["f", "g"])
        self._rti_data, self._rti_fg = qpdata, fg
        if s.codegen:
            def generate() -> None:
                cg = ca.CodeGenerator("mpc_rti.c")
                cg.add(qpdata)
                cg.add(fg)
                cg.generate()

            lib = self._compile_c("mpc_rti", generate, "mpc_rti.c")
            if lib is not None:
                self.codegen_active = True
                self._rti_data = ca.external("mpc_rti_qp_data", lib)
                self._rti_fg = ca.external("mpc_rti_fg", lib)
        if not self.codegen_active:
            self._rti_data, self._rti_fg = qpdata.expand(), fg.expand()
        self._rti_qp = ca.conic("mpc_rti_qp", s.qp_solver, {"h": H.sparsity(), "a": A.sparsity()},
                                _qp_options(s.qp_solver))
        self._rti_path0 = ca.Function("mpc_rti_path0", [V], [self.path(V[:NX] * xs, V[NX])])
        self._rti_path0_lb = np.asarray(self._path_lb, float)
        self._rti_path0_ub = np.asarray(self._path_ub, float)

    # ------------------------------------------------------------------ helpers
    def _params(self, z0: np.ndarray, w: np.ndarray, weights: FollowingWeights | None,
                stage_weights: np.ndarray | None) -> np.ndarray:
        wt = weights or self.settings.weights
        sw = np.ones(self.settings.N) if stage_weights is None else np.asarray(stage_weights, float).ravel()
        if sw.size != self.settings.N or not np.all(np.isfinite(sw)) or np.any(sw < 0):
            raise ParameterError(f"MPC stage_weights must be {self.settings.N} finite numbers >= 0")
        return np.concatenate([w.ravel(order="F"), [wt.w_Q, wt.w_V, wt.w_r, wt.w_a], sw])

    def guess(self, z0: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Cold-start primal guess (scaled NLP vector): the closed-form law rolled out over the horizon."""
        Zn, A = self._rollout(ca.DM(z0), ca.DM(w))
        Z = np.hstack([np.asarray(z0, float).reshape(NX, 1), np.asarray(Zn)]) / X_SCALE[:, None]
        A = np.asarray(A).reshape(1, -1)
        return np.concatenate([np.vstack([Z[:, :-1], A]).ravel(order="F"), Z[:, -1]])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(X (5, N+1) in physical units, a (N,)) from the scaled NLP vector."""
        N, nb = self.settings.N, NX + 1
        blocks = x[:nb * N].reshape(N, nb).T
        X = np.hstack([blocks[:NX], x[nb * N:].reshape(NX, 1)]) * X_SCALE[:, None]
        return X, blocks[NX].copy()

    def _shift(self, z0: np.ndarray, w: np.ndarray) -> dict[str, np.ndarray]:
        """Warm start from the previous solution shifted by one interval: (z_1, a_1, …, z_N, a_{N−1},
        F(z_N, a_{N−1})), z_0 replaced by the measurement; multipliers shifted the same way."""
        prev = self._warm
        assert prev is not None
        N, nb, ngs = self.settings.N, NX + 1, self._ng_stage

        def shift_v(v: np.ndarray, new_last: np.ndarray) -> np.ndarray:
            blocks = v[:nb * N].reshape(N, nb)
            nbk = np.vstack([blocks[1:], np.concatenate([v[nb * N:], blocks[-1, NX:]])])
            return np.concatenate([nbk.ravel(), new_last])

        x = prev["x"]
        zN = x[nb * N:] * X_SCALE
        z_ext = np.asarray(self.step(zN, x[nb * N - 1], w[:, -1])).ravel() / X_SCALE
        z_ext = np.clip(z_ext, self._lbx[-NX:], self._ubx[-NX:])
        x0 = shift_v(x, z_ext)
        x0[:NX] = z0 / X_SCALE
        lam_x = prev["lam_x"]
        g_st = prev["lam_g"].reshape(N, ngs)
        lg = np.vstack([g_st[1:], g_st[-1:]]).ravel()
        return {"x0": x0, "lam_x0": shift_v(lam_x, lam_x[nb * N:]), "lam_g0": lg}

    def _violation(self, x: np.ndarray, g: np.ndarray, lbx: np.ndarray, ubx: np.ndarray) -> float:
        vg = np.maximum(np.maximum(self._lbg - g, g - self._ubg), 0.0)
        vx = np.maximum(np.maximum(lbx - x, x - ubx), 0.0)
        return float(max(vg.max(initial=0.0), vx.max(initial=0.0)))

    def reset(self) -> None:
        """Forget the warm start (the next solve starts cold from the closed-form-law guess)."""
        self._warm = None

    # ------------------------------------------------------------------ solving
    def solve(self, z0: np.ndarray, v_mean: np.ndarray, v_hat: np.ndarray, *,
              weights: FollowingWeights | None = None, stage_weights: np.ndarray | None = None) -> MPCSolution:
        """Solve from the measured state z0 = (h, v, V1, V2, S) with the forecast per interval:
        v_mean (N,) interval-mean leader speed and v_hat (N,) leader speed at the interval starts
        [model speed]. ``weights`` overrides the settings' weights for this solve (no rebuild).
        Never raises on solver failure: returns success=False with a status."""
        s = self.settings
        N = s.N
        z0 = np.asarray(z0, float).ravel()
        if z0.size != NX or not np.all(np.isfinite(z0)):
            raise ParameterError(f"MPC: z0 must be 5 finite numbers (h, v, V1, V2, S), got {z0!r}")
        vm_, vh_ = np.asarray(v_mean, float).ravel(), np.asarray(v_hat, float).ravel()
        if vm_.size != N or vh_.size != N or not (np.all(np.isfinite(vm_)) and np.all(np.isfinite(vh_))):
            raise ParameterError(f"MPC: the leader forecast (v_mean, v_hat) must be N = {N} finite values each, "
                                 f"got {vm_.size} and {vh_.size}")
        w = np.vstack([vm_, vh_])
        p = self._params(z0, w, weights, stage_weights)
        warm = self._warm is not None and s.solver != "ipopt-cold"
        if warm:
            args = self._shift(z0, w)
            solver, path = self._fast, s.solver
        else:
            args = {"x0": self.guess(z0, w)}
            solver, path = self._cold, "ipopt-cold"
        lbx, ubx = self._lbx.copy(), self._ubx.copy()
        lbx[:NX] = ubx[:NX] = z0 / X_SCALE
        if warm and s.solver == "rti":
            return self._solve_rti(args, p, lbx, ubx)
        t0 = time.perf_counter()
        try:
            out = solver(p=p, lbx=lbx, ubx=ubx, lbg=self._lbg, ubg=self._ubg, **args)
            err = None
        except RuntimeError as exc:  # e.g. NaN in a function evaluation that the solver did not catch
            out, err = None, str(exc).splitlines()[0][:200]
        dt_wall = time.perf_counter() - t0
        if out is None:
            self._warm = None
            return MPCSolution(False, f"exception: {err}", 0, dt_wall, np.full((NX, N + 1), np.nan),
                               np.full(N, np.nan), float("nan"), float("inf"), path)
        st = solver.stats()
        x, g = np.asarray(out["x"]).ravel(), np.asarray(out["g"]).ravel()
        viol = self._violation(x, g, lbx, ubx)
        status = str(st.get("return_status", st.get("unified_return_status", "")))
        success = bool(st.get("success", False)) and viol < 1e-6 and np.all(np.isfinite(x))
        iters = int(st.get("iter_count", st.get("iterations", {}).get("iter", [0])[-1]
                           if isinstance(st.get("iterations"), dict) else 0))
        X, a = self.unpack(x)
        if success:
            self._warm = {"x": x, "lam_x": np.asarray(out["lam_x"]).ravel(), "lam_g": np.asarray(out["lam_g"]).ravel()}
        else:
            self._warm = None
        return MPCSolution(success, status, iters, dt_wall, X, a, float(out["f"]), viol, path,
                           {"t_wall_solver": float(st.get("t_wall_total", float("nan")))})

    def _solve_rti(self, args: dict[str, np.ndarray], p: np.ndarray, lbx: np.ndarray,
                   ubx: np.ndarray) -> MPCSolution:
        """``rti_iterations`` full SQP steps from the shifted previous solution (see :meth:`_build_rti`).
        Success: every QP solved, a finite step, and the applied control's path constraints (pack
        current, current map at node 0, where the state is the measurement) hold on the exact model."""
        s = self.settings
        N = s.N
        data, qp = self._rti_data, self._rti_qp
        t0 = time.perf_counter()
        x, lam_g, lam_x = args["x0"], args["lam_g0"], args["lam_x0"]
        ok, status, it, step = True, "", 0, float("inf")
        try:
            while it < s.rti_iterations:
                d = data(x, p, lam_g, lbx, ubx)
                out = qp(h=d[0], g=d[1], a=d[2], lba=d[3], uba=d[4], lbx=d[5], ubx=d[6])
                it += 1
                st = qp.stats()
                dx = np.asarray(out["x"]).ravel()
                if not st.get("success", False) or not np.all(np.isfinite(dx)):
                    ok, status = False, f"QP failed: {st.get('return_status', '')}"
                    break
                x = x + dx
                lam_g, lam_x = np.asarray(out["lam_a"]).ravel(), np.asarray(out["lam_x"]).ravel()
                step = float(np.abs(dx).max())
                if step <= s.tol:
                    break
            c0 = np.asarray(self._rti_path0(x)).ravel() if ok else None
        except RuntimeError as exc:
            ok, status, c0 = False, f"exception: {str(exc).splitlines()[0][:200]}", None
        dt_wall = time.perf_counter() - t0
        viol0 = float("inf")
        if c0 is not None:
            viol0 = float(np.maximum(np.maximum(self._rti_path0_lb - c0, c0 - self._rti_path0_ub), 0).max(initial=0))
            if not np.isfinite(viol0) or viol0 > 1e-6:
                ok, status = False, f"applied control violates the path constraints by {viol0:.3g}"
        if not ok:
            self._warm = None
            return MPCSolution(False, status, it, dt_wall, np.full((NX, N + 1), np.nan), np.full(N, np.nan),
                               float("nan"), viol0, "rti")
        # plan, cost and the nonlinear constraint violation of the plan (the RTI plan is feasible only
        # to first order; reported, not required)
        f, g = self._rti_fg(x, p)
        viol = self._violation(x, np.asarray(g).ravel(), lbx, ubx)
        X, a = self.unpack(x)
        self._warm = {"x": x, "lam_x": lam_x, "lam_g": lam_g}
        return MPCSolution(True, "RTI_Step" if step > s.tol else "RTI_Converged", it, dt_wall, X, a,
                           float(f), viol, "rti", {"step_inf": step, "node0_violation": viol0})

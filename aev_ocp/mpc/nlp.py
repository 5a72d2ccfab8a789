"""The MPC's horizon NLP, assembled once from an :class:`~aev_ocp.ocp.problem.OCPProblem` on the shared interval
function of the whole-horizon transcription (:func:`aev_ocp.ocp.transcription.interval_function`, multiple
shooting, RK4), and the NLP solvers built on it (IPOPT, sqpmethod; compiled to C when codegen is on):

    min Σ_k s_k J_k(z_k, u_k)  (J_k = stage cost·dt + integral cost over interval k) + terminal cost
    s.t. z_{k+1} = F(z_k, u_k, w_k, p), path constraints at nodes 0…N−1, simple bounds at 1…N.

NLP parameters (nothing is rebuilt between solves or weight sweeps): the per-interval stage parameters w_k
(the forecast), the problem's parameters p and per-interval stage weights s_k. Decision variables are ordered
(z_0, u_0, z_1, u_1, …, z_N) on scaled variables (x/x_scale, u/u_scale) and constraints stage by stage, so the
KKT system is banded. The measured initial state is fixed by equal simple bounds (set per solve).

This is the public interface the RTI step (:mod:`aev_ocp.mpc.rti`) and the C export (:mod:`aev_ocp.mpc.export`)
build on: :class:`HorizonNLP` (dimensions, scaling, bounds, the interval and step functions, the cold-start
rollout, the NLP expressions, packing and unpacking of the NLP vector).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import os
import tempfile
import warnings
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable

import casadi as ca
import numpy as np

from ..compiled import compile_shared, compiler
from ..models.carfollowing import CarFollowingLaw
from ..numerics import rk4
from ..ocp.problem import OCPProblem
from ..ocp.transcription import TranscriptionOptions, horizon_nlp, interval_function, with_discrete_update
from ..params import remember
from .settings import MPCSettings

_SQP_EXTRA: dict[str, Any] = {}
_PLUGIN_GEN_OPTS: dict[str, dict[str, Any]] = {
    "sqpmethod": {
        "print_header": False,
        "qpsol": "qrqp",
        "qpsol_options": {"print_info": False, "print_header": False, "print_iter": False},
    }
}

#: nlpsol Functions built in this process, by a hash of what each was built from (name, plugin, the NLP's whole
#: graph or its compiled library's path, and the options), the most recently used last. Controllers of the same
#: problem and settings (the vehicles of a platoon, the runs of a sweep, a controller built again on the same
#: settings) share one solver instead of each expanding the NLP and its exact Hessian again (~1 s at N = 40, issue
#: 40). An nlpsol keeps nothing from one call to the next that changes a result (each controller already calls its
#: own many times), and every caller reads the solver's stats right after its own call.
_NLPSOLS: "OrderedDict[str, ca.Function]" = OrderedDict()
NLPSOL_MEMO_SIZE = 32  # keys kept, two per solver at most (an N = 40 expanded IPOPT holds a few MB)


def shared_nlpsol(name: str, plugin: str, problem: dict[str, Any] | str, opts: dict[str, Any]) -> ca.Function:
    """``ca.nlpsol(name, plugin, problem, opts)``, built once per process for the same name, plugin, problem (its
    serialized graph: equal bit for bit, constants included; or the same compiled library) and options."""
    keys = [_nlpsol_key(name, plugin, problem, opts)]
    f = _NLPSOLS.get(keys[0])
    if f is None:
        f = ca.nlpsol(name, plugin, problem, opts)
        # building the solver leaves derivatives cached in the Functions its graph calls (e.g. the OCV's B-spline),
        # which their serialization holds: the same problem built next has the graph as it is now
        keys.append(_nlpsol_key(name, plugin, problem, opts))
    for k in keys:
        _NLPSOLS[k] = f
        _NLPSOLS.move_to_end(k)
    while len(_NLPSOLS) > NLPSOL_MEMO_SIZE:
        _NLPSOLS.popitem(last=False)
    return f


def _nlpsol_key(name: str, plugin: str, problem: dict[str, Any] | str, opts: dict[str, Any]) -> str:
    """A hash of the name, plugin, options and problem (the serialized graph of the NLP dict, or the library path)."""
    if isinstance(problem, str):
        what = problem.encode()
    else:
        what = ca.Function("nlp", [problem["x"], problem["p"]], [problem["f"], problem["g"]]).serialize().encode()
    h = hashlib.sha256("\0".join((name, plugin, json.dumps(opts, sort_keys=True, default=repr))).encode())
    h.update(b"\0" + what)
    return h.hexdigest()


class HorizonNLP:
    """The horizon-N NLP of a closed-loop problem (see the module docstring), assembled once.

    Attributes: ``nx``, ``nu`` (states, controls), ``x_scale``, ``u_scale``; ``F`` the interval function
    (scaled; (xk, uk, xc, xn, w, p, h) -> (eq, path, J)); ``step`` the one-interval model
    (z, u, w, p) -> z_next [model units]; ``rollout`` the cold-start guess (the closed-form law rolled out over
    the horizon, mapaccum over N); ``nlp`` the NLP dict (x, p, f, g: MX); ``lbg``/``ubg``, ``lbx``/``ubx`` its
    bounds (scaled; the initial state's set per solve); ``ng_stage`` constraint rows per interval (dynamics,
    then path); ``nv``, ``ng``, ``np_`` its sizes."""

    def __init__(self, problem: OCPProblem, settings: MPCSettings, guess_law: CarFollowingLaw) -> None:
        self.problem, self.settings, self.guess_law = problem, settings, guess_law
        self._build_model()
        self._build_nlp()

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
        # the same step, states clipped to their bounds. The bounds lo = (x_lb, u_lb), hi = (x_ub, u_ub) (an
        # infinite state bound as ±1e20) and the law's coefficients q are inputs, so the compiled step's C does not
        # hold them (issue 40): ``rollout_inputs`` are their values
        make_law, q_val = law_parameters(self.guess_law)
        lo, hi, q = ca.SX.sym("lo", nx + nu), ca.SX.sym("hi", nx + nu), ca.SX.sym("q", q_val.size)
        law = make_law(q)
        ag = ca.fmin(ca.fmax(law.accel(ca.fmax(z[0], 1e-2), z[1], w[1]), lo[nx]), hi[nx])
        ug = ca.vertcat(ag, ca.fmin(ca.fmax(ca.DM.zeros(nu - 1), lo[nx + 1 :]), hi[nx + 1 :])) if nu > 1 else ag
        zg = self.step(z, ug, w, p)
        zg = ca.fmin(ca.fmax(zg, lo[:nx]), hi[:nx])
        self.rollout = ca.Function("mpc_rollout", [z, w, p, lo, hi, q], [zg, ug]).mapaccum(s.N)
        self.rollout_inputs = (
            np.concatenate([np.where(np.isfinite(xl), xl, -1e20), ul]),
            np.concatenate([np.where(np.isfinite(xu), xu, 1e20), uu]),
            q_val,
        )

    # ------------------------------------------------------------------ NLP
    def stage_inputs(self, V: Any, P: Any) -> tuple[Any, ...]:
        """(X_k (nx, N), U_k (nu, N), X_{k+1} (nx, N), W (nw, N), p, SW (1, N)) of the scaled NLP vector V and
        the NLP parameter vector P (symbols)."""
        pr, N = self.problem, self.settings.N
        nx, nb = pr.nx, pr.nx + pr.nu
        B = ca.reshape(V[: nb * N], nb, N)
        Xn = ca.horzcat(B[:nx, 1:], V[nb * N :]) if N > 1 else V[nb * N :]
        nwN = pr.nw * N
        return (B[:nx, :], B[nx:, :], Xn, ca.reshape(P[:nwN], pr.nw, N), P[nwN : nwN + pr.np_], P[nwN + pr.np_ :].T)

    def _build_nlp(self) -> None:
        s, pr = self.settings, self.problem
        N, nx, nu = s.N, pr.nx, pr.nu
        nb = nx + nu
        V = ca.MX.sym("V", nb * N + nx)
        P = ca.MX.sym("p", pr.nw * N + pr.np_ + N)  # stage parameters per interval, p, stage weights
        W, PP, SW = self.stage_inputs(V, P)[3:]
        # the one horizon NLP of the transcription (as OCP-D's), on the MPC's parameters and stage weights; the
        # measured initial state is fixed by equal simple bounds (per solve)
        hz = horizon_nlp(
            pr,
            TranscriptionOptions(method="ms", N=N, rk4_substeps=s.rk4_substeps),
            V,
            W,
            PP,
            s.dt,
            stage_weights=SW,
            interval=self.F,
        )
        self.nlp = {"x": V, "p": P, "f": hz.objective, "g": ca.vertcat(*hz.g)}
        self.lbg, self.ubg = np.concatenate(hz.lbg), np.concatenate(hz.ubg)
        self.ng_stage = hz.n_eq + hz.n_path
        (xl, xu), (ul, uu) = self._xb, self._ub
        xl_s, xu_s = xl / self.x_scale, xu / self.x_scale
        self.lbx = np.concatenate([np.tile(np.concatenate([xl_s, ul / self.u_scale]), N), xl_s])
        self.ubx = np.concatenate([np.tile(np.concatenate([xu_s, uu / self.u_scale]), N), xu_s])
        self.nv, self.ng, self.np_ = V.numel(), self.lbg.size, P.numel()

    # ------------------------------------------------------------------ vectors
    def w_and_p(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(W (nw, N), p) back from the NLP parameter vector."""
        pr, N = self.problem, self.settings.N
        return p[: pr.nw * N].reshape(N, pr.nw).T, p[pr.nw * N : pr.nw * N + pr.np_]

    def guess(self, z0: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Cold-start primal guess (scaled NLP vector): the closed-form law rolled out over the horizon."""
        W, pp = self.w_and_p(p)
        N = self.settings.N
        lo, hi, q = (np.repeat(v.reshape(-1, 1), N, axis=1) for v in self.rollout_inputs)
        Zn, U = self.rollout(ca.DM(z0), W, np.repeat(pp.reshape(-1, 1), N, axis=1), lo, hi, q)
        Z = np.hstack([np.asarray(z0, float).reshape(self.nx, 1), np.asarray(Zn)]) / self.x_scale[:, None]
        U = np.asarray(U).reshape(self.nu, -1) / self.u_scale[:, None]
        return np.concatenate([np.vstack([Z[:, :-1], U]).ravel(order="F"), Z[:, -1]])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X (nx, N+1), a (N,), U (nu, N)) in physical units from the scaled NLP vector."""
        N, nx, nb = self.settings.N, self.nx, self.nx + self.nu
        blocks = x[: nb * N].reshape(N, nb).T
        X = np.hstack([blocks[:nx], x[nb * N :].reshape(nx, 1)]) * self.x_scale[:, None]
        U = blocks[nx:] * self.u_scale[:, None]
        return X, U[0].copy(), U

    def shift(self, prev: dict[str, np.ndarray], z0: np.ndarray, p: np.ndarray) -> dict[str, np.ndarray]:
        """Warm start from the previous solution ``prev`` (x, lam_x, lam_g) shifted by one interval: (z_1, u_1,
        …, z_N, u_{N−1}, F(z_N, u_{N−1})), z_0 replaced by the measurement; multipliers shifted the same way."""
        N, nx, nb, ngs = self.settings.N, self.nx, self.nx + self.nu, self.ng_stage

        def shift_v(v: np.ndarray, new_last: np.ndarray) -> np.ndarray:
            blocks = v[: nb * N].reshape(N, nb)
            nbk = np.vstack([blocks[1:], np.concatenate([v[nb * N :], blocks[-1, nx:]])])
            return np.concatenate([nbk.ravel(), new_last])

        x = prev["x"]
        W, pp = self.w_and_p(p)
        zN = x[nb * N :] * self.x_scale
        uN = x[nb * N - self.nu : nb * N] * self.u_scale
        z_ext = np.asarray(self.step(zN, uN, W[:, -1], pp)).ravel() / self.x_scale
        z_ext = np.clip(z_ext, self.lbx[-nx:], self.ubx[-nx:])
        x0 = shift_v(x, z_ext)
        x0[:nx] = z0 / self.x_scale
        lam_x = prev["lam_x"]
        lg = prev["lam_g"]
        g_st = lg[: N * ngs].reshape(N, ngs)
        lg = np.concatenate([np.vstack([g_st[1:], g_st[-1:]]).ravel(), lg[N * ngs :]])
        return {"x0": x0, "lam_x0": shift_v(lam_x, lam_x[nb * N :]), "lam_g0": lg}

    def violation(self, x: np.ndarray, g: np.ndarray, lbx: np.ndarray, ubx: np.ndarray) -> float:
        """Largest violation of the constraints (g against lbg/ubg) and the simple bounds (NLP units)."""
        vg = np.maximum(np.maximum(self.lbg - g, g - self.ubg), 0.0)
        vx = np.maximum(np.maximum(lbx - x, x - ubx), 0.0)
        return float(max(vg.max(initial=0.0), vx.max(initial=0.0)))

    # ------------------------------------------------------------------ solvers
    def compile(self, plugin: str) -> str | None:
        """C code of the NLP functions (objective, constraints, their Jacobians and the Lagrangian
        Hessian) of nlpsol ``plugin``, compiled once (see :func:`compile_c`)."""
        gen = ca.nlpsol("mpc_nlp", plugin, self.nlp, {**_PLUGIN_GEN_OPTS.get(plugin, {})})
        return compile_c(f"mpc_nlp_{plugin}", lambda: gen.generate_dependencies("mpc_nlp.c"), "mpc_nlp.c")

    def nlpsol(self, name: str, plugin: str, opts: dict[str, Any]) -> tuple[ca.Function, bool]:
        """(nlpsol on the compiled library of the NLP functions when codegen is on and works, else on the
        symbolic NLP expanded to SX; whether it is compiled), one per process for the same NLP and options
        (:func:`shared_nlpsol`)."""
        base = {"print_time": False, "error_on_fail": False}
        if self.settings.codegen:
            lib = self.compile(plugin)
            if lib is not None:
                return shared_nlpsol(name, plugin, lib, {**base, **opts}), True
        return shared_nlpsol(name, plugin, self.nlp, {**base, "expand": True, **opts}), False

    def ipopt(self, name: str, warm: bool) -> tuple[ca.Function, bool]:
        """IPOPT on the NLP (exact Hessian, MUMPS), cold or warm-started; see :meth:`nlpsol`."""
        s = self.settings
        ip: dict[str, Any] = {
            "print_level": 5 if s.verbose else 0,
            "sb": "yes",
            "tol": s.tol,
            "max_iter": s.max_iter,
            "linear_solver": "mumps",
            "hessian_approximation": "exact",
            "nlp_scaling_method": "none" if warm else "gradient-based",
        }
        if warm:
            ip.update(
                {
                    "warm_start_init_point": "yes",
                    "warm_start_bound_push": 1e-9,
                    "warm_start_mult_bound_push": 1e-9,
                    "warm_start_slack_bound_push": 1e-9,
                    "mu_init": 1e-5,
                    "mu_strategy": "monotone",
                    "nlp_scaling_method": "gradient-based",
                }
            )
        if s.budget == "wall":  # real time only: in simulation max_iter bounds IPOPT, the clock decides nothing
            ip["max_wall_time"] = s.max_cpu_time_s
        return self.nlpsol(name, "ipopt", {"ipopt": ip})

    def sqp(self, qp_opts: dict[str, Any]) -> tuple[ca.Function, bool]:
        """CasADi's sqpmethod on the NLP (exact Hessian, the QP solver ``settings.qp`` with ``qp_opts``)."""
        s = self.settings
        opts = {
            "qpsol": s.qp,
            "qpsol_options": qp_opts,
            "hessian_approximation": "exact",
            "max_iter": s.max_iter,
            "tol_pr": s.tol * 100,
            "tol_du": s.tol * 100,
            "print_header": s.verbose,
            "print_iteration": s.verbose,
            "print_status": s.verbose,
            "min_step_size": 1e-12,
            **_SQP_EXTRA,
        }
        return self.nlpsol("mpc_sqp", "sqpmethod", opts)


#: HorizonNLPs built in this process, by (the problem's id, the settings, the guess law); each entry holds its problem,
#: so the id names it as long as the entry lives. The MPCs of a platoon, a sweep or a study's points, built on the
#: one problem :meth:`aev_ocp.ocp.formulation.Formulation.mpc_problem` keeps per (formulation, vehicle, dt, OCV form),
#: share one horizon NLP and the C generated from it, which they read and never change (issue 40: ~80 ms of a
#: default MPC's 84 ms build, a third of it assembling the NLP, the rest its step's C for the compile cache's key).
_HORIZONS: dict[tuple[int, MPCSettings, CarFollowingLaw], tuple[OCPProblem, HorizonNLP]] = {}
HORIZONS_KEPT = 16


def shared_horizon_nlp(problem: OCPProblem, settings: MPCSettings, guess_law: CarFollowingLaw) -> HorizonNLP:
    """``HorizonNLP(problem, settings, guess_law)``, built once per process for the same problem object and equal
    settings and guess law (:data:`_HORIZONS`); a guess law that cannot be a key (unhashable) gets its own. For
    problems nothing changes once built (a built-in formulation's, :meth:`Formulation.mpc_problem`)."""
    try:
        key = (id(problem), settings, guess_law)
        hash(key)
    except TypeError:
        return HorizonNLP(problem, settings, guess_law)
    hit = _HORIZONS.get(key)
    if hit is not None and hit[0] is problem:
        return hit[1]
    return remember(_HORIZONS, key, (problem, HorizonNLP(problem, settings, guess_law)), HORIZONS_KEPT)[1]


def law_parameters(law: CarFollowingLaw) -> tuple[Callable[[Any], CarFollowingLaw], np.ndarray]:
    """(make, values): ``make(q)`` is the closed-form law with its float coefficients (those not in its
    ``compile_constants``) replaced by the entries of q, ``values`` their numbers; a law that is not a dataclass,
    or whose accel gives other numbers with symbolic coefficients (1e-12 relative at probe points), keeps its
    numbers (values empty)."""
    names = (
        [
            f.name
            for f in dataclasses.fields(law)
            if isinstance(getattr(law, f.name), float) and f.name not in getattr(law, "compile_constants", ())
        ]
        if dataclasses.is_dataclass(law)
        else []
    )

    def make(q: Any) -> CarFollowingLaw:
        twin = copy.copy(law)
        for j, nm in enumerate(names):
            object.__setattr__(twin, nm, q[j])  # validation ran on law
        return twin

    values = np.array([float(getattr(law, nm)) for nm in names])
    if names:
        try:
            h, v, vl, q = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl"), ca.SX.sym("q", len(names))
            f = ca.Function("probe", [h, v, vl, q], [make(q).accel(h, v, vl)])
            for pt in ((1.3, 0.9, 1.1), (2.7, 1.6, 1.45), (0.6, 0.2, 0.35), (0.21, 1.9, 0.02)):
                ref = float(law.accel(*pt))
                if not abs(float(f(*pt, values)) - ref) <= 1e-12 * (1.0 + abs(ref)):
                    raise ValueError("symbolic coefficients change the law")
            return make, values
        except (TypeError, ValueError, RuntimeError, NotImplementedError):
            pass
    return (lambda q: law), np.zeros(0)


def compile_c(stem: str, generate: Any, cfile: str) -> str | None:
    """Run ``generate()`` (writes ``cfile`` into the current folder) in a temporary folder and
    compile the C file into the private cache (:func:`aev_ocp.compiled.compile_shared`, keyed by
    the source's hash). Returns the shared library's path, or None (with a warning) when no
    compiler works."""
    if compiler() is None:
        warnings.warn(
            "MPC codegen requested but no C compiler (gcc) was found: using the interpreted CasADi functions instead",
            RuntimeWarning,
            stacklevel=5,
        )
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
        warnings.warn(
            f"MPC codegen failed ({type(exc).__name__}: {str(exc)[:200]}): using the "
            "interpreted CasADi functions instead",
            RuntimeWarning,
            stacklevel=5,
        )
        return None
    built = compile_shared(src, stem, "mpc")
    if built.path is None:
        warnings.warn(
            f"MPC codegen failed ({built.error}): using the interpreted CasADi functions instead",
            RuntimeWarning,
            stacklevel=5,
        )
        return None
    return str(built.path)


def rti_stage_functions(nlp: HorizonNLP) -> tuple[ca.Function, ca.Function]:
    """The QP of one SQP step, stage by stage (SX, shared by :class:`aev_ocp.mpc.rti.RTIStep` and the exported step's
    ``aev_cg_qpdata``): ``mpc_rti_stage(z_k, u_k, z_{k+1}, w_k, p, stage weight, λ_k) -> (H_k, q_k, J_k, g_k,
    cost_k)``: the Lagrangian Hessian block ∇²(cost + λ_kᵀc_k) in (z_k, u_k), the cost gradient, the
    Jacobian of c_k = (interval end state; path constraints) and c_k − (z_{k+1}; 0); and
    ``mpc_rti_terminal(x_N scaled, p) -> (H_N, q_N, terminal cost)``, the Mayer term's."""
    s, pr = nlp.settings, nlp.problem
    nx, nu, ngs = pr.nx, pr.nu, nlp.ng_stage
    zk, uk = ca.SX.sym("zk", nx), ca.SX.sym("uk", nu)
    zn, w, pp = ca.SX.sym("zn", nx), ca.SX.sym("w", pr.nw), ca.SX.sym("p", pr.np_)
    sw, lk = ca.SX.sym("sw"), ca.SX.sym("lk", ngs)
    u = ca.vertcat(zk, uk)
    eq, path, J = nlp.F(zk, uk, ca.SX(0, 1), ca.SX.zeros(nx), w, pp, s.dt)
    ck = ca.vertcat(eq, path)  # g_k + (z_{k+1}; 0): the interval's end state and the path constraints
    cost = sw * J
    Hk = ca.densify(ca.hessian(cost + ca.dot(lk, ck), u)[0])
    Jk = ca.densify(ca.jacobian(ck, u))
    gk = ck - ca.vertcat(zn, ca.SX.zeros(ngs - nx))
    stage = ca.Function("mpc_rti_stage", [zk, uk, zn, w, pp, sw, lk], [Hk, ca.gradient(cost, u), Jk, gk, cost])
    # terminal cost (Mayer) on the scaled x_N: its Hessian block and gradient
    xNs, pT = ca.SX.sym("xN", nx), ca.SX.sym("pT", pr.np_)
    mayer = pr.terminal_cost(xNs * ca.DM(nlp.x_scale), pT) if pr.terminal_cost is not None else ca.SX(0)
    term = ca.Function(
        "mpc_rti_terminal", [xNs, pT], [ca.densify(ca.hessian(mayer, xNs)[0]), ca.gradient(mayer, xNs), mayer]
    )
    return stage, term


#: Eigenvalue floor of the RTI Hessian's diagonal blocks, relative to (1 + the block's max |λ|) (our choice:
#: far below the curvature of every cost term, so PD blocks are unchanged and the step is undamped).
RTI_HESSIAN_FLOOR = 1e-8


def project_pd(B: np.ndarray) -> np.ndarray:
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

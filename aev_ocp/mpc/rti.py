"""The MPC's real-time iteration (solver 'rti'): one SQP step per control step on the QP of the exact Lagrangian
Hessian, each diagonal block projected onto the positive-definite cone (``rti_hessian = 'projected'``).

One step, two implementations of it:

* the product: the compiled whole step (qp_solver 'riccati', the default): the C of ``aev-ocp mpc-export``
  (aev_ocp/c/mpc_step.c driving aev_ocp/c/ocp_qp.c on CasADi-generated QP data, :mod:`aev_ocp.mpc.export`),
  loaded through ctypes (:func:`solve_compiled`);
* :class:`RTIStep`, the same step in Python with the QP solved by a CasADi ``ca.conic`` plugin (qp_solver
  'hpipm', 'qrqp', 'osqp', ...; and where the compiled step cannot be built, e.g. without a C compiler): the QP
  data of the whole horizon from one mapped stage function (compiled when codegen is on), HPIPM detecting the
  OCP structure from the sparsity. Its QP backend is one method (:meth:`RTIStep.qp_step`), so the test suite runs
  the Python twin of the C driver (tests/rti_twin.py: the stage-layout QP data solved by ocp_qp.c) as an oracle
  of the compiled step on this same loop.

Both start cold by RTI iterations from the closed-form law's rollout (traffic), or (§9) after a cold IPOPT
step. Both measure the step's wall time (reported); with ``budget = 'wall'`` (real time) they discard a step longer
than ``max_step_ms`` (cause 'budget', :mod:`aev_ocp.mpc.fallback`); with ``budget = 'counted'`` (the default, every
simulation) the iteration limits alone bound a step, so the result does not depend on the machine's load.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import casadi as ca
import numpy as np

from ..params import ParameterError
from ..plant import PLAN_TOLERANCE
from .cstep import STATUS as STEP_STATUS
from .nlp import RTI_HESSIAN_FLOOR, HorizonNLP, compile_c, project_pd, rti_stage_functions  # noqa: F401
from .ocpqp import STATUS as QP_STATUS
from .solution import MPCSolution


class RTIHost(Protocol):
    """What the RTI step needs of its controller (:class:`aev_ocp.mpc.controller.MPCController`; a Protocol, so
    this module does not import the controller): the warm start it keeps, its failed and late results, its
    horizon NLP, settings and compiled step."""

    warm: dict[str, np.ndarray] | None
    nlp: HorizonNLP
    settings: Any
    compiled_step: Any

    def failed(self, status: str, iters: int, dt_wall: float, viol: float, path: str) -> MPCSolution: ...

    def late(self, warm: dict[str, Any], iters: int, dt_wall: float, viol: float, path: str) -> MPCSolution: ...


#: HPIPM's stand-in for an infinite bound in the traffic formulation's QPs (CasADi's default 1e8 next to
#: O(1…1e3) scaled variables stalls HPIPM at its iteration limit (status 1) on the slack and epigraph
#: controls, which have no upper bound; measured: 100 iterations without convergence vs 14).
HPIPM_INF_TRAFFIC = 1e5


#: qrqp's smallest multiplier treated as nonzero (its option min_lam; CasADi's default is 0): see :func:`qp_options`
QRQP_MIN_LAM = 1e-9


def qp_options(qp_solver: str, hpipm_inf: float | None = None) -> dict[str, Any]:
    """Silent, tight options of a QP solver (the 'sqp' path's qpsol and the 'rti' path's conic)."""
    opts: dict[str, Any] = {"error_on_fail": False}
    if qp_solver == "hpipm" and hpipm_inf is not None:
        opts["inf"] = hpipm_inf
    if qp_solver == "qrqp":
        # min_lam: multipliers below 1e-9 count as zero, so a bound that is only just active (a degenerate active set)
        # does not make the active set cycle: with CasADi's default 0, the canonical closed loop's second step ran
        # qrqp into its 1000-iteration limit (1.2 s) and a fallback, from plant states 1e-9 apart (tests/test_mpc.py)
        opts.update({"print_iter": False, "print_header": False, "print_info": False, "min_lam": QRQP_MIN_LAM})
    elif qp_solver == "osqp":
        opts["osqp"] = {"verbose": False, "eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True, "max_iter": 20000}
    elif qp_solver == "hpipm":
        opts["hpipm"] = {"iter_max": 100, "warm_start": 0}
    elif qp_solver == "qpoases":
        opts.update({"printLevel": "none", "sparse": True})
    return opts


class RTIStep:
    """The real-time iteration in Python (see the module docstring): the QP of one SQP step at a primal-dual
    point (x, λ_g) of the scaled NLP, stage by stage: H = ∇²_x(f + λ_gᵀg) (block diagonal: the stage (z_k, u_k)
    blocks; gap_k is linear in z_{k+1}), ∇f, A = ∂g/∂x (banded), g's bound offsets and the step bounds; one
    mapped stage function, compiled to C when ``codegen``. :meth:`qp_step` solves it by ``ca.conic`` with
    ``qp_plugin``; :meth:`solve` runs the step. ``codegen_active``: the QP data run compiled."""

    def __init__(self, nlp: HorizonNLP, qp_plugin: str, hpipm_inf: float | None, codegen: bool) -> None:
        self.nlp = nlp
        s, pr = nlp.settings, nlp.problem
        N, nx, nu, ngs = s.N, pr.nx, pr.nu, nlp.ng_stage
        nb = nx + nu
        stage, term = rti_stage_functions(nlp)
        V, P = ca.MX.sym("x", nlp.nv), ca.MX.sym("p", nlp.np_)
        LAM, LBX, UBX = ca.MX.sym("lam_g", nlp.ng), ca.MX.sym("lbx", nlp.nv), ca.MX.sym("ubx", nlp.nv)
        LBG, UBG = ca.MX.sym("lbg", nlp.ng), ca.MX.sym("ubg", nlp.ng)  # inputs: the C holds no bound (issue 40)
        Xk, Uk, Xn, W, PP, SW = nlp.stage_inputs(V, P)
        Hs, Qs, Js, Gs, Cs = stage.map(N, "serial")(Xk, Uk, Xn, W, ca.repmat(PP, 1, N), SW, ca.reshape(LAM, ngs, N))
        HN, qN, cN = term(V[nb * N :], PP)
        H = ca.diagcat(*([ca.DM.ones(ca.Sparsity.dense(nb, nb))] * N), ca.DM.ones(ca.Sparsity.dense(nx, nx)))
        E = ca.DM(nlp.ng, nlp.nv)  # −I of gap_k in z_{k+1}
        for k in range(N):
            for i in range(nx):
                E[k * ngs + i, (k + 1) * nb + i] = -1.0
        A = ca.horzcat(ca.diagcat(*ca.horzsplit(Js, nb)), ca.MX(nlp.ng, nx)) + ca.sparsify(E)
        g = ca.vec(Gs)
        # the exact Hessian comes out as its dense diagonal blocks (hblk: the N stage blocks side by side,
        # hN: the terminal block); :meth:`regularised_hessian` projects each onto the PD cone
        qpdata = ca.Function(
            "mpc_rti_qp_data",
            [V, P, LAM, LBX, UBX, LBG, UBG],
            [
                Hs,
                HN,
                ca.vertcat(ca.vec(Qs), qN),
                A,
                LBG - g,
                UBG - g,
                LBX - V,
                UBX - V,
                ca.sum2(Cs) + cN,
                g,
            ],
            ["x", "p", "lam_g", "lbx", "ubx", "lbg", "ubg"],
            ["hblk", "hN", "g", "a", "lba", "uba", "lbdx", "ubdx", "f", "gx"],
        )
        self.H_sparsity = H.sparsity()
        # objective and constraints only (cost and nonlinear violation of the returned plan)
        fg = ca.Function(
            "mpc_rti_fg", [nlp.nlp["x"], nlp.nlp["p"]], [nlp.nlp["f"], nlp.nlp["g"]], ["x", "p"], ["f", "g"]
        )
        # path constraints of the applied control at node 0 (where the state is the measurement)
        path0 = nlp.F(V[:nx], V[nx:nb], ca.MX(0, 1), ca.MX.zeros(nx), W[:, 0], PP, s.dt)[1]
        p0 = ca.Function("mpc_rti_path0", [V, P], [path0])
        self.data, self.fg, self.path0 = qpdata, fg, p0
        self.codegen_active = False
        if codegen:

            def generate() -> None:
                cg = ca.CodeGenerator("mpc_rti.c")
                cg.add(qpdata)
                cg.add(fg)
                cg.add(p0)
                cg.generate()

            lib = compile_c("mpc_rti", generate, "mpc_rti.c")
            if lib is not None:
                self.codegen_active = True
                self.data = ca.external("mpc_rti_qp_data", lib)
                self.fg = ca.external("mpc_rti_fg", lib)
                self.path0 = ca.external("mpc_rti_path0", lib)
        if not self.codegen_active:
            self.data, self.fg, self.path0 = qpdata.expand(), fg.expand(), p0.expand()
        self.qp = ca.conic(
            "mpc_rti_qp", qp_plugin, {"h": H.sparsity(), "a": A.sparsity()}, qp_options(qp_plugin, hpipm_inf)
        )
        self.path0_lb = np.asarray(pr.path_lb, float)
        self.path0_ub = np.asarray(pr.path_ub, float)

    def regularised_hessian(self, hblk: Any, hN: Any, project: bool = True) -> ca.DM:
        """The RTI QP's Hessian from the exact Lagrangian Hessian's diagonal blocks (``hblk`` (nb, nb·N):
        the stage blocks side by side, ``hN`` (nx, nx): the terminal block), each projected onto the
        positive-definite cone: symmetric eigendecomposition, eigenvalues below
        ``RTI_HESSIAN_FLOOR·(1 + max|λ|)`` raised to that floor (a no-op where the block is safely PD).
        Block-wise projection makes the whole (block-diagonal) Hessian, hence every reduced Hessian, PD.
        ``project=False``: the exact blocks, assembled."""
        N, nx, nb = self.nlp.settings.N, self.nlp.nx, self.nlp.nx + self.nlp.nu
        B = (
            np.asarray(hblk, float).reshape(nb, N, nb).transpose(1, 0, 2)
        )  # (N, nb, nb): block k = hblk[:, k·nb:(k+1)·nb]
        HN = np.asarray(hN, float).reshape(1, nx, nx)
        # column-major nonzeros of the dense diagonal blocks (the sparsity of H_sparsity)
        if project:
            B, HN = project_pd(B), project_pd(HN)
        nz = np.concatenate([B.transpose(0, 2, 1).ravel(), HN[0].T.ravel()])
        return ca.DM(self.H_sparsity, nz)

    def qp_step(
        self, x: np.ndarray, p: np.ndarray, lam_g: np.ndarray, lam_x: np.ndarray, lbx: np.ndarray, ubx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, str]:
        """One SQP step's QP at (x, lam_g) solved by ``ca.conic``: (dx, lam_g, lam_x, solved, the QP solver's
        status); the multipliers are the QP's when solved, else the ones given."""
        d = self.data(x, p, lam_g, lbx, ubx, self.nlp.lbg, self.nlp.ubg)
        H = self.regularised_hessian(d[0], d[1], project=self.nlp.settings.rti_hessian == "projected")
        out = self.qp(h=H, g=d[2], a=d[3], lba=d[4], uba=d[5], lbx=d[6], ubx=d[7])
        st = self.qp.stats()
        dx = np.asarray(out["x"]).ravel()
        ok_qp, qst = bool(st.get("success", False)), str(st.get("return_status", ""))
        if ok_qp:
            lam_g, lam_x = np.asarray(out["lam_a"]).ravel(), np.asarray(out["lam_x"]).ravel()
        return dx, lam_g, lam_x, ok_qp, qst

    def solve(
        self, c: RTIHost, args: dict[str, np.ndarray], p: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, iterations: int
    ) -> MPCSolution:
        """Up to ``iterations`` full SQP steps from ``args`` (the shifted previous solution, or the cold
        guess), each QP by :meth:`qp_step`. Success: every QP solved, a finite step, the applied control's
        path constraints (node 0, where the state is the measurement) hold within
        :data:`aev_ocp.plant.PLAN_TOLERANCE`, and, with ``budget = 'wall'`` only, the step took at most
        ``max_step_ms`` (else the cause 'budget'). A failure's status starts with its cause: 'QP failed', 'exception',
        'path constraint', 'budget'. The controller ``c`` keeps the warm start."""
        s, nlp = self.nlp.settings, self.nlp
        t0 = time.perf_counter()
        x, lam_g, lam_x = args["x0"], args["lam_g0"], args["lam_x0"]
        ok, status, it, step = True, "", 0, float("inf")
        try:
            while it < iterations:
                dx, lam_g, lam_x, ok_qp, qst = self.qp_step(x, p, lam_g, lam_x, lbx, ubx)
                it += 1
                if not ok_qp or not np.all(np.isfinite(dx)):
                    ok, status = False, f"QP failed: {qst}"
                    break
                x = x + dx
                step = float(np.abs(dx).max())
                if step <= s.tol:
                    break
            c0 = np.asarray(self.path0(x, p)).ravel() if ok else None
        except RuntimeError as exc:
            ok, status, c0 = False, f"exception: {str(exc).splitlines()[0][:200]}", None
        dt_wall = time.perf_counter() - t0
        viol0 = float("inf")
        if c0 is not None:
            viol0 = float(np.maximum(np.maximum(self.path0_lb - c0, c0 - self.path0_ub), 0).max(initial=0))
            if not np.isfinite(viol0) or viol0 > PLAN_TOLERANCE:
                ok, status = False, f"path constraint: the applied control violates them by {viol0:.3g}"
        if ok and s.over_budget(dt_wall):
            X_late = nlp.unpack(x)[0]
            return c.late({"x": x, "lam_x": lam_x, "lam_g": lam_g, "X1": X_late[:, 1]}, it, dt_wall, viol0, "rti")
        if not ok:
            return c.failed(status, it, dt_wall, viol0, "rti")
        # plan, cost and the nonlinear constraint violation of the plan (the RTI plan is feasible only
        # to first order; reported, not required)
        f, g = self.fg(x, p)
        viol = nlp.violation(x, np.asarray(g).ravel(), lbx, ubx)
        X, a, U = nlp.unpack(x)
        c.warm = {"x": x, "lam_x": lam_x, "lam_g": lam_g, "X1": X[:, 1]}
        return MPCSolution(
            True,
            "RTI_Step" if step > s.tol else "RTI_Converged",
            it,
            dt_wall,
            X,
            a,
            float(f),
            viol,
            "rti",
            {"step_inf": step, "node0_violation": viol0},
            U,
        )


def check_rti_qp(qp_solver: str, family: str) -> None:
    """ParameterError for a QP solver the rti path cannot run on a formulation."""
    if qp_solver == "qrqp" and family == "traffic":
        raise ParameterError(
            "MPCSettings.qp_solver = 'qrqp' cannot take the traffic formulation: its ω "
            "epigraph control enters the cost linearly and qrqp needs curvature in every "
            "control; use qp_solver = 'riccati' or 'hpipm'"
        )


def solve_compiled(c: RTIHost, z0: np.ndarray, p: np.ndarray) -> MPCSolution:
    """One step of the compiled whole RTI step (:class:`aev_ocp.mpc.export.CStep`, the same C as
    ``aev-ocp mpc-export``): a cold start (SQP from the guess) when the controller has no warm start."""
    cs = c.compiled_step
    assert cs is not None
    if c.warm is None:
        cs.reset()
    t0 = time.perf_counter()
    st = cs.step_full(z0, p)
    dt_wall = time.perf_counter() - t0
    x, lam_g, lam_x, info = cs.solution()
    if st != 0:
        why = STEP_STATUS.get(st, f"status {st}")
        if st == 1:  # the QP solver's own status (ocp_qp.h)
            why = f"{why} {QP_STATUS.get(info.qp_status, info.qp_status)}"
        return c.failed(why, info.iterations, dt_wall, info.node0_violation, "rti")
    X, a, U = c.nlp.unpack(x)
    warm = {"x": x.copy(), "X1": X[:, 1]}  # (the library keeps its own warm start)
    if c.settings.over_budget(dt_wall):
        return c.late(warm, info.iterations, dt_wall, info.node0_violation, "rti")
    c.warm = warm
    return MPCSolution(
        True,
        "RTI_Step" if info.step_inf > c.settings.tol else "RTI_Converged",
        info.iterations,
        dt_wall,
        X,
        a,
        info.cost,
        info.violation,
        "rti",
        {
            "step_inf": info.step_inf,
            "node0_violation": info.node0_violation,
            "cold_start": bool(info.cold),
            "qp_acceptable": int(info.qp_acceptable),
        },
        U,
    )

"""Test oracle (not part of the package): the Python twin of the compiled RTI step's SQP step
(aev_ocp/c/mpc_step.c's sqp_step) on the package's Python RTI loop (aev_ocp.mpc.rti.RTIStep): the QP data in the
stage layout of ocp_qp.h from the interpreted CasADi function (aev_ocp.mpc.cstep.qp_data_function), the Hessian
blocks projected by NumPy (eigh; the C by Householder tridiagonalisation and QL), solved by ocp_qp.c through ctypes, and the
same retry rule (an exact-Hessian QP that fails with max_iter or factorization is re-solved with the projected
blocks) and the same start of the QPs of a warm step (ocpqp_solve_warm from the shifted multipliers). It shares with the compiled step only the QP solver and the CasADi expressions, so the two agreeing over
a closed loop checks the C driver, its shift and its multiplier layout."""

from __future__ import annotations

from typing import Any

import numpy as np

from aev_ocp.mpc.controller import HPIPM_INF_TRAFFIC, MPCController
from aev_ocp.mpc.cstep import QP_MAX_ITER, QP_TOL, qp_data_function
from aev_ocp.mpc.ocpqp import OcpQP, OcpQPDims, OcpQPSettings
from aev_ocp.mpc.rti import RTIStep, project_pd


class TwinRTIStep(RTIStep):
    """:class:`RTIStep` whose QP is the stage-layout one solved by ocp_qp.c (the compiled step's QP settings)."""

    def __init__(self, c: MPCController, warm_qp: bool = True) -> None:
        super().__init__(c.nlp, "hpipm", HPIPM_INF_TRAFFIC if c.formulation.family == "traffic" else None, False)
        N, nx, nu = c.settings.N, c.nx, c.nu
        self.fdata = qp_data_function(c).expand()
        self.ocp_qp = OcpQP(
            OcpQPDims(N, nx, nu, c.nlp.ng_stage - nx, 0),
            OcpQPSettings(max_iter=QP_MAX_ITER, tol_stat=QP_TOL, tol_eq=QP_TOL, tol_ineq=QP_TOL, tol_comp=QP_TOL),
        )
        self.use_warm_qp, self.warm_qp = warm_qp, False
        self.qp_iterations: list[int] = []  # interior-point iterations of every QP solved

    def solve(
        self, c: Any, args: dict[str, np.ndarray], p: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, iterations: int
    ) -> Any:
        # the C driver warm-starts the QPs of a warm step only (warm_qp False: every QP cold, as before)
        self.warm_qp = self.use_warm_qp and c.warm is not None
        return super().solve(c, args, p, lbx, ubx, iterations)

    def qp_step(
        self, x: np.ndarray, p: np.ndarray, lam_g: np.ndarray, lam_x: np.ndarray, lbx: np.ndarray, ubx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, str]:
        nlp = self.nlp
        N, nx, nb, ngs = nlp.settings.N, nlp.nx, nlp.nx + nlp.nu, nlp.ng_stage
        H, g, E, e, C, lc, uc, lbw, ubw = (np.asarray(v, float).ravel() for v in self.fdata(x, p, lam_g))

        def projected(H: np.ndarray) -> np.ndarray:
            B = project_pd(H[: N * nb * nb].reshape(N, nb, nb).transpose(0, 2, 1))
            HN = project_pd(H[N * nb * nb :].reshape(1, nx, nx).transpose(0, 2, 1))
            return np.concatenate([B.transpose(0, 2, 1).ravel(), HN.transpose(0, 2, 1).ravel()])

        exact = nlp.settings.rti_hessian == "exact"
        qp = self.ocp_qp
        Hq = H if exact else projected(H)
        if self.warm_qp:  # a warm step: the QP from the multipliers (as mpc_step.c)
            lg = lam_g.reshape(N, ngs)
            guess = {"pi": lg[:, :nx].ravel(), "lam_w": lam_x, "lam_c": lg[:, nx:].ravel()}
            r = qp.solve(Hq, g, E, e, C, lc, uc, lbw, ubw, np.zeros(nx), warm=guess)
        else:
            r = qp.solve(Hq, g, E, e, C, lc, uc, lbw, ubw, np.zeros(nx))
        self.qp_iterations.append(r.iterations)
        if exact and r.status in (1, 2, 6):  # MAX_ITER, FACTORIZATION, ACCEPTABLE: not convex enough (mpc_step.c)
            r = qp.solve(projected(H), g, E, e, C, lc, uc, lbw, ubw, np.zeros(nx))
        if r.status not in (0, 6):  # ok, or acceptable (every residual within 100x the tolerance: taken)
            return r.w, lam_g, np.zeros(nlp.nv), False, f"ocp_qp {r.status_name}"
        lg = np.concatenate([r.pi.reshape(N, nx), r.lam_c.reshape(N, ngs - nx)], axis=1).ravel()
        return r.w, lg, r.lam_w, True, ""


def install(c: Any, warm_qp: bool = True) -> Any:
    """Make a built controller (solver 'rti'; a policy or a closed loop's first controller also accepted) run the
    twin instead of the compiled step (``warm_qp`` False: every QP from ocp_qp.c's cold start, the driver's rule
    before the warm start); returns the controller."""
    c = getattr(c, "controller", c)
    c.compiled_step = None
    c.rti = TwinRTIStep(c, warm_qp)
    c.qp_in_use = "riccati-twin"
    c.codegen_active = False
    return c

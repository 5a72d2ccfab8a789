"""A moving-horizon estimator on :class:`~aev_ocp.estimation.base.EstimationModel`: a small CasADi nlpsol (IPOPT)
over the last ``window`` measurements, with the EKF's filtered estimate at the window's start as arrival cost and
the EKF's learnt cell parameters (the scales) held over the window."""

from __future__ import annotations

from collections import deque
from typing import Any

import casadi as ca
import numpy as np

from ..params import EVParams, ParameterError
from .base import NX, PARAM_NAMES, Estimate, estimate_of
from .kalman import EKF, bridge_delays
from .sensors import Measurement, Sensors

ND = NX - len(PARAM_NAMES)  # the dynamic states the window optimises (S, V1, V2, h, v_l, a_l, v)
#: the unit of each of those states in the NLP (1 % SOC, 1 mV, 1 m, 1 m/s, 1 m/s², 1 m/s): IPOPT sees variables of
#: order one (in SI units V1 and V2 are ~1e-3 and their model-error weights ~1e5, and its steps stall)
MHE_SCALE = (0.01, 1e-3, 1e-3, 1.0, 1.0, 1.0, 1.0)


class MHE:
    """Moving-horizon estimator (SI): minimise over the window's dynamic states x_0…x_M (S, V1, V2, h, v_l, a_l, v)

        ‖x_0 − x̄_0‖²_{P_0⁻¹} + Σ ‖x_{k+1} − F(x_k, θ, u_k)‖²_{Q⁻¹} + Σ ‖y_k − h(x_k, θ, u_k)‖²_{R⁻¹},   0 ≤ S ≤ 1,

    F, h, Q and R those of the EKF (the same model), x̄_0 and diag(P_0) the EKF's filtered estimate at the window's
    start, θ the cell's scales (:data:`~aev_ocp.estimation.base.PARAM_NAMES`) as the EKF has learnt them by the
    window's end: a 2 s window holds too little information to learn a time constant of 4 or 100 s, and freeing θ
    there makes the problem bilinear and badly conditioned (the EKF runs alongside; until the window is full the
    MHE returns the EKF's estimate). ``window``: intervals M (default 10 steps, 2 s at the MPC's 0.2 s)."""

    name = "mhe"

    def __init__(
        self, ev: EVParams, sensors: Sensors, soc0: float | None = None, ocv_offset_V: float = 0.0, window: int = 10
    ) -> None:
        if not isinstance(window, int) or isinstance(window, bool) or window < 2:
            raise ParameterError(f"MHE: window = {window!r} is not allowed: must be an integer >= 2")
        self.ekf = EKF(ev, sensors, soc0, ocv_offset_V)
        self.model, self.M = self.ekf.model, window
        self._build()
        self.buf: deque[tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]] = deque(maxlen=window + 1)
        self._guess: np.ndarray | None = None
        self.x = np.zeros(NX)
        self.fails = 0

    def _build(self) -> None:
        M, m, nd = self.M, self.model, ND
        Z = ca.SX.sym("Z", nd, M + 1)  # the decision variables: the states in units of MHE_SCALE
        X = ca.diag(ca.DM(MHE_SCALE)) @ Z
        th = ca.SX.sym("theta", NX - nd)
        x0b, L0 = ca.SX.sym("x0b", nd), ca.SX.sym("L0", nd, nd)  # L0: Cholesky factor of P_0⁻¹ (upper)
        U, Y, DT = ca.SX.sym("U", 2, M + 1), ca.SX.sym("Y", 4, M + 1), ca.SX.sym("DT", M)
        LQ, LR = ca.SX.sym("LQ", nd, nd), ca.SX.sym("LR", 4, 4)
        Fs = ca.Function("Fs", [m.x, m.u, m.dt], [m.f_sym[:nd]])
        Hs = ca.Function("Hs", [m.x, m.u], [m.h_sym])
        r0 = L0 @ (X[:, 0] - x0b)
        J = ca.sumsqr(r0)
        for k in range(M):
            uk = ca.vertcat(U[0, k + 1], 0.5 * (U[1, k] + U[1, k + 1]))  # the inputs of the interval, as the EKF's
            J += ca.sumsqr(LQ @ (X[:, k + 1] - Fs(ca.vertcat(X[:, k], th), uk, DT[k])))
        for k in range(M + 1):
            J += ca.sumsqr(LR @ (Y[:, k] - Hs(ca.vertcat(X[:, k], th), U[:, k])))
        p = ca.vertcat(x0b, ca.vec(L0), ca.vec(U), ca.vec(Y), DT, ca.vec(LQ), ca.vec(LR), th)
        opts: dict[str, Any] = {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.sb": "yes",
            "ipopt.max_iter": 30,
            "ipopt.tol": 1e-8,
            "ipopt.warm_start_init_point": "yes",
        }
        self.solver = ca.nlpsol("mhe", "ipopt", {"x": ca.vec(Z), "f": J, "p": p}, opts)
        self.cost = ca.Function("mhe_cost", [ca.vec(Z), p], [J])
        lb, ub = -np.inf * np.ones((nd, M + 1)), np.inf * np.ones((nd, M + 1))
        lb[0, :], ub[0, :] = 0.0, 1.0 / MHE_SCALE[0]
        self.lbx, self.ubx = lb.ravel(order="F"), ub.ravel(order="F")

    def reset(self, first: Measurement) -> Estimate:
        self.buf.clear()
        self._guess = None
        self.fails = 0
        e = self.ekf.reset(first)
        self._push(first)
        self.x = self.ekf.x.copy()
        return e

    def _push(self, y: Measurement) -> None:
        # (u, y, t, filtered x, filtered P) per measurement
        self.buf.append((self.model.inputs(y), self.model.outputs(y), y.t_s, self.ekf.x.copy(), self.ekf.P.copy()))

    def update(self, y: Measurement) -> Estimate:
        e = self.ekf.update(y)
        self._push(y)
        if len(self.buf) <= self.M:
            self.x = self.ekf.x.copy()
            return e
        U = np.column_stack([b[0] for b in self.buf])
        Yv = np.column_stack([b[1] for b in self.buf])
        T = np.array([b[2] for b in self.buf])
        DT = np.diff(T)
        nd = ND
        x0b, P0 = self.buf[0][3][:nd], self.buf[0][4][:nd, :nd]
        theta = self.ekf.x[nd:]
        # the arrival cost keeps the EKF's variances, not its correlations: linearised on the flat OCV plateau the
        # EKF's P is loose along (S down, V2 down) and the window would slide down the plateau into a wrong minimum
        L0 = np.diag(1.0 / np.sqrt(np.maximum(np.diag(P0), 1e-18)))
        dt_nom = float(np.median(DT))
        _, _, B = self.model.F(self.ekf.x, U[:, -1], dt_nom)
        LQ = np.linalg.cholesky(np.linalg.inv(self.model.process_noise(dt_nom, np.asarray(B))[:nd, :nd])).T
        LR = np.linalg.cholesky(np.linalg.inv(self.model.R)).T
        p = np.concatenate(
            [
                x0b,
                L0.ravel(order="F"),
                U.ravel(order="F"),
                Yv.ravel(order="F"),
                DT,
                LQ.ravel(order="F"),
                LR.ravel(order="F"),
                theta,
            ]
        )
        scale = np.asarray(MHE_SCALE)
        guess = np.column_stack([b[3][:nd] / scale for b in self.buf]).ravel(order="F")
        if self._guess is not None:  # the last solution shifted by one step, the EKF's newest state appended
            guess = np.concatenate([self._guess[nd:], self.ekf.x[:nd] / scale])
        sol = self.solver(x0=guess, p=p, lbx=self.lbx, ubx=self.ubx)
        if not self.solver.stats()["success"]:
            self.fails += 1
        xs = np.asarray(sol["x"]).ravel()
        self._guess = xs
        self.x = np.concatenate([xs[-nd:] * scale, theta])
        return self.estimate()

    def estimate(self) -> Estimate:
        """The last window node predicted over the sensors' delays (as the EKF)."""
        return estimate_of(
            bridge_delays(self.x, self.ekf.u[1], self.ekf.lead_delay_s, self.ekf.speed_delay_s), self.ekf.P
        )

    def describe(self) -> dict[str, Any]:
        return {
            **self.ekf.describe(),
            "estimator": self.name,
            "window": self.M,
            "solver": "ipopt",
            "arrival_cost": "EKF filtered estimate at the window start",
            "parameters": "the EKF's scales, held over the window",
            "failed_solves": self.fails,
        }

"""Direct transcription of optimal-control problems into a parametric NLP solved by IPOPT.

An :class:`OCPProblem` describes a problem on a fixed grid of ``N`` intervals of length
``h = t_f / N`` (time in the problem's own unit): the ODE right-hand side, an integrated
(Lagrange) cost and/or a cost sampled at the start of each interval (``stage(x_k, u_k)·h``, as in
model guide §9), path constraints at the nodes ``k = 0 … N−1`` (optionally also at collocation
points), terminal constraints, and simple bounds on states (nodes ``1 … N`` and collocation
points; the initial state is fixed by an equality constraint) and on controls. Controls are
piecewise constant. Every function takes ``(x, u, w, p)``: ``w`` is a per-interval parameter
(e.g. the leader's interval-mean speed) and ``p`` a global one.

Two transcriptions (model guide §8, "multiple shooting and collocation, selectable"):

* ``method="ms"``: direct multiple shooting, RK4 with ``rk4_substeps`` sub-steps per interval;
  the Lagrange cost is integrated by the same RK4 as an extra quadrature state.
* ``method="collocation"``: direct collocation, Legendre or Radau points of selectable degree;
  the Lagrange cost uses the collocation quadrature.

The NLP is parametric: ``x0``, ``p``, the stage parameters ``w`` and ``t_f`` are NLP parameters,
so :class:`OCPSolver` builds ``ca.nlpsol('ipopt')`` ONCE (exact Hessian, MUMPS, ``expand=True``)
and re-solves with new values and warm starts (primal ``x0`` and duals ``lam_x0``, ``lam_g0``).
Decision variables and constraints are ordered interval by interval, so the KKT matrix is banded.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import casadi as ca
import numpy as np

from ..numerics import rk4
from ..params import ParameterError
from .problem import OCPProblem
from ..ocp_result import OCPResult

METHODS = ("ms", "collocation")
SCHEMES = ("radau", "legendre")

# IPOPT return statuses -> (short status, success, explanation)
_IPOPT_STATUS: dict[str, tuple[str, bool, str]] = {
    "Solve_Succeeded": ("optimal", True, "IPOPT converged to the requested tolerance"),
    "Solved_To_Acceptable_Level": ("acceptable", True, "IPOPT converged to the acceptable tolerance only"),
    "Infeasible_Problem_Detected": (
        "infeasible",
        False,
        "IPOPT detected local infeasibility: the constraints (e.g. the "
        "demanded energy/distance, current limit or bounds) cannot all be met",
    ),
    "Maximum_Iterations_Exceeded": ("iteration_limit", False, "IPOPT hit its iteration limit"),
    "Maximum_CpuTime_Exceeded": ("time_limit", False, "IPOPT hit its CPU-time limit"),
    "Maximum_WallTime_Exceeded": ("time_limit", False, "IPOPT hit its wall-time limit"),
    "Restoration_Failed": (
        "restoration_failed",
        False,
        "IPOPT's feasibility restoration failed (often an infeasible problem)",
    ),
    "Search_Direction_Becomes_Too_Small": ("small_step", False, "IPOPT's search direction became too small"),
    "Diverging_Iterates": ("diverging", False, "IPOPT's iterates diverged (unbounded problem?)"),
    "Invalid_Number_Detected": (
        "invalid_number",
        False,
        "a function returned NaN/Inf (e.g. a state left the model's domain)",
    ),
    "Error_In_Step_Computation": ("step_error", False, "IPOPT could not compute a step"),
    "User_Requested_Stop": ("stopped", False, "stopped by a callback"),
    "Not_Enough_Degrees_Of_Freedom": ("too_few_dof", False, "more equality constraints than unknowns"),
    "Infeasible_Problem_Definition": ("bad_bounds", False, "a lower bound exceeds its upper bound"),
}


#: IPOPT's linear_solver values (IPOPT options reference, coin-or.github.io/Ipopt/OPTIONS.html)
IPOPT_LINEAR_SOLVERS = ("mumps", "ma27", "ma57", "ma77", "ma86", "ma97", "pardiso", "pardisomkl", "spral", "wsmp")


@dataclass(frozen=True)
class TranscriptionOptions:
    """How to transcribe and solve.

    method: 'ms' (multiple shooting, RK4) or 'collocation'; N: number of intervals;
    rk4_substeps: RK4 steps per interval (ms); degree, scheme: collocation polynomial degree and
    points ('radau' or 'legendre'); tol, max_iter: IPOPT settings; print_level: IPOPT verbosity
    (0 = silent, the default); violation_tol: largest constraint violation accepted in a returned
    "solution" (NLP units, i.e. after scaling); mx_map: keep the NLP as MX calls of ONE mapped
    SX interval Function (derivatives generated once: build time independent of N) instead of
    expanding everything to SX (expand=True; slower build, fastest evaluation).
    """

    method: str = "ms"
    N: int = 200
    rk4_substeps: int = 4
    degree: int = 3
    scheme: str = "radau"
    tol: float = 1e-9
    max_iter: int = 1000
    print_level: int = 0
    violation_tol: float = 1e-6
    mu_init_warm: float = 1e-6
    linear_solver: str = "mumps"
    mx_map: bool = False

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ParameterError(
                f"TranscriptionOptions.method = {self.method!r} is not allowed: must be one of {METHODS}"
            )
        if self.scheme not in SCHEMES:
            raise ParameterError(
                f"TranscriptionOptions.scheme = {self.scheme!r} is not allowed: must be one of {SCHEMES}"
            )
        if self.linear_solver not in IPOPT_LINEAR_SOLVERS:
            raise ParameterError(
                f"TranscriptionOptions.linear_solver = {self.linear_solver!r} is not allowed: must be one of "
                f"{IPOPT_LINEAR_SOLVERS} (IPOPT's; all but mumps need their library installed)"
            )
        for nm, lo in (("N", 1), ("rk4_substeps", 1), ("degree", 1), ("max_iter", 1)):
            v = getattr(self, nm)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ParameterError(f"TranscriptionOptions.{nm} = {v!r} is not allowed: must be an integer >= {lo}")
        for nm in ("tol", "violation_tol", "mu_init_warm"):
            v = getattr(self, nm)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"TranscriptionOptions.{nm} = {v!r} is not allowed: must be a finite number > 0")


def collocation_coefficients(degree: int, scheme: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Collocation points τ (with τ0 = 0), derivative matrix C, continuity D and quadrature B weights."""
    tau = np.append(0.0, ca.collocation_points(degree, scheme))
    d = degree
    C = np.zeros((d + 1, d + 1))
    D = np.zeros(d + 1)
    B = np.zeros(d + 1)
    for j in range(d + 1):
        poly = np.poly1d([1.0])
        for r in range(d + 1):
            if r != j:
                poly *= np.poly1d([1.0, -tau[r]]) / (tau[j] - tau[r])
        D[j] = poly(1.0)
        dpoly = np.polyder(poly)
        C[j, :] = [dpoly(tau[r]) for r in range(d + 1)]
        B[j] = np.polyint(poly)(1.0)
    return tau, C, D, B


def sx_function(
    name: str,
    inputs: Sequence[ca.SX],
    outputs: Sequence[Any],
    in_names: Sequence[str] | None = None,
    out_names: Sequence[str] | None = None,
) -> ca.Function:
    """Small helper: an SX Function with optional names."""
    outs = [ca.SX(o) if not isinstance(o, ca.SX) else o for o in outputs]
    if in_names is not None and out_names is not None:
        return ca.Function(name, list(inputs), outs, list(in_names), list(out_names))
    return ca.Function(name, list(inputs), outs)


def _finite(what: str, value: Any, size: int | None, rows: int) -> np.ndarray:
    """``value`` as a float array of ``size`` finite entries (any size if None); ParameterError naming ``what``."""
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise ParameterError(f"{what} must be an array of numbers, got {type(value).__name__}") from None
    want = f"{rows} × {size // max(rows, 1)} finite numbers" if size is not None else "finite numbers"
    if size is not None and a.size != size:
        raise ParameterError(f"{what} must be {want}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{what} must be {want}, got a NaN or infinite entry")
    return a


def _vec(v: Sequence[float] | None, n: int, default: float) -> np.ndarray:
    return np.full(n, default) if v is None else np.asarray(v, dtype=float).reshape(n)


def with_discrete_update(pr: OCPProblem, x_end: Any, xk: Any, uk: Any, w: Any, p: Any) -> Any:
    """x_end with the problem's discrete-time states replaced by their update x_{k+1} = next(x_k, u_k, w, p)."""
    if pr.discrete_next is None:
        return x_end
    nxt = pr.discrete_next(xk, uk, w, p)
    parts = [x_end[i] for i in range(pr.nx)]
    for j, i in enumerate(pr.discrete_states):
        parts[i] = nxt[j]
    return ca.vertcat(*parts)


def interval_function(pr: OCPProblem, o: TranscriptionOptions) -> ca.Function:
    """One interval of the transcription on SCALED variables (x/x_scale, u/u_scale): inputs
    (xk, uk, xc collocation states, xn next node, w, p, h interval length) -> (eq, path, J):
    eq = 0 are the continuity (and collocation) equations, path the path constraints at the interval
    start (and collocation points), J the interval's cost (stage·h + integral). Shared by
    :class:`OCPSolver` and the MPC, so both discretise a problem identically."""
    nx, nu, nw, npar = pr.nx, pr.nu, pr.nw, pr.np_
    xs = ca.DM(_vec(pr.x_scale, nx, 1.0))
    us = ca.DM(_vec(pr.u_scale, nu, 1.0))
    d = o.degree if o.method == "collocation" else 0
    xk_s, uk_s = ca.SX.sym("xk", nx), ca.SX.sym("uk", nu)
    xc_s, xn_s = ca.SX.sym("xc", nx * d), ca.SX.sym("xn", nx)
    w, p, h = ca.SX.sym("w", nw), ca.SX.sym("p", npar), ca.SX.sym("h")
    xk, uk, xn = xk_s * xs, uk_s * us, xn_s * xs

    def f(x: Any) -> Any:
        return pr.ode(x, uk, w, p)

    def ell(x: Any) -> Any:
        assert pr.lagrange is not None  # ell is only called when the problem has a Lagrange term
        return pr.lagrange(x, uk, w, p)

    J = pr.stage(xk, uk, w, p) * h if pr.stage is not None else ca.SX(0)
    eqs: list[Any] = []
    path: list[Any] = [pr.path(xk, uk, w, p)] if pr.path is not None else []
    if o.method == "ms":
        x_end, q = rk4(f, xk, h, o.rk4_substeps, ell if pr.lagrange is not None else None)
        J = J + q
    else:
        _, C, D, B = collocation_coefficients(o.degree, o.scheme)
        Xc = [xk] + [xc_s[j * nx : (j + 1) * nx] * xs for j in range(d)]
        x_end = D[0] * xk
        for j in range(1, d + 1):
            xp = C[0, j] * Xc[0]
            for r in range(1, d + 1):
                xp = xp + C[r, j] * Xc[r]
            eqs.append((h * f(Xc[j]) - xp) / xs)
            x_end = x_end + D[j] * Xc[j]
            if pr.lagrange is not None:
                J = J + B[j] * ell(Xc[j]) * h
            if pr.path is not None and pr.path_at_collocation:
                path.append(pr.path(Xc[j], uk, w, p))
    x_end = with_discrete_update(pr, x_end, xk, uk, w, p)
    eqs.append((x_end - xn) / xs)
    # cse: the battery side of the state at the interval start appears in the dynamics, the stage cost and
    # the path constraints (and in any term a user adds): evaluate each common subexpression once
    return ca.Function(
        "interval",
        [xk_s, uk_s, xc_s, xn_s, w, p, h],
        [ca.vertcat(*eqs), ca.vertcat(*path) if path else ca.SX(0, 1), J],
        ["xk", "uk", "xc", "xn", "w", "p", "h"],
        ["eq", "path", "J"],
        {"cse": True},
    )


@dataclass
class HorizonNLP:
    """The horizon NLP of a problem on the transcription's interval function (:func:`horizon_nlp`), on the
    caller's symbols: node states ``X`` (nx, N+1), controls ``U`` (nu, N), collocation states ``Xc`` (nx·d, N)
    (all scaled), the objective, the constraint parts ``g`` (the intervals' equations and path constraints
    stage by stage, then the terminal constraints) with their bounds ``lbg``/``ubg``, and ``n_eq``, ``n_path``
    rows per interval."""

    X: Any
    U: Any
    Xc: Any
    objective: Any
    g: list[Any]
    lbg: list[np.ndarray]
    ubg: list[np.ndarray]
    n_eq: int
    n_path: int


def horizon_nlp(
    pr: OCPProblem,
    o: TranscriptionOptions,
    V: Any,
    W: Any,
    p: Any,
    h: Any,
    stage_weights: Any = None,
    interval: ca.Function | None = None,
) -> HorizonNLP:
    """The one assembly of a problem's horizon NLP, shared by :class:`OCPSolver` (OCP-D and every OCP) and the
    MPC (:class:`aev_ocp.mpc.nlp.HorizonNLP`): the decision vector ``V`` = (x_0, u_0, xc_0, x_1, …, x_N) scaled
    (blocks of nx + nu + nx·d per interval, then x_N), the stage parameters ``W`` (nw, N), the parameters ``p``
    and the interval length ``h`` (a scalar or (1, N)), all symbols of one class (SX or MX); the interval
    function mapped over the N intervals; the objective Σ_k J_k (or Σ_k s_k J_k with ``stage_weights`` (1, N))
    plus the terminal cost; the terminal constraints last. The initial state is the caller's (an equality
    constraint for OCPSolver, equal simple bounds for the MPC). ``interval``: the problem's
    :func:`interval_function` for ``o`` when the caller has built it already."""
    nx, nu, N = pr.nx, pr.nu, o.N
    d = o.degree if o.method == "collocation" else 0
    nb = nx + nu + nx * d
    blocks = ca.reshape(V[: nb * N], nb, N)
    X = ca.horzcat(blocks[:nx, :], V[nb * N :])
    U = blocks[nx : nx + nu, :]
    Xc = blocks[nx + nu :, :]
    F = (interval if interval is not None else interval_function(pr, o)).map(N)
    eq, path, J = F(X[:, :N], U, Xc, X[:, 1:], W, ca.repmat(p, 1, N), h)
    xs = ca.DM(_vec(pr.x_scale, nx, 1.0))
    n_eq, n_path = eq.size1(), path.size1()
    lbg_k = np.concatenate(
        [
            np.zeros(n_eq),
            np.tile(np.asarray(pr.path_lb, float), n_path // max(len(pr.path_lb), 1)) if n_path else np.zeros(0),
        ]
    )
    ubg_k = np.concatenate(
        [
            np.zeros(n_eq),
            np.tile(np.asarray(pr.path_ub, float), n_path // max(len(pr.path_ub), 1)) if n_path else np.zeros(0),
        ]
    )
    g, lbg, ubg = [ca.vec(ca.vertcat(eq, path))], [np.tile(lbg_k, N)], [np.tile(ubg_k, N)]
    obj = ca.sum2(J) if stage_weights is None else ca.sum2(J * stage_weights)
    if pr.terminal_cost is not None:
        obj = obj + pr.terminal_cost(X[:, N] * xs, p)
    if pr.terminal is not None:
        g.append(pr.terminal(X[:, N] * xs, p))
        lbg.append(np.asarray(pr.terminal_lb, float))
        ubg.append(np.asarray(pr.terminal_ub, float))
    return HorizonNLP(X, U, Xc, obj, g, lbg, ubg, n_eq, n_path)


class OCPSolver:
    """A transcribed OCP with its IPOPT solver, built once; :meth:`solve` re-solves with new data.

    Parameters of :meth:`solve`: ``x0`` initial state, ``p`` global parameter, ``w`` per-interval
    parameters (shape (nw, N)), ``t_f`` horizon [problem time unit].
    """

    def __init__(self, problem: OCPProblem, options: TranscriptionOptions | None = None) -> None:
        problem.validate()
        self.problem = problem
        self.options = options or TranscriptionOptions()
        t0 = time.perf_counter()
        self._build()
        self.build_time_s = time.perf_counter() - t0
        self._warm_solver: ca.Function | None = None
        self._last: dict[str, np.ndarray] | None = None

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        pr, o = self.problem, self.options
        nx, nu, nw, npar, N = pr.nx, pr.nu, pr.nw, pr.np_, o.N
        d = o.degree if o.method == "collocation" else 0
        nb = nx + nu + nx * d  # per-interval block: x_k, u_k, collocation states
        self._nb, self._d = nb, d
        nv = nb * N + nx
        # SX or MX by option: CasADi's stubs overload each function per symbol class and reject the union
        # MX | SX, so the symbols (and the expressions built from them) are typed Any
        SYM: Any = ca.MX if o.mx_map else ca.SX
        V = SYM.sym("V", nv)
        P_x0 = SYM.sym("x0", nx)
        P_p = SYM.sym("p", npar)
        P_w = SYM.sym("w", nw * N)
        P_tf = SYM.sym("tf")
        h = P_tf / N
        W = ca.reshape(P_w, nw, N)
        hz = horizon_nlp(pr, o, V, W, P_p, ca.repmat(h, 1, N))
        Xs, Us, Xcs = hz.X, hz.U, hz.Xc
        xs = ca.DM(_vec(pr.x_scale, nx, 1.0))
        # the initial state: an equality constraint (x0 is a parameter), first
        g_parts = [(Xs[:, 0] * xs - P_x0) / xs, *hz.g]
        lbg = [np.zeros(nx), *hz.lbg]
        ubg = [np.zeros(nx), *hz.ubg]
        obj = hz.objective
        self._lbg, self._ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._n_eq, self._n_path = hz.n_eq, hz.n_path
        # simple bounds (scaled): initial state free (fixed by g), nodes 1..N and collocation states bounded
        us = _vec(pr.u_scale, nu, 1.0)
        xl = _vec(pr.x_lb, nx, -np.inf) / xs.full().ravel()
        xu = _vec(pr.x_ub, nx, np.inf) / xs.full().ravel()
        ul, uu = _vec(pr.u_lb, nu, -np.inf) / us, _vec(pr.u_ub, nu, np.inf) / us
        lb_block = np.concatenate([xl, ul, np.tile(xl, d)])
        ub_block = np.concatenate([xu, uu, np.tile(xu, d)])
        lbx, ubx = np.tile(lb_block, N), np.tile(ub_block, N)
        lbx[:nx], ubx[:nx] = -np.inf, np.inf
        self._lbx, self._ubx = np.concatenate([lbx, xl]), np.concatenate([ubx, xu])
        P = ca.vertcat(P_x0, P_p, P_w, P_tf)
        self._nlp = {"x": V, "p": P, "f": obj, "g": ca.vertcat(*g_parts)}
        self._solver = self._make_solver(warm=False)
        # unpacking helper
        self._unpack = ca.Function("unpack", [V], [Xs * xs, Us * ca.DM(us), Xcs])
        self._nv = nv

    def _ipopt_opts(self, warm: bool) -> dict[str, Any]:
        o = self.options
        ipopt: dict[str, Any] = {
            "print_level": o.print_level,
            "sb": "yes",
            "tol": o.tol,
            "max_iter": o.max_iter,
            "linear_solver": o.linear_solver,
            "hessian_approximation": "exact",
            "mu_strategy": "adaptive",
        }
        if warm:
            ipopt.update(
                {
                    "warm_start_init_point": "yes",
                    "warm_start_bound_push": 1e-9,
                    "warm_start_mult_bound_push": 1e-9,
                    "warm_start_slack_bound_push": 1e-9,
                    "mu_init": o.mu_init_warm,
                }
            )
        return {"ipopt": ipopt, "print_time": False, "expand": not o.mx_map, "error_on_fail": False}

    def _make_solver(self, warm: bool) -> ca.Function:
        try:
            return ca.nlpsol(
                f"{self.problem.name}_{self.options.method}{'_warm' if warm else ''}",
                "ipopt",
                self._nlp,
                self._ipopt_opts(warm),
            )
        except RuntimeError as exc:  # e.g. an HSL linear solver whose library is not installed
            raise ParameterError(
                f"{self.problem.name}: IPOPT refused its options (linear_solver = {self.options.linear_solver!r}): "
                f"{str(exc).strip().splitlines()[-1]}"
            ) from None

    # ------------------------------------------------------------------ solving
    def time_grid(self, t_f: float) -> np.ndarray:
        """Node times 0, h, …, t_f [problem time unit]."""
        return np.linspace(0.0, t_f, self.options.N + 1)

    def _pack_guess(self, X: np.ndarray, U: np.ndarray, t_f: float) -> np.ndarray:
        pr, o = self.problem, self.options
        nx, nu, N, d = pr.nx, pr.nu, o.N, self._d
        xs, us = _vec(pr.x_scale, nx, 1.0), _vec(pr.u_scale, nu, 1.0)
        X = np.asarray(X, float).reshape(nx, N + 1) / xs[:, None]
        U = np.asarray(U, float).reshape(-1, N)
        if U.shape[0] < nu:  # controls the guess does not give (e.g. slacks of soft constraints) start at 0
            U = np.vstack([U, np.zeros((nu - U.shape[0], N))])
        U = U.reshape(nu, N) / us[:, None]
        if d:
            tau = collocation_coefficients(o.degree, o.scheme)[0][1:]
            Xc = np.concatenate([X[:, :N] + tj * (X[:, 1:] - X[:, :N]) for tj in tau], axis=0)
        else:
            Xc = np.zeros((0, N))
        blocks = np.concatenate([X[:, :N], U, Xc], axis=0)
        return np.concatenate([blocks.ravel(order="F"), X[:, N]])

    def solve(
        self,
        x0: Sequence[float],
        t_f: float,
        p: Sequence[float] | None = None,
        w: np.ndarray | None = None,
        guess: tuple[np.ndarray, np.ndarray] | None = None,
        warm: bool = False,
        objective_name: str = "objective",
    ) -> OCPResult:
        """Solve for initial state ``x0`` over ``[0, t_f]``.

        guess: (X (nx, N+1), U (nu, N)) primal initial guess (default: x0 held, controls at 0
        clipped to bounds). warm=True re-uses the previous solution's primal and dual values
        (IPOPT warm start) when no guess is given, or together with the guess's primal values.
        """
        pr, o = self.problem, self.options
        nx, nu, nw, npar, N = pr.nx, pr.nu, pr.nw, pr.np_, o.N
        x0a = np.asarray(x0, float).ravel()
        if x0a.size != nx or not np.all(np.isfinite(x0a)):
            raise ParameterError(f"{pr.name}: x0 must be {nx} finite numbers ({list(pr.state_names)}), got {x0!r}")
        if not (isinstance(t_f, (int, float)) and math.isfinite(t_f) and t_f > 0):
            raise ParameterError(f"{pr.name}: t_f = {t_f!r} must be a finite number > 0")
        pa = np.zeros(0) if p is None else np.asarray(p, float).ravel()
        if pa.size != npar or not np.all(np.isfinite(pa)):
            raise ParameterError(f"{pr.name}: p must be {npar} finite numbers, got {p!r}")
        wa = np.zeros((nw, N)) if w is None else _finite(f"{pr.name}: w (per-interval parameters)", w, nw * N, nw)
        wa = wa.reshape(nw, N)
        par = np.concatenate([x0a, pa, wa.ravel(order="F"), [float(t_f)]])
        args: dict[str, Any] = {"p": par, "lbx": self._lbx, "ubx": self._ubx, "lbg": self._lbg, "ubg": self._ubg}
        if guess is not None:
            if not (isinstance(guess, (tuple, list)) and len(guess) == 2):
                raise ParameterError(f"{pr.name}: guess must be a pair (X, U), got {type(guess).__name__}")
            X = _finite(f"{pr.name}: guess X (states at the nodes)", guess[0], nx * (N + 1), nx)
            U = _finite(f"{pr.name}: guess U (controls per interval)", guess[1], None, N)
            if U.size % N or U.size // N > nu:
                raise ParameterError(f"{pr.name}: guess U must be (up to) {nu} × {N} controls, got shape {U.shape}")
            args["x0"] = self._pack_guess(X, U, t_f)
        elif warm and self._last is not None:
            args["x0"] = self._last["x"]
        else:
            U0 = np.clip(np.zeros((nu, N)), _vec(pr.u_lb, nu, -np.inf)[:, None], _vec(pr.u_ub, nu, np.inf)[:, None])
            args["x0"] = self._pack_guess(np.repeat(x0a[:, None], N + 1, axis=1), U0, t_f)
        solver = self._solver
        if warm and self._last is not None:
            if self._warm_solver is None:
                self._warm_solver = self._make_solver(warm=True)
            solver = self._warm_solver
            args["lam_x0"] = self._last["lam_x"]
            args["lam_g0"] = self._last["lam_g"]
        t0 = time.perf_counter()
        try:
            sol = solver(**args)
            stats = solver.stats()
        except RuntimeError as exc:  # CasADi evaluation errors: report, never propagate a deep traceback
            return OCPResult.failed(
                pr.name,
                o.method,
                N,
                f"solver_error: {str(exc).splitlines()[-1]}",
                time.perf_counter() - t0,
                self.time_grid(t_f),
                pr.time_unit,
            )
        wall = time.perf_counter() - t0
        xopt = np.asarray(sol["x"]).ravel()
        self._last = {"x": xopt, "lam_x": np.asarray(sol["lam_x"]).ravel(), "lam_g": np.asarray(sol["lam_g"]).ravel()}
        return self._result(sol, stats, wall, x0a, pa, wa, float(t_f), objective_name)

    def _max_violation(self, x: np.ndarray, g: np.ndarray) -> float:
        vx = np.concatenate([np.maximum(self._lbx - x, 0), np.maximum(x - self._ubx, 0)])
        vg = np.concatenate([np.maximum(self._lbg - g, 0), np.maximum(g - self._ubg, 0)])
        allv = np.concatenate([vx, vg])
        allv = np.where(np.isnan(allv), np.inf, allv)
        return float(np.max(allv)) if allv.size else 0.0

    def _result(
        self,
        sol: dict[str, Any],
        stats: dict[str, Any],
        wall: float,
        x0: np.ndarray,
        p: np.ndarray,
        w: np.ndarray,
        t_f: float,
        objective_name: str,
    ) -> OCPResult:
        pr, o = self.problem, self.options
        N = o.N
        x = np.asarray(sol["x"]).ravel()
        g = np.asarray(sol["g"]).ravel()
        X, U, Xc = (np.asarray(a) for a in self._unpack(x))
        raw = str(stats.get("return_status", "unknown"))
        status, success, why = _IPOPT_STATUS.get(
            raw, (raw.lower(), bool(stats.get("success", False)), f"IPOPT returned {raw}")
        )
        viol = self._max_violation(x, g)
        obj = float(sol["f"])
        if success and not (viol <= o.violation_tol and math.isfinite(obj)):
            status, success = "constraint_violation", False
            why = f"IPOPT reported {raw} but the returned point violates constraints by {viol:.3g}"
        iters = int(stats.get("iter_count", -1))
        outputs: dict[str, np.ndarray] = {}
        if pr.outputs is not None:
            Uext = np.concatenate([U, U[:, -1:]], axis=1)
            fm = pr.outputs.map(N + 1)
            wext = np.concatenate([w, w[:, -1:]], axis=1) if w.size else np.zeros((pr.nw, N + 1))
            vals = fm(X, Uext, wext, np.repeat(p.reshape(-1, 1), N + 1, axis=1))
            vals = vals if isinstance(vals, (list, tuple)) else [vals]
            for i, nm in enumerate(pr.outputs.name_out()):
                outputs[nm] = np.asarray(vals[i]).ravel()
        t = self.time_grid(t_f)
        t_colloc = None
        if self._d:
            tau = collocation_coefficients(o.degree, o.scheme)[0][1:]
            t_colloc = (t[:-1, None] + tau[None, :] * (t_f / N)).ravel()
        return OCPResult(
            problem=pr.name,
            method=o.method,
            N=N,
            t=t,
            time_unit=pr.time_unit,
            states={nm: X[i] for i, nm in enumerate(pr.state_names)},
            controls={nm: U[i] for i, nm in enumerate(pr.control_names)},
            outputs=outputs,
            objective=obj,
            objective_name=objective_name,
            status=status,
            success=success,
            message=why,
            solver_status=raw,
            iterations=iters,
            wall_time_s=wall,
            solver_time_s=float(stats.get("t_wall_total", wall)),
            max_violation=viol,
            t_colloc=t_colloc,
            meta={"x0": x0.tolist(), "p": p.tolist(), "t_f": t_f, "options": asdict(o)},
        )

    def last_solution(self) -> dict[str, np.ndarray] | None:
        """Primal and dual values of the last solve (x, lam_x, lam_g; NLP scaling)."""
        return self._last

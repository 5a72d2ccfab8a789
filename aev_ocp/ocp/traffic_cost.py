"""The traffic formulation's objective (:mod:`aev_ocp.ocp.traffic`) of any sampled trajectory: ``cost_traffic``.

A run (the MPC's closed loop, a closed-form law, OCP-D replayed) gives states z_k = (h, v, V1, V2, S) at the
nodes t_k and the acceleration a_k applied on [t_k, t_{k+1}). The traffic problem also has an own state
``a_prev`` (the previous applied command: a_prev_0 = 0, the closed loop's first ``Observation.a_prev``, then
a_prev_k = a_{k−1}) and two auxiliary controls whose optimal values are fixed by (z_k, a_k):

* ``omega_rate`` e (the paper's ω rate): the smallest e meeting both epigraph rows (e ≥ v a/η, e ≥ η v a), i.e. v g(a);
* ``slack_gap`` σ: the smallest σ ≥ 0 meeting both soft gap constraints (headway, braking).

Both are read from the problem's own path constraints (which are affine in them), and the cost is the
problem's own interval function (:func:`aev_ocp.ocp.transcription.interval_function`, J = ℓ(x_k, u_k, w_k)·dt_k)
summed over the intervals, plus its terminal cost at the last node. So an OCP-D optimum of the traffic problem
has ``cost_traffic`` of its own trajectory equal to its NLP objective, and any other run on the same grid costs
at least as much (the bound).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from ..params import ParameterError
from .problem import OCPProblem
from .transcription import TranscriptionOptions, interval_function

#: The auxiliary controls of the traffic problem: control -> (the path rows it must satisfy, its floor).
AUXILIARY_CONTROLS: dict[str, tuple[tuple[str, ...], float]] = {
    "omega_rate": (("omega_epi_drive", "omega_epi_brake"), -ca.inf),  # e = max of the two right-hand sides
    "slack_gap": (("headway", "braking"), 0.0),  # σ = the smallest σ ≥ 0 meeting both soft constraints
}


def _auxiliary_rows(pr: OCPProblem, require_traffic: bool) -> dict[str, tuple[tuple[str, ...], float]]:
    """Every control but 'a' -> (its rows, its floor): the traffic problem's (AUXILIARY_CONTROLS; all required
    when ``require_traffic``), or a soft constraint's slack ``slack_<name>`` (rows <name>_lb / <name>_ub,
    ProblemBuilder.subject_to(soft=...); floor 0). Another control cannot be recovered from (x, a): ParameterError."""
    names, rows = list(pr.control_names), list(pr.meta.get("path_names", []))
    if require_traffic:
        return dict(AUXILIARY_CONTROLS)
    out: dict[str, tuple[tuple[str, ...], float]] = {}
    for ctrl in names[1:]:
        if ctrl in AUXILIARY_CONTROLS:
            out[ctrl] = AUXILIARY_CONTROLS[ctrl]
        elif ctrl.startswith("slack_") and any(f"{ctrl[6:]}_{s}" in rows for s in ("lb", "ub")):
            out[ctrl] = (tuple(f"{ctrl[6:]}_{s}" for s in ("lb", "ub") if f"{ctrl[6:]}_{s}" in rows), 0.0)
        else:
            raise ParameterError(
                f"the cost of problem {pr.name!r} cannot be evaluated on a run: its control {ctrl!r} "
                "is neither 'a' nor an epigraph or soft-constraint slack fixed by (x, a)"
            )
    return out


def auxiliary_controls(pr: OCPProblem, require_traffic: bool = True) -> ca.Function:
    """Function (x, a, w, p) -> u: the problem's whole control vector (a first) with every auxiliary control
    (AUXILIARY_CONTROLS; with ``require_traffic`` False also any soft constraint's slack) at its optimal value
    given (x, a). Its rows are affine in it: σ = max(floor, max_r (b_r − c_r(x, a, 0))/∂c_r/∂σ) with b_r the
    row's finite bound. Raises ParameterError if the problem lacks a control or row."""
    names = list(pr.control_names)
    rows = list(pr.meta.get("path_names", []))
    if not names or names[0] != "a" or (pr.path is None and (require_traffic or pr.nu > 1)):
        raise ParameterError(f"cost_traffic: problem {pr.name!r} needs control 'a' first and path constraints")
    if pr.path is None:
        x, a, w, p = (ca.SX.sym(n, k) for n, k in (("x", pr.nx), ("a", 1), ("w", pr.nw), ("p", pr.np_)))
        return ca.Function("aux_controls", [x, a, w, p], [a], ["x", "a", "w", "p"], ["u"])
    x, a, w, p = (ca.SX.sym(n, k) for n, k in (("x", pr.nx), ("a", 1), ("w", pr.nw), ("p", pr.np_)))
    u = ca.SX.sym("u", pr.nu)
    c = pr.path(x, u, w, p)
    dc = ca.jacobian(c, u)
    u0 = ca.vertcat(a, ca.SX.zeros(pr.nu - 1))
    c0 = ca.substitute(c, u, u0)
    dc0 = ca.substitute(dc, u, u0)
    val = [a] + [ca.SX(0)] * (pr.nu - 1)
    for ctrl, (need, floor) in _auxiliary_rows(pr, require_traffic).items():
        missing = [n for n in (ctrl, *need) if n not in names + rows]
        if missing:
            raise ParameterError(
                f"cost_traffic: problem {pr.name!r} has no {missing} (the traffic formulation's "
                "auxiliary controls and their constraints)"
            )
        j = names.index(ctrl)
        v: Any = ca.SX(floor) if np.isfinite(floor) else None
        for r in (rows.index(n) for n in need):
            bound = float(pr.path_lb[r]) if np.isfinite(float(pr.path_lb[r])) else float(pr.path_ub[r])
            vr = (bound - c0[r]) / dc0[r, j]
            v = vr if v is None else ca.fmax(v, vr)
        val[j] = v
    return ca.Function("aux_controls", [x, a, w, p], [ca.vertcat(*val)], ["x", "a", "w", "p"], ["u"])


def cost_traffic_of_trajectory(
    pr: OCPProblem,
    t: np.ndarray,
    z: np.ndarray,
    a: np.ndarray,
    w: np.ndarray,
    a_prev0: float = 0.0,
    p: np.ndarray | None = None,
    require_traffic: bool = True,
) -> dict[str, float]:
    """The traffic objective of a sampled trajectory on the node times t (N+1) [model time].

    z: (5, N+1) states (h, v [model], V1, V2 [V], S [-]) at the nodes; a: (N,) acceleration applied on each
    interval [model]; w: (nw, N) stage parameters (v̄_l, v̂_l) [model speed]; a_prev0: the command applied
    before t_0 (the closed loop's: 0). The own state a_prev is a shifted by one interval; the auxiliary
    controls are at their optimum given (z_k, a_k) (:func:`auxiliary_controls`). Returns 'stage' (Σ J_k
    through the problem's interval function, dt_k = t_{k+1} − t_k), 'terminal' (its terminal cost at z_N)
    and 'total', in the problem's cost unit (traffic: J/kg). ``require_traffic`` False: any problem whose extra
    controls are epigraph or soft-constraint slacks (:func:`problem_cost_of_result`)."""
    t = np.asarray(t, float).ravel()
    N = t.size - 1
    z = np.asarray(z, float)
    a = np.asarray(a, float).ravel()
    w = np.asarray(w, float).reshape(pr.nw, -1)
    if N < 1 or z.shape != (5, N + 1) or a.size != N or w.shape[1] != N:
        raise ParameterError(
            f"cost_traffic: t has {t.size} nodes, so z needs shape (5, {N + 1}), a {N} values and "
            f"w {N} columns (got z {z.shape}, a {a.size}, w {w.shape[1]})"
        )
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(a)) and np.all(np.isfinite(w))):
        raise ParameterError("cost_traffic: the trajectory (z, a, w) must be finite")
    own = list(pr.state_names[5:])
    if own not in ([], ["a_prev"]):
        raise ParameterError(f"cost_traffic: problem {pr.name!r} has own states {own}; only 'a_prev' is known")
    X = z if not own else np.vstack([z, np.concatenate([[a_prev0], a])])
    pp = np.zeros(pr.np_) if p is None else np.asarray(p, float).ravel()
    P = np.repeat(pp.reshape(-1, 1), N, axis=1)
    U = np.asarray(auxiliary_controls(pr, require_traffic).map(N)(X[:, :N], a.reshape(1, -1), w, P))
    xs = np.asarray(pr.x_scale if pr.x_scale is not None else np.ones(pr.nx), float)[:, None]
    us = np.asarray(pr.u_scale if pr.u_scale is not None else np.ones(pr.nu), float)[:, None]
    F = interval_function(pr, TranscriptionOptions(method="ms", N=N, rk4_substeps=1)).map(N)
    J = np.asarray(F(X[:, :N] / xs, U / us, ca.DM(0, N), X[:, 1:] / xs, w, P, np.diff(t).reshape(1, -1))[2])
    stage = float(J.sum())
    term = float(pr.terminal_cost(X[:, N], pp)) if pr.terminal_cost is not None else 0.0
    return {"stage": stage, "terminal": term, "total": stage + term}


def cost_traffic_of_result(
    r: Any, i: int, dt: float, pr: OCPProblem, p: np.ndarray | None = None, require_traffic: bool = True
) -> dict[str, float]:
    """``cost_traffic`` of follower i of a :class:`aev_ocp.results.SimulationResult` on the grid of step dt
    [model time] from the result's first time (the MPC's grid): states, the applied a_k and the predecessor's
    speed are the result's samples interpolated at the nodes (exact where the nodes are samples, as in a closed
    loop); v̂_l = the predecessor's speed at t_k, v̄_l its trapezoidal mean over the interval (v̄_l enters only
    the dynamics, not the cost). a_prev_0 = 0 (the closed loop's first command before t_0)."""
    K = int(round((r.t[-1] - r.t[0]) / dt))
    if K < 1:
        raise ParameterError(f"cost_traffic: the run covers {r.t[-1] - r.t[0]:g}, less than one interval dt = {dt:g}")
    tg = np.linspace(r.t[0], r.t[0] + K * dt, K + 1)

    def f(y: np.ndarray) -> np.ndarray:
        return np.interp(tg, r.t, y)

    vl = f(r.leader_speed if i == 0 else r.speed[:, i - 1])
    z = np.vstack([f(r.gap[:, i]), f(r.speed[:, i]), f(r.V1[:, i]), f(r.V2[:, i]), f(r.S[:, i])])
    w = np.vstack([0.5 * (vl[:-1] + vl[1:]), vl[:-1]])
    return cost_traffic_of_trajectory(pr, tg, z, f(r.accel[:, i])[:-1], w, p=p, require_traffic=require_traffic)


def problem_cost_of_result(r: Any, i: int, dt: float, pr: OCPProblem, p: np.ndarray | None = None) -> dict[str, float]:
    """The objective of any problem ``pr`` (e.g. a user's, with global parameters ``p``) of follower i's run on
    the grid of step dt [model time], as :func:`cost_traffic_of_result` (ParameterError if a control of the
    problem is not fixed by (x, a))."""
    return cost_traffic_of_result(r, i, dt, pr, p, require_traffic=False)

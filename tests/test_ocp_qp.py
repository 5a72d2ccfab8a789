"""The structure-exploiting interior-point QP solver (aev_ocp/c/ocp_qp.c through aev_ocp.mpc.ocpqp).

* Random convex OCP QPs (hypothesis, derandomized): solution and objective equal qpOASES (``ca.conic``) on
  the same QP assembled in CasADi's full sparse form, and the multipliers satisfy the KKT conditions of that
  full-space QP (stationarity, feasibility, complementarity, signs) in CasADi's convention.
* A control that enters the cost only linearly, bounded through general rows (an energy epigraph):
  solved (qrqp cannot).
* An LQR (no inequalities): one Newton step, equal to numpy's solve of the dense KKT system.
* nu = 0: the recursion is the state propagation.
* Statuses: non-convex control block, lb > ub, a NaN, the iteration limit; wrongly sized arguments.
* Real RTI QPs of the MPC (tests/data/ocp_qp_rti_*.npz, harvested from closed loops, on which the solver
  failed: plain Mehrotra stalled on degenerate energy-epigraph rows; the square-root Riccati could not take
  indefinite Hessian blocks of QPs whose reduced Hessian is positive definite): solved at the MPC's settings,
  and at a tight tolerance equal to the exact solution (the KKT system of the active set solved by numpy,
  checked feasible and sign-correct).
* A QP that is not convex (negative curvature along the dynamics) ends with a failure status, never "ok".
* A degenerate RTI QP (the §9 MPC, UDDS, stopped on its gap floor) on which the complementarity stalls at
  3.7e-9 above the tolerance 1e-9 and the iterates then diverge: the best iterate is returned as 'acceptable'
  (every residual within 100x its tolerance), equal to the exact solution as closely as the converged cases.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from aev_ocp.compiled import compiler
from aev_ocp.mpc.ocpqp import INF, OcpQP, OcpQPDims, OcpQPSettings, hpipm_library, random_qp, sparse_qp
from aev_ocp.params import ParameterError

pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler")

OK, MAX_ITER, FACTORIZATION, NONFINITE, INFEASIBLE, ACCEPTABLE = 0, 1, 2, 3, 4, 6


def _full(dims: OcpQPDims, data: dict[str, Any]) -> dict[str, Any]:
    """The full-space QP as dense numpy arrays (plus the row index sets)."""
    sq = sparse_qp(dims, data)
    return dict(sq, H=np.array(sq["h"]), A=np.array(sq["a"]))


def _objective(f: dict[str, Any], w: np.ndarray) -> float:
    return float(0.5 * w @ f["H"] @ w + f["g"] @ w)


def _kkt_violation(f: dict[str, Any], w: np.ndarray, lam_a: np.ndarray, lam_x: np.ndarray) -> float:
    """Largest violation of the KKT conditions of min 1/2 w'Hw + g'w s.t. lba <= A w <= uba, lbx <= w <= ubx
    with CasADi's multipliers (stationarity H w + g + A' lam_a + lam_x = 0; lam > 0 only on an active
    upper bound, < 0 only on an active lower one)."""
    stat = np.abs(f["H"] @ w + f["g"] + f["A"].T @ lam_a + lam_x).max()

    def rows(v: np.ndarray, lo: np.ndarray, up: np.ndarray, lam: np.ndarray) -> float:
        feas = np.maximum(np.maximum(lo - v, v - up), 0.0)
        gap_up = np.where(np.isfinite(up), up - v, np.inf)
        gap_lo = np.where(np.isfinite(lo), v - lo, np.inf)
        with np.errstate(invalid="ignore"):
            comp_up = np.where(lam > 0, np.where(np.isinf(gap_up), lam, lam * gap_up), 0.0)
            comp_lo = np.where(lam < 0, np.where(np.isinf(gap_lo), -lam, -lam * gap_lo), 0.0)
        return float(np.max(np.concatenate([feas, np.abs(comp_up), np.abs(comp_lo), [0.0]])))

    return max(float(stat), rows(f["A"] @ w, f["lba"], f["uba"], lam_a), rows(w, f["lbx"], f["ubx"], lam_x))


def _lam_a(f: dict[str, Any], pi: np.ndarray, lam_c: np.ndarray) -> np.ndarray:
    lam = np.zeros(f["A"].shape[0])
    lam[f["rows_pi"]] = pi
    lam[f["rows_c"]] = lam_c
    return lam


def _qpoases(f: dict[str, Any]) -> np.ndarray:
    import casadi as ca

    solver = ca.conic(
        "ref",
        "qpoases",
        {"h": f["h"].sparsity(), "a": f["a"].sparsity()},
        {"printLevel": "none", "enableRegularisation": True, "error_on_fail": False},
    )
    ref = solver(h=f["h"], a=f["a"], g=f["g"], lba=f["lba"], uba=f["uba"], lbx=f["lbx"], ubx=f["ubx"])
    assert solver.stats()["success"]
    return np.array(ref["x"]).ravel()


def _assert_solves(dims: OcpQPDims, data: dict[str, Any], res: Any, kkt_tol: float) -> None:
    """res is qpOASES's solution of the QP (to 1e-6 relative), a KKT point (to kkt_tol relative), x_0 = x0 exactly."""
    assert res.status == OK, (dims, res.status_name, res.residuals)
    f = _full(dims, data)
    w_ref = _qpoases(f)
    scale = 1.0 + np.abs(w_ref).max()
    assert np.abs(res.w - w_ref).max() <= 1e-6 * scale
    assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= kkt_tol * scale
    assert np.array_equal(res.w[: dims.nx], np.asarray(data["x0"]))


def _random_dims(rng: np.random.Generator) -> OcpQPDims:
    return OcpQPDims(
        N=int(rng.integers(1, 16)),
        nx=int(rng.integers(1, 5)),
        nu=int(rng.integers(1, 4)),
        nc=int(rng.integers(0, 5)),
        ncN=int(rng.integers(0, 3)),
    )


@settings(max_examples=40, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_random_qps_match_qpoases_and_satisfy_kkt(seed: int) -> None:
    rng = np.random.default_rng(seed)
    dims = _random_dims(rng)
    data = random_qp(dims, rng, scale=float(rng.uniform(0.3, 7.0)))
    res = OcpQP(dims).solve(**data)
    assert res.status == OK, (dims, res.status_name, res.residuals)
    f = _full(dims, data)
    w_ref = _qpoases(f)
    scale = 1.0 + np.abs(w_ref).max()
    assert np.abs(res.w - w_ref).max() <= 1e-6 * scale
    j_ref = _objective(f, w_ref)
    assert abs(_objective(f, res.w) - j_ref) <= 1e-8 * (1.0 + abs(j_ref))
    assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-8 * scale
    # x_0 is fixed and returned exactly
    assert np.array_equal(res.w[: dims.nx], np.asarray(data["x0"]))


def test_equality_rows_hold() -> None:
    rng = np.random.default_rng(20261129)
    dims = OcpQPDims(N=9, nx=3, nu=2, nc=3, ncN=1)
    data = random_qp(dims, rng, equality_rows=1.0)  # every stage's first row an equality
    f = _full(dims, data)
    w_ref = _qpoases(f)
    res = OcpQP(dims).solve(**data)
    assert res.status == OK
    Cw = f["A"][f["rows_c"]] @ res.w
    eq = np.isclose(f["lba"][f["rows_c"]], f["uba"][f["rows_c"]])
    assert eq.sum() == dims.N + 1
    assert np.abs(Cw[eq] - f["lba"][f["rows_c"]][eq]).max() <= 1e-9
    assert np.abs(res.w - w_ref).max() <= 1e-7 * (1 + np.abs(w_ref).max())
    assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-8 * (1 + np.abs(w_ref).max())


def _epigraph_qp(N: int = 12) -> tuple[OcpQPDims, dict[str, Any]]:
    """x = (position gap, speed); u = (acceleration a, energy e); cost q (gap - 7.5)^2 + r a^2 + w_e e with e
    entering only linearly, bounded below through two general rows e >= 2.3 a and e >= -0.4 a (the epigraph of
    a convex piecewise-linear energy), and |a| <= 2.5."""
    nx, nu, dt = 2, 2, 0.35
    dims = OcpQPDims(N=N, nx=nx, nu=nu, nc=2)
    A = np.array([[1.0, -dt], [0.0, 1.0]])
    B = np.array([[-0.5 * dt * dt, 0.0], [dt, 0.0]])
    Hk = np.diag([2 * 0.8, 2 * 0.05, 2 * 0.3, 0.0])
    gk = np.array([-2 * 0.8 * 7.5, 0.0, 0.0, 0.6])
    Ck = np.array([[0.0, 0.0, -2.3, 1.0], [0.0, 0.0, 0.4, 1.0]])
    data = dict(
        H=[Hk] * N + [np.diag([1.6, 0.1])],
        g=[gk] * N + [np.array([-1.6 * 7.5, 0.0])],
        E=[np.hstack([A, B])] * N,
        e=[np.zeros(nx)] * N,
        C=[Ck] * N + [np.zeros((0, nx))],
        lc=[np.zeros(2)] * N + [np.zeros(0)],
        uc=[np.full(2, np.inf)] * N + [np.zeros(0)],
        lbw=[np.array([-INF, -INF, -2.5, -INF])] * N + [np.full(nx, -INF)],
        ubw=[np.array([INF, INF, 2.5, INF])] * N + [np.full(nx, INF)],
        x0=np.array([11.0, 1.7]),
    )
    return dims, data


def test_a_control_entering_the_cost_linearly_is_solved() -> None:
    dims, data = _epigraph_qp()
    res = OcpQP(dims).solve(**data)
    assert res.status == OK
    f = _full(dims, data)
    assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-8
    nb = dims.nb
    a = res.w[[k * nb + 2 for k in range(dims.N)]]
    e = res.w[[k * nb + 3 for k in range(dims.N)]]
    assert np.abs(e - np.maximum(2.3 * a, -0.4 * a)).max() <= 1e-8  # the epigraph is tight
    assert np.abs(a).max() > 0.1  # and the problem is not trivial
    w_ref = _qpoases(f)  # regularised by qpOASES (H is singular in e): agreement to its perturbation only
    assert np.abs(res.w - w_ref).max() <= 1e-5 * (1 + np.abs(w_ref).max())
    assert _objective(f, res.w) <= _objective(f, w_ref) + 1e-9


def _lqr(N: int, nx: int, nu: int, rng: np.random.Generator) -> tuple[OcpQPDims, dict[str, Any]]:
    dims = OcpQPDims(N=N, nx=nx, nu=nu)
    nb = nx + nu
    data: dict[str, Any] = dict(
        H=[], g=[], E=[], e=[], C=None, lc=None, uc=None, lbw=[], ubw=[], x0=rng.normal(size=nx) * 2.7
    )
    for k in range(N + 1):
        n = nb if k < N else nx
        M = rng.normal(size=(n, n))
        H = M @ M.T * 0.3
        H[nx:, nx:] += np.eye(n - nx) * 0.7
        data["H"].append(H)
        data["g"].append(rng.normal(size=n) * 1.3)
        data["lbw"].append(np.full(n, -np.inf))
        data["ubw"].append(np.full(n, np.inf))
        if k < N:
            data["E"].append(rng.normal(size=(nx, nb)) * 0.6)
            data["e"].append(rng.normal(size=nx) * 0.4)
    return dims, data


def _dense_kkt_solution(dims: OcpQPDims, data: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(w, pi, lam of x_0) from numpy's solve of the dense KKT system (equalities: dynamics and x_0 = x0)."""
    f = _full(dims, data)
    nx, nw = dims.nx, dims.nw
    Aeq = np.vstack([f["A"][f["rows_pi"]], np.eye(nx, nw)])
    beq = np.concatenate([f["lba"][f["rows_pi"]], np.asarray(data["x0"])])
    K = np.block([[f["H"], Aeq.T], [Aeq, np.zeros((Aeq.shape[0],) * 2)]])
    sol = np.linalg.solve(K, np.concatenate([-f["g"], beq]))
    return sol[:nw], sol[nw : nw + dims.N * nx], sol[nw + dims.N * nx :]


@pytest.mark.quick
def test_lqr_is_one_newton_step_equal_to_the_dense_kkt_solve() -> None:
    dims, data = _lqr(13, 3, 2, np.random.default_rng(7))
    res = OcpQP(dims).solve(**data)
    assert res.status == OK and res.iterations == 1
    w, pi, lam0 = _dense_kkt_solution(dims, data)
    assert np.abs(res.w - w).max() <= 1e-9 * (1 + np.abs(w).max())
    assert np.abs(res.pi - pi).max() <= 1e-9 * (1 + np.abs(pi).max())
    assert np.abs(res.lam_w[: dims.nx] - lam0).max() <= 1e-9 * (1 + np.abs(lam0).max())
    assert np.abs(res.lam_w[dims.nx :]).max() == 0.0


def test_no_controls_is_the_state_propagation() -> None:
    dims, data = _lqr(6, 3, 0, np.random.default_rng(11))
    res = OcpQP(dims).solve(**data)
    assert res.status == OK
    x = np.asarray(data["x0"])
    for k in range(dims.N):
        x = data["E"][k] @ x + data["e"][k]
    assert np.abs(res.w[-dims.nx :] - x).max() <= 1e-10 * (1 + np.abs(x).max())
    _, pi, _ = _dense_kkt_solution(dims, data)
    assert np.abs(res.pi - pi).max() <= 1e-9 * (1 + np.abs(pi).max())


@pytest.mark.quick
def test_status_codes() -> None:
    rng = np.random.default_rng(3)
    dims, data = _lqr(5, 2, 1, rng)
    bad = dict(data, H=[h.copy() for h in data["H"]])
    bad["H"][2][2, 2] = -0.9  # a control with negative curvature and no bounds
    assert OcpQP(dims).solve(**bad).status == FACTORIZATION
    dims = OcpQPDims(N=6, nx=2, nu=1, nc=1)
    data = random_qp(dims, rng)
    assert OcpQP(dims).solve(**data).status == OK
    crossed = dict(data, lbw=[v.copy() for v in data["lbw"]])
    crossed["lbw"][3][2] = data["ubw"][3][2] + 0.25 if np.isfinite(data["ubw"][3][2]) else 3.0
    if not np.isfinite(data["ubw"][3][2]):
        crossed["ubw"] = [v.copy() for v in data["ubw"]]
        crossed["ubw"][3][2] = 2.0
    assert OcpQP(dims).solve(**crossed).status == INFEASIBLE
    nan = dict(data, g=[v.copy() for v in data["g"]])
    nan["g"][4][1] = np.nan
    assert OcpQP(dims).solve(**nan).status == NONFINITE
    limited = OcpQP(dims, OcpQPSettings(max_iter=1)).solve(**data)
    assert limited.status == MAX_ITER and limited.iterations == 1


@pytest.mark.quick
def test_bad_sizes_name_the_argument() -> None:
    dims = OcpQPDims(N=4, nx=2, nu=1, nc=1)
    data = random_qp(dims, np.random.default_rng(5))
    qp = OcpQP(dims)
    with pytest.raises(ParameterError, match=r"^g must have 5 stage blocks, got 4"):
        qp.solve(**dict(data, g=data["g"][:4]))
    with pytest.raises(ParameterError, match=r"^E\[2\] must have shape \(2, 3\)"):
        qp.solve(**dict(data, E=data["E"][:2] + [np.zeros((3, 2))] + data["E"][3:]))
    with pytest.raises(ParameterError, match=r"^lbw must have 14 entries"):
        qp.solve(**dict(data, lbw=np.zeros(13)))
    with pytest.raises(ParameterError, match=r"^x0 must have nx = 2"):
        qp.solve(**dict(data, x0=np.zeros(3)))
    with pytest.raises(ParameterError, match=r"^C is required"):
        qp.solve(**dict(data, C=None))
    with pytest.raises(ParameterError, match=r"OcpQPDims.nx must be an integer >= 1"):
        OcpQPDims(N=3, nx=0, nu=1)


def test_compiled_in_dimensions_give_the_same_solution() -> None:
    rng = np.random.default_rng(41)
    dims = OcpQPDims(N=7, nx=3, nu=2, nc=2, ncN=1)
    data = random_qp(dims, rng)
    generic, fixed = OcpQP(dims).solve(**data), OcpQP(dims, specialise=True).solve(**data)
    assert generic.status == fixed.status == OK and generic.iterations == fixed.iterations
    assert np.abs(generic.w - fixed.w).max() <= 1e-12 * (1 + np.abs(generic.w).max())
    assert np.abs(generic.lam_c - fixed.lam_c).max() <= 1e-10 * (1 + np.abs(generic.lam_c).max())


# the stage kernels (ocp_qp.c: fully unrolled when the dimensions are compiled in, up to 16 per loop): the MPC's
# two shapes, a terminal constraint with no stage rows, no controls, and blocks larger than the unrolling
KERNEL_DIMS = [
    OcpQPDims(N=9, nx=5, nu=1, nc=2),  # canonical MPC (model guide sec. 9)
    OcpQPDims(N=6, nx=6, nu=3, nc=6),  # traffic MPC
    OcpQPDims(N=5, nx=3, nu=2, nc=0, ncN=2),
    OcpQPDims(N=4, nx=4, nu=0, nc=1, ncN=1),
    OcpQPDims(N=3, nx=11, nu=7, nc=3, ncN=1),
]


@pytest.mark.parametrize("specialise", [False, True], ids=["generic", "compiled_dims"])
@pytest.mark.parametrize("dims", KERNEL_DIMS, ids=lambda d: f"nx{d.nx}_nu{d.nu}_nc{d.nc}_ncN{d.ncN}")
def test_stage_kernels_give_the_exact_active_set_solution(dims: OcpQPDims, specialise: bool) -> None:
    """At a tight tolerance the solution equals the exact one (numpy's solve of the KKT system of the active
    set, started from qpOASES's point), with the dimensions as run-time values and compiled in, on random QPs
    with active bounds and general rows (equality rows among them)."""
    qp = OcpQP(dims, _solve_settings(1e-11), specialise=specialise)
    active = 0
    for seed in range(3):
        data = random_qp(dims, np.random.default_rng(1000 * dims.nx + 10 * dims.nu + seed), scale=2.3)
        res = qp.solve(**data)
        assert res.status == OK, (res.status_name, res.iterations, res.residuals)
        f = _full(dims, data)
        w = _exact_solution(f, _qpoases(f))
        assert np.abs(res.w - w).max() <= 1e-8 * (1.0 + np.abs(w).max())
        assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-8 * (1.0 + np.abs(w).max())
        gx = np.concatenate([f["A"][f["rows_c"]] @ w, w[dims.nx :]])
        lo = np.concatenate([f["lba"][f["rows_c"]], f["lbx"][dims.nx :]])
        up = np.concatenate([f["uba"][f["rows_c"]], f["ubx"][dims.nx :]])
        active += int(np.sum((np.abs(gx - lo) < 1e-9) | (np.abs(gx - up) < 1e-9)))
    assert active >= 3  # the inequalities matter: rows of the sides' kernels are active


# ---------------------------------------------------------------------------------------------- real RTI QPs
DATA = Path(__file__).parent / "data"
RTI_EPIGRAPH = [
    "us06_constant_280",
    "us06_constant_6412",
    "us06_decaying_792",
    "us06_decaying_6410",
    "udds_constant_2",
    "udds_constant_factorization",  # traffic formulation, Hessian blocks PD
    "udds_constant_14268",
]  # stalled (alpha 1e-3) an intermediate version, correctors in every phase
RTI_INDEFINITE = [
    "indefinite_cold",
    "indefinite_warm",  # traffic, exact Hessian (blocks' min eig -0.08, -0.05)
    "paper_platoon_10",
    "paper_platoon_15",
    "paper_platoon_20",
]  # canonical s9, min eig -0.011
RTI_CASES = RTI_EPIGRAPH + RTI_INDEFINITE
MPC_TOL, MPC_MAX_ITER = 1e-9, 50  # aev_ocp.mpc.export.QP_TOL, QP_MAX_ITER: the MPC's QP settings


def _rti_case(name: str) -> tuple[OcpQPDims, dict[str, Any]]:
    """A QP recorded from the exported MPC step (aev_mpc_last_qp: flat stage layout of ocp_qp.h, x_0 = 0)."""
    with np.load(DATA / f"ocp_qp_rti_{name}.npz") as z:
        N, nx, nu, nc = (int(z[k]) for k in ("N", "nx", "nu", "nc"))
        data = {k: np.array(z[k]) for k in ("H", "g", "E", "e", "C", "lc", "uc", "lbw", "ubw")}
    data["x0"] = np.zeros(nx)
    return OcpQPDims(N=N, nx=nx, nu=nu, nc=nc), data


def _solve_settings(tol: float) -> OcpQPSettings:
    return OcpQPSettings(max_iter=MPC_MAX_ITER, tol_stat=tol, tol_eq=tol, tol_ineq=tol, tol_comp=tol)


def _exact_solution(f: dict[str, Any], w_start: np.ndarray) -> np.ndarray:
    """The QP's exact solution, independent of ocp_qp: starting from the constraints active at ``w_start``
    (HPIPM's solution), the equality-constrained QP of the active set is solved through its KKT system
    (the minimum-norm least-squares solution of numpy's lstsq, from one SVD of the KKT matrix: the active rows may
    be linearly dependent; then five refinement steps on the same factors); a violated
    constraint is added, an active one whose multiplier has the wrong sign dropped, until the point is
    feasible to 1e-11 with every multiplier of the right sign: the KKT conditions hold."""
    H, A, g = f["H"], f["A"], f["g"]
    n = H.shape[0]
    G = np.vstack([A, np.eye(n)])
    lo, up = np.concatenate([f["lba"], f["lbx"]]), np.concatenate([f["uba"], f["ubx"]])
    gw = G @ w_start
    act = {
        i: ("eq" if lo[i] == up[i] else "lo" if abs(gw[i] - lo[i]) < 1e-7 else "up")
        for i in range(len(lo))
        if lo[i] == up[i] or abs(gw[i] - lo[i]) < 1e-7 or abs(gw[i] - up[i]) < 1e-7
    }
    for _ in range(40):
        idx = sorted(act)
        Ga = G[idx]
        rhs = np.array([up[i] if act[i] == "up" else lo[i] for i in idx])
        K = np.block([[H, Ga.T], [Ga, np.zeros((len(idx), len(idx)))]])
        b = np.concatenate([-g, rhs])
        U, sv, Vt = np.linalg.svd(K)
        inv = np.where(sv > 1e-14 * sv[0], 1.0 / np.where(sv > 0.0, sv, 1.0), 0.0)  # lstsq's rcond cut-off

        def lstsq(r: np.ndarray) -> np.ndarray:
            return Vt.T @ (inv * (U.T @ r))  # noqa: B023 (used within this iteration only)

        sol = lstsq(b)
        for _ in range(5):
            sol += lstsq(b - K @ sol)
        w, lam = sol[:n], sol[n:]  # H w + g + Ga' lam = 0: lam >= 0 on an upper bound, <= 0 on a lower one
        gw = G @ w
        viol = np.maximum(lo - gw, 0.0) + np.maximum(gw - up, 0.0)
        wrong = [
            (abs(l), i) for i, l in zip(idx, lam) if (act[i] == "lo" and l > 1e-10) or (act[i] == "up" and l < -1e-10)
        ]
        if viol.max() < 1e-11 and not wrong:
            assert np.abs(K @ sol - b).max() < 1e-10
            return w
        if viol.max() >= 1e-11:
            j = int(np.argmax(viol))
            act[j] = "lo" if gw[j] < lo[j] else "up"
        else:
            del act[max(wrong)[1]]
    raise AssertionError("the active-set reference did not converge")


def _hpipm(f: dict[str, Any]) -> np.ndarray:
    import casadi as ca

    solver = ca.conic("ref", "hpipm", {"h": f["h"].sparsity(), "a": f["a"].sparsity()}, {"error_on_fail": False})
    ref = solver(h=f["h"], a=f["a"], g=f["g"], lba=f["lba"], uba=f["uba"], lbx=f["lbx"], ubx=f["ubx"])
    assert solver.stats()["success"]
    return np.array(ref["x"]).ravel()


class _ExactSolutions(dict):  # type: ignore[type-arg]
    """{case: its exact solution}, each computed on first use (a pytest-xdist worker computes only the cases it
    runs; the whole set took 20 s of setup in each worker, issue 40)."""

    def __missing__(self, name: str) -> np.ndarray:
        dims, data = _rti_case(name)
        f = _full(dims, data)
        self[name] = w = _exact_solution(f, _hpipm(f))
        return w


@pytest.fixture(scope="module")
def rti_exact() -> dict[str, np.ndarray]:
    return _ExactSolutions()


@pytest.mark.parametrize("name", RTI_CASES)
def test_real_rti_qps_solve_at_the_mpc_settings(name: str, rti_exact: dict[str, np.ndarray]) -> None:
    dims, data = _rti_case(name)
    res = OcpQP(dims, _solve_settings(MPC_TOL), specialise=True).solve(**data)
    assert res.status == OK, (res.status_name, res.iterations, res.residuals)
    assert res.iterations <= 20  # plain Mehrotra: 50 (the limit), complementarity stuck at ~2e-4
    assert max(res.residuals.values()) <= MPC_TOL
    f = _full(dims, data)
    w = rti_exact[name]
    # degenerate (weakly active) rows: the interior point's w is O(sqrt(mean s z)) from the solution
    assert np.abs(res.w - w).max() <= 3e-4
    # the duality gap: sum of s z over the finite sides = their number times the mean (<= the tolerance)
    n_sides = sum(
        int(np.isfinite(v).sum())
        for v in (f["lbx"][dims.nx :], f["ubx"][dims.nx :], f["lba"][f["rows_c"]], f["uba"][f["rows_c"]])
    )
    assert 0.0 <= _objective(f, res.w) - _objective(f, w) <= 1.01 * n_sides * MPC_TOL
    assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-6


@pytest.mark.parametrize("name", RTI_CASES)
def test_real_rti_qps_at_a_tight_tolerance_equal_the_exact_solution(
    name: str, rti_exact: dict[str, np.ndarray]
) -> None:
    dims, data = _rti_case(name)
    res = OcpQP(dims, _solve_settings(1e-12), specialise=True).solve(**data)
    assert res.status == OK, (res.status_name, res.iterations, res.residuals)
    assert np.abs(res.w - rti_exact[name]).max() <= 2e-7  # observed <= 8e-8 (us06_constant_6412)


def test_a_stalled_degenerate_qp_returns_its_acceptable_iterate() -> None:
    """Recorded from the §9 MPC on UDDS (constant-velocity forecast, step 1825): the car stopped on its 3 m floor.
    Before the acceptable level the solver ran to its limit and returned the last iterate (residuals ~1e89), and
    the MPC fell back 12 times in a row. Reference: qpOASES (the active-set reference of the other cases does not
    converge here: the active rows are linearly dependent)."""
    dims, data = _rti_case("udds_s9_stopped_on_floor")
    res = OcpQP(dims, _solve_settings(MPC_TOL)).solve(**data)
    assert res.status == ACCEPTABLE and res.status_name == "acceptable", (res.status_name, res.residuals)
    assert MPC_TOL < max(res.residuals.values()) <= 100 * MPC_TOL
    assert res.iterations < MPC_MAX_ITER  # the divergence after the acceptable iterate ends the solve early
    f = _full(dims, data)
    w_ref = _qpoases(f)
    assert np.abs(res.w - w_ref).max() <= 1e-6  # observed 8.8e-8
    j_ref = _objective(f, w_ref)
    assert abs(_objective(f, res.w) - j_ref) <= 1e-8 * (1.0 + abs(j_ref))
    assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-6
    assert OcpQP(dims, _solve_settings(1e-7)).solve(**data).status == OK  # converged at a looser tolerance
    # a limit below the first acceptable iterate: no acceptable point, the plain failure
    two = OcpQPSettings(max_iter=2, **{k: MPC_TOL for k in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp")})
    assert OcpQP(dims, two).solve(**data).status == MAX_ITER


def _reduced_hessian_min_eig(dims: OcpQPDims, f: dict[str, Any]) -> float:
    """Smallest eigenvalue of the Hessian on the null space of the dynamics and x_0 = x0 (numpy SVD)."""
    A_eq = np.vstack([f["A"][f["rows_pi"]], np.eye(dims.nx, dims.nw)])
    _, sv, vt = np.linalg.svd(A_eq)
    Z = vt[int(np.sum(sv > 1e-10 * sv[0])) :].T
    return float(np.linalg.eigvalsh(Z.T @ f["H"] @ Z).min())


@pytest.mark.parametrize("name", RTI_INDEFINITE)
def test_indefinite_blocks_of_a_convex_qp(name: str) -> None:
    """These cases are outside the old contract (every H_k PSD) but convex: P_k of the Riccati recursion is
    then indefinite (solved without its square root) and every control block stays positive definite."""
    dims, data = _rti_case(name)
    nb = dims.nb
    blocks = data["H"][: dims.N * nb * nb].reshape(dims.N, nb, nb)
    assert np.linalg.eigvalsh(blocks).min() < -0.01
    assert _reduced_hessian_min_eig(dims, _full(dims, data)) > 1e-4


def test_a_nonconvex_qp_fails_with_a_status() -> None:
    """Negative curvature on the terminal state, no bounds: the reduced Hessian is indefinite; the Riccati
    recursion finds a control block that is not positive definite."""
    dims, data = _lqr(6, 2, 1, np.random.default_rng(17))
    data["H"][-1] = -np.diag([4.5, 3.5])
    f = _full(dims, data)
    assert _reduced_hessian_min_eig(dims, f) < 0.0
    res = OcpQP(dims).solve(**data)
    assert res.status == FACTORIZATION


# ---------------------------------------------------------------------------------------------- HPIPM backend
# The second backend of ocp_qp.h (aev_ocp/c/ocp_qp_hpipm.c, HPIPM's C API as the casadi wheel ships it): the same
# data and outputs; checked against the same independent references (qpOASES, the active-set exact solution,
# the KKT conditions with its multipliers).
_HPIPM_WHY = hpipm_library()
needs_hpipm = pytest.mark.skipif(isinstance(_HPIPM_WHY, str), reason=f"HPIPM backend unavailable: {_HPIPM_WHY}")


@needs_hpipm
@settings(max_examples=15, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_hpipm_backend_random_qps_match_qpoases_and_satisfy_kkt(seed: int) -> None:
    rng = np.random.default_rng(seed)
    dims = _random_dims(rng)
    if dims.nx == 1 and dims.nu == 3:  # refused by the backend (test_hpipm_backend_refuses_...)
        dims = OcpQPDims(dims.N, 2, dims.nu, dims.nc, dims.ncN)
    data = random_qp(dims, rng, scale=float(rng.uniform(0.3, 7.0)))
    res = OcpQP(dims, backend="hpipm", hpipm_mode="robust").solve(**data)
    _assert_solves(dims, data, res, 1e-7)


@needs_hpipm
@pytest.mark.parametrize("name", RTI_CASES)
def test_hpipm_backend_on_the_recorded_rti_qps(name: str, rti_exact: dict[str, np.ndarray]) -> None:
    """Mode ROBUST solves every recorded QP at the MPC's settings; every mode's 'ok' is the solution (the
    same bounds as ocp_qp.c's test above), its multipliers satisfy the KKT conditions."""
    dims, data = _rti_case(name)
    f = _full(dims, data)
    w = rti_exact[name]
    for mode in ("speed", "balance", "robust"):
        res = OcpQP(dims, _solve_settings(MPC_TOL), backend="hpipm", hpipm_mode=mode).solve(**data)
        if mode == "robust":
            assert res.status == OK, (res.status_name, res.iterations, res.residuals)
        if res.status != OK:
            continue
        assert np.abs(res.w - w).max() <= 3e-4, mode
        assert _kkt_violation(f, res.w, _lam_a(f, res.pi, res.lam_c), res.lam_w) <= 1e-6, mode


@needs_hpipm
def test_hpipm_backend_status_codes() -> None:
    rng = np.random.default_rng(31)
    dims = OcpQPDims(N=6, nx=2, nu=1, nc=1)
    data = random_qp(dims, rng)
    qp = OcpQP(dims, backend="hpipm")
    assert qp.solve(**data).status == OK
    crossed = dict(data, lbw=[v.copy() for v in data["lbw"]], ubw=[v.copy() for v in data["ubw"]])
    crossed["ubw"][3][2], crossed["lbw"][3][2] = 2.0, 2.25
    assert qp.solve(**crossed).status == INFEASIBLE
    nan = dict(data, g=[v.copy() for v in data["g"]])
    nan["g"][4][1] = np.nan
    assert qp.solve(**nan).status == NONFINITE
    limited = OcpQP(dims, OcpQPSettings(max_iter=1), backend="hpipm").solve(**data)
    assert limited.status == MAX_ITER and limited.iterations == 1


@pytest.mark.quick
def test_unknown_backend_or_mode_is_a_parameter_error() -> None:
    dims = OcpQPDims(N=3, nx=2, nu=1)
    with pytest.raises(ParameterError, match="backend"):
        OcpQP(dims, backend="qpoases")
    with pytest.raises(ParameterError, match="hpipm_mode"):
        OcpQP(dims, backend="hpipm", hpipm_mode="fast")


@needs_hpipm
def test_hpipm_backend_refuses_the_dimensions_it_gets_wrong() -> None:
    """nx = 1 with nx + nu a multiple of 4: the shipped libhpipm's controls are wrong there (ocp_qp_hpipm.c);
    the backend refuses them with a stated reason, and its neighbours agree with ocp_qp.c."""
    from aev_ocp.mpc.ocpqp import OcpQPError

    with pytest.raises(OcpQPError, match="nx = 1"):
        OcpQP(OcpQPDims(N=3, nx=1, nu=3), backend="hpipm")
    for nx, nu in ((1, 2), (1, 4), (2, 2), (3, 5)):
        dims = OcpQPDims(N=3, nx=nx, nu=nu)
        data = random_qp(dims, np.random.default_rng(7), absent=1.0)
        ref = OcpQP(dims).solve(**data)
        res = OcpQP(dims, backend="hpipm").solve(**data)
        assert res.status == OK and np.abs(res.w - ref.w).max() <= 1e-8 * (1 + np.abs(ref.w).max())


# ---------------------------------------------------------------------------------------------- warm start
def _guess(r: Any) -> dict[str, np.ndarray]:
    return {"w": r.w, "pi": r.pi, "lam_w": r.lam_w, "lam_c": r.lam_c}


def _perturbed_gradient(data: dict[str, Any], rng: np.random.Generator, size: float) -> dict[str, Any]:
    """The same QP with its gradient g moved by ``size`` relative (the next QP of a sequence: still feasible)."""
    g = np.concatenate([np.ravel(b) for b in data["g"]])
    return {**data, "g": g + size * rng.normal(size=g.size) * (1.0 + np.abs(g))}


@settings(max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_warm_started_sequences_match_qpoases_and_satisfy_kkt(seed: int) -> None:
    """A sequence of QPs (the gradient moved by 5 % each time), each started from the previous solution
    (ocpqp_solve_warm): every one equal to qpOASES's solution and a KKT point, x_0 exactly x0 (not the guess's)."""
    rng = np.random.default_rng(seed)
    dims = _random_dims(rng)
    data = random_qp(dims, rng, scale=float(rng.uniform(0.3, 7.0)))
    qp = OcpQP(dims)
    prev = qp.solve(**data)
    # the cold start does not converge on a few of these QPs (7 of the first 3000 seeds: 768, 934, 2145, 2210,
    # 2744, 2903 end 'acceptable', every residual within 100x the tolerance, a breakdown of the factorisation
    # after it; 770 'factorization'; the cold solver's own weakness, not the warm start's): no sequence then
    assume(prev.status == OK)
    for _ in range(3):
        data = _perturbed_gradient(data, rng, 0.05)
        guess = _guess(prev)
        guess["w"] = guess["w"] + 0.1  # x_0 of the guess is not x0: the solver must replace it
        res = qp.solve(**data, warm=guess)
        _assert_solves(dims, data, res, 1e-8)
        prev = res


def test_warm_start_saves_iterations() -> None:
    """Over 30 random QPs: from the QP's own solution the warm start takes at most 0.36 times the cold start's
    iterations (observed 0.31; 0.40 with the cold start's fraction to the boundary 0.995), from the previous
    solution of a sequence (gradient moved by 5 %) at most 0.6 times (observed 0.56; 0.63 with 0.995); a guess far off (random point, multipliers of size 1e3 and either sign) still ends
    at the cold start's solution (the warm start fails within OCPQP_WARM_MAX_ITER, then the cold one runs)."""
    its = {"cold": 0, "self": 0, "seq_cold": 0, "seq_warm": 0}
    for seed in range(30):
        rng = np.random.default_rng(seed)
        dims = _random_dims(rng)
        data = random_qp(dims, rng, scale=float(rng.uniform(0.3, 7.0)))
        qp = OcpQP(dims)
        cold = qp.solve(**data)
        own = qp.solve(**data, warm=_guess(cold))
        assert cold.status == own.status == OK
        assert np.abs(own.w - cold.w).max() <= 1e-6 * (1.0 + np.abs(cold.w).max())
        its["cold"] += cold.iterations
        its["self"] += own.iterations
        far = {
            "w": 10.0 * rng.normal(size=dims.nw),
            "pi": 1e3 * rng.normal(size=dims.N * dims.nx),
            "lam_w": 1e3 * rng.normal(size=dims.nw),
            "lam_c": 1e3 * rng.normal(size=dims.N * dims.nc + dims.ncN),
        }
        bad = qp.solve(**data, warm=far)
        assert bad.status == OK
        assert np.abs(bad.w - cold.w).max() <= 1e-6 * (1.0 + np.abs(cold.w).max())
        nxt = _perturbed_gradient(data, rng, 0.05)
        its["seq_cold"] += qp.solve(**nxt).iterations
        its["seq_warm"] += qp.solve(**nxt, warm=_guess(cold)).iterations
    assert its["self"] <= 0.36 * its["cold"], its
    assert its["seq_warm"] <= 0.6 * its["seq_cold"], its


@pytest.mark.quick
def test_warm_start_bad_guesses() -> None:
    rng = np.random.default_rng(20261203)
    dims = OcpQPDims(N=6, nx=3, nu=2, nc=2, ncN=1)
    data = random_qp(dims, rng)
    qp = OcpQP(dims)
    res = qp.solve(**data)
    guess = _guess(res)
    guess["lam_c"] = guess["lam_c"].copy()
    guess["lam_c"][3] = np.nan
    assert qp.solve(**data, warm=guess).status == NONFINITE
    with pytest.raises(ParameterError, match="lam_c"):
        qp.solve(**data, warm={"lam_c": np.zeros(3)})
    with pytest.raises(ParameterError, match="unknown warm-start keys"):
        qp.solve(**data, warm={"z": np.zeros(3)})
    # no guess at all (every part zero) is a valid warm start
    assert np.abs(qp.solve(**data, warm={}).w - res.w).max() <= 1e-6 * (1.0 + np.abs(res.w).max())

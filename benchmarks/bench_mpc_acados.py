"""aev_ocp's MPC step against acados on the same problem, in the same process (issue 40, item 6).

The problem: the canonical §9 MPC (scenarios/mpc_paper_single.toml: one follower behind the Table 1 leader,
h(0) = 0.3, v(0) = 1.87, oracle forecast, N = 40, dt = 0.1 model time, RK4 with one substep, exact Lagrangian
Hessian). acados gets the very same CasADi expressions aev_ocp's step is generated from
(:attr:`aev_ocp.mpc.nlp.HorizonNLP.F`, the interval function on the scaled variables): its discrete dynamics are
the interval's RK4 end state, its external stage cost s_k·J_k, its nonlinear constraints the two path constraints
at nodes 0…N−1, its simple bounds the state bounds at nodes 1…N and the control bounds; the measured state is fixed
at node 0; stage parameters (the forecast), the four §9 weights and the stage weight are per-stage parameters.
Each step is one SQP iteration (SQP_RTI, exact Hessian) warm-started as aev_ocp's: the previous primal-dual
solution shifted by one interval, the last node extended by the model (clipped to the bounds), node 0 replaced
by the measurement. The first step of both starts cold: 5 SQP iterations from the closed-form law's rollout.
The 1e-10 QP tolerances are aev_ocp's ocp_qp.c defaults, given to acados's QP solvers too.

The inputs: the closed loop of the shipped path (rti, qp_solver 'riccati': the compiled C step) is run once and
its measured states and forecasts recorded; every solver then replays that same sequence, step by step
interleaved (so machine load hits all alike). Agreement: max |Δa_0| (first control, model units) and max |ΔU|
(whole plan) of each acados configuration against aev_ocp on every step. Times per step, first (cold) step
excluded: 'solve' is the solver call alone (aev_ocp: the ctypes call of the compiled step, which also shifts
its warm start inside; acados: ``AcadosOcpSolver.solve()``, and acados's own ``time_tot``), 'step' the whole
step through each one's Python interface (aev_ocp: ``MPCController.solve``; acados: setting x0, the parameters
and the shifted warm start stage by stage, solve, reading the plan back). Interleaved, each step starts with cold
caches: between two steps of one solver the eight others run, whose code and data (several MB, with the other
processes of the machine) evict its own from the caches, so it is fetched from main memory again (measured: the
compiled step takes about twice its time replayed alone). So each solver also replays the inputs once on its own,
steps back to back ('solve_median_ms_alone'), as does the profile of aev_ocp's C parts.

acados is not a dependency of aev_ocp: this script runs in a separate venv where it is importable (recipe in
docs/guide/mpc.md, 'acados comparison'); without it the script says so and exits 0 without writing anything.
Usage: python benchmarks/bench_mpc_acados.py [--N 40] [--t-end 70] [--passes 2] [--configs hpipm-balance ...]
       [--out benchmarks/bench_mpc_acados.json]
"""

from __future__ import annotations

import argparse
import ctypes
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: the stand-in for an infinite bound (one-sided bounds): acados's own infinity (ACADOS_POS_INFTY, 1e9) is not
#: masked by this acados's HPIPM interface, which then stalls at its iteration limit on every QP (measured: 50
#: iterations, complementarity stuck at 1e-7); 1e4 is never active (scaled variables and constraints are O(1…50))
ACADOS_INF = 1.0e4
#: acados configurations compared (name -> solver options); the QP tolerances are aev_ocp's (ocp_qp.h defaults)
CONFIGS: dict[str, dict[str, Any]] = {
    # each stage's Hessian block projected onto the PD cone (acados PROJECT), against aev_ocp's rti_hessian 'projected'
    "hpipm-speed_abs": dict(qp_solver="PARTIAL_CONDENSING_HPIPM", hpipm_mode="SPEED_ABS"),
    "hpipm-speed": dict(qp_solver="PARTIAL_CONDENSING_HPIPM", hpipm_mode="SPEED"),
    "hpipm-balance": dict(qp_solver="PARTIAL_CONDENSING_HPIPM", hpipm_mode="BALANCE"),
    "hpipm-cond10": dict(qp_solver="PARTIAL_CONDENSING_HPIPM", hpipm_mode="BALANCE", qp_solver_cond_N=10),
    "full-qpoases": dict(qp_solver="FULL_CONDENSING_QPOASES"),
    # the exact Hessian (NO_REGULARIZE), against aev_ocp's rti_hessian 'exact' (§9 as published): the condensed QP
    # needs only a PD reduced Hessian, as aev_ocp's Riccati interior point
    "full-qpoases-exact": dict(qp_solver="FULL_CONDENSING_QPOASES", regularize_method="NO_REGULARIZE"),
    "full-hpipm-exact": dict(qp_solver="FULL_CONDENSING_HPIPM", regularize_method="NO_REGULARIZE"),
}
#: configurations not run by default (measured once: HPIPM's ROBUST mode ran into its 50-iteration limit on every QP;
#: the partially condensed HPIPM on the exact blocks, which are indefinite on this loop, too)
MORE_CONFIGS: dict[str, dict[str, Any]] = {
    "hpipm-robust": dict(qp_solver="PARTIAL_CONDENSING_HPIPM", hpipm_mode="ROBUST"),
    "hpipm-exact": dict(qp_solver="PARTIAL_CONDENSING_HPIPM", regularize_method="NO_REGULARIZE"),
}
ALL_CONFIGS = {**CONFIGS, **MORE_CONFIGS}


def hessian_of(opts: dict[str, Any]) -> str:
    """aev_ocp's rti_hessian that solves the same QP as an acados configuration."""
    return "exact" if opts.get("regularize_method") == "NO_REGULARIZE" else "projected"


QP_TOL = 1e-10
COLD_ITERATIONS = 5
#: acados's dynamics multipliers against CasADi's of g_k = F(z_k, u_k) − z_{k+1} = 0 (checked by the agreement)
PI_SIGN = 1.0
#: acados's own timers of a solve (CPU time [s]): linearisation (the CasADi-generated functions), regularisation
#: (the Hessian projection), the QP (with its condensing) and the QP solver alone
TIME_PARTS = ("time_lin", "time_reg", "time_qp", "time_qp_solver_call")  # MPCSettings.rti_cold_iterations (default)


def load_acados() -> tuple[Any, str] | None:
    """(acados_template, where) or None. comma-deps-acados ships acados_template inside its ``acados`` package with
    the libraries and t_renderer under ``acados/install``; an upstream install has ``acados_template`` top level
    and ACADOS_SOURCE_DIR set."""
    try:
        import acados  # comma-deps-acados

        os.environ.setdefault("ACADOS_SOURCE_DIR", acados.DIR)
        os.environ.setdefault("TERA_PATH", acados.TERA_PATH)
        os.environ.setdefault("ACADOS_PYTHON_INTERFACE_PATH", acados.TEMPLATE_DIR)
        # its libraries carry no run path: load libacados's dependencies first, globally
        for lib in ("libblasfeo.so", "libhpipm.so", "libqpOASES_e.so.3.1"):
            ctypes.CDLL(os.path.join(acados.LIB_DIR, lib), mode=ctypes.RTLD_GLOBAL)
        from acados import acados_template as at

        return at, f"comma-deps-acados ({acados.DIR})"
    except ImportError:
        pass
    try:
        import acados_template as at  # upstream acados

        return at, f"acados_template ({os.environ.get('ACADOS_SOURCE_DIR', '?')})"
    except ImportError:
        return None


def controller(N: int, hessian: str) -> Any:
    """The shipped controller (compiled step) of the canonical §9 scenario with the RTI Hessian ``hessian``."""
    from bench_mpc import COMPILED, F9, S9

    from aev_ocp.mpc.controller import MPCController
    from aev_ocp.mpc.settings import MPCSettings

    return MPCController(MPCSettings(N=N, **{**S9, "rti_hessian": hessian}, **COMPILED), formulation=F9)


def finite_bounds(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices of rows with a finite bound, lower, upper) with ±inf as acados's infinity."""
    idx = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
    return idx, np.maximum(lo[idx], -ACADOS_INF), np.minimum(hi[idx], ACADOS_INF)


class AcadosMPC:
    """acados on the MPC's problem (see the module docstring), with aev_ocp's warm-start policy."""

    def __init__(self, at: Any, c: Any, name: str, opts: dict[str, Any], build_dir: Path) -> None:
        import casadi as ca

        nlp, pr, s = c.nlp, c.problem, c.settings
        self.c, self.N, self.nx, self.nu = c, s.N, nlp.nx, nlp.nu
        nx, nu, nw, npp = nlp.nx, nlp.nu, pr.nw, pr.np_
        x, u, par = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("par", nw + npp + 1)
        w, pp, sw = par[:nw], par[nw : nw + npp], par[nw + npp]
        eq, path, J = nlp.F(x, u, ca.SX(0, 1), ca.SX.zeros(nx), w, pp, s.dt)
        model = at.AcadosModel()
        model.name = f"aev_{name.replace('-', '_')}_N{s.N}"
        model.x, model.u, model.p = x, u, par
        model.disc_dyn_expr = eq  # the interval's end state (scaled): x_{k+1} = F(x_k, u_k)
        model.con_h_expr = path
        model.cost_expr_ext_cost = sw * J
        mayer = pr.terminal_cost(x * ca.DM(nlp.x_scale), pp) if pr.terminal_cost is not None else 0 * x[0]
        model.cost_expr_ext_cost_e = mayer
        ocp = at.AcadosOcp()
        ocp.model = model
        ocp.dims.N = s.N
        ocp.cost.cost_type = ocp.cost.cost_type_e = "EXTERNAL"
        ocp.parameter_values = np.zeros(nw + npp + 1)
        ub = finite_bounds(*(b / nlp.u_scale for b in nlp._ub))
        xb = finite_bounds(*(b / nlp.x_scale for b in nlp._xb))
        ocp.constraints.idxbu, ocp.constraints.lbu, ocp.constraints.ubu = ub
        ocp.constraints.idxbx, ocp.constraints.lbx, ocp.constraints.ubx = xb
        ocp.constraints.idxbx_e, ocp.constraints.lbx_e, ocp.constraints.ubx_e = xb
        ocp.constraints.lh = np.maximum(np.asarray(pr.path_lb, float), -ACADOS_INF)
        ocp.constraints.uh = np.minimum(np.asarray(pr.path_ub, float), ACADOS_INF)
        ocp.constraints.x0 = np.ones(nx)
        o = ocp.solver_options
        o.integrator_type = "DISCRETE"
        o.nlp_solver_type = "SQP_RTI"
        o.hessian_approx = "EXACT"
        # each stage's Hessian block projected onto the PD cone, as aev_ocp's rti_hessian = 'projected' (HPIPM's
        # Riccati recursion fails on the exact blocks, which are indefinite on this loop: with NO_REGULARIZE every QP
        # ran into the iteration limit; acados's floor is 1e-4, aev_ocp's 1e-8·(1 + max |eigenvalue|))
        o.regularize_method = "PROJECT"
        o.tf = float(s.N)  # unit time steps: acados scales the stage cost by the step; the dynamics are discrete
        o.qp_solver_iter_max = 50  # ocp_qp.h's default
        o.qp_solver_tol_stat = o.qp_solver_tol_eq = o.qp_solver_tol_ineq = o.qp_solver_tol_comp = QP_TOL
        o.print_level = 0
        for k, v in opts.items():
            setattr(o, k, v)
        self.name, self.opts = name, opts
        cwd = os.getcwd()
        build_dir.mkdir(parents=True, exist_ok=True)
        os.chdir(build_dir)
        t0 = time.perf_counter()
        try:
            ocp.code_export_directory = str(build_dir / "c_generated_code")
            self.solver = at.AcadosOcpSolver(ocp, json_file=str(build_dir / f"{model.name}.json"), verbose=False)
        finally:
            os.chdir(cwd)
        self.build_s = time.perf_counter() - t0
        self.nlam = [self.solver.get(k, "lam").size for k in range(s.N + 1)]
        #: the previous step's solution (X, U, PI, LAM; scaled), None: the next step starts cold
        self.prev: tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]] | None = None

    # -- one step ---------------------------------------------------------
    def set_params(self, p: np.ndarray) -> None:
        """The NLP parameter vector of aev_ocp (forecast per interval, weights, stage weights) per stage."""
        W, pp = self.c.nlp.w_and_p(p)
        sw = p[-self.N :]
        for k in range(self.N):
            self.solver.set(k, "p", np.concatenate([W[:, k], pp, [sw[k]]]))
        self.solver.set(self.N, "p", np.concatenate([W[:, -1], pp, [0.0]]))

    def set_x0(self, xs0: np.ndarray) -> None:
        self.solver.set(0, "lbx", xs0)
        self.solver.set(0, "ubx", xs0)

    def set_iterate(self, X: np.ndarray, U: np.ndarray, PI: np.ndarray, LAM: list[np.ndarray]) -> None:
        for k in range(self.N):
            self.solver.set(k, "x", X[k])
            self.solver.set(k, "u", U[k])
            self.solver.set(k, "pi", PI[k])
            self.solver.set(k, "lam", LAM[k])
        self.solver.set(self.N, "x", X[self.N])
        self.solver.set(self.N, "lam", LAM[self.N])

    def get_iterate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
        g = self.solver.get
        X = np.array([g(k, "x") for k in range(self.N + 1)])
        U = np.array([g(k, "u") for k in range(self.N)])
        PI = np.array([g(k, "pi") for k in range(self.N)])
        return X, U, PI, [g(k, "lam") for k in range(self.N + 1)]

    def _lam_like(self, lam_from: np.ndarray, k_to: int, k_from: int) -> np.ndarray:
        """Multipliers of stage k_from moved to stage k_to: the h constraints' (they enter the exact Hessian) and
        the control bounds' where the layouts differ (node 0 bounds all states, the others only the finite ones)."""
        if self.nlam[k_to] == lam_from.size:
            return lam_from.copy()
        nbu, nh = 1, 2
        out = np.zeros(self.nlam[k_to])
        half_to, half_from = self.nlam[k_to] // 2, lam_from.size // 2
        for side in (0, 1):
            out[side * half_to : side * half_to + nbu] = lam_from[side * half_from : side * half_from + nbu]
            out[side * half_to + half_to - nh : (side + 1) * half_to] = lam_from[
                side * half_from + half_from - nh : (side + 1) * half_from
            ]
        return out

    def shifted(self, xs0: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
        """aev_ocp's warm start (HorizonNLP.shift): the previous solution one interval on, the last node by the
        model from (x_N, u_{N−1}) clipped to the bounds, node 0 the measurement; multipliers shifted alike."""
        nlp = self.c.nlp
        assert self.prev is not None
        X, U, PI, LAM = self.prev
        W, pp = nlp.w_and_p(p)
        zN = np.asarray(nlp.step(X[-1] * nlp.x_scale, U[-1] * nlp.u_scale, W[:, -1], pp)).ravel() / nlp.x_scale
        zN = np.clip(zN, nlp.lbx[-self.nx :], nlp.ubx[-self.nx :])
        Xs = np.vstack([xs0, X[2:], zN])
        Us = np.vstack([U[1:], U[-1:]])
        PIs = np.vstack([PI[1:], PI[-1:]])
        LAMs = [self._lam_like(LAM[k + 1], k, k + 1) for k in range(self.N - 1)]
        LAMs += [LAM[self.N - 1].copy(), LAM[self.N].copy()]
        return Xs, Us, PIs, LAMs

    def seed(self, x: np.ndarray, lam_g: np.ndarray, sign_pi: float = PI_SIGN) -> None:
        """Take aev_ocp's solution (scaled NLP vector x and constraint multipliers lam_g) as the previous
        solution, so the next (warm) step of both starts from the same primal-dual point: states, controls, the
        dynamics' multipliers (pi) and the path constraints' (acados splits them into lower and upper, both
        ≥ 0). The simple bounds' multipliers are set to 0: bounds are linear (they do not enter the Hessian)
        and the QP solvers start cold."""
        nlp, N, nx = self.c.nlp, self.N, self.nx
        X, _, U = nlp.unpack(x)
        Xs, Us = (X / nlp.x_scale[:, None]).T, (U / nlp.u_scale[:, None]).T
        G = lam_g[: N * nlp.ng_stage].reshape(N, nlp.ng_stage)
        PI = sign_pi * G[:, :nx]
        LAM = [np.zeros(n) for n in self.nlam]
        for k in range(N):
            lh = G[k, nx:]
            half = self.nlam[k] // 2
            LAM[k][half - lh.size : half] = np.maximum(-lh, 0.0)
            LAM[k][2 * half - lh.size :] = np.maximum(lh, 0.0)
        self.prev = (Xs, Us, PI, LAM)

    def step(self, z0: np.ndarray, p: np.ndarray) -> dict[str, Any]:
        """One MPC step: cold (the law's rollout, COLD_ITERATIONS SQP iterations) the first time, else warm."""
        nlp = self.c.nlp
        t_step = time.perf_counter()
        xs0 = z0 / nlp.x_scale
        self.set_x0(xs0)
        self.set_params(p)
        cold = self.prev is None
        if cold:
            X, a, U = nlp.unpack(self.c.guess(z0, p))
            Xs, Us = (X / nlp.x_scale[:, None]).T, (U / nlp.u_scale[:, None]).T
            self.set_iterate(Xs, Us, np.zeros((self.N, self.nx)), [np.zeros(n) for n in self.nlam])
        else:
            self.set_iterate(*self.shifted(xs0, p))
        t_solve, tot, status, qp_iter = 0.0, 0.0, 0, 0
        parts = dict.fromkeys(TIME_PARTS, 0.0)
        for _ in range(COLD_ITERATIONS if cold else 1):
            t0 = time.perf_counter()
            status = self.solver.solve()
            t_solve += time.perf_counter() - t0
            tot += float(np.asarray(self.solver.get_stats("time_tot")).ravel()[0])
            for k in parts:
                parts[k] += float(np.asarray(self.solver.get_stats(k)).ravel()[0])
            qp_iter += int(np.asarray(self.solver.get_stats("qp_iter")).ravel().sum())
        self.prev = self.get_iterate()
        U = self.prev[1].T * nlp.u_scale[:, None]
        return {
            "status": int(status),
            "a0": float(U[0, 0]),
            "U": U,
            "solve_s": t_solve,
            "time_tot_s": tot,
            "step_s": time.perf_counter() - t_step,
            "qp_iter": qp_iter,
            "parts_s": parts,
        }


def stats_ms(t_s: list[float] | np.ndarray) -> dict[str, float]:
    """median, p90, p99, max [ms] of per-step times [s]."""
    t = 1e3 * np.asarray(t_s, float)
    return {
        "median_ms": float(np.median(t)),
        "p90_ms": float(np.percentile(t, 90)),
        "p99_ms": float(np.percentile(t, 99)),
        "max_ms": float(t.max()),
    }


def warm_of(c: Any) -> tuple[np.ndarray, np.ndarray]:
    """(x, lam_g) of the controller's last solution (its warm start; the compiled step keeps it in C)."""
    if c.warm is not None and "lam_g" in c.warm:
        return c.warm["x"].copy(), c.warm["lam_g"].copy()
    x, lam_g, _, _ = c.compiled_step.solution()
    return x.copy(), lam_g.copy()


def aev_profile(rows: np.ndarray, N: int, hessian: str, flags: tuple[str, ...] | None = None) -> dict[str, Any]:
    """The compiled step's parts timed inside its C (the exported library built with -DAEV_MPC_PROFILE; by default
    with the compiled step's own flags, tuned), median ms per step over the recorded inputs (first, cold, step
    excluded)."""
    from bench_mpc import COMPILED, F9, S9

    from aev_ocp.compiled import exact_tuned_flags
    from aev_ocp.mpc.export import CStep, build_library, export_mpc

    if flags is None:
        flags = ("-O2", "-fno-math-errno", *exact_tuned_flags())
    from aev_ocp.mpc.settings import MPCSettings
    from aev_ocp.scenarios import find_scenario, load_scenario

    keys = ("t_shift", "t_qpdata", "t_project", "t_qp", "t_node0")
    got: dict[str, list[float]] = {k: [] for k in (*keys, "qp_iterations")}
    with tempfile.TemporaryDirectory() as tmp:
        settings = MPCSettings(N=N, **{**S9, "rti_hessian": hessian}, **COMPILED)
        export_mpc(load_scenario(find_scenario("mpc_paper_single")), Path(tmp), settings, F9)
        cs = CStep(build_library(Path(tmp), Path(tmp) / "lib.so", flags=(*flags, "-DAEV_MPC_PROFILE")))
        for row in rows:
            cs.step(row[:5], row[5:])
            info = cs.solution()[3]
            for k in got:
                got[k].append(float(getattr(info, k)))
    return {k: float(np.median(v[1:])) * (1.0 if k == "qp_iterations" else 1e3) for k, v in got.items()}


def replay_alone(rows: np.ndarray, aev: dict[str, Any], acs: dict[str, "AcadosMPC"], c: Any) -> dict[str, float]:
    """Median 'solve' [ms] of each solver replaying the recorded inputs once on its own, its steps back to back
    (first, cold, step excluded; acados seeded from aev_ocp's first solution as in the interleaved passes). Beside
    the interleaved passes, where the other eight solvers run between two steps of one: their code and data
    (several MB) push the step's (about 0.2 MB) out of the caches, so each interleaved step starts from main memory."""
    K, N = len(rows), aev["exact"].settings.N
    out: dict[str, float] = {}
    first: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # aev_ocp's first (cold) solution, acados's seed
    for h, ce in aev.items():
        ce.reset()
        t = []
        for i in range(K):
            t.append(ce.solve(rows[i, :5], rows[i, 5 : 5 + N], rows[i, 5 + N :]).solve_time_s)
            if i == 0:
                first[h] = warm_of(ce)
        out[f"aev_ocp {h}"] = 1e3 * float(np.median(t[1:]))
    for n, ac in acs.items():
        ac.prev, t = None, []
        for i in range(K):
            got = ac.step(rows[i, :5], c._params(np.vstack([rows[i, 5 : 5 + N], rows[i, 5 + N :]]), None, None))
            if i == 0:
                ac.seed(*first[hessian_of(ac.opts)])
            t.append(got["solve_s"])
        out[n] = 1e3 * float(np.median(t[1:]))
    return out


def run(N: int, t_end: float, passes: int, names: list[str], build_root: Path) -> dict[str, Any]:
    """Record the closed loop, then replay it through aev_ocp (projected and exact Hessian) and each acados
    configuration, step by step interleaved; acados is seeded with aev_ocp's first (cold) solution."""
    from bench_mpc import record_loop

    got = load_acados()
    assert got is not None
    at, where = got
    rows, applied, _ = record_loop(N, t_end)
    aev = {"projected": controller(N, "projected"), "exact": controller(N, "exact")}
    c = aev["projected"]  # (its parameter vector and horizon NLP: the same for both Hessians)
    acs = {n: AcadosMPC(at, c, n, ALL_CONFIGS[n], build_root / n) for n in names}
    K = len(rows)
    res: dict[str, dict[str, list[Any]]] = {}
    for h in aev:
        res[h] = {"solve": [], "step": [], "a0": [], "U": [], "ok": [], "qp_iter": [], "projected_retries": []}
    for n in names:
        res[n] = {"solve": [], "time_tot": [], "step": [], "a0": [], "U": [], "status": [], "qp_iter": [], "parts": []}
    load0, cpu0 = os.getloadavg(), time.process_time()
    for pas in range(passes):
        for ce in aev.values():
            ce.reset()
        for ac in acs.values():
            ac.prev = None
        for i in range(K):
            z0, vm, vh = rows[i, :5], rows[i, 5 : 5 + N], rows[i, 5 + N :]
            for h, ce in aev.items():
                t0 = time.perf_counter()
                sol = ce.solve(z0, vm, vh)
                t_call = time.perf_counter() - t0
                r = res[h]
                if i > 0:
                    info = ce.compiled_step.solution()[3]
                    r["solve"].append(sol.solve_time_s)
                    r["step"].append(t_call)
                    r["qp_iter"].append(info.qp_iterations)
                    r["projected_retries"].append(info.projected_retries)
                if pas == 0:
                    r["a0"].append(float(sol.a[0]))
                    r["U"].append(np.asarray(sol.U))
                    r["ok"].append(bool(sol.success))
            p = c._params(np.vstack([vm, vh]), None, None)
            for n, ac in acs.items():
                out = ac.step(z0, p)
                r = res[n]
                if i == 0:  # both warm steps start from the same primal-dual point
                    ac.seed(*warm_of(aev[hessian_of(ac.opts)]))
                else:
                    r["solve"].append(out["solve_s"])
                    r["time_tot"].append(out["time_tot_s"])
                    r["step"].append(out["step_s"])
                    r["qp_iter"].append(out["qp_iter"])
                    r["parts"].append(out["parts_s"])
                if pas == 0:
                    r["a0"].append(out["a0"])
                    r["U"].append(out["U"])
                    r["status"].append(out["status"])
    cpu, load1 = time.process_time() - cpu0, os.getloadavg()
    alone = replay_alone(rows, aev, acs, c)
    profile = {h: aev_profile(rows, N, h) for h in aev}
    out: dict[str, Any] = {
        "acados": where,
        "steps_per_pass": K,
        "passes": passes,
        "timed_steps": passes * (K - 1),
        "closed_loop_vs_replay_max_abs_da0_exact": float(np.abs(np.array(res["exact"]["a0"]) - applied).max()),
        "aev_ocp": {
            h: {
                "path": f"rti, qp_solver riccati (compiled C step, aev_ocp/c/ocp_qp.c), rti_hessian {h!r}",
                "solve": stats_ms(res[h]["solve"]),
                "step": stats_ms(res[h]["step"]),
                "failed_steps": int(np.sum(~np.array(res[h]["ok"]))),
                "qp_iter_median": float(np.median(res[h]["qp_iter"])),
                "qp_iter_max": int(np.max(res[h]["qp_iter"])),
                "steps_with_projected_retry": int(np.sum(np.array(res[h]["projected_retries"]) > 0)),
            }
            for h in aev
        },
        "aev_ocp_parts_median_ms": profile,
        "solve_median_ms_alone": alone,
        "acados_configs": {},
        "load_average_1_5_15_before": list(load0),
        "load_average_1_5_15_after": list(load1),
        "cpu_s": cpu,
    }
    for n, ac in acs.items():
        r, h = res[n], hessian_of(ac.opts)
        ref, a_ref, U_ref = out["aev_ocp"][h], np.array(res[h]["a0"]), np.array(res[h]["U"])
        st = np.array(r["status"][1:])
        da0 = np.abs(np.array(r["a0"]) - a_ref)[1:]
        dU = np.abs(np.array(r["U"]) - U_ref).reshape(K, -1).max(axis=1)[1:]
        solve, step = stats_ms(r["solve"]), stats_ms(r["step"])
        out["acados_configs"][n] = {
            "options": ac.opts,
            "compared_with": f"aev_ocp {h}",
            "build_s": ac.build_s,
            "solve": solve,
            "time_tot": stats_ms(r["time_tot"]),
            "step": step,
            "parts_median_ms": {k: 1e3 * float(np.median([q[k] for q in r["parts"]])) for k in TIME_PARTS},
            "qp_iter_median": float(np.median(r["qp_iter"])),
            "qp_iter_max": int(np.max(r["qp_iter"])),
            "nonzero_status_steps": int(np.sum(st != 0)),
            "max_abs_da0": float(da0.max()),
            "median_abs_da0": float(np.median(da0)),
            "max_abs_dU": float(dU.max()),
            "steps_compared": int(da0.size),
            "ratio_solve_median_aev_over_acados": ref["solve"]["median_ms"] / solve["median_ms"],
            "ratio_solve_p90_aev_over_acados": ref["solve"]["p90_ms"] / solve["p90_ms"],
            "ratio_step_median_aev_over_acados": ref["step"]["median_ms"] / step["median_ms"],
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, default=40)
    ap.add_argument("--t-end", type=float, default=70.0)
    ap.add_argument("--passes", type=int, default=2)
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(ALL_CONFIGS))
    ap.add_argument("--tol-da0", type=float, default=1e-4, help="agreement tolerance of the first control [model]")
    ap.add_argument("--build-dir", type=Path, default=None, help="acados's generated code (default: a temp folder)")
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("bench_mpc_acados.json"))
    a = ap.parse_args(argv)
    if load_acados() is None:
        print(
            "bench_mpc_acados: skipped: acados is not importable here (neither comma-deps-acados's 'acados' package "
            "nor an upstream 'acados_template'); see docs/guide/mpc.md, 'acados comparison', for the separate venv"
        )
        return 0
    from aev_ocp.results import write_json

    with tempfile.TemporaryDirectory() as tmp:
        res = run(a.N, a.t_end, a.passes, a.configs, a.build_dir or Path(tmp))
    print(
        f"\nMPC step, canonical §9 problem, N = {a.N}: {res['timed_steps']} timed steps "
        f"({res['passes']} passes of {res['steps_per_pass']}, first cold step of each excluded); {res['acados']}"
    )
    print(
        f"load average before {res['load_average_1_5_15_before'][0]:.2f}, after "
        f"{res['load_average_1_5_15_after'][0]:.2f} (1 min), {os.cpu_count()} CPUs"
    )
    hdr = f"{'solver':22s} {'solve med':>9s} {'p90':>7s} {'p99':>7s} {'tot med':>8s} {'step med':>9s} "
    hdr += f"{'QP it':>5s} {'max|da0|':>9s} {'max|dU|':>9s} {'ratio':>6s} {'ok':>3s}"
    print(hdr + "\n" + "-" * len(hdr))
    for h, ao in res["aev_ocp"].items():
        print(
            f"{'aev_ocp ' + h:22s} {ao['solve']['median_ms']:9.3f} {ao['solve']['p90_ms']:7.3f} "
            f"{ao['solve']['p99_ms']:7.3f} {'':>8s} {ao['step']['median_ms']:9.3f}"
        )
    for n, r in res["acados_configs"].items():
        r["agrees"] = bool(r["max_abs_da0"] <= a.tol_da0 and r["nonzero_status_steps"] == 0)
        print(
            f"{'acados ' + n:22s} {r['solve']['median_ms']:9.3f} {r['solve']['p90_ms']:7.3f} "
            f"{r['solve']['p99_ms']:7.3f} {r['time_tot']['median_ms']:8.3f} {r['step']['median_ms']:9.3f} "
            f"{r['qp_iter_median']:5.0f} {r['max_abs_da0']:9.2e} {r['max_abs_dU']:9.2e} "
            f"{r['ratio_solve_median_aev_over_acados']:6.2f} {'yes' if r['agrees'] else 'NO':>3s}"
        )
    for h, pr in res["aev_ocp_parts_median_ms"].items():
        print(
            f"aev_ocp {h} inside its C step (-DAEV_MPC_PROFILE, replayed alone), median ms: "
            + "  ".join(f"{k} {v:.3f}" for k, v in pr.items())
        )
    print("acados's own timers, median ms per step (CPU):")
    for n, r in res["acados_configs"].items():
        print(f"  {n:18s} " + "  ".join(f"{k[5:]} {v:.3f}" for k, v in r["parts_median_ms"].items()))
    res["vs_fastest_agreeing_acados"] = {}
    for h in res["aev_ocp"]:
        agreeing = {
            n: r for n, r in res["acados_configs"].items() if r["agrees"] and r["compared_with"] == f"aev_ocp {h}"
        }
        if not agreeing:
            continue
        best = min(agreeing, key=lambda n: agreeing[n]["solve"]["median_ms"])
        ratio = agreeing[best]["ratio_solve_median_aev_over_acados"]
        al = res["solve_median_ms_alone"]
        ratio_alone = al[f"aev_ocp {h}"] / al[best]
        res["vs_fastest_agreeing_acados"][h] = {
            "acados": best,
            "ratio_solve_median": ratio,
            "le_0.5": ratio <= 0.5,
            "ratio_solve_median_alone": ratio_alone,
        }
        print(
            f"aev_ocp {h} / fastest agreeing acados ({best}), median solve: {ratio:.2f} (issue 40 target ≤ 0.5: "
            f"{'met' if ratio <= 0.5 else 'not met'}); each replayed alone: {al[f'aev_ocp {h}']:.3f} / "
            f"{al[best]:.3f} ms = {ratio_alone:.2f}"
        )
    res.update(
        {
            "scenario": "mpc_paper_single (model guide §9 canonical), replayed inputs of the compiled-step closed loop",
            "N": a.N,
            "t_end": a.t_end,
            "tol_da0": a.tol_da0,
            "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count()},
        }
    )
    write_json(a.out, res)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

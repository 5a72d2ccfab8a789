"""The MPC step as self-contained C (the code generation and the ctypes binding; ``aev-ocp mpc-export`` is
:mod:`aev_ocp.mpc.export`): the real-time iteration of :class:`~aev_ocp.mpc.controller.MPCController`
(solver 'rti') as CasADi-generated functions plus two hand-written C files, so that nothing of Python or
CasADi is needed at run time.

Five CasADi Functions are built from the controller's (any) :class:`~aev_ocp.ocp.problem.OCPProblem` and
generated into ``mpc_casadi.c`` (:func:`rti_functions`):

* ``aev_cg_guess(z0, p) -> x``: the cold-start guess (the closed-form law rolled out, as
  :meth:`aev_ocp.mpc.nlp.HorizonNLP.guess`);
* ``aev_cg_shift(x, lam_g, lam_x, z0, p) -> (x, lam_g, lam_x)``: the warm start shifted by one interval
  (as :meth:`aev_ocp.mpc.nlp.HorizonNLP.shift`);
* ``aev_cg_qpdata(x, p, lam_g) -> (H, g, E, e, C, lc, uc, lbw, ubw)`` (:func:`qp_data_function`): the QP of
  one SQP step in stage blocks — the exact Lagrangian Hessian's stage blocks and the terminal cost's, the
  dynamics' Jacobians [A B] and defects, the path constraints' Jacobians and offsets, the step bounds;
* ``aev_cg_node0(x, p) -> (node-0 violation, u0)``: the applied control and its path constraints;
* ``aev_cg_eval(x, p) -> (f, violation)``: the plan's cost and constraint violation (evaluated only when
  asked for, by ``aev_mpc_get_info``).

The hand-written driver ``aev_ocp/c/mpc_step.c`` (header ``mpc_step.h``) runs them and solves each QP with
``aev_ocp/c/ocp_qp.c`` (``ocp_qp.h``): a primal-dual interior point (Mehrotra) whose Newton systems are
solved by a Riccati recursion over the stages, built with the problem's dimensions as compile-time
constants (:func:`qp_dimension_defines`). One SQP step: the QP data, each Hessian block projected onto
the positive-definite cone in C when ``rti_hessian = 'projected'`` (``aev_mpc_project_pd``: the same
floor as :func:`aev_ocp.mpc.nlp.project_pd`), the QP (a warm step's from the shifted multipliers:
``ocpqp_solve_warm``, 2-3 interior-point iterations instead of 6-10 from the cold start), a full step. A warm step shifts and does
``rti_iterations`` SQP steps; a cold step (the first, or after a failure) does ``rti_cold_iterations``
SQP steps from the guess (the traffic formulation, as the Python rti path), or, for §9 (whose Python path
starts with a cold IPOPT), Levenberg-Marquardt-regularised SQP until the step is below ``tol`` (at most
:data:`COLD_MAX_ITER` QPs). The Python rti path with qp_solver 'riccati' and codegen loads the same
library (:class:`CompiledStep`), so the Python controller and the exported C run the same code (with or
without codegen; the test suite keeps a Python twin of the driver, tests/rti_twin.py, as its oracle).

:func:`export_controller` writes the folder of ``aev-ocp mpc-export`` (:mod:`aev_ocp.mpc.export`): sources,
headers, generated config header, Makefile, CMakeLists.txt, a benchmark main and README.txt.

Why our own QP solver: CasADi generates C for only one QP solver, qrqp (an active set on a sparse QR of the
whole KKT matrix). qrqp took 70 % of the exported step (0.32 ms) and needs curvature in every control, so the
traffic formulation (its ω epigraph control enters the cost linearly) could not be exported. The interior
point takes linear-cost controls bounded through constraints, and its cost per iteration is linear in N. Its
limit: every QP must be convex (an indefinite exact Hessian block can stall it: use the default projected
Hessian). HPIPM's C API (the libhpipm.so of the casadi wheel) is the other backend of the same interface
ocp_qp.h (aev_ocp/c/ocp_qp_hpipm.c, :class:`aev_ocp.mpc.ocpqp.OcpQP` with backend 'hpipm'); on the 12 recorded
RTI QPs (benchmarks/bench_ocp_qp.py --only-harvested) it solves 6-7 in mode SPEED, 10 in BALANCE and 12 in
ROBUST, at a median 1.5-2.4 times ocp_qp.c's time, and it would make the export depend on HPIPM and BLASFEO:
the step keeps ocp_qp.c (12 of 12).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any, Protocol

import casadi as ca
import numpy as np

from ..params import ParameterError, remember
from .nlp import RTI_HESSIAN_FLOOR, HorizonNLP, rti_stage_functions


class ExportableController(Protocol):
    """What the C step is generated from: a built :class:`aev_ocp.mpc.controller.MPCController` (its horizon NLP,
    parameter layout, settings, problem and formulation); a Protocol, so this module does not import the
    controller (which imports it)."""

    settings: Any
    problem: Any
    formulation: Any
    ev: Any
    nlp: HorizonNLP
    layout: Any
    rti_cold_start: bool

    @property
    def nx(self) -> int: ...

    @property
    def nu(self) -> int: ...

    @property
    def nv(self) -> int: ...

    @property
    def ng(self) -> int: ...

    @property
    def np_(self) -> int: ...

    @property
    def x_scale(self) -> np.ndarray: ...

    @property
    def u_scale(self) -> np.ndarray: ...

    @property
    def F(self) -> ca.Function: ...

    @property
    def step(self) -> ca.Function: ...

    def constant_parameters(self) -> np.ndarray: ...


#: Hand-written templates (package data under aev_ocp/c/) copied or filled into an export.
TEMPLATES = ("mpc_step.c", "mpc_step.h", "ocp_qp.c", "ocp_qp.h", "mpc_bench_main.c")
#: The C files of an export compiled into the step's library (the others are headers, and mpc_bench_main.c, the
#: benchmark program's main).
LIBRARY_C = ("mpc_casadi.c", "mpc_step.c", "ocp_qp.c")
#: the library's source compiled into an object of its own, shared by the steps of the same QP dimensions
QP_C = "ocp_qp.c"
#: Files of an export folder.
EXPORT_FILES = (
    "mpc_casadi.c",
    "mpc_casadi.h",
    "mpc_config.h",
    "mpc_step.c",
    "mpc_step.h",
    "ocp_qp.c",
    "ocp_qp.h",
    "mpc_bench_main.c",
    "Makefile",
    "CMakeLists.txt",
    "README.txt",
)
#: The recorded input an export of a scenario writes beside the C (``aev-ocp mpc-export``; mpc_bench reads it).
RECORD_FILE = "mpc_input.txt"
#: At most this many SQP iterations from the cold-start guess (the first step, or after a failure).
COLD_MAX_ITER = 100
#: Cold start (Levenberg-Marquardt): the QP Hessian gets reg·I, reg = COLD_REG0 at first, divided by 10
#: whenever max|dx| < COLD_REG_STEP (0 once below 1e-6), multiplied by 10 and the step retried when the QP
#: fails (up to COLD_REG_MAX); full SQP steps. Used by the §9 problem's exact Hessian, which far from the
#: solution is indefinite (an interior-point QP needs convexity); with it the cold start of the canonical
#: scenario converges (max |dx| < 1e-14) in 19-24 SQP iterations (116-166 QP iterations in all) from three
#: different states.
COLD_REG0 = 0.1
COLD_REG_STEP = 1e-2
COLD_REG_MAX = 1e3
#: reg of the warm (RTI) steps: 0, the exact Hessian as in the Python rti path
RTI_REG = 0.0
#: Interior-point iterations per QP at most, and the QP's residual tolerances (ocp_qp.h; our choice: far
#: below the SQP tolerance, so the exported step and the Python paths agree to 1e-8 over a closed loop).
QP_MAX_ITER = 50
QP_TOL = 1e-9
#: Status codes of aev_mpc_step (mpc_step.h).
#: Status codes of the exported step, worded with the Python path's fallback causes ('QP failed', 'path
#: constraint', 'exception': the text before the first ':' is the cause counted in fallback_causes).
STATUS = {
    0: "RTI_Step",
    1: "QP failed: ocp_qp",
    2: "QP failed: non-finite step",
    3: "path constraint: the applied control violates them",
    4: "QP failed: the cold start did not converge",
    5: "exception: non-finite input",
}


class ExportError(ParameterError):
    """The MPC cannot be exported or built (names the cause)."""


def _template(name: str) -> str:
    return resources.files("aev_ocp").joinpath("c", name).read_text(encoding="utf-8")


# ---------------------------------------------------------------------------------------------- functions
def step_constants(c: ExportableController) -> np.ndarray:
    """The numbers the compiled step takes at run time after the NLP parameters (its generated C holds
    none of a vehicle's, a unit system's or a constraint's values, so one library serves every controller of the
    same structure): the simple bounds of a node (x_lb, x_ub scaled), of an interval (u_lb, u_ub scaled), the
    path constraints' bounds (lb, ub), then the cold-start guess's inputs (:attr:`HorizonNLP.rollout_inputs`:
    its bounds and the closed-form law's coefficients)."""
    nlp, nx, nu = c.nlp, c.nx, c.nu
    pr = c.problem
    return np.concatenate(
        [
            nlp.lbx[-nx:],
            nlp.ubx[-nx:],
            nlp.lbx[nx : nx + nu],
            nlp.ubx[nx : nx + nu],
            np.asarray(pr.path_lb, float),
            np.asarray(pr.path_ub, float),
            *nlp.rollout_inputs,
        ]
    )


def _bounds(c: ExportableController, B: Any) -> dict[str, Any]:
    """The bounds of the compiled step's functions: from the symbol B (layout of :func:`step_constants`), or the
    controller's numbers (B None)."""
    nx, nu, N, nc = c.nx, c.nu, c.settings.N, c.nlp.ng_stage - c.nx
    if B is None:
        B = ca.DM(step_constants(c))
    xl, xu, ul, uu = B[:nx], B[nx : 2 * nx], B[2 * nx : 2 * nx + nu], B[2 * nx + nu : 2 * (nx + nu)]
    k = 2 * (nx + nu)
    plb, pub = B[k : k + nc], B[k + nc : k + 2 * nc]
    k += 2 * nc
    nr = nx + nu
    return {
        "lbx": ca.vertcat(ca.repmat(ca.vertcat(xl, ul), N, 1), xl),
        "ubx": ca.vertcat(ca.repmat(ca.vertcat(xu, uu), N, 1), xu),
        "xl": xl,
        "xu": xu,
        "path_lb": plb,
        "path_ub": pub,
        "lbg": ca.repmat(ca.vertcat(ca.DM.zeros(nx), plb), N, 1),
        "ubg": ca.repmat(ca.vertcat(ca.DM.zeros(nx), pub), N, 1),
        "rollout": (B[k : k + nr], B[k + nr : k + 2 * nr], B[k + 2 * nr :]),
    }


def qp_data_function(c: ExportableController, constants_in_p: bool = False) -> ca.Function:
    """``aev_cg_qpdata(x, p, lam_g) -> (H, g, E, e, C, lc, uc, lbw, ubw)``: the QP of one SQP step at the
    primal-dual point (x, lam_g) of the controller's scaled NLP, in the stage layout of ``ocp_qp.h``
    (nc = the path constraints per interval, no terminal constraint, x_0's step fixed at 0): the exact
    Lagrangian Hessian's stage blocks (and the terminal cost's), the cost gradient, the dynamics'
    Jacobians [A B] and defects, the path constraints' Jacobians and bound offsets, the step bounds.
    ``constants_in_p``: p is the NLP parameters followed by :func:`step_constants` (the compiled step's), else
    the NLP parameters only (the bounds are the controller's numbers)."""
    s, pr = c.settings, c.problem
    N, nx, nu, ngs = s.N, pr.nx, pr.nu, c.nlp.ng_stage
    nb, nv, ng, npp = nx + nu, c.nv, c.ng, c.np_
    nk = step_constants(c).size if constants_in_p else 0
    stage, term = rti_stage_functions(c.nlp)  # the same stage QP as the Python rti path's
    V, P, LAM = ca.MX.sym("x", nv), ca.MX.sym("p", npp + nk), ca.MX.sym("lam_g", ng)
    bd = _bounds(c, P[npp:] if constants_in_p else None)
    Xk, Uk, Xn, W, PP, SW = c.nlp.stage_inputs(V, P[:npp])
    Hs, Qs, Js, Gs, _ = stage.map(N, "serial")(Xk, Uk, Xn, W, ca.repmat(PP, 1, N), SW, ca.reshape(LAM, ngs, N))
    HN, qN, _ = term(V[nb * N :], PP)
    path_lb = ca.repmat(bd["path_lb"], 1, N)
    path_ub = ca.repmat(bd["path_ub"], 1, N)
    cval = Gs[nx:, :]  # the path constraints' values at the point
    return ca.Function(
        "aev_cg_qpdata",
        [V, P, LAM],
        [
            ca.vertcat(ca.vec(Hs), ca.vec(HN)),
            ca.vertcat(ca.vec(Qs), qN),
            ca.vec(Js[:nx, :]),
            ca.vec(Gs[:nx, :]),
            ca.vec(Js[nx:, :]),
            ca.vec(path_lb - cval),
            ca.vec(path_ub - cval),
            bd["lbx"] - V,
            bd["ubx"] - V,
        ],
        ["x", "p", "lam_g"],
        ["H", "g", "E", "e", "C", "lc", "uc", "lbw", "ubw"],
    )


def rti_functions(c: ExportableController) -> list[ca.Function]:
    """The five CasADi Functions of the exported step (see the module docstring), from a built controller."""
    s, pr = c.settings, c.problem
    N, nx, nu, ngs = s.N, pr.nx, pr.nu, c.nlp.ng_stage
    nb, nv, ng, npp = nx + nu, c.nv, c.ng, c.np_
    xs, us = ca.DM(c.x_scale), ca.DM(c.u_scale)
    qpdata = qp_data_function(c, constants_in_p=True)
    # p: the NLP parameters, then the step's constants (step_constants: bounds, the guess law's coefficients)
    V, P = ca.MX.sym("x", nv), ca.MX.sym("p", npp + step_constants(c).size)
    bd = _bounds(c, P[npp:])
    LAM, LAMX = ca.MX.sym("lam_g", ng), ca.MX.sym("lam_x", nv)
    W, PP = c.nlp.stage_inputs(V, P[:npp])[3:5]
    # --- plan evaluation: cost, nonlinear violation, node-0 path violation, applied controls
    f_nlp = ca.Function("f", [c.nlp.nlp["x"], c.nlp.nlp["p"]], [c.nlp.nlp["f"], c.nlp.nlp["g"]])
    f, gg = f_nlp(V, P[:npp])
    lbx = ca.vertcat(V[:nx], bd["lbx"][nx:])  # the initial state is fixed at x[:nx]
    ubx = ca.vertcat(V[:nx], bd["ubx"][nx:])
    vg = ca.fmax(ca.fmax(bd["lbg"] - gg, gg - bd["ubg"]), 0)
    vx = ca.fmax(ca.fmax(lbx - V, V - ubx), 0)
    viol = ca.mmax(ca.vertcat(vg, vx, ca.DM(0)))
    path0 = c.F(V[:nx], V[nx:nb], ca.MX(0, 1), ca.MX.zeros(nx), W[:, 0], PP, s.dt)[1]
    lb0, ub0 = bd["path_lb"], bd["path_ub"]
    viol0 = ca.mmax(ca.vertcat(ca.fmax(ca.fmax(lb0 - path0, path0 - ub0), 0), ca.DM(0)))
    ev = ca.Function("aev_cg_eval", [V, P], [f, viol], ["x", "p"], ["f", "violation"])
    # expanded (SX): only the path constraints' operations of the interval function remain, not its RK4 step (8 of
    # 32 kB of machine code, which a step whose code is not in cache fetches from memory; issue 40)
    node0 = ca.Function("aev_cg_node0", [V, P], [viol0, V[nx:nb] * us], ["x", "p"], ["node0_violation", "u0"]).expand()
    # --- cold-start guess (HorizonNLP.guess) and shift (HorizonNLP.shift)
    Z0 = ca.MX.sym("z0", nx)
    Wm, pm = ca.reshape(P[: pr.nw * N], pr.nw, N), P[pr.nw * N : pr.nw * N + pr.np_]
    Zn, Ug = c.nlp.rollout(Z0, Wm, ca.repmat(pm, 1, N), *(ca.repmat(v, 1, N) for v in bd["rollout"]))
    Z = ca.horzcat(Z0, Zn) / ca.repmat(xs, 1, N + 1)
    Ug = ca.reshape(Ug, nu, N) / ca.repmat(us, 1, N)
    guess = ca.Function(
        "aev_cg_guess", [Z0, P], [ca.vertcat(ca.vec(ca.vertcat(Z[:, :N], Ug)), Z[:, N])], ["z0", "p"], ["x"]
    )
    zN, uN = V[nb * N :] * xs, V[nb * N - nu : nb * N] * us
    z_ext = c.step(zN, uN, Wm[:, N - 1], pm) / xs
    z_ext = ca.fmin(ca.fmax(z_ext, bd["xl"]), bd["xu"])

    def shift_v(v: Any, new_last: Any) -> Any:
        # blocks 1..N-1, then (z_N, u_{N-1}), then new_last; the first nx entries are replaced later
        return ca.vertcat(v[nb : nb * N], v[nb * N :], v[nb * N - nu : nb * N], new_last)

    x0 = shift_v(V, z_ext)
    x0 = ca.vertcat(Z0 / xs, x0[nx:])
    lam_g0 = ca.vertcat(LAM[ngs : N * ngs], LAM[(N - 1) * ngs : N * ngs], LAM[N * ngs :])
    shift = ca.Function(
        "aev_cg_shift",
        [V, LAM, LAMX, Z0, P],
        [x0, lam_g0, shift_v(LAMX, LAMX[nb * N :])],
        ["x", "lam_g", "lam_x", "z0", "p"],
        ["x0", "lam_g0", "lam_x0"],
    )
    return [guess, shift, qpdata, node0, ev]


def generate_casadi(c: ExportableController, folder: Path, functions: list[ca.Function] | None = None) -> None:
    """Write mpc_casadi.c and mpc_casadi.h (the five functions, CasADi's generated C; ``functions``: the controller's
    :func:`rti_functions`, if built already)."""
    cg = ca.CodeGenerator("mpc_casadi.c", {"with_header": True})
    for f in rti_functions(c) if functions is None else functions:
        cg.add(f)
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        cg.generate()
    finally:
        os.chdir(cwd)


def _c_array(values: np.ndarray) -> str:
    v = np.asarray(values, float).ravel()
    if v.size == 0:
        return "{0.0}"
    return (
        "{"
        + ", ".join(
            repr(float(x)) if np.isfinite(x) else "NAN" if np.isnan(x) else ("INFINITY" if x > 0 else "-INFINITY")
            for x in v
        )
        + "}"
    )


#: SI units of the MPC problems' states and controls by name: (unit, dimension of the model value: 'length',
#: 'speed', 'accel', 'power' (v·a, W/kg), or '' for a value that is SI already); a name not listed keeps the
#: problem's own unit (factor 1)
SI_UNITS: dict[str, tuple[str, str]] = {
    "h": ("m", "length"),
    "v": ("m/s", "speed"),
    "V1": ("V", ""),
    "V2": ("V", ""),
    "S": ("-", ""),
    "T": ("K", ""),
    "a_prev": ("m/s^2", "accel"),
    "a_act": ("m/s^2", "accel"),
    "a": ("m/s^2", "accel"),
    "slack_gap": ("m", "length"),
    "slack_margin": ("m", "length"),
    "slack_T": ("K", ""),
}


def si_factors(c: ExportableController) -> tuple[np.ndarray, np.ndarray, list[str], list[str]]:
    """(x_si (nx,), u_si (nu,), state units, control units): SI value = model value × factor for every state and
    control of the controller's problem (:data:`SI_UNITS`; the traffic formulation's omega_rate is in W/kg
    already, §9's in model units (v·a: U³/L W/kg); a name not known keeps the problem's unit, factor 1)."""
    u = c.ev.units
    dim = {"length": u.length_m, "speed": u.speed_mps, "accel": u.accel_mps2, "power": u.speed_mps * u.accel_mps2}
    known = dict(SI_UNITS)
    known["omega_rate"] = ("W/kg", "" if c.formulation.family == "traffic" else "power")

    def one(names: Any) -> tuple[np.ndarray, list[str]]:
        f = [float(dim[known[n][1]]) if n in known and known[n][1] else 1.0 for n in names]
        return np.array(f), [known[n][0] if n in known else "problem unit" for n in names]

    xs, xu = one(c.problem.state_names)
    us, uu = one(c.problem.control_names)
    return xs, us, xu, uu


def config_header(c: ExportableController, description: str, values: bool = True) -> str:
    """mpc_config.h: dimensions and constants of the exported problem (filled template). ``values`` False: the
    problem's numbers (parameters, constant stage parameters, own states' initial values, step constants) are NaN
    placeholders, replaced at run time by ``aev_mpc_set_constants`` (the cached library of :class:`CompiledStep`:
    one library for every controller of the same structure)."""
    from ..models.ego import STATE_NAMES

    s, pr = c.settings, c.problem
    NZ = len(STATE_NAMES)  # the measured states at the front of every MPC problem

    def num(v: np.ndarray) -> str:
        v = np.asarray(v, float)
        return _c_array(v if values else np.full(v.size, np.nan))

    x_si, u_si, x_units, u_units = si_factors(c)

    subs = {
        "DESCRIPTION": description.replace("*/", "* /"),
        "N": s.N,
        "NX": pr.nx,
        "NU": pr.nu,
        "NZ": NZ,
        "NW": pr.nw,
        "NW_EXTRA": pr.nw - 2,
        "NPP": pr.np_,
        "NV": c.nv,
        "NG": c.ng,
        "NP": c.np_,
        "NG_STAGE": c.nlp.ng_stage,
        "RTI_ITER": s.rti_iterations,
        "COLD_MAX_ITER": COLD_MAX_ITER,
        "COLD_REG0": repr(COLD_REG0),
        "RTI_REG": repr(RTI_REG),
        "COLD_REG_MAX": repr(COLD_REG_MAX),
        "COLD_REG_STEP": repr(COLD_REG_STEP),
        "COLD_ITER": s.rti_cold_iterations if c.rti_cold_start else 0,
        "PROJECT": int(s.rti_hessian == "projected"),
        "HESS_FLOOR": repr(RTI_HESSIAN_FLOOR),
        "PD_MAXN": max(pr.nx + pr.nu, 1),
        "QP_MAX_ITER": QP_MAX_ITER,
        "QP_TOL": repr(QP_TOL),
        "TOL": repr(float(s.tol)),
        "PLAN_TOL": repr(float(_plan_tolerance())),
        "DT": repr(float(s.dt)),
        "DT_S": repr(float(s.dt * c.ev.units.time_s)) if values else "NAN",
        "UNITS": units_text(c) if values else "set at run time",
        "X_SI": num(x_si),
        "U_SI": num(u_si),
        "STATE_SI": ", ".join(f"{n} [{un}]" for n, un in zip(pr.state_names, x_units)),
        "CONTROL_SI": ", ".join(f"{n} [{un}]" for n, un in zip(pr.control_names, u_units)),
        "X_SCALE": _c_array(c.x_scale),
        "U_SCALE": _c_array(c.u_scale),
        "OWN0": num(c.layout.x_own0),
        "W_EXTRA": num(c.layout.w_extra),
        "P_CONST": num(c.constant_parameters()),
        "NK": step_constants(c).size,
        "K_CONST": num(step_constants(c)),
        "STATE_NAMES": ", ".join(pr.state_names),
        "CONTROL_NAMES": ", ".join(pr.control_names),
    }
    text = _template("mpc_config_template.h")
    for k, v in subs.items():
        text = text.replace(f"@{k}@", str(v))
    return text


def units_text(c: ExportableController) -> str:
    """The model units of the controller's vehicle in words (length, speed, time)."""
    u = c.ev.units
    return f"length {u.length_m:g} m, speed {u.speed_mps:g} m/s, time {u.time_s:g} s"


def _plan_tolerance() -> float:
    from ..plant import PLAN_TOLERANCE

    return float(PLAN_TOLERANCE)


def step_sources(c: ExportableController, description: str, values: bool = True) -> dict[str, str]:
    """The step's C sources by file name: CasADi's generated mpc_casadi.c and .h (:func:`generated_casadi`),
    mpc_config.h (:func:`config_header`; ``values``: see there) and the hand-written :data:`TEMPLATES`. What an
    export writes (:func:`write_sources`) and what :class:`CompiledStep` compiles (:data:`LIBRARY_C` and the
    headers)."""
    main, header = generated_casadi(c)
    return {
        "mpc_casadi.c": main,
        "mpc_casadi.h": header,
        "mpc_config.h": config_header(c, description, values),
        **{name: _template(name) for name in TEMPLATES},
    }


def write_sources(c: ExportableController, folder: Path, description: str, values: bool = True) -> None:
    """:func:`step_sources` into ``folder`` (created)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in step_sources(c, description, values).items():
        (folder / name).write_text(text, encoding="utf-8")


#: CasADi's generated C of the step (:class:`CompiledStep`, an export) in this process: a hash of the five functions
#: (serialized: every operation, constant and name the generated C is written from) and of CasADi's version ->
#: (mpc_casadi.c, mpc_casadi.h). Controllers of the same structure (one library for them all, issue 40) generate it
#: once.
_GENERATED: dict[str, tuple[str, str]] = {}
#: the :data:`_GENERATED` key of a horizon NLP in this process, by its id (each entry holds the NLP, so the id names
#: it while the entry lives): the five functions are built from the controller's NLP alone (its problem, settings,
#: bounds, scaling, rollout), so controllers sharing one (:func:`aev_ocp.mpc.nlp.shared_horizon_nlp`) skip building
#: and serializing them again (~50 ms of a default controller's build)
_DIGESTS: dict[int, tuple[Any, str]] = {}
DIGESTS_KEPT = 16


def generated_casadi(c: ExportableController) -> tuple[str, str]:
    """(mpc_casadi.c, mpc_casadi.h) of the controller's five functions: :func:`generate_casadi`'s files, generated
    once per process for the same functions (:data:`_GENERATED`; the same horizon NLP: :data:`_DIGESTS`)."""
    hit = _DIGESTS.get(id(c.nlp))
    if hit is not None and hit[0] is c.nlp and hit[1] in _GENERATED:
        return _GENERATED[hit[1]]
    functions = rti_functions(c)
    key = hashlib.sha256(str(ca.CasadiMeta.version()).encode())
    for f in functions:
        key.update(b"\0" + f.serialize().encode())
    digest = key.hexdigest()
    if digest not in _GENERATED:
        with tempfile.TemporaryDirectory() as tmp:
            generate_casadi(c, Path(tmp), functions)
            _GENERATED[digest] = tuple(  # type: ignore[assignment]
                Path(tmp, n).read_text(encoding="utf-8") for n in ("mpc_casadi.c", "mpc_casadi.h")
            )
    remember(_DIGESTS, id(c.nlp), (c.nlp, digest), DIGESTS_KEPT)
    return _GENERATED[digest]


# ---------------------------------------------------------------------------------------------- export
def qp_dimension_defines(c: ExportableController) -> tuple[str, ...]:
    """The macros that specialise ocp_qp.c to the controller's QP (OCPQP_NX, _NU, _NC, _NCN; ocp_qp.h)."""
    return (f"OCPQP_NX={c.nx}", f"OCPQP_NU={c.nu}", f"OCPQP_NC={c.nlp.ng_stage - c.nx}", "OCPQP_NCN=0")


def check_exportable(c: ExportableController) -> None:
    """ExportError (naming the cause) for what the exported step does not implement: terminal constraints
    (as the Python rti path; a terminal cost is fine)."""
    if c.problem.terminal is not None:
        raise ExportError(
            f"problem {c.problem.name!r} has terminal constraints, which the exported step (like the "
            "Python 'rti' path) does not implement: make them a soft terminal cost"
        )


def export_controller(c: ExportableController, out: Path, description: str) -> list[Path]:
    """Write the export folder of a built controller; returns the files written."""
    check_exportable(c)
    out = Path(out)
    write_sources(c, out, description)
    defs = qp_dimension_defines(c)
    (out / "Makefile").write_text(
        _template("mpc_Makefile.in").replace("@QPDIMS@", " ".join(f"-D{d}" for d in defs)), encoding="utf-8"
    )
    (out / "CMakeLists.txt").write_text(
        _template("mpc_CMakeLists.txt.in").replace("@QPDIMS_CMAKE@", ";".join(defs)), encoding="utf-8"
    )
    s, pr = c.settings, c.problem
    readme = _template("mpc_README.txt.in")
    subs = {
        "DESCRIPTION": description,
        "N": s.N,
        "DT": f"{s.dt:g}",
        "NX": pr.nx,
        "NU": pr.nu,
        "STATES": ", ".join(pr.state_names),
        "CONTROLS": ", ".join(pr.control_names),
        "NV": c.nv,
        "NG": c.ng,
        "UNITS": units_text(c),
        "DT_S": f"{s.dt * c.ev.units.time_s:.6g}",
        "STATE_SI": ", ".join(f"{n} [{un}]" for n, un in zip(pr.state_names, si_factors(c)[2])),
        "CONTROL_SI": ", ".join(f"{n} [{un}]" for n, un in zip(pr.control_names, si_factors(c)[3])),
        "NZ2N": 5 + 2 * s.N,
        "RECORD": RECORD_FILE,
    }
    for k, v in subs.items():
        readme = readme.replace(f"@{k}@", str(v))
    (out / "README.txt").write_text(readme, encoding="utf-8")
    return [out / f for f in EXPORT_FILES]


# ---------------------------------------------------------------------------------------------- building
def _config_qp_defines(src: Path) -> list[str]:
    """-DOCPQP_* flags (qp_dimension_defines) from an export folder's mpc_config.h."""
    import re

    text = (src / "mpc_config.h").read_text(encoding="utf-8")
    val = {k: int(v) for k, v in re.findall(r"#define AEV_MPC_(NX|NU|NG_STAGE) (\d+)", text)}
    if len(val) != 3:
        raise ExportError(f"{src / 'mpc_config.h'} does not define AEV_MPC_NX, AEV_MPC_NU and AEV_MPC_NG_STAGE")
    return [
        f"-DOCPQP_NX={val['NX']}",
        f"-DOCPQP_NU={val['NU']}",
        f"-DOCPQP_NC={val['NG_STAGE'] - val['NX']}",
        "-DOCPQP_NCN=0",
    ]


def build_library(src: Path, out_lib: Path, cc: str | None = None, flags: tuple[str, ...] = ("-O2",)) -> Path:
    """Compile the export folder's C sources into a shared library (ExportError naming the cause)."""
    from ..compiled import compiler, run_tool

    cc = cc or compiler()
    if cc is None:
        raise ExportError("no C compiler found (set $CC or install gcc/cc) to build the exported MPC")
    cmd = [
        cc,
        *flags,
        *_config_qp_defines(Path(src)),
        "-fPIC",
        "-shared",
        "-o",
        str(out_lib),
        *LIBRARY_C,
        "-lm",
    ]
    try:
        proc = run_tool(cmd, src, 900.0)
    except subprocess.TimeoutExpired:
        raise ExportError("building the exported MPC took more than 900 s; stopped") from None
    if proc.returncode != 0:
        last = (proc.stderr or proc.stdout).strip().splitlines()
        raise ExportError(f"building the exported MPC failed: {last[-1] if last else proc.returncode}")
    return out_lib


class Info(ctypes.Structure):
    """aev_mpc_info of mpc_step.h."""

    _fields_ = [
        ("iterations", ctypes.c_int),
        ("qp_iterations", ctypes.c_int),
        ("qp_status", ctypes.c_int),
        ("projected_retries", ctypes.c_int),
        ("cold", ctypes.c_int),
        ("qp_acceptable", ctypes.c_int),
        ("step_inf", ctypes.c_double),
        ("qp_residual", ctypes.c_double),
        ("cost", ctypes.c_double),
        ("violation", ctypes.c_double),
        ("node0_violation", ctypes.c_double),
        ("t_shift", ctypes.c_double),
        ("t_qpdata", ctypes.c_double),
        ("t_project", ctypes.c_double),
        ("t_qp", ctypes.c_double),
        ("t_node0", ctypes.c_double),
    ]


_VP = ctypes.c_void_p


def _addr(a: np.ndarray) -> int:
    """Address of a C-contiguous float64 array (cheaper than ``ctypes.data_as``; keep ``a`` alive)."""
    return a.ctypes.data


class CStep:
    """ctypes binding of an exported (or cached) MPC step library: one workspace, allocated once; the
    library's own output buffers are addressed once (no per-step allocation besides the returned copies)."""

    def __init__(self, lib_path: str | Path) -> None:
        self.lib = lib = ctypes.CDLL(str(lib_path))
        lib.aev_mpc_create.restype = _VP
        for name, n in (
            ("aev_mpc_free", 1),
            ("aev_mpc_reset", 1),
            ("aev_mpc_set_warm", 4),
            ("aev_mpc_get_solution", 4),
            ("aev_mpc_get_info", 2),
            ("aev_mpc_dims", 1),
        ):
            getattr(lib, name).argtypes = [_VP] * n
            getattr(lib, name).restype = None
        for name in ("aev_mpc_step", "aev_mpc_step_full"):
            getattr(lib, name).argtypes = [_VP] * 5
            getattr(lib, name).restype = ctypes.c_int
        lib.aev_mpc_step_own.argtypes = [_VP] * 6
        lib.aev_mpc_step_own.restype = ctypes.c_int
        lib.aev_mpc_set_constants.argtypes = [_VP] * 5
        lib.aev_mpc_set_constants.restype = None
        lib.aev_mpc_set_si.argtypes = [_VP] * 3
        lib.aev_mpc_set_si.restype = None
        dims = np.zeros(8, dtype=np.intc)
        lib.aev_mpc_dims(dims.ctypes.data)
        self.N, self.nx, self.nu, self.nz, self.nv, self.ng, self.np_, self.nf = (int(d) for d in dims)
        self.ws = lib.aev_mpc_create()
        if not self.ws:
            raise MemoryError("aev_mpc_create: out of memory")
        self._u = np.zeros(self.nu)
        self._status = np.zeros(1, dtype=np.intc)
        self._info = Info()
        self.x, self.lam_g, self.lam_x = np.zeros(self.nv), np.zeros(self.ng), np.zeros(self.nv)
        self._a = {
            k: _addr(v)
            for k, v in (
                ("u", self._u),
                ("status", self._status),
                ("x", self.x),
                ("lam_g", self.lam_g),
                ("lam_x", self.lam_x),
            )
        }
        self._a["info"] = ctypes.addressof(self._info)

    def __del__(self) -> None:
        ws, self.ws = getattr(self, "ws", None), None
        if ws:
            self.lib.aev_mpc_free(ws)

    def reset(self) -> None:
        """Forget the warm start (next step is a cold start)."""
        self.lib.aev_mpc_reset(self.ws)

    def step(self, x_meas: np.ndarray, forecast: np.ndarray, own: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """(u0 (nu,) [SI], status) from the measured (h [m], v [m/s], V1 [V], V2 [V], S [-]) and forecast
        (v̄_l (N), v̂_l (N) [m/s]); ``own``: the controller's own states in SI (nx − 5 values, e.g. a_prev
        [m/s²]), else the previous plan's (aev_mpc_step_own). SI in and out (:func:`si_factors`)."""
        xm = np.ascontiguousarray(x_meas, float)
        fc = np.ascontiguousarray(forecast, float)
        if xm.size != self.nz or fc.size != self.nf:
            raise ParameterError(f"CStep.step: x_meas must have {self.nz} and forecast {self.nf} values")
        a = self._a
        if own is None:
            self.lib.aev_mpc_step(self.ws, _addr(xm), _addr(fc), a["u"], a["status"])
        else:
            ow = np.ascontiguousarray(own, float)
            if ow.size != self.nx - self.nz:
                raise ParameterError(f"CStep.step: own must have {self.nx - self.nz} values (the own states)")
            self.lib.aev_mpc_step_own(
                self.ws, _addr(xm), _addr(ow) if ow.size else None, _addr(fc), a["u"], a["status"]
            )
        return self._u.copy(), int(self._status[0])

    def step_full(self, z0: np.ndarray, p: np.ndarray) -> int:
        """Status of a step from the full initial state (nx) and the NLP parameter vector (np)."""
        z = np.ascontiguousarray(z0, float)
        pp = np.ascontiguousarray(p, float)
        if z.size != self.nx or pp.size != self.np_:
            raise ParameterError(f"CStep.step_full: z0 must have {self.nx} and p {self.np_} values")
        return int(self.lib.aev_mpc_step_full(self.ws, _addr(z), _addr(pp), self._a["u"], self._a["status"]))

    def set_constants(self, p_const: np.ndarray, w_extra: np.ndarray, own0: np.ndarray, k_const: np.ndarray) -> None:
        """Give the workspace the controller's numbers (``aev_mpc_set_constants``; sizes are the caller's: a
        library built with placeholders, :class:`CompiledStep`, gets them here)."""
        keep = [np.ascontiguousarray(v, float) for v in (p_const, w_extra, own0, k_const)]
        self._constants = keep  # alive while the library may read them (it copies them)
        self.lib.aev_mpc_set_constants(self.ws, *(_addr(v) if v.size else None for v in keep))

    def set_si(self, x_si: np.ndarray, u_si: np.ndarray) -> None:
        """The SI factors of the states and controls (``aev_mpc_set_si``: SI = model × factor)."""
        keep = [np.ascontiguousarray(v, float) for v in (x_si, u_si)]
        if keep[0].size != self.nx or keep[1].size != self.nu:
            raise ParameterError(f"CStep.set_si: x_si must have {self.nx} and u_si {self.nu} values")
        self._si = keep
        self.lib.aev_mpc_set_si(self.ws, _addr(keep[0]), _addr(keep[1]))

    def set_warm(self, x: np.ndarray, lam_g: np.ndarray, lam_x: np.ndarray, drop_below: float = 0.0) -> None:
        """Start the next step from this primal-dual point (scaled NLP vector and multipliers).
        ``drop_below``: multipliers of smaller magnitude are set to 0 (they enter the next step's Lagrangian
        Hessian; default: kept as given)."""
        a, b, d = (np.array(v, float) for v in (x, lam_g, lam_x))
        if a.size != self.nv or b.size != self.ng or d.size != self.nv:
            raise ParameterError(f"CStep.set_warm: x, lam_g, lam_x must have {self.nv}, {self.ng}, {self.nv} values")
        if drop_below > 0:
            b[np.abs(b) < drop_below] = 0.0
            d[np.abs(d) < drop_below] = 0.0
        self.lib.aev_mpc_set_warm(self.ws, _addr(a), _addr(b), _addr(d))

    def solution(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, Info]:
        """(x, lam_g, lam_x, info) of the last step (arrays reused: copy to keep)."""
        a = self._a
        self.lib.aev_mpc_get_solution(self.ws, a["x"], a["lam_g"], a["lam_x"])
        self.lib.aev_mpc_get_info(self.ws, a["info"])  # evaluates the plan's cost
        return self.x, self.lam_g, self.lam_x, self._info


class CompiledStep:
    """The exported step's library built into the private cache (:func:`aev_ocp.compiled.compile_shared`,
    keyed by a hash of the sources) for the Python rti path (qp_solver 'riccati', codegen)."""

    @staticmethod
    def build(c: ExportableController) -> "CStep | None":
        """A :class:`CStep` on the cached library, or None (with a warning) when it cannot be built."""
        import warnings

        from ..compiled import compiler, fastest_builds

        if compiler() is None:
            warnings.warn(
                "MPC codegen requested but no C compiler (gcc) was found: the rti step runs on "
                "interpreted CasADi functions instead of the compiled step",
                RuntimeWarning,
                stacklevel=4,
            )
            return None
        # an export's sources without the problem's numbers (values=False: set below), so one library serves every
        # controller of the structure; the generated C is generated once per process (issue 40: a controller's
        # build regenerated it only to find the cached library). mpc_casadi.c is the main source, the library's
        # other C files and the headers its companions, the benchmark's main is left out.
        src = step_sources(c, f"MPC controller {c.problem.name}", values=False)
        main = src.pop(LIBRARY_C[0])
        files = {n: t for n, t in src.items() if n in LIBRARY_C or n.endswith(".h")}
        # the hand-written QP solver depends on its header, the QP's dimensions and the flags only: one object per
        # dimensions, linked into every step that has them (issue 40: 4 of a step's 10 s of gcc)
        qp = {QP_C.removesuffix(".c"): (files.pop(QP_C), {"ocp_qp.h": files["ocp_qp.h"]})}
        defines = tuple(f"-D{d}" for d in qp_dimension_defines(c))
        # tuned first (-O3, the native CPU, contraction off: the same bits as the plain build, about 0.85x the
        # step's time; tests/test_compiled_speed.py), else plain
        for built in fastest_builds(main, "mpc_step", "mpc", extra_flags=defines, companions=files, objects=qp):
            if built.path is not None:
                break
        if built.path is None:
            warnings.warn(
                f"MPC codegen failed ({built.error}): the rti step runs on interpreted CasADi functions "
                "instead of the compiled step",
                RuntimeWarning,
                stacklevel=4,
            )
            return None
        cs = CStep(built.path)
        cs.set_constants(c.constant_parameters(), c.layout.w_extra, c.layout.x_own0, step_constants(c))
        cs.set_si(*si_factors(c)[:2])
        return cs

"""Checks that every OCP result carries: the smoothing gap, grid refinement, multi-start.

* :func:`record_smoothing_gap`: the objective as the NLP saw it (smoothed η switch / smoothed g,
  the transcription's integrator) next to the same objective re-evaluated on the EXACT model along
  the applied piecewise-constant controls. When they differ by more than a tolerance the result
  carries a warning with both numbers: an optimiser that exploits its own smoothing shows up here.
* :func:`resimulate_cell_current`: the exact re-simulation for the cell-level problems (OCP-A,
  OCP-B), CVODES interval by interval with that interval's current.
* :func:`record_refinement`: how the objective changes when N is doubled.
* :func:`multistart`: several initial guesses, keep the best, report the spread.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from ..models import battery
from ..numerics import integrate_held
from ..params import CellParams, ParameterError
from ..ocp_result import OCPResult

# Relative tolerance of the smoothing-gap warning: 0.5 %, the agreement issue 13 asks of the
# eco-trip's NLP objective and its exact re-simulation. The shipped problems stay well inside it
# (largest: OCP-C heat, 0.04 %); the smoothed-g ω objective the issue found was 3.8 % off.
GAP_RTOL = 5e-3


def record_term_gap(
    res: OCPResult, term: str, nlp: float, exact: float, what: str, rtol: float = GAP_RTOL, atol: float = 0.0
) -> dict[str, Any]:
    """The smoothing gap of ONE smoothed term of the objective (e.g. OCP-D's w_Q term, heat or ω, the only one
    the smoothing touches): a large gap there can hide in a total dominated by exact terms. Same rule
    and warning as :func:`record_smoothing_gap`; stored in ``res.meta['smoothing_gap_terms'][term]``."""
    if not (math.isfinite(rtol) and rtol >= 0 and math.isfinite(atol) and atol >= 0):
        raise ParameterError(f"smoothing-gap tolerance: rtol = {rtol!r}, atol = {atol!r} must be finite and >= 0")
    nlp, exact = float(nlp), float(exact)
    diff = nlp - exact
    scale = max(abs(nlp), abs(exact))
    fired = not math.isfinite(diff) or abs(diff) > rtol * scale + atol
    rec: dict[str, Any] = {
        "nlp": nlp,
        "exact": exact,
        "difference": diff,
        "relative": abs(diff) / scale if scale > 0 else 0.0,
        "rtol": rtol,
        "atol": atol,
        "exact_model": what,
        "warning": bool(fired),
    }
    res.meta.setdefault("smoothing_gap_terms", {})[term] = rec
    if fired:
        res.warnings.append(
            f"smoothing gap in the {term} term: {nlp:.6g} in the NLP, {exact:.6g} re-evaluated ({what}), "
            f"{100 * rec['relative']:.3g} % apart (tolerance {100 * rtol:.3g} %); the optimiser may exploit its smoothing"
        )
    return rec


def record_smoothing_gap(
    res: OCPResult, exact: float, what: str, rtol: float = GAP_RTOL, atol: float = 0.0
) -> dict[str, Any]:
    """Store the exact re-evaluation ``exact`` of ``res.objective`` (same units) and warn on a gap.

    The gap counts when |NLP − exact| > rtol·max(|NLP|, |exact|) + atol (atol in the objective's unit,
    for objectives that are 0 at the optimum). ``what`` names the exact model (e.g. 'exact η switch,
    CVODES'). Returns the record also stored in ``res.meta['smoothing_gap']``.
    """
    if not (math.isfinite(rtol) and rtol >= 0 and math.isfinite(atol) and atol >= 0):
        raise ParameterError(f"smoothing-gap tolerance: rtol = {rtol!r}, atol = {atol!r} must be finite and >= 0")
    nlp = float(res.objective)
    exact = float(exact)
    diff = nlp - exact
    scale = max(abs(nlp), abs(exact))
    rel = abs(diff) / scale if scale > 0 else 0.0
    fired = not math.isfinite(diff) or abs(diff) > rtol * scale + atol
    rec = {
        "objective_nlp": nlp,
        "objective_exact": exact,
        "difference": diff,
        "relative": rel,
        "rtol": rtol,
        "atol": atol,
        "exact_model": what,
        "warning": bool(fired),
    }
    res.objective_exact = exact
    res.meta["smoothing_gap"] = rec
    if fired:
        res.warnings.append(
            f"smoothing gap: the NLP objective {nlp:.6g} and its exact re-evaluation {exact:.6g} ({what}) "
            f"differ by {100 * rel:.3g} % (tolerance {100 * rtol:.3g} %); the optimiser may exploit its "
            f"smoothing — {res.objective_name}"
        )
    return rec


def resimulate_cell_current(
    cell: CellParams, t_s: np.ndarray, I_A: np.ndarray, x0: Sequence[float]
) -> dict[str, float]:
    """A piecewise-constant cell current I_k [A] on [t_k, t_{k+1}) [s] applied to the 2-RC cell from
    x0 = (V1 [V], V2 [V], S), integrated exactly by CVODES interval by interval (model guide §6).

    Returns heat_J (∫Q), heat_irr_J (∫Q_irr), energy_J (∫I V_T) per cell and the final V1, V2, S.
    """
    t = np.asarray(t_s, float).ravel()
    I = np.asarray(I_A, float).ravel()
    if t.size != I.size + 1:
        raise ParameterError(
            f"resimulate_cell_current: t has {t.size} nodes, so I needs {t.size - 1} values, got {I.size}"
        )
    x = ca.SX.sym("x", 3)
    prm = ca.SX.sym("prm", 2)  # (I [A], interval length [s]); normalised time on [0, 1]
    cur, dt = prm[0], prm[1]
    dV1, dV2, dS = battery.cell_derivatives(x[0], x[1], cur, cell)
    VT = battery.terminal_voltage(x[2], x[0], x[1], cur, cell)
    quad = ca.vertcat(battery.heat_Q(x[0], x[1], cur, cell), battery.heat_irreversible(x[0], x[1], cur, cell), cur * VT)
    F = ca.integrator(
        "cell_exact",
        "cvodes",
        {"x": x, "p": prm, "ode": dt * ca.vertcat(dV1, dV2, dS), "quad": dt * quad},
        0.0,
        1.0,
        {"abstol": 1e-12, "reltol": 1e-10},
    )
    xk, q = integrate_held(F, np.asarray(x0, float).ravel()[:3], I, np.diff(t))
    return {
        "heat_J": float(q[0]),
        "heat_irr_J": float(q[1]),
        "energy_J": float(q[2]),
        "V1_end": float(xk[0]),
        "V2_end": float(xk[1]),
        "S_end": float(xk[2]),
    }


def record_refinement(res: OCPResult, res_2N: OCPResult) -> dict[str, Any]:
    """Store in ``res.meta['refinement']`` how the objective changes from N to 2N (NLP and exact)."""
    rec: dict[str, Any] = {
        "N": res.N,
        "N_refined": res_2N.N,
        "status_refined": res_2N.status,
        "objective": res.objective,
        "objective_refined": res_2N.objective,
        "objective_exact": res.objective_exact,
        "objective_exact_refined": res_2N.objective_exact,
    }
    for key, a, b in (
        ("change", res.objective, res_2N.objective),
        ("change_exact", res.objective_exact, res_2N.objective_exact),
    ):
        rec[key] = b - a if res_2N.success else math.nan
        s = max(abs(a), abs(b))
        rec[key + "_rel"] = (b - a) / s if res_2N.success and s > 0 else (0.0 if res_2N.success else math.nan)
    res.meta["refinement"] = rec
    return rec


def refinement_line(res: OCPResult) -> str:
    """One line: 'N = 200 -> 400: objective 24.6 -> 24.59 (−0.02 %)' (empty if not computed)."""
    r = res.meta.get("refinement")
    if not r:
        return ""
    if r["status_refined"] not in ("optimal", "acceptable"):
        return f"N = {r['N']} -> {r['N_refined']}: refined solve {r['status_refined']}"
    return (
        f"N = {r['N']} -> {r['N_refined']}: objective {r['objective']:.6g} -> {r['objective_refined']:.6g} "
        f"({100 * r['change_rel']:+.3g} %)"
    )


def multistart(solve: Callable[[str], OCPResult], guesses: Sequence[str]) -> tuple[OCPResult, dict[str, Any]]:
    """Solve once per named initial guess (``solve(name)``) and keep the best successful result
    (lowest NLP objective). Returns (best, record); the record, also stored in
    ``best.meta['multistart']``, lists each start's status and objectives and the spread
    (max − min NLP objective over the successful starts)."""
    if not guesses:
        raise ParameterError("multistart: give at least one initial guess")
    runs: dict[str, OCPResult] = {g: solve(g) for g in guesses}
    ok = {g: r for g, r in runs.items() if r.success}
    best_name = min(ok, key=lambda g: ok[g].objective) if ok else guesses[0]
    best = runs[best_name]
    objs = [r.objective for r in ok.values()]
    rec = {
        "best": best_name,
        "starts": {
            g: {
                "status": r.status,
                "objective": r.objective,
                "objective_exact": r.objective_exact,
                "iterations": r.iterations,
            }
            for g, r in runs.items()
        },
        "spread": (max(objs) - min(objs)) if objs else math.nan,
        "spread_rel": ((max(objs) - min(objs)) / max(abs(min(objs)), 1e-300)) if objs else math.nan,
    }
    best.meta["multistart"] = rec
    return best, rec


def multistart_line(res: OCPResult) -> str:
    """One line listing each start's objective and the spread (empty if not run)."""
    r = res.meta.get("multistart")
    if not r:
        return ""
    parts = ", ".join(
        f"{g} {s['objective']:.6g}" if s["status"] in ("optimal", "acceptable") else f"{g} {s['status']}"
        for g, s in r["starts"].items()
    )
    return f"starts: {parts}; best {r['best']}, spread {r['spread']:.3g} ({100 * r['spread_rel']:.3g} %)"

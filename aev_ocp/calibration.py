"""Calibration, one routine for all laws: fit a law's free parameters so that its equilibrium gap matches a
stated equilibrium speed–gap curve (a fundamental diagram), and save the set with its target and residual.

The fit is a least-squares problem on the equilibrium gap, solved by IPOPT through CasADi's nlpsol (bounds keep
the parameters physical). The equilibrium gap of each law is closed-form: ℓ V⁻¹(v/u) for the OV-type laws (their
κ term vanishes at equal speeds, so the proposed law and OVFL share it), (s0 + v T)/√(1 − (v/v0)^δ) for the IDM.

:data:`RING_HUMANS` is the common target of the shipped sets (aev_ocp/data/calibrated/): the equilibrium curve of the
ring's human drivers, the IDM with Treiber, Hennecke & Helbing 2000's parameters as used for rings in the Flow
benchmarks (Wu et al. 2017; :data:`aev_ocp.ring.laws.IDM_SI`: s0 = 2 m, T = 1 s, v0 = 30 m/s, δ = 4) at 2–12 m/s.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import casadi as ca
import numpy as np

from .models.carfollowing import IDM, TANH2, V_INF, CarFollowingLaw, OVLaw, make_law
from .params import ParameterError

#: the ring humans' equilibrium speed–gap curve (module docstring): speeds [m/s] and gaps [m]
_V = np.linspace(2.0, 12.0, 11)
RING_HUMANS = {
    "name": "ring_humans",
    "source": "IDM (Treiber, Hennecke & Helbing 2000) s0 = 2 m, T = 1 s, v0 = 30 m/s, delta = 4 (Flow ring, Wu et al. 2017)",
    "speed_mps": [float(v) for v in _V],
    "gap_m": [float((2.0 + v * 1.0) / math.sqrt(1.0 - (v / 30.0) ** 4)) for v in _V],
}
#: parameters each law fits by default
DEFAULT_FREE = {
    "proposed": ("h_scale_m", "v_scale_mps"),
    "ovfl": ("h_scale_m", "v_scale_mps"),
    "ovm": ("h_scale_m", "v_scale_mps"),
    "idm": ("s0_m", "T_s"),
}
DATA = Path(__file__).parent / "data" / "calibrated"


@dataclass(frozen=True)
class Calibration:
    """A fitted law: its name, the fitted parameters, the law, the target, the RMS and largest gap residual [m]."""

    law_name: str
    params: dict[str, float]
    law: CarFollowingLaw
    target: dict[str, Any]
    rms_m: float
    max_abs_m: float


def _gap_expr(law: CarFollowingLaw, v: Any) -> Any:
    if isinstance(law, OVLaw):
        return law.h_scale_m * (2.0 + ca.atanh(v / law.v_scale_mps - TANH2))
    if isinstance(law, IDM):
        return (law.s0_m + v * law.T_s) / ca.sqrt(1.0 - (v / law.v0_mps) ** law.delta)
    raise ParameterError(f"calibrate: no closed-form equilibrium gap for law {law.name!r} (OV-type laws and IDM)")


def calibrate(
    law_name: str,
    speed_mps: Sequence[float],
    gap_m: Sequence[float],
    free: Sequence[str] | None = None,
    start: CarFollowingLaw | None = None,
) -> Calibration:
    """Fit ``free`` parameters of law ``law_name`` (default :data:`DEFAULT_FREE`) from ``start`` (default the law's
    defaults) so that its equilibrium gap at ``speed_mps`` matches ``gap_m`` in least squares."""
    v, g = _points(speed_mps, "speed_mps"), _points(gap_m, "gap_m")
    if v.size != g.size:
        raise ParameterError(f"calibrate: speed_mps and gap_m need as many values, got {v.size} and {g.size}")
    if np.any(v < 0) or np.any(g <= 0):
        raise ParameterError("calibrate: speeds must be >= 0 and gaps > 0 (speed_mps, gap_m)")
    if float(v.max()) > V_MAX_TARGET_MPS:
        raise ParameterError(
            f"calibrate: speed_mps = {float(v.max()):g} is not allowed: an equilibrium speed is at most "
            f"{V_MAX_TARGET_MPS:g} m/s"
        )
    base = start if start is not None else make_law(law_name)
    if isinstance(free, str) or (free is not None and not all(isinstance(n, str) for n in free)):
        raise ParameterError(f"calibrate: free = {free!r:.60} must be a list of parameter names")
    names = tuple(free if free is not None else DEFAULT_FREE.get(law_name, ()))
    if not names:
        raise ParameterError(f"calibrate: no free parameters for law {law_name!r}")
    if len(set(names)) != len(names):
        raise ParameterError(f"calibrate: free = {list(names)} names a parameter twice")
    x = ca.SX.sym("x", len(names))
    trial = _symbolic(base, names, x)
    r = ca.vertcat(*[_gap_expr(trial, float(vk)) - float(gk) for vk, gk in zip(v, g)])
    idle = [n for i, n in enumerate(names) if not ca.depends_on(r, x[i])]
    if idle:  # a parameter the equilibrium gap does not depend on: IPOPT would drift it anywhere (a_mps2 = 1e5)
        raise ParameterError(
            f"calibrate: free parameter(s) {idle} of law {law_name!r} do not change its equilibrium gap, so the "
            "target cannot fix them: leave them out of free"
        )
    lbx = [1e-6] * len(names)
    if isinstance(base, OVLaw) and "v_scale_mps" in names:  # v/u − tanh 2 must stay inside (−1, 1)
        lbx[names.index("v_scale_mps")] = float(v.max()) / V_INF * (1 + 1e-6) + 1e-9
    x0 = [max(float(getattr(base, n)), lbx[i] * 1.5) for i, n in enumerate(names)]
    solver = ca.nlpsol(
        "calibrate",
        "ipopt",
        {"x": x, "f": 0.5 * ca.dot(r, r)},
        {"ipopt.print_level": 0, "print_time": 0, "ipopt.tol": 1e-10, "ipopt.sb": "yes"},
    )
    try:
        sol = solver(x0=x0, lbx=lbx, ubx=[1e6] * len(names))
    except RuntimeError as exc:  # IPOPT stopped on a NaN/inf it could not step around
        raise ParameterError(
            f"calibrate: the fit of {law_name!r} failed ({str(exc).rsplit(':', 1)[-1].strip()[:100]})"
        ) from None
    if not solver.stats()["success"]:
        raise ParameterError(f"calibrate: the fit of {law_name!r} failed ({solver.stats()['return_status']})")
    params = {n: float(sol["x"][i]) for i, n in enumerate(names)}
    law = replace(base, **params)
    res = np.array([law.equilibrium_gap_m(float(vk)) - float(gk) for vk, gk in zip(v, g)])
    target = {"speed_mps": v.tolist(), "gap_m": g.tolist()}
    return Calibration(law_name, params, law, target, float(np.sqrt(np.mean(res**2))), float(np.max(np.abs(res))))


#: the largest equilibrium speed a target may hold [m/s]: 2022 Tesla Model 3 RWD top speed, 225 km/h
#: (VehicleLimits.v_max_mps)
V_MAX_TARGET_MPS = 62.5


def _points(x: Any, key: str) -> np.ndarray:
    """``x`` as a 1-D float array of at least 2 finite real numbers (no bool, no string), else a ParameterError."""
    seq = list(x) if isinstance(x, (list, tuple, np.ndarray)) else None
    if (
        seq is None
        or np.ndim(x) != 1
        or len(seq) < 2
        or not all(
            isinstance(e, (int, float, np.integer, np.floating)) and not isinstance(e, (bool, np.bool_)) for e in seq
        )
        or not all(math.isfinite(float(e)) for e in seq)
    ):
        raise ParameterError(f"calibrate: {key} = {x!r:.60} must be a list of at least 2 finite numbers")
    return np.asarray(seq, float)


def _toml_str(text: str) -> str:
    """``text`` as a TOML basic string (JSON's escapes are TOML's: quotes, backslashes, line breaks)."""
    import json

    return json.dumps(str(text), ensure_ascii=False)


def _symbolic(law: CarFollowingLaw, names: tuple[str, ...], x: Any) -> CarFollowingLaw:
    import copy

    twin = copy.copy(law)
    for i, n in enumerate(names):
        if not hasattr(law, n):
            raise ParameterError(f"calibrate: law {law.name!r} has no parameter {n!r}")
        object.__setattr__(twin, n, x[i])  # a symbolic twin for the gap expression (validation ran on law)
    return twin


def save(cal: Calibration, path: str | Path, target_name: str = "", source: str = "") -> Path:
    """Write the set as TOML (law, parameters, target with its source, residuals), atomically."""
    p = Path(path)
    lines = [
        f"law = {_toml_str(cal.law_name)}",
        f"rms_m = {cal.rms_m!r}",
        f"max_abs_m = {cal.max_abs_m!r}",
        "",
        "[params]",
    ]
    lines += [f"{k} = {v!r}" for k, v in cal.params.items()]
    lines += ["", "[target]", f"name = {_toml_str(target_name)}", f"source = {_toml_str(source)}"]
    lines += [f"speed_mps = {cal.target['speed_mps']!r}", f"gap_m = {cal.target['gap_m']!r}", ""]
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=p.parent, suffix=".tmp")
    except OSError as exc:
        raise ParameterError(
            f"calibration file {path}: cannot write it ({exc.strerror or type(exc).__name__})"
        ) from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write("\n".join(lines))
        os.replace(tmp, p)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise ParameterError(
            f"calibration file {path}: cannot write it ({exc.strerror or type(exc).__name__})"
        ) from None
    return p


def load(path: str | Path) -> tuple[CarFollowingLaw, dict[str, Any]]:
    """(the calibrated law, the file's content) of a saved set; a bare name finds a shipped one (e.g. 'proposed_ring')."""
    import tomllib

    p = Path(path)
    if not p.exists() and p.suffix == "" and (DATA / f"{p.name}.toml").is_file():
        p = DATA / f"{p.name}.toml"
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
        law = make_law(doc["law"], None, **doc["params"])
    except (OSError, KeyError, tomllib.TOMLDecodeError, TypeError, UnicodeDecodeError) as exc:
        raise ParameterError(f"calibration file {path}: cannot read it ({type(exc).__name__}: {exc})") from None
    return law, doc


# ----------------------------------------------------------------------------------------- by simulation
@dataclass(frozen=True)
class SimulatedCalibration:
    """A fit by simulation: the parameters, the statistics they reach, the residuals (achieved − target), the
    objective Σ (residual/scale)² and how many simulations it took."""

    params: dict[str, float]
    achieved: dict[str, float]
    residuals: dict[str, float]
    objective: float
    evaluations: int


def calibrate_by_simulation(
    statistics: Any,
    start: dict[str, float],
    bounds: dict[str, tuple[float, float]],
    targets: dict[str, float],
    scales: dict[str, float],
    *,
    max_evaluations: int = 60,
    xtol: float = 1e-3,
) -> SimulatedCalibration:
    """Fit parameters whose effect is known only by simulation (a jam's wave speed, say): minimise
    Σ_k ((statistics(params)[k] − targets[k]) / scales[k])² over the box ``bounds`` by Nelder–Mead (Nelder & Mead
    1965, the standard coefficients 1, 2, 1/2, 1/2) in coordinates scaled to the box, from ``start``.
    ``statistics`` maps {name: value} to {statistic: value}; it should use the same random draws at every call
    (common random numbers) so that the objective is a deterministic function of the parameters. A NaN statistic
    (a run that crashed) counts as a large objective. Stops after ``max_evaluations`` simulations or when the
    simplex is smaller than ``xtol`` of the box."""
    names = list(bounds)
    if not names or set(start) != set(names):
        raise ParameterError(
            f"calibrate_by_simulation: start {sorted(start)} and bounds {sorted(names)} must name the same parameters"
        )
    if not targets or set(scales) != set(targets) or not all(s > 0 for s in scales.values()):
        raise ParameterError("calibrate_by_simulation: targets and scales must name the same statistics, scales > 0")
    lo = np.array([float(bounds[k][0]) for k in names])
    hi = np.array([float(bounds[k][1]) for k in names])
    if not np.all(np.isfinite(lo) & np.isfinite(hi) & (hi > lo)):
        raise ParameterError(f"calibrate_by_simulation: bounds = {bounds!r:.80} must be finite (lower, upper) pairs")
    cache: dict[tuple[float, ...], tuple[float, dict[str, float]]] = {}

    def values(u: np.ndarray) -> dict[str, float]:
        return {k: float(x) for k, x in zip(names, lo + np.clip(u, 0.0, 1.0) * (hi - lo))}

    def f(u: np.ndarray) -> float:
        key = tuple(np.round(np.clip(u, 0, 1), 12))
        if key not in cache:
            st = statistics(values(np.asarray(key)))
            r = [(float(st[k]) - targets[k]) / scales[k] for k in targets]
            obj = float(sum(x * x for x in r)) if all(math.isfinite(x) for x in r) else 1e6
            cache[key] = (obj, st)
        return cache[key][0]

    u0 = np.clip((np.array([float(start[k]) for k in names]) - lo) / (hi - lo), 0.0, 1.0)
    d = len(names)
    simplex = [u0] + [u0 + np.where(np.arange(d) == j, 0.15 if u0[j] <= 0.85 else -0.15, 0.0) for j in range(d)]
    fs = [f(u) for u in simplex]
    while len(cache) < max_evaluations:
        order = np.argsort(fs)
        simplex, fs = [simplex[i] for i in order], [fs[i] for i in order]
        if max(float(np.max(np.abs(u - simplex[0]))) for u in simplex[1:]) < xtol:
            break
        c = np.mean(simplex[:-1], axis=0)
        xr = np.clip(c + (c - simplex[-1]), 0, 1)
        fr = f(xr)
        if fr < fs[0]:
            xe = np.clip(c + 2 * (c - simplex[-1]), 0, 1)
            fe = f(xe)
            simplex[-1], fs[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < fs[-2]:
            simplex[-1], fs[-1] = xr, fr
        else:
            xc = np.clip(c + 0.5 * (simplex[-1] - c), 0, 1)
            fc = f(xc)
            if fc < fs[-1]:
                simplex[-1], fs[-1] = xc, fc
            else:  # shrink towards the best
                simplex = [simplex[0]] + [simplex[0] + 0.5 * (u - simplex[0]) for u in simplex[1:]]
                fs = [fs[0]] + [f(u) for u in simplex[1:]]
    best = int(np.argmin(fs))
    ub = simplex[best]
    obj, st = cache[tuple(np.round(np.clip(ub, 0, 1), 12))]
    res = {k: float(st[k]) - targets[k] for k in targets}
    return SimulatedCalibration(values(ub), {k: float(v) for k, v in st.items()}, res, obj, len(cache))

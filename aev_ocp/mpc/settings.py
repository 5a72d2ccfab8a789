"""MPC settings (PROBLEM.md §9), validated in one place.

Every option lives in :class:`MPCSettings`, a frozen dataclass; an invalid value raises
:class:`aev_ocp.params.ParameterError` naming the option (``MPCSettings.N = 0 is not allowed: ...``).
Model units throughout (PROBLEM.md §1): ``dt`` in model time units (0.1 = 0.2 s at the default units).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..ocp.following import OBJECTIVES, FollowingBounds, FollowingWeights
from ..params import ParameterError, PowertrainOptions

#: Solver paths. 'ipopt': warm-started IPOPT (default). 'sqp': sqpmethod (exact Hessian, qpsol
#: ``qp_solver``) warm-started from the shifted previous solution after a cold IPOPT first solve.
#: (FATROP was tried: CasADi 3.8.2's interface raised 'fatrop inf' on this NLP, so it is not offered.)
#: 'ipopt-cold': IPOPT from the closed-form-law guess at every step (the benchmark baseline).
#: 'rti': real-time iteration — ``rti_iterations`` (default 1) full SQP steps per control step from the
#: shifted previous solution: one QP (exact Lagrangian Hessian, linearised constraints) built by a
#: stage-wise (optionally C-compiled) function and solved by ``qp_solver`` through ``ca.conic``; no
#: line search. The applied control's path constraints (current, map) are checked on the exact model.
SOLVER_PATHS = ("ipopt", "sqp", "ipopt-cold", "rti")
QP_SOLVERS = ("qrqp", "osqp", "hpipm", "qpoases", "proxqp")
PREDICTOR_NAMES = ("oracle", "constant-velocity", "constant-acceleration", "decaying-acceleration", "cooperative")


def _err(name: str, value: Any, allowed: str) -> ParameterError:
    return ParameterError(f"MPCSettings.{name} = {value!r} is not allowed: {allowed}")


@dataclass(frozen=True)
class MPCSettings:
    """Options of the receding-horizon controller (defaults: PROBLEM.md §9).

    N: horizon intervals; dt: interval length [model time]; weights: stage-cost weights (parameters of
    the NLP, changeable per solve without rebuilding); bounds: h, v, a bounds; objective: 'heat'
    (pack Q with the smoothed η switch) or 'energy' (v g̃(a)); smooth: η-switch smoothing (PROBLEM.md §7);
    rk4_substeps: RK4 steps per interval in the prediction model; solver: one of SOLVER_PATHS;
    qp_solver: QP solver of the 'sqp' and 'rti' paths; rti_iterations: SQP iterations per step of the
    'rti' path (1 = real-time iteration; fewer when the step falls below tol); codegen: compile the
    NLP functions to C with gcc
    (falls back to the interpreted path with a warning when no compiler is found); tol: optimality
    tolerance; max_iter: iteration limit per solve; max_cpu_time_s: wall-time limit per solve [s];
    predictor: leader forecast (PREDICTOR_NAMES); predictor_window: measured samples used by the
    constant-acceleration predictor; verbose: solver console output (silent by default).
    """

    N: int = 40  # PROBLEM.md §9
    dt: float = 0.1  # PROBLEM.md §9 (0.2 s at L = 10 m, U = 5 m/s)
    weights: FollowingWeights = field(default_factory=FollowingWeights)  # PROBLEM.md §9: 1, 1, 1, 0.1
    bounds: FollowingBounds = field(default_factory=FollowingBounds)  # PROBLEM.md §9
    objective: str = "heat"  # PROBLEM.md §9
    smooth: PowertrainOptions = field(default_factory=PowertrainOptions)  # PROBLEM.md §7: 300 W
    rk4_substeps: int = 1
    solver: str = "ipopt"
    qp_solver: str = "hpipm"
    codegen: bool = False
    tol: float = 1e-8
    max_iter: int = 200
    rti_iterations: int = 1
    max_cpu_time_s: float = 10.0
    predictor: str = "oracle"  # PROBLEM.md §9 canonical scenario: oracle forecast
    predictor_window: int = 5
    verbose: bool = False

    def __post_init__(self) -> None:
        for nm, lo in (("N", 1), ("rk4_substeps", 1), ("max_iter", 1), ("rti_iterations", 1),
                       ("predictor_window", 2)):
            v = getattr(self, nm)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise _err(nm, v, f"must be an integer >= {lo}")
        for nm in ("dt", "tol", "max_cpu_time_s"):
            v = getattr(self, nm)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise _err(nm, v, "must be a finite number > 0")
        for nm, choices in (("objective", OBJECTIVES), ("solver", SOLVER_PATHS), ("qp_solver", QP_SOLVERS),
                            ("predictor", PREDICTOR_NAMES)):
            v = getattr(self, nm)
            if v not in choices:
                raise _err(nm, v, f"must be one of {choices}")
        for nm in ("codegen", "verbose"):
            if not isinstance(getattr(self, nm), bool):
                raise _err(nm, getattr(self, nm), "must be true or false")
        for nm, cls in (("weights", FollowingWeights), ("bounds", FollowingBounds), ("smooth", PowertrainOptions)):
            if not isinstance(getattr(self, nm), cls):
                raise _err(nm, getattr(self, nm), f"must be a {cls.__name__}")

    @property
    def horizon(self) -> float:
        """Prediction horizon N·dt [model time]."""
        return self.N * self.dt

    def with_(self, **changes: Any) -> "MPCSettings":
        """A validated copy with some options changed."""
        return replace(self, **changes)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MPCSettings":
        """Build from a flat dict: MPCSettings fields plus w_Q, w_V, w_r, w_a, h_min, v_min, v_max,
        a_min, a_max, smoothing_width_W. Unknown keys raise ParameterError naming the key."""
        own = {f.name for f in fields(cls)} - {"weights", "bounds", "smooth"}
        wn = {f.name for f in fields(FollowingWeights)}
        bn = {f.name for f in fields(FollowingBounds)}
        kw: dict[str, Any] = {}
        w: dict[str, Any] = {}
        b: dict[str, Any] = {}
        s: dict[str, Any] = {}
        for k, v in d.items():
            if k in own:
                kw[k] = v
            elif k in wn:
                w[k] = v
            elif k in bn:
                b[k] = v
            elif k == "smoothing_width_W":
                s[k] = v
            else:
                raise ParameterError(f"MPC option {k!r} is unknown: known options are "
                                     f"{sorted(own | wn | bn | {'smoothing_width_W'})}")
        try:
            return cls(weights=FollowingWeights(**w), bounds=FollowingBounds(**b), smooth=PowertrainOptions(**s), **kw)
        except TypeError as exc:  # pragma: no cover - guarded above
            raise ParameterError(f"MPC options: {exc}") from None

"""The ``[mpc]`` table of scenario files, and building a closed loop from a scenario.

Keys (all optional; defaults PROBLEM.md §9): every :class:`MPCSettings` option (N, dt, objective,
solver, qp_solver, codegen, tol, max_iter, rti_iterations, max_cpu_time_s, predictor, predictor_window, rk4_substeps,
verbose), the weights w_Q, w_V, w_r, w_a, the bounds h_min, v_min, v_max, a_min, a_max,
smoothing_width_W, plus ``vehicles`` ("all" or an array of 1-based follower numbers on MPC; the others
keep the scenario's [platoon] law) and ``follower_predictor`` (forecast of an MPC follower behind
another vehicle: "cooperative" behind an MPC vehicle by default, else "constant-velocity").
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ..ocp.following import FollowingBounds, FollowingWeights
from ..params import ParameterError
from ..control import ClosedLoop
from .policy import MPCVehicle
from .settings import PREDICTOR_NAMES, QP_SOLVERS, SOLVER_PATHS, MPCSettings

_STR = {"objective": ("heat", "energy"), "solver": SOLVER_PATHS, "qp_solver": QP_SOLVERS,
        "predictor": PREDICTOR_NAMES}
_INT = ("N", "max_iter", "rti_iterations", "predictor_window", "rk4_substeps")
_BOOL = ("codegen", "verbose")


@dataclass(frozen=True)
class MPCConfig:
    """Validated [mpc] table: settings, 0-based MPC vehicle indices (None = all), follower predictor."""

    settings: MPCSettings
    vehicles: tuple[int, ...] | None = None
    follower_predictor: str | None = None


def validate_mpc_table(r: Any) -> MPCConfig:
    """Validator for ``aev_ocp.scenarios.register_section('mpc', ...)`` (a TableReader)."""
    d: dict[str, Any] = {}
    nums = ({f.name for f in fields(MPCSettings)} - set(_STR) - set(_INT) - set(_BOOL)
            - {"weights", "bounds", "smooth"}) | {f.name for f in fields(FollowingWeights)} \
        | {f.name for f in fields(FollowingBounds)} | {"smoothing_width_W"}
    for k in list(r.table):
        if k in _STR:
            d[k] = r.string(k, choices=list(_STR[k]))
        elif k in _INT:
            d[k] = r.integer(k, ge=1)
        elif k in _BOOL:
            d[k] = r.boolean(k)
        elif k in nums:
            d[k] = r.number(k)
    vehicles: tuple[int, ...] | None = None
    if r.has("vehicles"):
        val = r.table["vehicles"]
        if val == "all":
            r._get("vehicles", None)
        else:
            nums_v = r.numbers("vehicles", ge=1)
            if any(int(x) != x for x in nums_v):
                raise r.error("vehicles", val, "must be \"all\" or an array of follower numbers (1, 2, …)")
            vehicles = tuple(sorted({int(x) - 1 for x in nums_v}))
    fp = r.string("follower_predictor", None, choices=["cooperative", "constant-velocity", "constant-acceleration"])
    r.finish()
    settings = MPCSettings.from_dict(d)  # ParameterError names the option; the loader adds file and [mpc]
    return MPCConfig(settings, vehicles, fp)


def register() -> None:
    """Register the [mpc] table with the scenario loader."""
    from ..scenarios import register_section

    register_section("mpc", validate_mpc_table)


def closed_loop_from_scenario(scenario: Any, config: MPCConfig | None = None,
                              settings: MPCSettings | None = None) -> ClosedLoop:
    """A :class:`ClosedLoop` for a scenario: MPC on the configured followers, the scenario's laws on the
    others, the proposed law with the scenario's α, β, κ as the fallback."""
    cfg = config or scenario.extra.get("mpc") or MPCConfig(MPCSettings())
    s = settings or cfg.settings
    n = scenario.n_followers
    on = set(range(n)) if cfg.vehicles is None else set(cfg.vehicles)
    bad = [i + 1 for i in on if i >= n]
    if bad:
        raise ParameterError(f"[mpc].vehicles: followers {bad} do not exist (the platoon has {n})")
    ctrls: list[Any] = []
    for i in range(n):
        if i not in on:
            ctrls.append(scenario.laws[i])
        elif i == 0:
            ctrls.append(MPCVehicle(s))
        else:
            p = cfg.follower_predictor or ("cooperative" if (i - 1) in on else "constant-velocity")
            if p == "cooperative" and (i - 1) not in on:
                p = "constant-velocity"
            ctrls.append(MPCVehicle(s, predictor=p))
    return ClosedLoop(scenario.leader, ctrls, scenario.ev, fallback_law=scenario.law("proposed"),
                      rtol=scenario.rtol, atol=scenario.atol)

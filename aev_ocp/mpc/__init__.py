"""Receding-horizon MPC of the ego vehicle with the battery in the loop (PROBLEM.md §9).

Problem (:func:`aev_ocp.ocp.following.following_problem`, shared with OCP-D), controller
(:class:`MPCController`, built once from the problem), policy (:class:`MPCPolicy`: forecast, solve,
fallback — a :class:`aev_ocp.control.Controller`) and plant (:class:`aev_ocp.plant.Plant`, driven by
:class:`aev_ocp.control.ClosedLoop`) are kept apart; results are the shared
:class:`aev_ocp.results.SimulationResult`, so MPC and closed-form laws share the §10 metrics.
"""

from __future__ import annotations

from typing import Any

from ..control import ClosedLoop, ControlSequence, run_closed_loop
from .controller import MPCController, MPCSolution
from .policy import MPCPolicy, MPCVehicle, run_single
from .predictors import (ConstantAccelerationPredictor, ConstantVelocityPredictor, LeaderPredictor, Measurements,
                         OraclePredictor, make_predictor)
from .settings import PREDICTOR_NAMES, SOLVER_PATHS, MPCSettings


def cli_mpc(argv: list[str]) -> int:
    """``aev-ocp mpc SCENARIO.toml [--out DIR] [--solver ...]`` (see :mod:`aev_ocp.mpc.cli`)."""
    from .cli import cli_mpc as _cli

    return _cli(argv)


def _reproduce_section(out_dir: Any, progress: Any) -> str:
    from .report import mpc_section

    return mpc_section(out_dir, progress)


REPRODUCE_SECTIONS = [("mpc", _reproduce_section, 15)]  # 3 runs x 4 progress lines + OCP-D + replay + writing

try:  # the [mpc] table of scenario files
    from .scenario import register as _register_scenario_section

    _register_scenario_section()
except ImportError:  # pragma: no cover - scenario loader not installed
    pass

__all__ = ["ClosedLoop", "ControlSequence", "MPCPolicy", "ConstantAccelerationPredictor", "ConstantVelocityPredictor", "LeaderPredictor",
           "MPCController", "MPCSettings", "MPCSolution", "MPCVehicle", "Measurements", "OraclePredictor",
           "PREDICTOR_NAMES", "SOLVER_PATHS", "cli_mpc", "make_predictor", "run_closed_loop", "run_single"]

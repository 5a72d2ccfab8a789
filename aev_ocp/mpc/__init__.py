"""Receding-horizon MPC of the ego vehicle with the battery in the loop (model guide §9).

Problem (:func:`aev_ocp.ocp.following.following_problem`, shared with OCP-D), controller
(:class:`MPCController`, built once from the problem), policy (:class:`MPCPolicy`: forecast, solve,
fallback — a :class:`aev_ocp.control.Controller`) and plant (:class:`aev_ocp.plant.Plant`, driven by
:class:`aev_ocp.control.ClosedLoop`) are kept apart; results are the shared
:class:`aev_ocp.results.SimulationResult`, so MPC and closed-form laws share the §10 metrics.
The ``aev-ocp mpc`` command is :mod:`aev_ocp.mpc.cli`, its report section :mod:`aev_ocp.mpc.report`, the
``[mpc]`` table of scenario files :mod:`aev_ocp.mpc.scenario` (loaded by the scenario loader on demand).
"""

from __future__ import annotations

from ..control import ClosedLoop, ControlSequence, run_closed_loop
from .controller import MPCController, MPCSolution
from .policy import MPCPolicy, MPCVehicle, run_single
from .predictors import (
    ConstantAccelerationPredictor,
    ConstantVelocityPredictor,
    LeaderPredictor,
    Measurements,
    OraclePredictor,
    make_predictor,
)
from .settings import PREDICTOR_NAMES, SOLVER_PATHS, MPCSettings

__all__ = [
    "ClosedLoop",
    "ControlSequence",
    "MPCPolicy",
    "ConstantAccelerationPredictor",
    "ConstantVelocityPredictor",
    "LeaderPredictor",
    "MPCController",
    "MPCSettings",
    "MPCSolution",
    "MPCVehicle",
    "Measurements",
    "OraclePredictor",
    "PREDICTOR_NAMES",
    "SOLVER_PATHS",
    "make_predictor",
    "run_closed_loop",
    "run_single",
]

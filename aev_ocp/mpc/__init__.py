"""Receding-horizon MPC of the ego vehicle with the battery in the loop (model guide §9).

Problem (:func:`aev_ocp.ocp.following.following_problem`, shared with OCP-D), controller
(:class:`MPCController`, built once from the problem), policy (:class:`MPCPolicy`: forecast, solve,
fallback — a :class:`aev_ocp.control.Controller`) and plant (:class:`aev_ocp.plant.Plant`, driven by
:class:`aev_ocp.control.ClosedLoop`) are kept apart; results are the shared
:class:`aev_ocp.results.SimulationResult`, so MPC and closed-form laws share the §10 metrics.
The MPC beside the laws and OCP-D is :func:`run_comparison` (:mod:`aev_ocp.mpc.run`, application layer: so this
package's table stands in that layer too, and code below it imports the submodules, never the package). The
``aev-ocp mpc`` command is :mod:`aev_ocp.mpc.cli`, its report section :mod:`aev_ocp.mpc.report`, the
``[mpc]`` table of scenario files :mod:`aev_ocp.mpc.scenario` (loaded by the scenario loader on demand).
"""

from __future__ import annotations

from ..lazy import lazy_exports

#: name -> module that defines it (imported on first use: aev_ocp.lazy)
_EXPORTS = {
    "ClosedLoop": "aev_ocp.control",
    "ControlSequence": "aev_ocp.control",
    "run_closed_loop": "aev_ocp.control",
    "MPCController": "controller",
    "MPCSolution": "controller",
    "MPCPolicy": "policy",
    "MPCVehicle": "policy",
    "run_single": "policy",
    "ConstantAccelerationPredictor": "predictors",
    "ConstantVelocityPredictor": "predictors",
    "LeaderPredictor": "predictors",
    "Measurements": "predictors",
    "OraclePredictor": "predictors",
    "make_predictor": "predictors",
    "PREDICTOR_NAMES": "settings",
    "SOLVER_PATHS": "settings",
    "MPCSettings": "settings",
    "Comparison": "run",
    "run_comparison": "run",
}

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
    "run_comparison",
    "Comparison",
    "run_single",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

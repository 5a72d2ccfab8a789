"""aev_ocp: energy-aware control of autonomous electric vehicles, built on CasADi.

Layers: ``params`` (parameter sets with units and sources), ``models`` (physics only), ``plant``
(the exact platoon model and its event rules), ``control`` (the Controller protocol and the closed
loop), ``simulate`` (closed-form-law platoons), ``ocp`` (problem description, transcription, OCP-A…D),
``mpc`` (the receding-horizon controller built from the same problem), ``scenarios`` (TOML files),
``report``/``cli`` (figures, tables, command line), ``saved`` and ``loading`` (``load(folder)``: every
command's output folder back as its result object). The names most users need are exported here;
importing them is lazy, so ``import aev_ocp`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

from ._version import __version__

_EXPORTS = {
    # parameters and models
    "EVParams": "params",
    "Units": "params",
    "CarFollowingParams": "params",
    "VehicleParams": "params",
    "CellParams": "params",
    "PackParams": "params",
    "PowertrainOptions": "params",
    "SimOptions": "params",
    "ParameterError": "params",
    "OVM": "models",
    "OVFL": "models",
    "Proposed": "models",
    "IDM": "models",
    "IDMModelUnits": "models",
    "CarFollowingLaw": "models",
    "make_law": "models",
    "register_law": "models",
    "PaperLeader": "models",
    "ConstantSpeed": "models",
    "SpeedTrace": "models",
    "drive_cycle": "models",
    # plant, controllers, results
    "Plant": "plant",
    "EVENT_RULES": "plant",
    "ClosedLoop": "control",
    "Controller": "control",
    "Command": "control",
    "Observation": "control",
    "ControlSequence": "control",
    "SampledLaw": "control",
    "run_closed_loop": "control",
    "SimulationResult": "results",
    "simulate_platoon": "simulate",
    "replay": "trace_replay",
    "ReplayResult": "trace_replay",
    # optimal control and MPC
    "OCPProblem": "ocp",
    "ProblemBuilder": "ocp",
    "OCPSolver": "ocp",
    "TranscriptionOptions": "ocp",
    "following_problem": "ocp",
    "MPCSettings": "mpc",
    "MPCController": "mpc",
    "MPCVehicle": "mpc",
    "MPCPolicy": "mpc",
    # scenarios
    "load_scenario": "scenarios",
    "Scenario": "scenarios",
    # figures (each returns a matplotlib Figure; given a path it also writes the PNG)
    "plot_trajectories": "plots",
    "plot_space_time": "plots",
    # saved outputs (every command's folder loads back)
    "load": "loading",
    "load_all": "saved",
    "LoadError": "saved",
}
__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'aev_ocp' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)

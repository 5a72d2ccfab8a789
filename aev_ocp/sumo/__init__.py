"""Drive the toolkit's controllers inside Eclipse SUMO (optional extra ``aev_ocp[sumo]``).

A ``[sumo]`` scenario names a SUMO network and routes (a shipped one: the Sugiyama ring or a highway on-ramp
merge, or the user's own files), which vehicles the toolkit controls (by id, vehicle type or a share of the
traffic) and with which controller (a closed-form law by name, the MPC with a measured forecast, or any
:class:`aev_ocp.control.Controller`). Each step a controlled vehicle observes what a car can (its leader's gap
and speed from SUMO, its own speed), its controller commands an acceleration, SUMO moves it (ballistic update:
the command is held over the step), and the battery model integrates the realised motion of every vehicle.
Results come back as one :class:`aev_ocp.results.SimulationResult` per vehicle (the usual metrics), fleet
totals, a saved run (:func:`aev_ocp.load`), space-time diagrams and a Markdown report.

SUMO runs in-process through libsumo: one SUMO per process, so sweeps parallelise over processes.
Everything that needs SUMO imports it through :func:`require_sumo`, which says in one line how to install it.
"""

from __future__ import annotations

import importlib.util
from typing import Any

from ..scenarios import ScenarioError

INSTALL_HINT = (
    "SUMO is not installed: pip install 'aev_ocp[sumo]' (the eclipse-sumo, libsumo and sumolib packages from PyPI)"
)


class SumoError(ScenarioError):
    """A SUMO input (network, routes, configuration) that SUMO refuses, or SUMO missing; one line."""


def sumo_available() -> bool:
    """Whether libsumo and the SUMO binaries (the ``eclipse-sumo`` package) can be imported."""
    return all(importlib.util.find_spec(m) is not None for m in ("libsumo", "sumo"))


def require_sumo() -> Any:
    """The libsumo module, or :class:`SumoError` with :data:`INSTALL_HINT`."""
    if not sumo_available():
        raise SumoError(INSTALL_HINT)
    import libsumo

    return libsumo


def sumo_binary(tool: str) -> str:
    """Path of a SUMO tool (``sumo``, ``netconvert``, ``netgenerate``) of the installed ``eclipse-sumo``."""
    require_sumo()
    import os

    import sumo

    path = os.path.join(sumo.SUMO_HOME, "bin", tool)
    if not os.path.exists(path):
        raise SumoError(
            f"SUMO tool {tool!r} not found in {os.path.dirname(path)}; reinstall with "
            "pip install --force-reinstall 'aev_ocp[sumo]'"
        )
    return path


__all__ = ["INSTALL_HINT", "SumoError", "require_sumo", "sumo_available", "sumo_binary"]

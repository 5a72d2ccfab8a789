"""Optimal control (model guide §8–§9): a transcription layer (multiple shooting / collocation, IPOPT)
and the four problems OCP-A (Proposition 3.1), OCP-B (current profile), OCP-C (eco-trip) and
OCP-D (oracle following, the lower bound). Nothing here plots; see :mod:`aev_ocp.ocp_plots`.

The §9 problem shared with the MPC is stated once in :mod:`aev_ocp.ocp.following`; the problem
description (:class:`OCPProblem`, :class:`ProblemBuilder`) lives in :mod:`aev_ocp.ocp.problem`.
The runs that write files (``run_prop31``, ``run_oracle``, …) are in :mod:`aev_ocp.ocp.api`, the
``aev-ocp ocp`` command in :mod:`aev_ocp.ocp.cli`, the report section in :mod:`aev_ocp.ocp.report_section`.

The names below are imported on first use, so ``import aev_ocp.ocp.problem`` loads the problem
description only (docs/guide/layers.md).
"""

from __future__ import annotations

import importlib
from typing import Any

#: name -> submodule that defines it (problem description and solvers only: the package's own layers)
_EXPORTS = {
    "OCPResult": "result",
    "OCPProblem": "problem",
    "ProblemBuilder": "problem",
    "OCPSolver": "transcription",
    "TranscriptionOptions": "transcription",
    "FollowingBounds": "following",
    "FollowingWeights": "following",
    "following_problem": "following",
    "following_stage_terms": "following",
    "OracleScenario": "oracle",
    "OracleSolver": "oracle",
    "canonical_scenario": "oracle",
    "stage_cost_of_trajectory": "oracle",
}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'aev_ocp.ocp' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

"""Optimal control (model guide §8–§9): a transcription layer (multiple shooting / collocation, IPOPT)
and the four problems OCP-A (Proposition 3.1), OCP-B (current profile), OCP-C (eco-trip) and
OCP-D (oracle following, the lower bound). The solvers plot nothing; :mod:`aev_ocp.ocp.plots` draws their results.

The §9 problem shared with the MPC is stated once in :mod:`aev_ocp.ocp.following`; the problem
description (:class:`OCPProblem`, :class:`ProblemBuilder`) lives in :mod:`aev_ocp.ocp.problem`.
The runs that write files (``run_prop31``, ``run_oracle``, …) are in :mod:`aev_ocp.ocp.run`, the
``aev-ocp ocp`` command in :mod:`aev_ocp.ocp.cli`, the report section in :mod:`aev_ocp.ocp.section`.

The names below are imported on first use, so ``import aev_ocp.ocp.problem`` loads the problem
description only (docs/guide/layers.md).
"""

from __future__ import annotations

from ..lazy import lazy_exports

#: name -> submodule that defines it (problem description and solvers only: the package's own layers)
_EXPORTS = {
    "OCPResult": "aev_ocp.ocp_result",
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

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

"""Optimal control (PROBLEM.md §8–§9): a transcription layer (multiple shooting / collocation, IPOPT)
and the four problems OCP-A (Proposition 3.1), OCP-B (current profile), OCP-C (eco-trip) and
OCP-D (oracle following, the lower bound). Nothing here plots; see :mod:`aev_ocp.ocp_plots`.

The §9 problem shared with the MPC is stated once in :mod:`aev_ocp.ocp.following`; the problem
description (:class:`OCPProblem`, :class:`ProblemBuilder`) lives in :mod:`aev_ocp.ocp.problem`.
"""

from .api import run_current_profile, run_eco_trip, run_oracle, run_prop31
from .cli import cli_ocp
from .following import FollowingBounds, FollowingWeights, following_problem, following_stage_terms
from .oracle import OracleScenario, OracleSolver, canonical_scenario, stage_cost_of_trajectory
from .report_section import REPRODUCE_SECTIONS
from .result import OCPResult
from .problem import OCPProblem, ProblemBuilder
from .transcription import OCPSolver, TranscriptionOptions

__all__ = ["REPRODUCE_SECTIONS", "OCPResult", "OCPProblem", "OCPSolver", "TranscriptionOptions", "cli_ocp", "run_prop31",
           "run_current_profile", "run_eco_trip", "run_oracle", "FollowingBounds", "FollowingWeights",
           "following_problem", "following_stage_terms", "ProblemBuilder", "OracleScenario",
           "OracleSolver", "canonical_scenario", "stage_cost_of_trajectory"]

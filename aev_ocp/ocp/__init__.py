"""Optimal control (PROBLEM.md §8–§9): a transcription layer (multiple shooting / collocation, IPOPT)
and the four problems OCP-A (Proposition 3.1), OCP-B (current profile), OCP-C (eco-trip) and
OCP-D (oracle following, the lower bound). Nothing here plots; see :mod:`aev_ocp.ocp_plots`.
"""

from .api import run_prop31
from .cli import cli_ocp
from .result import OCPResult
from .transcription import OCPProblem, OCPSolver, TranscriptionOptions

__all__ = ["OCPResult", "OCPProblem", "OCPSolver", "TranscriptionOptions", "cli_ocp", "run_prop31"]

"""What a failed or late MPC step returns, so that the policy applies its fallback (:mod:`aev_ocp.mpc.policy`)
and counts it by cause: every failed step's status starts with its cause ('QP failed', 'budget', 'path
constraint', 'exception', or the NLP solver's status; the text before the first ':' is the cause counted in
``fallback_causes``)."""

from __future__ import annotations

import numpy as np

from .solution import MPCSolution


def failed_solution(
    status: str, iters: int, dt_wall: float, viol: float, path: str, nx: int, nu: int, N: int
) -> MPCSolution:
    """A failed solve (success False, plan NaN) with ``status`` (its cause first)."""
    return MPCSolution(
        False,
        status,
        iters,
        dt_wall,
        np.full((nx, N + 1), np.nan),
        np.full(N, np.nan),
        float("nan"),
        viol,
        path,
        {},
        np.full((nu, N), np.nan),
    )


def budget_status(dt_wall: float, max_step_ms: float) -> str:
    """The status of a valid plan that took longer than ``max_step_ms`` (``budget = 'wall'`` only): cause 'budget'."""
    return f"budget: the step took {dt_wall * 1e3:.3g} ms > max_step_ms = {max_step_ms:g}"


def cold_start_falls_back_to_ipopt(success: bool, was_cold: bool, rti_cold: bool, warm_left: bool) -> bool:
    """Whether a step of the compiled RTI step hands over to the cold IPOPT: only a failed cold start of a
    formulation that starts with a cold IPOPT (§9), and only when it left no warm start (a late cold start,
    cause 'budget', left its plan as the warm start: the next step is warm)."""
    return not (success or not was_cold or rti_cold or warm_left)

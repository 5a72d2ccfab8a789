"""What one MPC solve returns (:class:`MPCSolution`): the plan and the solve's statistics (status, iterations,
wall time, cost, constraint violation, path, solver-specific stats). The closed loop's per-run statistics
(medians, fallbacks and their causes) are built from these by :mod:`aev_ocp.control`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class MPCSolution:
    """One solve: success, status, iterations, wall time [s] of the solver call, the plan
    X (nx, N+1) and a (N,) [model units] (all controls: U (nu, N)), cost (NLP objective), max
    constraint violation (NLP units)."""

    success: bool
    status: str
    iterations: int
    solve_time_s: float
    X: np.ndarray
    a: np.ndarray
    cost: float
    violation: float
    path: str
    stats: dict[str, Any] = field(default_factory=dict)
    U: np.ndarray | None = None

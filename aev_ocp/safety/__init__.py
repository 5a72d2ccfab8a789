"""Safety: a kinematic avoidability bound, a safe fallback controller, and a suite of rear-end and cut-in cases.

* :mod:`.kinematics` — :func:`braking_bound`: the smallest gap when the ego brakes at its maximum from t = 0
  (pure physics, exact piecewise), and the labels avoidable / collision-avoidable only / unavoidable.
* :mod:`.fallback` — :func:`safe_acceleration_mps2` and :class:`SafeFallback`: the largest acceleration that keeps
  the braking-distance condition over the next step, else maximal braking; the MPC's fallback and safety filter.
* :mod:`.cases`, :mod:`.suite`, :mod:`.report`, :mod:`.cli` — the suite (``aev-ocp safety``) and its section of
  ``aev-ocp reproduce``; imported on use (the MPC policy imports :mod:`.fallback`, the suite imports the MPC).

Python API (SI)::

    from aev_ocp.safety import braking_bound, safe_acceleration_mps2
    braking_bound(25.0, 8.0, 25.0, -9.0)            # BrakingBound(min_gap_m=3.66, ..., label='avoidable')
    from aev_ocp.safety.suite import run_suite
    out = run_suite(quick=True); out.failures("mpc")
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from .fallback import SafeFallback, SafetyParams, safe_acceleration_mps2
from .kinematics import AVOIDABLE, COLLISION_AVOIDABLE_ONLY, LABELS, UNAVOIDABLE, BrakingBound, braking_bound, label_of


def cli_safety(argv: list[str]) -> int:
    """``aev-ocp safety`` (see :mod:`aev_ocp.safety.cli`)."""
    from .cli import cli_safety as run

    return run(argv)


def safety_section(out_dir: Path, progress: Callable[[str], None]) -> str:
    """The safety suite's section of ``aev-ocp reproduce`` (see :mod:`aev_ocp.safety.section`)."""
    from .section import safety_section as run

    return run(out_dir, progress)


REPRODUCE_SECTIONS = [("safety", safety_section, 1)]

__all__ = ["AVOIDABLE", "COLLISION_AVOIDABLE_ONLY", "LABELS", "REPRODUCE_SECTIONS", "UNAVOIDABLE", "BrakingBound",
           "SafeFallback", "SafetyParams", "braking_bound", "cli_safety", "label_of", "safe_acceleration_mps2",
           "safety_section"]

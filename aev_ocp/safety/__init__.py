"""Safety: a kinematic avoidability bound, a safe fallback controller, and a suite of rear-end and cut-in cases.

* :mod:`.kinematics` — :func:`braking_bound`: the smallest gap when the ego brakes at its maximum from t = 0
  (pure physics, exact piecewise), and the labels avoidable / collision-avoidable only / unavoidable.
* :mod:`.fallback` — :func:`safe_acceleration_mps2` and :class:`SafeFallback`: the largest acceleration that keeps
  the braking-distance condition over the next step, else maximal braking; the MPC's fallback and safety filter.
* :mod:`.cases`, :mod:`.suite`, :mod:`.report`, :mod:`.section`, :mod:`.cli` — the suite, its section of
  ``aev-ocp reproduce`` and the ``aev-ocp safety`` command; never imported here (the MPC policy imports
  :mod:`.fallback`, the suite imports the MPC; docs/guide/layers.md).

Python API (SI)::

    from aev_ocp.safety import braking_bound, safe_acceleration_mps2
    braking_bound(25.0, 8.0, 25.0, -9.0)            # BrakingBound(min_gap_m=3.66, ..., label='avoidable')
    from aev_ocp.safety.suite import run_suite
    out = run_suite(quick=True); out.failures("mpc")
"""

from __future__ import annotations

from .fallback import SafeFallback, SafetyParams, safe_acceleration_mps2
from .kinematics import AVOIDABLE, COLLISION_AVOIDABLE_ONLY, LABELS, UNAVOIDABLE, BrakingBound, braking_bound, label_of

__all__ = [
    "AVOIDABLE",
    "COLLISION_AVOIDABLE_ONLY",
    "LABELS",
    "UNAVOIDABLE",
    "BrakingBound",
    "SafeFallback",
    "SafetyParams",
    "braking_bound",
    "label_of",
    "safe_acceleration_mps2",
]

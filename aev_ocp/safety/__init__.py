"""Safety: a kinematic avoidability bound, a safe fallback controller, and a suite of rear-end and cut-in cases.

* :mod:`.kinematics` — :func:`braking_bound`: the smallest gap when the ego brakes at its maximum from t = 0
  (pure physics, exact piecewise), and the labels avoidable / collision-avoidable only / unavoidable.
* :mod:`.bound` — :func:`safe_acceleration_mps2`: the largest acceleration that keeps the braking-distance
  condition over the next step, else maximal braking (pure physics; the closed loop's safety stage uses it);
* :mod:`.fallback` — :class:`SafeFallback`: that bound as a controller; the MPC's fallback and safety filter.
* :mod:`.cases`, :mod:`.suite`, :mod:`.report`, :mod:`.section`, :mod:`.cli` — the suite, its section of
  ``aev-ocp reproduce`` and the ``aev-ocp safety`` command; never imported here (the MPC policy imports
  :mod:`.fallback`, the suite imports the MPC; docs/guide/layers.md). The names below are imported on first use,
  so ``import aev_ocp.safety.bound`` loads the bound only.

Python API (SI)::

    from aev_ocp.safety import braking_bound, safe_acceleration_mps2
    braking_bound(25.0, 8.0, 25.0, -9.0)            # BrakingBound(min_gap_m=3.66, ..., label='avoidable')
    from aev_ocp.safety.suite import run_suite
    out = run_suite(quick=True); out.failures("mpc")
"""

from __future__ import annotations

import importlib
from typing import Any

#: name -> submodule that defines it
_EXPORTS = {
    "AVOIDABLE": "kinematics",
    "COLLISION_AVOIDABLE_ONLY": "kinematics",
    "LABELS": "kinematics",
    "UNAVOIDABLE": "kinematics",
    "BrakingBound": "kinematics",
    "braking_bound": "kinematics",
    "label_of": "kinematics",
    "SafetyParams": "bound",
    "safe_acceleration_mps2": "bound",
    "SafeFallback": "fallback",
}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'aev_ocp.safety' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

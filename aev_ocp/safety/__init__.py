"""Safety: a suite of rear-end and cut-in cases, and the safety names of the layers below under one roof.

* :func:`braking_bound` (:mod:`aev_ocp.models.braking`): the smallest gap when the ego brakes at its maximum from
  t = 0 (pure physics, exact piecewise), and the labels avoidable / collision-avoidable only / unavoidable.
* :func:`safe_acceleration_mps2` (:mod:`aev_ocp.models.safety_bound`): the largest acceleration that keeps the
  braking-distance condition over the next step, else maximal braking (pure physics; the closed loop's safety
  stage uses it);
* :class:`SafeFallback` (:mod:`aev_ocp.mpc.safe_fallback`): that bound as a controller; the MPC's fallback and
  safety filter.
* :mod:`.cases`, :mod:`.run`, :mod:`.report`, :mod:`.section`, :mod:`.cli` — the suite, its section of
  ``aev-ocp reproduce`` and the ``aev-ocp safety`` command; never imported here (docs/guide/layers.md). The names
  below are imported on first use, so ``import aev_ocp.safety`` loads no physics until a name is used.

Python API (SI)::

    from aev_ocp.safety import braking_bound, safe_acceleration_mps2
    braking_bound(25.0, 8.0, 25.0, -9.0)            # BrakingBound(min_gap_m=3.66, ..., label='avoidable')
    from aev_ocp.safety.run import run_suite
    out = run_suite(quick=True); out.failures("mpc")
"""

from __future__ import annotations

from ..lazy import lazy_exports

#: name -> module that defines it
_EXPORTS = {
    "AVOIDABLE": "aev_ocp.models.braking",
    "COLLISION_AVOIDABLE_ONLY": "aev_ocp.models.braking",
    "LABELS": "aev_ocp.models.braking",
    "UNAVOIDABLE": "aev_ocp.models.braking",
    "BrakingBound": "aev_ocp.models.braking",
    "braking_bound": "aev_ocp.models.braking",
    "label_of": "aev_ocp.models.braking",
    "SafetyParams": "aev_ocp.models.safety_bound",
    "safe_acceleration_mps2": "aev_ocp.models.safety_bound",
    "SafeFallback": "aev_ocp.mpc.safe_fallback",
}
__all__ = list(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

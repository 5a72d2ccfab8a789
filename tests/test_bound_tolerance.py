"""One tolerance for 'beyond a bound': a sample counts as below a controller's hard gap floor (status 'violated', the
metrics' gap_violations, the MPC table's counts) or beyond a speed bound only when it is beyond by more than the
tolerance the controller's plans are accepted with (aev_ocp.plant.PLAN_TOLERANCE), on, inside and outside it."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from aev_ocp.control import ClosedLoop, Command, Observation
from aev_ocp.models import ConstantSpeed
from aev_ocp.metrics import vehicle_metrics
from aev_ocp.ocp.formulation import ModelBounds
from aev_ocp.params import UNLIMITED, EVParams, Units
from aev_ocp.plant import PLAN_TOLERANCE, floor_violations
from aev_ocp.numerics import BOUND_TOLERANCE


def test_the_plants_acceptance_and_the_counts_share_one_number() -> None:
    assert PLAN_TOLERANCE == BOUND_TOLERANCE == pytest.approx(1e-6, rel=0)


@pytest.mark.parametrize(
    ("below_model", "counted"),
    [
        (2.3e-9, False),  # the §9 UDDS run's 3.5e-8 m under a 3 m floor at L = 15 m: a solver's rounding
        (0.73 * BOUND_TOLERANCE, False),  # inside the tolerance
        (BOUND_TOLERANCE, False),  # on it: not beyond it
        (1.37 * BOUND_TOLERANCE, True),  # outside
        (4.1e-3, True),
    ],
)
def test_floor_counted_only_beyond_the_tolerance(below_model: float, counted: bool) -> None:
    units = Units(15.0, 17.0)
    h_min = 0.2
    t = np.linspace(0.0, 2.7, 10)
    gap = np.full((10, 1), 0.31)
    gap[4:6, 0] = h_min - below_model  # two samples at the depth, the rest well above the floor
    ev = floor_violations(t, gap, [{"bounds_model": {"h_min": h_min}}], units)
    assert bool(ev) is counted
    if counted:
        assert ev[0].time == pytest.approx(t[4], rel=0, abs=0) and "in 2 samples" in ev[0].message


@pytest.mark.parametrize(("beyond", "counted"), [(0.6e-6, 0), (1e-6, 0), (1.8e-6, 2)])
def test_mpc_tables_count_gap_and_speed_against_the_same_tolerance(beyond: float, counted: int) -> None:
    """aev_ocp.mpc.run's counts of a run's samples against the formulation's bounds: gap below h_min and speed above
    v_max, each by ``beyond`` in two samples."""
    from types import SimpleNamespace

    from aev_ocp.mpc.run import _violations

    h_min, v_max = 0.2, 1.6
    gap = np.full((8, 1), 0.5)
    speed = np.full((8, 1), 0.93)
    gap[2:4, 0] = h_min - beyond
    speed[5:7, 0] = v_max + beyond
    r = SimpleNamespace(gap=gap, speed=speed)
    b = ModelBounds(h_min=h_min, v_min=0.0, v_max=v_max, a_min=None, a_max=None)
    assert _violations(r, 0, b) == (counted, counted)  # type: ignore[arg-type]


class _Brake:
    """A sampled controller that brakes at a constant rate [model] and publishes a hard gap floor h_min [model]."""

    name, dt = "brake", 0.1

    def __init__(self, h_min: float) -> None:
        self.h_min = h_min

    def reset(self) -> None:
        pass

    def command(self, obs: Observation) -> Command:
        return Command(0.2)

    def describe(self) -> dict[str, Any]:
        return {"controller": self.name, "bounds_model": {"h_min": self.h_min, "v_max": 9.0}}


def test_vehicle_metrics_count_against_the_same_tolerance() -> None:
    """The per-vehicle metrics of a closed loop whose gap goes below its controller's floor, its samples then set
    to 2.3e-9 under the floor at one sample and 3.1e-6 under it at another: one counted sample, not two."""
    h_min = 1.35
    with pytest.warns(RuntimeWarning, match="violated its gap floor"):
        r = ClosedLoop(ConstantSpeed(1.0), [_Brake(h_min)], EVParams(limits=UNLIMITED)).run([2.0], [1.0], 4.0)
    h = r.gap[:, 0].copy()
    k = np.flatnonzero(h[1:] < h_min - BOUND_TOLERANCE) + 1
    assert k.size > 2 and vehicle_metrics(r, 0)["gap_violations"] == k.size
    r.gap[:, 0] = np.where(h < h_min, h_min + 0.01, h)  # every sample above the floor ...
    r.gap[k[0], 0] = h_min - 2.3e-9  # ... but one just under it (inside the tolerance)
    r.gap[k[1], 0] = h_min - 3.1e-6  # and one beyond it
    assert vehicle_metrics(r, 0)["gap_violations"] == 1

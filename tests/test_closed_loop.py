"""The closed loop's inputs (aev_ocp.control.ClosedLoop): a controller with a bad sampling period or a non-finite
command is refused naming it (a NaN command was once saturated into full braking without a word), NumPy scalars and
one-element arrays are taken like floats, and a finite command is applied exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aev_ocp.control import ClosedLoop, Command
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.params import ParameterError


# ----------------------------------------------------------------------------- ClosedLoop
class Held:
    """A user controller holding a (returned as given) every dt."""

    name = "held"

    def __init__(self, a: object, dt: object = 0.1) -> None:
        self.a, self.dt = a, dt

    def reset(self) -> None:
        pass

    def describe(self) -> dict:
        return {"controller": self.name}

    def command(self, obs: object) -> object:
        return Command(self.a)  # type: ignore[arg-type]


LEADER = ConstantSpeed(1.3)


@pytest.mark.parametrize("dt", [0.0, -0.1, math.nan, math.inf, True, "0.1", None])
def test_closed_loop_refuses_a_bad_sampling_period(dt: object) -> None:
    with pytest.raises(ParameterError, match=r"controller 'held' of vehicle 1: dt = .* not allowed"):
        ClosedLoop(LEADER, [Held(0.0, dt)])


@pytest.mark.parametrize("a", [math.nan, math.inf, -math.inf, True, "fast", [0.1, 0.2]])
def test_closed_loop_refuses_a_non_finite_command(a: object) -> None:
    with pytest.raises(ParameterError, match=r"controller 'held' of vehicle 1 returned Command\(a = .*\) at t = 0"):
        ClosedLoop(LEADER, [Held(a)]).run([2.5], [1.3], 0.5)


def test_closed_loop_refuses_a_non_command() -> None:
    class Bare(Held):
        def command(self, obs: object) -> object:
            return None

    with pytest.raises(ParameterError, match=r"returned NoneType None at t = 0: command\(\) must return a Command"):
        ClosedLoop(LEADER, [Bare(0.0)]).run([2.5], [1.3], 0.5)


def test_closed_loop_applies_a_finite_command_exactly() -> None:
    """A held -0.35 (model units; -0.875 m/s², inside the default limits) from v = 1.3 behind a leader far ahead:
    v(t) = 1.3 - 0.35 t at every node (closed form), numpy scalars accepted like floats."""
    r = ClosedLoop(LEADER, [Held(np.float32(-0.35))]).run([4.5], [1.3], 1.0)
    t = np.asarray(r.t)
    nodes = np.isclose(t[:, None], np.arange(0, 1.01, 0.1)[None, :], atol=1e-9).any(axis=1)
    np.testing.assert_allclose(np.asarray(r.speed)[nodes, 0], 1.3 - float(np.float32(0.35)) * t[nodes], atol=1e-8)


@pytest.mark.parametrize(
    ("a", "dt"),
    [(np.array(-0.35), np.float32(0.125)), (np.array([-0.35]), np.int64(1)), (np.float64(-0.35), np.float64(0.1))],
)
def test_closed_loop_takes_numpy_scalars_and_one_element_arrays_like_floats(a: object, dt: object) -> None:
    """What np.clip/np.minimum give (0-d arrays) and NumPy scalar periods run exactly as the plain floats do: the
    same speeds at every sample (they ran before the checks that refuse NaN commands were added)."""
    plain = ClosedLoop(LEADER, [Held(-0.35, float(dt))]).run([4.5], [1.3], 1.0)  # type: ignore[arg-type]
    r = ClosedLoop(LEADER, [Held(a, dt)]).run([4.5], [1.3], 1.0)
    np.testing.assert_array_equal(np.asarray(r.speed), np.asarray(plain.speed))
    np.testing.assert_array_equal(np.asarray(r.gap), np.asarray(plain.gap))


@pytest.mark.parametrize("a", [np.array(math.nan), np.array([0.1, 0.2]), np.array(True), np.array("x")])
def test_closed_loop_refuses_arrays_that_are_not_one_finite_number(a: object) -> None:
    with pytest.raises(ParameterError, match=r"controller 'held' of vehicle 1 returned Command\(a = .*\) at t = 0"):
        ClosedLoop(LEADER, [Held(a)]).run([2.5], [1.3], 0.5)

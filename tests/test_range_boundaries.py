"""Every declared range of the package (``spec(...)`` in any dataclass under aev_ocp, found by walking the package,
not listed by hand) behaves as its declaration says at the limit: a closed limit (ge/le) accepts the value exactly at
it, an open one (gt/lt) refuses it naming class, field and value; a value just inside is accepted, just outside
refused. Fields tied to another field by a cross-field rule are tried with that field moved out of the way. Plus a
declared cross-field limit: an output interval equal to the run's length."""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil

import pytest

import aev_ocp
from aev_ocp.params import ParameterError, field_checks
from aev_ocp.scenarios import ScenarioError, parse_scenario

#: other fields set so that the field under test alone decides (cross-field rules: target_gap_m ≥ standstill_gap_m,
#: ego_brake_mps2 ≤ −a_min_mps2)
COMPANIONS = {
    ("TrafficParams", "target_gap_m"): {"standstill_gap_m": 1e-7},
    ("SafetyParams", "a_min_mps2"): {"ego_brake_mps2": 1e-9},
    # T_max_K > ambient_K; the SUMO ring's cars fit on it and start at most at the lane's speed
    ("ThermalParams", "T_max_K"): {"ambient_K": 1e-9},
    ("ThermalParams", "ambient_K"): {"T_max_K": 1000.0},
    ("RingNetwork", "length_m"): {"vehicles": 1, "vehicle_length_m": 1e-9},
    ("RingNetwork", "vehicle_length_m"): {"length_m": 1e5},
    ("RingNetwork", "speed0_mps"): {"lane_speed_mps": 100.0},
    # a hold's upper side needs its latch speed (hold_min_mps > 0); its release speed is below that latch speed
    ("WaveParams", "hold_max_mps"): {"hold_min_mps": 1e-9},
    ("WaveParams", "hold_release_mps"): {"hold_min_mps": 100.0},
}
#: limits that a cross-field rule makes unreachable with any companion (charging must start after a trip at
#: >= 0 h, so charge_start_h = 0 is refused by that rule whatever the trips; a jerk limit is 0 (off) or >= 0.1 m/s³,
#: so the values just above 0 are refused by that rule, tested on, inside and outside 0.1 in test_loop_core.py)
UNREACHABLE = {("DailySchedule", "charge_start_h", "ge"), ("VehicleLimits", "command_jerk_max_mps3", "ge")}


def _declared_classes() -> list[type]:
    found: dict[str, type] = {}
    for m in pkgutil.walk_packages(aev_ocp.__path__, "aev_ocp."):
        try:
            mod = importlib.import_module(m.name)
        except ImportError:  # an optional extra that is not installed
            continue
        for v in vars(mod).values():
            if isinstance(v, type) and dataclasses.is_dataclass(v) and v.__module__ == mod.__name__:
                checks = field_checks(v)
                if any(c.kind in ("number", "integer") for c in checks.values()):
                    found[f"{v.__module__}.{v.__qualname__}"] = v
    return [found[k] for k in sorted(found)]


CLASSES = _declared_classes()


def _limits(cls: type):
    for name, c in field_checks(cls).items():
        if c.kind not in ("number", "integer"):
            continue
        for op, bound, sign in (("gt", c.gt, +1), ("ge", c.ge, +1), ("lt", c.lt, -1), ("le", c.le, -1)):
            if bound is not None:
                yield name, c, op, bound, sign


def test_the_walk_finds_the_declared_classes() -> None:
    names = {c.__name__ for c in CLASSES}
    assert {"CellParams", "SafetyParams", "TrafficParams", "DailySchedule", "Sensors", "MPCSettings"} <= names
    assert sum(1 for c in CLASSES for _ in _limits(c)) > 60


@pytest.mark.parametrize("cls", CLASSES, ids=[c.__name__ for c in CLASSES])
def test_every_limit_on_inside_and_outside(cls: type) -> None:
    cls()  # the defaults are valid
    for name, c, op, bound, sign in _limits(cls):
        d = 1 if c.kind == "integer" else max(abs(bound), 1.0) * 1e-6
        on, inside, outside = bound, bound + sign * d, bound - sign * d
        if c.kind == "integer":
            on, inside, outside = int(on), int(inside), int(outside)
        strict = op in ("gt", "lt")
        # the declaration itself
        assert (c.problem(on) is None) is (not strict), (cls.__name__, name, op, on)
        assert c.problem(inside) is None and c.problem(outside) is not None, (cls.__name__, name, op)
        if (cls.__name__, name, op) in UNREACHABLE:
            continue
        extra = COMPANIONS.get((cls.__name__, name), {})
        pattern = rf"^{cls.__name__}\.{name} = "
        cls(**extra, **{name: inside})
        with pytest.raises(ParameterError, match=pattern):
            cls(**extra, **{name: outside})
        if strict:
            with pytest.raises(ParameterError, match=pattern):
                cls(**extra, **{name: on})
        else:
            assert getattr(cls(**extra, **{name: on}), name) == on


DOC = {
    "leader": {"kind": "constant", "v": 1.3},
    "platoon": {"followers": 1, "gap0_first": 1.1, "speed0": 1.3},
    "simulation": {"t_end": 2.7},
}


@pytest.mark.parametrize("dt_out, ok", [(2.7, True), (2.7 * (1 - 1e-9), True), (2.7 * (1 + 1e-9), False)])
def test_an_output_interval_equal_to_the_runs_length_is_allowed(dt_out: float, ok: bool) -> None:
    """simulation.dt_out ≤ t_end: on the limit (one interval: the first and the last sample), inside, outside."""
    doc = {k: dict(v) for k, v in DOC.items()}
    doc["simulation"]["dt_out"] = dt_out
    if not ok:
        with pytest.raises(ScenarioError, match=r"^d\.toml: simulation\.dt_out = .*must be <= the horizon"):
            parse_scenario(doc, "d.toml")
        return
    sc = parse_scenario(doc, "d.toml")
    assert sc.dt_out == dt_out and sc.t_end == 2.7

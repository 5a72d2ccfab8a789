"""Battery life's read-out (aev_ocp/life.py ``life_from_model``) on hand-made capacity and resistance curves with
known crossings: years to 80 % by linear interpolation between the two samples around the first crossing (on,
inside and outside the limit: a sample exactly at 80 %, a crossing between samples, never below, below from the
start), and the capacity and resistance after 1/5/10 years; no BLAST-Lite needed (a model object with its
``stressors`` and ``outputs``)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from aev_ocp.life import END_OF_LIFE, life_from_model


def _model(years: list[float], q: list[float], r: list[float] | None = None) -> SimpleNamespace:
    out = {"q": np.array(q)}
    if r is not None:
        out["r"] = np.array(r)
    return SimpleNamespace(stressors={"t_days": np.array(years) * 365.0}, outputs=out)


# uneven sample times and a curve that bends: a wrong pair of samples or a swapped order shows
YEARS = [0.0, 0.4, 1.3, 2.9, 4.6, 7.7, 9.1, 11.0]
Q = [1.0, 0.981, 0.953, 0.904, 0.861, 0.793, 0.771, 0.742]
R = [1.0, 1.013, 1.041, 1.097, 1.152, 1.238, 1.271, 1.323]


def test_years_to_80_percent_is_the_linear_crossing_between_its_two_samples() -> None:
    out = life_from_model(_model(YEARS, Q, R), 11.0)
    # first below 0.8: index 5 (7.7 y, 0.793); before it 4.6 y at 0.861: 4.6 + (0.861 − 0.8)/(0.861 − 0.793) × 3.1
    expected = 4.6 + (0.861 - 0.8) / (0.861 - 0.793) * (7.7 - 4.6)
    assert out["years_to_80pct"] == pytest.approx(expected, rel=1e-13)
    assert out["years_simulated"] == pytest.approx(11.0, rel=1e-15)


def test_capacity_and_resistance_after_1_5_10_years() -> None:
    out = life_from_model(_model(YEARS, Q, R), 11.0)
    for y, (k0, k1) in ((1.0, (1, 2)), (5.0, (4, 5)), (10.0, (6, 7))):
        w = (y - YEARS[k0]) / (YEARS[k1] - YEARS[k0])
        assert out[f"capacity_{y:g}y"] == pytest.approx(Q[k0] + w * (Q[k1] - Q[k0]), rel=1e-13)
        assert out[f"resistance_{y:g}y"] == pytest.approx(R[k0] + w * (R[k1] - R[k0]), rel=1e-13)
    short = life_from_model(_model(YEARS[:6], Q[:6]), 7.7)  # 10 years not simulated: NaN, not extrapolated
    assert math.isnan(short["capacity_10y"]) and math.isnan(short["resistance_5y"])
    assert short["capacity_5y"] == pytest.approx(out["capacity_5y"], rel=1e-15)


def test_the_80_percent_limit_on_inside_and_outside() -> None:
    on = [1.0, 0.93, END_OF_LIFE, 0.77, 0.74]  # exactly 80 % at 2.0 y: that sample is the crossing
    assert life_from_model(_model([0.0, 1.0, 2.0, 3.5, 5.0], on), 5.0)["years_to_80pct"] == pytest.approx(2.0)
    inside = [1.0, 0.93, 0.8 + 1e-9, 0.77, 0.74]  # just above at 2.0 y: the crossing just after it
    y = life_from_model(_model([0.0, 1.0, 2.0, 3.5, 5.0], inside), 5.0)["years_to_80pct"]
    assert 2.0 < y < 2.0 + 1e-6
    never = [1.0, 0.95, 0.9, 0.85, 0.81]
    assert life_from_model(_model([0.0, 1.0, 2.0, 3.5, 5.0], never), 5.0)["years_to_80pct"] == math.inf
    at_start = [0.79, 0.75, 0.7]
    assert life_from_model(_model([0.0, 1.0, 2.0], at_start), 2.0)["years_to_80pct"] == 0.0

"""``.plot()`` of SimulationResult, OCPResult and StudyOutput: a matplotlib Figure whose axes carry SI units and
whose lines are the object's numbers (converted with its units, averaged per axis value: computed here again)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from aev_ocp.models.carfollowing import OVFL
from aev_ocp.models.leader import PaperLeader
from aev_ocp.ocp_result import OCPResult
from aev_ocp.params import UNLIMITED, EVParams, Units
from aev_ocp.saved import StudyOutput
from aev_ocp.simulate import simulate_platoon


def _labels(fig: Figure) -> set[str]:
    return {ax.get_ylabel() for ax in fig.axes} | {ax.get_xlabel() for ax in fig.axes} - {""}


@pytest.fixture(scope="module")
def run():
    units = Units(length_m=7.5, speed_mps=3.0)  # distinct, non-special units: T = 2.5 s
    ev = EVParams(units=units, limits=UNLIMITED)
    return simulate_platoon(PaperLeader(), [OVFL()] * 2, [0.9, 1.3], [1.5, 1.6], 3.0, ev=ev, dt_out=0.05)


def test_simulation_result_plots_in_si(run) -> None:
    fig = run.plot()
    assert isinstance(fig, Figure)
    labels = _labels(fig)
    for want in ("gap [m]", "speed [km/h]", "acceleration [m/s²]", "t [s]", "pack heat ∫Q dt [J]"):
        assert want in labels, labels
    gap_ax = next(ax for ax in fig.axes if ax.get_ylabel() == "gap [m]")
    x, y = gap_ax.lines[0].get_data()
    assert np.allclose(x, 2.5 * run.t) and np.allclose(y, 7.5 * run.gap[:, 0])  # T = L/U = 2.5 s, L = 7.5 m
    speed_ax = next(ax for ax in fig.axes if ax.get_ylabel() == "speed [km/h]")
    assert np.allclose(speed_ax.lines[1].get_ydata(), 3.0 * 3.6 * run.speed[:, 1])  # U = 3 m/s in km/h
    model = _labels(run.plot(si=False))
    assert "gap [model length]" in model and "t [model time]" in model


def _ocp_result() -> OCPResult:
    N = 7
    t = np.linspace(0.0, 21.0, N + 1)
    return OCPResult(
        problem="eco-trip",
        method="ms",
        N=N,
        t=t,
        time_unit="s",
        states={"x": 0.7 * t**2, "v": 1.4 * t},
        controls={"a": np.full(N, 1.4)},
        outputs={"I": 3.3 * np.sin(t)},
        objective=12.5,
        objective_name="heat",
        status="optimal",
        success=True,
        message="",
        solver_status="Solve_Succeeded",
        iterations=9,
        wall_time_s=0.1,
        solver_time_s=0.1,
        max_violation=0.0,
    )


def test_ocp_result_plots_every_quantity_with_its_unit() -> None:
    res = _ocp_result()
    fig = res.plot()
    assert isinstance(fig, Figure)
    labels = _labels(fig)
    for want in ("position x [m]", "speed v [m/s]", "acceleration a [m/s²]", "cell current I [A]", "t [s]"):
        assert want in labels, labels
    a_ax = next(ax for ax in fig.axes if ax.get_ylabel() == "acceleration a [m/s²]")
    assert np.allclose(a_ax.lines[0].get_ydata(), 1.4)  # the control as steps (N values, the last repeated)
    only = res.plot(names=["v"])
    assert [ax.get_ylabel() for ax in only.axes if ax.lines] == ["speed v [m/s]"]


def _rows() -> list[dict]:
    rows = []
    for seed, (e_a, e_b) in {11: (14.2, 15.1), 12: (13.6, 15.9), 13: (14.9, 16.4)}.items():
        for point in (0, 1):  # a second axis value: the line goes through the mean of both points per seed
            for ctrl, e in (("proposed", e_a + 0.3 * point), ("mpc", e_b - 0.2 * point)):
                rows.append(
                    {
                        "point": point,
                        "controller": ctrl,
                        "vehicle": 1,
                        "sensors.seed": seed,
                        "comparable": ctrl != "mpc",
                    }
                    | {"battery_energy_kWh_per_100km": e, "min_gap_m": 2.0 + point}
                )
                rows.append(dict(rows[-1], vehicle=2, battery_energy_kWh_per_100km=99.0))  # another follower
    return rows


def test_study_output_plots_a_metric_against_its_first_axis(tmp_path: Path) -> None:
    rows = _rows()
    out = StudyOutput(tmp_path, rows, [], 12, 0, {"settings": {"axes": [{"keys": ["sensors.seed"], "kind": "grid"}]}})
    fig = out.plot()
    assert isinstance(fig, Figure)
    (ax,) = fig.axes
    assert ax.get_xlabel() == "sensors.seed" and ax.get_ylabel() == "battery_energy_kWh_per_100km"
    for line in ax.lines:
        want = [
            np.mean(
                [
                    r["battery_energy_kWh_per_100km"]
                    for r in rows
                    if r["controller"] == line.get_label() and r["vehicle"] == 1 and r["sensors.seed"] == s
                ]
            )
            for s in (11, 12, 13)
        ]
        assert list(line.get_xdata()) == [11, 12, 13] and np.allclose(line.get_ydata(), want)
    assert sorted(line.get_label() for line in ax.lines) == ["mpc", "proposed"]
    g = out.plot("min_gap_m", axis="point", vehicle=2)
    assert g.axes[0].get_xlabel() == "point" and g.axes[0].get_ylabel() == "min_gap_m"
    with pytest.raises(ValueError, match="metric = 'no_such_m'"):
        out.plot("no_such_m")
    # without axes in its settings: against the point index
    assert StudyOutput(tmp_path, rows, [], 12, 0, {}).plot().axes[0].get_xlabel() == "point"
    assert math.isfinite(float(np.nanmax(g.axes[0].lines[0].get_ydata())))

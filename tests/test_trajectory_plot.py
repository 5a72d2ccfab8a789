"""One trajectory plot for every controller (issue 7 item 7): aev_ocp.plots.plot_trajectories draws closed-form
laws and MPC runs alike (sampled controls as steps) and keeps large platoons drawable."""

from __future__ import annotations

import numpy as np
import pytest

import aev_ocp.mpc.plots as mpc_plots
import aev_ocp.plots as plots
from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.simulate import simulate_platoon


def _capture(monkeypatch: pytest.MonkeyPatch) -> list:
    figs: list = []
    real = plots.save_figure

    def keep(fig, path):  # noqa: ANN001, ANN202
        figs.append((fig, [ax.get_ylabel() for ax in fig.axes], [len(ax.lines) for ax in fig.axes]))
        return real(fig, path)

    monkeypatch.setattr(plots, "save_figure", keep)
    return figs


def test_mpc_module_has_no_second_trajectory_plot() -> None:
    assert not hasattr(mpc_plots, "plot_trajectories")


def test_one_plot_for_a_law_run_and_a_sampled_run(tmp_path, monkeypatch) -> None:
    figs = _capture(monkeypatch)
    r = simulate_platoon(ConstantSpeed(1.3), [Proposed(), OVFL()], [1.1, 1.6], [1.2, 1.25], 2.0, dt_out=0.1)
    fig = plots.plot_trajectories(r, p := tmp_path / "law.png")
    assert fig is figs[-1][0]  # the figure drawn is the one returned
    assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    labels = figs[-1][1]
    assert any("acceleration" in lab for lab in labels) and any("current" in lab for lab in labels)
    assert any("state of charge" in lab for lab in labels) and figs[-1][2][0] == 2 + 1  # 2 gaps + h = 0 line
    acc_axis = next(i for i, lab in enumerate(figs[-1][1]) if "acceleration" in lab)
    assert figs[-1][0].axes[acc_axis].lines[0].get_drawstyle() == "default"
    r.jerk_sampled = True  # a sampled controller's piecewise-constant control is drawn as steps
    plots.plot_trajectories(r, tmp_path / "sampled.png")
    acc_axis = next(i for i, lab in enumerate(figs[-1][1]) if "acceleration" in lab)
    line = figs[-1][0].axes[acc_axis].lines[0]
    assert line.get_drawstyle() == "steps-post" and np.asarray(line.get_xdata()).size == r.t.size


def test_large_platoon_is_drawn_as_an_even_subset(tmp_path, monkeypatch) -> None:
    figs = _capture(monkeypatch)
    n = 137
    r = simulate_platoon(ConstantSpeed(1.0), [Proposed()] * n, [1.5] * n, [1.0] * n, 0.5, dt_out=0.25)
    plots.plot_trajectories(r, tmp_path / "big.png")
    assert figs[-1][2][0] == plots.MAX_TRAJECTORY_LINES + 1

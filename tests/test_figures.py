"""Figures a journal would print (issue 10 item 5): SI axes through the scenario's units (model units on
request), space-time diagrams, overlays where no controller hides another, real fallbacks only, the
signed % change of Table 1, Prop 3.1's numerically-zero currents with W(t), the OCP-B sweep as % saving.

Plotted data are read back from the matplotlib artists and compared with numbers computed here by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import aev_ocp.mpc.plots as mpc_plots
import aev_ocp.ocp.plots as ocp_plots
import aev_ocp.plots as plots
from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import ConstantSpeed, PaperLeader
from aev_ocp.ocp_result import OCPResult
from aev_ocp.params import CellParams, EVParams, Units
from aev_ocp.simulate import simulate_platoon

UNITS = Units(length_m=12.5, speed_mps=7.3)  # distinct, non-default units


@pytest.fixture()
def figs(monkeypatch: pytest.MonkeyPatch) -> list:
    """Every figure written through plots.save_figure (the modules share it), kept open for inspection."""
    kept: list = []
    real = plots.save_figure

    def keep(fig, path):  # noqa: ANN001, ANN202
        kept.append(fig)
        return real(fig, path)

    for mod in (plots, mpc_plots, ocp_plots):
        monkeypatch.setattr(mod, "save_figure", keep)
    return kept


@pytest.fixture(scope="module")
def run():  # noqa: ANN201
    return simulate_platoon(
        PaperLeader(), [Proposed()] * 3, [0.7, 2.9, 3.1], [1.8, 1.75, 1.72], 6.0, ev=EVParams(units=UNITS), dt_out=0.05
    )


def _axis(fig, word: str):  # noqa: ANN001, ANN202
    return next(ax for ax in fig.axes if word in ax.get_ylabel())


def test_axis_units_are_the_scenarios_si_units() -> None:
    au = plots.AxisUnits.of(UNITS)
    assert (au.t, au.x, au.v, au.a) == pytest.approx((12.5 / 7.3, 12.5, 7.3 * 3.6, 7.3**2 / 12.5))
    assert (au.t_label, au.x_label, au.v_label) == ("s", "m", "km/h")
    assert plots.AxisUnits.of(UNITS, si=False).v == 1.0


@pytest.mark.parametrize("si", [True, False])
def test_trajectories_in_si_or_model_units(run, figs, tmp_path, si: bool) -> None:  # noqa: ANN001
    plots.plot_trajectories(run, tmp_path / "t.png", si=si, h_min=0.35)
    fig = figs[-1]
    gap_ax, speed_ax = _axis(fig, "gap"), _axis(fig, "speed")
    kx, kv, kt = (12.5, 7.3 * 3.6, 12.5 / 7.3) if si else (1.0, 1.0, 1.0)
    line = gap_ax.lines[1]
    np.testing.assert_allclose(line.get_ydata(), kx * run.gap[:, 1])
    np.testing.assert_allclose(line.get_xdata(), kt * run.t)
    leader = next(ln for ln in speed_ax.lines if ln.get_label() == "leader")
    np.testing.assert_allclose(leader.get_ydata(), kv * run.leader_speed)
    assert ("[km/h]" in speed_ax.get_ylabel()) == si and ("[s]" in fig.axes[-1].get_xlabel()) == si
    labels = [t.get_text() for t in gap_ax.get_legend().get_texts()]
    assert any(lab.startswith("h_min") for lab in labels)
    h_line = next(ln for ln in gap_ax.lines if str(ln.get_label()).startswith("h_min"))
    assert h_line.get_ydata()[0] == pytest.approx(kx * 0.35)


def test_space_time_diagram_is_the_positions(run, figs, tmp_path) -> None:  # noqa: ANN001
    plots.plot_space_time(run, path := tmp_path / "st.png")
    assert path.read_bytes()[:4] == b"\x89PNG"
    ax = figs[-1].axes[0]
    segs = [np.asarray(c.get_segments()) for c in ax.collections]
    assert len(segs) == 3
    x_hand = UNITS.length_m * (run.leader_position[:, None] - np.cumsum(run.gap, axis=1))
    for i, s in enumerate(segs):
        np.testing.assert_allclose(s[:, 0, 1], x_hand[:-1, i])
        np.testing.assert_allclose(s[:, 1, 0], run.t[1:] * UNITS.time_s)
        np.testing.assert_allclose(ax.collections[i].get_array(), run.speed[:-1, i] * UNITS.speed_mps * 3.6)
    leader = next(ln for ln in ax.lines if ln.get_label() == "leader")
    np.testing.assert_allclose(leader.get_ydata(), UNITS.length_m * run.leader_position)
    assert np.all(x_hand[:, 0] < UNITS.length_m * run.leader_position)  # followers are behind the leader


def test_space_time_diagram_of_a_long_run_draws_every_kth_sample_and_the_last(run, figs, tmp_path, monkeypatch) -> None:  # noqa: ANN001,E501
    n = run.t.size
    monkeypatch.setattr(plots, "SPACE_TIME_MAX_POINTS", 7)  # fewer than the run's samples: thinned
    plots.plot_space_time(run, tmp_path / "st.png")
    k = -(-n // 7)
    keep = sorted({*range(0, n, k), n - 1})
    assert n > len(keep) and len(keep) <= 8
    x_hand = UNITS.length_m * (run.leader_position[:, None] - np.cumsum(run.gap, axis=1))
    ax = figs[-1].axes[0]
    for i, c in enumerate(ax.collections):
        s = np.asarray(c.get_segments())
        np.testing.assert_allclose(s[:, 0, 1], x_hand[keep[:-1], i])  # each segment from a kept sample
        np.testing.assert_allclose(s[:, 1, 0], run.t[keep[1:]] * UNITS.time_s)  # to the next, the last included
        np.testing.assert_allclose(c.get_array(), run.speed[keep[:-1], i] * UNITS.speed_mps * 3.6)


def test_overlay_styles_are_distinct_and_legend_names_leader_and_h_min(run, figs, tmp_path) -> None:  # noqa: ANN001
    labels = ["mpc", "proposed", "ovfl", "my law", "another law", "ocp-d"]
    styles = plots.controller_styles(labels)
    pairs = {(s["color"], str(s["ls"])) for s in styles.values()}
    assert len(pairs) == len(labels)
    results = {lab: run for lab in labels[:4]}  # identical runs: only the styles tell them apart
    mpc_plots.plot_overlay(results, tmp_path / "o.png", vehicle=0, h_min=0.41)
    fig = figs[-1]
    # Line2D has no public getter of the dash sequence; _dash_pattern is (offset, on/off lengths)
    got = {
        ln.get_label(): (ln.get_color(), str(ln._dash_pattern)) for ln in fig.axes[0].lines if ln.get_label() in labels
    }
    assert len(set(got.values())) == 4  # four controllers, four distinct (colour, dash) pairs
    widths = [ln.get_linewidth() for ln in fig.axes[0].lines if ln.get_label() in labels]
    assert widths == sorted(widths, reverse=True) and len(set(widths)) == 4  # each drawn over a wider one
    speed_legend = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    gap_legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "leader" in speed_legend and any(t.startswith("h_min = ") and "m" in t for t in gap_legend)
    h = next(ln for ln in fig.axes[0].lines if str(ln.get_label()).startswith("h_min"))
    assert h.get_ydata()[0] == pytest.approx(0.41 * UNITS.length_m)


def _with_steps(r, ok: list[bool], status: list[str]):  # noqa: ANN001, ANN202
    steps = {"solve_ms": list(np.linspace(0.7, 1.9, len(ok))), "status": status, "ok": ok, "iterations": [1] * len(ok)}
    return dataclasses.replace(
        r, meta={**r.meta, "mpc_steps": [steps, None, None]}, solver_stats=[{"solver_path": "rti"}, None, None]
    )


def test_solve_time_plot_marks_only_real_fallbacks(run, figs, tmp_path) -> None:  # noqa: ANN001
    k = 9
    # an RTI step reports its QP status, not IPOPT's "Solve_Succeeded": none of these is a fallback
    r = _with_steps(run, [True] * k, ["QP_SOLVED"] * k)
    mpc_plots.plot_solve_times(r, tmp_path / "s.png")
    ax = figs[-1].axes[0]
    assert not [ln for ln in ax.lines if "fallback" in str(ln.get_label())]
    assert "0 fallback" in ax.get_title()
    ok = [True] * k
    ok[2] = ok[6] = False
    r = _with_steps(run, ok, ["Solve_Succeeded"] * k)  # ok is the criterion, whatever the string says
    mpc_plots.plot_solve_times(r, tmp_path / "s2.png")
    ax = figs[-1].axes[0]
    marks = [ln for ln in ax.lines if "fallback" in str(ln.get_label())]
    assert len(marks) == 1 and marks[0].get_xdata().size == 2
    np.testing.assert_allclose(marks[0].get_xdata(), run.t[[2, 6]] * UNITS.time_s)
    assert "2 fallback" in ax.get_title()
    with pytest.raises(KeyError, match="ok"):
        mpc_plots.fallback_steps({"status": ["x"]})


def test_percent_change_bars_keep_their_sign(figs, tmp_path) -> None:  # noqa: ANN001
    ours, paper = [-1.37, -2.11, 0.83], [-1.56, -2.67, -3.47]
    plots.plot_percent_change(ours, paper, tmp_path / "pc.png")
    ax = figs[-1].axes[0]
    heights = [p.get_height() for p in ax.patches]
    np.testing.assert_allclose(heights, ours + paper)
    texts = [t.get_text() for t in ax.texts]
    assert "+0.83%" in texts and "-3.47%" in texts


def _ocp_result(I: np.ndarray, V1: np.ndarray, V2: np.ndarray, J: float) -> OCPResult:
    t = np.linspace(0.0, 60.0, I.size + 1)
    base = OCPResult.failed("ocp_a", "ms", I.size, "optimal", 0.1, t, "s")
    return dataclasses.replace(
        base,
        states={"V1": V1, "V2": V2, "S": np.full(t.size, 0.5)},
        controls={"I": I},
        objective=J,
        success=True,
        status="optimal",
    )


def test_prop31_zero_current_is_drawn_as_zero_and_w_is_the_stored_energy(figs, tmp_path) -> None:  # noqa: ANN001
    cell = CellParams()
    n = 12
    t_alt = np.linspace(0.0, 60.0, 31)
    V1a, V2a = 0.021 * np.exp(-t_alt / 4.1), 0.033 * np.exp(-t_alt / 97.0)
    V1s, V2s = np.linspace(0.021, 0.004, n + 1), np.linspace(0.033, 0.02, n + 1)
    tiny = 3.7e-7 * np.sin(np.arange(n) + 0.3)
    cases = {
        "relaxing_Q_nonneg": {
            "result": _ocp_result(tiny, V1s, V2s, -4.1e-7),
            "V0": [0.021, 0.033],
            "zero_heat_alternative_objective_J": 2.4e-18,
            "alternatives": {
                "neg_polarisation": {"sim": {"t": t_alt, "I": -(V1a + V2a) / 0.011, "V1": V1a, "V2": V2a}}
            },
        },
        "relaxing": {
            "result": _ocp_result(np.linspace(-1.8, -0.4, n), V1s, V2s, -0.467),
            "V0": [0.021, 0.033],
            "zero_heat_alternative_objective_J": 2.4e-18,
            "alternatives": {
                "neg_polarisation": {"sim": {"t": t_alt, "I": -(V1a + V2a) / 0.011, "V1": V1a, "V2": V2a}}
            },
        },
    }
    ocp_plots.plot_prop31(cases, tmp_path / "p.png", cell=cell)
    fig = figs[-1]
    ax_i0, ax_i1, ax_w0 = fig.axes[0], fig.axes[1], fig.axes[2]
    star = next(ln for ln in ax_i0.lines if str(ln.get_label()).startswith("I* = 0 (numerically"))
    assert np.all(star.get_ydata() == 0.0) and f"{np.max(np.abs(tiny)):.1e} A" in star.get_label()
    moving = next(ln for ln in ax_i1.lines if str(ln.get_label()).startswith("I* (max"))
    assert np.max(np.abs(moving.get_ydata())) == pytest.approx(1.8)
    w_star = next(ln for ln in ax_w0.lines if ln.get_label() == "I*")
    np.testing.assert_allclose(w_star.get_ydata(), 0.5 * cell.C1_F * V1s**2 + 0.5 * cell.C2_F * V2s**2)
    w_alt = next(ln for ln in ax_w0.lines if ln.get_label() != "I*")
    np.testing.assert_allclose(w_alt.get_ydata(), 0.5 * cell.C1_F * V1a**2 + 0.5 * cell.C2_F * V2a**2)
    legend = [t.get_text() for t in ax_i0.get_legend().get_texts()]
    assert any("≈ 0" in t for t in legend)


def test_current_profile_sweep_is_percent_saving(figs, tmp_path) -> None:  # noqa: ANN001
    rows = [
        {"E_req_J": e, "t_f_s": tf, "optimal_heat_J": q, "constant_current_heat_J": cc, "constant_power_heat_J": cp}
        for e, tf, q, cc, cp in [
            (1300.0, 45.0, 71.0, 77.5, 79.1),
            (2600.0, 45.0, 301.0, 334.0, 352.0),
            (1300.0, 90.0, 33.0, 35.1, 35.9),
            (3900.0, 90.0, float("nan"), 95.0, 97.0),
        ]
    ]
    ocp_plots.plot_current_profile_sweep(rows, tmp_path / "sw.png")
    ax = figs[-1].axes[0]
    line = next(ln for ln in ax.lines if ln.get_label() == "vs constant current, t_f = 45 s")
    np.testing.assert_allclose(line.get_xdata(), [1300.0, 2600.0])
    np.testing.assert_allclose(line.get_ydata(), [100 * (77.5 - 71.0) / 77.5, 100 * (334.0 - 301.0) / 334.0])
    line = next(ln for ln in ax.lines if ln.get_label() == "vs constant power, t_f = 90 s")
    np.testing.assert_allclose(line.get_ydata(), [100 * (35.9 - 33.0) / 35.9])  # the NaN row is skipped
    assert "%" in ax.get_ylabel() and "E_req" in ax.get_xlabel()


def test_ocp_result_panels_have_readable_names(figs, tmp_path) -> None:  # noqa: ANN001
    r = _ocp_result(np.linspace(-2.3, 1.1, 8), np.linspace(0.0, 0.01, 9), np.linspace(0.0, 0.02, 9), 1.23)
    ocp_plots.plot_result(r, tmp_path / "r.png")
    ylabels = [ax.get_ylabel() for ax in figs[-1].axes]
    assert "RC voltage V1 [V]" in ylabels and "cell current I [A]" in ylabels and "state of charge S [-]" in ylabels


def test_phase_plane_and_leader_in_si(figs, tmp_path) -> None:  # noqa: ANN001
    r = simulate_platoon(ConstantSpeed(0.9), [Proposed()], [1.6], [1.3], 4.0, ev=EVParams(units=UNITS), dt_out=0.1)
    o = simulate_platoon(ConstantSpeed(0.9), [OVFL()], [1.6], [1.3], 4.0, ev=EVParams(units=UNITS), dt_out=0.1)
    plots.plot_phase_planes([("case", {"proposed": r, "ovfl": o})], tmp_path / "pp.png")
    ax = figs[-1].axes[0]
    line = next(ln for ln in ax.lines if ln.get_label() == "ovfl")
    np.testing.assert_allclose(line.get_xdata(), UNITS.length_m * o.gap[:, 0])
    np.testing.assert_allclose(line.get_ydata(), UNITS.speed_mps * 3.6 * (0.9 - o.speed[:, 0]))
    plots.plot_leader(ConstantSpeed(0.9), 4.0, tmp_path / "l.png", units=UNITS)
    v_ax = figs[-1].axes[1]
    np.testing.assert_allclose(v_ax.lines[0].get_ydata(), 0.9 * UNITS.speed_mps * 3.6)
    assert v_ax.get_ylabel() == "v_l [km/h]"


def _two_panel_figure(layout: str):  # noqa: ANN202
    """A figure of the package's kind (two panels, legends, titles, SI labels), laid out by tight_layout() as the
    package's figures are, or by matplotlib's constrained layout (the ring's figures)."""
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 1, figsize=(5.3, 4.1), layout="constrained" if layout == "constrained" else None)
    t_s = np.linspace(0.0, 37.0, 211)
    for k, ax in enumerate(axs):
        ax.plot(t_s, 3.1 * np.sin(0.23 * (k + 1) * t_s), label=f"vehicle {k + 1}")
        ax.set_ylabel("v [m/s]")
        ax.set_title(f"panel {k + 1}")
        ax.legend(fontsize=8)
    axs[-1].set_xlabel("t [s]")
    if layout == "tight":
        fig.tight_layout()
    return fig


@pytest.mark.parametrize("layout, draws", [("tight", 1), ("constrained", 2)])
def test_a_saved_figure_is_the_file_savefig_writes_drawn_once_when_laid_out_already(
    tmp_path, monkeypatch: pytest.MonkeyPatch, layout: str, draws: int
) -> None:
    """save_figure_atomic writes the bytes matplotlib's own savefig writes for the same figure (a second figure built
    the same way), draws a figure tight_layout() laid out once (not a layout-only draw first: issue 40) and one with
    constrained layout twice (its layout needs that draw), and leaves the figure's layout engine as it was."""
    import io

    import matplotlib.figure
    import matplotlib.pyplot as plt
    from helpers import TEST_DPI

    from aev_ocp.results import save_figure_atomic

    reference = io.BytesIO()
    twin = _two_panel_figure(layout)
    twin.savefig(reference, format="png", dpi=TEST_DPI)
    plt.close(twin)

    fig = _two_panel_figure(layout)
    engine = fig.get_layout_engine()
    counted: list[int] = []
    real_draw = matplotlib.figure.Figure.draw

    def draw(self, renderer):  # noqa: ANN001, ANN202
        counted.append(1)
        return real_draw(self, renderer)

    monkeypatch.setattr(matplotlib.figure.Figure, "draw", draw)
    path = save_figure_atomic(fig, tmp_path / "fig.png", dpi=TEST_DPI)
    monkeypatch.undo()
    assert len(counted) == draws
    assert fig.get_layout_engine() is engine
    assert path.read_bytes() == reference.getvalue()
    plt.close(fig)

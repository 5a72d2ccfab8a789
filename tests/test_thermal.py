"""Lumped pack thermal model (aev_ocp.models.thermal) in the model, the plant and the metrics."""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest

from aev_ocp.metrics import vehicle_metrics
from aev_ocp.models import battery, thermal
from aev_ocp.models.carfollowing import make_law
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.params import CarFollowingParams, CellParams, EVParams, PackParams, ParameterError, ThermalParams
from aev_ocp.plant import Plant
from aev_ocp.simulate import simulate_platoon

CELL = CellParams(heat_capacity_JpK=71.3, surface_area_m2=5.9e-3)
PACK = PackParams(n_series=7, n_parallel=3)
TH = ThermalParams(enabled=True, ambient_K=301.7, h_Wpm2K=37.3)


def test_constant_heat_load_matches_closed_form_to_1e9() -> None:
    """C dT/dt = Q − hA (T − T_amb), Q constant, T(0) = T_amb: T = T_amb + Q/hA (1 − e^{−t hA/C}) to 1e-9 K."""
    Q = 123.45  # W per pack
    C = PACK.n_cells * CELL.heat_capacity_JpK
    hA = PACK.n_cells * TH.h_Wpm2K * CELL.surface_area_m2
    T = ca.SX.sym("T")
    ts = np.linspace(0.0, 3 * C / hA, 31)
    F = ca.integrator(
        "th",
        "cvodes",
        {"x": T, "ode": thermal.temperature_rate_Kps(T, Q, CELL, PACK, TH)},
        0.0,
        ts[1:],
        {"abstol": 1e-12, "reltol": 1e-14},
    )
    num = np.concatenate([[TH.ambient_K], np.asarray(F(x0=TH.ambient_K)["xf"]).ravel()])
    exact = TH.ambient_K + Q / hA * (1 - np.exp(-ts * hA / C))
    assert np.max(np.abs(num - exact)) < 1e-9
    assert np.max(np.abs(thermal.step_response_K(ts, Q, CELL, PACK, TH) - exact)) < 1e-9
    assert exact[-1] - TH.ambient_K > 0.9 * Q / hA  # three time constants: 95 % of the rise


def test_plant_standing_pack_with_cooling_matches_closed_form() -> None:
    """A vehicle at standstill draws no current (Q_irr = 0); with cooling power P and T(0) ≠ T_amb the plant's
    temperature is T_∞ + (T0 − T_∞) e^{−t/τ}, T_∞ = T_amb − P/hA, to 1e-9 K."""
    th = dataclasses.replace(TH, cooling_power_W=17.5, T0_K=309.2)
    ev = EVParams(cell=CELL, pack=PACK, thermal=th)
    plant = Plant(ConstantSpeed(0.0), [None], ev, rtol=1e-13, atol=1e-12, samples=20)
    x0 = plant.initial_state([1.7], [0.0])
    assert x0.size == 6 and x0[5] == pytest.approx(309.2)
    out: tuple[list, list, list, list] = (
        [np.array([0.0])],
        [x0[:, None]],
        [np.zeros((plant.nq, 1))],
        [plant.samples(np.array([0.0]), x0[:, None], np.zeros(1))],
    )
    t_end = 600.0 / ev.units.time_s  # 600 s
    assert plant.advance(0.0, t_end, x0, np.zeros(plant.nq), np.zeros(1), out, [])
    t_s = np.concatenate(out[0]) * ev.units.time_s
    T = np.concatenate(out[1], axis=1)[5]
    hA = PACK.n_cells * th.h_Wpm2K * CELL.surface_area_m2
    tau = PACK.n_cells * CELL.heat_capacity_JpK / hA
    T_inf = th.ambient_K - 17.5 / hA
    assert np.max(np.abs(T - (T_inf + (309.2 - T_inf) * np.exp(-t_s / tau)))) < 1e-9


def _drive(th: ThermalParams, cell: CellParams = CELL, method: str = "auto"):
    ev = EVParams(cell=cell, pack=PackParams(n_series=96, n_parallel=31), thermal=th)
    law = make_law("ovfl", CarFollowingParams())
    return simulate_platoon(
        ConstantSpeed(1.7),
        [law, law],
        [1.3, 0.6],
        [0.4, 1.9],
        12.0,
        ev=ev,
        dt_out=0.005,
        rtol=1e-11,
        atol=1e-11,
        method=method,
    )


def test_driving_pack_energy_balance_with_arrhenius() -> None:
    """C (T(t) − T0) = ∫Q_irr − hA ∫(T − T_amb) − P t along a drive (temperature-dependent resistances on):
    the temperature state is driven by exactly the plant's dissipated heat."""
    cell = dataclasses.replace(CELL, activation_energy_Jpmol=2.37e4, T_ref_K=296.0)
    th = dataclasses.replace(TH, cooling_power_W=3.1, T0_K=305.0)
    r = _drive(th, cell)
    assert r.status == "ok" and r.meta.get("plant", "").startswith("cvodes")
    ev = r.ev
    t_s = ev.units.time_to_si(r.t)
    C = thermal.heat_capacity_JpK(cell, ev.pack)
    hA = thermal.conductance_WpK(cell, ev.pack, th)
    for i in range(2):
        T = r.temperature_K[:, i]
        lhs = C * (T[-1] - T[0])
        rhs = (
            r.heat_irr_J[-1, i]
            - hA * np.sum(0.5 * (T[1:] + T[:-1] - 2 * th.ambient_K) * np.diff(t_s))
            - th.cooling_power_W * t_s[-1]
        )
        assert lhs == pytest.approx(rhs, rel=1e-6, abs=1e-6 * r.heat_irr_J[-1, i])
        m = vehicle_metrics(r, i)
        assert m["peak_temperature_K"] == pytest.approx(np.max(T))
        assert m["time_above_T_max_s"] == 0.0


def test_arrhenius_resistances() -> None:
    cell = dataclasses.replace(CELL, activation_energy_Jpmol=3.1e4, T_ref_K=296.0)
    hot = battery.cell_at(cell, 318.4)
    f = math.exp(3.1e4 / 8.314462618 * (1 / 318.4 - 1 / 296.0))
    assert hot.R_s_ohm == pytest.approx(cell.R_s_ohm * f, rel=1e-14) and f < 1  # hotter: lower resistance
    assert hot.R2_ohm == pytest.approx(cell.R2_ohm * f, rel=1e-14) and hot.C1_F == cell.C1_F
    assert battery.cell_at(cell, 296.0).R1_ohm == pytest.approx(cell.R1_ohm, rel=1e-15)
    assert battery.cell_at(CELL, 318.4) is CELL  # no activation energy: the cell itself


def test_thermal_off_changes_nothing() -> None:
    r = _drive(ThermalParams())
    assert r.temperature_K is None and "peak_temperature_K" not in vehicle_metrics(r, 0)


def test_cascade_refuses_thermal() -> None:
    with pytest.raises(ParameterError, match="thermal"):
        _drive(TH, method="cascade")


def test_temperature_metrics_by_hand() -> None:
    t = np.array([0.0, 10.0, 20.0, 30.0])
    T = np.array([300.0, 320.0, 300.0, 300.0])
    m = thermal.temperature_metrics(t, T, 310.0)
    assert m["peak_K"] == 320.0 and m["mean_K"] == pytest.approx((10 * 310 + 10 * 310 + 10 * 300) / 30)
    assert m["time_above_s"] == pytest.approx(10.0)  # 5 s either side of the peak


def test_thermal_params_validated() -> None:
    with pytest.raises(ParameterError, match="h_Wpm2K"):
        ThermalParams(h_Wpm2K=0.0)
    with pytest.raises(ParameterError, match="cooling_power_W"):
        ThermalParams(cooling_power_W=-1.0)


# ----------------------------------------------------------------------------- the temperature in the OCPs
def _ocp_ev(T_max_K: float = 340.0) -> EVParams:
    cell = dataclasses.replace(CELL, activation_energy_Jpmol=2.6e4, T_ref_K=297.0)
    return EVParams(
        cell=cell,
        pack=PackParams(n_series=96, n_parallel=31),
        thermal=dataclasses.replace(TH, T_max_K=T_max_K, cooling_power_W=4.4),
    )


@pytest.mark.parametrize("builder", ["following", "traffic"])
def test_problem_temperature_state_is_the_thermal_model(builder: str) -> None:
    """With with_temperature the problem's last state is T [K]: its derivative (model time) is T_unit ·
    (Q_irr_pack − hA (T − T_amb) − P)/C with the problem's own Q_irr output, the cell's dV1/dt uses R1(T)
    (Arrhenius), and T ≤ T_max is the state's upper bound."""
    from aev_ocp.ocp.following import following_problem
    from aev_ocp.ocp.traffic import traffic_problem

    ev = _ocp_ev()
    pb = (
        following_problem(ev, with_temperature=True)
        if builder == "following"
        else traffic_problem(ev, with_temperature=True)
    )
    pr = pb.build()
    names = list(pr.state_names)
    assert names[-1] == "T" and pr.x_ub[-1] == ev.thermal.T_max_K
    x = np.zeros(len(names))
    x[:5] = [1.3, 1.1, 0.017, 0.006, 0.71]
    x[-1] = 312.6
    u = np.zeros(len(pr.control_names))
    u[0] = 0.43
    w, p = [1.2, 1.15], np.ones(pr.np_)
    dx = np.asarray(pr.ode(x, u, w, p)).ravel()
    outs = dict(zip([pr.outputs.name_out(i) for i in range(pr.outputs.n_out())], pr.outputs(x, u, w, p)))
    Q, I = float(outs["Q_irr_pack_W"]), float(outs["I"])
    C = ev.pack.n_cells * ev.cell.heat_capacity_JpK
    hA = ev.pack.n_cells * ev.thermal.h_Wpm2K * ev.cell.surface_area_m2
    Tu = ev.units.time_s
    assert dx[-1] == pytest.approx(Tu * (Q - hA * (312.6 - ev.thermal.ambient_K) - 4.4) / C, rel=1e-12)
    f = math.exp(2.6e4 / 8.314462618 * (1 / 312.6 - 1 / 297.0))
    R1 = ev.cell.R1_ohm * f
    assert dx[2] == pytest.approx(Tu * (-0.017 / (R1 * ev.cell.C1_F) + I / ev.cell.C1_F), rel=1e-12)
    assert float(outs["T_K"]) == 312.6


def test_with_temperature_needs_the_thermal_model() -> None:
    from aev_ocp.ocp.following import following_problem

    with pytest.raises(ParameterError, match="thermal"):
        following_problem(EVParams(), with_temperature=True)


def test_ocp_respects_a_temperature_limit() -> None:
    """OCP with T ≤ T_max: where the unconstrained optimum heats the pack past T_max, the constrained one stays
    at or below it (IPOPT bound tolerance) and costs more; a looser limit costs less than a tighter one."""
    from aev_ocp.ocp.following import FollowingWeights, following_problem, weight_vector
    from aev_ocp.ocp.transcription import OCPSolver, TranscriptionOptions

    cell = dataclasses.replace(CellParams(), heat_capacity_JpK=0.04, surface_area_m2=2.1e-5)  # a hot toy pack
    N, w = 20, np.full((2, 20), 1.9)
    out = {}
    for T_max in (400.0, 303.6, 303.3):
        ev = EVParams(
            cell=cell,
            pack=PackParams(n_series=96, n_parallel=31),
            thermal=ThermalParams(enabled=True, ambient_K=301.7, h_Wpm2K=37.3, T0_K=303.0, T_max_K=T_max),
        )
        s = OCPSolver(following_problem(ev, with_temperature=True).build(), TranscriptionOptions(method="ms", N=N))
        r = s.solve([2.5, 1.0, 0.0, 0.0, 0.7, 303.0], 6.0, p=weight_vector(FollowingWeights(w_Q=0.02)), w=w)
        assert r.success
        out[T_max] = (r.objective, float(np.max(r.states["T"])))
    assert out[400.0][1] > 305.0  # unconstrained: well above both limits
    for T_max in (303.6, 303.3):
        assert out[T_max][1] <= T_max + 1e-5
    assert out[400.0][0] < out[303.6][0] < out[303.3][0]


def test_saved_run_keeps_temperature_cell_and_thermal(tmp_path) -> None:
    """A thermal run with a cell of its own (OCV table) saved and loaded: the same temperatures and parameters."""
    from aev_ocp.saved import load, save_output

    cell = dataclasses.replace(
        CELL, ocv_soc=(0.0, 0.3, 0.6, 1.0), ocv_V=(3.1, 3.55, 3.8, 4.15), activation_energy_Jpmol=2.2e4
    )
    r = _drive(dataclasses.replace(TH, T0_K=304.4), cell)
    save_output(tmp_path / "run", "simulate", {"run": r})
    back = load(tmp_path / "run")
    assert back.ev == r.ev and np.array_equal(back.temperature_K, r.temperature_K)


def test_trajectory_plot_shows_the_temperature(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib.pyplot as plt

    from aev_ocp import plots

    r = _drive(dataclasses.replace(TH, T0_K=304.4))
    labels: list[str] = []
    orig = plots.save_figure

    def keep(fig, path):  # type: ignore[no-untyped-def]
        labels.extend(ax.get_ylabel() for ax in fig.axes)
        return orig(fig, path)

    monkeypatch.setattr(plots, "save_figure", keep)
    plots.plot_trajectories(r, tmp_path / "t.png")
    plt.close("all")
    assert "pack temperature T [K]" in labels and (tmp_path / "t.png").stat().st_size > 0

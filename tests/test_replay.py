"""The exact replay (aev_ocp.replay, aev-ocp replay): its battery energy against SciPy's quadrature of an
independent NumPy powertrain, its cell against a SciPy integration of the same power, the energy balances (battery
= traction + losses + aux − regen; wheel work = kinetic energy + road load), the regenerative limit in a run, and
bad input named."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

import aev_ocp
from aev_ocp.models.battery import ocv_function
from aev_ocp.models.leader import load_cycle_si
from aev_ocp.params import EVParams, ParameterError, VehicleParams
from cli_helpers import run_cli
from powertrain_oracle import battery_power, wheel_power

EV = EVParams(vehicle=VehicleParams.model3())
# the first 300 s of US06 (hard accelerations and braking, 0 to 31 m/s) keep the runs short
T_US06, V_US06 = (x[:301] for x in load_cycle_si("us06"))


def _scipy_energy(t: np.ndarray, v: np.ndarray, p: VehicleParams) -> float:
    total = 0.0
    for k in range(t.size - 1):
        dt, a = t[k + 1] - t[k], (v[k + 1] - v[k]) / (t[k + 1] - t[k])
        f = lambda s, v0=v[k], a=a: float(battery_power(wheel_power(np.array(v0 + a * s), a, p), p))  # noqa: E731
        total += quad(f, 0.0, dt, epsabs=1e-9, epsrel=1e-12, limit=200)[0]
    return total


@pytest.mark.parametrize("powertrain", ["map", "constant"])
def test_battery_energy_against_scipy_quadrature(powertrain: str) -> None:
    r = aev_ocp.replay((T_US06, V_US06), ev=EV, powertrain=powertrain)
    ref = _scipy_energy(T_US06, V_US06, r.ev.vehicle)
    assert r.battery_energy_J == pytest.approx(ref, rel=1e-7)
    assert r.powertrain == powertrain


def test_energy_balances_on_a_replay() -> None:
    r = aev_ocp.replay("udds")
    p = r.ev.vehicle
    # battery = traction + losses + aux − regen, to round-off
    assert r.battery_energy_J == pytest.approx(r.traction_J + r.loss_J + r.aux_J - r.regen_J, rel=1e-9)
    # wheel work = (m + m_rot) Δv²/2 + rolling resistance × distance + ∫ drag v dt (exact for linear v)
    t, v = r.t_s, r.speed_mps
    drag = 0.5 * p.air_density_kgpm3 * p.drag_coefficient * p.frontal_area_m2
    dt = np.diff(t)
    w_drag = drag * np.sum(dt * (v[1:] + v[:-1]) * (v[1:] ** 2 + v[:-1] ** 2) / 4)
    dist = float(np.sum(dt * (v[1:] + v[:-1]) / 2))
    wheel = (
        0.5 * (p.mass_kg + p.rotating_mass_kg) * (v[-1] ** 2 - v[0] ** 2)
        + p.rolling_coefficient * p.mass_kg * p.gravity_mps2 * dist
        + w_drag
    )
    # (CVODES at rtol 1e-10 over 1369 intervals whose power has a kink where P_w changes sign: 2.5e-7 measured)
    assert r.traction_J - r.regen_J - r.friction_J == pytest.approx(wheel, rel=2e-6)
    assert r.distance_m == pytest.approx(dist, rel=1e-7)
    assert r.aux_J == pytest.approx(p.aux_power_W * r.duration_s, rel=1e-9)
    s = r.summary()
    assert s["battery_energy_kWh_per_100km"] == pytest.approx(s["battery_energy_Wh_per_km"] / 10, rel=1e-12)
    assert s["battery_energy_J_per_km"] == pytest.approx(s["battery_energy_Wh_per_km"] * 3600, rel=1e-12)


def test_cell_against_scipy_integration_of_the_same_power() -> None:
    r = aev_ocp.replay((T_US06[:121], V_US06[:121]), ev=EV)
    cell, n, ocv = EV.cell, EV.pack.n_cells, ocv_function()
    p = EV.vehicle

    def rhs(tt: float, y: np.ndarray) -> list[float]:
        k = min(int(np.searchsorted(T_US06, tt, side="right")) - 1, 119)
        a = (V_US06[k + 1] - V_US06[k]) / (T_US06[k + 1] - T_US06[k])
        Pc = float(battery_power(wheel_power(np.array(V_US06[k] + a * (tt - T_US06[k])), a, p), p)) / n
        E = float(ocv(y[2])) - y[0] - y[1]
        I = 2 * Pc / (E + np.sqrt(E * E - 4 * cell.R_s_ohm * Pc))
        return [
            -y[0] / cell.tau1_s + I / cell.C1_F,
            -y[1] / cell.tau2_s + I / cell.C2_F,
            -I / (3600 * cell.capacity_Ah),
            I * (y[0] + y[1]) + cell.R_s_ohm * I**2,
            abs(I),
        ]

    y = np.array([0.0, 0.0, cell.soc0, 0.0, 0.0])
    for k in range(120):  # interval by interval: the power has kinks at the samples
        y = solve_ivp(rhs, (T_US06[k], T_US06[k + 1]), y, rtol=1e-11, atol=1e-12, method="LSODA").y[:, -1]
    assert r.soc[-1] == pytest.approx(y[2], abs=1e-9)
    assert r.heat_pack_J == pytest.approx(n * y[3], rel=1e-5)
    assert r.charge_throughput_Ah == pytest.approx(y[4] * EV.pack.n_parallel / 3600, rel=1e-6)


def test_regenerative_limit_binds_in_a_replay() -> None:
    free = aev_ocp.replay((T_US06, V_US06), ev=EV)
    lim = dataclasses.replace(EV, vehicle=dataclasses.replace(EV.vehicle, regen_power_max_W=2.2e4))
    cut = aev_ocp.replay((T_US06, V_US06), ev=lim)
    assert free.friction_J == 0.0 and cut.friction_J > 1e4
    assert cut.battery_energy_J > free.battery_energy_J  # less recovered
    assert cut.regen_J + cut.friction_J == pytest.approx(free.regen_J, rel=1e-8)  # the same braking, split
    assert cut.battery_energy_J == pytest.approx(_scipy_energy(T_US06, V_US06, lim.vehicle), rel=1e-7)


def test_cycles_and_paper_eta_differ_as_stated() -> None:
    m = aev_ocp.replay("hwfet").summary()
    c = aev_ocp.replay("hwfet", powertrain="constant").summary()
    assert m["status"] == "ok" and m["delta_soc"] < 0 and m["charge_throughput_Ah_per_km"] > 0
    assert m["battery_energy_kWh_per_100km"] == pytest.approx(9.79, abs=0.01)  # FASTSim 3.1: 9.785 (docs table)
    assert c["battery_energy_kWh_per_100km"] > 1.09 * m["battery_energy_kWh_per_100km"]


@pytest.mark.parametrize(
    ("trace", "kw", "match"),
    [
        ("nedc", {}, "neither a shipped cycle"),
        (([0.0, 1.0, 1.0], [0.0, 2.0, 3.0]), {}, "strictly increasing"),
        (([0.0, 1.0], [0.0, -2.0]), {}, "≥ 0"),
        (([0.0, 1.0], [0.0]), {}, "same length"),
        ("udds", {"powertrain": "eta"}, "powertrain"),
        ("udds", {"soc0": 1.2}, "soc0"),
    ],
)
def test_bad_input_named(trace: object, kw: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        aev_ocp.replay(trace, **kw)  # type: ignore[arg-type]


def test_cli_replay(tmp_path, capsys) -> None:  # noqa: ANN001
    out = tmp_path / "r.json"
    rc, stdout, stderr = run_cli(["replay", "hwfet", "--powertrain", "constant", "--json", str(out)], capsys)
    assert rc == 0, stderr
    assert "battery energy" in stdout and "kWh/100 km" in stdout
    s = json.loads(out.read_text())
    assert s["powertrain"] == "constant" and s["battery_energy_kWh_per_100km"] > 10
    rc, _, stderr = run_cli(["replay", "nedc"], capsys)
    assert rc == 2 and stderr.startswith("aev-ocp: error: replay: trace 'nedc'")
    # --json onto a folder: one line naming the option (it named a temporary file '..xyz.tmp' before)
    rc, _, stderr = run_cli(["replay", "hwfet", "--json", str(tmp_path)], capsys)
    assert rc == 2 and stderr.startswith(f"aev-ocp: error: --json {tmp_path}: cannot write it"), stderr


def test_plant_with_the_map_matches_the_replay() -> None:
    # the platoon plant (CVODES, its own integration) under a held-acceleration sequence and the replay of the same
    # piecewise-linear speed: both use the map through battery_side, so SOC and pack heat agree
    from aev_ocp.control import ControlSequence, run_closed_loop
    from aev_ocp.models.leader import ConstantSpeed
    from aev_ocp.params import Units, VehicleLimits

    u = Units(10.0, 5.0)
    ev = EVParams(units=u, vehicle=VehicleParams.model3(), limits=VehicleLimits(enabled=False))
    a_si = np.array([2.3, 2.3, 1.1, 0.0, -0.7, -3.1, -1.9, 0.4, 1.7, -2.6])  # m/s², held 1.5 s each
    dt_s = 1.5
    v0 = 4.2
    v = v0 + np.concatenate([[0.0], np.cumsum(a_si * dt_s)])
    r = run_closed_loop(
        ConstantSpeed(float(u.speed_from_si(v0))),
        [ControlSequence(tuple(u.accel_from_si(a_si)), u.time_from_si(dt_s))],
        [400.0],
        [float(u.speed_from_si(v0))],
        u.time_from_si(dt_s * a_si.size),
        ev=ev,
    )
    assert r.status == "ok"
    rep = aev_ocp.replay((dt_s * np.arange(v.size), v), ev=ev)
    assert r.S[-1, 0] == pytest.approx(rep.soc[-1], abs=1e-10)
    assert r.heat_J[-1, 0] == pytest.approx(rep.heat_pack_J, rel=1e-6)
    m = r.metrics()[0]
    assert m["battery_energy_J"] == pytest.approx(rep.battery_energy_J, rel=2e-3)  # the samples' trapezoid
    const = aev_ocp.replay((dt_s * np.arange(v.size), v), ev=ev, powertrain="constant")
    assert abs(r.S[-1, 0] - const.soc[-1]) > 1e-5  # the plant did use the map


@pytest.mark.parametrize(
    ("v1", "dt1", "ok", "match"),
    [
        (7.93, 1.0, True, ""),  # inside the grip limit (8 m/s^2)
        (8.0, 1.0, True, ""),  # exactly on it
        (8.07, 1.0, False, "tyre-road friction limit"),  # just outside
        (60.0, 1e-6, False, "6e\\+07 m/s\\^2"),  # a jump: status ok and 1.7e11 kJ/km of pack heat before
        (1e300, 1.0, False, "limits.v_max_mps = 62.5"),  # CVODES failed with an internal error before
    ],
)
def test_a_trace_beyond_the_grip_or_the_top_speed_is_refused(v1: float, dt1: float, ok: bool, match: str) -> None:
    t, v = [0.0, dt1, dt1 + 3.0], [0.0, v1, max(v1 - 3.0 * 7.5, 0.0) if v1 < 100 else 3.0]
    if ok:
        r = aev_ocp.replay((t, v))
        assert r.status == "ok" and r.distance_m == pytest.approx(0.5 * v1 * dt1 + 0.5 * (v[1] + v[2]) * 3.0)
    else:
        with pytest.raises(ParameterError, match=match):
            aev_ocp.replay((t, v))


def test_top_speed_on_and_above_the_limit() -> None:
    t = [0.0, 10.0, 20.0]
    assert aev_ocp.replay((t, [0.0, 62.5, 60.0])).status in ("ok", "infeasible_current")  # on v_max: not refused
    with pytest.raises(ParameterError, match="speed_mps = 62.51 at t = 10 s"):
        aev_ocp.replay((t, [0.0, 62.51, 60.0]))

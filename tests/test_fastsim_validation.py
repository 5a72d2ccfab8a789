"""The replay against NREL FASTSim 3.1's own run of its 2022 Tesla Model 3 RWD on UDDS, HWFET and US06 (the
``[validation]`` extra; the test extra brings it, so CI runs this file): battery energy within 2 % with the map
powertrain, the paper's η = 0.8 outside it, and the map's numbers equal to FASTSim's vehicle file."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aev_ocp.models import powertrain as pt
from aev_ocp.params import MODEL3_AUX_POWER_W, MODEL3_ROTATING_MASS_KG, VehicleParams

fastsim = pytest.importorskip("fastsim", reason="NREL FASTSim 3.1 is not installed: pip install 'aev_ocp[validation]'")

from aev_ocp import validation  # noqa: E402 - after the skip


def _array(x: object) -> np.ndarray:
    """A FASTSim array: a list, or its serialised ndarray {'v', 'dim', 'data'}."""
    return np.asarray(x["data"] if isinstance(x, dict) else x, float)


@pytest.fixture(scope="module")
def rows() -> list[dict]:
    return validation.comparison_rows()


def test_battery_energy_within_two_percent_of_fastsim(rows: list[dict]) -> None:
    assert [r["cycle"] for r in rows] == ["udds", "hwfet", "us06"]
    for r in rows:
        assert abs(r["map_error_pct"]) < 100 * validation.TOLERANCE, r
        # the paper's constant η = 0.8 on the same vehicle is 10-20 % high (stated in docs/guide/powertrain.md)
        assert 9.0 < r["eta_error_pct"] < 21.0, r


def test_map_is_fastsims_vehicle_file() -> None:
    veh = validation.fastsim_vehicle()
    bev = veh["pt_type"]["BEV"]
    em = bev["em"]["eff_interp_achieved"]["data"]
    np.testing.assert_array_equal(_array(em["grid"][0]), pt.MOTOR_MAP_POWER_FRACTION)
    np.testing.assert_allclose(_array(em["values"]), pt.MOTOR_MAP_EFFICIENCY, rtol=0, atol=1e-15)
    p = VehicleParams.model3()
    assert bev["em"]["pwr_out_max_watts"] == p.motor_power_max_W
    assert bev["transmission"]["eff_interp"] == p.transmission_efficiency
    assert veh["pwr_aux_base_watts"] == MODEL3_AUX_POWER_W == p.aux_power_W
    ch = veh["chassis"]
    assert ch["wheel_inertia_kilogram_square_meters"] * ch["num_wheels"] / ch[
        "wheel_radius_meters"
    ] ** 2 == pytest.approx(MODEL3_ROTATING_MASS_KG, rel=1e-12)
    assert (veh["mass_kilograms"], ch["drag_coef"], ch["frontal_area_square_meters"], ch["wheel_rr_coef"]) == (
        p.mass_kg,
        p.drag_coefficient,
        p.frontal_area_m2,
        p.rolling_coefficient,
    )


def test_fastsim_recuperates_at_the_maps_first_value() -> None:
    # the regen efficiency default (0.84) is what FASTSim applies: P_elec / P_mech at every braking step of US06
    fs = validation._fastsim()
    from aev_ocp.models.leader import load_cycle_si

    t, v = load_cycle_si("us06")
    sd = fs.SimDrive(
        fs.Vehicle.from_resource(validation.FASTSIM_VEHICLE),
        fs.Cycle.from_dict({"time_seconds": t.tolist(), "speed_meters_per_second": v.tolist()}),
    )
    sd.run()
    em = sd.to_dict()["veh"]["pt_type"]["BEV"]["em"]["history"]
    m, e = np.asarray(em["pwr_mech_prop_out_watts"]), np.asarray(em["pwr_elec_prop_in_watts"])
    brake = m < -1.0
    assert brake.sum() > 100
    np.testing.assert_allclose(e[brake] / m[brake], VehicleParams.model3().regen_efficiency, rtol=1e-12)


def test_regen_at_the_map_would_miss_fastsim(rows: list[dict]) -> None:
    # recuperating at the map's efficiency instead (a physically plausible choice) leaves UDDS outside 2 %: the
    # default follows FASTSim, and this test shows that the choice matters
    from aev_ocp import replay
    from aev_ocp.params import EVParams

    ev = EVParams(vehicle=dataclasses.replace(VehicleParams.model3(), regen_efficiency=None))
    udds = replay("udds", ev=ev).summary()["battery_energy_kWh_per_100km"]
    assert udds / rows[0]["fastsim_kWh_per_100km"] - 1 < -validation.TOLERANCE


def test_the_guides_table_is_this_comparison(rows: list[dict]) -> None:
    from pathlib import Path

    guide = (Path(__file__).parents[1] / "docs" / "guide" / "powertrain.md").read_text(encoding="utf-8")
    table = validation.markdown_table(rows)
    for line in table.splitlines()[2:]:
        assert line in guide, f"docs/guide/powertrain.md is out of date: {line}"

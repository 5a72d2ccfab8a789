"""Physical nonsense in the vehicle tables is one line naming the key and the allowed range: a cooling power that
drives the pack below 0 K, a temperature limit below the ambient, an OCV curve falling with SOC, a negative vehicle
length for the ring's stability."""

from __future__ import annotations

import dataclasses

import pytest

from aev_ocp.models.thermal import conductance_WpK, step_response_K
from aev_ocp.params import CellParams, EVParams, PackParams, ParameterError, ThermalParams, check_ocv_table
from aev_ocp.scenarios import ScenarioError, parse_scenario

PACK = PackParams(n_series=13, n_parallel=7)
CELL = CellParams()
TH = ThermalParams(enabled=True, ambient_K=287.3, h_Wpm2K=23.0)


def test_cooling_power_on_inside_and_outside() -> None:
    hA = conductance_WpK(CELL, PACK, TH)
    cap = hA * TH.ambient_K  # the cooling power whose steady state is 0 K with no heat from the cells
    inside = dataclasses.replace(TH, cooling_power_W=0.999 * cap)
    ev = EVParams(cell=CELL, pack=PACK, thermal=inside)
    # the steady state of the pack at rest stays above 0 K, at 0.1 % of the ambient (the closed form of the model)
    T_inf = float(step_response_K(1e9, 0.0, ev.cell, ev.pack, ev.thermal))
    assert T_inf == pytest.approx(0.001 * TH.ambient_K, rel=1e-6) and T_inf > 0
    for p in (cap, 1.7 * cap, 1e300):
        with pytest.raises(
            ParameterError, match=rf"ThermalParams.cooling_power_W = .* must be a finite number in \[0, {cap:.6g}\) W"
        ):
            EVParams(cell=CELL, pack=PACK, thermal=dataclasses.replace(TH, cooling_power_W=p))


def test_cooling_power_in_a_scenario_names_the_key() -> None:
    doc = {"name": "x", "thermal": {"enabled": True, "cooling_power_W": 5e6}}
    with pytest.raises(
        ScenarioError, match=r"^c.toml: thermal.cooling_power_W: ThermalParams.cooling_power_W = 5000000.0"
    ):
        parse_scenario(doc, "c.toml")


def test_t_max_below_ambient() -> None:
    with pytest.raises(ParameterError, match=r"ThermalParams.T_max_K = 287.3 is not allowed: .*\(287.3, 1000\] K"):
        ThermalParams(ambient_K=287.3, T_max_K=287.3)
    assert ThermalParams(ambient_K=287.3, T_max_K=287.31).T_max_K == 287.31
    with pytest.raises(ParameterError, match=r"ThermalParams.T_max_K = 1000.5 is not allowed"):
        ThermalParams(T_max_K=1000.5)
    with pytest.raises(ScenarioError, match=r"c.toml: thermal.T_max_K: .*above ambient_K = 298.15 K"):
        parse_scenario({"name": "x", "thermal": {"T_max_K": 290.0}}, "c.toml")


def test_ocv_falling() -> None:
    soc = (0.0, 0.3, 0.6, 1.0)
    check_ocv_table(soc, (3.1, 3.3, 3.3, 3.6), "t")  # a flat plateau is a real LFP curve
    with pytest.raises(
        ParameterError, match=r"t.ocv_V is not allowed: must not decrease .* falls from 3.3 V to 3.29 V"
    ):
        check_ocv_table(soc, (3.1, 3.3, 3.29, 3.6), "t")
    with pytest.raises(ParameterError, match=r"does not rise \(3.3 V at SOC 0, 3.3 V at SOC 1\)"):
        check_ocv_table(soc, (3.3, 3.3, 3.3, 3.3), "t")
    with pytest.raises(ParameterError, match="CellParams.ocv_V is not allowed"):
        CellParams(ocv_soc=soc, ocv_V=(3.6, 3.4, 3.3, 3.1))


def test_ring_stability_vehicle_length() -> None:
    from aev_ocp.cli import main
    from aev_ocp.models.carfollowing import OVM
    from aev_ocp.stability.ring import ring_stability

    with pytest.raises(ParameterError, match="vehicle_length_m = -1.0 is not allowed"):
        ring_stability(OVM(), 22, 220.0, -1.0)
    for bad in ("-1", "nan", "31"):
        assert main(["stability", "--law", "ovm", "--ring", "22", "--spacing-m", "10", "--vehicle-length-m", bad]) == 2

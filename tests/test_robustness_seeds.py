"""The seeded robustness comparison (aev_ocp.robustness, issue 33.5 / 35.5): the study it builds (real: seeds ×
powertrains × cycles, the same seed for model error and sensors; ideal: no seeds), each cycle's cut, and its table."""

from __future__ import annotations

from typing import Any

import pytest

from aev_ocp.mpc.cycles import cycle_scenario
from aev_ocp.params import ParameterError, VehicleParams
from aev_ocp.robustness import (
    POWERTRAIN_KEYS,
    REAL_OVERRIDES,
    SEED_METRICS,
    cycle_cuts,
    powertrain_values,
    robustness_study,
    seeded_markdown,
)
from aev_ocp.study.seeds import seed_keys, study_seeds


def test_cuts_end_at_rest_or_at_the_bound() -> None:
    cuts = cycle_cuts(("udds", "hwfet"), 120.0, 150.0)
    udds = cycle_scenario("udds", 120.0, end_at_rest=True)
    assert cuts["udds"] == udds.t_end  # UDDS's first stop after 120 s comes before 150 s: the cut is at rest
    assert 140.0 < udds.t_end * udds.units.time_s < 150.0
    hw = cycle_scenario("hwfet", 150.0)
    assert cuts["hwfet"] == hw.t_end  # HWFET stops only at its end (765 s): cut at 150 s
    assert cycle_cuts(("hwfet",), 120.0)["hwfet"] == cycle_scenario("hwfet").t_end  # unbounded: the whole cycle


def test_real_study_pairs_model_error_and_sensors_by_seed() -> None:
    st = robustness_study(("udds", "us06"), 60.0, (4, 7, 9), ("map", "constant"), "real", 60.0)
    assert seed_keys(st.axes) == ["mismatch.seed", "sensors.seed"]
    assert len(st.tasks()) == 2 * 2 * 3 * 3  # cycles × powertrains × seeds × (mpc, proposed, ovfl)
    assert {c.label for c in st.controllers} == {"mpc", "proposed", "ovfl"}
    for p in st.points:
        assert p.values["mismatch.seed"] == p.values["sensors.seed"] in (4, 7, 9)
        mm, sen = p.document["mismatch"], p.document["sensors"]
        for k, v in REAL_OVERRIDES.items():
            table, key = k.split(".")
            assert (mm if table == "mismatch" else sen)[key] == v
        pt = p.values["vehicle.powertrain"]
        assert tuple(p.document["vehicle"][k.split(".")[1]] for k in POWERTRAIN_KEYS) == powertrain_values(pt)
    m3 = VehicleParams.model3()
    assert powertrain_values("map") == ("map", m3.aux_power_W, m3.rotating_mass_kg, m3.air_density_kgpm3)
    assert powertrain_values("constant")[:2] == ("constant", 0.0)
    assert st.report["differences"] == [("mpc", "proposed"), ("mpc", "ovfl")]
    ideal = robustness_study(("udds",), 60.0, (4, 7, 9), ("map",), "ideal", 60.0)
    assert seed_keys(ideal.axes) == [] and len(ideal.tasks()) == 3
    assert "mismatch" not in ideal.points[0].document and "sensors" not in ideal.points[0].document


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"condition": "noisy"}, "condition"),
        ({"powertrains": ("map", "map")}, "powertrains"),
        ({"powertrains": ("hybrid",)}, "powertrain"),
        ({"seeds": (1, 1)}, "seeds"),
        ({"seeds": (-1, 2)}, "seeds"),
    ],
)
def test_bad_settings_name_the_field(kw: dict[str, Any], field: str) -> None:
    with pytest.raises(ParameterError, match=field):
        robustness_study(("udds",), 60.0, **{"max_s": 60.0, **kw})


def _rows(seed: int, e_mpc: float, e_law: float) -> list[dict[str, Any]]:
    base = {"scenario": "udds", "vehicle.powertrain": "map", "mismatch.seed": seed, "sensors.seed": seed}
    out = []
    for ctrl, e in (("mpc", e_mpc), ("proposed", e_law), ("ovfl", e_law + 0.01 * (-1) ** seed)):
        out.append(
            {
                **base,
                "controller": ctrl,
                "vehicle": 1,
                "status": "ok",
                "conditioning": "none" if ctrl == "mpc" else "filter 0.5 s, jerk <= 5 m/s^3",
                **{m: e * (1 + i) for i, m in enumerate(SEED_METRICS)},
            }
        )
    return out


def test_table_of_a_seeded_result() -> None:
    st = robustness_study(("udds",), 60.0, (0, 1, 2, 3), ("map",), "real", 60.0)
    rows = [r for s, (a, b) in enumerate([(9.1, 9.6), (9.3, 9.6), (9.0, 9.6), (9.2, 9.6)]) for r in _rows(s, a, b)]
    seeds = study_seeds(st, rows)
    assert seeds is not None
    res = {
        "settings": {"seeds": [0, 1, 2, 3], "powertrains": ["map"]},
        "duration_s": {"udds": 60.0},
        "real": seeds,
        "ideal": [],
        "real_failed": 0,
        "real_events": 0,
    }
    md = seeded_markdown(res)
    vs = {(r["a"], r["b"]): r for r in seeds["differences"]}
    p = vs[("mpc", "proposed")]
    assert p["battery_energy_kWh_per_100km_diff_mean"] == pytest.approx(-0.45)
    assert p["battery_energy_kWh_per_100km_verdict"] == "better"
    assert p["min_gap_m_verdict"] == "worse"  # the MPC's gaps are smaller on every seed: larger is better
    assert "| UDDS (60) | map | mpc | none | 4 |" in md
    assert "filter 0.5 s, jerk <= 5 m/s^3" in md and "**better**" in md and "**worse**" in md

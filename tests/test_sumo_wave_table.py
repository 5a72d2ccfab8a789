"""A SUMO scenario's ``[sumo.wave]``: the wave MPC's WaveParams fields, read and checked when the file is read
(errors name the file and ``sumo.wave.<field>``), reaching the WaveMPC of every "wave-mpc" run (also one chosen
after the file is read, as ``--controller`` and the studies do); absent, the WaveParams defaults, bit for bit."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from aev_ocp.mpc.wave import WaveParams
from aev_ocp.params import as_dict
from aev_ocp.scenarios import ScenarioError
from aev_ocp.sumo import sumo_available
from aev_ocp.sumo.run import make_controller_factory, run_sumo
from aev_ocp.sumo.scenario import load_sumo_scenario, parse_sumo_scenario

needs_sumo = pytest.mark.skipif(not sumo_available(), reason="SUMO is not installed (pip install 'aev_ocp[sumo]')")
#: distinct non-default values of fields that enter the wave MPC's reference, not its compiled problem (the default
#: 8 m, 0.1 1/s, 38 s): no new C library to compile
TABLE = {"target_gap_m": 5.3, "catch_gain_per_s": 0.07, "window_s": 23.0}


def _doc(name: str, wave: dict | None, **sumo: object) -> dict:
    doc = copy.deepcopy(load_sumo_scenario(name).document)
    doc["sumo"].update(sumo)
    doc["sumo"].pop("wave", None)
    if wave is not None:
        doc["sumo"]["wave"] = wave
    return doc


def _params(sc) -> WaveParams:  # noqa: ANN001
    _, factory = make_controller_factory(sc)
    assert factory is not None
    return factory().params


def test_the_table_reaches_the_wave_mpc_and_its_absence_is_the_defaults() -> None:
    """The WaveMPC that a "wave-mpc" run builds has the table's fields, the others at WaveParams' defaults; a file
    whose sumo.controller is another one carries it to the wave MPC a sweep point or --controller chooses later."""
    sc = parse_sumo_scenario(_doc("sumo_ring_idm", TABLE), "w.toml")
    assert sc.spec.wave == TABLE
    assert _params(sc) == dataclasses.replace(WaveParams(), **TABLE)
    assert _params(parse_sumo_scenario(_doc("sumo_ring_idm", None), "w.toml")) == WaveParams()
    krauss = parse_sumo_scenario(_doc("sumo_ring", TABLE), "k.toml")  # sumo.controller = "proposed"
    assert krauss.spec.controller == "proposed"
    assert _params(krauss.with_point(0.05, "wave-mpc")) == dataclasses.replace(WaveParams(), **TABLE)


@pytest.mark.parametrize(
    "wave, says",
    [
        ({"target_gap_mm": 5.0}, r"w\.toml: unknown key 'sumo\.wave\.target_gap_mm' \(= 5\.0\); allowed keys here: .*"),
        ({"window_s": -23.0}, r"w\.toml: sumo\.wave\.window_s = -23\.0 is not allowed: must be a finite number > 0"),
        (
            {"base_predecessor_share": 1.25},
            r"w\.toml: sumo\.wave\.base_predecessor_share = 1\.25 is not allowed: must be a finite number in \[0, 1\]",
        ),
        ({"speed_weight": "high"}, r"w\.toml: sumo\.wave\.speed_weight = 'high' is not allowed: expected a finite"),
        ({"min_ref_mps": 4.5, "max_ref_mps": 3.5}, r"w\.toml: sumo\.wave: WaveParams: min_ref_mps = 4\.5 m/s is above"),
        ({"traffic": {"time_headway_s": 1.2}}, r"w\.toml: unknown key 'sumo\.wave\.traffic'"),
    ],
)
def test_a_bad_field_is_refused_when_the_file_is_read_naming_it(wave: dict, says: str) -> None:
    with pytest.raises(ScenarioError, match=says):
        parse_sumo_scenario(_doc("sumo_ring_idm", wave), "w.toml")


@needs_sumo
def test_a_run_with_the_table_drives_as_its_fields_say() -> None:
    """Three 15 s runs of the IDM ring with its one wave-MPC car: the table of TABLE's fields changes the car's
    trajectory and is what its saved settings record; a table stating only default values gives the very run of no
    table (the same speeds to the bit)."""

    def car(wave: dict | None):  # noqa: ANN202
        run = run_sumo(parse_sumo_scenario(_doc("sumo_ring_idm", wave, t_end_s=15.0), "w.toml"))
        (vid,) = [k for k, c in run.controlled.items() if c]
        return run.vehicles[vid]

    plain, same, other = car(None), car({"target_gap_m": 8.0, "window_s": 38.0}), car(TABLE)
    assert plain.meta["controllers"][0]["wave"] == as_dict(WaveParams())
    assert other.meta["controllers"][0]["wave"] == as_dict(dataclasses.replace(WaveParams(), **TABLE))
    assert np.array_equal(plain.speed, same.speed) and np.array_equal(plain.gap, same.gap)
    assert plain.speed.shape == other.speed.shape
    print("largest speed difference [model]:", np.max(np.abs(plain.speed - other.speed)))
    assert np.max(np.abs(plain.speed - other.speed)) > 1e-3

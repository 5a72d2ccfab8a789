"""A SUMO scenario's ``[sumo.wave]``: the wave MPC's WaveParams fields, read and checked when the file is read
(errors name the file and ``sumo.wave.<field>``), reaching the WaveMPC of every "wave-mpc" run (also one chosen
after the file is read, as ``--controller`` and the studies do); absent, the WaveParams defaults, bit for bit."""

from __future__ import annotations

import copy
import dataclasses
import re
import runpy
from pathlib import Path

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


# ----------------------------------------------------------------------------- bench_sumo.py --wave
BENCH = runpy.run_path(str(Path(__file__).resolve().parents[1] / "benchmarks" / "bench_sumo.py"), run_name="bench")


@pytest.mark.parametrize("name", ["sumo_ring", "sumo_merge"])
def test_the_study_copy_is_the_shipped_scenario_with_its_wave_table(name: str, tmp_path: Path) -> None:
    """The copied scenario's document is the shipped one with speed_limits, the safety layer and [sumo.wave]: the
    shipped file's own (sumo_ring has one, sumo_merge none) with the given fields over it: without fields the
    study's tasks are today's (the same keys)."""
    from aev_ocp.study.traffic import sumo_tasks

    want = copy.deepcopy(load_sumo_scenario(name).document)
    shipped = want["sumo"].get("wave", {})
    assert bool(shipped) == (name == "sumo_ring") and ("buffer_rate" in shipped) == (name == "sumo_ring")
    want["sumo"]["speed_limits"] = True
    want["limits"] = {"safety_layer": True}
    plain = BENCH["scenario_copy"](name, tmp_path / "a")
    assert load_sumo_scenario(plain).document == want
    fields = {"target_gap_m": 6.5, "buffer_time_s": 7.25}  # target_gap_m is also sumo_ring's own: the given wins
    waved = load_sumo_scenario(BENCH["scenario_copy"](name, tmp_path / "b", fields))
    merged = {**shipped, **fields}
    assert waved.document == {**want, "sumo": {**want["sumo"], "wave": merged}} and waved.spec.wave == merged
    keys = [
        [t.key for t in sumo_tasks(p, [0.0, 0.05], ["wave-mpc"], [100, 101])]
        for p in (plain, BENCH["scenario_copy"](name, tmp_path / "a2", None))
    ]
    empty = BENCH["scenario_copy"](name, tmp_path / "c", {})
    assert keys[0] == keys[1] == [t.key for t in sumo_tasks(empty, [0.0, 0.05], ["wave-mpc"], [100, 101])]
    with pytest.raises(SystemExit, match=r"d/" + name + r"\.toml: sumo\.wave\.buffer_time_s = -1\.0 is not allowed"):
        BENCH["scenario_copy"](name, tmp_path / "d", {"buffer_time_s": -1.0})


def _run(seed: int, controller: str, **m: float | None) -> dict:
    events = {k: 0 for k in BENCH["WAVE_EVENTS"]}
    return {"share": 0.05, "controller": controller, "seed": seed, "status": "ok", **m, **events}


def _runs(controller: str, *columns: list[float]) -> list[dict]:
    """Runs on seeds 100, 101, … with the values of VARIANT_METRICS in their order, one column per metric."""
    names = list(BENCH["VARIANT_METRICS"])
    return [_run(100 + i, controller, **dict(zip(names, row))) for i, row in enumerate(zip(*columns))]


def test_the_variant_comparison_is_the_paired_t_interval_of_variant_minus_base(capsys) -> None:  # noqa: ANN001
    """Three seeds with both runs and one whose variant failed to run (left out, named); the mean and 95 % t
    interval of the per-seed differences (t = 4.302653 for 2 degrees of freedom, Student's table), verdicts for
    the variant (lower speed std and energy, higher speed and throughput are better), event sums per wave MPC."""
    std_b, std_v = [0.91, 1.27, 0.64, 0.7], [0.83, 1.19, 0.57]
    base = _runs("wave-mpc", std_b, [3.1, 4.1, 5.1, 3.0], [1500.0, 1620.0, 1410.0, 1500.0], [12.0, 13.0, 14.0, 12.0])
    var = _runs("wave-mpc-variant", std_v, [3.0, 4.0, 5.0], [1490.0, 1631.0, 1409.0], [12.5, 13.6, 14.7])
    base[1]["lane_end_stop_events"], var[2]["collisions"] = 2, 1
    var.append({**_run(103, "wave-mpc-variant", **dict.fromkeys(BENCH["VARIANT_METRICS"])), "status": "error"})
    out = BENCH["variant_comparison"]("ring", [_run(100, "sumo"), *base], var, [100, 101, 102, 103])
    assert out["seeds"] == [100, 101, 102] and out["left_out"] == [103]
    d = np.array(std_v) - np.array(std_b[:3])
    half = 4.302653 * d.std(ddof=1) / np.sqrt(3)
    got = out["difference"]["speed_std_mps"]
    assert got["mean"] == pytest.approx(d.mean(), abs=1e-12)
    assert (got["lo"], got["hi"]) == pytest.approx((d.mean() - half, d.mean() + half), abs=1e-6)
    assert got["verdict"] == "better"  # −0.08, −0.08, −0.07 m/s: every seed calmer
    assert out["difference"]["throughput_veh_per_h"]["verdict"] == "tie"  # −10, +11, −1 veh/h
    assert out["difference"]["mean_speed_mps"]["verdict"] == "worse"  # −0.1 m/s on every seed
    assert out["difference"]["battery_energy_kWh_per_100km"]["verdict"] == "worse"  # +0.5, +0.6, +0.7
    assert [r["speed_std_mps"] for r in out["per_seed"]] == pytest.approx(list(d), abs=1e-12)
    assert (
        out["events"]["wave-mpc"]["lane_end_stop_events"] == 2 and out["events"]["wave-mpc-variant"]["collisions"] == 1
    )
    assert "| 101 | ok / ok | -0.08 |" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--variant-params", "[1.5]"], "--variant-params '\\[1.5\\]': must be a JSON object of WaveParams fields"),
        (["--wave-params", "{target_gap_m: 6}"], "--wave-params '{target_gap_m: 6}': not JSON"),
        (["--wave-params", '{"follower_law": {"a_mps2": 1.2}}'], "--wave-params: 'follower_law' must be a number"),
        (["--controllers", "proposed", "--wave-params", '{"target_gap_m": 6}'], "--controllers must include wave-mpc"),
        (["--scenarios", "sumo_merge", "--record"], "--record writes the guide's full study"),
    ],
)
def test_the_wave_studys_options_are_checked_before_any_run(argv: list[str], says: str, capsys) -> None:  # noqa: ANN001
    with pytest.raises(SystemExit) as exc:
        BENCH["main_wave"](["--wave", *argv])
    assert exc.value.code == 2
    assert re.search(says, capsys.readouterr().err)

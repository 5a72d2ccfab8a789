"""A SUMO scenario's inputs, checked before SUMO starts: the shipped networks' declared ranges, the allow-listed
``sumo_args``, the size budget, the command line's options (``--controller mpc`` gets its [mpc]); and a saved run
loads from any folder."""

from __future__ import annotations

import argparse
import os

import pytest

from aev_ocp.limits import MAX_SUMO_T_END_S, SUMO_BYTES_PER_RECORD, check_sumo_size
from aev_ocp.params import ParameterError
from aev_ocp.scenarios import ScenarioError
from aev_ocp.sumo import SumoError, sumo_available
from aev_ocp.sumo.networks import MergeNetwork, RingNetwork
from aev_ocp.sumo.scenario import load_sumo_scenario, parse_sumo_scenario


def _parse(**sumo: object) -> object:
    table: dict[str, object] = {"network": "ring", "t_end_s": 12.5}
    table.update(sumo)
    return parse_sumo_scenario({"sumo": table}, "q.toml")


def _args(**kw: object) -> argparse.Namespace:
    base = {"t_end_s": None, "share": None, "controller": None, "sweep": False, "workers": None}
    base.update(kw)
    return argparse.Namespace(**base)


# ------------------------------------------------------------------------------------------ the networks
@pytest.mark.parametrize(
    "table, key, value, allowed",
    [
        ("ring", "length_m", -230.0, r"must be a finite number in \(0, 100000\]"),
        ("ring", "lane_speed_mps", 1e300, r"must be a finite number in \(0, 100\]"),
        ("ring", "vehicle_length_m", -4.7, r"must be a finite number in \(0, 30\]"),
        ("ring", "vehicles", 2.5, "expected an integer"),
        ("merge", "main_flow_vph", 1e9, r"must be a finite number in \[0, 10000\]"),
        ("merge", "accel_lane_m", 0.0, r"must be a finite number in \(0, 100000\]"),
    ],
)
def test_network_keys_outside_their_declared_range(table: str, key: str, value: object, allowed: str) -> None:
    with pytest.raises(ScenarioError, match=rf"q.toml: sumo.{table}.{key} = .* is not allowed: {allowed}"):
        _parse(network=table, **{table: {key: value}})


def test_unknown_vehicle_type_on_a_shipped_network() -> None:
    with pytest.raises(ScenarioError, match=r"q.toml: sumo.vtypes = \['aev'\] .*all of type 'ring_car'"):
        _parse(vtypes=["aev"])
    with pytest.raises(ScenarioError, match=r"sumo.vtypes = .*'ring_car'.*all of type 'human'"):
        _parse(network="merge", vtypes=["human", "ring_car"])
    assert _parse(vtypes=["ring_car"]).spec.vtypes == ("ring_car",)  # type: ignore[attr-defined]


def test_network_rules_between_keys() -> None:
    with pytest.raises(SumoError, match=r"sumo.ring.speed0_mps = 40.5 is not allowed: must be in \[0, 40\] m/s"):
        RingNetwork(speed0_mps=40.5)
    assert RingNetwork(speed0_mps=40.0).speed0_mps == 40.0
    with pytest.raises(SumoError, match="do not fit"):
        RingNetwork(length_m=100.0, vehicles=22)
    with pytest.raises(SumoError, match=r"^MergeNetwork.ramp_speed_mps = -1.0 is not allowed"):
        MergeNetwork(ramp_speed_mps=-1.0)


# ------------------------------------------------------------------------------------------ sumo_args
@pytest.mark.parametrize(
    "args, says",
    [
        (["--help"], "'--help' is not an allowed SUMO option"),
        (["--tripinfo-output", "victim.xml"], "'--tripinfo-output' is not an allowed"),
        (["--time-to-teleport=-1", "--log", "x.log"], "'--log' is not an allowed"),
        (["-a", "more.add.xml"], "'-a' is not an allowed"),
        (["--end", "5"], "'--end' is not an allowed"),  # the scenario's own t_end_s sets it
        (["--time-to-teleport"], "--time-to-teleport needs a value"),
    ],
)
def test_sumo_args_outside_the_allow_list(args: list[str], says: str) -> None:
    with pytest.raises(ScenarioError, match=rf"q.toml: sumo.sumo_args = .*{says}"):
        _parse(sumo_args=args)


def test_sumo_args_inside_the_allow_list() -> None:
    args = ["--time-to-teleport", "-1", "--collision.check-junctions", "--ignore-route-errors", "true", "--scale=1.5"]
    assert _parse(sumo_args=args).spec.sumo_args == tuple(args)  # type: ignore[attr-defined]


# ------------------------------------------------------------------------------------------ the size budget
def test_sumo_size_budget_on_inside_and_outside(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "0.25")
    # 37 vehicles x (steps + 1) records: the budget allows 0.25e9 / SUMO_BYTES_PER_RECORD records in all
    steps_max = 0.25e9 / SUMO_BYTES_PER_RECORD / 37 - 1
    assert check_sumo_size(37, 0.1 * int(steps_max), 0.1) <= 0.25e9
    with pytest.raises(ParameterError, match=r"sumo: 37 vehicles x .* more than the limit of 0.25 GB"):
        check_sumo_size(37, 0.1 * (int(steps_max) + 2), 0.1)
    # recording every 10th step fits ten times longer runs
    assert check_sumo_size(37, 0.1 * 10 * int(steps_max), 0.1, record_every=10) <= 0.25e9


@pytest.mark.parametrize(
    "sumo, says",
    [
        (
            {"t_end_s": 1e7},
            rf"sumo.t_end_s = 10000000.0 is not allowed: must be a finite number > 0 and <= {MAX_SUMO_T_END_S:g}",
        ),
        ({"t_end_s": 1e300}, r"sumo.t_end_s = 1e\+300 is not allowed"),
        ({"step_s": 1e-5}, r"sumo.step_s = 1e-05 is not allowed: must be a finite number >= 0.001 and <= 1"),
        ({"ring": {"length_m": 99_000.0, "vehicles": 20_000}, "t_end_s": 900.0}, r"20000 vehicles x 9000 steps"),
    ],
)
def test_runs_beyond_the_budget_are_refused_when_read(sumo: dict[str, object], says: str) -> None:
    with pytest.raises(ScenarioError, match=rf"q.toml: .*{says}"):
        _parse(**sumo)


# ------------------------------------------------------------------------------------------ command-line options
def test_controller_mpc_from_the_command_line_gets_the_default_mpc() -> None:
    from aev_ocp.sumo.cli import _with_options

    sc = load_sumo_scenario("sumo_ring")
    assert sc.spec.controller == "proposed" and sc.mpc is None
    sc2 = _with_options(sc, _args(controller="mpc"))
    assert sc2.spec.controller == "mpc" and sc2.mpc is not None
    k = sc2.mpc.settings.dt * sc2.ev.units.time_s / sc2.spec.step_s  # whole SUMO steps, as from the file
    assert k == pytest.approx(round(k)) and round(k) >= 1
    pt = sc.with_point(0.25, "mpc")  # a sweep point naming the MPC gets it the same way
    assert pt.mpc is not None and pt.mpc.settings.dt == sc2.mpc.settings.dt


@pytest.mark.parametrize(
    "kw, says",
    [
        ({"t_end_s": 1e9}, r"--t-end-s = 1000000000.0 is not allowed: must be a finite number in \(0, 86400\] s"),
        ({"t_end_s": 1e300}, r"--t-end-s = 1e\+300 is not allowed"),
        ({"sweep": True, "share": 0.5}, "--share cannot be combined with --sweep"),
        ({"sweep": True, "controller": "idm"}, "--controller cannot be combined with --sweep"),
        ({"sweep": True, "workers": 0}, "--workers 0: must be an integer from 1"),
        ({"workers": 2}, "--workers applies to --sweep only"),
    ],
)
def test_command_line_options_checked_never_ignored(kw: dict[str, object], says: str) -> None:
    from aev_ocp.sumo.cli import _with_options

    with pytest.raises((ScenarioError, ParameterError), match=says):
        _with_options(load_sumo_scenario("sumo_ring"), _args(**kw))


# ------------------------------------------------------------------------------------------ a saved run
def test_saved_run_with_a_relative_cell_file_loads_from_another_folder(
    tmp_path: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    if not sumo_available():
        pytest.skip("SUMO is not installed (pip install 'aev_ocp[sumo]')")
    from aev_ocp.cells import shipped_cells
    from aev_ocp.cli import main
    from aev_ocp.sumo.outputs import load_sumo

    d = tmp_path / "scen"  # type: ignore[operator]
    (d / "data").mkdir(parents=True)
    shipped = shipped_cells()["a123_anr26650"]
    (d / "data" / "my_cell.toml").write_text(shipped.read_text(encoding="utf-8"), encoding="utf-8")
    (d / "a123_ocv_25C.csv").write_bytes((shipped.parent.parent / "a123_ocv_25C.csv").read_bytes())
    (d / "s.toml").write_text(
        '[cell]\nfile = "data/my_cell.toml"\nsoc0 = 0.73\n[sumo]\nnetwork = "ring"\nt_end_s = 1.5\nshare = 0.25\n'
        "[sumo.ring]\nlength_m = 120.0\nvehicles = 6\n",
        encoding="utf-8",
    )
    out = tmp_path / "out"  # type: ignore[operator]
    monkeypatch.chdir(d)
    assert main(["sumo", "s.toml", "--out", str(out), "--no-plots"]) == 0
    monkeypatch.chdir(tmp_path)  # another folder: the relative cell file is not here
    assert not os.path.exists("data/my_cell.toml")
    run = load_sumo(out)
    assert run.scenario.ev.cell.soc0 == 0.73 and len(run.vehicles) == 6

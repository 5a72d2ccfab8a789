"""The shipped SUMO networks' netconvert runs once per process for the same plain XML (aev_ocp.sumo.networks.netconvert,
issue 40): a second build of the same network in another folder runs no netconvert and writes the same bytes as
a fresh netconvert; a network whose parameters change (any field that reaches the plain XML) is built again,
and is the one a fresh netconvert writes for the new parameters."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from aev_ocp.sumo import sumo_available

pytestmark = pytest.mark.skipif(not sumo_available(), reason="SUMO (eclipse-sumo) not installed")


def _body(net: Path) -> str:
    """The network file without netconvert's 'generated on <time>' line (the only line two builds differ in)."""
    return re.sub(r"generated on \S+", "generated on", net.read_text(encoding="utf-8"))


@pytest.fixture
def runs(monkeypatch: pytest.MonkeyPatch) -> list[list[str]]:
    """The netconvert commands run from here on, with this process's built networks forgotten first."""
    from aev_ocp.sumo import networks

    monkeypatch.setattr(networks, "_BUILT", {})
    calls: list[list[str]] = []
    real = networks.run_tool

    def counted(args: list[str], what: str, cwd: Any = None) -> None:
        calls.append(list(args))
        real(args, what, cwd)

    monkeypatch.setattr(networks, "run_tool", counted)
    return calls


def _fresh(build: Any, net: Any, folder: Path) -> str:
    """The network netconvert itself writes for ``net`` (this process's built networks set aside)."""
    from aev_ocp.sumo import networks

    kept = dict(networks._BUILT)
    networks._BUILT.clear()
    try:
        return _body(build(net, folder, 47.0)[0])
    finally:
        networks._BUILT.clear()
        networks._BUILT.update(kept)


def _built_again(runs: list[list[str]], build: Any, first: Path, changed: list[Any], folder: Path) -> None:
    """Each network of ``changed`` (a field of the plain XML changed) runs netconvert again, differs from ``first``
    and is the network a fresh netconvert writes for it."""
    for k, net in enumerate(changed):
        n = len(runs)
        path = build(net, folder / f"changed{k}", 47.0)[0]
        assert len(runs) == n + 1
        assert _body(path) != _body(first)
        assert _body(path) == _fresh(build, net, folder / f"fresh{k}")


def test_the_same_ring_is_built_once_and_a_changed_one_again(runs: list[list[str]], tmp_path: Path) -> None:
    from aev_ocp.sumo.networks import RingNetwork, build_ring

    a = RingNetwork(length_m=263.0, vehicles=19, lane_speed_mps=31.7)
    net1, routes1 = build_ring(a, tmp_path / "one", 47.0)
    net2, routes2 = build_ring(a, tmp_path / "two", 47.0)
    assert len(runs) == 1 and net2 == tmp_path / "two" / "ring.net.xml"
    assert net2.read_bytes() == net1.read_bytes()
    assert routes2[0].read_bytes() == routes1[0].read_bytes()
    assert "/one/" not in net2.read_text(encoding="utf-8")  # its header names the inputs relative to its folder
    # a field that changes the plain XML builds again: the lane's speed limit, the circumference
    changed = [
        RingNetwork(length_m=263.0, vehicles=19, lane_speed_mps=27.3),
        RingNetwork(length_m=241.0, vehicles=19, lane_speed_mps=31.7),
    ]
    _built_again(runs, build_ring, net1, changed, tmp_path)
    assert 'speed="27.30"' in (tmp_path / "changed0" / "ring.net.xml").read_text(encoding="utf-8")
    # fields that only reach the routes (the cars) reuse the network
    n = len(runs)
    build_ring(
        RingNetwork(length_m=263.0, vehicles=11, lane_speed_mps=31.7, perturbation_m=1.3), tmp_path / "cars", 47.0
    )
    assert len(runs) == n


def test_the_same_merge_is_built_once_and_a_changed_one_again(runs: list[list[str]], tmp_path: Path) -> None:
    from aev_ocp.sumo.networks import MergeNetwork, build_merge

    a = MergeNetwork(accel_lane_m=213.0, main_speed_mps=29.1)
    net1 = build_merge(a, tmp_path / "one", 47.0)[0]
    assert build_merge(a, tmp_path / "two", 47.0)[0].read_bytes() == net1.read_bytes() and len(runs) == 1
    assert _body(net1) == _fresh(build_merge, a, tmp_path / "fresh")
    changed = [
        MergeNetwork(accel_lane_m=187.0, main_speed_mps=29.1),
        MergeNetwork(accel_lane_m=213.0, ramp_speed_mps=17.9),
    ]
    _built_again(runs, build_merge, net1, changed, tmp_path)
    # a flow reaches the routes only: the network is reused
    n = len(runs)
    build_merge(MergeNetwork(accel_lane_m=213.0, main_speed_mps=29.1, main_flow_vph=1730.0), tmp_path / "flow", 47.0)
    assert len(runs) == n


def test_a_failed_netconvert_is_not_kept(
    runs: list[list[str]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A netconvert that fails raises its one-line error and keeps nothing: the next build runs it again."""
    from aev_ocp.sumo import SumoError, networks
    from aev_ocp.sumo.networks import RingNetwork, build_ring

    net = RingNetwork(length_m=263.0, vehicles=19, lane_speed_mps=31.7)
    real = networks._write

    def broken(path: Path, text: str) -> Path:  # the nodes' file cut short: netconvert refuses it
        return real(path, "<nodes>" if path.name.endswith(".nod.xml") else text)

    with monkeypatch.context() as m:
        m.setattr(networks, "_write", broken)
        with pytest.raises(SumoError, match="netconvert"):
            build_ring(net, tmp_path / "bad", 47.0)
    assert networks._BUILT == {}
    assert build_ring(net, tmp_path / "good", 47.0)[0].is_file() and len(runs) == 2

"""Ring and SUMO sweeps through the study layer (issue 36.5): tasks, the executors (in process, pool, Dask) into
the hash-keyed store, resume, and the table over seeds. A tiny sweep: seconds."""

from __future__ import annotations

import dataclasses
import json

import pytest

from aev_ocp.params import ParameterError
from aev_ocp.study.runner import Store, execute
from aev_ocp.study.traffic import ring_tasks, sumo_tasks, traffic_table
from aev_ocp.study.traffic_study import run_traffic_study


def _metrics(results):
    return {k: r["metrics"] for k, r in sorted(results.items())}


def test_ring_sweep_through_the_study_layer(tmp_path) -> None:
    """ring_calibrated, 40 s: 0 and 1 FollowerStopper × 2 densities × seeds 0, 1 = 8 tasks. A point's metrics are
    those of the same ring run directly; the pool stores what the in-process loop stores; a rerun computes
    nothing; the table pairs each density's AEV row with its all-human row."""
    from aev_ocp.ring.field import field_metrics
    from aev_ocp.ring.scenario import build_ring, load_ring_scenario, spread
    from aev_ocp.ring.simulate import RingOptions, RingSimulator

    tasks = ring_tasks("ring_calibrated", [0, 1], ["followerstopper"], [95.65, 84.6], [0, 1], t_end_s=40.0)
    assert len(tasks) == 8 and len({t.key for t in tasks}) == 8
    res_in, rows = run_traffic_study(tasks, tmp_path / "a", executor="inprocess")
    assert all(r["status"] == "ok" for r in res_in.values())
    # one point against a direct run
    t = next(t for t in tasks if t.spec["values"] == {"density_per_km": 84.6, "aevs": 1, "seed": 1, "t_end_s": 40.0})
    sc = load_ring_scenario("ring_calibrated")
    sc = dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, seed=1))
    ring, init = build_ring(sc, "followerstopper", 1000.0 * 22 / 84.6, spread(1, 22))
    direct = field_metrics(RingSimulator(ring, RingOptions(braking_from_s=20.0)).run(init, 40.0), 20.0)
    got = res_in[t.key]["metrics"][0]
    for k in ("throughput_veh_per_h", "speed_std_mps", "battery_energy_kWh_per_100km", "braking_events"):
        assert got[k] == direct[k]
    # the pool stores the same
    res_pool, rows_pool = run_traffic_study(tasks, tmp_path / "b", executor="pool", workers=2)
    assert _metrics(res_pool) == _metrics(res_in) and rows_pool == rows
    # resume: nothing left to compute
    seen: list[str] = []
    execute(tasks, Store(tmp_path / "a"), executor="inprocess", on_result=lambda k, r: seen.append(k))
    assert seen == []
    # the table: per density, all human (baseline) and 1 AEV with paired verdicts over the 2 seeds
    assert [(r["density_per_km"], r["run"]) for r in rows] == [
        (95.65, "0 human"),
        (95.65, "1 followerstopper"),
        (84.6, "0 human"),
        (84.6, "1 followerstopper"),
    ]
    assert rows[1]["seeds"] == 2 and rows[1]["speed_std_mps_vs_0 human"]["verdict"] in ("better", "worse", "tie")
    doc = json.loads((tmp_path / "a" / "traffic.json").read_text())
    assert doc["tasks"] == 8 and len(doc["rows"]) == 4
    assert (tmp_path / "a" / "traffic.md").read_text().count("\n") == 6
    with pytest.raises(ParameterError, match="controller"):
        ring_tasks("ring_calibrated", [1], ["nope"])
    with pytest.raises(ParameterError, match="do not fit"):
        ring_tasks("ring_calibrated", [1], ["followerstopper"], [250.0])


def test_ring_points_on_dask(tmp_path) -> None:
    pytest.importorskip("dask.distributed")
    tasks = ring_tasks("ring_calibrated", [0, 1], ["followerstopper"], None, [3, 4], t_end_s=20.0)
    res_d = execute(tasks, Store(tmp_path / "d"), executor="dask", workers=1)
    res_i = execute(tasks, Store(tmp_path / "i"), executor="inprocess")
    assert _metrics(res_d) == _metrics(res_i)
    assert len(traffic_table(tasks, res_d)) == 2


def test_sumo_sweep_through_the_study_layer(tmp_path) -> None:
    """sumo_ring for 30 s: share 0 and 0.2 under the paper's law × seeds 1, 2 through the in-process executor;
    every point carries the field's metrics; throughput = density × mean speed on the ring."""
    pytest.importorskip("libsumo")
    tasks = sumo_tasks("sumo_ring", [0.0, 0.2], ["proposed"], [1, 2], t_end_s=30.0)
    assert len(tasks) == 4
    results, rows = run_traffic_study(tasks, tmp_path, executor="inprocess")
    for r in results.values():
        assert r["status"] != "error", r["message"]
        m = r["metrics"][0]
        assert m["throughput_veh_per_h"] > 0 and m["speed_std_mps"] >= 0
    assert [r["run"] for r in rows] == ["0.0 sumo", "0.2 proposed"]

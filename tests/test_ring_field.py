"""The field's metrics of ring runs over seeds (issue 36.2): hand-computed values on a synthetic trajectory, braking
events counted on the integrator's steps (the same count whatever the output sampling), seed tables with intervals
and verdicts against the all-human ring."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from aev_ocp.intervals import summarize
from aev_ocp.params import ParameterError
from aev_ocp.ring.field import (
    FIELD_METRICS,
    field_metrics,
    scenario_over_seeds,
    seed_table,
    table_markdown,
    window_metrics,
)
from aev_ocp.ring.humans import calibrated_ring
from aev_ocp.ring.simulate import RingOptions, RingSimulator, uniform_flow


def test_window_metrics_against_hand_values() -> None:
    """3 vehicles on 100 m at 4, 5 and 7 m/s for 20 s: 320 m driven, v̄ = 320/(3·20) = 5.333 m/s, density 30/km,
    throughput 30 × 5.333 × 3.6 = 576 veh/h, a lap 100/5.333 = 18.75 s; 3 braking events over 0.32 km = 9.375 per
    vehicle-km; 1.2 MJ of battery energy = 1.2e6/0.32/3.6e4 = 104.17 kWh/100 km; 800 J of heat = 2500 J/km."""
    t = np.array([10.0, 20.0, 30.0])
    v = np.array([4.0, 5.0, 7.0])
    dist = 50.0 + (t[:, None] - 10.0) * v[None, :]
    speed = np.tile(v, (3, 1))
    energy = np.array([[0, 0, 0], [2e5, 2e5, 2e5], [4e5, 4e5, 4e5]], float)
    heat = np.array([[10, 10, 10], [100, 100, 100], [310, 250, 270]], float)
    m = window_metrics(t, dist, speed, energy, heat, 3, 100.0)
    assert m["mean_speed_mps"] == pytest.approx(320.0 / 60.0, rel=1e-12)
    assert m["density_per_km"] == pytest.approx(30.0, rel=1e-12)
    assert m["throughput_veh_per_h"] == pytest.approx(576.0, rel=1e-12)
    assert m["travel_time_per_lap_s"] == pytest.approx(18.75, rel=1e-12)
    assert m["speed_std_mps"] == pytest.approx(float(np.std([4.0, 5.0, 7.0])), rel=1e-12)
    assert m["braking_events_per_veh_km"] == pytest.approx(9.375, rel=1e-12)
    assert m["battery_energy_kWh_per_100km"] == pytest.approx(1.2e6 / 0.32 / 3.6e4, rel=1e-12)
    assert m["heat_pack_J_per_km"] == pytest.approx(800.0 / 0.32, rel=1e-12)
    with pytest.raises(ParameterError, match="window"):
        window_metrics(t[:1], dist[:1], speed[:1], energy[:1], heat[:1], 0, 100.0)


def test_braking_counter_on_a_hand_sequence() -> None:
    """The counter's rule on irregular step ends (model time = s here): a < −1 from 1.0 to 1.7 (held 0.7 s: one
    event), from 2.0 to 2.3 (0.3 s: none), from 3.1 on, held 0.5 s exactly at 3.6 (one, begun after the window's
    start 2.5 s: counted in the window too); a second vehicle never brakes."""
    ring = calibrated_ring(seed=1)
    sim = RingSimulator(ring, RingOptions())
    sim._brake = np.zeros((2, 4))
    sim._brake[:, 0] = -1.0
    sim._brake_args = (-1.0, 0.5, 2.5)
    seq = [(0.5, -0.5), (1.0, -1.2), (1.3, -2.0), (1.7, -1.1), (1.9, 0.2), (2.0, -1.5), (2.3, -1.1), (2.4, 0.0)]
    seq += [(3.1, -1.01), (3.35, -3.0), (3.6, -1.2), (4.0, -1.3), (4.2, 0.5)]
    for te, a in seq:
        sim._count_braking(te, np.array([a, 0.3]))
    assert sim._brake[:, 2].tolist() == [2.0, 0.0]
    assert sim._brake[:, 3].tolist() == [1.0, 0.0]


def test_braking_events_do_not_depend_on_the_output_sampling() -> None:
    """The calibrated ring (noise, reaction times) over 200 s sampled every 0.1, 0.5 and 2 s: the same braking
    events in each (counted on the integrator's steps); a count on the samples would differ between them."""
    ring = calibrated_ring(seed=12)
    counts, sampled = [], []
    for dt in (0.1, 0.5, 2.0):
        res = RingSimulator(ring, RingOptions(rtol=1e-6, atol=1e-6, dt_out_s=dt, braking_from_s=100.0)).run(
            uniform_flow(ring, shift_m=2.0), 200.0
        )
        m = field_metrics(res, 100.0)
        counts.append(m["braking_events"])
        a = res.accel_mps2[res.t_s >= 100.0]
        on = a < -1.0
        sampled.append(int(np.sum(on[1:] & ~on[:-1])))
    assert counts[0] > 20 and counts == [counts[0]] * 3
    assert len(set(sampled)) > 1  # what the counter avoids
    with pytest.raises(ParameterError, match="braking_from_s"):
        field_metrics(res, 150.0)


def test_seed_table_intervals_and_verdicts() -> None:
    rng = np.random.default_rng(5)
    base = [dict.fromkeys(FIELD_METRICS, 0.0) for _ in range(10)]
    aev = [dict.fromkeys(FIELD_METRICS, 0.0) for _ in range(10)]
    for b, a in zip(base, aev):
        e = float(rng.normal(18.0, 0.5))
        b["battery_energy_kWh_per_100km"], a["battery_energy_kWh_per_100km"] = e, e - 3.0 + float(rng.normal(0, 0.2))
        s = float(rng.normal(2.0, 0.3))
        b["throughput_veh_per_h"], a["throughput_veh_per_h"] = s, s - 0.5 + float(rng.normal(0, 0.05))
        b["speed_std_mps"], a["speed_std_mps"] = s, s + float(rng.normal(0, 0.3))
    rows = seed_table({"all human": base, "aev": aev}, "all human")
    e = [r["battery_energy_kWh_per_100km"] for r in aev]
    assert rows[1]["battery_energy_kWh_per_100km"] == summarize(e).as_dict()
    assert rows[1]["battery_energy_kWh_per_100km_vs_all human"]["verdict"] == "better"
    assert rows[1]["throughput_veh_per_h_vs_all human"]["verdict"] == "worse"  # higher throughput is better
    assert rows[1]["speed_std_mps_vs_all human"]["verdict"] == "tie"
    assert "better" in table_markdown(rows) and rows[0]["failed"] == 0
    with pytest.raises(ParameterError, match="baseline"):
        seed_table({"aev": aev}, "all human")


def test_scenario_over_seeds_pairs_the_runs() -> None:
    """ring_calibrated over 3 seeds for 120 s: every run once per seed, the AEV run paired with the all-human run
    of the same seed (the same human draws)."""
    from aev_ocp.ring.scenario import load_ring_scenario

    sc = load_ring_scenario("ring_calibrated")
    sc = dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, metrics_from_s=60.0))
    runs = scenario_over_seeds(sc, (4, 5, 6), t_end_s=120.0)
    assert list(runs) == ["all human", "followerstopper"]
    assert [r["seed"] for r in runs["all human"]] == [4, 5, 6]
    for r in runs["all human"] + runs["followerstopper"]:
        assert r["status"] == "ok" and r["window_s"][0] == 60.0
        assert r["throughput_veh_per_h"] == pytest.approx(r["density_per_km"] * r["mean_speed_mps"] * 3.6, rel=1e-12)
        assert math.isfinite(r["battery_energy_kWh_per_100km"])
    rows = seed_table(runs, "all human")
    assert rows[1]["seeds"] == 3 and "speed_std_mps_vs_all human" in rows[1]


def test_count_braking_rule_and_sumo_thinning() -> None:
    """count_braking on 0.1 s steps: a < −1 for 0.4 s (no), 0.6 s (one), then 1.2 s (one); SUMO's per-vehicle record
    counts on its own steps, so keeping every 7th step of the output changes neither the braking events nor the
    speed sums behind the speed std."""
    from aev_ocp.params import EVParams
    from aev_ocp.ring.field import count_braking
    from aev_ocp.sumo.run import _result, _Track

    t = np.arange(0.0, 5.0, 0.1)
    a = np.zeros(t.size)
    a[5:9] = -1.5  # 0.5 … 0.8 s: held 0.3 s between step ends
    a[12:19] = -2.0  # 1.2 … 1.8 s: 0.6 s
    a[25:38] = -1.1  # 2.5 … 3.7 s
    assert count_braking(t, a) == 2
    assert count_braking(t, a, hold_s=0.3) == 3 and count_braking(t, a, -1.6) == 1
    v = 8.0 + np.cumsum(a) * 0.1
    tr = _Track("v1", "car", "r", False, "", 2.5, 0.0)
    tr.t_s, tr.v, tr.odo = list(t), list(v), list(np.cumsum(v) * 0.1)
    tr.gap, tr.v_lead, tr.lane = [20.0] * t.size, list(v), ["e_0"] * t.size
    tr.x_bat = [np.array([0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 0.0])] * t.size
    tr.current = [0.0] * t.size
    ev = EVParams()
    r1, r7 = _result(tr, ev, 250.0, 0.1, 1), _result(tr, ev, 250.0, 0.1, 7)
    assert r1.t.size > r7.t.size
    assert r1.meta["braking_events"] == r7.meta["braking_events"] == count_braking(t[:-1], np.diff(v) / 0.1)
    assert r1.meta["speed_steps"] == r7.meta["speed_steps"]


def test_the_ring_table_carries_the_field_columns() -> None:
    """aev-ocp ring's fleet table (run_ring_scenario) has the same throughput and braking events per vehicle-km as
    field_metrics of the same run (the second half of 60 s)."""
    from aev_ocp.ring.run import run_ring_scenario
    from aev_ocp.ring.scenario import load_ring_scenario

    sc = load_ring_scenario("ring_calibrated")
    for e in run_ring_scenario(sc, t_end_s=60.0):
        f = field_metrics(e.result, 30.0)
        assert e.fleet["throughput_veh_per_h"] == pytest.approx(f["throughput_veh_per_h"], rel=1e-12)
        assert e.fleet["braking_events_per_veh_km"] == pytest.approx(f["braking_events_per_veh_km"], rel=1e-12)

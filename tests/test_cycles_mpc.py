"""MPC on drive cycles (issue 8 items 5-6): the shipped MPC cycle scenarios load and run, and the section's
table builder flags runs that cannot be compared (ended by an event, other distance/duration) and never
ranks them."""

from __future__ import annotations

import dataclasses
import math
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from aev_ocp.control import ClosedLoop, ControlSequence
from aev_ocp.models.carfollowing import OVFL, V_INF, Proposed
from aev_ocp.models.leader import PaperLeader
from aev_ocp.mpc.cycles import cycle_rows, cycle_scenario, platoon_rows, rank_rows, run_cycle
from aev_ocp.mpc.cycles_section import platoon_markdown, verdicts, write_tables
from aev_ocp.params import EVParams, ParameterError
from aev_ocp.results import Event
from aev_ocp.scenarios import ScenarioWarning, find_scenario, load_scenario, shipped_scenarios
from aev_ocp.simulate import simulate_platoon

NEW = {
    "mpc_udds_single": ("udds", 1, 15.0, 17.0, 1369.0),
    "mpc_hwfet_single": ("hwfet", 1, 15.0, 17.0, 765.0),
    "mpc_us06_single": ("us06", 1, 20.0, 22.0, 600.0),
    "mpc_udds_platoon": ("udds", 5, 15.0, 17.0, 1369.0),
}


@pytest.mark.parametrize("name", sorted(NEW))
def test_new_cycle_scenarios_load_with_default_formulation(name: str) -> None:
    cyc, n, L, U, dur_s = NEW[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)  # as tests/test_scenarios.py: leaders below V∞
        sc = load_scenario(find_scenario(name))
    assert sc.name == name and name in shipped_scenarios() and sc.leader.max_speed(sc.t_end) < V_INF
    assert sc.n_followers == n and sc.compare == ("proposed", "ovfl")
    assert (sc.units.length_m, sc.units.speed_mps) == (L, U)
    assert sc.gaps0 == (0.8,) * n and sc.speeds0 == (0.0,) * n
    assert 0 <= sc.t_end * sc.units.time_s - dur_s < 0.1  # the whole cycle (rounded up to the MPC step)
    steps = sc.t_end / sc.extra["mpc"].settings.dt  # the closed loop needs whole MPC steps
    assert abs(steps - round(steps)) < 1e-9
    assert sc.leader.max_speed(sc.t_end) < 2.0  # below the §9 v_max
    cfg = sc.extra["mpc"]
    assert cfg.settings.predictor not in ("oracle",) and cfg.vehicles is None
    # the [mpc] table only names the forecast and the vehicles: the formulation is MPCSettings()'s default
    doc = tomllib.loads(Path(find_scenario(name)).read_text(encoding="utf-8"))
    assert set(doc["mpc"]) <= {"predictor", "vehicles", "follower_predictor"}


@pytest.mark.parametrize("name", ["mpc_udds_single", "mpc_us06_single", "mpc_udds_platoon"])
def test_new_cycle_scenarios_run_on_a_short_horizon(name: str) -> None:
    sc = load_scenario(find_scenario(name)).replace(t_end=0.3)
    runs, _ = run_cycle(sc, (sc.extra["mpc"].settings.predictor,), laws=("proposed",))
    r = runs[("mpc", sc.extra["mpc"].settings.predictor)]
    assert r.status == "ok" and r.t[-1] == pytest.approx(0.3)
    steps = r.meta["mpc_steps"]
    dt = sc.extra["mpc"].settings.dt
    assert all(len(st["solve_ms"]) == round(0.3 / dt) for st in steps)
    # the followers start at rest 0.8 L = 12 m (UDDS) / 16 m (US06) behind: initial gap in metres
    assert r.gap[0] * sc.units.length_m == pytest.approx(0.8 * sc.units.length_m)
    assert np.all(r.speed >= -1e-9)


def test_cycle_scenario_segment_and_bad_input() -> None:
    sc = cycle_scenario("hwfet", 30.0)
    assert sc.t_end * sc.units.time_s == pytest.approx(30.0)  # 34.0 model time: whole MPC steps already
    sc = cycle_scenario("us06", 10.03)  # 11.033 model time, rounded up to 111 MPC steps of 0.1
    assert sc.t_end == pytest.approx(11.1) and sc.t_end * sc.units.time_s >= 10.03
    assert cycle_scenario("paper", 1e6).t_end == 70.0  # longer than the scenario: unchanged
    with pytest.raises(ParameterError, match="cycle"):
        cycle_scenario("nedc")
    with pytest.raises(ParameterError, match="segment_s"):
        cycle_scenario("udds", -3.0)


@pytest.fixture(scope="module")
def tiny_runs() -> dict:
    """Four runs behind the paper leader: the reference, OVFL (comparable), a shorter run (other duration
    and distance) and an open-loop run that accelerates into the leader (ended by a collision)."""
    ev, lead = EVParams(), PaperLeader()
    ref = simulate_platoon(lead, [Proposed()], [1.3], [1.6], 3.0, ev=ev, dt_out=0.05)
    ovfl = simulate_platoon(lead, [OVFL()], [1.3], [1.6], 3.0, ev=ev, dt_out=0.05)
    short = simulate_platoon(lead, [Proposed()], [1.3], [1.6], 2.4, ev=ev, dt_out=0.05)
    crash = ClosedLoop(lead, [ControlSequence((1.7,) * 40, 0.1, "rush")], ev).run([0.35], [1.6], 3.0)
    assert crash.status != "ok" and crash.t[-1] < 3.0  # the constructed event
    # ended by an event at t_end: same duration and distance as OVFL, only the event flag can catch it
    ended = dataclasses.replace(ovfl, events=[Event("negative_speed", 3.0, 0, "constructed")])
    return {
        ("proposed", None): ref,
        ("ovfl", None): ovfl,
        ("mpc", "constant-velocity"): short,
        ("mpc", "decaying-acceleration"): crash,
        ("mpc", "cooperative"): ended,
    }


def test_table_builder_flags_and_never_ranks_non_comparable_rows(tiny_runs: dict) -> None:
    rows = {(r["controller"], r["predictor"]): r for r in rank_rows(cycle_rows("paper", tiny_runs))}
    ref, ovfl = rows[("proposed", "—")], rows[("ovfl", "—")]
    short, crash = rows[("mpc", "constant-velocity")], rows[("mpc", "decaying-acceleration")]
    assert ref["comparable"] and ovfl["comparable"] and ref["flags"] == ""
    assert (
        not short["comparable"] and "duration" in short["flags"] and short["duration_diff_pct"] == pytest.approx(-20.0)
    )
    assert not crash["comparable"] and "event" in crash["flags"]
    ended = rows[("mpc", "cooperative")]
    assert not ended["comparable"] and ended["flags"] == "event: negative_speed" and ended["rank"] is None
    assert short["rank"] is None and crash["rank"] is None
    # rank by pack ∫Q/km, computed here from the raw results: heat / (∫v dt · L / 1000)
    per_km = {}
    for key in (("proposed", None), ("ovfl", None)):
        r = tiny_runs[key]
        dist_km = np.trapezoid(r.speed[:, 0], r.t) * r.units.length_m / 1000.0
        per_km[key[0]] = r.heat_J[-1, 0] / dist_km
        assert rows[(key[0], "—")]["heat_pack_J_per_km"] == pytest.approx(per_km[key[0]], rel=1e-3)
    best = min(per_km, key=per_km.get)
    assert rows[(best, "—")]["rank"] == 1 and {ref["rank"], ovfl["rank"]} == {1, 2}
    text = "\n".join(verdicts(list(rows.values())))
    assert "MPC/constant-velocity not comparable" in text and "MPC/decaying-acceleration not comparable" in text
    assert "MPC/cooperative not comparable (event: negative_speed)" in text
    assert f"lowest pack ∫Q/km among comparable runs: {best}" in text  # a law here: the MPC rows are not ranked
    # the equal-distance view ranks every run that did not end by an event (the MPC rows too), by its ∫Q/km
    eq = {k: r for k, r in rows.items() if r["status"] == "ok"}
    assert sorted(r["rank_eq_distance"] for r in eq.values()) == list(range(1, len(eq) + 1))
    assert all(r["rank_eq_distance"] is None for r in rows.values() if r["status"] != "ok")
    first = min(eq.values(), key=lambda r: r["heat_pack_J_per_km_eq_distance"])
    assert first["rank_eq_distance"] == 1 and "Equal distance (every run up to" in text
    assert min(r["distance_m"] for r in eq.values()) == pytest.approx(first["eq_distance_m"], rel=1e-9)


def test_table_builder_without_reference_flags_every_row(tiny_runs: dict) -> None:
    runs = {k: v for k, v in tiny_runs.items() if k != ("proposed", None)}
    rows = rank_rows(cycle_rows("paper", runs))
    assert all(not r["comparable"] and "no reference" in r["flags"] and r["rank"] is None for r in rows)


def test_solve_time_percentiles_and_written_tables(tiny_runs: dict, tmp_path: Path) -> None:
    r = tiny_runs[("mpc", "constant-velocity")]
    r.meta["mpc_steps"] = [{"solve_ms": [float(k) for k in range(100, 0, -1)]}]  # 1 … 100 ms, any order
    rows = rank_rows(cycle_rows("paper", tiny_runs))
    row = next(x for x in rows if x["predictor"] == "constant-velocity")
    # linear interpolation between order statistics: p50 = (50 + 51)/2, p99 = 99 + 0.01
    assert row["solve_ms_p50"] == pytest.approx(50.5) and row["solve_ms_p99"] == pytest.approx(99.01)
    assert math.isnan(next(x for x in rows if x["controller"] == "ovfl")["solve_ms_p50"])
    plat = platoon_rows(tiny_runs, ("mpc", "constant-velocity"))
    assert not plat[0]["comparable"] and "not ranked" in platoon_markdown(plat)
    md, files = write_tables(rows, plat, tmp_path / "t", {"segment_s": 3.0})
    assert md.count("\n") == len(rows) + 2 and "**no**" in md and "not ranked" in md
    csv_lines = (tmp_path / "t" / "cycles.csv").read_text().splitlines()
    assert len(csv_lines) == len(rows) + 1 and csv_lines[0].startswith("cycle,vehicle,controller")
    assert all(f.stat().st_size > 0 for f in files)


def test_segments_end_once_the_leader_has_stood_still() -> None:
    """leader_rest_end against the SI cycle data read independently: UDDS's first stop after 120 s begins at
    125 s, so a 20 s hold ends at 145 s; HWFET has no such stop (whole cycle)."""
    from aev_ocp.mpc.cycles import STOP_HOLD_S, leader_rest_end

    sc = cycle_scenario("udds")
    csv = Path(__file__).resolve().parents[1] / "aev_ocp" / "data" / "cycles"
    t_si, v_si = np.loadtxt(next(csv.glob("udds*")), delimiter=",", skiprows=1, unpack=True)[:2]
    i0 = np.flatnonzero((t_si >= 120.0) & (v_si == 0.0))[0]  # the first sample at rest after 120 s
    t_rest = leader_rest_end(sc, sc.units.time_from_si(120.0))
    assert t_rest is not None and abs(sc.units.time_to_si(t_rest) - (t_si[i0] + STOP_HOLD_S)) <= 0.5 + 1e-9
    seg = cycle_scenario("udds", 120.0, end_at_rest=True)
    assert seg.t_end >= t_rest and seg.t_end - t_rest < seg.extra["mpc"].settings.dt + 1e-9
    hw = cycle_scenario("hwfet")
    assert cycle_scenario("hwfet", 120.0, end_at_rest=True).t_end == hw.t_end
    assert cycle_scenario("udds", 120.0).t_end < t_rest  # without end_at_rest: the plain cut


def test_cycles_section_runs_end_to_end(tmp_path: Path) -> None:
    """The section on a tiny cap (every run 1.5 model time units): text, tables and the segment sentence."""
    from aev_ocp.mpc.cycles_section import cycles_section

    txt = cycles_section(tmp_path, lambda m: None, cycles=("udds",), predictors=("constant-velocity",), t_end_max=1.5)
    assert (
        txt.startswith("## MPC on drive cycles")
        and "stood still for 20 s" in txt
        and "udds 1 s, capped at t = 1.5" in txt
    )
    assert (tmp_path / "mpc_cycles" / "cycles.csv").stat().st_size > 0

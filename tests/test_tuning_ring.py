"""The ring in the tuning (aev_ocp.tuning.ring), the drive-cycle tuned sets in the safety suite (aev_ocp.tuning.safety)
and ``aev-ocp sumo --seeds`` (aev_ocp.sumo.cli): the same budget for every ring controller, the ring's objective and
constraints at, inside and outside their limits, tuned sets that reach the controller, and the seeds' intervals
against SciPy's."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("optuna")

from aev_ocp.params import ParameterError  # noqa: E402
from aev_ocp.tuning import ring as tr  # noqa: E402

# ----------------------------------------------------------------------------- equal budget on the ring


def _fake_ring_execute(log: list[tuple[str, dict[str, Any]]]) -> Any:
    """A stand-in for the study runner: a ring task's result from its controller and seed (no simulation)."""

    def execute(tasks: list[Any], store: Any, **kw: Any) -> dict[str, dict[str, Any]]:
        out = {}
        for t in tasks:
            log.append((t.controller, t.spec))
            seed = t.spec["values"]["seed"]
            m = {
                "status": "ok",
                "battery_energy_kWh_per_100km": 17.3 + 0.01 * seed + 0.1 * len(log) % 7,
                "mean_speed_mps": 2.31 + 0.002 * seed,
                "speed_std_mps": 2.7,
                "braking_events_per_veh_km": 40.0,
                "throughput_veh_per_h": 800.0,
                "heat_pack_J_per_km": 300.0,
            }
            out[t.key] = {"key": t.key, "status": "ok", "message": "", "metrics": [m]}
        return out

    return execute


def test_every_ring_controller_gets_the_same_budget(tmp_path: Path, monkeypatch: Any) -> None:
    import aev_ocp.study.runner as runner

    log: list[tuple[str, dict[str, Any]]] = []
    monkeypatch.setattr(runner, "execute", _fake_ring_execute(log))
    train, held = (3, 5), (21, 22, 23)
    res = tr.run_ring_tuning(budget=4, out=tmp_path / "r", train_seeds=train, heldout_seeds=held, batch=3)
    tuned = list(tr.RING_TABLE)
    per: dict[tuple[str, frozenset[int]], int] = {}
    for label, spec in log:
        seeds = frozenset([spec["values"]["seed"]])
        key = (label, frozenset(train) if seeds <= set(train) else frozenset(held))
        per[key] = per.get(key, 0) + 1
    for c in tuned:  # 4 trials × 2 training seeds each; default and tuned on every held-out seed
        assert per[(c, frozenset(train))] == 4 * len(train)
        assert per[(c, frozenset(held))] == 2 * len(held)
    for c in tr.UNTUNED:  # at its defaults only, and never on a training seed
        assert per[(c, frozenset(held))] == len(held) and (c, frozenset(train)) not in per
    assert per[("human", frozenset(train))] == len(train) and per[("human", frozenset(held))] == len(held)
    saved = json.loads((tmp_path / "r" / "ring.json").read_text())
    assert saved["evaluations"] == {c: 4 * len(train) for c in tuned}
    assert len((tmp_path / "r" / "ring_trials.csv").read_text().splitlines()) == 1 + 4 * len(tuned)
    md = (tmp_path / "r" / "ring.md").read_text()
    assert f"4 trials per controller × {len(train)} training seeds = {4 * len(train)}" in md
    assert len(res.rows) == 1 + 2 * len(tuned) + len(tr.UNTUNED)
    # every task ran one AEV (the all-human ones none) at the ring's density
    assert {spec["values"]["aevs"] for label, spec in log if label != "human"} == {1}
    assert {spec["values"]["aevs"] for label, spec in log if label == "human"} == {0}


# ----------------------------------------------------------------------------- objective and constraints


def _run(e: float, v: float, status: str = "ok") -> dict[str, Any]:
    return {"status": status, "battery_energy_kWh_per_100km": e, "mean_speed_mps": v}


def test_ring_objective_is_the_mean_energy_and_the_speed_limit_is_on_inside_outside() -> None:
    human = [_run(19.7, 2.34), _run(19.1, 2.48)]
    # inside: both seeds faster than 0.95 × human
    obj, cons = tr.ring_score([_run(16.4, 2.30), _run(17.2, 2.40)], human)
    assert obj == pytest.approx((16.4 + 17.2) / 2)
    assert cons[0] == 0 and cons[1] == pytest.approx(max(0.95 * 2.34 - 2.30, 0.95 * 2.48 - 2.40)) and cons[1] < 0
    # on the limit on seed 2: feasible (≤ 0), its violation exactly 0
    obj, cons = tr.ring_score([_run(16.4, 2.30), _run(17.2, 0.95 * 2.48)], human)
    assert cons[1] == pytest.approx(0.0, abs=1e-12)
    # outside on seed 1 only: the largest shortfall in m/s
    obj, cons = tr.ring_score([_run(15.1, 2.1), _run(17.2, 2.40)], human)
    assert cons[1] == pytest.approx(0.95 * 2.34 - 2.1) and cons[1] > 0
    # a run ended on an event: counted, and the objective is the penalty
    obj, cons = tr.ring_score([_run(math.nan, math.nan, "collision"), _run(17.2, 2.40)], human)
    assert cons[0] == 1 and obj == tr.PENALTY_KWH_PER_100KM
    # another share moves the limit
    _, cons = tr.ring_score([_run(16.4, 2.30), _run(17.2, 2.40)], human, share=0.99)
    assert cons[1] == pytest.approx(max(0.99 * 2.34 - 2.30, 0.99 * 2.48 - 2.40))
    with pytest.raises(ParameterError, match="one each per seed"):
        tr.ring_score([_run(16.4, 2.30)], human)


@pytest.mark.parametrize(
    "train, held, words",
    [
        ([1, 2], [2, 11, 12], ["[2]", "both"]),
        ([1], [11], ["heldout_seeds", "2 seeds"]),
        ([], [11, 12], ["train_seeds"]),
        ([1, -3], [11, 12], ["train_seeds"]),
        ([1, 1], [11, 12], ["train_seeds"]),
        ([1, 2.5], [11, 12], ["train_seeds", "whole"]),
    ],
)
def test_bad_seeds_are_refused_naming_them(train: list[Any], held: list[Any], words: list[str]) -> None:
    with pytest.raises(ParameterError) as e:
        tr.check_seeds(train, held)
    for w in words:
        assert w in str(e.value)


def test_bad_ring_controllers_and_horizon_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="'pid'"):
        tr.run_ring_tuning(["proposed", "pid"], budget=2, out=tmp_path / "r")
    with pytest.raises(ParameterError, match="twice"):
        tr.run_ring_tuning(["idm", "idm"], budget=2, out=tmp_path / "r")
    with pytest.raises(ParameterError, match="t_end_s = 900"):
        tr.run_ring_tuning(["idm"], budget=2, out=tmp_path / "r", t_end_s=900.0)
    assert not (tmp_path / "r").exists()


# ----------------------------------------------------------------------------- a tuned set reaches the controller


def _aev(space: str, values: dict[str, float] | None) -> tuple[Any, Any]:
    from aev_ocp.ring.scenario import build_ring, parse_ring_scenario

    rs = tr.ring_set()
    doc = tr.ring_document(tr.RING_TABLE[space], values, rs)
    sc = parse_ring_scenario(doc, rs.file)
    ring, _ = build_ring(sc, tr.RING_TABLE[space].law, aevs=(0,))
    human, _ = build_ring(sc, None)
    return ring.vehicles[0], human


def test_tuned_ring_sets_reach_the_aev_in_si() -> None:
    law, ring = _aev("proposed", {"kappa_per_m": 0.0071, "h_scale_m": 6.3})
    si = law.si_coefficients()
    assert si["kappa_per_m"] == pytest.approx(0.0071) and si["h_scale_m"] == pytest.approx(6.3)
    # the untuned coefficients stay at the scenario's SI values when the scale moves (α = 2 · 5/10 1/s)
    assert si["alpha_per_s"] == pytest.approx(1.0) and si["v_scale_mps"] == pytest.approx(5.0)
    law, _ = _aev("idm", {"T_s": 1.37, "s0_m": 3.4})
    assert (law.T_s, law.s0_m, law.a_mps2) == (pytest.approx(1.37), pytest.approx(3.4), pytest.approx(1.0))
    fs, humans = _aev("followerstopper", {"r_fraction": 0.73, "dx01_m": 6.1, "tau_s": 1.3})
    from aev_ocp.ring.laws import FollowerStopper
    from aev_ocp.ring.simulate import uniform_speed_mps

    u = humans.ev.units
    default, _ = _aev("followerstopper", None)
    expect = FollowerStopper.from_si(
        u, 0.73 * uniform_speed_mps(humans), 1.3, (6.1, 6.1 * 5.25 / 4.5, 6.1 * 6 / 4.5), (1.5, 1.0, 0.5)
    )
    assert fs.r == pytest.approx(expect.r, rel=1e-6)  # r from the all-human ring's uniform speed
    for f in ("dx1", "dx2", "dx3", "d1", "d2", "d3", "tau"):
        assert getattr(fs, f) == pytest.approx(getattr(expect, f))
    assert default.dx1 == pytest.approx(float(u.length_from_si(4.5)))  # the default: the paper's constants
    assert default.r == pytest.approx(expect.r * 0.85 / 0.73)


def test_ring_defaults_are_the_scenarios_settings() -> None:
    rs = tr.ring_set()
    assert tr.ring_defaults(tr.RING_TABLE["ovfl"], rs) == pytest.approx(
        {"alpha_per_s": 1.0, "beta_m2ps": 150.0, "h_scale_m": 10.0, "v_scale_mps": 5.0}
    )
    assert tr.ring_defaults(tr.RING_TABLE["followerstopper"], rs) == pytest.approx(
        {"r_fraction": 0.85, "dx01_m": 4.5, "d1_mps2": 1.5, "tau_s": 0.6}
    )
    assert tr.ring_defaults(tr.RING_TABLE["mpc"], rs)["target_time_gap_s"] == pytest.approx(2.5)


def test_ring_followerstopper_table_is_checked() -> None:
    from aev_ocp.ring.scenario import parse_ring_scenario
    from aev_ocp.scenarios import ScenarioError

    rs = tr.ring_set()
    for table, words in (
        ({"dx0_m": [5.0, 4.0, 6.0]}, "must increase"),
        ({"d_mps2": [1.0, 0.5]}, "three values"),
        ({"tau_s": 0.0}, "tau_s"),
        ({"r": 1.0}, "r"),
    ):
        doc = json.loads(json.dumps(rs.document))
        doc["ring"]["followerstopper"] = table
        with pytest.raises(ScenarioError, match=words):
            parse_ring_scenario(doc, "x.toml")


# ----------------------------------------------------------------------------- tuned sets in the safety suite


def test_tuned_sets_enter_the_suites_laws_in_si() -> None:
    from aev_ocp.safety.cases import CASE_UNITS, suite_cases
    from aev_ocp.safety.run import _law
    from aev_ocp.tuning.safety import suite_overrides

    case = suite_cases()[0]
    vals = {"kappa_per_m": 0.00117, "eps_m2ps2": 0.41, "h_scale_m": 25.1, "v_scale_mps": 26.3}
    own = (("proposed", tuple(suite_overrides("proposed", vals).items())),)
    si = _law("proposed", case, CASE_UNITS, own).si_coefficients()
    for k, v in vals.items():
        assert si[k] == pytest.approx(v)
    assert si["alpha_per_s"] == pytest.approx(2.0 * 17.0 / 15.0)  # untuned: the suite's α in SI
    idm = _law("idm", case, CASE_UNITS, (("idm", (("T_s", 2.74),)),))
    assert idm.T_s == 2.74 and idm.v0_mps == pytest.approx(case.v_ego_mps)  # v0: the case's speed, as the suite's
    from aev_ocp.safety.run import run_suite

    with pytest.raises(ParameterError, match="law_overrides"):
        run_suite(suite_cases()[:1], ["idm"], law_overrides={"idm": {"T_h": 1.0}})
    with pytest.raises(ParameterError, match="'mpc'"):
        run_suite(suite_cases()[:1], ["idm"], law_overrides={"mpc": {"accel_weight": 1.0}})


# ----------------------------------------------------------------------------- aev-ocp sumo --seeds


def test_sumo_seeds_options_are_checked(tmp_path: Path, capsys: Any) -> None:
    from aev_ocp.cli import main

    for argv, words in (
        (["--seeds", "1"], "--seeds = 1"),
        (["--in-process"], "--in-process applies to --seeds"),
        (["--seeds", "3", "--in-process", "--workers", "2"], "--in-process"),
        (["--workers", "2"], "--workers applies to --sweep only"),
    ):
        assert main(["sumo", "sumo_ring", *argv, "--out", str(tmp_path / "s")]) == 2
        assert words in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_sumo_seed_points_add_the_all_sumo_reference() -> None:
    from aev_ocp.sumo.cli import seed_points
    from aev_ocp.sumo.scenario import load_sumo_scenario

    sc = load_sumo_scenario("sumo_merge")
    shares, ctrls, seeds = seed_points(sc, True, 4)
    assert shares == [0.0, 0.2, 0.5] and ctrls == ["proposed", "idm"] and seeds == [42, 43, 44, 45]
    shares, ctrls, _ = seed_points(sc, False, 2)
    assert shares == [0.0, 0.2] and ctrls == ["proposed"]


def _scipy_interval(x: list[float]) -> tuple[float, float, float]:
    from scipy import stats

    a = np.asarray(x, float)
    h = stats.t.ppf(0.975, a.size - 1) * a.std(ddof=1) / math.sqrt(a.size)
    return float(a.mean()), float(a.mean() - h), float(a.mean() + h)


def test_seed_table_intervals_match_scipy() -> None:
    """The table --seeds prints (aev_ocp.study.traffic.traffic_table) against SciPy's t interval and a paired t
    interval of the differences, on 3 and 4 seeds of planted values."""
    from aev_ocp.study.traffic import sumo_tasks, traffic_table

    tasks = sumo_tasks("sumo_ring", [0.0, 0.25], ["proposed"], seeds=[5, 6, 7, 8], t_end_s=10.0)
    energy = {(0.0, 5): 14.61, (0.0, 6): 14.93, (0.0, 7): 14.72, (0.0, 8): 15.02}
    energy.update({(0.25, 5): 13.9, (0.25, 6): 14.41, (0.25, 7): 14.05, (0.25, 8): 14.6})
    results = {}
    for t in tasks:
        v = t.spec["values"]
        e = energy[(v["share"], v["seed"])]
        m = {"status": "ok", "battery_energy_kWh_per_100km": e, "mean_speed_mps": 4.3 + 0.01 * v["seed"]}
        results[t.key] = {"status": "ok", "metrics": [m]}
    rows = {r["run"]: r for r in traffic_table(tasks, results)}
    for label, share in (("0.0 sumo", 0.0), ("0.25 proposed", 0.25)):
        got = rows[label]["battery_energy_kWh_per_100km"]
        mean, lo, hi = _scipy_interval([energy[(share, s)] for s in (5, 6, 7, 8)])
        assert (got["mean"], got["lo"], got["hi"]) == pytest.approx((mean, lo, hi), rel=1e-9)
    d = [energy[(0.25, s)] - energy[(0.0, s)] for s in (5, 6, 7, 8)]
    vs = rows["0.25 proposed"]["battery_energy_kWh_per_100km_vs_0.0 sumo"]
    mean, lo, hi = _scipy_interval(d)
    assert (vs["difference"]["mean"], vs["difference"]["lo"], vs["difference"]["hi"]) == pytest.approx((mean, lo, hi))
    assert vs["verdict"] == ("better" if hi < 0 else "tie")


def test_cli_sumo_seeds_writes_the_intervals_of_its_runs(tmp_path: Path, capsys: Any) -> None:
    """A real --seeds run (3 seeds, 10 s): seeds.md's and traffic.json's intervals are SciPy's of seeds.csv's."""
    from aev_ocp.sumo import sumo_available

    if not sumo_available():
        pytest.skip("SUMO is not installed")
    import csv

    from aev_ocp.cli import main

    out = tmp_path / "s"
    assert main(["sumo", "sumo_ring", "--seeds", "3", "--t-end-s", "10", "--in-process", "--out", str(out)]) == 0
    assert "over 3 seeds" in capsys.readouterr().out
    rows = list(csv.DictReader((out / "seeds.csv").open()))
    assert len(rows) == 6 and {r["seed"] for r in rows} == {"42", "43", "44"}
    table = json.loads((out / "traffic.json").read_text())["rows"]
    for r in table:
        share = 0.0 if r["run"].startswith("0.0") else 0.25
        x = [float(q["mean_speed_mps"]) for q in rows if float(q["share"]) == share]
        mean, lo, hi = _scipy_interval(x)
        got = r["mean_speed_mps"]
        assert (got["mean"], got["lo"], got["hi"]) == pytest.approx((mean, lo, hi), rel=1e-9)
    assert (out / "seeds.md").read_text().count("|") > 10


def test_cli_ring_options_are_parsed_and_checked(tmp_path: Path, capsys: Any) -> None:
    from aev_ocp.cli import main
    from aev_ocp.tuning.cli import seeds_arg

    assert seeds_arg("1,3-5", "--x") == [1, 3, 4, 5] and seeds_arg("7", "--x") == [7]
    for argv, words in (
        (["--ring", "--bounds", "idm.T_s=1:2"], "--bounds applies to the drive-cycle tuning"),
        (["--ring", "--safety-suite"], "--safety-suite applies to the drive-cycle tuning"),
        (["--train-seeds", "1,2"], "--train-seeds applies to --ring only"),
        (["--t-end-s", "60"], "--t-end-s applies to --ring only"),
        (["--ring", "--heldout-seeds", "11-x"], "--heldout-seeds '11-x'"),
        (["--ring", "--train-seeds", "1,2", "--heldout-seeds", "2-12"], "both training and held-out"),
        (["--ring", "--controllers", "proposed,pid"], "'pid'"),
    ):
        assert main(["tune", *argv, "--out", str(tmp_path / "t")]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1
    assert not (tmp_path / "t").exists()

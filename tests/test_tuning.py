"""Equal tuning effort (aev_ocp.tuning): the same budget for every controller, an optimiser that finds a known optimum,
clear errors, and tuned sets that round-trip into a scenario's laws and MPC."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("optuna")

from aev_ocp import tuning as tu  # noqa: E402
from aev_ocp.params import ParameterError  # noqa: E402
from aev_ocp.study.points import parse_scenario_quiet  # noqa: E402


@pytest.fixture(scope="module")
def train() -> list[tu.Case]:
    return tu.training_cases()


# ----------------------------------------------------------------------------- the optimiser on a toy objective


def test_planted_worse_default_is_improved_to_the_known_constrained_optimum() -> None:
    """f = (x − 0.8)² + (y + 0.3)² with the constraint x ≤ 0.5: the constrained optimum is (0.5, −0.3), f = 0.09. The
    default (−0.9, 0.9) is planted far worse (f = 4.33); the tuner must end feasible, near the optimum."""
    params = [tu.Param("x", -1.0, 1.0, "toy"), tu.Param("y", -1.0, 1.0, "toy")]

    def evaluate(sets: list[dict[str, float]]) -> list[tuple[float, list[float]]]:
        return [((s["x"] - 0.8) ** 2 + (s["y"] + 0.3) ** 2, [s["x"] - 0.5]) for s in sets]

    t = tu.optimise(params, {"x": -0.9, "y": 0.9}, budget=40, evaluate=evaluate, seed=3, batch=4)
    assert t.records[0].values == {"x": -0.9, "y": 0.9}  # trial 0 is the default
    assert t.records[0].objective == pytest.approx(1.7**2 + 1.2**2)
    best = t.best()
    assert best is not None and best.feasible
    assert best.values["x"] <= 0.5
    assert best.objective < 0.09 + 0.05  # within 0.05 of the constrained optimum 0.09 (default: 4.33)
    assert abs(best.values["x"] - 0.5) < 0.15 and abs(best.values["y"] + 0.3) < 0.2
    assert any(not r.feasible for r in t.records)  # the sampler did try the infeasible side: the constraint mattered


def test_the_best_ignores_infeasible_trials_and_none_when_none_is_feasible() -> None:
    params = [tu.Param("x", 0.0, 1.0, "toy")]
    t = tu.optimise(params, {"x": 0.5}, budget=6, evaluate=lambda sets: [(-s["x"], [1.0]) for s in sets], batch=3)
    assert len(t.records) == 6 and t.best() is None
    t = tu.optimise(
        params, {"x": 0.5}, budget=6, evaluate=lambda sets: [(-s["x"], [s["x"] - 0.5]) for s in sets], batch=2
    )
    b = t.best()
    assert b is not None and b.values["x"] <= 0.5  # never the better but infeasible x > 0.5


def test_same_seed_same_trials() -> None:
    params = [tu.Param("x", 0.1, 10.0, "toy", log=True)]
    runs = [
        [r.values["x"] for r in tu.optimise(params, {"x": 1.0}, 7, lambda s: [(v["x"], [0.0]) for v in s], 5).records]
        for _ in range(2)
    ]
    assert runs[0] == runs[1]
    assert all(0.1 <= x <= 10.0 for x in runs[0])


# ----------------------------------------------------------------------------- the same budget for every controller


def _fake_execute(log: list[tuple[str, dict[str, Any]]], calls: list[dict[str, Any]] | None = None) -> Any:
    """A stand-in for aev_ocp.study.runner.execute: records each task (controller label, document) and returns a
    result shaped as run_task's, its energy a smooth function of the document's tuned numbers."""

    def execute(tasks: list[Any], store: Any, **kw: Any) -> dict[str, dict[str, Any]]:
        if calls is not None:
            calls.append(kw)
        out = {}
        for t in tasks:
            doc = t.spec["document"]
            log.append((t.spec["controller"]["label"], doc))
            nums = [float(v) for tab in ("mpc",) for v in (doc.get(tab) or {}).values() if isinstance(v, float)]
            nums += [float(v) for v in (doc.get("carfollowing") or {}).get(t.spec["controller"]["name"], {}).values()]
            m = {
                "battery_energy_kWh_per_100km": 10.0 + 0.01 * sum(nums),
                "min_gap_m": 5.0,
                "min_ttc_s": 4.0,
                "rms_jerk_mps3": 0.5,
                "distance_m": 1000.0,
            }
            out[t.key] = {"key": t.key, "status": "ok", "message": "", "metrics": [m], "profiles": []}
        return out

    return execute


def test_every_controller_gets_the_same_budget_of_closed_loop_evaluations(tmp_path: Path, monkeypatch: Any) -> None:
    import aev_ocp.study.runner as runner

    log: list[tuple[str, dict[str, Any]]] = []
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(runner, "execute", _fake_execute(log, calls))
    res = tu.run_tuning(list(tu.TUNING_TABLE), budget=5, out=tmp_path / "t", batch=2, executor="dask", workers=3)
    # 3 rounds of at most 2 trials per controller, then default and tuned: 4 study executions, on the executor asked
    assert len(calls) == 4
    assert all(kw["executor"] == "dask" and kw["workers"] == 3 and kw["scheduler"] is None for kw in calls)
    n_train, n_held = len(res.result["training_cases"]), len(res.result["heldout_cases"])
    per: dict[str, int] = {}
    for label, _ in log:
        per[label] = per.get(label, 0) + 1
    # tuning: 5 trials × n_train each; then default and tuned on every case
    assert per == {c: 5 * n_train + 2 * (n_train + n_held) for c in tu.TUNING_TABLE}
    saved = json.loads((tmp_path / "t" / "tuning.json").read_text())
    for c in tu.TUNING_TABLE:
        assert saved["controllers"][c]["closed_loop_evaluations"] == 5 * n_train
        assert saved["controllers"][c]["trials"] == 5
    trials = (tmp_path / "t" / "trials.csv").read_text().splitlines()
    assert len(trials) == 1 + 5 * len(tu.TUNING_TABLE)
    md = (tmp_path / "t" / "tuning.md").read_text()
    assert f"5 trials per controller × {n_train} training scenarios" in md
    # every task went through the study layer with the controller's own law in the document
    assert {doc["platoon"]["law"] for label, doc in log if label == "idm"} == {"idm"}


# ----------------------------------------------------------------------------- bad input names the field


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"controllers": ["proposed", "pid"]}, ["unknown controller", "'pid'"]),
        ({"controllers": []}, ["controllers"]),
        ({"bounds": {"idm": {"T_h": (1.0, 2.0)}}}, ["'idm'", "'T_h'", "T_s"]),
        ({"bounds": {"idm": {"T_s": (2.0, 2.0)}}}, ["idm.T_s", "lo = 2"]),
        ({"bounds": {"idm": {"T_s": (2.5, 1.0)}}}, ["idm.T_s", "lo = 2.5", "hi = 1"]),
        ({"controllers": ["mpc"], "bounds": {"mpc": {"accel_weight": (0.0, 5.0)}}}, ["mpc.accel_weight", "log scale"]),
        ({"bounds": {"ovfl": {"alpha_per_s": (1.0, 2.0)}}}, ["'ovfl'", "not tuned in this run"]),
        ({"budget": 0}, ["budget = 0"]),
        ({"budget": -3}, ["budget = -3"]),
        ({"budget": 2.5}, ["budget = 2.5"]),
        ({"budget": True}, ["budget = True"]),
        ({"batch": 0}, ["batch = 0"]),
        ({"seed": -1}, ["seed = -1"]),
    ],
)
def test_bad_input_is_refused_naming_the_field(tmp_path: Path, kwargs: dict[str, Any], words: list[str]) -> None:
    args: dict[str, Any] = {"controllers": ["proposed", "idm"], "budget": 3, "out": tmp_path / "t"}
    args.update(kwargs)
    with pytest.raises(ParameterError) as e:
        tu.run_tuning(**args)
    for w in words:
        assert w in str(e.value)
    assert not (tmp_path / "t").exists()  # refused before the folder is claimed


def test_bounds_inside_limits_are_accepted() -> None:
    (s,) = tu.check_spaces(["idm"], {"idm": {"T_s": (1.2, 1.21)}})
    assert (s.param("T_s").lo, s.param("T_s").hi) == (1.2, 1.21)
    assert s.param("a_mps2") == tu.TUNING_TABLE["idm"].param("a_mps2")


def test_cli_bad_budget_exits_2_naming_it(tmp_path: Path, capsys: Any) -> None:
    from aev_ocp.cli import main

    assert main(["tune", "--budget", "0", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert "budget = 0" in err and err.count("\n") == 1
    assert main(["tune", "--bounds", "idm.T_s=1", "--out", str(tmp_path / "t")]) == 2
    assert "CONTROLLER.PARAMETER=LO:HI" in capsys.readouterr().err


# ----------------------------------------------------------------------------- a tuned set in a scenario


def test_a_tuned_set_round_trips_into_the_scenarios_laws_and_mpc(train: list[tu.Case]) -> None:
    case = train[0]
    proposed = {"kappa_per_m": 0.0037, "eps_m2ps2": 0.021, "h_scale_m": 23.5, "v_scale_mps": 19.25}
    sp = tu.TUNING_TABLE["proposed"]
    before = parse_scenario_quiet(case.document, case.file).law("proposed").si_coefficients()
    sc = parse_scenario_quiet(tu.case_document(sp, proposed, case), case.file)
    law = sc.law("proposed")
    si = law.si_coefficients()
    for k, v in proposed.items():
        assert si[k] == pytest.approx(v, rel=1e-12)
    # the untuned SI coefficients stay as the scenario sets them, though the scales changed
    assert si["alpha_per_s"] == pytest.approx(before["alpha_per_s"], rel=1e-12)
    assert si["beta_m2ps"] == pytest.approx(before["beta_m2ps"], rel=1e-12)
    assert tu.default_values(sp, tu.case_document(sp, proposed, case), case.file) == pytest.approx(proposed)
    # the platoon runs the tuned law; the MPC's fallback (the file's [carfollowing]) is untouched
    assert [lw.name for lw in sc.laws] == ["proposed"]
    assert sc.cf.h_scale_m == 15.0
    idm = {"T_s": 1.7, "a_mps2": 0.9, "b_mps2": 2.2}
    sc = parse_scenario_quiet(tu.case_document(tu.TUNING_TABLE["idm"], idm, case), case.file)
    got = sc.law("idm")
    assert (got.T_s, got.a_mps2, got.b_mps2) == (1.7, 0.9, 2.2)  # type: ignore[attr-defined]
    mpc = {"accel_weight": 2.5, "gap_weight": 0.05, "target_time_gap_s": 1.8}
    tp = parse_scenario_quiet(tu.case_document(tu.TUNING_TABLE["mpc"], mpc, case), case.file).extra["mpc"]
    assert (tp.formulation.traffic.accel_weight, tp.formulation.traffic.gap_weight) == (2.5, 0.05)
    assert tp.formulation.traffic.target_time_gap_s == 1.8
    with pytest.raises(ParameterError, match="'proposed' has no tuned parameter 'alpha'"):
        tu.scenario_overrides(sp, {"alpha": 1.0}, case.document, case.file)


def test_one_si_set_gives_the_same_law_in_scenarios_of_different_units(train: list[tu.Case]) -> None:
    """UDDS (L = 15 m, U = 17 m/s) and US06 (L = 20 m, U = 22 m/s): the same tuned SI set, the same equilibrium gap
    and the same acceleration in SI."""
    us06 = tu.cycle_case("mpc_us06_single", 30.0, False, "held-out")
    vals = {"alpha_per_s": 1.3, "beta_m2ps": 420.0, "h_scale_m": 18.0, "v_scale_mps": 21.0}
    sp = tu.TUNING_TABLE["ovfl"]
    laws = [parse_scenario_quiet(tu.case_document(sp, vals, c), c.file).law("ovfl") for c in (train[0], us06)]
    assert laws[0].model_units != laws[1].model_units
    for v in (3.0, 11.0, 24.0):
        assert laws[0].equilibrium_gap_m(v) == pytest.approx(laws[1].equilibrium_gap_m(v), rel=1e-12)
    for h, v, vl in ((12.0, 8.0, 9.5), (30.0, 20.0, 17.0)):
        assert float(laws[0].accel_si(h, v, vl)) == pytest.approx(float(laws[1].accel_si(h, v, vl)), rel=1e-12)


# ----------------------------------------------------------------------------- scoring


def _case(leader_t: np.ndarray, leader_x: np.ndarray, gap0: float, kind: str = "cycle") -> tu.Case:
    return tu.Case("toy", "train", kind, {}, "", tuple(leader_t), tuple(leader_x), gap0)


def test_time_gap_of_a_follower_at_constant_speed_is_gap_over_speed() -> None:
    t = np.linspace(0.0, 60.0, 601)
    case = _case(t, 12.5 * t, 30.0)  # the leader at 12.5 m/s, the follower 30 m behind at the same speed: 2.4 s
    tau = tu.time_gaps_s({"t_s": t.tolist(), "distance_m": (12.5 * t).tolist()}, case)
    assert tau.size > 400
    assert np.allclose(tau, 30.0 / 12.5, atol=1e-9)
    # standing still does not count: a follower at rest has no time gap
    tau = tu.time_gaps_s({"t_s": t.tolist(), "distance_m": [0.0] * t.size}, case)
    assert tau.size == 0


def _run(**kw: Any) -> dict[str, Any]:
    r = {
        "status": "ok",
        "battery_energy_kWh_per_100km": 12.0,
        "min_gap_m": 4.0,
        "min_ttc_s": 3.0,
        "rms_jerk_mps3": 0.8,
        "mean_time_gap_s": 2.0,
    }
    r.update(kw)
    return r


def test_score_limits_on_inside_and_outside() -> None:
    cyc = _case(np.array([0.0, 1.0]), np.array([0.0, 1.0]), 1.0)
    saf = _case(np.array([0.0, 1.0]), np.array([0.0, 1.0]), 1.0, "safety")
    L = tu.LIMITS
    obj, cons = tu.score([_run(battery_energy_kWh_per_100km=9.0), _run(battery_energy_kWh_per_100km=13.0)], [cyc, cyc])
    assert obj == 11.0 and tu.feasible(cons)
    for key, limit, side in (
        ("min_gap_m", L["min_gap_m"], -1),
        ("min_ttc_s", L["min_ttc_s"], -1),
        ("rms_jerk_mps3", L["rms_jerk_max_mps3"], 1),
        ("mean_time_gap_s", L["mean_time_gap_max_s"], 1),
    ):
        assert tu.feasible(tu.score([_run(**{key: limit})], [cyc])[1])  # on the limit: feasible
        assert not tu.feasible(tu.score([_run(**{key: limit + side * 0.01})], [cyc])[1])  # just outside
        assert tu.feasible(tu.score([_run(**{key: limit - side * 0.01})], [cyc])[1])  # just inside
    # a safety case: hard braking and a short TTC are its point; its gap and events count, its energy does not
    assert tu.feasible(tu.score([_run(), _run(rms_jerk_mps3=9.0, min_ttc_s=0.4)], [cyc, saf])[1])
    assert tu.score([_run(), _run(battery_energy_kWh_per_100km=-200.0)], [cyc, saf])[0] == 12.0
    assert not tu.feasible(tu.score([_run(), _run(min_gap_m=0.5)], [cyc, saf])[1])
    obj, cons = tu.score([_run(), _run(status="collision")], [cyc, saf])
    assert obj == tu.PENALTY_KWH_PER_100KM and cons[0] == 1.0
    obj, _ = tu.score([_run(status="error", battery_energy_kWh_per_100km=math.nan)], [cyc])
    assert obj == tu.PENALTY_KWH_PER_100KM

"""Dotted-path overrides (aev_ocp.overrides), Scenario.with_overrides / replace, and the comparable-results
metrics (distance, per-km values, time-to-collision, comparability)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import one_error
from helpers import _run_study
from study_helpers import write_tiny_study as _study

from aev_ocp.metrics import comparability, distance_metrics
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.overrides import OverrideError, apply_to_document, parse_assignment, parse_assignments
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario
from aev_ocp.simulate import simulate_platoon

pytestmark = pytest.mark.quick  # the whole module runs in the sub-minute subset (pytest -m quick)

TABLE1_TEXT = find_scenario("table1").read_text()


def _edited(tmp_path: Path, *edits: tuple[str, str]):
    """The Table 1 scenario with lines edited in the file: the independent route to the same scenario."""
    text = TABLE1_TEXT
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    f = tmp_path / "edited.toml"
    f.write_text(text)
    return load_scenario(f)


def test_override_equals_editing_the_file(tmp_path):
    base = load_scenario("table1")
    over = base.with_overrides({"carfollowing.kappa": 0.047, "platoon.gap0_others": 3.1})
    edited = _edited(tmp_path, ("kappa = 0.03", "kappa = 0.047"), ("gap0_others = 3.5", "gap0_others = 3.1"))
    assert over.laws == edited.laws and over.law("proposed").kappa == 0.047
    assert over.gaps0 == edited.gaps0 == (0.3, 3.1, 3.1, 3.1, 3.1)
    assert over.cf == edited.cf and over.leader == edited.leader and over.speeds0 == edited.speeds0
    assert base.law("proposed").kappa == 0.03  # the original is untouched


def test_exclusive_keys_are_swapped_not_added():
    sc = load_scenario("table1").with_overrides({"platoon.speed0": 1.23})  # the file has speed0_factor
    assert sc.speeds0 == (1.23,) * 5
    sc = load_scenario("table1").with_overrides({"platoon.gaps0": [0.4, 0.5, 0.6, 0.7, 0.8]})
    assert sc.gaps0 == (0.4, 0.5, 0.6, 0.7, 0.8)


def test_leader_kind_change_clears_the_old_kind_keys():
    sc = load_scenario("table1").with_overrides(
        {"leader.kind": "cycle", "leader.cycle": "hwfet", "units.length_m": 15.0, "units.speed_mps": 17.0}
    )
    ref = load_scenario("hwfet_platoon")
    assert sc.leader == ref.leader and sc.units == ref.units


@pytest.mark.parametrize(
    "key, value, needle",
    [
        ("carfollowing.kappa", -0.2, "carfollowing.kappa"),
        ("carfollowing.kapa", 0.1, "carfollowing.kapa"),
        ("vehicle.efficiency", 1.3, "vehicle.efficiency"),
        ("units.length_m", "ten", "units.length_m"),
        ("mpc.N", 0, "N"),
        ("mpc.w_Q", -1.5, "w_Q"),
    ],
)
def test_bad_override_names_file_and_key(key, value, needle):
    with pytest.raises(ScenarioError) as exc:
        load_scenario("mpc_paper_single").with_overrides({key: value})
    msg = str(exc.value)
    assert "mpc_paper_single.toml" in msg and needle in msg


def test_ignored_override_is_an_error():
    with pytest.raises(OverrideError, match="would be ignored.*compare"):
        load_scenario("table1").with_overrides({"platoon.law": "ovm"})
    # without compare it takes effect
    sc = load_scenario("table1").with_overrides({"compare": None, "platoon.law": "ovm"})
    assert {law.name for law in sc.laws} == {"ovm"} and sc.runs()[0][0] == "ovm"


def test_override_through_a_value_is_an_error():
    with pytest.raises(OverrideError, match="carfollowing.kappa is a value"):
        apply_to_document({"carfollowing": {"kappa": 0.1}}, {"carfollowing.kappa.x": 1}, "f.toml")


def test_parse_assignments():
    assert parse_assignment("carfollowing.kappa=0.05") == ("carfollowing.kappa", 0.05)
    assert parse_assignment("mpc.N = 12") == ("mpc.N", 12)
    assert parse_assignment("leader.cycle=udds") == ("leader.cycle", "udds")
    assert parse_assignment('leader.cycle="us06"') == ("leader.cycle", "us06")
    assert parse_assignment("platoon.gaps0=[1, 2.5]") == ("platoon.gaps0", [1, 2.5])
    assert parse_assignment("mpc.codegen=false") == ("mpc.codegen", False)
    assert parse_assignments(["a.b=1", "a.b=2"]) == {"a.b": 2}
    for bad in ("kappa", "=1", "a..b=1", "a.b="):
        with pytest.raises(OverrideError):
            parse_assignment(bad)


def test_load_with_sets():
    from aev_ocp.scenarios import load_with_sets

    sc = load_with_sets("table1", ["carfollowing.kappa=0.071", "simulation.t_end=12.5"])
    assert sc.law("proposed").kappa == 0.071 and sc.t_end == 12.5
    assert load_with_sets("table1", None).t_end == 70.0
    with pytest.raises(ScenarioError, match="table1.toml: simulation.t_end"):
        load_with_sets("table1", ["simulation.t_end=-3"])


# ----------------------------------------------------------------------------- replace
def test_replace_cf_takes_effect_without_compare():
    """The bug of issue 9: replace(cf=...) did nothing on a scenario without compare."""
    sc = load_scenario("udds_platoon").replace(compare=())
    assert sc.compare == ()
    sc2 = sc.replace(cf=dataclasses.replace(sc.cf, kappa=0.061))
    assert all(law.kappa == 0.061 for law in sc2.laws)
    assert sc2.runs()[0][1][0].kappa == 0.061


def test_replace_without_document_rebuilds_laws():
    sc = load_scenario("table1").replace(compare=(), leader=load_scenario("table1").leader)  # drops the document
    assert sc.document is None
    sc2 = sc.replace(cf=dataclasses.replace(sc.cf, alpha=1.7))
    assert all(law.alpha == 1.7 for law in sc2.laws)
    with pytest.raises(ScenarioError, match="no document"):
        sc2.with_overrides({"carfollowing.kappa": 0.1})


def test_replace_units_reconverts_the_cycle_leader():
    sc = load_scenario("udds_platoon")
    sc2 = sc.replace(units=dataclasses.replace(sc.units, speed_mps=20.0))
    assert sc2.ev.units.speed_mps == 20.0
    # the same SI trace in model units scales with 1/U
    assert math.isclose(sc2.leader.max_speed(sc2.t_end) * 20.0, sc.leader.max_speed(sc.t_end) * 17.0, rel_tol=1e-9)


def test_replace_errors():
    sc = load_scenario("table1")
    with pytest.raises(ScenarioError, match="unknown field"):
        sc.replace(tend=3.0)
    with pytest.raises(ScenarioError, match="dt_out"):
        sc.replace(t_end=0.005)  # below dt_out = 0.01: validated like the file
    with pytest.raises(ScenarioError, match="would be ignored"):
        sc.replace(laws=sc.laws)
    with pytest.raises(ScenarioError, match="5 gaps0"):
        sc.replace(compare=()).replace(laws=sc.laws[:3])
    assert sc.replace(t_end=7.5).t_end == 7.5


# ----------------------------------------------------------------------------- metrics
def test_distance_and_per_km_against_an_independent_integral():
    sc = load_scenario("table1").replace(t_end=6.0, dt_out=0.001)
    r = simulate_platoon(sc.leader, list(sc.laws), **sc.simulate_kwargs())
    for i in (0, 4):
        m = distance_metrics(r, i)
        trap = float(np.trapezoid(r.speed[:, i], r.t))  # ∫ v dt, second-order accurate at dt = 0.001
        assert math.isclose(m["distance_model"], trap, rel_tol=1e-6)
        assert math.isclose(m["distance_m"], trap * sc.units.length_m, rel_tol=1e-6)
        assert math.isclose(m["heat_pack_J_per_km"], r.heat_J[-1, i] / (m["distance_m"] / 1000), rel_tol=1e-12)
        assert m["duration_s"] == pytest.approx(6.0 * sc.units.time_s)


def test_min_ttc_closing_follower():
    """Constant leader v_l = 1; follower 1 starts at v = 1.6, h = 2.5: TTC(0) = 2.5 / 0.6, and the
    minimum over the run is below that (the follower keeps closing at first) but positive."""
    from aev_ocp.models.carfollowing import make_law

    r = simulate_platoon(ConstantSpeed(1.0), [make_law("ovfl")], [2.5], [1.6], 3.0, dt_out=0.001)
    m = distance_metrics(r, 0)
    brute = min(h / (v - 1.0) for h, v in zip(r.gap[:, 0], r.speed[:, 0]) if v > 1.0)
    assert m["min_ttc_model"] == pytest.approx(brute, rel=1e-12)
    assert 0 < m["min_ttc_model"] <= 2.5 / 0.6
    r2 = simulate_platoon(ConstantSpeed(1.0), [make_law("ovfl")], [1.5], [0.0], 3.0)
    assert r2.speed[:, 0].max() < 1.0  # from rest below the equilibrium gap: never faster than the leader
    assert distance_metrics(r2, 0)["min_ttc_model"] == math.inf


def test_comparability_flags():
    ref = {"distance_m": 1000.0, "duration_s": 140.0, "run_status": "ok"}
    ok = comparability({"distance_m": 1009.3, "duration_s": 140.0, "run_status": "ok"}, ref)
    assert ok["comparable"] and ok["distance_diff_pct"] == pytest.approx(0.93)
    far = comparability({"distance_m": 1011.7, "duration_s": 140.0, "run_status": "ok"}, ref)
    assert far["flag_distance"] and not far["comparable"]
    short = comparability({"distance_m": 1000.0, "duration_s": 137.9, "run_status": "ok"}, ref)
    assert short["flag_duration"] and not short["flag_distance"] and not short["comparable"]
    evt = comparability({"distance_m": 1000.0, "duration_s": 140.0, "run_status": "collision"}, ref)
    assert evt["flag_event"] and not evt["comparable"]
    assert not comparability({"distance_m": 1000.0, "duration_s": 140.0, "run_status": "ok"}, None)["comparable"]


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
@pytest.mark.parametrize("key", [3, None, ("carfollowing", "kappa"), b"carfollowing.kappa"])
def test_override_key_that_is_not_a_string_is_named(key: object) -> None:
    """with_overrides({3: 1}) was an AttributeError ('int' object has no attribute 'split')."""
    from aev_ocp.overrides import OverrideError

    with pytest.raises(OverrideError, match=r"override key .* is not a dotted key path string"):
        load_scenario("table1").with_overrides({key: 0.05})  # type: ignore[dict-item]
    s = load_scenario("table1").with_overrides({"carfollowing.kappa": 0.07})  # a string key still works
    assert s.cf.kappa == 0.07


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


def test_set_on_an_axis_key_nan_and_newline_are_refused(tmp_path, capsys):
    f = _study(tmp_path)
    for sets, word in (
        (["platoon.gap0_first=0.5"], "platoon.gap0_first"),
        (["carfollowing.alpha=nan"], "nan"),
        (["simulation.t_end=2\nplatoon.followers=9"], "line break"),
    ):
        rc, err = _run_study(tmp_path, f, tmp_path / "o", capsys, *[x for s in sets for x in ("--set", s)])
        assert rc == 2 and word in one_error(err), err
    assert not (tmp_path / "o").exists()

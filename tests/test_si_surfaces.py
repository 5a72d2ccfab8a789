"""SI at the user-facing surfaces (issue 20 items 3-5): SI twins of the scenario keys, one precedence rule for
overrides, refusals instead of silently dropped values, SI command-line options and table columns."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from aev_ocp.metrics import SI_METRICS
from aev_ocp.ocp_result import OCPResult
from aev_ocp.overrides import OverrideError, apply_to_document, parse_assignment, parse_assignments
from aev_ocp.params import Units
from aev_ocp.scenarios import ScenarioError, parse_scenario
from aev_ocp.study import StudyError, read_study

ROOT = Path(__file__).resolve().parents[1]
UNITS = Units(length_m=13.0, speed_mps=7.0)  # distinct, non-special: T = 13/7 s, accel unit 49/13 m/s²


def _doc() -> dict:
    return {
        "units": {"length_m": UNITS.length_m, "speed_mps": UNITS.speed_mps},
        "leader": {"kind": "paper", "v0": 1.3, "amplitude": 0.7, "forcing_end": 4.5},
        "platoon": {"followers": 3, "law": "ovfl", "gap0_first": 0.45, "gap0_others": 2.2, "speed0": 1.25},
        "simulation": {"t_end": 6.5, "dt_out": 0.05},
    }


def _si(doc: dict, table: str, model_key: str, si_key: str, to_si) -> dict:  # noqa: ANN001
    out = copy.deepcopy(doc)
    v = out[table].pop(model_key)
    out[table][si_key] = [to_si(x) for x in v] if isinstance(v, list) else to_si(v)
    return out


CASES = [
    ("simulation", "t_end", "t_end_s", UNITS.time_to_si),
    ("simulation", "dt_out", "dt_out_s", UNITS.time_to_si),
    ("platoon", "gap0_first", "gap0_first_m", UNITS.length_to_si),
    ("platoon", "gap0_others", "gap0_others_m", UNITS.length_to_si),
    ("platoon", "speed0", "speed0_mps", UNITS.speed_to_si),
    ("leader", "v0", "v0_mps", UNITS.speed_to_si),
    ("leader", "amplitude", "amplitude_mps2", UNITS.accel_to_si),
    ("leader", "forcing_end", "forcing_end_s", UNITS.time_to_si),
]


@pytest.mark.parametrize("table, model_key, si_key, to_si", CASES)
def test_si_key_equals_the_model_key_after_conversion(table: str, model_key: str, si_key: str, to_si) -> None:  # noqa: ANN001
    ref = parse_scenario(_doc(), "m.toml")
    sc = parse_scenario(_si(_doc(), table, model_key, si_key, to_si), "s.toml")
    assert sc.t_end == pytest.approx(ref.t_end, rel=1e-12) and sc.dt_out == pytest.approx(ref.dt_out, rel=1e-12)
    np.testing.assert_allclose(sc.gaps0, ref.gaps0, rtol=1e-12)
    np.testing.assert_allclose(sc.speeds0, ref.speeds0, rtol=1e-12)
    t = np.linspace(0.0, 6.0, 13)
    np.testing.assert_allclose(sc.leader.speed_np(t), ref.leader.speed_np(t), rtol=1e-12)


def test_list_and_whole_platoon_si_keys() -> None:
    d = _doc()
    d["platoon"] = {"followers": 3, "law": "ovfl", "gaps0_m": [5.2, 9.1, 14.3], "speeds0_mps": [8.1, 8.4, 9.0]}
    sc = parse_scenario(d, "x.toml")
    np.testing.assert_allclose(sc.gaps0, [5.2 / 13.0, 9.1 / 13.0, 14.3 / 13.0], rtol=1e-12)
    np.testing.assert_allclose(sc.speeds0, [8.1 / 7.0, 8.4 / 7.0, 9.0 / 7.0], rtol=1e-12)
    d["platoon"] = {"followers": 3, "law": "ovfl", "gap0_m": 6.5, "speed0_mps": 8.75}
    sc = parse_scenario(d, "x.toml")
    assert sc.gaps0 == pytest.approx((0.5,) * 3) and sc.speeds0 == pytest.approx((1.25,) * 3)
    d["leader"] = {"kind": "array", "times_s": [0.0, 26.0], "speeds_mps": [7.0, 14.0]}
    lead = parse_scenario(d, "x.toml").leader
    assert lead.speed_np(np.array([7.0]))[0] == pytest.approx(1.5)  # 13 s = 7 model time, halfway 1 -> 2
    d["leader"] = {"kind": "constant", "v_mps": 10.5}
    assert parse_scenario(d, "x.toml").leader.speed_np(np.array([1.0]))[0] == pytest.approx(1.5)


@pytest.mark.parametrize(
    "table, model_key, si_key",
    [(c[0], c[1], c[2]) for c in CASES] + [("platoon", "gaps0", "gaps0_m"), ("platoon", "gap0_first", "gap0_m")],
)
def test_both_keys_given_is_an_error_naming_both(table: str, model_key: str, si_key: str) -> None:
    d = _doc()
    d[table].setdefault(model_key, [0.5, 0.6, 0.7] if model_key == "gaps0" else 0.5)
    d[table][si_key] = [5.0, 6.0, 7.0] if si_key == "gaps0_m" else 3.0
    if model_key == "gaps0":
        d[table].pop("gap0_first"), d[table].pop("gap0_others")
    with pytest.raises(ScenarioError) as err:
        parse_scenario(d, "both.toml")
    msg = str(err.value)
    assert "both.toml" in msg and f"{table}.{si_key}" in msg and model_key in msg


def test_an_override_replaces_the_twin_of_the_file() -> None:
    d = _si(_doc(), "simulation", "t_end", "t_end_s", UNITS.time_to_si)  # the file gives t_end_s
    out = apply_to_document(d, {"simulation.t_end": 3.25})
    assert out["simulation"] == {"t_end": 3.25, "dt_out": 0.05}
    out = apply_to_document(_doc(), {"simulation.t_end_s": 26.0, "platoon.speed0_mps": 9.1})
    sc = parse_scenario(out, "x.toml")
    assert sc.t_end == pytest.approx(14.0) and sc.speeds0[0] == pytest.approx(1.3)
    with pytest.raises(ScenarioError, match="t_end_s"):  # both in one layer: refused, never one dropped
        parse_scenario(apply_to_document(_doc(), {"simulation.t_end": 3.0, "simulation.t_end_s": 26.0}), "x.toml")


@pytest.mark.parametrize(
    "item, word",
    [
        ("carfollowing.kappa=nan", "finite"),
        ("carfollowing.kappa=inf", "finite"),
        ("carfollowing.kappa=-inf", "finite"),
        ("platoon.gaps0=[0.3, nan]", "finite"),
        ("carfollowing.kappa=0.05\nalpha = 3", "line break"),
        ("carfollowing.kappa\n=0.05", "dotted key"),
    ],
)
def test_set_refuses_non_finite_numbers_and_line_breaks(item: str, word: str) -> None:
    with pytest.raises(OverrideError, match=word):
        parse_assignment(item)


def test_set_keeps_finite_values() -> None:
    assert parse_assignment("carfollowing.kappa=0.07") == ("carfollowing.kappa", 0.07)
    assert parse_assignment('leader.cycle="udds"') == ("leader.cycle", "udds")


# ----------------------------------------------------------------------------- studies: one precedence rule
def _study(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "s.toml"
    p.write_text(body, encoding="utf-8")
    return p


BASE = (
    'scenarios = [{ scenario = "table1", label = "t", overrides = { "simulation.t_end" = 3.5, '
    '"platoon.followers" = 2 } }]\n[overrides]\n"simulation.dt_out" = 0.07\n'
)


def test_command_line_over_study_file_over_scenario_file(tmp_path: Path) -> None:
    p = _study(
        tmp_path, BASE + '[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.02, 0.05]\n[controllers]\nlaws = ["ovfl"]\n'
    )
    plain = read_study(p)
    assert {pt.document["simulation"]["t_end"] for pt in plain.points} == {3.5}  # study file over scenario (70)
    st = read_study(p, sets=parse_assignments(["simulation.t_end=1.75", "simulation.dt_out_s=0.3"]))
    assert {pt.document["simulation"]["t_end"] for pt in st.points} == {1.75}  # command line over study file
    assert all("dt_out" not in pt.document["simulation"] for pt in st.points)  # its SI twin replaced it
    assert {pt.document["simulation"]["dt_out_s"] for pt in st.points} == {0.3}
    notes = " ".join(st.warnings)
    assert "--set simulation.t_end = 1.75 replaces" in notes and "--set simulation.dt_out_s = 0.3 replaces" in notes
    # the point documents parse: t_end 1.75 model time, dt_out 0.3 s = 0.15 model time (table1: T = 2 s)
    sc = parse_scenario(st.points[0].document, "x.toml")
    assert sc.t_end == 1.75 and sc.dt_out == pytest.approx(0.15)


def test_shipped_predictor_study_takes_the_command_line_t_end(tmp_path: Path) -> None:
    st = read_study(ROOT / "studies" / "predictor_cycle.toml", sets=parse_assignments(["simulation.t_end_s=60"]))
    for pt in st.points:  # 60 s at each cycle's own units, never the study file's 300 time units
        sim = pt.document["simulation"]
        u = pt.document["units"]
        assert "t_end" not in sim and sim["t_end_s"] == 60
        assert parse_scenario(pt.document, "x.toml").t_end == pytest.approx(60.0 * u["speed_mps"] / u["length_m"])


@pytest.mark.parametrize(
    "item, word",
    [
        ("carfollowing.kappa=0.5", "axes[0] sweeps carfollowing.kappa"),
        ("platoon.speed0_mps=9.0", "axes[1] sweeps platoon.speed0_factor"),
        ("mpc.solver='sqp'", "controller 'mpc' sets mpc.solver"),
    ],
)
def test_set_that_the_study_would_override_is_refused(tmp_path: Path, item: str, word: str) -> None:
    p = _study(
        tmp_path,
        BASE + '[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.02, 0.05]\n'
        '[[axes]]\nkey = "platoon.speed0_factor"\nvalues = [1.05]\n'
        '[controllers]\nlaws = ["ovfl"]\n[[controllers.mpc]]\nlabel = "mpc"\nsolver = "rti"\n',
    )
    with pytest.raises(StudyError) as err:
        read_study(p, sets=parse_assignments([item]))
    assert word in str(err.value) and "would be ignored" in str(err.value)


def test_study_cli_refuses_nan_and_axis_keys(capsys: pytest.CaptureFixture[str]) -> None:
    from aev_ocp.cli import main

    study = str(ROOT / "studies" / "kappa_alpha_table1.toml")
    assert main(["study", study, "--set", "carfollowing.kappa=0.5", "--no-report"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "carfollowing.kappa" in err and "axes" in err
    assert main(["study", study, "--set", "simulation.rtol=nan"]) == 2
    assert "finite" in capsys.readouterr().err


# ----------------------------------------------------------------------------- command lines
def test_mpc_option_and_set_of_the_same_key_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    from aev_ocp.cli import main

    for argv, word in (
        (["--t-end", "3", "--set", "simulation.t_end=1.5"], "--t-end"),
        (["--t-end-model", "3", "--set", "simulation.t_end_s=1.5"], "--t-end-model"),
        (["--solver", "sqp", "--set", "mpc.solver='rti'"], "--solver"),
    ):
        assert main(["mpc", "mpc_paper_single", "--no-ocpd", *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and word in err and "--set" in err
    assert main(["mpc", "mpc_paper_single", "--t-end", "3", "--t-end-model", "2"]) == 2  # one of the two


def test_simulate_warns_about_the_mpc_table_and_takes_seconds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from aev_ocp.cli import main

    rc = main(
        [
            "simulate",
            "mpc_paper_single",
            "--out",
            str(tmp_path),
            "--no-plots",
            "--set",
            "simulation.t_end_s=3.3",
            "--time-limit",
            "600",
        ]
    )
    assert rc == 0
    err = capsys.readouterr().err
    assert "warning" in err and "[mpc]" in err and "aev-ocp mpc" in err and "t [s] = 3.3/3.3" in err
    import csv

    with open(tmp_path / "ovfl.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert float(rows[-1]["t_s"]) == pytest.approx(3.3) and float(rows[-1]["t_model"]) == pytest.approx(1.65)


def test_simulate_time_limit_skips_runs_not_started(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from aev_ocp.cli import main

    assert main(["simulate", "table1", "--out", str(tmp_path), "--time-limit", "1e-9"]) == 1
    assert "--time-limit" in capsys.readouterr().err and not list(tmp_path.glob("*.csv"))
    assert main(["simulate", "table1", "--out", str(tmp_path), "--time-limit", "-2"]) == 2


# ----------------------------------------------------------------------------- tables
def test_si_metrics_are_the_model_metrics_converted() -> None:
    from aev_ocp.scenarios import load_scenario

    sc = load_scenario("table1").replace(t_end=3.0, units=UNITS)
    m = sc.run(only="ovfl")["ovfl"].metrics()[1]
    assert m["min_speed_mps"] == pytest.approx(m["min_speed_model"] * 7.0, rel=1e-12)
    assert m["rms_jerk_mps3"] == pytest.approx(m["rms_jerk_model"] * 7.0**3 / 13.0**2, rel=1e-12)
    assert set(si for si, _ in SI_METRICS.values()) <= set(m)


def test_ocp_csv_of_a_model_problem_leads_with_si(tmp_path: Path) -> None:
    t = np.array([0.0, 0.5, 1.0])
    r = OCPResult(
        problem="p",
        method="ms",
        N=2,
        t=t,
        time_unit="model",
        states={"h": np.array([0.3, 0.4, 0.5]), "v": np.array([1.1, 1.2, 1.3]), "S": np.array([0.8, 0.8, 0.79])},
        controls={"a": np.array([0.2, -0.1])},
        outputs={},
        objective=1.0,
        objective_name="J",
        success=True,
        status="optimal",
        message="",
        solver_status="Solve_Succeeded",
        iterations=3,
        wall_time_s=0.1,
        solver_time_s=0.1,
        max_violation=0.0,
        meta={"units": {"length_m": 13.0, "speed_mps": 7.0}},
    )
    lines = r.to_csv(tmp_path / "o.csv").read_text().splitlines()
    head = lines[0].split(",")
    assert head[:5] == ["t_s", "h_m", "v_mps", "a_mps2", "t_model"] and "h_model" in head and "S" in head
    last = dict(zip(head, map(float, lines[-1].split(","))))
    assert last["t_s"] == pytest.approx(13.0 / 7.0) and last["h_m"] == pytest.approx(6.5)
    assert last["v_mps"] == pytest.approx(9.1) and last["a_mps2"] == pytest.approx(-0.1 * 49.0 / 13.0)
    assert last["h_model"] == 0.5 and math.isclose(last["t_model"], 1.0)

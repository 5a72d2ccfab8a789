"""The [mpc] scenario table, the ``aev-ocp mpc`` command and the reproduce section hook."""

from __future__ import annotations

import json

import pytest

import aev_ocp.mpc.report  # noqa: F401  (its REPRODUCE_SECTIONS)
from aev_ocp.mpc.cli import cli_mpc
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario, parse_scenario

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib


def _doc(**mpc):
    doc = tomllib.loads(find_scenario("mpc_paper_single").read_text())
    doc["mpc"].update(mpc)
    return doc


def test_shipped_mpc_scenarios_load():
    s = load_scenario(find_scenario("mpc_paper_single"))
    assert s.n_followers == 1 and s.extra["mpc"].settings.N == 40 and s.extra["mpc"].settings.predictor == "oracle"
    p = load_scenario(find_scenario("mpc_paper_platoon"))
    assert p.n_followers == 5 and p.extra["mpc"].follower_predictor == "cooperative"
    for sc in (s, p):  # the fast real-time-iteration path with compiled functions is the scenario default
        st = sc.extra["mpc"].settings
        assert (st.solver, st.qp_solver, st.qp, st.codegen, st.rti_iterations) == ("rti", "auto", "riccati", True, 1)


@pytest.mark.parametrize(
    "bad, word",
    [
        ({"N": 0}, "N"),
        ({"w_Q": -1.0}, "w_Q"),
        ({"solver": "x"}, "solver"),
        ({"horizon": 3}, "horizon"),
        ({"vehicles": [0]}, "vehicles"),
    ],
)
def test_bad_mpc_table_names_the_key(bad, word):
    with pytest.raises(ScenarioError, match=word):
        parse_scenario(_doc(**bad), "x.toml")


def test_cli_writes_results_and_compares(tmp_path, capsys):
    # --t-end is in seconds: 2 s = 1 model time unit (L/U = 10 m / 5 m/s) = 10 MPC steps of dt = 0.1
    rc = cli_mpc(
        [
            "mpc_paper_single",
            "--out",
            str(tmp_path),
            "--t-end",
            "2.0",
            "--solver",
            "sqp",
            "--qp-solver",
            "hpipm",
            "--no-codegen",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "proposed" in out and "ovfl" in out and "ocp-d" in out and "solve_ms_median" in out
    res = json.loads((tmp_path / "results.json").read_text())
    m = res["metrics"]["mpc"][0]
    assert m["n_steps"] == 10 and m["fallbacks"] == 0 and m["solver_path"] == "sqp"
    # the §9 cost of MPC is not below the OCP-D lower bound (small tolerance for the plant mismatch)
    assert m["cost_s9"] >= res["ocp_d"]["cost_s9"] * (1 - 1e-3)
    for f in ("trajectories_mpc.csv", "mpc_trajectories.png", "mpc_solve_times.png", "overlay_vehicle1.png"):
        assert (tmp_path / f).stat().st_size > 0


def test_cli_scenario_default_rti_path(tmp_path, capsys, monkeypatch, tmp_path_factory):
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
    rc = cli_mpc(
        ["mpc_paper_single", "--out", str(tmp_path), "--t-end-model", "1.0", "--no-ocpd", "--laws", "proposed"]
    )
    assert rc == 0
    m = json.loads((tmp_path / "results.json").read_text())["metrics"]["mpc"][0]
    assert m["n_steps"] == 10 and m["fallbacks"] == 0 and m["solver_path"] == "rti+codegen"
    assert m["gap_violations"] == 0 and m["speed_violations"] == 0
    rc = cli_mpc(
        [
            "mpc_paper_single",
            "--out",
            str(tmp_path / "b"),
            "--t-end",
            "1.0",
            "--no-ocpd",
            "--laws",
            "proposed",
            "--solver",
            "rti",
            "--no-codegen",
        ]
    )
    assert rc == 0
    m = json.loads((tmp_path / "b" / "results.json").read_text())["metrics"]["mpc"][0]
    assert m["solver_path"] == "rti" and m["fallbacks"] == 0


def test_cli_bad_input_is_exit_2(capsys):
    assert cli_mpc(["no_such_scenario_file.toml"]) == 2
    assert "error" in capsys.readouterr().err


def test_reproduce_section_is_provided():
    assert [s[0] for s in aev_ocp.mpc.report.REPRODUCE_SECTIONS] == ["mpc"]


def test_mpc_comparison_reports_its_cost_on_the_exact_model_and_warns_on_a_smoothing_gap() -> None:
    """Issue 13 for the MPC: every run reports its §9 cost twice (smoothed η as the optimiser saw it, and
    exact). Silent on the canonical settings (300 W); a 200 kW smoothing makes the warning fire."""
    from aev_ocp.mpc.report import run_comparison
    from aev_ocp.params import PowertrainOptions

    sc = load_scenario(find_scenario("mpc_paper_single")).replace(t_end=4.0)
    s, f = sc.extra["mpc"].settings, sc.extra["mpc"].formulation
    c = run_comparison(sc, s, laws=(), with_ocpd=False)
    m = c.metrics["mpc"][0]
    assert abs(m["smoothing_gap_pct"]) < 0.05 and c.warnings == []
    assert m["forecast_rms"] < 1e-9  # the canonical scenario's oracle forecast
    wide = f.with_(smooth=PowertrainOptions(smoothing_width_W=2e5))
    c2 = run_comparison(sc, s, laws=(), with_ocpd=False, formulation=wide)
    m2 = c2.metrics["mpc"][0]
    assert abs(m2["smoothing_gap_pct"]) > 0.5 and len(c2.warnings) == 1 and "exact model" in c2.warnings[0]

"""The [mpc] scenario table, the ``aev-ocp mpc`` command and the reproduce section hook."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import one_error, run_cli

import aev_ocp.mpc.report  # noqa: F401  (its REPRODUCE_SECTIONS)
from aev_ocp.mpc.cli import cli_mpc
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario, parse_scenario


# the figures these tests write at TEST_DPI: they check each file, not its resolution (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("figures_at_test_dpi")


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


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
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


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_cli_scenario_default_rti_path(tmp_path, capsys):
    # --no-plots: no figure is checked here (test_cli_writes_results_and_compares checks the MPC's figures)
    rc = cli_mpc(
        [
            *("mpc_paper_single", "--out", str(tmp_path), "--t-end-model", "1.0", "--no-ocpd", "--laws", "proposed"),
            "--no-plots",
        ]
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
            "--no-plots",
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


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_mpc_comparison_reports_its_cost_on_the_exact_model_and_warns_on_a_smoothing_gap() -> None:
    """Issue 13 for the MPC: every run reports its §9 cost twice (smoothed η as the optimiser saw it, and
    exact). Silent on the canonical settings (300 W); a 200 kW smoothing makes the warning fire."""
    from aev_ocp.mpc.run import run_comparison
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


# ----------------------------------------------------------------------------- from the issue-28 re-probe (test_reprobe.py)
EXIT_OK, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 2, 130


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--t-end", "1.5"], "--t-end = 1.5 s (0.75 model time)"),
        (["--t-end-model", "0.33"], "--t-end-model = 0.66 s (0.33 model time)"),
        (["--set", "simulation.t_end_s=2.9"], "simulation.t_end = 2.9 s (1.45 model time)"),
    ],
)
def test_mpc_horizon_that_is_not_whole_steps_names_the_option(
    argv: list[str], named: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """mpc_paper_single steps dt = 0.1 model time = 0.2 s: a horizon of 1.5 s is 7.5 steps. Before: 'closed
    loop: t_end = 0.75 must be a multiple of dt = 0.1' (model units, no option named); now one line naming the
    option, both units and the nearest multiple, before anything is written."""
    code, _, err = run_cli(["mpc", "mpc_paper_single", "--out", str(tmp_path / "o"), *argv], capsys)
    assert code == EXIT_BAD_INPUT
    line = one_error(err)
    assert named in line and "mpc.dt = 0.2 s (0.1 model time)" in line, line
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- from the issue-28 small leftovers (test_reliability_minors.py)
def _refuse_too_large_horizons(tmp_path, capsys) -> None:
    from cli_helpers import one_error, run_cli

    for argv, n_max in (
        (["mpc", "mpc_paper_single", "--set", "mpc.N=1501"], 1500),
        (["mpc-export", "mpc_paper_single", "--set", "mpc.N=2000000"], 1500),
        (["mpc", "mpc_paper_platoon", "--set", "mpc.N=301"], 300),
    ):
        rc, _, err = run_cli([*argv, "--out", str(tmp_path / "o")], capsys)
        line = one_error(err)
        assert rc == 2 and f"{argv[-1].replace('=', ' = ')} is not allowed" in line, line
        assert f"lower mpc.N to at most {n_max}" in line and "MPCSettings" not in line, line
        assert not (tmp_path / "o").exists()  # nothing written


def test_a_too_large_mpc_horizon_names_mpc_N_and_the_limit_before_anything_is_built(tmp_path, capsys, monkeypatch):
    """Budget 1.5 GB at 1 MB per interval (limits.MPC_BYTES_PER_INTERVAL): 1500 intervals for one MPC vehicle,
    300 each for the five of mpc_paper_platoon; the message names mpc.N (what --set and [mpc] take), never
    the Python field MPCSettings.N, and the platoon is refused before its first NLP is compiled."""
    import aev_ocp.mpc.export
    import aev_ocp.mpc.run
    from aev_ocp.limits import MPC_BYTES_PER_INTERVAL
    from aev_ocp.mpc.controller import MPCController
    from aev_ocp.mpc.scenario import check_mpc_setup
    from aev_ocp.scenarios import ScenarioError, load_scenario

    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "1.5")
    assert MPC_BYTES_PER_INTERVAL == 1_000_000

    def built(*a: object, **k: object) -> None:  # "before anything is built": no controller, no run, no export
        raise AssertionError("an MPC was built")

    with monkeypatch.context() as m:
        for owner, name in (
            (MPCController, "__init__"),
            (aev_ocp.mpc.run, "run_comparison"),
            (aev_ocp.mpc.export, "export_mpc"),
        ):
            m.setattr(owner, name, built)
        _refuse_too_large_horizons(tmp_path, capsys)
    platoon = load_scenario("mpc_paper_platoon")
    for N, ok in ((299, True), (300, True), (301, False)):  # the five vehicles' budget: on, inside, outside
        sc = platoon.with_overrides({"mpc.N": N})
        if ok:
            check_mpc_setup(sc)
        else:
            with pytest.raises(ScenarioError, match=r"mpc\.N = 301 is not allowed: 5 MPC vehicles .*at most 300"):
                check_mpc_setup(sc)

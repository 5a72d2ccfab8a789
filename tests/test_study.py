"""Studies (aev_ocp.study): points equal direct runs, executors agree byte for byte (a real Dask
LocalCluster included), resume recomputes nothing, failures are recorded, bad input is one line."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import one_error, run_cli
from helpers import _BIG_STR, _BIG_TABLE, _never, _run_study
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from study_helpers import TINY_STUDY, record_cluster_stops, write_tiny_study

from aev_ocp.cli import main
from aev_ocp.params import ParameterError
from aev_ocp.results import EVENT_KINDS
from aev_ocp.scenarios import load_scenario
from aev_ocp.simulate import simulate_platoon
from aev_ocp.study import StudyError, load_table, read_study, run_study
from aev_ocp.study import runner as runner_mod
from aev_ocp.study.report import pareto_mask
from aev_ocp.study.tables import report_columns

# the study reports' figures at TEST_DPI (aev_ocp.plots.DPI): these tests check that each figure is written and shown,
# not its resolution (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("module_figures_at_test_dpi")

# Table 1 platoon cut to 3 followers and t_end = 2.5: cheap, but every metric non-trivial.
STUDY = """
name = "tiny"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.t_end" = 2.5
"simulation.dt_out" = 0.05
"platoon.followers" = 3
[[axes]]
key = "platoon.gap0_first"
values = [0.35, 0.9]
[[axes]]
key = "carfollowing.kappa"
values = [0.03, 0.26]
[controllers]
laws = ["proposed", "ovfl"]
[report]
metrics = ["omega_model"]
pareto = [["heat_pack_J_per_km", "rms_rel_speed_model"]]
"""

VOLATILE = ("wall_s",)


def _study(tmp_path: Path, text: str = STUDY, name: str = "tiny.toml") -> Path:
    f = tmp_path / name
    f.write_text(text)
    return f


def _point(base, gap: float, kappa: float):
    """The study's point (gap0_first = gap, kappa) of ``base``, built directly with the study's overrides."""
    return base.with_overrides(
        {
            "simulation.t_end": 2.5,
            "simulation.dt_out": 0.05,
            "platoon.followers": 3,
            "platoon.gap0_first": gap,
            "carfollowing.kappa": kappa,
        }
    )


def _stable(rows: list[dict]) -> str:
    return json.dumps([{k: v for k, v in r.items() if k not in VOLATILE} for r in rows], sort_keys=True)


@pytest.mark.quick
def test_points_equal_direct_simulations(tmp_path):
    out = run_study(
        read_study(_study(tmp_path)), tmp_path / "out", executor="inprocess", report=False, progress_stream=sys.stderr
    )
    rows = out.rows
    assert len(rows) == 4 * 2 * 3  # points × controllers × vehicles
    assert set().union(*rows) <= report_columns(
        read_study(_study(tmp_path)).axes
    )  # what a [report] may name covers every column
    # OVFL does not read kappa: its two kappa values share one task (one hash), 6 tasks in all
    assert out.n_tasks == 6
    base = load_scenario("table1")
    for gap, kappa in ((0.35, 0.26), (0.9, 0.03)):
        sc = _point(base, gap, kappa)
        for law in ("proposed", "ovfl"):
            direct = simulate_platoon(sc.leader, [sc.law(law)] * 3, **sc.simulate_kwargs()).metrics()
            got = [
                r
                for r in rows
                if r["platoon.gap0_first"] == gap and r["carfollowing.kappa"] == kappa and r["controller"] == law
            ]
            assert [r["vehicle"] for r in got] == [1, 2, 3]
            for r, m in zip(got, direct):
                for k in (
                    "omega_model",
                    "heat_pack_J",
                    "min_gap_model",
                    "rms_jerk_model",
                    "distance_m",
                    "heat_pack_J_per_km",
                    "min_ttc_s",
                    "delta_soc",
                ):
                    assert r[k] == m[k], (law, gap, kappa, k)
    # % change and comparability against the reference run of the same point and vehicle
    r, ref = (
        next(
            x
            for x in rows
            if x["controller"] == law
            and x["vehicle"] == 2
            and x["carfollowing.kappa"] == 0.26
            and x["platoon.gap0_first"] == 0.9
        )
        for law in ("proposed", "ovfl")
    )
    assert r["omega_model_change_pct"] == pytest.approx(100 * (r["omega_model"] / ref["omega_model"] - 1), rel=1e-12)
    assert r["distance_diff_pct"] == pytest.approx(100 * (r["distance_m"] / ref["distance_m"] - 1), rel=1e-12)
    assert r["comparable"] == (abs(r["distance_diff_pct"]) <= 1.0)
    # provenance on every row
    assert all(x["aev_ocp_version"] and x["casadi_version"] for x in rows)


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_executors_identical_and_dask_local_cluster(tmp_path, monkeypatch):
    pytest.importorskip("dask.distributed")
    stops = record_cluster_stops(monkeypatch)
    f = _study(tmp_path)
    tables = {}
    # the pool's two workers return results out of order; the local Dask cluster runs one (issue 40: a second
    # worker process, importing NumPy and CasADi, cost a second of CPU and checked nothing the pool does not)
    for ex, kw in (("inprocess", {}), ("pool", {"workers": 2}), ("dask", {"workers": 1})):
        out = run_study(read_study(f), tmp_path / ex, executor=ex, report=False, **kw)
        tables[ex] = _stable(out.rows)
        # the stored task files hold the same bytes apart from the wall time
        stored = sorted(
            (p.name, {k: v for k, v in json.loads(p.read_text()).items() if k not in VOLATILE})
            for p in (tmp_path / ex / "points").glob("*.json")
        )
        tables[ex + "-store"] = json.dumps(stored, sort_keys=True)
    assert tables["pool"] == tables["inprocess"] == tables["dask"]
    assert tables["pool-store"] == tables["inprocess-store"] == tables["dask-store"]
    assert stops == [True]  # a study that got every result asks its cluster to close gracefully


@pytest.mark.quick
def test_resume_recomputes_only_what_is_missing(tmp_path, monkeypatch):
    f = _study(tmp_path)
    out1 = run_study(read_study(f), tmp_path / "o", executor="inprocess", report=False)
    calls: list[str] = []
    real = runner_mod.run_task
    monkeypatch.setattr(runner_mod, "run_task", lambda spec: calls.append(spec["key"]) or real(spec))
    out2 = run_study(read_study(f), tmp_path / "o", executor="inprocess", report=False)
    assert calls == [] and _stable(out2.rows) == _stable(out1.rows)
    # one file deleted and one truncated (an interrupted foreign write): exactly those two rerun
    files = sorted((tmp_path / "o" / "points").glob("*.json"))
    files[0].unlink()
    files[3].write_text(files[3].read_text()[:40])
    out3 = run_study(read_study(f), tmp_path / "o", executor="inprocess", report=False)
    assert sorted(calls) == sorted([files[0].stem, files[3].stem])
    assert _stable(out3.rows) == _stable(out1.rows)
    # extending the study (a third kappa) computes only the new proposed runs
    calls.clear()
    run_study(
        read_study(_study(tmp_path, STUDY.replace("[0.03, 0.26]", "[0.03, 0.26, 0.11]"))),
        tmp_path / "o",
        executor="inprocess",
        report=False,
    )
    assert len(calls) == 2  # two gaps × proposed(κ = 0.11); OVFL is already stored


def test_failures_and_events_are_recorded(tmp_path, monkeypatch):
    text = STUDY.replace("values = [0.35, 0.9]", "values = [0.35, 0.9, 0.0004]").replace(
        '"platoon.followers" = 3', '"platoon.followers" = 1'
    )
    study = read_study(_study(tmp_path, text))
    real = runner_mod._simulate
    doomed = next(t.key for t in study.tasks() if t.controller == "proposed" and t.point == 1)

    def flaky(spec):
        if spec["key"] == doomed:
            raise FloatingPointError("planted failure")
        return real(spec)

    monkeypatch.setattr(runner_mod, "_simulate", flaky)
    out = run_study(study, tmp_path / "o", executor="inprocess")
    rows = out.rows
    failed = [r for r in rows if r["status"] == "error"]
    assert len(failed) == 1 and "planted failure" in failed[0]["message"] and not failed[0]["comparable"]
    assert out.n_failed == 1
    # gap 0.0004 at 1.87 speed: the run stops on an event (β/h² makes it stiff: integration_failed),
    # recorded as the row's status, flagged, the other points unaffected
    tiny = [r for r in rows if r["platoon.gap0_first"] == 0.0004]
    assert tiny and all(r["status"] in EVENT_KINDS and r["flag_event"] and not r["comparable"] for r in tiny)
    assert all(r["status"] == "ok" for r in rows if r["platoon.gap0_first"] != 0.0004 and r["status"] != "error")
    report = (tmp_path / "o" / "report.md").read_text()
    assert "planted failure" in report and "Pareto front" in report


def test_table_loads_back_from_csv_and_jsonl(tmp_path):
    out = run_study(read_study(_study(tmp_path)), tmp_path / "o", executor="inprocess")
    a = load_table(tmp_path / "o")
    b = load_table(tmp_path / "o" / "table.csv")
    assert len(a) == len(b) == len(out.rows)
    for x, y in zip(a, b):
        for k in ("omega_model", "heat_pack_J_per_km", "carfollowing.kappa", "vehicle", "controller", "comparable"):
            assert x[k] == y[k], k
    assert (tmp_path / "o" / "fig_omega_model_vs_carfollowing_kappa.png").stat().st_size > 1000


@pytest.mark.quick
def test_random_and_zip_axes(tmp_path):
    text = """
scenarios = ["table1"]
[overrides]
"simulation.t_end" = 1.0
[[axes]]
keys = ["carfollowing.kappa", "carfollowing.beta"]
random = { n = 5, seed = 7, low = [0.01, 2.0], high = [0.2, 4.0] }
[[axes]]
keys = ["platoon.gap0_first", "platoon.gap0_others"]
values = [[0.3, 0.6], [3.5, 2.9]]
[controllers]
laws = ["proposed"]
"""
    s1, s2 = read_study(_study(tmp_path, text)), read_study(_study(tmp_path, text, "again.toml"))
    assert [p.values for p in s1.points] == [p.values for p in s2.points]  # seeded
    assert len(s1.points) == 10
    ks = [p.values["carfollowing.kappa"] for p in s1.points]
    assert all(0.01 <= k <= 0.2 for k in ks) and len(set(ks)) == 5
    assert {(p.values["platoon.gap0_first"], p.values["platoon.gap0_others"]) for p in s1.points} == {
        (0.3, 3.5),
        (0.6, 2.9),
    }
    s3 = read_study(_study(tmp_path, text.replace("seed = 7", "seed = 8"), "other.toml"))
    assert [p.values for p in s3.points] != [p.values for p in s1.points]


@pytest.mark.parametrize(
    "edit, needles",
    [
        (('key = "carfollowing.kappa"', 'key = "carfollowing.kapa"'), ["tiny.toml", "axis carfollowing.kapa", "kapa"]),
        (
            ("values = [0.03, 0.26]", "values = [0.03, -0.26]"),
            ["tiny.toml", "axis carfollowing.kappa", "point 1", "-0.26"],
        ),
        (('laws = ["proposed", "ovfl"]', 'laws = ["proposed", "ovlf"]'), ["tiny.toml", "controllers.laws"]),
        (('"simulation.t_end" = 2.5', '"simulation.t_end" = "long"'), ["tiny.toml", "overrides", "simulation.t_end"]),
        (('reference = "ovfl"', 'reference = "mpc"'), ["tiny.toml", "reference"]),
        # a [report] that could only warn after every task had run is refused when the file is read
        (
            ('metrics = ["omega_model"]', 'metrics = ["omega_modle"]'),
            ["report.metrics", "'omega_modle'", "did you mean omega_model,"],
        ),
        (('"rms_rel_speed_model"]]', '"rms_rel_sped"]]'), ["report.pareto", "'rms_rel_sped'", "rms_rel_speed_mps"]),
        (("[report]\n", '[report]\npareto_by = ["kappa"]\n'), ["report.pareto_by", "'kappa'", "carfollowing.kappa"]),
        (
            ("[report]\n", '[report]\nchange_metric = "rms_jerk_model"\n'),
            ["report.change_metric", "heat_pack_J_per_km"],
        ),
        (("[report]\n", "[report]\nvehicle = 4\n"), ["report.vehicle = 4", "follower 1-3", "have 3 follower"]),
        (("[report]\n", "[report]\nvehicle = [2, 99]\n"), ["report.vehicle = 99", "follower 1-3"]),
    ],
)
def test_bad_study_is_one_line_naming_file_axis_key(tmp_path, capsys, edit, needles):
    f = _study(tmp_path, STUDY.replace(*edit))
    with pytest.raises(StudyError) as exc:
        read_study(f)
    for n in needles:
        assert n in str(exc.value), (n, str(exc.value))
    rc = main(["study", str(f), "--out", str(tmp_path / "o"), "--in-process"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("aev-ocp: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "o").exists()  # nothing ran


def test_report_vehicle_is_checked_against_every_scenario(tmp_path):
    """Follower counts differ per scenario: a [report] vehicle that one scenario has is accepted (the report warns
    after the run about the others), one that none has is refused; the metric names are the table's columns."""
    two = STUDY.replace(
        'scenarios = ["table1"]',
        'scenarios = [{ scenario = "table1", label = "three" }, '
        '{ scenario = "table1", label = "five", overrides = { "platoon.followers" = 5 } }]',
    )
    for v in (3, 5, [1, 5]):
        assert read_study(_study(tmp_path, two.replace("[report]\n", f"[report]\nvehicle = {v}\n"))).report
    with pytest.raises(StudyError, match=r"report\.vehicle = 6 .*follower 1-5 .*have 3, 5 follower"):
        read_study(_study(tmp_path, two.replace("[report]\n", "[report]\nvehicle = 6\n")))
    ok = 'metrics = ["min_ttc_s", "carfollowing.kappa", "solve_ms_median", "nfev", "est_gap_err_rms_m"]'
    assert read_study(_study(tmp_path, STUDY.replace('metrics = ["omega_model"]', ok))).report["metrics"][-1]


@pytest.mark.quick
def test_cli_set_and_mpc_validation(tmp_path, capsys):
    f = _study(tmp_path)
    rc = main(
        ["study", str(f), "--out", str(tmp_path / "o"), "--in-process", "--set", "simulation.t_end=1.5", "--no-report"]
    )
    assert rc == 0
    rows = load_table(tmp_path / "o")
    assert {r["duration_model"] for r in rows} == {1.5}
    assert "ETA" in capsys.readouterr().err
    bad = STUDY + '[[controllers.mpc]]\nlabel = "m"\nN = 0\n'
    with pytest.raises(StudyError, match="controller m.*N"):
        read_study(_study(tmp_path, bad, "bad.toml"))


def test_dask_missing_is_a_clear_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import fails as if not installed
    rc = main(["study", str(_study(tmp_path)), "--dask-local", "2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "aev_ocp[dask]" in err and err.count("\n") == 1


def test_pareto_mask():
    pts = [(1.0, 5.0), (2.0, 3.0), (3.0, 3.5), (4.0, 1.0), (2.5, 3.0), (1.0, 5.0)]
    assert pareto_mask(pts) == [True, True, False, True, False, True]
    assert not math.isnan(sum(x for x, _ in pts))


def test_mpc_and_ocpd_points_equal_direct_runs(tmp_path):
    """An MPC point equals the closed loop built directly from the overridden scenario (solve times aside)."""
    from aev_ocp.mpc.scenario import closed_loop_from_scenario

    text = """
scenarios = ["mpc_paper_single"]
reference = "proposed"
[overrides]
"simulation.t_end" = 1.2
"mpc.N" = 8
[[axes]]
key = "mpc.w_Q"
values = [0.4, 3.0]
[controllers]
laws = ["proposed"]
ocpd = true
[[controllers.mpc]]
label = "mpc-ipopt"
solver = "ipopt"
codegen = false
"""
    out = run_study(read_study(_study(tmp_path, text)), tmp_path / "o", executor="inprocess", report=False)
    rows = {(r["mpc.w_Q"], r["controller"]): r for r in out.rows}
    assert set().union(*out.rows) <= report_columns(
        read_study(_study(tmp_path, text)).axes
    )  # the MPC's and OCP-D's columns too
    assert all(r["status"] == "ok" for r in out.rows) and len(rows) == 6
    for wq in (0.4, 3.0):
        sc = load_scenario("mpc_paper_single").with_overrides(
            {"simulation.t_end": 1.2, "mpc.N": 8, "mpc.w_Q": wq, "mpc.solver": "ipopt", "mpc.codegen": False}
        )
        m = closed_loop_from_scenario(sc).run(list(sc.gaps0), list(sc.speeds0), sc.t_end).metrics()[0]
        r = rows[(wq, "mpc-ipopt")]
        for k in ("heat_pack_J", "omega_model", "rms_jerk_model", "min_gap_model", "distance_m", "fallbacks"):
            assert r[k] == m[k], (wq, k)
        assert r["solve_ms_median"] > 0
        assert rows[(wq, "ocp-d")]["cost_s9_optimum"] > 0
    # more weight on heat: less pack heat per km (the w_Q axis reaches the controller)
    assert rows[(3.0, "mpc-ipopt")]["heat_pack_J_per_km"] < rows[(0.4, "mpc-ipopt")]["heat_pack_J_per_km"]
    # the law does not read [mpc]: one run serves both w_Q points
    assert rows[(0.4, "proposed")]["task_hash"] == rows[(3.0, "proposed")]["task_hash"]


def test_study_ocpd_beside_a_traffic_mpc_is_the_traffic_optimum(tmp_path):
    """A study's OCP-D beside a traffic-formulation MPC solves the MPC's own problem (as `aev-ocp mpc` does):
    its optimum equals run_comparison's traffic OCP-D on the same scenario (it used to solve §9's)."""
    from aev_ocp.mpc.run import run_comparison

    text = """
scenarios = ["mpc_udds_single"]
reference = "proposed"
[overrides]
"simulation.t_end" = 3.0
"mpc.N" = 8
[controllers]
laws = ["proposed"]
ocpd = true
[[controllers.mpc]]
label = "mpc"
codegen = false
"""
    out = run_study(read_study(_study(tmp_path, text)), tmp_path / "o", executor="inprocess", report=False)
    row = next(r for r in out.rows if r["controller"] == "ocp-d")
    sc = load_scenario("mpc_udds_single").with_overrides({"simulation.t_end": 3.0, "mpc.N": 8, "mpc.codegen": False})
    c = run_comparison(sc, laws=())
    assert "cost_s9_optimum" not in row
    assert row["cost_traffic_optimum"] == pytest.approx(c.ocpd["cost_traffic"], rel=1e-8)


def test_interrupt_leaves_only_complete_results(tmp_path, monkeypatch):
    f = _study(tmp_path)
    real = runner_mod.run_task
    count = {"n": 0}

    def interrupted(spec):
        count["n"] += 1
        if count["n"] == 4:
            raise KeyboardInterrupt
        return real(spec)

    monkeypatch.setattr(runner_mod, "run_task", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_study(read_study(f), tmp_path / "o", executor="inprocess")
    stored = list((tmp_path / "o" / "points").glob("*"))
    assert len(stored) == 3 and all(json.loads(p.read_text())["status"] == "ok" for p in stored)
    assert not (tmp_path / "o" / "table.csv").exists()
    monkeypatch.setattr(runner_mod, "run_task", real)
    out = run_study(read_study(f), tmp_path / "o", executor="inprocess")
    assert out.n_tasks == 6 and len(out.rows) == 24


def test_dask_scheduler_address(tmp_path):
    """--scheduler ADDRESS: a running cluster (here a LocalCluster started by the test) gives the same table."""
    distributed = pytest.importorskip("dask.distributed")
    f = _study(tmp_path, STUDY.replace("values = [0.35, 0.9]", "values = [0.35]"))
    ref = run_study(read_study(f), tmp_path / "ref", executor="inprocess", report=False)
    # the cluster's worker a thread of this process, its scheduler on TCP: the study still reaches it by its address
    # and sends it the tasks (issue 40: a worker process importing NumPy, CasADi and aev_ocp cost 3-5 s of CPU and
    # checked nothing the --dask-local tests do not)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://", dashboard_address=None
    ) as cl:
        assert cl.scheduler_address.startswith("tcp://")
        out = run_study(
            read_study(f), tmp_path / "sched", executor="dask", scheduler=cl.scheduler_address, report=False
        )
    assert _stable(out.rows) == _stable(ref.rows)


@pytest.mark.parametrize(
    "name, points, controllers", [("kappa_alpha_table1", 32, 2), ("wq_pareto_mpc", 10, 3), ("predictor_cycle", 9, 3)]
)
def test_shipped_studies_validate(name, points, controllers):
    study = read_study(Path(__file__).resolve().parents[1] / "studies" / f"{name}.toml")
    assert len(study.points) == points and len(study.controllers) == controllers
    assert not study.warnings


def test_chunks_cover_every_task_once(tmp_path):
    from aev_ocp.study.runner import chunk_size, run_tasks

    assert chunk_size(200, 2) == 13 and chunk_size(6, 2) == 1 and chunk_size(1, 64) == 1
    specs = [t.spec for t in read_study(_study(tmp_path)).tasks()][:3]
    batch = run_tasks(specs)
    assert [r["key"] for r in batch] == [s["key"] for s in specs]
    single = [runner_mod.run_task(s) for s in specs]
    strip = lambda rs: [{k: v for k, v in r.items() if k != "wall_s"} for r in rs]  # noqa: E731
    assert strip(batch) == strip(single)


def test_equal_distance_and_time_columns_equal_the_exact_cut_of_direct_runs(tmp_path):
    """The table's eq_distance_* / eq_time_* columns (issue 21 item 5): every run of a point cut at the shortest
    distance (common time) of that point's runs, from the compact profiles the tasks keep, against the exact
    truncation (aev_ocp.truncation.equal_views) of the same runs simulated directly; ranks by ∫Q/km."""
    from aev_ocp.truncation import equal_views

    out = run_study(
        read_study(_study(tmp_path)), tmp_path / "out", executor="inprocess", report=True, progress_stream=sys.stderr
    )
    base = load_scenario("table1")
    gap, kappa = 0.9, 0.26
    sc = _point(base, gap, kappa)
    runs = {law: simulate_platoon(sc.leader, [sc.law(law)] * 3, **sc.simulate_kwargs()) for law in ("proposed", "ovfl")}
    for vehicle in (1, 3):
        exact = equal_views(runs, vehicle - 1)
        got = {
            r["controller"]: r
            for r in out.rows
            if r["vehicle"] == vehicle and r["platoon.gap0_first"] == gap and r["carfollowing.kappa"] == kappa
        }
        assert got["ovfl"]["eq_distance_cut_m"] == pytest.approx(exact["distance"]["cut_m"], rel=1e-12)
        assert got["ovfl"]["eq_time_cut_s"] == pytest.approx(exact["time"]["cut_s"], rel=1e-12)
        for law in ("proposed", "ovfl"):
            for view in ("distance", "time"):
                want = exact[view]["runs"][law]
                # linear interpolation between the kept samples (every 0.1 s here) against the exact cut
                assert got[law][f"eq_{view}_heat_pack_J_per_km"] == pytest.approx(want["heat_pack_J_per_km"], rel=2e-3)
                assert got[law][f"eq_{view}_rank"] == want["rank"]
        d_prop = got["proposed"]["eq_distance_heat_pack_J_per_km"]
        d_ref = got["ovfl"]["eq_distance_heat_pack_J_per_km"]
        assert got["proposed"]["eq_distance_heat_pack_J_per_km_change_pct"] == pytest.approx(100 * (d_prop / d_ref - 1))
    report = (tmp_path / "out" / "report.md").read_text()
    assert "## Equal-distance view, follower 1" in report


def test_study_ocpd_is_the_same_solve_and_replay_as_aev_ocp_mpc_on_a_coarse_grid(tmp_path, monkeypatch):
    """The study's OCP-D runs aev-ocp mpc's solve-and-replay: a run too long for the MPC's grid gets the coarse
    grid there too (said in 'grid_dt' and 'coarse'), and its replay equals run_comparison's to the bit."""
    import aev_ocp.ocp.oracle as oracle
    from aev_ocp.mpc.run import run_comparison

    monkeypatch.setattr(oracle, "ORACLE_BOUND_MAX_INTERVALS", 20)  # the run is too long for the MPC's grid
    text = """
scenarios = ["mpc_udds_single"]
reference = "proposed"
[overrides]
"simulation.t_end" = 2.7
"mpc.N" = 8
[controllers]
laws = ["proposed"]
ocpd = true
"""
    out = run_study(read_study(_study(tmp_path, text)), tmp_path / "o", executor="inprocess", report=False)
    row = next(r for r in out.rows if r["controller"] == "ocp-d")
    sc = load_scenario("mpc_udds_single").with_overrides({"simulation.t_end": 2.7, "mpc.N": 8})
    c = run_comparison(sc, laws=(), with_ocpd=True)
    assert row["coarse"] is True and row["grid_dt"] == pytest.approx(c.ocpd["grid_dt"], rel=1e-12)
    assert c.ocpd["grid_dt"] == pytest.approx(sc.t_end / 2, rel=1e-12)  # the 1 s grid (1.3 model time, 2 intervals)
    assert row["cost_traffic_optimum"] == c.ocpd["cost_traffic_grid"]
    for k in ("heat_pack_J", "omega_model", "rms_jerk_model", "distance_m"):
        assert row[k] == c.ocpd[k], k


def test_study_ocpd_row_gets_the_bound_check_of_aev_ocp_mpc(tmp_path, monkeypatch):
    """The study's OCP-D row is a 'bound' only when its optimum is at most every MPC run's own cost on the same
    grid (as run_comparison's ocpd['role']); a planted optimum above an MPC run's cost makes it a 'reference'
    naming that run; a coarse grid is always a 'reference'."""
    import aev_ocp.study.table as table

    text = """
scenarios = ["mpc_udds_single"]
reference = "proposed"
[overrides]
"simulation.t_end" = 2.6
"mpc.N" = 7
[controllers]
laws = ["proposed"]
ocpd = true
[[controllers.mpc]]
label = "mpc-a"
codegen = false
"""
    study = read_study(_study(tmp_path, text))
    out = run_study(study, tmp_path / "o", executor="inprocess", report=False)
    rows = {r["controller"]: r for r in out.rows}
    mpc, ocpd = rows["mpc-a"], rows["ocp-d"]
    assert mpc["cost_traffic"] > ocpd["cost_traffic_optimum"] > 0  # the MPC's own cost on its grid, and the optimum
    assert ocpd["ocpd_role"] == "bound" and ocpd["ocpd_role_reason"] == "" and ocpd["coarse"] is False
    # the same check with the optimum moved above the MPC's cost (a solve that is no optimum of that grid)
    planted = [dict(r) for r in out.rows]
    for r in planted:
        if r["controller"] == "ocp-d":
            r["cost_traffic_optimum"] = 1.01 * mpc["cost_traffic"]
    table._ocpd_roles(study, planted)
    bad = next(r for r in planted if r["controller"] == "ocp-d")
    assert bad["ocpd_role"] == "reference" and "mpc-a" in bad["ocpd_role_reason"]
    coarse = [dict(r, coarse=True) if r["controller"] == "ocp-d" else dict(r) for r in out.rows]
    table._ocpd_roles(study, coarse)
    assert next(r for r in coarse if r["controller"] == "ocp-d")["ocpd_role"] == "reference"


@pytest.mark.parametrize(
    ("kw", "named"),
    [
        ({"executor": "cloud"}, "executor 'cloud'"),
        ({"executor": None}, "executor None"),
        ({"executor": "pool", "workers": 0}, "workers 0"),
        ({"executor": "pool", "workers": 2.5}, "workers 2.5"),
        ({"executor": "pool", "scheduler": "tcp://127.0.0.1:8786"}, "only for executor 'dask'"),
    ],
)
def test_run_study_refuses_a_bad_executor_before_claiming_its_folder(tmp_path, kw, named):
    """run_study's executor arguments are checked before anything is written: a ParameterError naming the
    argument (it was a bare ValueError, raised after the output folder had been claimed)."""

    out = tmp_path / "o"
    with pytest.raises(ParameterError, match=re.escape(named)):
        run_study(_study(tmp_path), out, report=False, **kw)
    assert not out.exists()


# ----------------------------------------------------------------------------- from the issue-28 re-probe (test_reprobe.py)
@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("table.jsonl", b"\xbc\x00junk\xff"),
        ("table.jsonl", b'{"a": 1}\n{"a": \n'),
        ("table.jsonl", b"[1, 2]\n"),
        ("table.jsonl", b"[" * 100_000 + b"]" * 100_000 + b"\n"),
        ("table.csv", b"a,b\n\xbc\xff,2\n"),
        ("missing.jsonl", None),
        ("fifo.jsonl", "fifo"),
    ],
)
def test_load_table_of_a_damaged_file_raises_load_error(tmp_path: Path, name: str, content: object) -> None:
    """load_table raised UnicodeDecodeError/JSONDecodeError on a damaged table and would hang on a FIFO."""
    from aev_ocp import LoadError
    from aev_ocp.study import load_table

    f = tmp_path / name
    if content == "fifo":
        os.mkfifo(f)
    elif isinstance(content, bytes):
        f.write_bytes(content)
    with pytest.raises(LoadError, match=name):
        load_table(f)


def test_load_table_reads_both_files_alike(tmp_path: Path) -> None:
    from aev_ocp.study import load_table

    (tmp_path / "table.jsonl").write_text('{"kappa": 0.047, "law": "ovfl", "n": 3}\n', encoding="utf-8")
    (tmp_path / "table.csv").write_text("kappa,law,n\n0.047,ovfl,3\n", encoding="utf-8")
    assert load_table(tmp_path) == load_table(tmp_path / "table.csv") == [{"kappa": 0.047, "law": "ovfl", "n": 3}]


# ----------------------------------------------------------------------------- from the issue-28 small leftovers (test_reliability_minors.py)


_GRID = """
name = "grid"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.dt_out" = 0.05
"simulation.t_end" = 35.0
[[axes]]
key = "carfollowing.kappa"
values = [0.004, 0.011, 0.027, 0.045, 0.083, 0.12]
[[axes]]
key = "carfollowing.alpha"
values = [1.3, 1.7, 2.2, 2.6, 3.1]
[controllers]
laws = ["proposed", "ovfl"]
"""


def test_a_bad_study_value_and_a_long_set_value_are_echoed_shortly(tmp_path, capsys, monkeypatch):
    from pathlib import Path

    from cli_helpers import one_error

    repo = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(repo)
    text = (repo / "studies" / "kappa_alpha_table1.toml").read_text()
    cases = [
        (text + f"\n[report.a.b]\nzz = {_BIG_TABLE}\n", [], "report.a"),
        (text.replace("values = [1.0, 1.5, 2.0, 3.0]", f'values = [1.0, "{_BIG_STR}"]'), [], "carfollowing.alpha"),
        (text.replace('name = "kappa_alpha_table1"', f'name = "{_BIG_STR}"'), [], "name = 'qqq"),
        (text, ["--set", f"carfollowing.kappa={_BIG_STR}"], "--set carfollowing.kappa = 'qqq"),
        (text, ["--set", f"carfollowing.beta.x={_BIG_STR}"], "override carfollowing.beta.x = 'qqq"),
    ]
    for i, (body, extra, word) in enumerate(cases):
        f = tmp_path / f"s{i}.toml"
        f.write_text(body)
        rc, _, err = run_cli(["study", str(f), *extra, "--out", str(tmp_path / f"o{i}")], capsys)
        line = one_error(err)
        assert rc == 2 and word in line and "…" in line and len(line) < len(str(f)) + 600, (i, line[:300])
        assert not (tmp_path / f"o{i}").exists()


def test_study_points_are_validated_without_sampling_the_leader_or_copying_the_base_per_layer(tmp_path, monkeypatch):
    """A 6 x 5 grid: every point's document is what applying the [overrides], the --set and the axis values
    to the base scenario in turn gives (computed here independently), yet the leader is sampled once (not
    once per point: a CasADi Function each) and the overrides and --set are applied once per base scenario."""
    from aev_ocp.models.leader import LeaderProfile
    from aev_ocp.scenarios import load_scenario
    from aev_ocp.study import points as points_mod
    from aev_ocp.study import read_study

    f = tmp_path / "grid.toml"
    f.write_text(_GRID)
    sampled, applied = [], []
    real_speed_np, real_apply = LeaderProfile.speed_np, points_mod.apply_to_document

    def speed_np(self, t):  # noqa: ANN001, ANN202
        sampled.append(np.size(t))
        return real_speed_np(self, t)

    def apply(doc, layer, file="<scenario>"):  # noqa: ANN001, ANN202
        applied.append(dict(layer))
        return real_apply(doc, layer, file)

    monkeypatch.setattr(LeaderProfile, "speed_np", speed_np)
    monkeypatch.setattr(points_mod, "apply_to_document", apply)
    sets = {"platoon.followers": 3}
    study = read_study(f, sets=sets)
    assert len(study.points) == 30
    assert sampled.count(1) <= 1  # v_l(0) for speed0_factor: once for the equal leaders of all points
    assert len(applied) == 2 + 30  # [overrides] and --set once, then each point's axis values
    base = dict(load_scenario("table1").document)
    base.setdefault("name", "table1")
    over = {"simulation.dt_out": 0.05, "simulation.t_end": 35.0}
    for p in study.points:
        want = real_apply(real_apply(real_apply(base, over), sets), p.values)
        assert p.document == want


def test_a_study_override_of_a_swept_key_is_refused_not_dropped(tmp_path, capsys):
    """[overrides] (or a base scenario's own overrides) setting a key an axis sweeps, or its SI twin, was
    dropped at every point without a word, whatever its value (a 2000-entry table ran the study)."""
    from cli_helpers import one_error

    cases = [
        ('"carfollowing.kappa" = 0.5', "[overrides] carfollowing.kappa = 0.5 would be ignored: axes[0] sweeps"),
        (f'"carfollowing.alpha" = {_BIG_TABLE}', "[overrides] carfollowing.alpha = {'k0': 0, 'k1': 1,"),
    ]
    for i, (line, word) in enumerate(cases):
        f = tmp_path / f"g{i}.toml"
        f.write_text(_GRID.replace('"simulation.t_end" = 35.0', f'"simulation.t_end" = 35.0\n{line}'))
        rc, _, err = run_cli(["study", str(f), "--out", str(tmp_path / f"o{i}")], capsys)
        assert rc == 2 and word in one_error(err), err
        assert not (tmp_path / f"o{i}").exists()
    inline = _GRID.replace(
        'scenarios = ["table1"]',
        'scenarios = [{ scenario = "table1", label = "t1", overrides = { "carfollowing.kappa" = 0.2 } }]',
    )
    f = tmp_path / "inline.toml"
    f.write_text(inline)
    rc, _, err = run_cli(["study", str(f), "--out", str(tmp_path / "o_inline")], capsys)
    assert rc == 2 and "scenario 't1' overrides carfollowing.kappa = 0.2 would be ignored" in one_error(err)


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


_TOKENS = [
    'name = "z"',
    'scenarios = ["table1"]',
    "[[axes]]",
    'key = "carfollowing.kappa"',
    'keys = ["carfollowing.kappa", "carfollowing.alpha"]',
    "values = [0.1, 0.2]",
    "values = []",
    "values = [[0.1], [1.5, 2]]",
    "random = { n = 3, seed = 1, low = [0.0], high = [0.5] }",
    "random = { n = -1, seed = 1, low = 0.5, high = 0.1 }",
    "random = { n = 1e300 }",
    "[controllers]",
    'laws = ["proposed"]',
    'laws = ["nope"]',
    "laws = 3",
    "[overrides]",
    '"platoon.followers" = 2',
    '"simulation.t_end" = nan',
    'reference = "ovfl"',
    "[report]",
    "metrics = [1]",
    'name = "../x"',
    "[[controllers.mpc]]",
    "N = 100000000",
    "= =",
    "[axes]",
    'description = "\\u0000"',
]


_ENTRY_DAMAGE = st.sampled_from(
    ["empty", "junk", "list", "nested", "swap", "edit", "folder", "fifo", "link", "utf16", "missing_key", "huge_number"]
)


@pytest.fixture(scope="module")
def stored_study(tmp_path_factory):
    """A finished tiny study (4 tasks), read once for the store fuzz."""
    from aev_ocp.study import read_study, run_study

    d = tmp_path_factory.mktemp("study")
    study = read_study(write_tiny_study(d))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return study, run_study(study, d / "o", executor="inprocess", report=False)


@pytest.mark.parametrize(
    "axes, key",
    [
        (
            '[[axes]]\nkey = "carfollowing.kappa"\nrandom = { n = 1000000000, seed = 1, low = [0.0], high = [0.5] }\n',
            "random.n",
        ),
        (
            "".join(
                f'[[axes]]\nkey = "carfollowing.{k}"\nvalues = [{", ".join(str(0.5 + 0.001 * i) for i in range(1000))}]\n'
                for k in ("kappa", "alpha", "beta")
            ),
            "carfollowing.beta",
        ),
    ],
)
def test_study_too_large_is_refused_before_any_point_is_built(tmp_path, capsys, monkeypatch, axes, key):
    monkeypatch.setattr("aev_ocp.study.spec._point_document", _never("a point's document"))
    text = TINY_STUDY.replace('[[axes]]\nkey = "platoon.gap0_first"\nvalues = [0.35, 0.9]\n', axes)
    assert text != TINY_STUDY
    rc, err = _run_study(tmp_path, write_tiny_study(tmp_path, text=text), tmp_path / "o", capsys)
    line = one_error(err)
    assert rc == 2 and key in line and "100000" in line


def test_validation_reports_progress_when_slow(tmp_path, capsys, monkeypatch):
    import functools
    import itertools

    from aev_ocp import progress
    from aev_ocp.study import read_study, spec

    ticks = itertools.count(0, 3)  # a clock that advances 3 s per reading: validation looks slow
    monkeypatch.setattr(spec, "Progress", functools.partial(progress.Progress, clock=lambda: float(next(ticks))))
    read_study(write_tiny_study(tmp_path))
    err = capsys.readouterr().err
    assert "[study tiny] validating 1/2 (50 %)" in err


def test_damaged_store_entries_are_detected_and_recomputed(tmp_path):
    from aev_ocp.study import read_study, run_study

    study = read_study(write_tiny_study(tmp_path))
    out = tmp_path / "o"
    first = run_study(study, out, executor="inprocess", report=False)
    files = sorted((out / "points").glob("*.json"))
    assert len(files) == 4
    a, b = files[0].read_bytes(), files[1].read_bytes()
    files[0].write_bytes(b)  # two results swapped between files
    files[1].write_bytes(a)
    files[2].write_text("{}")
    files[3].write_text("[1, 2, 3]")
    with pytest.warns(UserWarning, match="4 stored result"):
        again = run_study(study, out, executor="inprocess", report=False)
    drop = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert drop(again.rows) == drop(first.rows)
    # an entry whose content no longer matches its hash (a metric edited) is recomputed too
    entry = json.loads(files[0].read_text())
    entry["metrics"][0]["omega_model"] = 1.2345
    files[0].write_text(json.dumps(entry))
    with pytest.warns(UserWarning, match="1 stored result"):
        third = run_study(study, out, executor="inprocess", report=False)
    assert drop(third.rows) == drop(first.rows)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    lines=st.lists(st.sampled_from(_TOKENS), max_size=12),
    noise=st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=20),
)
def test_fuzz_study_toml_is_valid_or_one_clear_error(tmp_path, lines, noise):
    from aev_ocp.overrides import OverrideError
    from aev_ocp.scenarios import ScenarioError
    from aev_ocp.study import StudyError, read_study

    f = tmp_path / "fz.toml"
    f.write_text("\n".join(lines) + "\n" + noise, encoding="utf-8")
    try:
        read_study(f)
    except (StudyError, ScenarioError, OverrideError, ParameterError) as exc:  # exit 2 with one line on the CLI
        assert str(exc)


def test_study_mpc_horizon_over_the_budget_is_refused_before_any_task(tmp_path, capsys):
    f = write_tiny_study(tmp_path, text=TINY_STUDY + '[[controllers.mpc]]\nlabel = "m"\nN = 100000000\n')
    rc, err = _run_study(tmp_path, f, tmp_path / "o", capsys)
    line = one_error(err)
    assert rc == 2 and "controller m" in line and "N = 100000000" in line and not (tmp_path / "o").exists()


def test_store_rebuilds_a_folder_entry_and_a_points_file(tmp_path):
    from aev_ocp.study import read_study, run_study

    study = read_study(write_tiny_study(tmp_path))
    out = tmp_path / "o"
    first = run_study(study, out, executor="inprocess", report=False)
    drop = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    f = sorted((out / "points").glob("*.json"))[0]
    f.unlink()
    (f / "inner").mkdir(parents=True)  # a folder under an entry's name
    with pytest.warns(UserWarning, match="1 stored result"):
        again = run_study(study, out, executor="inprocess", report=False)
    assert drop(again.rows) == drop(first.rows) and f.is_file()
    shutil.rmtree(out / "points")
    (out / "points").write_text("not a folder")
    with pytest.warns(UserWarning, match="4 stored result"):
        third = run_study(study, out, executor="inprocess", report=False)
    assert drop(third.rows) == drop(first.rows) and len(list((out / "points").glob("*.json"))) == 4


@pytest.mark.filterwarnings("ignore:study tiny")  # the rerun says which entries it computes again
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(damage=st.lists(st.tuples(st.integers(0, 3), _ENTRY_DAMAGE), min_size=1, max_size=4))
def test_fuzz_damaged_store_entries_are_recomputed_to_the_same_table(stored_study, tmp_path, damage):
    """Whatever happens to a finished study's stored entries, a rerun gives the same table (wall times aside) and
    leaves a store whose every entry verifies."""
    import tempfile

    from aev_ocp.study import Store, run_study

    study, first = stored_study
    out = Path(tempfile.mkdtemp(dir=tmp_path)) / "o"
    shutil.copytree(first.folder, out)
    files = sorted((out / "points").glob("*.json"))
    for k, how in damage:
        f = files[k]
        if f.is_dir():
            shutil.rmtree(f)
        elif f.exists() or f.is_symlink():
            text = f.read_text(errors="replace") if f.is_file() else "{}"
            f.unlink()
            if how == "swap":
                f.write_bytes(files[(k + 1) % 4].read_bytes() if files[(k + 1) % 4].is_file() else b"{}")
            elif how == "edit":
                f.write_text(text.replace('"omega_model": ', '"omega_model": 1', 1))
            elif how == "huge_number":
                f.write_text(text.replace('"status": "ok"', '"status": 1' + "0" * 5000, 1))
            elif how == "missing_key":
                f.write_text(text.replace('"metrics"', '"metricz"', 1))
            else:
                {
                    "empty": lambda: f.write_bytes(b""),
                    "junk": lambda: f.write_bytes(b"\xff\x00junk"),
                    "list": lambda: f.write_text("[1, 2]"),
                    "nested": lambda: f.write_text("[" * 50_000 + "]" * 50_000),
                    "folder": lambda: (f / "x").mkdir(parents=True),
                    "fifo": lambda: os.mkfifo(f),
                    "link": lambda: f.symlink_to("/dev/zero"),
                    "utf16": lambda: f.write_bytes(text.encode("utf-16")),
                }[how]()
    again = run_study(study, out, executor="inprocess", report=False)
    drop = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert drop(again.rows) == drop(first.rows)
    store = Store(out)
    assert all(store.get(f.stem) is not None for f in files) and store.damaged == []


def test_a_store_kept_behind_a_link_is_followed_and_a_dangling_link_replaced(tmp_path):
    """points/ as a link to a folder on another disk keeps its entries (they are read and added to); a link to
    nothing is damage and is replaced by a folder."""
    from aev_ocp.study.runner import Store

    elsewhere = tmp_path / "other_disk"
    elsewhere.mkdir()
    run = tmp_path / "study"
    run.mkdir()
    (run / "points").symlink_to(elsewhere, target_is_directory=True)

    def result(x: float) -> dict:
        return {"controller": "ovfl", "status": "ok", "message": "", "metrics": [{"omega_J_per_kg": x}]}

    st = Store(run)
    st.put("a1", result(2.5))
    assert (elsewhere / "a1.json").is_file() and (run / "points").is_symlink()
    st.put("b2", result(3.5))
    got = Store(run).get("a1")
    assert got is not None and got["metrics"] == [{"omega_J_per_kg": 2.5}] and (elsewhere / "b2.json").is_file()
    dangling = tmp_path / "study2"
    dangling.mkdir()
    (dangling / "points").symlink_to(tmp_path / "nowhere")
    Store(dangling).put("c3", result(4.5))
    assert (dangling / "points").is_dir() and not (dangling / "points").is_symlink()

"""Every command's output folder loads back (aev_ocp.load): arrays bit for bit, metrics recomputed from the
loaded trajectories equal to the saved ones, settings and provenance present; clear errors otherwise."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

import aev_ocp
from aev_ocp.cli import main
from aev_ocp.saved import ARRAYS, MANIFEST, SIM_ARRAYS, LoadError, load_all
from aev_ocp.scenarios import find_scenario
from aev_ocp.scenarios import load_with_sets


def _same(a, b) -> bool:
    """Equal, with NaN == NaN and JSON's null == NaN (non-finite numbers are null in JSON)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    nan = lambda x: x is None or (isinstance(x, float) and math.isnan(x))  # noqa: E731
    if nan(a) or nan(b):
        return nan(a) and nan(b)
    return a == b


def _check_metrics(r) -> None:
    saved = r.meta["output"]["saved_metrics"]
    assert _same(json.loads(json.dumps(aev_ocp.results.to_jsonable(r.metrics()))), saved)


@pytest.mark.quick
def test_simulate_round_trip(tmp_path, capsys):
    sets = ["simulation.t_end=3.7", "carfollowing.kappa=0.07"]
    rc = main(["simulate", "table1", "--no-plots", "--out", str(tmp_path)] + [x for s in sets for x in ("--set", s)])
    capsys.readouterr()
    assert rc == 0
    runs = load_all(tmp_path)
    direct = load_with_sets(str(find_scenario("table1")), sets).run()  # a second, independent run
    assert list(runs) == list(direct)
    for label, r in runs.items():
        d = direct[label]
        for name in SIM_ARRAYS:
            np.testing.assert_array_equal(getattr(r, name), getattr(d, name), err_msg=name)
        assert r.ev == d.ev and r.controllers == d.controllers and r.status == d.status == "ok"
        _check_metrics(r)
        assert _same(aev_ocp.results.to_jsonable(r.metrics()), aev_ocp.results.to_jsonable(d.metrics()))
        out = r.meta["output"]
        assert out["kind"] == "simulate" and out["settings"]["options"]["sets"] == sets
        assert out["settings"]["document"]["carfollowing"]["kappa"] == 0.07
        assert out["provenance"]["aev_ocp"] == aev_ocp.__version__ and out["provenance"]["casadi"]
    first = aev_ocp.load(tmp_path / MANIFEST)  # the manifest path works too; default = the first run
    assert first.meta["output"]["label"] == list(runs)[0]
    # the CSV written beside it holds the same trajectories (10 significant digits)
    label = list(runs)[1]
    with open(tmp_path / f"{label}.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["vehicle"] == "3"]
    np.testing.assert_allclose([float(r["speed_model"]) for r in rows], runs[label].speed[:, 2], rtol=1e-9, atol=1e-12)


def test_mpc_round_trip_and_time_limit(tmp_path, capsys):
    from aev_ocp.mpc.cli import cli_mpc

    out = tmp_path / "full"
    # the same controller and steps twice: the full run, then one stopped by a time limit
    same = ["--set", "simulation.t_end=1.2", "--solver", "sqp", "--no-codegen", "--no-ocpd", "--laws", "ovfl"]
    rc = cli_mpc(["mpc_paper_single", "--out", str(out), *same])
    assert rc == 0
    r = aev_ocp.load(out)
    assert r.meta["output"]["runs"] == ["mpc", "ovfl"] and r.controllers[0].startswith("mpc")
    saved = json.loads((out / "results.json").read_text())
    _check_metrics(r)
    assert _same(
        json.loads(json.dumps(aev_ocp.results.to_jsonable(r.metrics()[0]["omega_model"]))),
        saved["metrics"]["mpc"][0]["omega_model"],
    )
    with open(out / "trajectories_mpc.csv", newline="") as fh:
        gap = np.array([float(row["gap_model"]) for row in csv.DictReader(fh)])
    np.testing.assert_allclose(gap, r.gap[:, 0], rtol=1e-9)
    assert r.solver_stats[0]["n_steps"] == 12
    law = aev_ocp.load(out, run="ovfl")
    _check_metrics(law)
    with pytest.raises(LoadError, match=r"no run 'ipopt'.*\['mpc', 'ovfl'\]"):
        aev_ocp.load(out, run="ipopt")

    # a time limit stops the loop cleanly: exit 1, a partial result flagged by its status, equal to the
    # first part of the full run (same controller, same steps)
    part = tmp_path / "part"
    capsys.readouterr()
    rc = cli_mpc(["mpc_paper_single", "--out", str(part), *same, "--time-limit", "1e-9"])
    err = capsys.readouterr().err
    assert rc == 1 and "time_limit" in err and "partial" in err
    p = aev_ocp.load(part)
    assert p.status == "time_limit" and p.events[0].vehicle == -1 and p.t[-1] < 1.2
    k = p.t.size
    np.testing.assert_array_equal(p.gap[: k - 1], r.gap[: k - 1])
    assert p.metrics()[0]["run_status"] == "time_limit"


@pytest.mark.quick
def test_ocp_round_trip_with_grid(tmp_path, capsys):
    from aev_ocp.ocp.cli import cli_ocp

    rc = cli_ocp(
        [
            "current-profile",
            "--N",
            "20",
            "--no-refine",
            "--grid",
            "E_req=1500,2500",
            "--grid",
            "t_f=45",
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    main_r = aev_ocp.load(tmp_path)
    saved = json.loads((tmp_path / "current_profile.json").read_text())  # the JSON written beside it
    np.testing.assert_array_equal(main_r.t, saved["t"])
    np.testing.assert_array_equal(main_r.controls["I"], saved["controls"]["I"])
    assert main_r.objective == saved["objective"] and main_r.status == saved["status"]
    assert _same(
        json.loads(json.dumps(aev_ocp.results.to_jsonable(main_r.stats()))), main_r.meta["output"]["saved_metrics"]
    )
    runs = load_all(tmp_path)
    assert list(runs) == ["main", "sweep000", "sweep001"]
    sweep = json.loads((tmp_path / "current_profile_sweep.json").read_text())["sweep"]
    assert [(s["E_req_J"], s["t_f_s"]) for s in sweep] == [(1500.0, 45.0), (2500.0, 45.0)]
    for s, lab in zip(sweep, ["sweep000", "sweep001"]):
        assert runs[lab].objective == s["optimal_heat_J"]
        assert runs[lab].t[-1] == pytest.approx(45.0)  # the sweep point's horizon t_f [s]
    assert main_r.meta["output"]["settings"]["grids"] == {"E_req": [1500.0, 2500.0], "t_f": [45.0]}


@pytest.mark.quick
@pytest.mark.parametrize(
    "grid, word",
    [
        (["E_req=1,x"], "value 2"),
        (["D=100"], "does not apply"),
        (["Z=1"], "unknown grid"),
        (["E_req=-5"], "> 0"),
        (["E_req"], "NAME=V1"),
    ],
)
def test_ocp_grid_errors(tmp_path, capsys, grid, word):
    from aev_ocp.ocp.cli import cli_ocp

    rc = cli_ocp(["current-profile", "--out", str(tmp_path)] + [x for g in grid for x in ("--grid", g)])
    assert rc == 2 and word in capsys.readouterr().err


@pytest.mark.quick
def test_ocp_grid_file(tmp_path):
    from aev_ocp.ocp.cli import parse_grids

    (tmp_path / "g.toml").write_text("D = [500, 750.5]\nt_f = [60]\n")
    (tmp_path / "g.json").write_text('{"E_req": [1200, 3400]}')
    assert parse_grids("eco-trip", ["t_f=70,80"], str(tmp_path / "g.toml")) == {
        "D": [500.0, 750.5],
        "t_f": [70.0, 80.0],
    }
    assert parse_grids("current-profile", [], str(tmp_path / "g.json")) == {"E_req": [1200.0, 3400.0]}


def test_study_round_trip(tmp_path, capsys):
    from aev_ocp.study import load_table
    from aev_ocp.study.cli import cli_study

    rc = cli_study(
        [
            "studies/kappa_alpha_table1.toml",
            "--in-process",
            "--no-report",
            "--out",
            str(tmp_path),
            "--set",
            "simulation.t_end=1.5",
        ]
    )
    assert rc == 0
    o = aev_ocp.load(tmp_path)
    assert o.rows == load_table(tmp_path) and o.n_tasks == 36 and o.n_failed == 0
    assert o.meta["output"]["settings"]["study"] == "kappa_alpha_table1" and o.meta["output"]["provenance"]
    # a row's metrics are those of the simulation it names, run again independently
    row = next(r for r in o.rows if r["controller"] == "proposed" and r["vehicle"] == 2 and r["point"] == 5)
    sc = load_with_sets(
        str(find_scenario("table1")),
        [
            f"carfollowing.kappa={row['carfollowing.kappa']!r}",
            f"carfollowing.alpha={row['carfollowing.alpha']!r}",
            "simulation.t_end=1.5",
            "simulation.dt_out=0.05",
            'compare=["proposed"]',
        ],
    )
    m = sc.run()["proposed"].metrics()[1]
    assert row["omega_model"] == pytest.approx(m["omega_model"], rel=1e-12)


@pytest.mark.quick
def test_load_errors(tmp_path):
    with pytest.raises(LoadError, match="not an aev_ocp output"):
        aev_ocp.load(tmp_path)
    (tmp_path / MANIFEST).write_text("{not json")
    with pytest.raises(LoadError, match="cannot read it as JSON"):
        aev_ocp.load(tmp_path)
    (tmp_path / MANIFEST).write_text(json.dumps({"format": "other"}))
    with pytest.raises(LoadError, match="not an aev_ocp output"):
        aev_ocp.load(tmp_path)
    (tmp_path / MANIFEST).write_text(json.dumps({"format": "aev_ocp-output", "format_version": 99, "kind": "mpc"}))
    with pytest.raises(LoadError, match="newer"):
        aev_ocp.load(tmp_path)


@pytest.mark.quick
def test_damaged_arrays_are_refused(tmp_path, capsys):
    assert main(["simulate", "table1", "--no-plots", "--out", str(tmp_path), "--set", "simulation.t_end=0.5"]) == 0
    data = bytearray((tmp_path / ARRAYS).read_bytes())
    data[-100] ^= 1
    (tmp_path / ARRAYS).write_bytes(bytes(data))
    with pytest.raises(LoadError, match="SHA-256"):
        aev_ocp.load(tmp_path)


def test_ocp_eco_trip_time_limit_writes_a_flagged_partial_sweep(tmp_path, capsys):
    """A time limit that has passed after the first solve: exit 1, the heat-optimal trip solved and saved,
    the energy objective and the D sweep not run, the manifest flagged."""
    from aev_ocp.ocp.cli import cli_ocp

    rc = cli_ocp(
        ["eco-trip", "--N", "20", "--no-refine", "--grid", "D=800,900", "--time-limit", "1e-9", "--out", str(tmp_path)]
    )
    err = capsys.readouterr().err
    assert rc == 1 and "stopped by --time-limit" in err and "partial" in err
    m = json.loads((tmp_path / MANIFEST).read_text())
    assert m["time_limit"] is True and m["sweep"] == []
    assert list(load_all(tmp_path)) == ["heat"] and aev_ocp.load(tmp_path).success


@pytest.mark.quick
def test_study_trajectories_are_optional_and_load_back(tmp_path):
    """run_study(..., trajectories=True) saves each task's run; a stored task without them is run again;
    the loaded trajectories give back the table's metrics."""
    import io

    from aev_ocp.study import run_study
    from aev_ocp.study.cli import _with_sets
    from aev_ocp.study.spec import parse_study

    study = _with_sets("studies/kappa_alpha_table1.toml", {"simulation.t_end": 0.8}, parse_study)
    out = run_study(study, tmp_path, executor="inprocess", report=False, progress_stream=io.StringIO())
    with pytest.raises(LoadError, match="--trajectories"):
        out.trajectory(3, "proposed")
    buf = io.StringIO()
    out = run_study(study, tmp_path, executor="inprocess", report=False, trajectories=True, progress_stream=buf)
    assert "(0 stored" in buf.getvalue()  # nothing reused: the stored tasks had no trajectories
    r = out.trajectory(3, "proposed")
    rows = {row["vehicle"]: row for row in out.rows if row["point"] == 3 and row["controller"] == "proposed"}
    for m in r.metrics():
        assert m["omega_model"] == rows[m["vehicle"]]["omega_model"]
        assert m["min_gap_model"] == rows[m["vehicle"]]["min_gap_model"]
    assert aev_ocp.load(tmp_path).trajectory(3, "proposed").t.size == r.t.size


@pytest.mark.quick
def test_ocp_prop31_cases_load_back(tmp_path, capsys):
    """Every OCP-A case is saved; the loaded optima equal a second, in-process solve bit for bit."""
    from aev_ocp.ocp.api import run_prop31
    from aev_ocp.ocp.cli import cli_ocp

    assert cli_ocp(["prop31", "--N", "16", "--no-refine", "--out", str(tmp_path)]) == 0
    runs = load_all(tmp_path)
    direct = run_prop31("ms", N=16, refine=False)
    assert list(runs) == list(direct)
    for case, e in direct.items():
        np.testing.assert_array_equal(runs[case].controls["I"], e["result"].controls["I"])
        assert runs[case].objective == e["result"].objective and runs[case].problem == e["result"].problem

"""Every command's output folder loads back (aev_ocp.load): arrays bit for bit, metrics recomputed from the
loaded trajectories equal to the saved ones, settings and provenance present; clear errors otherwise."""

from __future__ import annotations

import csv
import json
import os
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers import _unblocked_after
from helpers import same_numbers as _same
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import aev_ocp
from aev_ocp.cli import main
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.saved import ARRAYS, MANIFEST, SIM_ARRAYS, LoadError, load_all
from aev_ocp.scenarios import find_scenario, load_with_sets


# the figures these tests write at TEST_DPI: they check each file, not its resolution (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("figures_at_test_dpi")


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
    # the same controller and steps twice: the full run, then one stopped by a time limit; no PNG plots (issue 40:
    # half the test's time; the plots of aev-ocp mpc: test_mpc_cli.py)
    same = ["--set", "simulation.t_end=1.2", "--solver", "sqp", "--no-codegen", "--no-ocpd", "--laws", "ovfl"]
    rc = cli_mpc(["mpc_paper_single", "--out", str(out), *same, "--no-plots"])
    assert rc == 0 and not list(out.glob("*.png"))
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
    rc = cli_mpc(["mpc_paper_single", "--out", str(part), *same, "--time-limit", "1e-9", "--no-plots"])
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
            "--no-plots",  # no figure is checked here
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
        [
            *("eco-trip", "--N", "20", "--no-refine", "--grid", "D=800,900", "--time-limit", "1e-9"),
            *("--out", str(tmp_path), "--no-plots"),  # no figure is checked here
        ]
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
    from aev_ocp.ocp.run import run_prop31
    from aev_ocp.ocp.cli import cli_ocp

    assert cli_ocp(["prop31", "--N", "16", "--no-refine", "--out", str(tmp_path), "--no-plots"]) == 0
    assert not (tmp_path / "prop31_currents.png").exists()  # the figure is test_ocp_prop31's (test_outputs_written)
    runs = load_all(tmp_path)
    direct = run_prop31("ms", N=16, refine=False)
    assert list(runs) == list(direct)
    for case, e in direct.items():
        np.testing.assert_array_equal(runs[case].controls["I"], e["result"].controls["I"])
        assert runs[case].objective == e["result"].objective and runs[case].problem == e["result"].problem


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
@pytest.mark.parametrize("path", [12345, None, 2.5, ["o"]])
def test_load_of_a_non_path_says_so(path: object) -> None:
    import aev_ocp
    from aev_ocp.saved import LoadError

    with pytest.raises(LoadError, match=r"expected an output folder \(a str or pathlib.Path\), got"):
        aev_ocp.load(path)  # type: ignore[arg-type]
    with pytest.raises(LoadError, match="expected an output folder"):
        aev_ocp.load_all(path)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)
@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    from aev_ocp.models.carfollowing import Proposed
    from aev_ocp.saved import save_output
    from aev_ocp.simulate import simulate_platoon

    d = tmp_path_factory.mktemp("saved")
    r = simulate_platoon(ConstantSpeed(1.3), [Proposed()], gaps0=[0.8], speeds0=[1.1], t_end=0.7)
    save_output(d, "simulate", {"proposed": r})
    return d


def _copy(saved: Path, tmp_path: Path) -> Path:
    d = tmp_path / "copy"
    shutil.copytree(saved, d)
    return d


def _mutate(d: Path, data: st.DataObject) -> None:
    from aev_ocp.saved import ARRAYS, MANIFEST

    name = data.draw(st.sampled_from([ARRAYS, MANIFEST]))
    f = d / name
    raw = f.read_bytes()
    how = data.draw(st.sampled_from(["truncate", "bytes", "rename", "json", "npz", "member", "array"]))
    if how in ("npz", "member", "array"):  # damage inside the arrays file, its SHA-256 updated (the check passes)
        import hashlib
        import io

        a = d / ARRAYS
        z = a.read_bytes()
        if how == "npz":
            at = data.draw(st.integers(0, len(z) - 1))
            z = z[:at] + data.draw(st.binary(min_size=1, max_size=64)) + z[at + 64 :]
        else:
            src, buf = zipfile.ZipFile(io.BytesIO(z)), io.BytesIO()
            names = src.namelist()
            victim = data.draw(st.sampled_from(names))
            with zipfile.ZipFile(buf, "w") as dst:
                for n in names:
                    body = src.read(n)
                    if n == victim and how == "array":  # a valid .npy of another shape or type
                        arr = np.zeros(
                            data.draw(st.lists(st.integers(0, 4), max_size=3)),
                            dtype=data.draw(st.sampled_from(["f8", "i4", "U2", "c16", "?"])),
                        )
                        out = io.BytesIO()
                        np.save(out, arr)
                        body = out.getvalue()
                    elif n == victim:
                        n, body = data.draw(
                            st.sampled_from(
                                [("proposed/renamed.npy", body), (n, body[: len(body) // 2]), (n, b"\x93NUMPY junk")]
                            )
                        )
                    dst.writestr(n, body)
            z = buf.getvalue()
        a.write_bytes(z)
        m = json.loads((d / MANIFEST).read_text())
        m["arrays_sha256"] = hashlib.sha256(z).hexdigest()
        (d / MANIFEST).write_text(json.dumps(m))
    elif how == "truncate":
        f.write_bytes(raw[: data.draw(st.integers(0, len(raw) - 1))])
    elif how == "bytes":
        at = data.draw(st.integers(0, len(raw) - 1))
        f.write_bytes(raw[:at] + data.draw(st.binary(min_size=1, max_size=16)) + raw[at + 16 :])
    elif how == "rename":
        f.rename(d / data.draw(st.sampled_from(["other.npz", "manifest.json.bak"])))
    else:  # a structurally valid manifest with a field of the wrong type
        m = json.loads((d / MANIFEST).read_text())
        run = m["runs"]["proposed"]
        key = data.draw(st.sampled_from(["runs", "ev", "events", "controllers", "meta", "solver_stats", "type"]))
        junk = data.draw(st.sampled_from([{}, [], None, 3, "x", [[{}]], {"a": []}]))
        (m if key == "runs" else run)[key] = junk
        (d / MANIFEST).write_text(json.dumps(m))


def test_loader_refuses_a_fifo_without_hanging(saved, tmp_path):
    from aev_ocp import load
    from aev_ocp.saved import ARRAYS, LoadError

    d = _copy(saved, tmp_path)
    (d / ARRAYS).unlink()
    os.mkfifo(d / ARRAYS)
    with _unblocked_after(d / ARRAYS, 300.0) as opened_for_writing:
        with pytest.raises(LoadError, match="not a regular file"):
            load(d)
    assert not opened_for_writing.is_set()  # load() did not wait on the FIFO (300 s: a bound against a hang only)


@pytest.mark.parametrize("member", ["trajectories.npz", "manifest.json"])
def test_loader_refuses_a_symlink_to_dev_zero(saved, tmp_path, member):
    from aev_ocp import load
    from aev_ocp.saved import LoadError

    d = _copy(saved, tmp_path)
    (d / member).unlink()
    (d / member).symlink_to("/dev/zero")
    with pytest.raises(LoadError, match="not a regular file"):
        load(d)


def test_loader_refuses_a_zip_bomb_member_before_inflating_it(saved, tmp_path, monkeypatch):
    import hashlib

    from aev_ocp import load
    from aev_ocp.saved import ARRAYS, MANIFEST, LoadError

    d = _copy(saved, tmp_path)
    with zipfile.ZipFile(d / ARRAYS, "a", compression=zipfile.ZIP_DEFLATED) as z:  # 3 MB of zeros, ~3 kB packed
        z.writestr("proposed/bomb.npy", b"\0" * 3_000_000)
    m = json.loads((d / MANIFEST).read_text())
    m["arrays_sha256"] = hashlib.sha256((d / ARRAYS).read_bytes()).hexdigest()
    (d / MANIFEST).write_text(json.dumps(m))
    assert (d / ARRAYS).stat().st_size < 100_000
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "0.002")  # 2 MB: the member's stated size is above it
    with pytest.raises(LoadError, match="once unpacked"):
        load(d)
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "0.01")
    assert load(d).status == "ok"  # within the budget the same folder loads (extra member ignored)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_damaged_saved_folders_give_load_error_only(saved, tmp_path, data):
    import tempfile

    from aev_ocp import load
    from aev_ocp.saved import LoadError, load_all

    d = Path(tempfile.mkdtemp(dir=tmp_path)) / "c"
    shutil.copytree(saved, d)
    try:
        _mutate(d, data)
        for fn in (load, load_all):
            try:
                got = fn(d)
            except LoadError as exc:  # the only exception allowed; it names the folder or one of its files
                assert str(d) in str(exc)
                continue
            for r in got.values() if isinstance(got, dict) else [got]:  # what loads is a consistent run
                n = r.t.shape[0]
                assert r.t.shape == (n,) and r.leader_speed.shape == (n,) and r.gap.shape == r.speed.shape == (n, 1)
                assert np.isfinite(r.metrics()[0]["omega_model"])
    finally:
        shutil.rmtree(d.parent)


def test_deeply_nested_manifest_is_a_load_error(saved, tmp_path):
    from aev_ocp import load
    from aev_ocp.saved import MANIFEST, LoadError

    d = _copy(saved, tmp_path)
    (d / MANIFEST).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(LoadError):
        load(d)


@pytest.mark.parametrize(
    "name, bad", [("t", np.arange(3.0)), ("gap", np.zeros((2, 2, 2))), ("speed", np.array(["a"])), ("heat_J", None)]
)
def test_saved_arrays_of_the_wrong_shape_or_type_are_a_load_error(saved, tmp_path, name, bad):
    import hashlib
    import io

    from aev_ocp import load
    from aev_ocp.saved import ARRAYS, MANIFEST, LoadError

    d = _copy(saved, tmp_path)
    with zipfile.ZipFile(d / ARRAYS) as z:
        members = {n: z.read(n) for n in z.namelist()}
    key = f"proposed/{name}.npy"
    if bad is None:
        del members[key]
    else:
        buf = io.BytesIO()
        np.save(buf, bad)
        members[key] = buf.getvalue()
    with zipfile.ZipFile(d / ARRAYS, "w") as z:
        for n, b in members.items():
            z.writestr(n, b)
    m = json.loads((d / MANIFEST).read_text())
    m["arrays_sha256"] = hashlib.sha256((d / ARRAYS).read_bytes()).hexdigest()  # the SHA check passes
    (d / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(LoadError, match=name):
        load(d)

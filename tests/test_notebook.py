"""Results at home in a notebook (issue 26): short reprs that state the metrics, HTML reprs, figures returned as
objects (written only when a path is given), DataFrames when pandas is there and a one-line hint when it is
not, and the commit recorded when the package is built."""

from __future__ import annotations

import io
import json
import math
import os
import re
import runpy
import shutil
import subprocess
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

from aev_ocp import plots, provenance
from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.ocp_result import OCPResult
from aev_ocp.params import EVParams, Units
from aev_ocp.results import fmt_value, summary_html
from aev_ocp.saved import StudyOutput
from aev_ocp.simulate import simulate_platoon

ROOT = Path(__file__).parents[1]
UNITS = Units(length_m=13.0, speed_mps=19.0)


@pytest.fixture(scope="module")
def run():  # noqa: ANN201
    """Six followers (two laws) behind a leader at 1.3, from distinct gaps and speeds."""
    ev = EVParams(units=UNITS)
    n = 6
    return simulate_platoon(
        ConstantSpeed(1.3),
        [Proposed(), OVFL()] * 3,
        [1.1 + 0.07 * i for i in range(n)],
        [1.2 + 0.01 * i for i in range(n)],
        3.7,
        ev=ev,
        dt_out=0.1,
    )


def test_simulation_repr_is_a_few_lines_with_the_metrics_in_si(run) -> None:  # noqa: ANN001
    text = repr(run)
    lines = text.splitlines()
    assert len(lines) <= 8 and len(text) < 900
    assert lines[0] == "SimulationResult: 6 followers (ovfl, proposed), status ok"
    assert f"duration_s {3.7 * UNITS.time_s:.4g}" in lines[1] and f"samples {run.t.size}" in lines[1]
    for i, m in enumerate(run.metrics()[:4]):  # the numbers are the metrics', in SI
        assert (
            f"vehicle {i + 1} ({m['controller']}): ok, ω {m['omega_J_per_kg']:.4g} J/kg, pack ∫Q "
            f"{m['heat_pack_J']:.4g} J, min gap {m['min_gap_m']:.4g} m"
        ) in lines[2 + i]
    assert lines[-1].strip().startswith("… 2 more vehicles")
    html = run._repr_html_()
    assert html.count("<tr>") == 3 + 1 + 4 and "min_gap_m" in html and f"{run.metrics()[0]['min_gap_m']:.4g}" in html
    assert str(run) == text  # print() shows the same few lines


def test_a_stopped_run_names_its_event(run) -> None:  # noqa: ANN001
    r = simulate_platoon(ConstantSpeed(0.0), [OVFL()], [0.08], [1.7], 5.0, ev=EVParams(units=UNITS))
    assert r.status == "collision"
    assert repr(r).splitlines()[0].endswith("status collision")
    assert f"event {str(r.events[0])[:40]}" in repr(r).splitlines()[1]


def _ocp_result() -> OCPResult:
    t = np.linspace(0.0, 4.3, 6)
    return OCPResult(
        problem="ocp-b",
        method="collocation",
        N=5,
        t=t,
        time_unit="s",
        states={"V1": 0.01 * t, "V2": 0.02 * t},
        controls={"I": np.full(5, 7.5)},
        outputs={"Q": 0.3 * t},
        objective=12.345678,
        objective_name="heat_J",
        status="optimal",
        success=True,
        message="ok",
        solver_status="Solve_Succeeded",
        iterations=17,
        wall_time_s=0.0432,
        solver_time_s=0.04,
        max_violation=3.2e-9,
    )


def test_ocp_result_repr() -> None:
    text = repr(_ocp_result())
    assert text.splitlines()[0] == "OCPResult ocp-b (collocation, N = 5): optimal"
    assert "heat_J: 12.35" in text and "iterations: 17" in text and "wall_time_s: 0.0432" in text
    assert "states: V1, V2" in text and "controls: I" in text and len(text.splitlines()) <= 10
    failed = OCPResult.failed("ocp-d", "ms", 40, "infeasible", 1.25, np.zeros(41), "s", "no feasible point")
    assert "message: no feasible point" in repr(failed) and failed.status in repr(failed).splitlines()[0]
    assert "<table>" in _ocp_result()._repr_html_()


def test_study_output_repr(tmp_path: Path) -> None:
    rows = [
        {"point": p, "controller": c, "vehicle": 1, "task_hash": f"{p}{c}"}
        for p in range(3)
        for c in ("proposed", "mpc")
    ]
    out = StudyOutput(tmp_path, rows, [tmp_path / "table.csv"], n_tasks=6, n_failed=1)
    assert repr(out).splitlines()[0] == "StudyOutput: 3 points × 2 controllers (mpc, proposed), 1 of 6 tasks failed"
    assert "rows: 6" in repr(out)


def test_html_repr_escapes_and_cuts() -> None:
    html = summary_html("a <b>", [("x<", "<script>")], [{"c": i} for i in range(23)])
    assert "<script>" not in html and "&lt;script&gt;" in html and "a &lt;b&gt;" in html
    assert html.count("<tr>") == 1 + 1 + 20 and "3 more rows" in html
    assert fmt_value(math.pi * 1e5) == "3.142e+05" and fmt_value(True) == "True" and fmt_value(np.int64(7)) == "7"


@pytest.mark.parametrize("call", ["sim", "ocp", "study", "table"])
def test_without_pandas_the_error_says_how_to_get_it(run, tmp_path, monkeypatch, call) -> None:  # noqa: ANN001
    from aev_ocp.study.table import load_table

    (tmp_path / "table.jsonl").write_text('{"point": 0}\n')
    monkeypatch.setitem(sys.modules, "pandas", None)  # import pandas -> ImportError
    f = {
        "sim": run.to_dataframe,
        "ocp": _ocp_result().to_dataframe,
        "study": StudyOutput(tmp_path, [], [], 0, 0).to_dataframe,
        "table": lambda: load_table(tmp_path, as_dataframe=True),
    }[call]
    with pytest.raises(
        ImportError,
        match=r"needs pandas, which is not installed; install it with: "
        r"pip install 'aev_ocp\[pandas\]'",
    ) as err:
        f()
    name = {
        "sim": "SimulationResult.to_dataframe()",
        "ocp": "OCPResult.to_dataframe()",
        "study": "StudyOutput.to_dataframe()",
        "table": "load_table(as_dataframe=True)",
    }[call]
    assert str(err.value).startswith(f"{name} needs pandas")  # it names the call


def test_dataframes_hold_what_the_csv_files_hold(run, tmp_path) -> None:  # noqa: ANN001
    pd = pytest.importorskip("pandas")
    df = run.to_dataframe()
    csv = pd.read_csv(run.to_csv(tmp_path / "r.csv"))
    assert list(df.columns) == list(csv.columns) and len(df) == len(csv) == run.t.size * 6
    for col in csv.columns:
        if col == "controller":
            assert (df[col] == csv[col]).all()
        else:
            rtol = 1e-5 if col.startswith("t_") else 1e-9  # the CSV writes times with 6 digits, values with 10
            np.testing.assert_allclose(df[col].to_numpy(float), csv[col].to_numpy(float), rtol=rtol, atol=1e-12)
    r = _ocp_result()
    d2 = r.to_dataframe()
    c2 = pd.read_csv(r.to_csv(tmp_path / "o.csv"))
    assert list(d2.columns) == list(c2.columns) == ["t_s", "V1", "V2", "I", "Q"]
    np.testing.assert_allclose(d2.to_numpy(float), c2.to_numpy(float))


def test_plots_return_the_figure_and_write_only_when_given_a_path(run, tmp_path, monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.chdir(tmp_path)
    before = set(plt.get_fignums())
    fig = plots.plot_trajectories(run)
    assert isinstance(fig, Figure) and len(fig.axes) >= 4 and list(tmp_path.iterdir()) == []
    assert set(plt.get_fignums()) == before  # released by pyplot: a notebook draws it once, where it is returned
    fig2 = plots.plot_space_time(run, tmp_path / "st.png", title="a title")
    assert isinstance(fig2, Figure) and (tmp_path / "st.png").read_bytes()[:4] == b"\x89PNG"
    assert fig2.axes[0].get_title() == "a title"
    buf = io.BytesIO()
    fig.savefig(buf, format="png")  # the returned figure still draws
    assert buf.getvalue()[:4] == b"\x89PNG"


# ----------------------------------------------------------------------------- the commit, recorded at build time
def test_an_installed_copy_reads_the_commit_recorded_at_build(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    (tmp_path / provenance.BUILD_INFO).write_text(json.dumps({"git_commit": "0123abc+dirty"}))
    assert provenance._built_commit(tmp_path) == "0123abc+dirty"
    (tmp_path / provenance.BUILD_INFO).write_text("{not json")
    assert provenance._built_commit(tmp_path) is None
    assert provenance._built_commit(tmp_path / "absent") is None
    monkeypatch.setattr(provenance, "_checkout_commit", lambda: None)
    monkeypatch.setattr(provenance, "_built_commit", lambda folder=None: "feedbeef")
    provenance.git_commit.cache_clear()
    try:
        assert provenance.git_commit() == "feedbeef"
    finally:
        provenance.git_commit.cache_clear()


def _setup_module(monkeypatch) -> dict:  # noqa: ANN001
    import setuptools

    monkeypatch.setattr(setuptools, "setup", lambda **kw: None)
    return runpy.run_path(str(ROOT / "setup.py"))


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_the_build_hook_records_the_commit_and_never_fails(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    g = _setup_module(monkeypatch)
    info = g["build_info"]
    repo = tmp_path / "clone"
    repo.mkdir()
    env = {
        **os.environ,
        "GIT_AUTHOR_NAME": "t",
        "GIT_AUTHOR_EMAIL": "t@t",
        "GIT_COMMITTER_NAME": "t",
        "GIT_COMMITTER_EMAIL": "t@t",
    }
    for cmd in (["init", "-q"], ["add", "-A"], ["commit", "-q", "--allow-empty", "-m", "x"]):
        subprocess.run(["git", "-C", str(repo), *cmd], check=True, env=env, capture_output=True)
    head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    info.__globals__["ROOT"] = repo
    assert info() == {"git_commit": head}
    (repo / "f.txt").write_text("a")
    subprocess.run(["git", "-C", str(repo), "add", "f.txt"], check=True)
    assert info() == {"git_commit": head + "+dirty"}  # built from changed files
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))  # no git at all
    assert info() == {"git_commit": None}
    info.__globals__["ROOT"] = tmp_path / "no_git_here"  # a copy without .git
    assert info() == {"git_commit": None}


# ----------------------------------------------------------------------------- no silent waits
@pytest.mark.skipif(
    shutil.which(os.environ.get("CC") or "gcc") is None and shutil.which("cc") is None, reason="needs a C compiler"
)
def test_a_compilation_says_so_and_a_cache_hit_is_quiet(tmp_path: Path, monkeypatch, capsys) -> None:  # noqa: ANN001
    from aev_ocp.compiled import compile_shared

    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    monkeypatch.setenv("AEV_OCP_CACHE", str(cache))
    src = "double aev_twice(double x) { return 2.5 * x; }\n"
    assert compile_shared(src, "twice_test", "t").path is not None
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith("aev_ocp: compiling twice_test with ") and str(cache) in err[0]
    assert re.fullmatch(r"aev_ocp: compiled twice_test in \d+\.\d s", err[1])
    assert compile_shared(src, "twice_test", "t").path is not None  # cached: nothing to wait for, nothing said
    assert capsys.readouterr().err == ""


def test_comparison_and_safety_suite_reprs(run) -> None:  # noqa: ANN001
    from aev_ocp.mpc.run import Comparison
    from aev_ocp.safety.cases import suite_cases
    from aev_ocp.safety.run import run_suite

    one = simulate_platoon(ConstantSpeed(1.3), [Proposed()], [1.1], [1.2], 3.7, ev=EVParams(units=UNITS), dt_out=0.1)
    ms = {"proposed": [{**m, "cost_s9": 0.375} for m in one.metrics()]}
    c = Comparison({"proposed": one}, ms, ocpd={"status": "optimal", "cost_s9": 0.3125, "role": "bound"})
    text = repr(c)
    assert text.splitlines()[0] == "Comparison (s9 formulation): proposed on 1 follower(s)"
    assert f"ω {ms['proposed'][0]['omega_J_per_kg']:.4g} J/kg" in text and "cost 0.375" in text
    assert "OCP-D: optimal, cost 0.3125 (bound)" in text and "<table>" in c._repr_html_()
    cases = [c for c in suite_cases(quick=True) if c.family == "CCRs"][:2]
    out = run_suite(cases, ("proposed",), actuators=("ideal",))
    text = repr(out)
    lines = text.splitlines()
    assert lines[0] == "SuiteOutput: 2 safety cases × 1 controllers" and len(lines) == 2
    assert lines[1].startswith(
        f"  proposed: {len(out.failures('proposed'))} failed of 2 cases, "
        f"{sum(r.collision for r in out.rows)} collisions, min gap "
        f"{min(r.min_gap_m for r in out.rows):.3g} m"
    )


def test_ring_result_repr() -> None:
    from aev_ocp.ring.run import human_ring, run_ring

    res = run_ring(human_ring(230.0, 7, seed=3), 12.5).result
    lines = repr(res).splitlines()
    v = res.speed_mps[res.speed_mps.shape[0] // 2 :]
    assert lines[0] == f"RingResult: 7 vehicles (0 AEV) on 230 m, status {res.status}"
    assert lines[1] == f"  duration_s {float(res.t_s[-1]):.4g}, samples {res.t_s.size}"
    assert lines[2] == (
        f"  mean speed, second half [m/s] {v.mean():.4g}, speed std, second half [m/s] {v.std():.4g}, "
        f"min gap [m] {res.gap_m.min():.4g}"
    )
    assert "<table>" in res._repr_html_()

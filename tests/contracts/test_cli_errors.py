"""Issue 11: no lost files, no crash, one clear line for every bad input.

One test per class of defect found by the probe (path traversal and clobbering, ignored keys, crashes
from tolerances, interrupts, concurrent writers, size limits, unreadable files, exit codes, error
style) and the minor ones beside them. Each asserts the exit code, exactly one ``aev-ocp: error:``
line, no traceback, and that nothing was written where it must not be.
"""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import crash_toml, one_error, run_cli
from study_helpers import write_tiny_study as _study

from aev_ocp import interrupts
from aev_ocp.params import ParameterError, SimOptions
from aev_ocp.results import write_atomic
from aev_ocp.scenarios import ScenarioError, ScenarioWarning, find_scenario, load_scenario

# Names that issue 11 added are imported inside the tests, so that each test fails on its own on a
# checkout without the fix (rather than the whole file failing to import).
EXIT_BAD_INPUT, EXIT_FAILED_RUN, EXIT_INTERRUPTED = 2, 1, 130

ROOT = Path(__file__).resolve().parents[2]

SMALL = """\
name = "{name}"
{compare}
[leader]
kind = "constant"
v = 1.3
[platoon]
followers = {followers}
law = "{law}"
gap0_first = 1.7
speed0 = 1.1
[simulation]
t_end = {t_end}
dt_out = {dt_out}
"""


def small(
    tmp_path: Path,
    fname: str = "s.toml",
    *,
    name: str = "small",
    law: str = "proposed",
    compare: str = "",
    followers: int | str = 2,
    t_end: float | str = 3.0,
    dt_out: float | str = 0.05,
    extra: str = "",
) -> Path:
    p = tmp_path / fname
    p.write_text(
        SMALL.format(name=name, law=law, compare=compare, followers=followers, t_end=t_end, dt_out=dt_out) + extra,
        encoding="utf-8",
    )
    return p


# ----------------------------------------------------------------------------- 1. where files land
@pytest.mark.quick
@pytest.mark.parametrize("bad", ["ABSOLUTE", "../../../escape", "", "a/b", "..", ".hidden"])
def test_scenario_name_cannot_choose_a_folder_outside_results(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], bad: str
) -> None:
    work = tmp_path / "a" / "b" / "c"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    bad = str(tmp_path / "abs_target") if bad == "ABSOLUTE" else bad
    scen = small(work, name=bad)
    targets = [tmp_path / "abs_target", tmp_path / "escape", work / "results" / "a" / "b", work / "results"]
    assert not any(t.exists() for t in targets)
    rc, _, err = run_cli(["simulate", str(scen), "--no-plots"], capsys)
    assert rc == EXIT_BAD_INPUT
    assert "name" in one_error(err)
    assert not any(t.exists() for t in targets)


@pytest.mark.quick
def test_output_folder_of_another_run_is_never_clobbered(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    a = small(tmp_path, "a.toml", name="same")
    b = small(tmp_path, "b.toml", name="same", law="ovfl")
    assert run_cli(["simulate", str(a), "--no-plots"], capsys)[0] == 0
    assert run_cli(["simulate", str(a), "--no-plots"], capsys)[0] == 0  # re-running replaces its own files
    first = (tmp_path / "results" / "same" / "metrics.json").read_bytes()
    rc, _, err = run_cli(["simulate", str(b), "--no-plots"], capsys)  # same name, other file
    assert rc == EXIT_BAD_INPUT and "a.toml" in one_error(err)
    assert (tmp_path / "results" / "same" / "metrics.json").read_bytes() == first
    user = tmp_path / "mine"
    user.mkdir()
    (user / "metrics.json").write_text('{"mine": 1}')
    rc, _, err = run_cli(["simulate", str(a), "--out", str(user), "--no-plots"], capsys)
    assert rc == EXIT_BAD_INPUT and "metrics.json" in one_error(err)
    assert (user / "metrics.json").read_text() == '{"mine": 1}'


@pytest.mark.quick
def test_claim_output_dir_unit(tmp_path: Path) -> None:
    from aev_ocp.results import OutputError, claim_output_dir

    d = tmp_path / "o"
    claim_output_dir(d, "simulate", "x", str(tmp_path / "x.toml"), ["x.csv"])
    claim_output_dir(d, "simulate", "x", str(tmp_path / "x.toml"), ["x.csv"])
    with pytest.raises(OutputError, match="'aev-ocp simulate' of scenario 'x'"):
        claim_output_dir(d, "mpc", "x", str(tmp_path / "x.toml"))
    (tmp_path / "f").write_text("")
    with pytest.raises(OutputError, match="not a folder"):
        claim_output_dir(tmp_path / "f", "simulate", "x", None)


# ----------------------------------------------------------------------------- 2. nothing ignored silently
@pytest.mark.quick
def test_law_that_compare_would_ignore_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (ROOT / "scenarios" / "table1.toml").read_text().replace('law = "proposed"', 'law = "idm"')
    scen = tmp_path / "copy.toml"
    scen.write_text(text)
    rc, _, err = run_cli(["simulate", str(scen), "--out", str(tmp_path / "o"), "--no-plots"], capsys)
    assert rc == EXIT_BAD_INPUT
    line = one_error(err)
    assert "platoon.law" in line and "idm" in line and "compare" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.quick
@pytest.mark.parametrize(
    "compare, platoon_extra, match",
    [
        ('compare = ["ovfl", "ovfl"]', "", "compare.*twice"),
        ('compare = ["ovfl", "proposed"]', 'laws = ["ovfl", "proposed"]', "platoon.laws.*compare"),
    ],
)
def test_compare_siblings(tmp_path: Path, compare: str, platoon_extra: str, match: str) -> None:
    text = SMALL.format(name="c", law="proposed", compare=compare, followers=2, t_end=1.0, dt_out=0.1)
    if platoon_extra:
        text = text.replace('law = "proposed"', platoon_extra)
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ScenarioError, match=match):
        load_scenario(p)


@pytest.mark.quick
def test_coefficients_of_a_law_that_never_runs_warn(tmp_path: Path) -> None:
    p = small(tmp_path, extra="[carfollowing.idm]\nv0_mps = 19.5\n")
    with pytest.warns(ScenarioWarning, match="carfollowing.idm"):
        load_scenario(p)


# ----------------------------------------------------------------------------- 3. no crash from tolerances
@pytest.mark.parametrize("key", ["rtol", "atol"])
def test_tolerances_the_integrators_cannot_honour_are_bad_input(tmp_path: Path, key: str) -> None:
    p = small(tmp_path, extra="")
    p.write_text(p.read_text().replace("dt_out = 0.05", f"dt_out = 0.05\n{key} = 1e-30"))
    with pytest.raises(ScenarioError, match=rf"simulation\.{key} = 1e-30"):
        load_scenario(p)
    with pytest.raises(ParameterError, match=key):
        SimOptions(**{key: 1e-30})


def test_api_with_tiny_tolerances_raises_instead_of_crashing() -> None:
    code = textwrap.dedent("""
        from aev_ocp.models.carfollowing import Proposed
        from aev_ocp.models.leader import PaperLeader
        from aev_ocp.params import ParameterError
        from aev_ocp.simulate import simulate_platoon
        try:
            simulate_platoon(PaperLeader(), [Proposed()], [0.3], [1.87], 5.0, rtol=1e-30, atol=1e-30)
        except ParameterError as exc:
            print("refused:", exc)
    """)
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-500:])
    assert proc.stdout.startswith("refused:") and "rtol" in proc.stdout


# ----------------------------------------------------------------------------- 4. interrupts
def test_an_interrupt_a_solver_swallowed_is_not_lost(capsys: pytest.CaptureFixture[str]) -> None:
    from aev_ocp.cli import guarded

    def swallowing_solver() -> int:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
        except KeyboardInterrupt:
            pass  # what IPOPT/CVODES do: the solve just "fails"
        return 0

    # the state a command starts in, whatever ran before in this process (a C library such as a solver may leave its
    # own SIGINT handler behind, which Python does not see; setting Python's puts Python's back in C too)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert guarded(swallowing_solver) == EXIT_INTERRUPTED
        assert one_error(capsys.readouterr().err) == "aev-ocp: error: interrupted"
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers restored
    finally:
        signal.signal(signal.SIGINT, before if before is not None else signal.SIG_DFL)


def test_sigterm_during_mpc_exits_130_and_leaves_no_temp_files(tmp_path: Path) -> None:
    out = tmp_path / "o"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "aev_ocp.cli",
            "mpc",
            "mpc_paper_single",
            "--solver",
            "ipopt",
            "--no-codegen",
            "--t-end",
            "80",
            "--out",
            str(out),
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    head = []  # stderr up to the closed loop's first progress line, which says it runs (or to the process's end)
    for line in iter(proc.stderr.readline, ""):
        head.append(line)
        if line.startswith("[mpc] step"):
            break
    assert head and head[-1].startswith("[mpc] step"), "".join(head)[-800:]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    err = "".join(head) + err
    assert proc.returncode == EXIT_INTERRUPTED, err[-800:]
    assert one_error(err) == "aev-ocp: error: interrupted"
    assert out.is_dir() and not [p for p in out.iterdir() if ".tmp" in p.name]  # the run's folder, whole


# ----------------------------------------------------------------------------- 5. concurrent writers
def test_plot_and_file_writers_use_unique_temp_names_and_plain_modes(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aev_ocp.mpc.plots import save_figure as mpc_save  # both modules write through aev_ocp.plots.save_figure
    from aev_ocp.ocp.plots import save_figure as ocp_save

    for fixed in (".mpc_trajectories.tmp.png", ".ocp.tmp.png"):  # the old fixed temp names, taken by others
        (tmp_path / fixed).mkdir()
    fig = plt.figure()
    mpc_save(fig, tmp_path / "mpc_trajectories.png")
    ocp_save(plt.figure(), tmp_path / "ocp.png")
    plt.close(fig)
    write_atomic(tmp_path / "a.csv", "x\n")
    umask = os.umask(0)
    os.umask(umask)
    for f in ("mpc_trajectories.png", "ocp.png", "a.csv"):
        assert stat.S_IMODE((tmp_path / f).stat().st_mode) == 0o666 & ~umask, f
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["a.csv", "mpc_trajectories.png", "ocp.png"]


@pytest.mark.quick
def test_failed_figure_write_leaves_no_temp_file(tmp_path: Path) -> None:
    from aev_ocp.results import save_figure_atomic

    class Broken:
        def savefig(self, path: str, **kw: object) -> None:
            Path(path).write_text("partial")
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        save_figure_atomic(Broken(), tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- 6. size limits
@pytest.mark.quick
@pytest.mark.parametrize(
    "followers, t_end, dt_out, key",
    [
        (10**7, 3.0, 0.05, "platoon.followers"),
        (2**62, 3.0, 0.05, "platoon.followers"),
        (2, "1e12", 0.05, "simulation.t_end"),
        (2, 70.0, "1e-9", "simulation.dt_out"),
    ],
)
def test_runs_too_large_for_memory_are_refused_before_they_start(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    followers: int,
    t_end: object,
    dt_out: object,
    key: str,
) -> None:
    import aev_ocp.simulate

    def started(*a: object, **k: object) -> None:  # "before they start": the integration is never entered
        raise AssertionError("the run started")

    monkeypatch.setattr(aev_ocp.simulate, "simulate_platoon", started)
    scen = small(tmp_path, followers=followers, t_end=t_end, dt_out=dt_out)
    rc, _, err = run_cli(["simulate", str(scen), "--out", str(tmp_path / "o")], capsys)
    assert rc == EXIT_BAD_INPUT and not (tmp_path / "o").exists()
    line = one_error(err)
    assert key in line and ("GB" in line or "samples" in line), line


@pytest.mark.quick
def test_ten_thousand_followers_are_thinned_to_fit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from aev_ocp.scenarios import estimate_run_bytes, memory_limit_bytes

    monkeypatch.delenv("AEV_OCP_MAX_MEMORY_GB", raising=False)
    scen = small(tmp_path, followers=10_000, t_end=70.0, dt_out=0.01)
    with pytest.warns(ScenarioWarning, match="dt_out raised from 0.01"):
        s = load_scenario(scen)
    assert s.n_followers == 10_000 and s.dt_out > 0.01
    assert estimate_run_bytes(10_000, 70.0, s.dt_out) <= memory_limit_bytes() <= 4e9


@pytest.mark.quick
def test_mpc_horizon_too_large_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = small(tmp_path, followers=1, extra='[mpc]\nN = 1000000000\nsolver = "ipopt"\n')
    rc, _, err = run_cli(["mpc", str(scen), "--out", str(tmp_path / "o")], capsys)
    assert rc == EXIT_BAD_INPUT and "mpc.N" in one_error(err)
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- 7. unreadable files
@pytest.mark.quick
def test_unreadable_scenario_files_are_one_line_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cases = {}
    (tmp_path / "bin.toml").write_bytes(b'name = "x"\n\xff\xfe\x00\x01binary')
    cases["bin.toml"] = "UTF-8"
    (tmp_path / "deep.toml").write_text("a = " + "[" * 3000 + "]" * 3000 + "\n")
    cases["deep.toml"] = "nested too deeply"
    (tmp_path / "deep2.toml").write_text("a = " + "{b = " * 3000 + "1" + "}" * 3000 + "\n")
    cases["deep2.toml"] = "nested too deeply"
    (tmp_path / "folder").mkdir()
    cases["folder"] = "folder"
    os.symlink(tmp_path / "loop2", tmp_path / "loop1")
    os.symlink(tmp_path / "loop1", tmp_path / "loop2")
    cases["loop1"] = "loop of symbolic links"
    os.mkfifo(tmp_path / "fifo.toml")
    cases["fifo.toml"] = "not a regular file"
    for name, what in cases.items():
        for cmd in (["simulate", str(tmp_path / name)], ["mpc", str(tmp_path / name)]):
            rc, _, err = run_cli(cmd, capsys)
            assert rc == EXIT_BAD_INPUT, (cmd, err)
            line = one_error(err)
            assert name in line and what in line, line


def test_a_broken_local_scenario_does_not_hide_the_shipped_ones(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "table1.toml").write_bytes(b"\xff broken")
    rc, out, err = run_cli(["scenarios"], capsys)
    assert rc == 0 and "fig1a" in out and "us06_platoon" in out
    assert "aev-ocp: warning: skipping" in err and "Traceback" not in err


def test_api_type_errors_name_the_argument() -> None:
    with pytest.raises(TypeError, match="scenario must be a path"):
        find_scenario(42)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- 8. exit codes of mpc
def test_mpc_run_stopped_by_an_event_exits_1_with_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scen = tmp_path / "crash.toml"
    scen.write_text(
        crash_toml("proposed", 0.3, 1.87, 1.0, limits=False)
    )  # (without limits the law brakes at -43 m/s² and stops in time; with them it collides too)
    rc, out, err = run_cli(
        [
            "mpc",
            str(scen),
            "--solver",
            "ipopt",
            "--no-codegen",
            "--no-ocpd",
            "--laws",
            "proposed",
            "--out",
            str(tmp_path / "o"),
        ],
        capsys,
    )
    assert rc == EXIT_FAILED_RUN, err
    line = one_error(err)
    assert "collision at t = " in line and "vehicle 1" in line
    status = next(ln for ln in out.splitlines() if ln.startswith("status"))
    assert "collision at t = " in status and status.rstrip().endswith("ok")  # the law's run did not stop
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert res["status"] == "collision" and res["runs"]["proposed"]["status"] == "ok"


@pytest.mark.quick
@pytest.mark.parametrize(
    "extra, match",
    [
        ("[mpc]\nvehicles = [7]\n", r"s\.toml: mpc\.vehicles = \[7\].*do not exist"),
        ('[mpc]\nformulation = "s9"\nh_min = 2.5\n', r"mpc\.h_min = 2\.5.*infeasible"),
        ("[mpc]\nh_min = 2.5\n", r"mpc\.h_min = 2\.5.*§9 formulation only"),
    ],
)
def test_mpc_infeasible_or_missing_vehicles_are_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, match: str
) -> None:
    scen = small(tmp_path, followers=1, extra=extra)
    rc, _, err = run_cli(["mpc", str(scen), "--out", str(tmp_path / "o")], capsys)
    assert rc == EXIT_BAD_INPUT
    import re

    assert re.search(match, one_error(err)), err


# ----------------------------------------------------------------------------- 10. one error style
@pytest.mark.quick
@pytest.mark.parametrize(
    "argv",
    [
        ["mpc"],
        ["mpc", "mpc_paper_single", "--solver", "nope"],
        ["mpc", "mpc_paper_single", "--t-end", "-1"],
        ["ocp"],
        ["ocp", "nope"],
        ["ocp", "prop31", "--N", "0"],
        ["ocp", "prop31", "table1"],
        ["simulate"],
        ["frobnicate"],
    ],
)
def test_every_subcommand_reports_bad_input_in_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run_cli(argv, capsys)
    assert rc == EXIT_BAD_INPUT
    one_error(err)
    assert "usage:" not in err and err.count("\n") == 1, err


def test_warnings_are_one_line_on_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    import warnings

    from aev_ocp.cli import guarded

    def warn() -> int:
        warnings.warn("two\nlines", UserWarning)
        return 0

    assert guarded(warn) == 0
    assert capsys.readouterr().err == "aev-ocp: warning: two lines\n"
    assert interrupts.interrupted() == 0


@pytest.mark.quick
def test_csv_round_trip_matches_the_arrays(tmp_path: Path) -> None:
    import csv

    r = load_scenario("table1").run(t_end=2.0)["ovfl"]
    f = r.to_csv(tmp_path / "r.csv")
    with open(f, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == r.t.size * r.n_vehicles
    for i in (0, r.n_vehicles - 1):
        mine = [row for row in rows if int(row["vehicle"]) == i + 1]
        assert {row["controller"] for row in mine} == {"ovfl"}
        for col, attr in (("gap_model", "gap"), ("speed_model", "speed"), ("soc", "S"), ("heat_J", "heat_J")):
            np.testing.assert_allclose([float(row[col]) for row in mine], getattr(r, attr)[:, i], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose([float(row["t_model"]) for row in mine], r.t, rtol=1e-5)
        # SI columns lead, named with their units, = the model arrays converted with the scenario's units
        u = r.units
        for col, attr, conv in (
            ("gap_m", "gap", u.length_to_si),
            ("speed_mps", "speed", u.speed_to_si),
            ("accel_mps2", "accel", u.accel_to_si),
            ("omega_J_per_kg", "omega", u.energy_per_mass_to_si),
        ):
            np.testing.assert_allclose(
                [float(row[col]) for row in mine], conv(getattr(r, attr)[:, i]), rtol=1e-9, atol=1e-12
            )
        np.testing.assert_allclose([float(row["t_s"]) for row in mine], u.time_to_si(r.t), rtol=1e-5)
        np.testing.assert_allclose(
            [float(row["leader_speed_mps"]) for row in mine], u.speed_to_si(r.leader_speed), rtol=1e-9
        )
    header = f.read_text(encoding="utf-8").splitlines()[0].split(",")
    first_model = min(header.index(c) for c in header if c.endswith("_model"))
    assert header[0] == "t_s" and all(not c.endswith("_model") for c in header[:first_model])


# ----------------------------------------------------------------------------- siblings
@pytest.mark.quick
def test_ocp_sizes_are_checked_before_building(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, _, err = run_cli(["ocp", "eco-trip", "--N", str(10**9)], capsys)
    line = one_error(err)
    assert rc == EXIT_BAD_INPUT and "--N" in line and "1000000000" in line and "GB" in line
    text = (ROOT / "scenarios" / "mpc_paper_single.toml").read_text().replace("t_end = 70.0", "t_end = 1e5")
    (tmp_path / "long.toml").write_text(text.replace("dt_out = 0.01", "dt_out = 1.0"))
    rc, _, err = run_cli(["ocp", "oracle", str(tmp_path / "long.toml")], capsys)
    assert rc == EXIT_BAD_INPUT and "simulation.t_end" in one_error(err) and "GB" in one_error(err)


def test_reproduce_does_not_replace_a_foreign_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    out.mkdir()
    (out / "report.md").write_text("my notes\n")
    rc, _, err = run_cli(["reproduce", "--quick", "--out", str(out)], capsys)
    assert rc == EXIT_BAD_INPUT and "report.md" in one_error(err)
    assert (out / "report.md").read_text() == "my notes\n"


def test_thinning_rounds_up_and_single_follower_hint(tmp_path: Path) -> None:
    from aev_ocp.scenarios import check_run_size, estimate_run_bytes, memory_limit_bytes, thinned_dt_out

    with pytest.warns(ScenarioWarning):
        dt = thinned_dt_out(3000, 70.0, 0.01)
    assert estimate_run_bytes(3000, 70.0, dt) <= memory_limit_bytes() and dt < 0.0236
    with pytest.raises(ScenarioError, match=r"simulation\.dt_out = 1e-09 .* at least 7.01e-05"):
        thinned_dt_out(2, 70.0, 1e-9)
    with pytest.raises(ScenarioError, match=r"simulation\.t_end = 1e\+12"):
        thinned_dt_out(2, 1e12, 1e9)
    with pytest.raises(ScenarioError, match="lower simulation.t_end") as exc:
        check_run_size(1, 1e6, 0.01)
    assert "platoon.followers" not in str(exc.value)


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
@pytest.mark.parametrize("value", ["0.1", "0.02,0.03,0.04", "a,b", "0.02,nan"])
def test_ocp_v_relax_option_is_named_as_typed(value: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The message named run_prop31's v_relax_V, not the --v-relax-V the user typed."""
    rc, _, err = run_cli(["ocp", "prop31", "--v-relax-V", value, "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and f"--v-relax-V = {value!r} is not allowed" in one_error(err)


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


@pytest.mark.parametrize(
    "argv, word",
    [
        (["simulate", "table1", "--set", "simulation.t_end=1e308"], "simulation.t_end"),
        (["stability", "--law", "ovm", "--ring", "22", "--density-per-km", "0"], "--density-per-km"),
        (["stability", "--law", "ovm", "--ring", "22", "--density-per-km", "nan"], "--density-per-km"),
        (["ring", "sugiyama", "--seed", "-1"], "--seed"),
        (["simulate", "table1", "--set", "simulation.t_end=" + "9" * 5000], "simulation.t_end"),
    ],
)
def test_absurd_numbers_are_bad_input(tmp_path, capsys, argv, word):
    rc, _, err = run_cli([*argv, "--out", str(tmp_path / "o")], capsys)
    line = one_error(err)
    assert rc == 2 and word in line and "internal error" not in line and "Error:" not in line


@pytest.mark.parametrize(
    "argv, word",
    [
        (["simulate", "table1", "--out", ""], "--out: an empty folder name"),
        (["study", "studies/kappa_alpha_table1.toml", "--out", ""], "--out: an empty folder name"),
        (["stability", "--law", "ovm", "--out", ""], "--out: an empty folder name"),
        (["sumo", "sumo_ring", "--out", ""], "--out: an empty folder name"),
        (["sumo", "sumo_ring", "--bogus"], "unrecognized arguments: --bogus"),
        (["study", "{study}", "--scheduler", "nonsense", "--out", "{d}/o"], "is not a Dask scheduler address"),
        (["ocp", "current-profile", "--grid-file", "{grid}", "--out", "{d}/o"], "--grid-file {grid}: grid E_req"),
        (["ocp", "current-profile", "--grid-file", "{json}", "--out", "{d}/o"], "--grid-file {json}: not valid JSON"),
    ],
)
def test_more_bad_input_is_one_line_naming_it(tmp_path, capsys, monkeypatch, argv, word):
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # studies/ and the shipped names
    (tmp_path / "g.toml").write_text("E_req = [1e400]\n")
    (tmp_path / "g.json").write_text("[1, 2]\n")
    subs = {
        "{d}": str(tmp_path),
        "{grid}": str(tmp_path / "g.toml"),
        "{json}": str(tmp_path / "g.json"),
        "{study}": str(_study(tmp_path)),
    }

    def fill(a: str) -> str:
        for k, v in subs.items():
            a = a.replace(k, v)
        return a

    rc, _, err = run_cli([fill(a) for a in argv], capsys)
    assert rc == 2 and fill(word) in one_error(err)
    assert not (tmp_path / "o").exists()

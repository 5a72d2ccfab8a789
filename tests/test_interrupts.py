"""Tries of the independent re-probe of issue 28 on landed main that found defects, each a test.

Ctrl-C during one long compiled cascade run, `mpc --t-end` that is not a whole number of MPC steps,
input files that start with a UTF-8 byte-order mark."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from cli_helpers import one_error, run_cli

EXIT_OK, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 2, 130

LONG = """\
name = "long"
[leader]
kind = "constant"
v = 1.3
[platoon]
followers = {followers}
law = "proposed"
gap0_first = 1.7
speed0 = 1.1
[simulation]
t_end = {t_end}
dt_out = 2.5
"""


def test_ctrl_c_stops_one_long_compiled_run_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The cascade integrates the whole platoon in one C call (7.6 s here): a SIGINT 0.3 s into that call must
    stop it inside the call, through its cancel flag (before: only when the call returned; 98 s for the probe's
    platoon)."""
    import aev_ocp.simulate as simulate
    from aev_ocp import interrupts
    from aev_ocp.scenarios import load_scenario

    p = tmp_path / "long.toml"
    p.write_text(LONG.format(followers=300, t_end=7.5), encoding="utf-8")
    load_scenario(p).run()  # compiles (or finds) the library outside the timed part
    p.write_text(LONG.format(followers=300, t_end=5000.0), encoding="utf-8")
    s = load_scenario(p)
    main = threading.main_thread().ident
    assert main is not None
    codes: list[int] = []
    real = simulate._interruptible_call

    def call_then_interrupt(fn: Any, args: Any, cancel: Any) -> int:  # the signal arrives while the C code runs
        def c_run(*a: object) -> int:
            codes.append(int(fn(*a)))  # the C call's own return code: 2 = stopped through its cancel flag
            return codes[-1]

        threading.Timer(0.3, lambda: signal.pthread_kill(main, signal.SIGINT)).start()
        return real(c_run, args, cancel)

    monkeypatch.setattr(simulate, "_interruptible_call", call_then_interrupt)
    with pytest.raises(KeyboardInterrupt), interrupts.handle_signals():
        s.run()
    assert codes == [2], codes  # one C call, stopped inside (not run to its end, 0)


def test_an_interrupt_swallowed_while_the_run_was_built_stops_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """CasADi's SWIG layer swallows a KeyboardInterrupt raised while the run's functions are built; the recorded
    signal must still stop the run before its compiled part starts (before: the whole run, then exit 130)."""
    import aev_ocp.simulate as simulate
    from aev_ocp import interrupts
    from aev_ocp.scenarios import load_scenario

    p = tmp_path / "long.toml"
    p.write_text(LONG.format(followers=300, t_end=5000.0), encoding="utf-8")
    s = load_scenario(p)
    entered: list[object] = []
    real = simulate._interruptible_call

    def recorded(fn: Any, args: Any, cancel: Any) -> int:  # records whether the C run itself was entered
        def c_run(*a: object) -> int:
            entered.append(a)
            return int(fn(*a))

        return real(c_run, args, cancel)

    monkeypatch.setattr(simulate, "_interruptible_call", recorded)
    with pytest.raises(KeyboardInterrupt), interrupts.handle_signals():
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
        except KeyboardInterrupt:
            pass  # what CasADi does with it
        s.run()
    assert entered == []  # stopped before the compiled C run started, whatever the machine's speed


def test_the_library_can_run_again_after_a_cancelled_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The cancel flag is cleared for the next call: a run after an interrupted one gives the same numbers
    as a fresh run."""
    import aev_ocp.simulate as simulate
    from aev_ocp import interrupts
    from aev_ocp.scenarios import load_scenario

    p = tmp_path / "long.toml"
    p.write_text(LONG.format(followers=40, t_end=30.0), encoding="utf-8")
    ref = load_scenario(p).run()["proposed"]
    p2 = tmp_path / "longer.toml"
    p2.write_text(LONG.format(followers=300, t_end=5000.0), encoding="utf-8")
    main = threading.main_thread().ident
    assert main is not None
    real = simulate._interruptible_call

    def call_then_interrupt(*args: object) -> int:
        threading.Timer(0.3, lambda: signal.pthread_kill(main, signal.SIGINT)).start()
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(simulate, "_interruptible_call", call_then_interrupt)
    with pytest.raises(KeyboardInterrupt), interrupts.handle_signals():
        load_scenario(p2).run()
    monkeypatch.undo()
    again = load_scenario(p).run()["proposed"]
    assert not again.events
    assert again.t.shape == ref.t.shape
    assert float(abs(again.gap - ref.gap).max()) == 0.0 and float(abs(again.speed - ref.speed).max()) == 0.0


BOM = b"\xef\xbb\xbf"
SMALL = """\
name = "bom"
[leader]
kind = "constant"
v = 1.3
[platoon]
followers = 2
law = "proposed"
gap0_first = 1.7
speed0 = 1.1
[simulation]
t_end = 3.5
dt_out = 0.05
"""


def test_a_byte_order_mark_is_read_like_the_same_file_without_it(tmp_path: Path) -> None:
    """Scenario, study and grid files saved with a UTF-8 BOM (Notepad) load exactly as without it (before: 'not
    valid TOML: Invalid statement (at line 1, column 1)', exit 2)."""
    from aev_ocp.scenarios import load_scenario
    from aev_ocp.study.spec import read_study

    plain, marked = tmp_path / "plain.toml", tmp_path / "marked.toml"
    plain.write_text(SMALL, encoding="utf-8")
    marked.write_bytes(BOM + SMALL.replace("\n", "\r\n").encode("utf-8"))
    a, b = load_scenario(plain).run()["proposed"], load_scenario(marked).run()["proposed"]
    assert float(abs(a.gap - b.gap).max()) == 0.0 and float(abs(a.speed - b.speed).max()) == 0.0
    study = 'name = "st"\nscenarios = ["plain.toml"]\n[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.013, 0.047]\n'
    study += '[controllers]\nlaws = ["proposed"]\n'
    (tmp_path / "st.toml").write_bytes(BOM + study.encode("utf-8"))
    assert len(read_study(tmp_path / "st.toml").points) == 2


def test_a_grid_file_with_a_byte_order_mark_is_read(tmp_path: Path) -> None:
    from aev_ocp.limits import read_input_file

    f = tmp_path / "g.json"
    f.write_bytes(BOM + b'{"E_req": [1500.0], "t_f": [45.0]}')
    assert read_input_file(f, "grid file", ValueError) == b'{"E_req": [1500.0], "t_f": [45.0]}'
    f.write_bytes(b"\xef\xbb" + b"{}")  # a broken mark is not a mark: left for the parser to refuse
    assert read_input_file(f, "grid file", ValueError) == b"\xef\xbb{}"


def test_workers_start_with_sigint_blocked() -> None:
    """interrupts.sigint_blocked: a process spawned inside inherits SIGINT blocked (a terminal Ctrl-C reaches the
    whole group: a worker still importing printed a KeyboardInterrupt traceback); this thread's mask is restored."""
    import multiprocessing as mp

    from aev_ocp import interrupts

    if not hasattr(signal, "pthread_sigmask"):
        pytest.skip("no signal masks on this platform")
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    with interrupts.sigint_blocked():
        p = ctx.Process(target=_report_mask, args=(q,))
        p.start()
    blocked = q.get(timeout=600)  # bounds against a hang only: a spawned process imports the package first
    p.join(600)
    assert p.exitcode == 0
    assert signal.SIGINT in blocked
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])  # the mask is restored


def _report_mask(q: object) -> None:
    q.put(signal.pthread_sigmask(signal.SIG_BLOCK, []))  # type: ignore[attr-defined]


def test_study_pool_workers_ignore_the_terminal_ctrl_c(tmp_path: Path) -> None:
    """The study's pool workers run with SIGINT blocked (read from /proc while the study runs)."""
    import subprocess
    import sys

    if not Path("/proc/self/status").exists():
        pytest.skip("needs /proc")
    (tmp_path / "long.toml").write_text(LONG.format(followers=30, t_end=3000.0), encoding="utf-8")
    (tmp_path / "st.toml").write_text(
        'name = "st"\nscenarios = ["long.toml"]\n[[axes]]\nkey = "carfollowing.kappa"\n'
        'values = [0.011, 0.023, 0.037, 0.041]\n[controllers]\nlaws = ["proposed"]\n',
        encoding="utf-8",
    )
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    cmd = [sys.executable, "-m", "aev_ocp.cli", "study", "st.toml", "--out", "o", "--workers", "2", "--no-report"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        masks: dict[int, int] = {}
        deadline = time.monotonic() + 60
        while len(masks) < 2 and time.monotonic() < deadline and proc.poll() is None:
            for child in Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split():
                status = Path(f"/proc/{child}/status").read_text()
                cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
                if b"resource_tracker" not in cmdline and b"spawn_main" in cmdline:
                    masks[int(child)] = int(status.split("SigBlk:")[1].split()[0], 16)
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.communicate(timeout=30)
    assert len(masks) == 2, masks
    assert all(m & (1 << (signal.SIGINT - 1)) for m in masks.values()), masks


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


def test_output_folder_that_cannot_be_created_is_one_short_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--out with a 6000-character path printed 'File name too long: <the whole path>', a dangling symbolic link
    'File exists: link'; both now name the output folder (shortened) and why, exit 2."""
    scen = tmp_path / "s.toml"
    scen.write_text(SMALL, encoding="utf-8")
    long_out = "/".join(["b" * 200] * 30)
    code, _, err = run_cli(["simulate", str(scen), "--no-plots", "--out", str(tmp_path / long_out)], capsys)
    line = one_error(err)
    assert code == EXIT_BAD_INPUT and line.startswith("aev-ocp: error: output folder ") and len(line) < 300, line
    assert "characters) cannot be created or read (File name too long)" in line
    (tmp_path / "link").symlink_to(tmp_path / "nowhere" / "x")
    code, _, err = run_cli(["simulate", str(scen), "--no-plots", "--out", str(tmp_path / "link")], capsys)
    line = one_error(err)
    assert code == EXIT_BAD_INPUT and "is a symbolic link to" in line and "which does not exist" in line, line


@pytest.mark.parametrize(
    ("vehicle", "outcome"),
    [
        ("[2, 7]", "report.vehicle = 7"),
        ("9", "report.vehicle = 9"),
        ("[1, 2]", None),
        ("3", "scenario(s) ['s'] have no follower 3"),
    ],
)
def test_report_vehicle_without_rows_is_refused_or_warns(tmp_path: Path, vehicle: str, outcome: str | None) -> None:
    """[report] vehicle = [99] on a 1-follower platoon wrote a report of nothing ('0 of 0') without a word: a
    follower no scenario has is refused before any task runs; one that only some scenarios lack is a warning."""
    import warnings

    from aev_ocp.study import StudyError, run_study

    (tmp_path / "s.toml").write_text(SMALL, encoding="utf-8")  # 2 followers
    (tmp_path / "st.toml").write_text(
        'name = "st"\nscenarios = ["s.toml", { scenario = "s.toml", label = "s3", overrides = '
        '{ "platoon.followers" = 3 } }]\n[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.013, 0.047]\n'
        f'[controllers]\nlaws = ["proposed"]\n[report]\nvehicle = {vehicle}\n',
        encoding="utf-8",
    )
    if outcome is not None and outcome.startswith("report.vehicle"):
        with pytest.raises(StudyError, match=rf"{outcome} is not allowed: must be a follower 1-3 .*have 2, 3 follower"):
            run_study(tmp_path / "st.toml", tmp_path / "o", executor="inprocess")
        assert not (tmp_path / "o").exists()
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run_study(tmp_path / "st.toml", tmp_path / "o", executor="inprocess")
    said = [str(w.message) for w in caught if "[report] vehicle" in str(w.message)]
    assert len(said) == (outcome is not None), said
    if outcome is not None:
        assert outcome in said[0], said


def test_a_compiler_in_cc_that_does_not_exist_is_reported_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """CC=/nonexistent/cc aev-ocp mpc-export --build built with gcc without a word."""
    import shutil

    from aev_ocp import compiled

    monkeypatch.setenv("CC", "/nonexistent/cc-7")
    monkeypatch.setattr(compiled, "_CC_WARNED", set())
    first, second = compiled.compiler(), compiled.compiler()
    err = capsys.readouterr().err
    assert first == second == shutil.which("cc")
    assert err.count("$CC = '/nonexistent/cc-7' is not a compiler found on PATH") == 1, err
    monkeypatch.setenv("CC", "gcc")
    compiled.compiler()
    assert capsys.readouterr().err == ""

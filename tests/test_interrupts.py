"""Interrupts (aev_ocp.interrupts): Ctrl-C and SIGTERM stop a long compiled run inside its C call, a signal held
back by interrupts.deferred() is raised by its own block however it ends, an interrupt a library swallowed or
turned into another error is still one, workers and compilers stop with the command, and every interrupt the
command reports is one line with exit 130."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from helpers import _computing

from aev_ocp import interrupts
from aev_ocp.scenarios import load_scenario

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


# ----------------------------------------------------------------------------- from the issue-28 small leftovers (test_reliability_minors.py)
def _group_members(pgid: int) -> set[int]:
    """Live (not zombie) processes of process group ``pgid`` (Linux /proc)."""
    out = set()
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                with open(f"/proc/{p}/stat") as fh:
                    state, _ppid, pgrp = fh.read().rsplit(")", 1)[-1].split()[:3]
            except OSError:
                continue
            if int(pgrp) == pgid and state not in ("Z", "X"):
                out.add(int(p))
    return out


def test_a_signal_held_back_by_deferred_is_raised_when_its_block_ends_normally():
    with interrupts.handle_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                done = "the block ran to its end"  # held back: the handler does not cut the block
        assert done and info.value.__cause__ is None
        with interrupts.deferred():  # raised once: the next block is not interrupted again
            pass


def test_a_signal_held_back_by_deferred_is_raised_when_its_block_fails():
    """The block ends with another exception: the interrupt is raised at the end of that block (the failure as
    its cause), not by the next deferred() block of the same command."""
    with interrupts.handle_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                raise OSError(28, "No space left on device")
        assert isinstance(info.value.__cause__, OSError)
        with interrupts.deferred():  # nothing left pending
            pass
        with pytest.raises(interrupts.Interrupted):  # a KeyboardInterrupt of the block itself passes unchanged
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                raise interrupts.Interrupted("SIGINT")
        with interrupts.deferred():
            pass


def test_nested_deferred_blocks_raise_at_the_outermost_end_even_when_the_inner_one_fails():
    with interrupts.handle_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.deferred():
                try:
                    with interrupts.deferred():
                        os.kill(os.getpid(), signal.SIGINT)
                        raise ValueError("inner")
                except ValueError:
                    reached = True  # the inner block does not raise the interrupt: it is still held back
        assert reached and info.value.__cause__ is None


def test_a_second_ctrl_c_during_the_grace_wait_still_kills_the_compiler_group(tmp_path, monkeypatch):
    """A tool (and its child) that ignore SIGTERM, as a hung compiler may: the first Ctrl-C sends the group
    SIGTERM and waits TOOL_STOP_GRACE_S (30 s here); a second Ctrl-C in that wait ends the wait (the wait itself
    raises the interrupt, it does not time out) and goes straight to SIGKILL (before: it skipped the kill, and the
    whole group ran on)."""
    import subprocess
    import threading
    import time

    import aev_ocp.compiled as compiled
    from aev_ocp.compiled import run_tool

    monkeypatch.setattr(compiled, "TOOL_STOP_GRACE_S", 30.0)
    sent: list[int] = []
    real_killpg = os.killpg

    def killpg(pgid: int, sig: int) -> None:
        sent.append(sig)
        real_killpg(pgid, sig)

    waits: list[tuple[object, str]] = []  # (timeout, how the wait ended) of each communicate call
    real_communicate = subprocess.Popen.communicate

    def communicate(self, *a, **kw):  # noqa: ANN001, ANN002, ANN003, ANN202
        try:
            out = real_communicate(self, *a, **kw)
        except BaseException as exc:
            waits.append((kw.get("timeout"), "interrupt" if isinstance(exc, KeyboardInterrupt) else type(exc).__name__))
            raise
        waits.append((kw.get("timeout"), "returned"))
        return out

    monkeypatch.setattr(os, "killpg", killpg)
    monkeypatch.setattr(subprocess.Popen, "communicate", communicate)
    pidf = tmp_path / "tool.pid"
    script = f'trap "" TERM; echo $$ > {pidf}; sleep 30 & wait; wait'

    def ctrl_c_twice() -> None:
        while not pidf.exists() or not pidf.read_text().strip():
            time.sleep(0.02)
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGINT)  # interrupts the build: SIGTERM to the group, then the grace wait
        while not waits:  # the build's own wait has ended: the grace wait is on
            time.sleep(0.02)
        time.sleep(0.4)
        os.kill(os.getpid(), signal.SIGINT)  # in the grace wait

    timer = threading.Thread(target=ctrl_c_twice, daemon=True)
    with interrupts.handle_signals():
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            run_tool(["sh", "-c", script], tmp_path, 60.0)
        timer.join()
    assert sent == [signal.SIGTERM, signal.SIGKILL], sent
    assert waits[:2] == [(60.0, "interrupt"), (30.0, "interrupt")], waits  # the grace wait was cut, not timed out
    pgid = int(pidf.read_text())
    deadline = time.monotonic() + 3.0
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    survivors = _group_members(pgid)
    if survivors:  # do not leave them running when the test fails
        os.killpg(pgid, signal.SIGKILL)
    assert survivors == set()


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


class _Stop(Exception):
    """Raised in the main thread by a signal handler: an exception arriving while run_tool waits (as Ctrl-C does)."""


def test_an_interrupt_the_command_reported_is_one_line(capsys):
    import signal

    from aev_ocp.console import EXIT_INTERRUPTED, error_line, guarded

    def command() -> int:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)
        except KeyboardInterrupt:
            error_line("interrupted: finished tasks are stored")
            return EXIT_INTERRUPTED
        return 0

    assert guarded(command) == EXIT_INTERRUPTED
    from aev_ocp import interrupts

    interrupts.check()  # handled: a later check (a study's progress in this process) does not raise it again
    err = capsys.readouterr().err
    assert err.count("aev-ocp: error:") == 1 and "finished tasks are stored" in err


def test_a_stopped_compiler_takes_its_children_and_temporaries_with_it(tmp_path):
    """run_tool (every C build: the cached libraries and mpc-export --build) stops the compiler's whole process
    group: a child it started (cc1/as in gcc's case) does not run on, and the TERM it gets first lets it remove
    its temporary file, as gcc does. No verdict depends on the machine's speed: the stop comes once the tool has
    started its child and written its temporary (an event), the waits are bounds against a hang only."""
    import signal
    import subprocess
    import threading

    from aev_ocp.compiled import run_tool

    tmpf, pidf = tmp_path / "cc123.s", tmp_path / "child.pid"
    script = f'trap "rm -f {tmpf}; exit 143" TERM; touch {tmpf}; sleep 600 & echo $! > {pidf}; wait'

    def ready() -> bool:
        return tmpf.exists() and pidf.exists() and pidf.read_text().strip().isdigit()

    def gone(pid: int) -> bool:
        deadline = time.monotonic() + 120.0  # a hang guard: a stopped group is gone at once
        while _computing(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        return not _computing(pid)

    # 1. an exception while the tool runs (Ctrl-C, any error): sent once its child exists
    main = threading.get_ident()

    def stop_when_ready() -> None:
        deadline = time.monotonic() + 300.0
        while not ready() and time.monotonic() < deadline:
            time.sleep(0.02)
        signal.pthread_kill(main, signal.SIGUSR1)

    def raise_stop(*_: object) -> None:
        raise _Stop

    old = signal.signal(signal.SIGUSR1, raise_stop)
    try:
        th = threading.Thread(target=stop_when_ready, daemon=True)
        th.start()
        with pytest.raises(_Stop):
            run_tool(["sh", "-c", script], tmp_path, 600.0)
        th.join(300.0)
    finally:
        signal.signal(signal.SIGUSR1, old)
    child = int(pidf.read_text())
    assert gone(child) and not tmpf.exists()
    # 2. its own timeout: a timeout shorter than the tool's start-up (a loaded machine) stops the group before its
    # child exists; the timeout grows until the child existed when it fired, then the child must be gone too
    for timeout_s in (0.5, 2.0, 8.0, 32.0, 128.0):
        pidf.unlink(missing_ok=True)
        with pytest.raises(subprocess.TimeoutExpired):
            run_tool(["sh", "-c", script], tmp_path, timeout_s)
        if pidf.exists() and pidf.read_text().strip().isdigit():
            break
    child = int(pidf.read_text())
    assert gone(child) and not tmpf.exists()
    ok = run_tool(["sh", "-c", "echo built; echo warn >&2"], tmp_path, 600.0)
    assert (ok.returncode, ok.stdout, ok.stderr) == (0, "built\n", "warn\n")


def test_ctrl_c_while_the_command_is_still_importing_is_one_line_and_130(tmp_path):
    """A Ctrl-C in the first ~0.3 s of 'aev-ocp ...' lands in the imports of NumPy and CasADi: one line, exit 130,
    no traceback (the signal is sent from inside the import of aev_ocp.console, deterministically)."""
    import subprocess
    import sys

    code = (
        "import importlib.abc, os, signal, sys\n"
        "class Hook(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path, target=None):\n"
        "        if name == 'aev_ocp.console':\n"
        "            os.kill(os.getpid(), signal.SIGINT)\n"
        "        return None\n"
        "sys.meta_path.insert(0, Hook())\n"
        "sys.argv = ['aev-ocp', 'scenarios']\n"
        "import runpy; runpy.run_module('aev_ocp.cli', run_name='__main__')\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert (p.returncode, p.stderr) == (130, "aev-ocp: error: interrupted\n")


def test_a_ctrl_c_a_library_turned_into_another_error_is_an_interrupt(capsys):
    """CasADi's SWIG layer turns a KeyboardInterrupt raised inside DM.__array__ into a SystemError: still exit 130
    and 'interrupted', not 'internal error'."""
    import signal

    from aev_ocp.console import EXIT_INTERRUPTED, guarded

    def command() -> int:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)
        except KeyboardInterrupt:
            raise SystemError("<function DM.__array__> returned a result with an exception set") from None
        return 0

    assert guarded(command) == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    assert err == "aev-ocp: error: interrupted\n"

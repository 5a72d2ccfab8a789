"""Issue 28, the small leftovers: a signal held back by interrupts.deferred() is raised by its own block however
it ends, folder locks follow a folder that was removed and made again, a second Ctrl-C cannot skip the kill of a
compiler, bad nested keys are echoed shortly, mpc.N is named as typed, and --time-limit stops a run in progress."""

from __future__ import annotations

import fcntl
import os
import shutil
import signal

import pytest

from aev_ocp import interrupts


# ----------------------------------------------------------------------------- interrupts.deferred


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


# ----------------------------------------------------------------------------- output-folder locks


def _locked_by_someone(folder) -> bool:
    """Whether another open file description of folder's lock file cannot take the lock (flock treats each
    open() independently, even within one process)."""
    from aev_ocp.results import LOCK

    fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def test_a_folder_removed_and_made_again_is_locked_again(tmp_path):
    from aev_ocp.results import claim_output_dir, output_lock, release_output_locks

    out = tmp_path / "o"
    try:
        claim_output_dir(out, "simulate", "table1", None, ["a.csv"])  # held until the command ends
        assert _locked_by_someone(out)
        shutil.rmtree(out)  # a notebook removes the folder and runs again into the same name
        claim_output_dir(out, "simulate", "table1", None, ["a.csv"])
        assert _locked_by_someone(out)  # the new folder is locked too (before: the cached path said 'held')
        os.unlink(out / ".aev-ocp.lock")  # only the lock file removed: taken again as well
        with output_lock(out):
            assert _locked_by_someone(out)
        assert _locked_by_someone(out)  # the claim's lock outlives the inner block, as before
        release_output_locks()
        assert not _locked_by_someone(out)
    finally:
        release_output_locks()


# ----------------------------------------------------------------------------- compiler process group


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


def test_a_second_ctrl_c_during_the_grace_wait_still_kills_the_compiler_group(tmp_path):
    """A tool (and its child) that ignore SIGTERM, as a hung compiler may: the first Ctrl-C sends the group
    SIGTERM and waits TOOL_STOP_GRACE_S; a second Ctrl-C in that wait goes straight to SIGKILL (before: it skipped
    the kill, and the whole group ran on)."""
    import threading
    import time

    from aev_ocp.compiled import TOOL_STOP_GRACE_S, run_tool

    pidf = tmp_path / "tool.pid"
    script = f'trap "" TERM; echo $$ > {pidf}; sleep 30 & wait; wait'

    def ctrl_c_twice() -> None:
        while not pidf.exists() or not pidf.read_text().strip():
            time.sleep(0.02)
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGINT)  # interrupts the build: SIGTERM to the group, then the grace wait
        time.sleep(0.4)
        os.kill(os.getpid(), signal.SIGINT)  # in the grace wait

    timer = threading.Thread(target=ctrl_c_twice, daemon=True)
    t0 = time.perf_counter()
    with interrupts.handle_signals():
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            run_tool(["sh", "-c", script], tmp_path, 60.0)
        timer.join()
    assert time.perf_counter() - t0 < TOOL_STOP_GRACE_S + 0.5  # the second Ctrl-C cut the grace wait short
    pgid = int(pidf.read_text())
    deadline = time.monotonic() + 3.0
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    survivors = _group_members(pgid)
    if survivors:  # do not leave them running when the test fails
        os.killpg(pgid, signal.SIGKILL)
    assert survivors == set()

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

"""Helpers that tests of several subjects share: small scenario texts, a study run through the CLI, a stand-in that
fails when called, a process check and a FIFO unblocker."""

from __future__ import annotations

import contextlib
import math
import os
import threading
from pathlib import Path

from cli_helpers import run_cli

#: The figures' resolution [dpi] in tests that check that a figure is written and shown, not how it looks
#: (``aev_ocp.plots.DPI`` patched; the package's 120 dpi: the quick reproduce took 30.9 s of CPU, 27.2 s at 40 dpi)
TEST_DPI = 40


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


SCENARIO = """\
name = "units_probe"
[units]
length_m = {L}
speed_mps = {U}
[leader]
kind = "constant"
v = 1.3
[platoon]
followers = 1
law = "proposed"
gap0 = 2.5
speed0 = 1.3
[simulation]
t_end = 2.0
"""


_BIG_STR = "q" * 10_000


_BIG_TABLE = "{" + ", ".join(f"k{i} = {i}" for i in range(2000)) + "}"


def _run_study(tmp_path: Path, f: Path, out: Path, capsys, *extra: str) -> tuple[int, str]:
    rc, _, err = run_cli(["study", str(f), "--out", str(out), "--in-process", "--no-report", *extra], capsys)
    return rc, err


def _computing(pid: int) -> bool:
    """True while process ``pid`` exists and is not a zombie (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            state = fh.read().rsplit(")", 1)[-1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def _never(what: str):
    """A stand-in for ``what`` (the work a test must not reach) that fails the test when called."""

    def called(*a, **k):
        raise AssertionError(f"{what} was called")

    return called


@contextlib.contextmanager
def _unblocked_after(fifo: Path, after_s: float):
    """If the block is still running after ``after_s`` [s], open ``fifo`` for writing and close it (a reader
    blocked on it then sees an end of file), every 0.2 s until the block ends, and set the event yielded: the
    block waited on the FIFO."""

    done, fired = threading.Event(), threading.Event()

    def watch() -> None:
        if done.wait(after_s):
            return
        fired.set()
        while not done.wait(0.2):  # again and again: the block may open the FIFO more than once
            try:
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    try:
        yield fired
    finally:
        done.set()
        t.join()


def same_numbers(a, b) -> bool:
    """Equal, with NaN == NaN and JSON's null == NaN (non-finite numbers are null in JSON)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_numbers(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_numbers(x, y) for x, y in zip(a, b))
    nan = lambda x: x is None or (isinstance(x, float) and math.isnan(x))  # noqa: E731
    if nan(a) or nan(b):
        return nan(a) and nan(b)
    return a == b

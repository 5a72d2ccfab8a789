"""Progress lines with an ETA, and a wall-clock time limit: one helper for every long run.

The MPC closed loop, the OCP sweeps and the studies report through :class:`Progress`: a line on
stderr at most every ``every_s`` seconds (and at the end) with done/total, the elapsed time and a
linear ETA; :meth:`Progress.update` also checks for Ctrl-C/SIGTERM (:mod:`aev_ocp.interrupts`) and,
once the time limit has passed, raises :class:`TimeLimitReached`. A loop that can stop cleanly
catches it and returns what it has, flagged (status ``"time_limit"``); the closed loop
(:class:`aev_ocp.control.ClosedLoop`) turns it into an event of that kind.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from typing import Any, Callable, Iterator

from .errors import AevOcpError
from . import interrupts
from .params import ParameterError

TIME_LIMIT = "time_limit"  # the status/event kind of a run stopped by its time limit


class TimeLimitReached(AevOcpError):
    """The wall-clock time limit of a run has passed (raised by :meth:`Progress.update`/:meth:`Progress.check`)."""

    kind = TIME_LIMIT


def format_seconds(s: float) -> str:
    """A duration for humans: '42 s', '3 min 05 s', '2 h 07 min' ('?' if unknown)."""
    if not math.isfinite(s) or s < 0:
        return "?"
    if s < 60:
        return f"{s:.1f} s" if s < 10 else f"{s:.0f} s"
    m, sec = divmod(int(round(s)), 60)
    if m < 60:
        return f"{m} min {sec:02d} s"
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min"


def check_time_limit(value: float | None, what: str = "--time-limit") -> float | None:
    """``value`` [s] if it is None or a finite number > 0, else ParameterError naming ``what``."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{what} = {value!r} is not allowed: must be a number of seconds > 0")
    return float(value)


_LOCAL = threading.local()  # .clocks: the Progress objects whose time limit applies to this thread's code now


@contextlib.contextmanager
def time_limited(clock: "Progress") -> Iterator["Progress"]:
    """Within the block, :func:`check_deadline` raises :class:`TimeLimitReached` once ``clock``'s time limit
    has passed: code that cannot report progress while it runs (one compiled integration, which polls
    check_deadline while it waits) stops at the limit instead of at its end."""
    clocks = _LOCAL.__dict__.setdefault("clocks", [])
    clocks.append(clock)
    try:
        yield clock
    finally:
        clocks.remove(clock)


def check_deadline() -> None:
    """Raise on Ctrl-C/SIGTERM (:func:`aev_ocp.interrupts.check`) or once the time limit of an enclosing
    :func:`time_limited` block (this thread's) has passed; call it between steps of long work."""
    interrupts.check()
    for clock in getattr(_LOCAL, "clocks", ()):
        clock.check()


class Progress:
    """Progress of one long run, printed as ``[label] step 120/700 (17 %), 12.3 s elapsed, ETA 48 s``.

    total: the amount of work (steps, tasks, model time …, ``unit`` names it); time_limit_s: wall-clock
    budget [s] from construction (None: none); every_s: minimum interval between lines [s]; stream: where
    lines go (default stderr; ``say`` instead receives each line); clock: a monotonic clock [s] (tests).
    """

    def __init__(
        self,
        label: str,
        total: float | None = None,
        *,
        unit: str = "steps",
        time_limit_s: float | None = None,
        every_s: float = 2.0,
        stream: Any = None,
        say: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.perf_counter,
        deadline: float | None = None,
    ) -> None:
        self.label, self.total, self.unit, self.every_s = label, total, unit, every_s
        self.clock = clock
        self.t0 = clock()
        self.time_limit_s = check_time_limit(time_limit_s, "time limit")
        self.deadline = (
            deadline
            if deadline is not None
            else (self.t0 + self.time_limit_s if self.time_limit_s is not None else None)
        )
        self._stream = stream
        self._say = say
        self._last = -math.inf
        self.done = 0.0
        self._ref: tuple[float, float] | None = None  # (clock, done) at the first update: the ETA's origin
        self.lines: list[str] = []

    # ------------------------------------------------------------------ time
    def elapsed_s(self) -> float:
        """Wall time since construction [s]."""
        return self.clock() - self.t0

    def remaining_s(self) -> float:
        """Wall time left before the time limit [s] (inf without one)."""
        return math.inf if self.deadline is None else self.deadline - self.clock()

    def expired(self) -> bool:
        """True once the time limit has passed."""
        return self.deadline is not None and self.clock() >= self.deadline

    def eta_s(self, done: float | None = None, total: float | None = None) -> float:
        """Linear estimate of the wall time still needed [s]: the rate since the first update (so that a
        set-up before the first step, e.g. building a solver, does not skew it) times the work left
        (nan until two updates show progress)."""
        done = self.done if done is None else done
        total = self.total if total is None else total
        if total is not None and done >= total:
            return 0.0
        if total is None or self._ref is None:
            return math.nan
        t_ref, done_ref = self._ref
        if done <= done_ref:
            return math.nan
        return (self.clock() - t_ref) * max(total - done, 0.0) / (done - done_ref)

    def child(self, label: str, total: float | None = None, unit: str = "steps") -> "Progress":
        """A progress for a part of this run: same stream, same deadline."""
        return Progress(
            label,
            total,
            unit=unit,
            every_s=self.every_s,
            stream=self._stream,
            say=self._say,
            clock=self.clock,
            deadline=self.deadline,
        )

    # ------------------------------------------------------------------ output
    def line(self, what: str = "", note: str = "") -> str:
        """The progress line for the current state."""
        head = (f"[{self.label}] " if self.label else "") + (f"{what} " if what else "")
        if self.total:
            whole = self.unit in ("steps", "tasks", "solves")
            d = f"{self.done:.0f}" if whole else f"{self.done:.4g}"
            t = f"{self.total:.0f}" if whole else f"{self.total:g}"
            head += f"{d}/{t}{'' if what else ' ' + self.unit} ({100 * self.done / self.total:.0f} %), "
        tail = f"{format_seconds(self.elapsed_s())} elapsed"
        if self.total:
            tail += f", ETA {format_seconds(self.eta_s())}"
        if self.deadline is not None:
            tail += (
                f", time limit {format_seconds(self.time_limit_s or (self.deadline - self.t0))} "
                f"({format_seconds(max(self.remaining_s(), 0.0))} left)"
            )
        return head + tail + (f" {note}" if note else "")

    def say(self, text: str) -> None:
        """Print one line (stream or ``say``)."""
        self.lines.append(text)
        if self._say is not None:
            self._say(text)
        else:
            print(text, file=self._stream if self._stream is not None else sys.stderr, flush=True)

    # ------------------------------------------------------------------ steps
    def check(self) -> None:
        """Raise on Ctrl-C/SIGTERM (:class:`aev_ocp.interrupts.Interrupted`) or a passed time limit."""
        interrupts.check()
        if self.expired():
            raise TimeLimitReached(
                f"time limit of {format_seconds(self.time_limit_s or 0.0)} reached after "
                f"{self.done:.4g}/{self.total if self.total is not None else '?'} {self.unit}"
            )

    def update(
        self,
        done: float,
        total: float | None = None,
        what: str = "",
        force: bool = False,
        note: str = "",
        check: bool = True,
    ) -> None:
        """Record progress (``done`` of ``total``), print a line when one is due (``what`` before the count,
        ``note`` after the times), then :meth:`check` (unless ``check`` is False)."""
        self.done = float(done)
        if total is not None:
            self.total = total
        now = self.clock()
        if self._ref is None:
            self._ref = (now, self.done)
        finished = self.total is not None and self.done >= self.total
        if force or finished or now - self._last >= self.every_s:
            self._last = now
            self.say(self.line(what, note))
        if check:
            self.check()

    def closed_loop(self, dt: float | None = None) -> Callable[[float, float], None]:
        """A ``progress(t, t_end)`` callback for :meth:`aev_ocp.control.ClosedLoop.run` (model time):
        counts steps of ``dt`` when given, else model time."""
        if dt:
            self.unit = "steps"
            return lambda t, t_end: self.update(round(t / dt), round(t_end / dt), "step")
        self.unit = "model time"
        return lambda t, t_end: self.update(t, t_end, "t =")

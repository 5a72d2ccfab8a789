"""Ctrl-C and SIGTERM: one behaviour for every command, even inside solvers that swallow them.

IPOPT, CVODES and CasADi's own interrupt check turn a KeyboardInterrupt raised during a solve into a
failed solve; an MPC loop then applies its fallback and carries on, and a run that was interrupted
could finish with status 'ok'. :func:`handle_signals` records every SIGINT/SIGTERM in a flag (and
raises KeyboardInterrupt as Python does); long loops call :func:`check` between steps, and the
command line checks :func:`interrupted` after a command returns, so an interrupt is never lost.
:func:`stop_pool` ends a process pool's running workers at once (a study's, a SUMO sweep's, reproduce's).
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from typing import Any, Iterator

_state = {"signal": 0}


class Interrupted(KeyboardInterrupt):
    """Raised by :func:`check` after SIGINT or SIGTERM."""


def interrupted() -> int:
    """The number of the last SIGINT/SIGTERM received inside :func:`handle_signals`, else 0."""
    return _state["signal"]


def check() -> None:
    """Raise :class:`Interrupted` if SIGINT or SIGTERM arrived (call it between steps of long loops)."""
    if _state["signal"]:
        raise Interrupted(signal.Signals(_state["signal"]).name)


def _handler(signum: int, frame: Any) -> None:  # noqa: ARG001 - signal handler signature
    _state["signal"] = signum
    if _state.get("defer", 0):  # inside deferred(): raised when the block ends
        _state["pending"] = signum
        return
    raise Interrupted(signal.Signals(signum).name)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A block that a signal must not cut in half (creating a temporary file and entering the code that removes
    it, starting a cluster that must then be stopped): under :func:`handle_signals`, a SIGINT/SIGTERM arriving
    inside is recorded and raised as :class:`Interrupted` when the outermost such block ends, whether it ends normally
    or by an exception (then the exception is the interrupt's ``__cause__``; a KeyboardInterrupt passes unchanged)."""
    depth = _state.get("defer", 0)
    _state["defer"] = depth + 1
    try:
        yield
    except BaseException as exc:  # the block failed: a held-back signal is still raised here, not by a later block
        _state["defer"] = depth
        pending = _state.pop("pending", 0) if depth == 0 else 0
        if pending and not isinstance(exc, KeyboardInterrupt):
            raise Interrupted(signal.Signals(pending).name) from exc
        raise
    _state["defer"] = depth
    pending = _state.pop("pending", 0) if depth == 0 else 0
    if pending:
        raise Interrupted(signal.Signals(pending).name)


@contextlib.contextmanager
def sigint_blocked() -> Iterator[None]:
    """A block during which this thread does not receive SIGINT (held pending, delivered when the block ends),
    for starting worker processes: they inherit the blocked SIGINT, so a Ctrl-C in the terminal, which reaches the
    whole process group, is left to this process (it stops its workers) instead of printing a KeyboardInterrupt
    traceback in each worker. No-op where signal masks do not exist (Windows) or outside the main thread."""
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


@contextlib.contextmanager
def handle_signals() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted` and are remembered.

    Outside the main thread (where Python cannot install handlers) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _state["signal"] = 0
    _state.pop("pending", None)
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for s in old:
            signal.signal(s, _handler)
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        _state["signal"] = 0  # handled within the block: a later check() outside it must not raise it again
        _state.pop("pending", None)


STOP_GRACE_S = 5.0  # how long a stopped worker may take to exit after SIGTERM before it is killed [s]


def stop_pool(ex: Any) -> None:
    """Stop a process pool now: cancel pending tasks AND end the worker processes that are computing
    (``shutdown(wait=False, cancel_futures=True)`` alone lets them finish their tasks, for minutes)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    manager = getattr(ex, "_executor_manager_thread", None)  # shutdown() forgets it and the result queue
    results = getattr(ex, "_result_queue", None)
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)
    writer = getattr(results, "_writer", None)
    if writer is not None and not any(p.is_alive() for p in procs):
        # a worker stopped while it sent its result left half a message in the result pipe: the manager thread
        # waits for the rest for ever, and so does this process's exit; with the workers gone this is the pipe's
        # last writer, so closing it ends that wait (EOF: the pool is marked broken and cleans up)
        writer.close()
    if manager is not None:  # let the pool's manager thread finish closing its pipes before this process exits:
        # else the exit's wake-up of that thread races with the close ("OSError: Bad file descriptor", CPython 3.11)
        manager.join(max(0.0, deadline - time.monotonic()) + 1.0)

"""A Dask ``LocalCluster`` in a session of its own, for ``aev-ocp study --dask-local N``.

A terminal's Ctrl-C goes to every process of its foreground process group. A LocalCluster started inside the
study's process puts its scheduler, nannies and workers in that group, and they are started from Dask's own
event-loop thread, out of reach of the study's signal handling: a Ctrl-C while they import NumPy and CasADi
printed their KeyboardInterrupt tracebacks and could leave a worker behind. So the study starts the cluster
through this module as a separate process in a new session (:class:`LocalClusterProcess`): only the study
sees the terminal's signals, and it stops the cluster itself.

The cluster process writes its scheduler's address as one JSON line on a pipe of its own, then serves until its stdin
closes (the study ended, whatever way, even killed) or it gets SIGTERM/SIGINT. A study that stops it writes
:data:`CLOSE_REQUEST` first: then it closes the cluster, and whatever of its process group is still alive after the
study's grace period is killed. A stdin that ends without the request means the study died, or stops the cluster
after an interrupt: nobody waits for a result, so the cluster process removes the workers' scratch folder and kills
its whole process group at once.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import selectors
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

#: How long the cluster process may take to start its workers before the study gives up [s]. Each worker
#: imports NumPy and CasADi (about 1-3 s on one core); the workers are capped per core (limits.check_local_workers).
CLUSTER_START_TIMEOUT_S = 180.0
#: After a normal end, how long the cluster may take to close its workers before they are killed [s].
CLOSE_GRACE_S = 10.0
#: After an interrupt or a failure, the same, short: the user is waiting for the prompt [s]. The study then does not
#: ask for a close: the cluster process ends its group at once (:func:`main`). A cluster that has not started yet is
#: killed at once.
INTERRUPT_GRACE_S = 1.0
#: The last characters of the cluster process's log shown when it fails to start.
LOG_TAIL_CHARS = 600
#: What the study writes on the cluster process's stdin before it closes it to end the cluster gracefully
#: (:meth:`LocalClusterProcess.stop`): a stdin that ends without it (the study killed or crashed, or stopping the
#: cluster after an interrupt) makes the cluster end its workers at once.
CLOSE_REQUEST = b"close\n"


class LocalClusterProcess:
    """A LocalCluster of ``n_workers`` single-threaded worker processes, run by ``python -m aev_ocp.study.cluster``
    in a session of its own. ``address`` is its scheduler's (``tcp://127.0.0.1:PORT``); :meth:`stop` ends it and
    every process it started. ``scratch`` is the workers' local directory (the caller owns and removes it);
    ``config`` is Dask configuration (dotted keys) the cluster process sets before it starts."""

    def __init__(self, n_workers: int, scratch: str, config: dict[str, Any]) -> None:
        self.log_path = Path(scratch) / "cluster.log"
        # the address comes back on a pipe of its own: the workers keep this process's stdout (a verbose solver's
        # output reaches the terminal, as from the process pool); a pipe nobody reads would block them at 64 KiB
        self._addr_r, addr_w = os.pipe()
        args = [sys.executable, "-m", "aev_ocp.study.cluster", "--workers", str(int(n_workers))]
        args += ["--scratch", scratch, "--config", json.dumps(config), "--address-fd", str(addr_w)]
        try:
            with open(self.log_path, "wb") as log:
                self.proc = subprocess.Popen(
                    args, stdin=subprocess.PIPE, stderr=log, pass_fds=(addr_w,), start_new_session=True
                )
        except BaseException:
            os.close(self._addr_r)
            raise
        finally:
            os.close(addr_w)
        self.address = ""

    def wait_address(self, timeout_s: float = CLUSTER_START_TIMEOUT_S, poll: Callable[[], None] | None = None) -> str:
        """Block until the cluster process writes its scheduler address (RuntimeError if it ends first or
        ``timeout_s`` [s] passes), calling ``poll`` (e.g. a time-limit check) every half second meanwhile.
        A KeyboardInterrupt or what ``poll`` raises propagates at once: the caller stops the process."""
        deadline = time.monotonic() + timeout_s
        line = b""
        with selectors.DefaultSelector() as sel:
            sel.register(self._addr_r, selectors.EVENT_READ)
            while not line.endswith(b"\n"):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise RuntimeError(f"the local Dask cluster did not start within {timeout_s:g} s{self._log_tail()}")
                if not sel.select(min(left, 0.5)):
                    if poll is not None:
                        poll()
                    continue
                chunk = os.read(self._addr_r, 4096)
                if not chunk:  # the process ended before it was ready
                    self.proc.wait()
                    raise RuntimeError(
                        f"the local Dask cluster could not start (exit code {self.proc.returncode}){self._log_tail()}"
                    )
                line += chunk
        try:
            self.address = str(json.loads(line.decode())["address"])
        except (ValueError, KeyError, TypeError):
            raise RuntimeError(f"the local Dask cluster answered {line[:80]!r}, not its address") from None
        return self.address

    def _log_tail(self) -> str:
        try:
            text = self.log_path.read_bytes()[-LOG_TAIL_CHARS:].decode("utf-8", "replace").strip()
        except OSError:
            return ""
        return f": {text.splitlines()[-1]}" if text else ""

    def stop(self, grace_s: float = CLOSE_GRACE_S, graceful: bool = True) -> None:
        """End the cluster: ``graceful``, ask it to close (:data:`CLOSE_REQUEST`, then its stdin closes), else close
        its stdin unasked (it kills its workers at once, as when the study dies: an interrupted study waits for no
        result); wait up to ``grace_s`` [s], then kill whatever of its process group is left (scheduler, nannies,
        workers, resource tracker). Safe to call twice."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            if graceful:
                try:
                    self.proc.stdin.write(CLOSE_REQUEST)  # a close the study asks for, not its death (see main)
                    self.proc.stdin.flush()
                except OSError:
                    pass
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        pid = self.proc.pid
        deadline = time.monotonic() + (grace_s if self.address else 0.0)
        # wait without reaping: while the leader is a zombie, its process-group id cannot be reused
        while self.proc.returncode is None and time.monotonic() < deadline:
            if os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None:
                break
            time.sleep(0.05)
        if self.proc.returncode is None:
            try:
                os.killpg(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            self.proc.wait()
        if self._addr_r >= 0:
            os.close(self._addr_r)
            self._addr_r = -1
        # the orphaned members of the group (reparented once the leader is reaped) die of the SIGKILL above;
        # wait a moment for them, so that the caller may remove the scratch folder they wrote into
        deadline = time.monotonic() + 1.0
        while _group_alive(pid) and time.monotonic() < deadline:
            time.sleep(0.02)


def _group_members(pgid: int) -> list[int] | None:
    """The live processes of group ``pgid`` (zombies, which hold nothing open, do not count); None where there is
    no /proc to list them."""
    proc = Path("/proc")
    if not proc.is_dir():
        return None
    members = []
    for p in proc.iterdir():
        if p.name.isdigit():
            try:
                stat = (p / "stat").read_text().rsplit(")", 1)[-1].split()
            except OSError:
                continue
            if int(stat[2]) == pgid and stat[0] not in ("Z", "X"):
                members.append(int(p.name))
    return members


def _group_alive(pgid: int) -> bool:
    """Whether a process of group ``pgid`` still runs (zombies do not count; where there is no /proc, any member
    counts)."""
    members = _group_members(pgid)
    if members is None:
        try:
            os.killpg(pgid, 0)
        except (ProcessLookupError, PermissionError):
            return False
        return True
    return bool(members)


def _kill_own_group(scratch: str) -> bool:
    """End this process's group at once: the cluster's workers and multiprocessing's resource tracker (the cluster
    process leads a session of its own), then this process. The others are stopped first (SIGSTOP: a stopped
    worker writes nothing more, and a nanny restarts no worker that has not died), the workers' ``scratch`` folder is
    removed, then SIGKILL goes to the whole group, this process included: this function does not return then.
    False (nothing done) where the group's members cannot be listed (no /proc)."""
    me, group = os.getpid(), os.getpgrp()
    members = _group_members(group)
    if members is None:
        return False
    for pid in members:
        if pid != me:
            try:
                os.kill(pid, signal.SIGSTOP)
            except ProcessLookupError:
                pass
    shutil.rmtree(scratch, ignore_errors=True)
    os.killpg(group, signal.SIGKILL)
    return True  # not reached


def main(argv: list[str] | None = None) -> int:
    """The cluster process (see the module docstring); not a user command."""
    ap = argparse.ArgumentParser(prog="python -m aev_ocp.study.cluster")
    ap.add_argument("--workers", type=int, required=True)
    ap.add_argument("--scratch", required=True)
    ap.add_argument("--config", default="{}")
    ap.add_argument("--address-fd", type=int, required=True)
    a = ap.parse_args(argv)

    def stop(signum: int, frame: Any) -> None:  # noqa: ARG001 - signal handler signature
        raise SystemExit(0)

    study = os.getppid()
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    import dask
    from dask.distributed import LocalCluster

    dask.config.set(json.loads(a.config))
    cluster = LocalCluster(
        n_workers=a.workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.CRITICAL,
        local_directory=a.scratch,
    )
    unasked = False  # stdin ended without CLOSE_REQUEST: the study died, or stops the cluster after an interrupt
    try:
        with os.fdopen(a.address_fd, "w") as addr:
            addr.write(json.dumps({"address": cluster.scheduler_address}) + "\n")
        tail = b""
        while chunk := sys.stdin.buffer.read(65536):  # until the study closes its end (or ends)
            tail = (tail + chunk)[-len(CLOSE_REQUEST) :]
        unasked = tail != CLOSE_REQUEST
    finally:
        logging.getLogger("distributed").setLevel(logging.CRITICAL)  # "stream closed" while closing is no news
        # unasked, nobody waits for a result: the workers end at once (a graceful close let a computing worker run on
        # for 4 s, until Dask's nanny killed it; measured); else (asked, or a SIGTERM/SIGINT) they close gracefully
        if not (unasked and _kill_own_group(a.scratch)):
            cluster.close(timeout=CLOSE_GRACE_S)
        if unasked or os.getppid() != study:  # the study may be gone: nobody else would remove the scratch folder
            shutil.rmtree(a.scratch, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

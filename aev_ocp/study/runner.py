"""Running a study: one task = one point under one controller; executors; the hash-keyed store.

Executors (same inputs -> same stored bytes, whichever runs them):

- ``"inprocess"``: a loop in this process;
- ``"pool"`` (default): :class:`concurrent.futures.ProcessPoolExecutor`, one worker per core;
- ``"dask"``: Dask distributed, a running scheduler (``scheduler="tcp://host:8786"``) or a
  ``LocalCluster`` of ``workers`` processes, run in a session of its own (:mod:`aev_ocp.study.cluster`).
  Dask is imported only here, only when asked for.

Each task's result is written atomically to ``<out>/points/<hash>.json`` as soon as it arrives
(only this process writes); a rerun loads what is there and computes only the missing tasks. A task
that fails (a simulation event is data, not a failure; an exception is recorded as status 'error')
does not stop the others. Ctrl-C cancels what is pending and leaves only complete files.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from ..errors import AevOcpError
from .. import interrupts
from ..progress import Progress, TimeLimitReached
from ..truncation import cumulative_profile
from ..results import to_jsonable, write_atomic
from .spec import Task

EXECUTORS = ("inprocess", "pool", "dask")


# ----------------------------------------------------------------------------- one task
def run_task(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one task specification (picklable dict from :func:`aev_ocp.study.spec.make_task`).

    Returns {key, controller, status, message, metrics: [per-vehicle §10 metrics], wall_s}; status is
    'ok', the kind of the event that ended the run, or 'error' (an exception; message holds it). A ring or SUMO
    point (``spec["kind"]``) runs through :func:`aev_ocp.study.traffic.run_point`."""
    if spec.get("kind") in ("ring", "sumo"):
        from .traffic import run_point

        return run_point(spec)
    t0 = time.perf_counter()
    c = spec["controller"]
    out: dict[str, Any] = {"key": spec["key"], "controller": c["label"]}
    try:
        result = _simulate(spec)
        metrics = result.metrics()
        for m, st in zip(metrics, result.solver_stats or []):  # estimation errors beside the closed-loop metrics
            for k, v in ((st or {}).get("estimation") or {}).items():
                m[f"est_{k}"] = v
        out.update(
            status=result.status, message="; ".join(str(e) for e in result.events + result.violations), metrics=metrics
        )
        # compact cumulative profiles, so the table can cut this point's runs at their common distance and time
        out["profiles"] = [cumulative_profile(result, i) for i in range(result.n_vehicles)] if result.t.size > 1 else []
        if spec.get("trajectories"):  # optional: the run's trajectories, loadable by aev_ocp.load
            from ..saved import save_output

            save_output(
                Path(spec["trajectories"]) / spec["key"],
                "simulate",
                {c["label"]: result},
                settings={"task": spec["key"], "file": spec["file"], "controller": c, "document": spec["document"]},
            )
    except Exception as exc:  # noqa: BLE001 - a failed point is recorded, the others go on
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" ({Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
        out.update(status="error", message=f"{type(exc).__name__}: {exc}{where}", metrics=[])
    out["wall_s"] = time.perf_counter() - t0
    return json.loads(json.dumps(to_jsonable(out)))  # exactly what the store holds


def run_tasks(specs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """:func:`run_task` on each spec in turn (one Dask task per chunk: fewer scheduler round trips)."""
    return [run_task(sp) for sp in specs]


def chunk_size(n_tasks: int, slots: int, per_slot: int = 8) -> int:
    """Tasks per chunk so that each worker slot gets about ``per_slot`` chunks (load balance vs overhead)."""
    return max(1, -(-n_tasks // (slots * per_slot)))


def _simulate(spec: dict[str, Any]) -> Any:
    """The SimulationResult of one task."""
    from .spec import Controller, controller_document, parse_scenario_quiet

    c = spec["controller"]
    ctrl = Controller(c["label"], c["kind"], c["name"], tuple(sorted(c["settings"].items())))
    doc = controller_document(spec["document"], ctrl, spec["file"])
    sc = parse_scenario_quiet(doc, spec["file"])
    from ..estimation.scenario import measurements_degraded, realism_kwargs
    from ..mpc.scenario import MPCConfig, closed_loop_from_scenario
    from ..mpc.settings import MPCSettings

    cfg = sc.extra.get("mpc") or MPCConfig(MPCSettings())
    if ctrl.kind == "law" and measurements_degraded(sc):  # the law sampled at the MPC's step on the same measurements
        from ..control import ClosedLoop

        return ClosedLoop(
            sc.leader,
            [sc.law(ctrl.name)] * sc.n_followers,
            sc.ev,
            rtol=sc.rtol,
            atol=sc.atol,
            law_dt=cfg.settings.dt,
            **realism_kwargs(sc),
        ).run(list(sc.gaps0), list(sc.speeds0), sc.t_end)
    if ctrl.kind == "law":
        return _simulator(sc, ctrl.name).run(list(sc.gaps0), list(sc.speeds0), sc.t_end)
    if ctrl.kind == "mpc":
        r = closed_loop_from_scenario(sc, cfg).run(list(sc.gaps0), list(sc.speeds0), sc.t_end)
        if spec.get("own_cost"):  # the study has an OCP-D: its bound check needs follower 1's own cost
            from ..mpc.run import own_cost

            f = cfg.formulation
            st = dict(r.solver_stats[0] or {}) if r.solver_stats else {}
            st[f.cost_key] = own_cost(r, 0, cfg.settings, f, sc.ev)
            r.solver_stats = [st, *r.solver_stats[1:]]
        return r
    return _ocpd(sc, cfg.settings, cfg.formulation)


_SIMULATORS: OrderedDict[Any, Any] = OrderedDict()  # per process: the last few built simulators
_SIMULATORS_MAX = 8


def _simulator(sc: Any, law: str) -> Any:
    """A :class:`~aev_ocp.simulate.PlatoonSimulator` with every follower on ``law`` (what
    ``simulate_platoon(sc.leader, [law] * n, **sc.simulate_kwargs())`` builds), reused across tasks that
    differ only in the initial state or horizon: building one costs tens of ms (CasADi functions, code
    generation, loading the compiled library) against ~20 ms for a Table 1 run."""
    from ..simulate import PlatoonSimulator, SimOptions

    laws = (sc.law(law),) * sc.n_followers
    opts = SimOptions(dt_out=sc.dt_out, rtol=sc.rtol, atol=sc.atol)
    key = (sc.leader, laws, sc.ev, opts)
    try:
        hash(key)
    except TypeError:
        return PlatoonSimulator(sc.leader, list(laws), sc.ev, opts)
    sim = _SIMULATORS.get(key)
    if sim is None:
        sim = _SIMULATORS[key] = PlatoonSimulator(sc.leader, list(laws), sc.ev, opts)
        while len(_SIMULATORS) > _SIMULATORS_MAX:
            _SIMULATORS.popitem(last=False)
    else:
        _SIMULATORS.move_to_end(key)
    return sim


def _ocpd(sc: Any, s: Any, f: Any) -> Any:
    """OCP-D (the MPC's formulation ``f`` over the whole scenario, on the MPC's grid, or the coarse grid when that
    is too large) with its optimal controls replayed through the exact plant: the solve-and-replay of
    :func:`aev_ocp.mpc.report.run_comparison` (:func:`aev_ocp.ocp.oracle.solve_and_replay`). solver_stats holds
    the optimum ('<cost_key>_optimum'), its grid step 'grid_dt' [model time] and 'coarse' (a coarse grid's optimum
    is a reference, never a bound)."""
    from ..ocp.oracle import solve_and_replay

    sr = solve_and_replay(sc, s.dt, f)
    if sr.replay is None:
        raise RuntimeError(f"OCP-D did not converge: {sr.result.status}")
    r = sr.replay
    r.solver_stats = [
        {f"{f.cost_key}_optimum": float(sr.result.objective), "grid_dt": sr.scenario.dt, "coarse": sr.coarse}
    ]
    return r


# ----------------------------------------------------------------------------- store
class Store:
    """Task results under ``<root>/points/<hash>.json`` (atomic writes). Each entry holds its task's key and
    the SHA-256 of its content (:data:`HASH_FIELD`); an entry that is unreadable, not a result, filed under
    another task's name or whose content does not match its hash counts as missing and is computed again."""

    HASH_FIELD = "content_sha256"
    FIELDS = ("key", "controller", "status", "message", "metrics")  # what a stored result must hold

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.dir = Path(root) / "points"
        self.damaged: list[str] = []  # keys whose stored entry was rejected by get()

    def path(self, key: str) -> Path:
        """File of the task with hash ``key``."""
        return self.dir / f"{key}.json"

    @classmethod
    def digest(cls, result: dict[str, Any]) -> str:
        """SHA-256 of a result's canonical JSON, without the hash field itself and the wall time (so that every
        executor stores the same bytes apart from ``wall_s``)."""
        body = {k: v for k, v in result.items() if k not in (cls.HASH_FIELD, "wall_s")}
        return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored result, or None if missing, unreadable or damaged (see the class docstring)."""
        f = self.path(key)
        try:
            if not f.is_file() or f.stat().st_size > MAX_ENTRY_BYTES:
                raise ValueError("not a regular file of a sane size")
            got = json.loads(f.read_text(encoding="utf-8"))
            if (
                not isinstance(got, dict)
                or got.get("key") != key
                or any(k not in got for k in self.FIELDS)
                or not isinstance(got["metrics"], list)
                or got.get(self.HASH_FIELD) != self.digest(got)
            ):
                raise ValueError("damaged entry")
        except FileNotFoundError:
            return None
        except (OSError, ValueError, RecursionError):
            if f.exists() or f.is_symlink() or (self.dir.exists() and not self.dir.is_dir()):
                self.damaged.append(key)
            return None
        return {k: v for k, v in got.items() if k != self.HASH_FIELD}

    def put(self, key: str, result: dict[str, Any]) -> None:
        """Store a result atomically, with its key and content hash (a damaged entry that is not a file, e.g. a
        folder or a FIFO under the entry's name, or a ``points`` that is not a folder, is replaced)."""
        entry = {**result, "key": key}
        entry[self.HASH_FIELD] = self.digest(entry)
        f = self.path(key)
        if (self.dir.exists() or self.dir.is_symlink()) and not self.dir.is_dir():
            # points/ is the store's own folder: a file, a FIFO or a dangling link in its place is damage (a link
            # to a folder, a store kept on another disk, is followed)
            self.dir.unlink()
        if f.is_dir() and not f.is_symlink():
            shutil.rmtree(f)  # a folder under an entry's name (os.replace cannot replace it; a FIFO or link it can)
        write_atomic(f, json.dumps(entry, sort_keys=True) + "\n")


MAX_ENTRY_BYTES = 50_000_000  # a stored task result is a few kB (metrics + profiles); larger is not one of ours


# ----------------------------------------------------------------------------- time limit
class TimeLimitStop(AevOcpError, RuntimeError):
    """The study's time limit passed: finished tasks are stored, the rest did not run."""


# ----------------------------------------------------------------------------- executors
def check_executor(executor: str, workers: int | None, scheduler: str | None) -> None:
    """ParameterError naming the argument unless ``executor`` is one of EXECUTORS, ``workers`` a worker count this
    machine allows (pool and a local Dask cluster) and ``scheduler`` given only to the Dask executor (checked
    before a study claims its folder)."""
    from ..limits import check_local_workers
    from ..params import ParameterError

    if not isinstance(executor, str) or executor not in EXECUTORS:
        raise ParameterError(f"executor {executor!r} is not allowed: must be one of {', '.join(EXECUTORS)}")
    check_local_workers(workers, "workers")
    if scheduler is not None and executor != "dask":
        raise ParameterError(f"scheduler {scheduler!r} is only for executor 'dask', not {executor!r}")
    if scheduler is not None and not isinstance(scheduler, str):
        raise ParameterError(f"scheduler {scheduler!r} is not allowed: must be an address such as tcp://host:8786")


def _unique(tasks: Iterable[Task]) -> dict[str, Task]:
    out: dict[str, Task] = {}
    for t in tasks:
        out.setdefault(t.key, t)
    return out


def execute(
    tasks: list[Task],
    store: Store,
    *,
    executor: str = "pool",
    workers: int | None = None,
    scheduler: str | None = None,
    name: str = "study",
    progress_stream: Any = None,
    on_result: Callable[[str, dict[str, Any]], None] | None = None,
    time_limit_s: float | None = None,
    every_s: float = 1.0,
    trajectories_dir: str | os.PathLike[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Run every task missing from ``store``; returns {hash: result} for all tasks.

    executor: 'inprocess', 'pool' (``workers`` processes, default one per core) or 'dask'
    (``scheduler`` address, else a LocalCluster of ``workers`` processes). Progress (tasks done, ETA)
    goes to ``progress_stream`` (default stderr) every ``every_s`` s. time_limit_s [s]: once passed,
    pending tasks are cancelled and :class:`TimeLimitStop` is raised; finished tasks are stored, so
    rerunning resumes. trajectories_dir: also save each task's trajectories into ``<dir>/<hash>/``
    (manifest.json + trajectories.npz; a stored task without them is run again); the Dask executor
    then needs a folder its workers share."""
    check_executor(executor, workers, scheduler)
    todo = _unique(tasks)
    results: dict[str, dict[str, Any]] = {}
    from ..saved import MANIFEST

    for key in list(todo):
        got = store.get(key)
        if got is not None and (
            trajectories_dir is None or got["status"] == "error" or (Path(trajectories_dir) / key / MANIFEST).is_file()
        ):
            results[key] = got
    missing = [t for k, t in todo.items() if k not in results]
    if store.damaged:
        import warnings

        warnings.warn(
            f"study {name}: {len(store.damaged)} stored result(s) in {store.dir} were damaged (not a "
            f"result, another task's, or content not matching its hash; first {store.damaged[0]}.json): "
            "computing them again",
            stacklevel=2,
        )
    prog = Progress(
        f"study {name}", len(todo), unit="tasks", time_limit_s=time_limit_s, every_s=every_s, stream=progress_stream
    )
    cached, failed = len(results), [0]
    # the first update is the ETA's origin: the ETA counts only the tasks computed in this run
    prog.update(cached, len(todo), force=True, note=f"({cached} stored, 0 failed)", check=False)

    def done(res: dict[str, Any]) -> None:
        store.put(res["key"], res)
        results[res["key"]] = res
        failed[0] += int(res["status"] == "error")
        if on_result is not None:
            on_result(res["key"], res)
        try:
            prog.update(len(results), len(todo), note=f"({cached} stored, {failed[0]} failed)")
        except TimeLimitReached:
            if len(results) < len(todo):  # the limit passing as the last task ends stops nothing
                raise TimeLimitStop(f"{len(results)} of {len(todo)} tasks stored") from None

    def poll() -> None:  # while the pool or cluster computes (or starts): the time limit holds between results too
        try:
            prog.check()
        except TimeLimitReached:
            raise TimeLimitStop(f"{len(results)} of {len(todo)} tasks stored") from None

    if not missing:
        return results
    specs = [
        t.spec if trajectories_dir is None else {**t.spec, "trajectories": str(Path(trajectories_dir).resolve())}
        for t in missing
    ]
    if executor == "inprocess":
        for sp in specs:
            done(run_task(sp))
    elif executor == "pool":
        _run_pool(specs, workers, done, poll)
    else:
        _run_dask(specs, workers, scheduler, done, poll)
    return results


#: How often a waiting executor checks the time limit [s].
POLL_S = 0.25


def _no_poll() -> None:
    pass


def _run_pool(
    specs: list[dict[str, Any]],
    workers: int | None,
    done: Callable[[dict[str, Any]], None],
    poll: Callable[[], None] = _no_poll,
) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from ..limits import check_local_workers

    n = check_local_workers(workers, "workers") or os.cpu_count() or 1
    _export_path()
    # each worker ends itself if this process dies without stopping it (SIGKILL, the OOM killer): it would
    # otherwise compute its task on, for minutes, for nobody
    ex = ProcessPoolExecutor(
        max_workers=n, mp_context=mp.get_context("spawn"), initializer=_end_with, initargs=(os.getpid(),)
    )
    try:
        # submit() starts the worker processes: a Ctrl-C while one is half started left a process the pool did not
        # know, and the exit then waited for it for ever; it is honoured once every worker can be stopped
        # and each worker starts with SIGINT blocked: a Ctrl-C in the terminal reaches the whole process group, and
        # a worker still importing printed a KeyboardInterrupt traceback; this process stops them (SIGTERM)
        with interrupts.deferred(), interrupts.sigint_blocked():
            pending = {ex.submit(run_task, sp) for sp in specs}
        while pending:
            finished, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
            if not finished:
                poll()
            for f in finished:
                try:
                    res = f.result()
                except Exception as exc:  # run_task records its own errors: this is the pool failing
                    raise RuntimeError(f"a worker process failed ({type(exc).__name__}: {exc})") from exc
                done(res)
    except BaseException:
        interrupts.stop_pool(ex)
        raise
    ex.shutdown(wait=True)


PARENT_CHECK_S = 1.0  # how often a pool worker checks that the study that started it still runs [s]


def _end_with(parent_pid: int) -> None:
    """Pool-worker initializer: end this worker once the study ``parent_pid`` that started it is gone. On Linux the
    kernel kills it (``prctl(PR_SET_PDEATHSIG, SIGKILL)``: it works while the worker sits in a long CasADi call
    that holds the GIL); elsewhere a daemon thread checks, every PARENT_CHECK_S, that the worker was not
    re-parented."""
    import threading

    if sys.platform.startswith("linux"):
        import ctypes

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1 (linux/prctl.h)
        except (OSError, AttributeError):
            pass  # no prctl: the thread below still watches
    if os.getppid() != parent_pid:  # the study died before the line above took effect
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_S)
        os._exit(1)

    threading.Thread(target=watch, name="aev-ocp-parent-watch", daemon=True).start()


def _export_path() -> None:
    """Make sure worker processes import this aev_ocp (a source checkout that is not installed)."""
    root = str(Path(__file__).resolve().parents[2])
    parts = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    if root not in parts:
        os.environ["PYTHONPATH"] = os.pathsep.join([root] + parts)


SCHEDULER_CONNECT_TIMEOUT_S = 20.0  # connecting to a Dask scheduler (Dask's own default is 30 s) [s]
SCHEDULER_HEARTBEAT_TIMEOUT_S = 60.0  # a connection silent this long is dropped (Dask's tcp timeout, default 30 s) [s]
CONNECT_ERROR_WAIT_S = 1.0  # how long past SCHEDULER_CONNECT_TIMEOUT_S the study waits for Dask's own error [s]


def _connect(client_type: Any, scheduler: str) -> Any:
    """A Dask client of ``scheduler``, or RuntimeError once SCHEDULER_CONNECT_TIMEOUT_S has passed: the connect
    runs in a daemon thread, so a peer that accepts and never completes the handshake cannot hang the study."""
    import threading

    box: dict[str, Any] = {}

    def go() -> None:
        try:
            box["client"] = client_type(scheduler, timeout=SCHEDULER_CONNECT_TIMEOUT_S)
        except BaseException as exc:  # noqa: BLE001 - reported below, in the caller's thread
            box["error"] = exc

    t = threading.Thread(target=go, name="aev-ocp-dask-connect", daemon=True)
    t.start()
    t.join(SCHEDULER_CONNECT_TIMEOUT_S + CONNECT_ERROR_WAIT_S)
    exc = box.get("error")
    if isinstance(exc, (ValueError, TypeError)):  # the address itself: bad input, not a scheduler that failed
        raise _bad_address(scheduler, exc)
    if t.is_alive() or exc is not None:
        how = (
            f"could not be reached ({type(exc).__name__}: {exc})"
            if exc is not None
            else f"did not answer within {SCHEDULER_CONNECT_TIMEOUT_S:g} s"
        )
        raise RuntimeError(f"the Dask scheduler {scheduler} {how}")
    return box["client"]


def _bad_address(scheduler: str, exc: Exception) -> Exception:
    from ..params import ParameterError

    return ParameterError(
        f"--scheduler {scheduler!r} is not a Dask scheduler address (e.g. tcp://10.0.0.5:8786): {exc}"
    )


def check_scheduler_address(scheduler: str) -> str:
    """``scheduler`` if Dask reads it as an address with a host and a port, else ParameterError naming --scheduler
    (checked before the study claims its folder; whether anything answers there is found out by connecting)."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(scheduler)
        if scheme in ("tcp", "tls"):
            parse_host_port(loc)
    except (ValueError, TypeError) as exc:
        raise _bad_address(scheduler, exc) from None
    return scheduler


def dask_missing_message() -> str:
    """What to do when Dask is not installed."""
    return (
        "Dask is not installed: the Dask executor (--dask-local N, --scheduler ADDRESS) needs "
        "pip install 'aev_ocp[dask]' (dask[distributed]); the default process pool needs nothing extra"
    )


def _run_dask(
    specs: list[dict[str, Any]],
    workers: int | None,
    scheduler: str | None,
    done: Callable[[dict[str, Any]], None],
    poll: Callable[[], None] = _no_poll,
) -> None:
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise RuntimeError(dask_missing_message()) from None
    import dask

    from ..limits import check_local_workers
    from .cluster import CLOSE_GRACE_S, INTERRUPT_GRACE_S, LocalClusterProcess

    n_local = check_local_workers(workers, "dask workers") or os.cpu_count() or 1
    cluster: LocalClusterProcess | None = None
    client = None
    # the workers' scratch space (Dask's default: <tmp>/dask-scratch-space, left behind) is ours, removed at the end
    scratch = None if scheduler else tempfile.mkdtemp(prefix="aev_ocp_dask_")
    # a scheduler that accepts and then stays silent must not hang the study (issue 28)
    timeouts = {
        "distributed.comm.timeouts.connect": f"{SCHEDULER_CONNECT_TIMEOUT_S}s",
        "distributed.comm.timeouts.tcp": f"{SCHEDULER_HEARTBEAT_TIMEOUT_S}s",
    }
    cfg = dask.config.set(timeouts)
    finished = False  # every result in: the cluster closes gracefully; else (interrupted, failed) it ends at once
    try:
        if scheduler:
            client = _connect(Client, scheduler)
        else:
            assert scratch is not None
            _export_path()
            # its own session: a terminal's Ctrl-C reaches this process only, which stops the cluster (cluster.py)
            with interrupts.deferred():
                cluster = LocalClusterProcess(n_local, scratch, {**timeouts, "temporary-directory": scratch})
            client = _connect(Client, cluster.wait_address(poll=poll))
        slots = max(1, sum(client.nthreads().values()))
        size = chunk_size(len(specs), slots)
        chunks = [specs[i : i + size] for i in range(0, len(specs), size)]
        futures = [
            client.submit(run_tasks, ch, key=f"aev-ocp-tasks-{ch[0]['key']}-{len(ch)}", pure=False) for ch in chunks
        ]
        try:
            for fut in _completed(as_completed(futures), poll):
                try:
                    batch = fut.result()
                except Exception as exc:  # run_task records its own errors: this is the cluster failing
                    raise RuntimeError(
                        f"a Dask worker could not run a study task ({type(exc).__name__}: {exc}); "
                        "do the workers have this aev_ocp installed?"
                    ) from exc
                for res in batch:
                    done(res)
        except BaseException:
            if cluster is None:  # a shared scheduler: withdraw this study's tasks (a local cluster just ends)
                client.cancel(futures)
            raise
        finished = True
    finally:
        quiet = logging.getLogger("distributed")  # closing after Ctrl-C: the heartbeats' "stream closed" are no news
        level = quiet.level
        quiet.setLevel(logging.CRITICAL)
        try:
            grace = CLOSE_GRACE_S if finished else INTERRUPT_GRACE_S
            with interrupts.deferred():  # a second Ctrl-C must not leave the cluster running
                if client is not None:
                    client.close(timeout=grace)
                if cluster is not None:
                    cluster.stop(grace, graceful=finished)  # ends the processes this study started, computing or not
        finally:
            quiet.setLevel(level)
            cfg.__exit__(None, None, None)
            if scratch is not None:
                shutil.rmtree(scratch, ignore_errors=True)


def _completed(ac: Any, poll: Callable[[], None]) -> Iterator[Any]:
    """The futures of Dask's ``as_completed`` ``ac`` as they finish, calling ``poll`` every POLL_S while none does."""
    while not ac.is_empty():
        batch = ac.next_batch(block=False)
        if not batch:
            poll()
            time.sleep(POLL_S)
        yield from batch

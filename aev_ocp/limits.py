"""How much memory a run needs, estimated before it starts.

One place that answers "will this fit?" for every kind of run, against one budget
(:func:`memory_limit_bytes`: ``$AEV_OCP_MAX_MEMORY_GB``, default 3 GB):

* platoon simulation (closed-form laws): followers × samples × bytes per sample
  (:func:`estimate_run_bytes`; the scenario layer thins ``dt_out`` where a large
  platoon is legitimate, :func:`aev_ocp.scenarios.thinned_dt_out`);
* MPC: horizon N × bytes per interval of the NLP (:data:`MPC_BYTES_PER_INTERVAL`);
* OCP (``aev-ocp ocp``): intervals N × bytes per interval of the transcribed NLP (this module's table).

Each ``check_*`` raises :class:`~aev_ocp.params.ParameterError` with one line that says how much, the
limit, and which key or argument to change; it returns the estimate [bytes] when the run fits.
"""

from __future__ import annotations

import errno
import math
import os
import stat
from typing import Callable, Sequence

from .errors import AevOcpError
from .params import ParameterError, SimOptions

# Peak memory of a simulation per (sample x follower): 255 B measured with the cascade on the Table 1
# platoon (200 and 1000 followers, 7001 samples, peak RSS after run + metrics); 300 B leaves a margin.
BYTES_PER_SAMPLE = 300
DEFAULT_MEMORY_LIMIT_GB = 3.0  # default budget of one run's arrays; $AEV_OCP_MAX_MEMORY_GB overrides
# Memory of building and solving the horizon-N NLP [bytes per interval]: 0.88-1.29 MB measured by
# benchmarks/bench_limits.py (peak RSS of MPCController construction + one solve, ipopt and rti, N = 40 ... 1600).
MPC_BYTES_PER_INTERVAL = 1_000_000

#: Peak resident memory of building and solving one OCP, per interval of the grid [bytes]: the slope of
#: peak RSS between two N (ms: prop31 200/800, current-profile 200/800, eco-trip 100/300, oracle
#: 350/1400; collocation: eco-trip 100/400, current-profile and oracle at 800/700, total/N), CasADi 3.x
#: with IPOPT/MUMPS on the project's 2-core machine, rounded up by ~25 %. Multiple shooting of the
#: eco-trip is heavy because its interval map is an RK4 of the full vehicle + pack model (3.3 MB).
#: The oracle (OCP-D) keeps its NLP as one mapped interval Function (no SX expansion): measured on UDDS at
#: N = 300/1200, 66/93 MB (ms) and 90/187 MB (collocation), i.e. 30 kB and 107 kB per interval.
OCP_BYTES_PER_INTERVAL: dict[tuple[str, str], float] = {
    ("prop31", "ms"): 0.65e6,
    ("prop31", "collocation"): 0.65e6,
    ("current-profile", "ms"): 0.8e6,
    ("current-profile", "collocation"): 0.25e6,
    ("eco-trip", "ms"): 4.2e6,
    ("eco-trip", "collocation"): 0.75e6,
    ("oracle", "ms"): 0.04e6,
    ("oracle", "collocation"): 0.135e6,
}
#: Fixed part of an OCP run (CasADi, IPOPT, the OCV spline, plots) [bytes], measured at small N.
OCP_BASE_BYTES = 0.15e9


def memory_limit_bytes() -> float:
    """The memory budget of one run [bytes]: $AEV_OCP_MAX_MEMORY_GB, default DEFAULT_MEMORY_LIMIT_GB; ParameterError
    naming the variable when it is set to anything but a finite positive number."""
    raw = os.environ.get("AEV_OCP_MAX_MEMORY_GB", "").strip()
    if not raw:
        return DEFAULT_MEMORY_LIMIT_GB * 1e9
    try:
        gb = float(raw)
    except ValueError:
        gb = math.nan
    if not (math.isfinite(gb) and gb > 0):  # a setting that says something else is refused, never replaced by 3 GB
        raise ParameterError(
            f"$AEV_OCP_MAX_MEMORY_GB = {raw!r:.40} is not allowed: must be a finite number of GB > 0 "
            f"(unset it for the default {DEFAULT_MEMORY_LIMIT_GB:g} GB)"
        )
    return gb * 1e9


def n_samples(t_end: float, dt_out: float) -> float:
    """Samples per follower of a run [-]: one per dt_out and at least one per integrator chunk (inf when the
    ratio overflows, e.g. t_end = 1e308: such a run is refused by the size checks, never rounded)."""
    ratio = t_end / min(dt_out, SimOptions().chunk)
    return math.ceil(ratio) + 1.0 if math.isfinite(ratio) else math.inf


def estimate_run_bytes(n_followers: int, t_end: float, dt_out: float) -> float:
    """Estimated peak memory of simulating ``n_followers`` over [0, t_end] sampled every dt_out [bytes]."""
    return BYTES_PER_SAMPLE * float(n_followers) * n_samples(t_end, dt_out)


def _gb(x: float) -> str:
    return f"{x / 1e9:.3g} GB"


def estimate_ocp_bytes(problem: str, N: int, method: str = "ms") -> float:
    """Estimated peak memory of solving OCP ``problem`` on N intervals with ``method`` [bytes]."""
    try:
        per = OCP_BYTES_PER_INTERVAL[(problem, method)]
    except KeyError:
        raise ParameterError(
            f"ocp: no memory model for problem {problem!r} with method {method!r}; known: "
            f"{sorted({p for p, _ in OCP_BYTES_PER_INTERVAL})} x ['ms', 'collocation']"
        ) from None
    return OCP_BASE_BYTES + per * float(N)


def max_ocp_intervals(problem: str, method: str = "ms") -> int:
    """The largest N that fits the budget for ``problem`` and ``method``."""
    per = OCP_BYTES_PER_INTERVAL[(problem, method)]
    return max(0, int((memory_limit_bytes() - OCP_BASE_BYTES) // per))


def check_ocp_size(problem: str, N: int, method: str = "ms", key: str = "--N") -> float:
    """Raise ParameterError if OCP ``problem`` with N intervals needs more than the budget; ``key`` names
    what sets N (e.g. '--N', or 'simulation.t_end (N = t_end/dt)' for the oracle). Returns the estimate."""
    if isinstance(N, bool) or not isinstance(N, int) or N < 1:
        raise ParameterError(f"ocp {problem}: {key} gives N = {N!r}: must be an integer >= 1")
    need, limit = estimate_ocp_bytes(problem, N, method), memory_limit_bytes()
    if need <= limit:
        return need
    raise ParameterError(
        f"ocp {problem}: N = {N} intervals ({method}) need about {_gb(need)}, more than the limit of "
        f"{_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): lower {key} so that N <= "
        f"{max_ocp_intervals(problem, method)}"
    )


def oracle_intervals(t_end: float, dt: float) -> int:
    """N of the oracle OCP over [0, t_end] with interval dt (model time), refusing absurd values early."""
    if not (math.isfinite(t_end) and math.isfinite(dt) and t_end > 0 and dt > 0):
        raise ParameterError(f"ocp oracle: t_end = {t_end!r} and dt = {dt!r} must be finite and > 0")
    n = t_end / dt
    return int(min(round(n), 2**62))


def check_simulation_size(n_followers: int, t_end: float, dt_out: float) -> float:
    """For :meth:`aev_ocp.simulate.PlatoonSimulator.run` (Python API): raise ParameterError naming the
    arguments if the sampled output of a platoon simulation would exceed the budget; returns the estimate."""
    need, limit = estimate_run_bytes(n_followers, t_end, dt_out), memory_limit_bytes()
    if need <= limit:
        return need
    per_vehicle = need / max(n_followers, 1)
    raise ParameterError(
        f"simulate: {n_followers} followers x {n_samples(t_end, dt_out):.3g} samples (t_end = {t_end:g}, "
        f"dt_out = {dt_out:g}) need about {_gb(need)}, more than the limit of {_gb(limit)} "
        f"($AEV_OCP_MAX_MEMORY_GB): raise dt_out, lower t_end, or simulate at most "
        f"{int(limit // per_vehicle)} followers"
    )


def check_suite_size(t_ends: Sequence[float], n_runs_per_case: int, dt_out: float, kept: bool, n_workers: int) -> float:
    """For the safety suite (:func:`aev_ocp.safety.run.run_suite`): raise ParameterError if its runs (one vehicle
    over each case's t_end [model] sampled every dt_out [model], ``n_runs_per_case`` controllers x actuators per case)
    exceed the memory budget: all of them when their trajectories are ``kept`` (workers = 1), else the
    ``n_workers`` longest at once; returns the estimate [bytes]."""
    per_case = sorted((estimate_run_bytes(1, t, dt_out) for t in t_ends), reverse=True)
    need = n_runs_per_case * (math.fsum(per_case) if kept else math.fsum(per_case[: max(n_workers, 1)]))
    limit = memory_limit_bytes()
    if need > limit:
        raise ParameterError(
            f"safety suite: {len(per_case)} cases x {n_runs_per_case} runs (controllers x actuators) need about "
            f"{_gb(need)}, more than the limit of {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): run fewer or shorter "
            "cases, fewer controllers or actuators, or more --workers (which keep no trajectories)"
        )
    return need


# Peak memory of a ring run per (sample x vehicle): 249-251 B measured (tracemalloc peak of run_ring, i.e. the
# integration and the fleet metrics; 22 and 100 vehicles, 3001-12001 samples, dt_out_s 0.05-0.1 s); 300 B, as a platoon.
RING_BYTES_PER_SAMPLE = 300


def ring_samples(t_end_s: float, dt_out_s: float) -> float:
    """Samples of a ring run [-]: one per dt_out_s over [0, t_end_s] plus the first (inf if the ratio overflows)."""
    ratio = t_end_s / dt_out_s
    return math.ceil(ratio - 1e-9) + 1.0 if math.isfinite(ratio) else math.inf


def check_ring_size(
    n_vehicles: int, t_end_s: float, dt_out_s: float, keys: tuple[str, str, str] | None = None
) -> float:
    """Raise ParameterError if a ring run of ``n_vehicles`` over [0, t_end_s] sampled every dt_out_s [s] needs more
    than the budget; ``keys``: how the user sets the vehicles, the horizon and the sampling (named in the message;
    default the Python arguments). Returns the estimate [bytes]."""
    need, limit = RING_BYTES_PER_SAMPLE * float(n_vehicles) * ring_samples(t_end_s, dt_out_s), memory_limit_bytes()
    if need <= limit:
        return need
    kv, kt, kd = keys or ("n_vehicles", "t_end_s", "dt_out_s")
    per_vehicle = need / max(n_vehicles, 1)
    raise ParameterError(
        f"ring: {n_vehicles} vehicles x {ring_samples(t_end_s, dt_out_s):.6g} samples ({kt} = {t_end_s:g} s, "
        f"{kd} = {dt_out_s:g} s) need about {_gb(need)}, more than the limit of {_gb(limit)} "
        f"($AEV_OCP_MAX_MEMORY_GB): raise {kd}, lower {kt}, or use at most {int(limit // per_vehicle)} vehicles ({kv})"
    )


#: Most integration cuts of one ring run (noise changes and controller instants): each restarts the compiled
#: integrator from Python (~0.1 ms of overhead, a thread for Ctrl-C) and holds a float of the grid; 10^6 cuts are
#: minutes of overhead alone. The shipped rings need 1 200 (600 s, noise held 0.5 s) to 6 000 (an MPC every 0.1 s).
MAX_RING_CUTS = 1_000_000


def check_ring_cuts(t_end_s: float, intervals: dict[str, float]) -> int:
    """Raise ParameterError if a ring run over [0, t_end_s] cut every interval of ``intervals`` ({key naming it:
    interval [s]}, e.g. {"ring.noise_dt_s": 0.5, "the controllers' dt": 0.1}) needs more than :data:`MAX_RING_CUTS`
    integration cuts; checked before the cuts are built. Returns the number of cuts."""
    total = 0.0
    for key, dt in intervals.items():
        if not (math.isfinite(dt) and dt > 0):
            raise ParameterError(f"ring: {key} = {dt!r} is not allowed: must be a finite number of seconds > 0")
        total += t_end_s / dt
    if not total <= MAX_RING_CUTS:
        what = ", ".join(f"{k} = {v:g} s" for k, v in intervals.items())
        raise ParameterError(
            f"ring: {what} over t_end_s = {t_end_s:g} s cut the integration {total:.4g} times, more than the "
            f"{MAX_RING_CUTS} a run may have: raise {' or '.join(intervals)} (each at least "
            f"{t_end_s * len(intervals) / MAX_RING_CUTS:.3g} s) or lower t_end_s"
        )
    return int(total)


def check_mpc_size(N: int, n_mpc_vehicles: int = 1, key: str = "MPCSettings.N") -> float:
    """For :class:`aev_ocp.control.ClosedLoop` (Python API) and every [mpc] table: raise ParameterError if the
    MPC NLPs (one per MPC vehicle, horizon N) exceed the budget; returns the estimate [bytes]. ``key`` is the
    horizon's name as the user gave it ("mpc.N" for a scenario, --set or study; the field for the API)."""
    n = max(n_mpc_vehicles, 1)
    need, limit = float(MPC_BYTES_PER_INTERVAL) * N * n, memory_limit_bytes()
    if need <= limit:
        return need
    raise ParameterError(
        f"{key} = {N} is not allowed: {n} MPC vehicle{'s' if n > 1 else ''} with this horizon need{'' if n > 1 else 's'} about "
        f"{_gb(need)}, more than the limit of {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): lower {key} to at most "
        f"{int(limit // (MPC_BYTES_PER_INTERVAL * n))}"
    )


# ----------------------------------------------------------------------------- SUMO
#: Peak memory of a SUMO run per recorded (vehicle x step) [bytes]: the toolkit's record of every vehicle (time,
#: speed, odometer, gap, leader's speed, lane, battery state, current: Python lists) and its SimulationResult, plus
#: SUMO's own state: measured on the shipped sumo_ring (22 cars, 0.1 s steps) between 60 s and 240 s runs, 320 B
#: per record traced by tracemalloc (Python) and 1.39 kB per record of peak RSS (Python, SUMO and the tracing).
SUMO_BYTES_PER_RECORD = 1_500
#: Memory of one repetition of a shipped ring's route in SUMO and in its route file [bytes per lap] (two routes
#: of two edges each, ~12 characters and one pointer per edge): a ring's routes repeat it for the whole run.
SUMO_BYTES_PER_LAP = 100
#: Longest SUMO run [s]: one day, the longest horizon of SUMO's traffic-demand studies (a city's day).
MAX_SUMO_T_END_S = 86_400.0


def check_sumo_size(
    n_vehicles: float, t_end_s: float, step_s: float, record_every: int = 1, laps: float = 0.0, keys: str = ""
) -> float:
    """Raise ParameterError if a SUMO run of ``n_vehicles`` vehicles at once over [0, t_end_s] with steps of step_s
    [s], recording every ``record_every``-th step (and a ring route of ``laps`` laps), needs more than the budget;
    ``keys``: what the user sets these with (named in the message). Returns the estimate [bytes]."""
    steps = t_end_s / step_s
    records = float(n_vehicles) * (math.ceil(steps / max(record_every, 1)) + 1.0) if math.isfinite(steps) else math.inf
    need, limit = SUMO_BYTES_PER_RECORD * records + SUMO_BYTES_PER_LAP * laps, memory_limit_bytes()
    if need <= limit:
        return need
    raise ParameterError(
        f"sumo: {n_vehicles:.6g} vehicles x {steps:.6g} steps of {step_s:g} s (t_end_s = {t_end_s:g} s) need about "
        f"{_gb(need)}, more than the limit of {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): lower {keys or 't_end_s'}"
    )


# ----------------------------------------------------------------------------- studies
#: Peak memory of reading and validating one study point [bytes]: 19.8 kB measured (tracemalloc peak of
#: read_study on a 30 x 30 random grid of the Table 1 scenario, 900 points: 17.8 MB), rounded up.
STUDY_BYTES_PER_POINT = 25_000
#: Most tasks (points x controllers) one study may hold: validation costs ~1-6 ms per point (measured on the
#: 30 x 30 grid above, 5.6 s for 900 points under tracemalloc), so 10^5 tasks already take minutes to check
#: and hours to run; split a larger sweep into several studies.
MAX_STUDY_TASKS = 100_000


def check_study_size(n_points: int, n_controllers: int, where: str) -> float:
    """Raise ParameterError naming ``where`` (the study file and the axes that set the size) if a study of
    ``n_points`` points x ``n_controllers`` controllers exceeds :data:`MAX_STUDY_TASKS` or the memory budget,
    before any point is built; returns the estimated memory [bytes]."""
    n_tasks = n_points * max(n_controllers, 1)
    need, limit = STUDY_BYTES_PER_POINT * float(n_points), memory_limit_bytes()
    if n_tasks > MAX_STUDY_TASKS:
        raise ParameterError(
            f"{where}: {n_points:.4g} points x {n_controllers} controllers = {n_tasks:.4g} tasks, more "
            f"than the {MAX_STUDY_TASKS} a study may hold: use fewer values or a smaller random n, "
            "or split the sweep into several studies"
        )
    if need > limit:
        raise ParameterError(
            f"{where}: {n_points:.4g} points need about {_gb(need)} to validate, more than the limit "
            f"of {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): use fewer values or a smaller random n"
        )
    return need


#: Local worker processes per core at most (``--workers``, ``--dask-local``): each worker imports CasADi and
#: NumPy (~150 MB resident) and opens a few pipes; past a few per core they only contend for the cores and
#: for file descriptors (10 000 requested ones ended in "Too many open files").
MAX_WORKERS_PER_CORE = 4


def max_local_workers() -> int:
    """The most local worker processes a study may start: :data:`MAX_WORKERS_PER_CORE` x the core count."""
    return MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)


def check_local_workers(n: int | None, key: str = "--workers") -> int | None:
    """``n`` if it is None or 1 ... :func:`max_local_workers`, else ParameterError naming ``key``."""
    if n is None:
        return None
    cap = max_local_workers()
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= cap:
        raise ParameterError(
            f"{key} {n!r}: must be an integer from 1 to {cap} ({MAX_WORKERS_PER_CORE} per core on "
            f"this machine's {os.cpu_count() or 1} cores)"
        )
    return n


# ----------------------------------------------------------------------------- reading a file of a bounded size
class FileRefused(AevOcpError):
    """A file :func:`read_regular_file` did not read; the message says why in a few words, for the caller to put
    after its own name of the file ("cannot read the scenario file (it is a folder)")."""


def read_regular_file(path: str | os.PathLike[str], max_bytes: int) -> bytes:
    """The bytes of ``path`` if it is a regular file (a symbolic link to one is fine) of at most ``max_bytes``
    [bytes], checked BEFORE reading: a FIFO would hang the read, /dev/zero never ends. :class:`FileRefused`
    otherwise, also for a file that cannot be opened or read (its message is the system's reason)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # opening a FIFO must not wait for a writer
    except OSError as exc:
        raise FileRefused(_os_reason(exc)) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FileRefused(
                "it is a folder"
                if stat.S_ISDIR(st.st_mode)
                else "it is not a regular file but a FIFO, device or socket"
            )
        if st.st_size > max_bytes:
            raise FileRefused(f"it is {st.st_size} bytes, more than the {max_bytes} it may have")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise FileRefused(_os_reason(exc)) from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise FileRefused(f"it grew past {max_bytes} bytes while read")
    return data


#: Largest input file (study, cell, OCV table, grid file) that is read [bytes]: such files are a few kB of TOML,
#: JSON or CSV; anything larger is not one of them, and is refused before it is read.
MAX_INPUT_FILE_BYTES = 16 * 2**20


def read_input_file(
    path: str | os.PathLike[str],
    what: str,
    error: Callable[[str], Exception],
    max_bytes: int = MAX_INPUT_FILE_BYTES,
    label: str | None = None,
) -> bytes:
    """:func:`read_regular_file` for a text input file of the user's (TOML, JSON, CSV): ``raise error(message)``
    instead of :class:`FileRefused`, one line naming ``label`` (default the path) and ``what`` (e.g. 'study
    file'); a leading UTF-8 byte-order mark (what some editors on Windows write) is dropped."""
    try:
        return strip_bom(read_regular_file(path, max_bytes))
    except FileRefused as exc:
        raise error(f"{path if label is None else label}: cannot read the {what} ({exc})") from None


UTF8_BOM = b"\xef\xbb\xbf"


def strip_bom(data: bytes) -> bytes:
    """``data`` without a leading UTF-8 byte-order mark: TOML and JSON parsers refuse one ("invalid statement at
    line 1, column 1"), though the text after it is fine."""
    return data[len(UTF8_BOM) :] if data.startswith(UTF8_BOM) else data


def _os_reason(exc: OSError) -> str:
    """The system's reason for an OSError, in words ("a loop of symbolic links" for ELOOP)."""
    if exc.errno == errno.ELOOP:
        return "a loop of symbolic links"
    return exc.strerror or str(exc)

"""Benchmark of the test suite (issue 40): the README's test command's wall and CPU time.

Runs ``python -m pytest -q -n WORKERS --dist MODE`` in a child process from the checkout's root and measures:

* wall time [s] and CPU time [s] (user + system of pytest, its xdist workers and everything they started,
  ``resource.getrusage(RUSAGE_CHILDREN)`` around the child);
* the machine's load (1-minute load average before and after: the machine may be shared, and on a loaded machine
  the wall time says little, the CPU time more);
* the counts pytest reports (passed, skipped, failed, ...) and the compilations (``aev_ocp: compiling <stem>``
  lines, shown by pytest only for failing tests, so usually none: the compile cache's own test counts them);
* the ten slowest phases and each file's seconds (setup, call and teardown of its tests, ``--durations=0``);
* the environment variables that change the time (:data:`TIMING_ENV`): the BLAS thread counts (tests/conftest.py
  sets 1 unless given) and ``PYTHONDONTWRITEBYTECODE``, which ``--bytecode`` sets for the run.

``--bytecode on`` (the default) runs the suite as Python runs it unless told otherwise: ``PYTHONDONTWRITEBYTECODE``
is removed from the suite's environment, so the package's modules are compiled to bytecode once and pytest's
rewritten test modules are cached (``__pycache__``), after an untimed ``pytest --collect-only`` that fills both (the
way the compile cache is warm). ``--bytecode off`` sets ``PYTHONDONTWRITEBYTECODE=1`` (some machines set it for every
process, this one among them) and first removes the checkout's ``__pycache__`` folders (package, tests), as in a fresh
clone on such a machine: each worker rewrites every test module again (collecting takes about 10 s of one core
instead of 4) and each process a test starts compiles the modules it imports; measured in turns, three runs each,
the suite's wall time did not move beyond its run-to-run spread (README). ``--bytecode
inherit`` keeps this process's environment. Repeatable like ``--dist``; every (dist, bytecode) pair runs ``--repeat``
times, the pairs in turns (A B A B: the machine's speed drifts, each pair meets the same drift), the last pair being
the quoted one.

``--dist MODE`` (repeatable) runs the suite once per mode in this process, in the order given, the first being the
baseline of the ratios: ``python benchmarks/bench_suite.py --dist load --dist loadfile``. ``--repeat K`` runs each
mode K times: the machine's speed moves by 10-20 % from one run to the next (five runs of one commit on the quiet
machine took 155-182 s), so the JSON keeps every run, each mode's median wall and CPU time (``medians``) and the
last mode's run of median wall time (``quoted``: the run README quotes). ``--cache DIR``: the compile cache the
suite uses (``$AEV_OCP_CACHE``; default: the user's, warm after one run). Writes ``benchmarks/bench_suite.json``
(atomic) and prints a table. Run it with nothing else heavy on the machine. ``--record`` also writes the quoted
run's seconds per file to ``tests/data/file_seconds.json``: the order the suite's files are handed to the workers
in when pytest's cache has no run of its own (tests/conftest.py: heaviest first).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from aev_ocp.results import write_json

OUT = Path(__file__).with_name("bench_suite.json")
ROOT = Path(__file__).resolve().parents[1]
FILE_SECONDS = ROOT / "tests" / "data" / "file_seconds.json"
_COUNTS = re.compile(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed|deselected|warnings?)\b")
_DURATION = re.compile(r"^\s*(\d+\.\d+)s (setup|call|teardown)\s+(\S+)", re.M)
_COMPILING = re.compile(r"aev_ocp: compiling (\S+) with ")
#: README's quote of this benchmark is checked against its JSON by this test, left out of the measured runs
QUOTE_TEST = "tests/test_docs_site.py::test_the_suite_timing_the_readme_quotes_is_the_benchmarks"
#: environment variables recorded with each run: they change its time, not its results
TIMING_ENV = ("PYTHONDONTWRITEBYTECODE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def children_cpu_s() -> float:
    """User + system CPU [s] of every child process reaped so far (and their reaped children)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: --bytecode: the suite's PYTHONDONTWRITEBYTECODE (None: removed, Python's default; "1": set; absent: inherited)
BYTECODE = {"on": None, "off": "1"}


def suite_env(cache: Path | None, bytecode: str) -> dict[str, str]:
    """The suite's environment: this one with the checkout first on the path, the compile cache and ``bytecode``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    if cache is not None:
        env["AEV_OCP_CACHE"] = str(cache)
    if bytecode in BYTECODE:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        if BYTECODE[bytecode] is not None:
            env["PYTHONDONTWRITEBYTECODE"] = BYTECODE[bytecode]
    return env


def warm_bytecode(env: dict[str, str], python: str = sys.executable) -> None:
    """An untimed collection: compiles the package's modules and caches pytest's rewritten test modules (where
    ``env`` lets Python write bytecode)."""
    subprocess.run([python, "-m", "pytest", "-q", "--collect-only"], cwd=ROOT, env=env, capture_output=True)


def distributions(python: str) -> int:
    """How many distributions (installed packages) the interpreter ``python`` sees: the README's test environment
    (a fresh venv of ``.[test]``) has about 60, a development venv (``.[test,dev,docs]``) about 135."""
    code = "import importlib.metadata as m; print(len({d.metadata['Name'] for d in m.distributions()}))"
    out = subprocess.run([python, "-c", code], capture_output=True, text=True)
    return int(out.stdout.strip() or -1)


def machine_speed_s(repeats: int = 5) -> float:
    """CPU seconds [s] of a fixed workload (a pure-Python loop and NumPy element-wise functions, no BLAS threads;
    median of ``repeats``), taken before each run, so the JSON shows whether one core's speed moved between runs.
    On this machine it did not follow the suite's swings (0.20-0.29 s while the suite took 123-176 s): what moves
    the suite's time is not a core's speed alone."""
    x = np.linspace(0.0, 1.0, 1_000_000)
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        acc = 0
        for k in range(2_000_000):
            acc += k % 7
        for _ in range(10):
            x = np.sin(x) + np.exp(-x)
        times.append(time.process_time() - t0)
    return float(np.median(times))


def clear_bytecode() -> int:
    """Remove the checkout's bytecode caches (``__pycache__`` under the package and the tests); how many."""
    found = [d for top in ("aev_ocp", "tests") for d in (ROOT / top).rglob("__pycache__") if d.is_dir()]
    for d in found:
        shutil.rmtree(d, ignore_errors=True)
    return len(found)


def run(
    mode: str, workers: str, cache: Path | None, extra: list[str], bytecode: str = "on", python: str = sys.executable
) -> dict[str, Any]:
    """One run of the suite with ``--dist mode`` and ``--bytecode bytecode`` by the interpreter ``python``; its
    measurements."""
    env = suite_env(cache, bytecode)
    cmd = [
        python,
        "-m",
        "pytest",
        "-q",
        "-n",
        workers,
        "--dist",
        mode,
        "--durations=0",
        "--durations-min=0",
        # the test that holds README's quote to this benchmark's JSON cannot run inside the run that writes it
        "--deselect",
        QUOTE_TEST,
        *extra,
    ]
    speed = machine_speed_s()
    load0 = os.getloadavg()[0]
    cpu0, t0 = children_cpu_s(), time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, children_cpu_s() - cpu0
    tail = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    phases = sorted(((float(x), ph, t) for x, ph, t in _DURATION.findall(proc.stdout)), reverse=True)
    per_file: dict[str, float] = {}
    for x, _ph, t in phases:
        per_file[t.split("::", 1)[0]] = per_file.get(t.split("::", 1)[0], 0.0) + x
    counts = {k.rstrip("s") if k.startswith(("error", "warning")) else k: int(n) for n, k in _COUNTS.findall(tail)}
    return {
        "command": " ".join(["pytest", *cmd[3:]]),
        "dist": mode,
        "bytecode": bytecode,
        "interpreter": {"path": python, "distributions": distributions(python)},
        "returncode": proc.returncode,
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "load_1min_before": round(load0, 2),
        "machine_speed_s": round(speed, 4),
        "load_1min_after": round(os.getloadavg()[0], 2),
        "environment": {k: env.get(k) for k in TIMING_ENV},
        "counts": counts,
        "compilations": _COMPILING.findall(proc.stdout + proc.stderr),
        "slowest": [{"seconds": x, "phase": ph, "test": t} for x, ph, t in phases[:10]],
        "file_seconds": {f: round(x, 2) for f, x in sorted(per_file.items(), key=lambda kv: -kv[1])},
        "summary": tail,
        "failures": [ln for ln in proc.stdout.splitlines() if ln.startswith(("FAILED ", "ERROR "))],
    }


def median_run(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The run of median wall time among ``runs`` (of one mode; the lower middle of an even count): the run a
    document quotes, so one fast or slow run (the machine's speed moves by 10-20 % between runs) is not the number
    a reader sees."""
    ordered = sorted(runs, key=lambda r: r["wall_s"])
    return ordered[(len(ordered) - 1) // 2]


def summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Median wall and CPU [s] of one mode's runs, with every run's, for the JSON."""
    walls, cpus = [r["wall_s"] for r in runs], [r["cpu_s"] for r in runs]
    return {
        "dist": runs[0]["dist"],
        "bytecode": runs[0]["bytecode"],
        "repeats": len(runs),
        "wall_s_median": float(np.median(walls)),
        "cpu_s_median": float(np.median(cpus)),
        "wall_s_all": walls,
        "cpu_s_all": cpus,
        "passed_all": all(r["returncode"] == 0 for r in runs),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dist", action="append", help="xdist mode(s), the first is the baseline (default: loadfile)")
    ap.add_argument(
        "--bytecode",
        action="append",
        choices=["on", "off", "inherit"],
        help="on: Python's default, bytecode cached (the default); off: PYTHONDONTWRITEBYTECODE=1; inherit: as here",
    )
    ap.add_argument("-n", "--workers", default="auto", help="pytest-xdist workers (default: auto, one per core)")
    ap.add_argument("--cache", type=Path, default=None, help="compile cache folder ($AEV_OCP_CACHE)")
    ap.add_argument(
        "--python",
        default=sys.executable,
        help="the interpreter whose pytest runs the suite (default: this one), e.g. a fresh venv's as README's test "
        "command makes it: python3 -m venv /tmp/v && /tmp/v/bin/pip install '.[test]'; --python /tmp/v/bin/python",
    )
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--repeat", type=int, default=1, help="runs per mode (the medians and the median run are kept)")
    ap.add_argument(
        "--record", action="store_true", help=f"write the quoted (median) run's seconds per file to {FILE_SECONDS}"
    )
    ap.add_argument("pytest_args", nargs="*", help="more pytest arguments (after --), e.g. -m 'not slow'")
    a = ap.parse_args(argv)
    if a.repeat < 1:
        ap.error(f"--repeat = {a.repeat} is not allowed: must be >= 1")
    pairs = list(dict.fromkeys((m, b) for b in a.bytecode or ["on"] for m in a.dist or ["loadfile"]))
    runs = []
    cached = None  # the checkout's bytecode caches: None unknown, True filled (an 'on' run), False cleared ('off')
    # in turns (A B A B ...), not A A B B: the machine's speed drifts over minutes, and each configuration should
    # meet the same drift
    for _ in range(a.repeat):
        for m, b in pairs:
            if b == "on" and cached is not True:
                warm_bytecode(suite_env(a.cache, b), a.python)
            elif b == "off" and cached is not False:
                clear_bytecode()
            cached = {"on": True, "off": False}.get(b)  # inherit: whatever the environment lets Python write
            runs.append(run(m, a.workers, a.cache, a.pytest_args, b, a.python))
    by_mode = [[r for r in runs if (r["dist"], r["bytecode"]) == pair] for pair in pairs]
    medians = [summary(rs) for rs in by_mode]
    base = medians[0]
    print(
        f"{'dist':10} {'bytecode':8} {'wall [s]':>9} {'CPU [s]':>9} {'wall/base':>9} {'CPU/base':>9} {'load':>11}  result"
    )
    for r in runs:
        print(
            f"{r['dist']:10} {r['bytecode']:8} {r['wall_s']:9.1f} {r['cpu_s']:9.1f} {r['wall_s'] / base['wall_s_median']:9.2f} "
            f"{r['cpu_s'] / base['cpu_s_median']:9.2f} {r['load_1min_before']:5.2f}/{r['load_1min_after']:5.2f}  "
            f"{r['summary']}"
        )
    for m in medians:
        print(
            f"{m['dist']:10} {m['bytecode']:8} {m['wall_s_median']:9.1f} {m['cpu_s_median']:9.1f}  "
            f"median of {m['repeats']} run(s)"
        )
    quoted = median_run(by_mode[-1])
    uname = os.uname()
    write_json(
        a.out,
        {
            "machine": {"cpus": os.cpu_count(), "system": f"{uname.sysname} {uname.release} {uname.machine}"},
            "python": sys.version.split()[0],
            "runs": runs,
            "medians": medians,
            "quoted": quoted,
        },
    )
    print(f"wrote {a.out}")
    if a.record and quoted["returncode"] == 0:
        write_json(FILE_SECONDS, quoted["file_seconds"], provenance=False)
        print(f"wrote {FILE_SECONDS}")
    return max(r["returncode"] for r in runs)


if __name__ == "__main__":
    sys.exit(main())

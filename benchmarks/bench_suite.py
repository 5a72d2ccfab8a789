"""Benchmark of the test suite (issue 40): the README's test command's wall and CPU time.

Runs ``python -m pytest -q -n WORKERS --dist MODE`` in a child process from the checkout's root and measures:

* wall time [s] and CPU time [s] (user + system of pytest, its xdist workers and everything they started,
  ``resource.getrusage(RUSAGE_CHILDREN)`` around the child);
* the machine's load (1-minute load average before and after: the machine may be shared, and on a loaded machine
  the wall time says little, the CPU time more);
* the counts pytest reports (passed, skipped, failed, ...) and the compilations (``aev_ocp: compiling <stem>``
  lines, shown by pytest only for failing tests, so usually none: the compile cache's own test counts them);
* the ten slowest phases and each file's seconds (setup, call and teardown of its tests, ``--durations=0``);
* the environment variables that change the time (:data:`TIMING_ENV`): ``PYTHONDONTWRITEBYTECODE`` set makes every
  process compile the package's modules and pytest rewrite every test module again (about 4 s of CPU per worker to
  collect, more in each process a test starts); the BLAS thread counts (tests/conftest.py sets 1 unless given).

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


def run(mode: str, workers: str, cache: Path | None, extra: list[str]) -> dict[str, Any]:
    """One run of the suite with ``--dist mode``; its measurements."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    if cache is not None:
        env["AEV_OCP_CACHE"] = str(cache)
    cmd = [
        sys.executable,
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
        "returncode": proc.returncode,
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "load_1min_before": round(load0, 2),
        "load_1min_after": round(os.getloadavg()[0], 2),
        "environment": {k: os.environ.get(k) for k in TIMING_ENV},
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
    ap.add_argument("-n", "--workers", default="auto", help="pytest-xdist workers (default: auto, one per core)")
    ap.add_argument("--cache", type=Path, default=None, help="compile cache folder ($AEV_OCP_CACHE)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--repeat", type=int, default=1, help="runs per mode (the medians and the median run are kept)")
    ap.add_argument(
        "--record", action="store_true", help=f"write the quoted (median) run's seconds per file to {FILE_SECONDS}"
    )
    ap.add_argument("pytest_args", nargs="*", help="more pytest arguments (after --), e.g. -m 'not slow'")
    a = ap.parse_args(argv)
    if a.repeat < 1:
        ap.error(f"--repeat = {a.repeat} is not allowed: must be >= 1")
    modes = a.dist or ["loadfile"]
    runs = [run(m, a.workers, a.cache, a.pytest_args) for m in modes for _ in range(a.repeat)]
    by_mode = [[r for r in runs if r["dist"] == m] for m in dict.fromkeys(modes)]
    medians = [summary(rs) for rs in by_mode]
    base = medians[0]
    print(f"{'dist':10} {'wall [s]':>9} {'CPU [s]':>9} {'wall/base':>9} {'CPU/base':>9} {'load':>11}  result")
    for r in runs:
        print(
            f"{r['dist']:10} {r['wall_s']:9.1f} {r['cpu_s']:9.1f} {r['wall_s'] / base['wall_s_median']:9.2f} "
            f"{r['cpu_s'] / base['cpu_s_median']:9.2f} {r['load_1min_before']:5.2f}/{r['load_1min_after']:5.2f}  "
            f"{r['summary']}"
        )
    for m in medians:
        print(f"{m['dist']:10} {m['wall_s_median']:9.1f} {m['cpu_s_median']:9.1f}  median of {m['repeats']} run(s)")
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

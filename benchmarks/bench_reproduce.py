"""Benchmark of ``aev-ocp reproduce`` (issue 40): CPU and wall time, compilations, output size.

Runs ``python -m aev_ocp.cli reproduce`` in a child process with an EMPTY compile cache (a fresh machine: every
library it needs is compiled once) into a temporary folder, and measures:

* wall time [s] and CPU time [s] (user + system of the child and its children, ``resource.getrusage``);
* the machine's load (1-minute load average before and after: the machine may be shared);
* compilations per library (the "aev_ocp: compiling <stem>" lines on stderr: one per library built);
* the output's size [MB] and its largest files.

``--baseline DIR_OR_JSON`` adds a column with another run's numbers (a JSON this script wrote) and their ratio.
Writes ``benchmarks/bench_reproduce.json`` (atomic) and prints a table. Run it with nothing else heavy on the
machine: ``python benchmarks/bench_reproduce.py [--quick] [--keep OUT]``.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from aev_ocp.results import write_json

OUT = Path(__file__).with_name("bench_reproduce.json")
ROOT = Path(__file__).resolve().parents[1]
_COMPILING = re.compile(r"^aev_ocp: compiling (\S+) with ", re.M)


def folder_size(path: Path) -> tuple[int, list[tuple[str, int]]]:
    """(total bytes, the five largest files as (relative path, bytes)) of a folder."""
    files = [(p.relative_to(path).as_posix(), p.stat().st_size) for p in path.rglob("*") if p.is_file()]
    return sum(s for _, s in files), sorted(files, key=lambda x: -x[1])[:5]


def run(
    quick: bool, keep: Path | None, profile: Path | None = None, full: bool = False, cache: Path | None = None
) -> dict[str, Any]:
    """One reproduce run in a child process with an empty compile cache (``cache``: that folder, e.g. one a previous
    run filled: the warm case); its measurements. ``profile``: profile each section into that folder
    (benchmarks/profile_reproduce.py: cProfile, CPU per section, compiled sources)."""
    with tempfile.TemporaryDirectory(prefix="aev_bench_repro_") as tmp:
        out = keep if keep is not None else Path(tmp) / "results"
        if keep is not None and keep.exists():
            shutil.rmtree(keep)
        cache_dir = cache if cache is not None else Path(tmp) / "cache"
        cache_state = "warm" if cache_dir.is_dir() and any(cache_dir.rglob("*.so")) else "empty"
        env = {**os.environ, "AEV_OCP_CACHE": str(cache_dir), "PYTHONPATH": str(ROOT)}
        head = [sys.executable, "-m", "aev_ocp.cli", "reproduce"]
        if profile is not None:
            head = [sys.executable, str(ROOT / "benchmarks" / "profile_reproduce.py"), str(profile.resolve())]
        args = ["--out", str(out)] + (["--quick"] if quick else []) + (["--full"] if full else [])
        cmd = head + args
        load0 = os.getloadavg()[0]
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        load1 = os.getloadavg()[0]
        if proc.returncode != 0:
            raise SystemExit(f"reproduce failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
        total, largest = folder_size(out)
        last = [ln for ln in proc.stderr.splitlines() if ln.startswith("[")][-1:]
        return {
            "quick": quick,
            "full": full,
            "compile_cache": cache_state,
            "command": " ".join(["aev-ocp reproduce", *args]),
            "wall_s": wall,
            "cpu_s": (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime),
            "load_1min_before": load0,
            "load_1min_after": load1,
            "cpu_count": os.cpu_count(),
            "compilations": dict(collections.Counter(_COMPILING.findall(proc.stderr))),
            "output_MB": total / 1e6,
            "largest_files_MB": {k: v / 1e6 for k, v in largest},
            "last_progress_line": last[0] if last else "",
        }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="reproduce --quick (a smoke run, not the reproduction)")
    ap.add_argument("--cache", type=Path, default=None, help="compile cache folder (default: a new, empty one)")
    ap.add_argument("--full", action="store_true", help="reproduce --full (the extended studies at full size)")
    ap.add_argument("--keep", type=Path, default=None, help="write the reproduction here (default: a temp folder)")
    ap.add_argument("--baseline", type=Path, default=None, help="a JSON this script wrote (another version's run)")
    ap.add_argument("--profile", type=Path, default=None, help="profile each section into this folder (slower)")
    a = ap.parse_args(argv)
    res = run(a.quick, a.keep, a.profile, a.full, a.cache)
    base = json.loads(a.baseline.read_text()) if a.baseline else None
    if base is not None and "run" in base:  # a JSON this script wrote: its measurements are under "run"
        base = base["run"]
    rows = [
        ("wall [s]", "wall_s"),
        ("CPU [s]", "cpu_s"),
        ("output [MB]", "output_MB"),
        ("load (1 min) before", "load_1min_before"),
        ("load (1 min) after", "load_1min_after"),
    ]
    head = f"{'quantity':24s} {'this run':>12s}" + (f" {'baseline':>12s} {'ratio':>8s}" if base else "")
    print(head)
    for label, key in rows:
        line = f"{label:24s} {res[key]:12.1f}"
        if base:
            line += f" {base[key]:12.1f} {res[key] / base[key]:8.2f}"
        print(line)
    print(f"{'compilations':24s} {sum(res['compilations'].values()):12d}  {res['compilations']}")
    print(res["last_progress_line"])
    write_json(OUT, {"run": res, "baseline": base}, provenance=True)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

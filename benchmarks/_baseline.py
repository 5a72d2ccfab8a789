"""What the scaling benchmarks (bench_ring.py, bench_platoon_scaling.py) share: the machine's load beside every
timing, a hash of a run's trajectories (equal hashes: the same numbers to the bit), and a baseline measured by the
same script in a child process whose ``PYTHONPATH`` is another checkout of the toolkit (``--baseline DIR``, e.g. a
``git worktree`` of main): the code under test replaces the old code in this process, so the old one runs beside it.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from typing import Any

import numpy as np


def load_1min() -> float:
    """The 1-minute load average (on a shared machine the wall time is the CPU time the scheduler gave)."""
    return float(os.getloadavg()[0])


def trajectory_hash(*arrays: Any) -> str:
    """The first 16 hex digits of the SHA-256 of the arrays' bytes (C order)."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a, float)).tobytes())
    return h.hexdigest()[:16]


def run_baseline(script: str, checkout: str, args: list[str]) -> dict[str, Any]:
    """One measurement by ``script --child ARGS`` with the toolkit of ``checkout``: the JSON row it prints last."""
    env = {**os.environ, "PYTHONPATH": os.path.abspath(checkout)}
    proc = subprocess.run(
        [sys.executable, script, "--child", *args], env=env, capture_output=True, text=True, check=False
    )
    if proc.returncode != 0:
        raise RuntimeError(f"baseline run failed ({checkout}): {proc.stderr.strip().splitlines()[-1:]}")
    return dict(json.loads(proc.stdout.strip().splitlines()[-1]))

"""Memory of the MPC's horizon-N NLP and of platoon simulations: calibrates the size limits of issue 11
(aev_ocp.limits.MPC_BYTES_PER_INTERVAL, aev_ocp.limits.BYTES_PER_SAMPLE).

Each measurement runs in a fresh process and reports its peak RSS (ru_maxrss) above the baseline after
imports. Prints a table and writes results/bench_limits.json.

    python benchmarks/bench_limits.py [--quick]
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

MPC_CHILD = """
import resource, sys, numpy as np
from aev_ocp.mpc.controller import MPCController
from aev_ocp.mpc.settings import MPCSettings
N, solver = int(sys.argv[1]), sys.argv[2]
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
c = MPCController(MPCSettings(N=N, solver=solver, max_iter=3))
z0 = np.array([0.5, 1.7, 0.0, 0.0, 0.8])
c.solve(z0, np.full(N, 1.7), np.full(N, 1.7))
print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) * 1024)
"""

SIM_CHILD = """
import resource, sys
from aev_ocp.scenarios import load_scenario
n, dt_out = int(sys.argv[1]), float(sys.argv[2])
s = load_scenario("table1")
s = s.replace(laws=(s.law("proposed"),) * n, gaps0=(3.5,) * n, speeds0=(1.87,) * n, compare=("proposed",),
              dt_out=dt_out)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
r = s.run()["proposed"]
r.metrics()
print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) * 1024 / (n * r.t.size))
"""


def child(code: str, *args: str) -> float:
    out = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    quick = "--quick" in sys.argv
    rows = []
    for solver in ("ipopt", "rti"):
        for N in (40, 400) if quick else (40, 400, 1600):
            b = child(MPC_CHILD, str(N), solver)
            rows.append({"what": f"MPC {solver}", "size": N, "bytes": b, "bytes_per_unit": b / N})
    for n in (50,) if quick else (200, 1000):
        per = child(SIM_CHILD, str(n), "0.01")
        rows.append({"what": "simulate table1", "size": n, "bytes": per * n * 7001, "bytes_per_unit": per})
    print(f"{'what':18s} {'size':>6s} {'peak MB':>9s} {'B per unit':>11s}")
    for r in rows:
        print(f"{r['what']:18s} {r['size']:6d} {r['bytes'] / 1e6:9.1f} {r['bytes_per_unit']:11.0f}")
    out = ROOT / "results" / "bench_limits.json"
    sys.path.insert(0, str(ROOT))
    from aev_ocp.results import write_json

    write_json(
        out, {"rows": rows, "units": {"MPC": "bytes per horizon interval", "simulate": "bytes per sample x follower"}}
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

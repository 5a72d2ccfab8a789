"""The closed-loop plant's CVODES method: time per 0.1 s interval and accuracy of its Adams–Moulton method with
functional iteration (aev_ocp.plant.NONSTIFF, the plant's default) against CVODES's BDF with Newton iteration (its
fallback, and the plant's method before), on the same plant, inputs and tolerances (rtol = atol = 1e-10).

Each case integrates K intervals of 0.1 s one after the other, as a closed loop does (held commands that change every
interval); the error is the largest |x − x_ref| over the K interval ends against a BDF reference at rtol = atol =
1e-13. Medians of ``--repeat`` runs; the ratio is BDF / Adams in the same process. Prints a table and writes
results/bench_plant.json (atomically).

    python benchmarks/bench_plant.py [--repeat 5] [--intervals 300]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from _baseline import load_1min
from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import PaperLeader
from aev_ocp.params import EVParams
from aev_ocp.plant import NONSTIFF, BufferedCall, Plant
from aev_ocp.results import write_json

ROOT = Path(__file__).resolve().parents[1]
DT_S = 0.1  # the closed loop's sample interval [s]


def cases() -> list[tuple[str, Plant]]:
    ev = EVParams()
    limited = dataclasses.replace(ev, limits=dataclasses.replace(ev.limits, enabled=True))
    lead = PaperLeader()
    return [
        ("1 commanded (MPC loop)", Plant(lead, [None], ev)),
        ("1 commanded, limits on", Plant(lead, [None], limited)),
        ("OVFL + proposed + commanded", Plant(lead, [OVFL(), Proposed(), None], ev)),
        ("5 OVFL, 10 samples/interval", Plant(lead, [OVFL()] * 5, ev, samples=10)),
    ]


def integrate(plant: Plant, opts: dict[str, Any], K: int) -> tuple[float, np.ndarray]:
    """(seconds, interval-end states (K, nx)) of K consecutive intervals of DT_S with the integrator ``opts``."""
    F = BufferedCall(ca.integrator("bench_plant", "cvodes", plant._dae, 0.0, plant._grid.tolist(), opts))
    ix, ip, jx, _ = plant._io
    n = plant.n
    x = plant.initial_state([2.0] * n, [1.6] * n, 0.8)
    dt = DT_S / plant.ev.units.time_s
    ends = np.empty((K, plant.nx))
    t0 = time.perf_counter()
    for k in range(K):
        F.args[ix][:] = x
        F.args[ip][0], F.args[ip][1] = k * dt, dt
        F.args[ip][2:] = 0.3 * np.sin(0.05 * k)  # a held command that changes every interval
        if not F():
            raise RuntimeError(f"CVODES failed at interval {k}")
        x = F.res[jx].reshape(plant.nx, -1, order="F")[:, -1].copy()
        ends[k] = x
    return time.perf_counter() - t0, ends


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--intervals", type=int, default=300)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_plant.json"))
    a = ap.parse_args(argv)
    rows = []
    print(f"load before: {load_1min():.2f}")
    print(f"{'case':32s} {'BDF ms/int':>11s} {'Adams ms/int':>13s} {'ratio':>6s} {'BDF err':>9s} {'Adams err':>10s}")
    for name, plant in cases():
        bdf_opts = plant._stiff_opts
        adams_opts = {**bdf_opts, **NONSTIFF}
        ref_opts = {**bdf_opts, "abstol": 1e-13, "reltol": 1e-13}
        _, ref = integrate(plant, ref_opts, a.intervals)
        t_bdf, t_adams = [], []
        for _ in range(a.repeat):  # interleaved: the machine's load falls on both alike
            tb, xb = integrate(plant, bdf_opts, a.intervals)
            ta, xa = integrate(plant, adams_opts, a.intervals)
            t_bdf.append(tb)
            t_adams.append(ta)
        mb, ma = statistics.median(t_bdf), statistics.median(t_adams)
        row = {
            "case": name,
            "intervals": a.intervals,
            "bdf_ms_per_interval": 1e3 * mb / a.intervals,
            "adams_ms_per_interval": 1e3 * ma / a.intervals,
            "ratio_bdf_over_adams": mb / ma,
            "bdf_max_error": float(np.max(np.abs(xb - ref))),
            "adams_max_error": float(np.max(np.abs(xa - ref))),
        }
        rows.append(row)
        print(
            f"{name:32s} {row['bdf_ms_per_interval']:11.3f} {row['adams_ms_per_interval']:13.3f} "
            f"{row['ratio_bdf_over_adams']:6.2f} {row['bdf_max_error']:9.1e} {row['adams_max_error']:10.1e}"
        )
    out = {
        "machine": {"cpus": os.cpu_count(), "system": f"{platform.system()} {platform.machine()}"},
        "python": platform.python_version(),
        "casadi": ca.__version__,
        "load_1min_after": load_1min(),
        "repeat": a.repeat,
        "rows": rows,
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_json(a.out, out)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark of :mod:`aev_ocp.study` against the targets of GitHub issue 9 (2 cores).

1. A 200-point closed-form study (Table 1 platoon, proposed law, initial gap × initial speed: the
   laws' C code is the same at every point, so this measures the executors, not the compiler), run
   by a process pool of 1 and of 2 workers and by a Dask LocalCluster of 2 workers (start-up
   included). Targets: pool(2) ≥ 1.7× pool(1), Dask(2) ≥ 1.5× pool(1).
2. Per-point overhead: the in-process study's wall time (validation excluded) minus the same
   simulations called directly (one PlatoonSimulator, run + metrics per point), per point. Target ≤ 50 ms.
3. A 1000-point κ × α grid of the Table 1 platoon (40 × 25, proposed and OVFL, t ∈ [0, 70]) on 2
   workers with an empty compile cache (the laws' coefficients are compiled into the simulator's C
   code, so every new (κ, α) costs one gcc run). Target < 60 s. The same grid again into an empty
   store with the compile cache warm shows the cost without gcc. Also: where ω's saving of the
   proposed law against OVFL changes sign, follower by follower.
4. Resuming that finished study (nothing recomputed). Target < 5 s.

Writes ``benchmarks/bench_study.json`` (atomic) and prints a table. The machine is shared: timings
are noisy. Run: ``python benchmarks/bench_study.py [--quick]`` (quick: 40 points, a 100-point grid).
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from aev_ocp.results import write_json
from aev_ocp.study import load_table, parse_study, run_study

OUT = Path(__file__).with_name("bench_study.json")


def _doc(axes: list[dict[str, Any]], laws: list[str], overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    return {
        "name": "bench",
        "scenarios": ["table1"],
        "reference": laws[-1],
        "overrides": overrides or {},
        "axes": axes,
        "controllers": {"laws": laws},
    }


def _timed(study: Any, out: Path, **kw: Any) -> tuple[float, Any]:
    t0 = time.perf_counter()
    res = run_study(study, out, report=False, progress_stream=io.StringIO(), **kw)
    return time.perf_counter() - t0, res


def closed_form(n_gap: int, n_speed: int, tmp: Path) -> dict[str, Any]:
    """Part 1 and 2."""
    gaps = np.round(np.linspace(0.25, 1.2, n_gap), 6).tolist()
    speeds = np.round(np.linspace(0.9, 1.2, n_speed), 6).tolist()
    study = parse_study(
        _doc(
            [{"key": "platoon.gap0_first", "values": gaps}, {"key": "platoon.speed0_factor", "values": speeds}],
            ["proposed"],
            {"simulation.dt_out": 0.05},
        ),
        "bench_closed_form.toml",
    )
    n = len(study.points)
    # warm the compile cache once (the same law everywhere), untimed
    run_study(
        parse_study(
            _doc([{"key": "platoon.gap0_first", "values": [0.3]}], ["proposed"], {"simulation.dt_out": 0.05}),
            "warm.toml",
        ),
        tmp / "warm",
        executor="inprocess",
        report=False,
        progress_stream=io.StringIO(),
    )
    out: dict[str, Any] = {"points": n}
    out["inprocess_s"], res = _timed(study, tmp / "inproc", executor="inprocess")
    out["task_wall_sum_s"] = float(sum(r["wall_s"] for r in _task_results(tmp / "inproc")))
    # the same work called directly: parse + simulate + metrics per point
    from aev_ocp.scenarios import parse_scenario
    from aev_ocp.simulate import PlatoonSimulator, SimOptions

    scs = [parse_scenario(p.document, p.file) for p in study.points]  # parsed beforehand, untimed
    sim = PlatoonSimulator(
        scs[0].leader,
        [scs[0].law("proposed")] * scs[0].n_followers,
        scs[0].ev,
        SimOptions(dt_out=scs[0].dt_out, rtol=scs[0].rtol, atol=scs[0].atol),
    )
    t0 = time.perf_counter()  # the best a hand-written loop can do: one simulator, run per initial state
    for sc in scs:
        sim.run(list(sc.gaps0), list(sc.speeds0), sc.t_end).metrics()
    out["direct_s"] = time.perf_counter() - t0
    out["overhead_ms_per_point"] = 1000 * (out["inprocess_s"] - out["direct_s"]) / n
    out["pool1_s"], _ = _timed(study, tmp / "pool1", executor="pool", workers=1)
    out["pool2_s"], _ = _timed(study, tmp / "pool2", executor="pool", workers=2)
    out["speedup_pool2"] = out["pool1_s"] / out["pool2_s"]
    try:
        import dask.distributed  # noqa: F401

        out["dask2_s"], _ = _timed(study, tmp / "dask2", executor="dask", workers=2)
        out["speedup_dask2"] = out["pool1_s"] / out["dask2_s"]
        out["dask_cluster_start_s"] = _dask_startup(2)
        out["speedup_dask2_without_start"] = out["pool1_s"] / (out["dask2_s"] - out["dask_cluster_start_s"])
    except ImportError:
        out["dask2_s"] = out["speedup_dask2"] = None
    same = [load_table(tmp / d) for d in ("inproc", "pool1", "pool2")]
    strip = [[{k: v for k, v in r.items() if k != "wall_s"} for r in t] for t in same]
    out["tables_identical"] = strip[0] == strip[1] == strip[2]
    return out


def _dask_startup(n: int) -> float:
    """Seconds to start a LocalCluster of n workers, connect a client and close both."""
    from dask.distributed import Client, LocalCluster

    t0 = time.perf_counter()
    with (
        LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40) as cl,
        Client(cl) as c,
    ):
        c.run(lambda: 0)  # every worker is up
    return time.perf_counter() - t0


def _task_results(folder: Path) -> list[dict[str, Any]]:
    import json

    return [json.loads(p.read_text()) for p in (folder / "points").glob("*.json")]


def kappa_alpha(n_kappa: int, n_alpha: int, tmp: Path) -> dict[str, Any]:
    """Part 3 and 4."""
    kappas = np.round(np.linspace(0.0, 0.5, n_kappa), 6).tolist()
    alphas = np.round(np.linspace(1.0, 3.0, n_alpha), 6).tolist()
    study = parse_study(
        _doc(
            [{"key": "carfollowing.kappa", "values": kappas}, {"key": "carfollowing.alpha", "values": alphas}],
            ["proposed", "ovfl"],
            {"simulation.dt_out": 0.05},
        ),
        "bench_kappa_alpha.toml",
    )
    cache = tmp / "cache"
    os.environ["AEV_OCP_CACHE"] = str(cache)  # empty: every law is compiled (workers inherit it)
    out: dict[str, Any] = {"points": len(study.points), "tasks_unique": len({t.key for t in study.tasks()})}
    out["run_s"], res = _timed(study, tmp / "ka", executor="pool", workers=2)
    out["failed"] = res.n_failed
    out["resume_s"], _ = _timed(study, tmp / "ka", executor="pool", workers=2)
    # the same study again into an empty store with the compile cache now warm: the cost without gcc
    out["run_warm_cache_s"], _ = _timed(study, tmp / "ka_warm", executor="pool", workers=2)
    walls = [r["wall_s"] for r in _task_results(tmp / "ka")]
    out["task_wall_median_s"] = float(np.median(walls))
    out["sign_changes"] = _sign_changes(res.rows, kappas, alphas)
    return out


def _sign_changes(rows: list[dict[str, Any]], kappas: list[float], alphas: list[float]) -> dict[str, Any]:
    """Per follower: the α values at which ω(proposed) − ω(OVFL) changes sign along κ, and where."""
    out: dict[str, Any] = {}
    by = {
        (r["carfollowing.kappa"], r["carfollowing.alpha"], r["vehicle"]): r
        for r in rows
        if r["controller"] == "proposed"
    }
    for veh in sorted({r["vehicle"] for r in rows}):
        found = []
        for a in alphas:
            seq = [(k, by[(k, a, veh)]) for k in kappas if (k, a, veh) in by]
            seq = [
                (k, r["omega_model_change_pct"], r["comparable"])
                for k, r in seq
                if r["omega_model_change_pct"] is not None and abs(r["omega_model_change_pct"]) > 1e-9
            ]
            for (k0, c0, ok0), (k1, c1, ok1) in zip(seq, seq[1:]):
                if c0 * c1 < 0:
                    found.append(
                        {
                            "alpha": a,
                            "kappa_from": k0,
                            "kappa_to": k1,
                            "change_from_pct": c0,
                            "change_to_pct": c1,
                            "comparable": bool(ok0 and ok1),
                        }
                    )
        out[f"follower_{veh}"] = found
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="40 closed-form points, a 10 x 10 κ × α grid")
    ap.add_argument("--out", type=Path, default=OUT, help="JSON output path")
    ap.add_argument("--closed-form-only", action="store_true", help="parts 1 and 2 only (skip the κ × α grid)")
    args = ap.parse_args()
    root = str(Path(__file__).resolve().parents[1])
    os.environ["PYTHONPATH"] = os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    )
    with tempfile.TemporaryDirectory(prefix="bench_study_") as d:
        tmp = Path(d)
        cf = closed_form(8 if args.quick else 20, 5 if args.quick else 10, tmp)
        print(
            f"closed-form study, {cf['points']} points: 1 worker {cf['pool1_s']:.2f} s, 2 workers {cf['pool2_s']:.2f} s "
            f"({cf['speedup_pool2']:.2f}x), Dask 2 {cf['dask2_s'] or float('nan'):.2f} s "
            f"({cf['speedup_dask2'] or float('nan'):.2f}x), in-process {cf['inprocess_s']:.2f} s",
            file=sys.stderr,
        )
        if args.closed_form_only:
            print(
                f"pool(2) vs pool(1) {cf['speedup_pool2']:.2f}x, Dask(2) vs pool(1) {cf['speedup_dask2'] or float('nan'):.2f}x "
                f"({cf.get('speedup_dask2_without_start') or float('nan'):.2f}x without its "
                f"{cf.get('dask_cluster_start_s') or float('nan'):.1f} s start-up), overhead "
                f"{cf['overhead_ms_per_point']:.1f} ms/point, tables identical {cf['tables_identical']}, "
                f"load average {os.getloadavg()[0]:.1f}"
            )
            write_json(
                args.out,
                {"closed_form": cf, "machine": {"cpus": os.cpu_count(), "load_average_at_end": os.getloadavg()}},
            )
            print(f"wrote {args.out}")
            return
        ka = kappa_alpha(10 if args.quick else 40, 10 if args.quick else 25, tmp)
    res = {
        "closed_form": cf,
        "kappa_alpha": ka,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "load_average_at_end": os.getloadavg(),
        },
        "quick": args.quick,
    }
    rows = [
        ("pool(2) speed-up vs pool(1)", f"{cf['speedup_pool2']:.2f}x", ">= 1.7x"),
        ("Dask LocalCluster(2) vs pool(1)", f"{cf['speedup_dask2'] or float('nan'):.2f}x", ">= 1.5x"),
        ("  same, cluster start-up excluded", f"{cf.get('speedup_dask2_without_start') or float('nan'):.2f}x", ""),
        ("per-point overhead", f"{cf['overhead_ms_per_point']:.1f} ms", "<= 50 ms"),
        (f"{ka['points']}-point κ×α grid, 2 workers, cold cache", f"{ka['run_s']:.1f} s", "< 60 s"),
        ("  same grid, warm compile cache", f"{ka['run_warm_cache_s']:.1f} s", ""),
        ("resume of that study", f"{ka['resume_s']:.2f} s", "< 5 s"),
        ("executors' tables identical", str(cf["tables_identical"]), "True"),
    ]
    w = max(len(r[0]) for r in rows)
    print(f"{'measure':{w}}  {'measured':>12}  target")
    for name, val, tgt in rows:
        print(f"{name:{w}}  {val:>12}  {tgt}")
    print(
        f"(closed-form: {cf['points']} points, 1 worker {cf['pool1_s']:.2f} s, 2 workers {cf['pool2_s']:.2f} s, "
        f"Dask {cf['dask2_s'] or float('nan'):.2f} s, in-process {cf['inprocess_s']:.2f} s, direct {cf['direct_s']:.2f} s; "
        f"κ×α median task {ka['task_wall_median_s']:.2f} s)"
    )
    for veh, found in ka["sign_changes"].items():
        txt = (
            "; ".join(
                f"α={f['alpha']:g}: κ {f['kappa_from']:g}→{f['kappa_to']:g} "
                f"({f['change_from_pct']:+.2f}% → {f['change_to_pct']:+.2f}%{'' if f['comparable'] else ', not comparable'})"
                for f in found
            )
            or "none"
        )
        print(f"sign change of ω saving, {veh}: {txt}")
    write_json(args.out, res)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

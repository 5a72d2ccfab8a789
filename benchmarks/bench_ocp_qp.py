"""Solve time of aev_ocp's Riccati interior-point QP solver (aev_ocp/c/ocp_qp.c, ctypes binding
aev_ocp.mpc.ocpqp) against ``ca.conic`` HPIPM and qrqp on the same QPs in the same process.

Problems: random convex OCP QPs (aev_ocp.mpc.ocpqp.random_qp, feasible by construction, values of order
3) on the two reference dimensions of the project's MPC — canonical (model guide §9: N = 40, nx = 5,
nu = 1, nc = 2, bounds on some stage variables), the same with N = 100, traffic (N = 25, nx = 6, nu = 3,
nc = 6) — and the real RTI QPs of the controller (MPCController, solver 'rti', the QP of the third
closed-loop step recorded from its ``ca.conic`` call and split into stage blocks).

ocpqp: median wall time of the C solve (one ctypes call with prepared pointers, >= 200 repetitions)
per solve and per interior-point iteration; 'fixed': the same source compiled with the dimensions as
constants (-DOCPQP_NX=... , OcpQP(dims, specialise=True)); conic: median of >= 200 calls of the CasADi Function
(including CasADi's conversion of the sparse data; a call slower than 2 ms, a failing solve, is
repeated only for 0.5 s). 'agree' is max |w - w_conic| over the QP's variables
(qrqp's and HPIPM's own accuracy included). Tolerances: ocp_qp.h's defaults (1e-10), and 1e-8 in the
'tol 1e-8' rows. Times on a shared machine are noisy: medians, and ratios
within one process.

Real RTI QPs (tests/data/ocp_qp_rti_*.npz, harvested from closed loops; each was a failure of an earlier
version) at the MPC's settings (tolerances 1e-9, 50 iterations, dimensions compiled in): status, iterations
and median time. ``--baseline-src PATH`` (e.g. the file from ``git show drv:aev_ocp/c/ocp_qp.c``) compiles
another ocp_qp.c into the same process and adds its status, iterations and time to every row, and the ratio.
Usage: PYTHONPATH=. python benchmarks/bench_ocp_qp.py [--reps 300] [--baseline-src PATH] [--skip-rti]
       [--out benchmarks/bench_ocp_qp.json]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from aev_ocp.mpc.ocpqp import HPIPM_MODES, OcpQP, OcpQPDims, OcpQPError, OcpQPSettings, random_qp, sparse_qp
from aev_ocp.results import write_json

RANDOM = {
    "canonical N=40 (random)": OcpQPDims(N=40, nx=5, nu=1, nc=2),
    "canonical N=100 (random)": OcpQPDims(N=100, nx=5, nu=1, nc=2),
    "traffic N=25 (random)": OcpQPDims(N=25, nx=6, nu=3, nc=6),
}
DATA = Path(__file__).resolve().parent.parent / "tests" / "data"
CONIC = {
    "hpipm": {"hpipm": {"iter_max": 100, "warm_start": 0}},  # as aev_ocp.mpc.rti.qp_options
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
}


def _median_call(f: Any, reps: int) -> float:
    t = np.empty(reps)
    for j in range(reps):
        t0 = time.perf_counter()
        f()
        t[j] = time.perf_counter() - t0
    return float(np.median(t))


def blocks_from_full(N: int, nx: int, nu: int, q: dict[str, Any]) -> tuple[OcpQPDims, dict[str, Any]]:
    """Stage blocks of a full-space RTI QP as the MPC builds it (variables (x_0, u_0, ..., x_N); A's rows
    stage by stage: nx dynamics rows [A_k B_k] with -I on x_{k+1}, then the stage's path rows; x_0 fixed
    by lbx = ubx)."""
    nb = nx + nu
    H, A = np.array(ca.DM(q["h"])), np.array(ca.DM(q["a"]))
    g, lba, uba = (np.asarray(ca.DM(q[k])).ravel() for k in ("g", "lba", "uba"))
    lbx, ubx = np.asarray(ca.DM(q["lbx"])).ravel(), np.asarray(ca.DM(q["ubx"])).ravel()
    ngs = (A.shape[0]) // N
    nc = ngs - nx
    if A.shape[0] != N * ngs:
        raise ValueError(f"rows {A.shape[0]} are not N = {N} stages of the same size")
    d: dict[str, Any] = {k: [] for k in ("H", "g", "E", "e", "C", "lc", "uc", "lbw", "ubw")}
    for k in range(N + 1):
        o, n = k * nb, (nb if k < N else nx)
        d["H"].append(H[o : o + n, o : o + n])
        d["g"].append(g[o : o + n])
        d["lbw"].append(lbx[o : o + n])
        d["ubw"].append(ubx[o : o + n])
        if k < N:
            r = k * ngs
            if (
                np.abs(A[r : r + nx, o + nb : o + nb + nx] + np.eye(nx)).max() > 0
                or np.abs(lba[r : r + nx] - uba[r : r + nx]).max() > 0
            ):
                raise ValueError(f"stage {k}: not the dynamics layout (-I on x_k+1, equality rows)")
            d["E"].append(A[r : r + nx, o : o + nb])
            d["e"].append(-lba[r : r + nx])
            d["C"].append(A[r + nx : r + ngs, o : o + nb])
            d["lc"].append(lba[r + nx : r + ngs])
            d["uc"].append(uba[r + nx : r + ngs])
        else:
            d["C"].append(np.zeros((0, nx)))
            d["lc"].append(np.zeros(0))
            d["uc"].append(np.zeros(0))
    d["x0"] = lbx[:nx]
    return OcpQPDims(N=N, nx=nx, nu=nu, nc=nc, ncN=0), d


def rti_qp(formulation: str, N: int) -> tuple[OcpQPDims, dict[str, Any]]:
    """The QP of the third RTI step of the controller on the paper's leader (recorded from its conic call)."""
    from aev_ocp.models.leader import PaperLeader
    from aev_ocp.mpc.controller import MPCController
    from aev_ocp.mpc.predictors import Measurements, OraclePredictor, forecast_intervals
    from aev_ocp.mpc.settings import MPCSettings

    from aev_ocp.ocp.formulation import formulation_from_dict

    c = MPCController(
        MPCSettings(rti_hessian="exact", solver="rti", qp_solver="hpipm", codegen=False, N=N, max_step_ms=1e4),
        formulation=formulation_from_dict({"formulation": formulation}),
    )
    seen: list[dict[str, Any]] = []
    assert c.rti is not None
    qp = c.rti.qp

    class Recorder:
        def __call__(self, **kw: Any) -> Any:
            seen.append(kw)
            return qp(**kw)

        def stats(self) -> Any:
            return qp.stats()

    c.rti.qp = Recorder()
    dt = c.settings.dt
    z = np.array([0.6, 1.7, 0.0, 0.0, 0.8])
    for step in range(3):
        x, v = OraclePredictor(PaperLeader()).predict(step * dt, dt, N, Measurements(np.array([0.0]), np.array([0.0])))
        sol = c.solve(z, *forecast_intervals(x, v, dt))
        z = np.array([sol.X[i, 1] for i in range(5)])
    if not seen:
        raise RuntimeError("the controller made no RTI QP call")
    nx, nu = c.problem.nx, c.problem.nu
    return blocks_from_full(N, nx, nu, seen[-1])


def _baseline(
    row: dict[str, Any], dims: OcpQPDims, st: OcpQPSettings, data: dict[str, Any], reps: int, base_src: str | None
) -> None:
    """The baseline source's status, iterations and median time (dimensions compiled in) into ``row``."""
    if base_src is None:
        return
    base = OcpQP(dims, st, specialise=True, source=base_src)
    res = base.solve(**data)
    row.update(
        base_status=res.status_name,
        base_iterations=res.iterations,
        base_fixed_ms=float(np.median(base.timed_calls(reps))) * 1e3,
    )


def rti_cases() -> list[tuple[str, OcpQPDims, dict[str, Any]]]:
    """The harvested RTI QPs of tests/data (flat stage layout, x_0 = 0)."""
    out = []
    for f in sorted(DATA.glob("ocp_qp_rti_*.npz")):
        with np.load(f) as z:
            N, nx, nu, nc = (int(z[k]) for k in ("N", "nx", "nu", "nc"))
            data = {k: np.array(z[k]) for k in ("H", "g", "E", "e", "C", "lc", "uc", "lbw", "ubw")}
        data["x0"] = np.zeros(nx)
        out.append((f.stem.removeprefix("ocp_qp_rti_"), OcpQPDims(N=N, nx=nx, nu=nu, nc=nc), data))
    return out


def bench_case(name: str, dims: OcpQPDims, data: dict[str, Any], reps: int, base_src: str | None) -> dict[str, Any]:
    """A harvested RTI QP at the MPC's settings (tolerances 1e-9, 50 iterations), dimensions compiled in."""
    st = OcpQPSettings(max_iter=50, tol_stat=1e-9, tol_eq=1e-9, tol_ineq=1e-9, tol_comp=1e-9)
    fixed = OcpQP(dims, st, specialise=True)
    res = fixed.solve(**data)
    row: dict[str, Any] = {
        "problem": name,
        "N": dims.N,
        "nx": dims.nx,
        "nu": dims.nu,
        "nc": dims.nc,
        "status": res.status_name,
        "iterations": res.iterations,
        "ocpqp_fixed_ms": float(np.median(fixed.timed_calls(reps))) * 1e3,
    }
    _baseline(row, dims, st, data, reps, base_src)
    for mode in HPIPM_MODES:  # the second backend of ocp_qp.h: HPIPM's C API, same data, same settings
        try:
            hp = OcpQP(dims, st, backend="hpipm", hpipm_mode=mode)
        except OcpQPError as exc:
            row[f"hpipm_{mode}_error"] = str(exc)[:200]
            continue
        r = hp.solve(**data)
        row[f"hpipm_{mode}_status"] = r.status_name
        row[f"hpipm_{mode}_iterations"] = r.iterations
        row[f"hpipm_{mode}_ms"] = float(np.median(hp.timed_calls(reps))) * 1e3
        row[f"hpipm_{mode}_dw"] = float(np.abs(r.w - res.w).max())
    return row


def backend_summary(cases: list[dict[str, Any]]) -> dict[str, Any]:
    """Per backend (ocp_qp.c, HPIPM in each mode) on the harvested QPs: how many solved ('ok'), and the
    median over the QPs both solved of its time / ocp_qp.c's time."""
    out: dict[str, Any] = {"ocp_qp": {"solved": sum(r["status"] == "ok" for r in cases), "of": len(cases)}}
    for mode in HPIPM_MODES:
        both = [r for r in cases if r["status"] == "ok" and r.get(f"hpipm_{mode}_status") == "ok"]
        out[f"hpipm_{mode}"] = {
            "solved": sum(r.get(f"hpipm_{mode}_status") == "ok" for r in cases),
            "of": len(cases),
            "median_time_ratio_vs_ocp_qp": float(np.median([r[f"hpipm_{mode}_ms"] / r["ocpqp_fixed_ms"] for r in both]))
            if both
            else None,
        }
    return out


def bench_one(
    name: str, dims: OcpQPDims, data: dict[str, Any], reps: int, tol: float = 1e-10, base_src: str | None = None
) -> dict[str, Any]:
    st = OcpQPSettings(tol_stat=tol, tol_eq=tol, tol_ineq=tol, tol_comp=tol)
    solver, fixed = OcpQP(dims, st), OcpQP(dims, st, specialise=True)
    res = solver.solve(**data)
    fixed.set_data(**data)
    t = float(np.median(solver.timed_calls(reps)))
    tf = float(np.median(fixed.timed_calls(reps)))
    row: dict[str, Any] = {
        "problem": name,
        "tol": tol,
        "N": dims.N,
        "nx": dims.nx,
        "nu": dims.nu,
        "nc": dims.nc,
        "status": res.status_name,
        "iterations": res.iterations,
        "ocpqp_ms": t * 1e3,
        "ocpqp_per_iter_us": t * 1e6 / max(1, res.iterations),
        "ocpqp_fixed_ms": tf * 1e3,
        "fixed_same_w": bool(np.array_equal(fixed.solve_data().w, res.w)),
    }
    _baseline(row, dims, st, data, reps, base_src)
    sq = sparse_qp(dims, data)
    args = dict(h=sq["h"], a=sq["a"], g=sq["g"], lba=sq["lba"], uba=sq["uba"], lbx=sq["lbx"], ubx=sq["ubx"])
    for plugin, opts in CONIC.items():
        try:
            f = ca.conic(
                f"bench_{plugin}",
                plugin,
                {"h": sq["h"].sparsity(), "a": sq["a"].sparsity()},
                {**opts, "error_on_fail": False},
            )
            t0 = time.perf_counter()
            out = f(**args)
            once = time.perf_counter() - t0
            ok = bool(f.stats().get("success", False))
            n = reps if once < 2e-3 else max(10, int(0.5 / once))  # slow failures: fewer repetitions
            row[f"{plugin}_ms"] = _median_call(lambda: f(**args), n) * 1e3
            row[f"{plugin}_reps"] = n
            row[f"{plugin}_ok"] = ok
            row[f"{plugin}_agree"] = float(np.abs(np.asarray(out["x"]).ravel() - res.w).max())
        except RuntimeError as exc:
            row[f"{plugin}_ms"], row[f"{plugin}_ok"] = float("nan"), False
            row[f"{plugin}_error"] = str(exc).splitlines()[-1][:160]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=300)
    ap.add_argument("--out", default="benchmarks/bench_ocp_qp.json")
    ap.add_argument("--skip-rti", action="store_true", help="only the random QPs and the harvested ones")
    ap.add_argument("--baseline-src", default=None, help="another ocp_qp.c to compare in the same process")
    ap.add_argument(
        "--only-harvested", action="store_true", help="only the harvested RTI QPs (the backends' comparison)"
    )
    a = ap.parse_args()
    base_src = Path(a.baseline_src).read_text(encoding="utf-8") if a.baseline_src else None
    rows = []
    for name, dims in ({} if a.only_harvested else RANDOM).items():
        rows.append(
            bench_one(
                name, dims, random_qp(dims, np.random.default_rng(2026), equality_rows=0.0), a.reps, base_src=base_src
            )
        )
    if not (a.skip_rti or a.only_harvested):
        for name, form, N in (("canonical RTI QP (s9, N=40)", "s9", 40), ("traffic RTI QP (N=25)", "traffic", 25)):
            try:
                dims, data = rti_qp(form, N)
                rows.append(bench_one(name, dims, data, a.reps, base_src=base_src))
                rows.append(
                    bench_one(name.replace("QP", "QP tol 1e-8"), dims, data, a.reps, tol=1e-8, base_src=base_src)
                )
            except Exception as exc:  # reported, not fatal: the random rows stand on their own
                rows.append({"problem": name, "error": f"{type(exc).__name__}: {str(exc).splitlines()[0][:200]}"})
    head = (
        f"{'problem':30s} {'dims':>16s} {'status':>9s} {'it':>3s} {'ocpqp ms':>9s} {'us/it':>6s} {'fixed ms':>8s} "
        f"{'hpipm ms':>9s} {'qrqp ms':>9s} {'x hpipm':>7s} {'x qrqp':>7s}  agree(hpipm, qrqp)"
    )
    print(head)
    for r in rows:
        if "error" in r:
            print(f"{r['problem']:30s} error: {r['error']}")
            continue
        dims = f"{r['N']}/{r['nx']}/{r['nu']}/{r['nc']}"
        print(
            f"{r['problem']:30s} {dims:>16s} {r['status']:>9s} {r['iterations']:3d} {r['ocpqp_ms']:9.4f} "
            f"{r['ocpqp_per_iter_us']:6.2f} {r['ocpqp_fixed_ms']:8.4f} {r['hpipm_ms']:9.4f} {r['qrqp_ms']:9.4f} "
            f"{r['hpipm_ms'] / r['ocpqp_ms']:7.1f} {r['qrqp_ms'] / r['ocpqp_ms']:7.1f}  "
            f"{r.get('hpipm_agree', float('nan')):.1e}{'' if r['hpipm_ok'] else '(fail)'}, "
            f"{r.get('qrqp_agree', float('nan')):.1e}{'' if r['qrqp_ok'] else '(fail)'}"
        )
    cases = [bench_case(name, dims, data, a.reps, base_src) for name, dims, data in rti_cases()]
    print("\nharvested RTI QPs (tests/data; tol 1e-9, 50 iterations, dimensions compiled in)")
    print(
        f"{'case':30s} {'dims':>12s} {'status':>9s} {'it':>3s} {'fixed ms':>8s}"
        + "".join(f" {'hpipm ' + m:>14s} {'it':>3s} {'ms':>7s}" for m in HPIPM_MODES)
        + (f" {'base status':>11s} {'it':>3s} {'base ms':>8s} {'base/new':>8s}" if base_src else "")
    )
    for r in cases:
        line = (
            f"{r['problem']:30s} {r['N']}/{r['nx']}/{r['nu']}/{r['nc']:<3d} {r['status']:>9s} {r['iterations']:3d} "
            f"{r['ocpqp_fixed_ms']:8.4f}"
        )
        for m in HPIPM_MODES:
            line += (
                f" {r[f'hpipm_{m}_status']:>14s} {r[f'hpipm_{m}_iterations']:3d} {r[f'hpipm_{m}_ms']:7.4f}"
                if f"hpipm_{m}_status" in r
                else f" {'n/a':>14s} {'':3s} {'':7s}"
            )
        if base_src:
            line += (
                f" {r['base_status']:>11s} {r['base_iterations']:3d} {r['base_fixed_ms']:8.4f} "
                f"{r['base_fixed_ms'] / r['ocpqp_fixed_ms']:8.2f}"
            )
        print(line)
    if base_src:
        print("\nbaseline (same process) on the rows above: base it -> it, base fixed ms -> fixed ms (ratio base/new)")
        for r in rows:
            if "base_fixed_ms" in r:
                print(
                    f"{r['problem']:30s} {r['base_iterations']:3d} -> {r['iterations']:3d}  {r['base_fixed_ms']:8.4f} -> "
                    f"{r['ocpqp_fixed_ms']:8.4f}  ({r['base_fixed_ms'] / r['ocpqp_fixed_ms']:.2f})"
                )
        rows_ok = [r for r in cases if r["status"] == "ok"]
        print(
            f"harvested: {len(rows_ok)}/{len(cases)} ok (baseline "
            f"{sum(r['base_status'] == 'ok' for r in cases)}/{len(cases)})"
        )
    summary = backend_summary(cases)
    print("\nbackends on the harvested QPs (solved of 12; median time ratio to ocp_qp.c over the QPs both solved):")
    for k, v in summary.items():
        ratio = v.get("median_time_ratio_vs_ocp_qp")
        print(f"  {k:15s} {v['solved']:2d}/{v['of']}" + (f"  x{ratio:.2f}" if ratio is not None else ""))
    rows.extend(cases)
    write_json(
        a.out,
        {
            "benchmark": "bench_ocp_qp",
            "reps": a.reps,
            "rows": rows,
            "backends": summary,
            "note": "dims = N/nx/nu/nc; times are medians (ms); 'x hpipm' = hpipm_ms / ocpqp_ms",
        },
    )
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

"""The w_Q Pareto front of the MPC: pack heat against tracking as the heat weight w_Q is swept.

w_Q weighs the pack heat in the §9 stage cost; raising it buys heat with tracking (and comfort). Each w_Q
is one closed loop on the canonical scenario (one follower behind the paper's leader, oracle forecast);
the closed-form laws are drawn as reference points, and the non-dominated runs (lower heat AND lower RMS
relative speed) form the front. (For many points or a cluster, the same sweep is
``aev-ocp study studies/wq_pareto_mpc.toml``.) Run: python examples/wq_pareto.py [--quick] [--out DIR]
Writes DIR/wq_pareto.json (one row per run, with its 'pareto' flag) and DIR/wq_pareto.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import PaperLeader
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.ocp.formulation import s9_formulation
from aev_ocp.params import EVParams
from aev_ocp.plots import plt, save_figure
from aev_ocp.simulate import simulate_platoon
from aev_ocp.study.report import pareto_mask

H0, V0 = 0.3, 1.87  # model guide §9 canonical initial state


def main(quick: bool = False, out: Path = Path("results/examples/wq_pareto")) -> list[dict[str, Any]]:
    ev = EVParams()
    leader = PaperLeader()
    t_end = 6.0 if quick else 70.0  # model time
    w_qs = (0.3, 1.0, 3.0) if quick else (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
    # model guide §9's formulation, as in scenarios/mpc_paper_single.toml (w_Q is a §9 weight)
    base = MPCSettings(N=40, predictor="oracle", rti_hessian="exact", max_step_ms=1e4)
    f9 = s9_formulation()
    rows: list[dict[str, Any]] = []
    for w_q in w_qs:
        f = f9.with_(weights=dataclasses.replace(f9.weights, w_Q=w_q))
        r = run_closed_loop(leader, [MPCVehicle(base, formulation=f)], [H0], [V0], t_end, ev=ev)
        rows.append({"controller": f"mpc w_Q={w_q:g}", "w_Q": w_q, **_metrics(r)})
    for law in (Proposed(), OVFL()):
        r = simulate_platoon(leader, [law], [H0], [V0], t_end, ev=ev, dt_out=base.dt)
        rows.append({"controller": law.name, "w_Q": None, **_metrics(r)})
    mpc = [r for r in rows if r["w_Q"] is not None and r["status"] == "ok"]
    for r, on in zip(mpc, pareto_mask([(r["heat_pack_J"], r["rms_rel_speed_model"]) for r in mpc])):
        r["pareto"] = bool(on)
    out.mkdir(parents=True, exist_ok=True)
    (out / "wq_pareto.json").write_text(json.dumps(rows, indent=1))
    _plot(rows, out / "wq_pareto.png")
    for r in rows:
        print(
            f"{r['controller']:>14}: pack heat {r['heat_pack_J']:8.1f} J, RMS rel. speed "
            f"{r['rms_rel_speed_model']:.4f}{'  (front)' if r.get('pareto') else ''}"
        )
    return rows


def _metrics(r: Any) -> dict[str, Any]:
    m = r.metrics()[0]
    return {k: m[k] for k in ("heat_pack_J", "rms_rel_speed_model", "rms_jerk_model", "omega_J_per_kg", "status")}


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    mpc = sorted((r for r in rows if r["w_Q"] is not None), key=lambda r: r["heat_pack_J"])
    ax.plot(
        [r["heat_pack_J"] for r in mpc],
        [r["rms_rel_speed_model"] for r in mpc],
        "o-",
        color="tab:red",
        label="MPC, w_Q swept",
    )
    for r in mpc:
        ax.annotate(
            f"w_Q = {r['w_Q']:g}",
            (r["heat_pack_J"], r["rms_rel_speed_model"]),
            fontsize=7,
            xytext=(4, 4),
            textcoords="offset points",
        )
    for r, marker in zip([r for r in rows if r["w_Q"] is None], ("s", "^")):
        ax.plot([r["heat_pack_J"]], [r["rms_rel_speed_model"]], marker, ms=8, label=r["controller"])
    ax.set_xlabel("pack heat ∫Q dt [J]")
    ax.set_ylabel("RMS relative speed [model speed]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a short horizon and three weights (for the test suite)")
    ap.add_argument("--out", type=Path, default=Path("results/examples/wq_pareto"))
    a = ap.parse_args()
    main(a.quick, a.out)

"""The drive-cycle tuning's output files (:data:`aev_ocp.tuning.core.FILES`): the tables of what was tuned and of
each controller at its default and tuned (``tuning.md``), the summary, every run and every trial as CSV, and all of it
as ``tuning.json``; each written atomically."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from .core import (
    CONSTRAINTS,
    LIMITS,
    Case,
    Space,
    TrialRecord,
    Tuner,
    TuningOutput,
    _aggregate,
    _fmt,
    scenario_overrides,
)


@dataclass(frozen=True)
class TuningRun:
    """What one drive-cycle tuning produced, for its files: the controllers' spaces, tuners, default and best sets,
    the final runs (per controller: default, tuned; each in case order), the cases, the budget, the sampler's seed,
    the batch, the closed-loop evaluations per controller while tuning and the command line."""

    spaces: Sequence[Space]
    tuners: Mapping[str, Tuner]
    defaults: Mapping[str, Mapping[str, float]]
    best: Mapping[str, TrialRecord | None]
    final: Sequence[Sequence[Mapping[str, Any]]]
    train: Sequence[Case]
    held: Sequence[Case]
    budget: int
    seed: int
    batch: int
    evals: Mapping[str, int]
    command: str | None


def csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    """Rows as CSV text, the columns in order of first appearance."""
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def result_rows(run: TuningRun) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """(summary, every run, every trial) rows: the summary per controller × default/tuned × train/held-out."""
    cases = list(run.train) + list(run.held)
    summary, runs_rows, trials_rows = [], [], []
    for i, s in enumerate(run.spaces):
        for which, runs in (("default", run.final[2 * i]), ("tuned", run.final[2 * i + 1])):
            for split, sub in (("train", list(run.train)), ("held-out", list(run.held))):
                rr = [r for r, c in zip(runs, cases) if c.split == split]
                summary.append({"controller": s.label, "set": which, "split": split, **_aggregate(rr, sub)})
            for r, c in zip(runs, cases):
                runs_rows.append({"controller": s.label, "set": which, "split": c.split, "case": c.name, **r})
        for rec in run.tuners[s.label].records:
            trials_rows.append(
                {
                    "controller": s.label,
                    "trial": rec.number,
                    "objective_kWh_per_100km": rec.objective,
                    "feasible": rec.feasible,
                    **{f"violation_{k}": v for k, v in zip(CONSTRAINTS, rec.constraints)},
                    **rec.values,
                }
            )
    return summary, runs_rows, trials_rows


def per_controller(run: TuningRun) -> dict[str, dict[str, Any]]:
    """Per controller: its parameters (bounds, default, tuned), trials, evaluations, best trial, tuned overrides."""
    out: dict[str, dict[str, Any]] = {}
    doc, file = run.train[0].document, run.train[0].file
    for s in run.spaces:
        b = run.best[s.label]
        out[s.label] = {
            "parameters": [
                {
                    "name": p.name,
                    "meaning": p.meaning,
                    "lo": p.lo,
                    "hi": p.hi,
                    "log": p.log,
                    "default": run.defaults[s.label][p.name],
                    "tuned": b.values[p.name] if b is not None else None,
                }
                for p in s.params
            ],
            "trials": run.budget,
            "closed_loop_evaluations": run.evals.get(s.label, 0),
            "best_trial": b.number if b is not None else None,
            "tuned_overrides": scenario_overrides(s, b.values, doc, file) if b is not None else None,
        }
    return out


def parameter_rows(spaces: Sequence[Space], per_ctrl: Mapping[str, Mapping[str, Any]]) -> list[list[str]]:
    """Rows of the 'What was tuned' table: controller, parameter, meaning, bounds, default, tuned."""
    rows = []
    for s in spaces:
        for p in per_ctrl[s.label]["parameters"]:
            rows.append(
                [
                    s.label,
                    p["name"],
                    p["meaning"],
                    f"[{_fmt(p['lo'])}, {_fmt(p['hi'])}]" + (" log" if p["log"] else ""),
                    _fmt(p["default"], 4),
                    _fmt(p["tuned"], 4) if p["tuned"] is not None else "no feasible trial",
                ]
            )
    return rows


def _head(run: TuningRun) -> list[str]:
    n_train = len(run.train)
    return [
        "# Equal tuning effort: each controller at its default and tuned",
        "",
        f"Command: `{run.command}`" if run.command else "",
        "",
        f"Budget: {run.budget} trials per controller × {n_train} training scenarios = {run.budget * n_train} "
        f"closed-loop evaluations per controller (trial 0 is the default); optuna TPE, seed {run.seed}, {run.batch} "
        "trials per controller per study execution.",
        f"Training: {', '.join(c.name for c in run.train)}. Held-out: {', '.join(c.name for c in run.held)}.",
        "Objective: the follower's battery energy [kWh/100 km], mean over the training drive cycles. Feasible: no "
        f"event, min gap ≥ {LIMITS['min_gap_m']:g} m, min TTC ≥ {LIMITS['min_ttc_s']:g} s, RMS jerk ≤ "
        f"{LIMITS['rms_jerk_max_mps3']:g} m/s³, mean time gap while moving ≤ {LIMITS['mean_time_gap_max_s']:g} s "
        "(drive cycles).",
        "",
        "## What was tuned",
        "",
    ]


def _summary_table(run: TuningRun, summary: Sequence[Mapping[str, Any]]) -> str:
    from ..report import markdown_table

    rows = []
    for s in run.spaces:
        cell = {(r["set"], r["split"]): r for r in summary if r["controller"] == s.label}
        row = [s.label, f"{run.budget} / {run.evals.get(s.label, 0)}"]
        for split in ("train", "held-out"):
            for which in ("default", "tuned"):
                r = cell[(which, split)]
                row.append(f"{_fmt(r['battery_energy_kWh_per_100km'], 4)} ({r['feasible_runs']}/{r['runs']} feasible)")
            e0, e1 = (cell[(w, split)]["battery_energy_kWh_per_100km"] for w in ("default", "tuned"))
            row.append(f"{100.0 * (e1 - e0) / e0:+.1f}" if math.isfinite(e0) and math.isfinite(e1) and e0 else "–")
        rows.append(row)
    head = ["controller", "trials / evaluations", "train default", "train tuned", "change %"]
    return markdown_table(head + ["held-out default", "held-out tuned", "change %"], rows)


def _runs_table(runs_rows: Sequence[Mapping[str, Any]]) -> str:
    from ..report import markdown_table

    head = ["controller", "set", "split", "case", "status", "kWh/100 km", "min gap m", "min TTC s", "RMS jerk m/s³"]
    return markdown_table(
        head + ["mean time gap s"],
        [
            [
                r["controller"],
                r["set"],
                r["split"],
                r["case"],
                r["status"],
                _fmt(r["battery_energy_kWh_per_100km"], 4),
                _fmt(r["min_gap_m"]),
                _fmt(r["min_ttc_s"]),
                _fmt(r["rms_jerk_mps3"]),
                _fmt(r["mean_time_gap_s"]),
            ]
            for r in runs_rows
        ],
    )


def markdown(
    run: TuningRun,
    per_ctrl: Mapping[str, Mapping[str, Any]],
    summary: Sequence[Mapping[str, Any]],
    runs_rows: Sequence[Mapping[str, Any]],
) -> str:
    """``tuning.md``: the budget, what was tuned, default and tuned side by side, every run."""
    from ..report import markdown_table

    md = _head(run)
    md.append(
        markdown_table(
            ["controller", "parameter (SI)", "meaning", "bounds", "default", "tuned"],
            parameter_rows(run.spaces, per_ctrl),
        )
    )
    md += ["", "## Default and tuned, side by side", "", _summary_table(run, summary)]
    md += [
        "",
        "Battery energy: kWh/100 km, mean over the drive cycles of the split (held-out: US06 only; the safety cases count "
        "for feasibility); change: tuned against default. Default and tuned are each one SI parameter set on every "
        "case (the default: the first training scenario's). A run is feasible when it meets the constraints above "
        "(a safety case: no event, the gap).",
        "",
        "## Every run",
        "",
        _runs_table(runs_rows),
        "",
    ]
    return "\n".join(md)


def write_tuning(folder: Path, run: TuningRun) -> TuningOutput:
    """Write the tuning's files (:data:`aev_ocp.tuning.core.FILES`) into ``folder``, atomically."""
    from ..results import to_jsonable, write_atomic, write_json

    summary, runs_rows, trials_rows = result_rows(run)
    per_ctrl = per_controller(run)
    result = {
        "command": run.command,
        "budget_trials": run.budget,
        "training_cases": [c.name for c in run.train],
        "heldout_cases": [c.name for c in run.held],
        "closed_loop_evaluations_per_controller": run.budget * len(run.train),
        "seed": run.seed,
        "batch": run.batch,
        "sampler": "optuna TPESampler (multivariate, constrained), seed fixed",
        "limits": LIMITS,
        "controllers": per_ctrl,
        "summary": summary,
    }
    files = [
        write_atomic(folder / "tuning.md", markdown(run, per_ctrl, summary, runs_rows)),
        write_atomic(folder / "tuning.csv", csv_text(summary)),
        write_atomic(folder / "runs.csv", csv_text(runs_rows)),
        write_atomic(folder / "trials.csv", csv_text(trials_rows)),
        write_json(folder / "tuning.json", to_jsonable({**result, "runs": runs_rows})),
    ]
    return TuningOutput(folder, files, summary, runs_rows, result)

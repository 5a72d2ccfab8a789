"""The drive-cycle tuned sets through the whole safety suite: every case of :mod:`aev_ocp.safety`, both
actuators, each tuned controller bare and under the braking-distance layer, once with the tuning's default sets and
once with its tuned sets (a drive-cycle tuning folder's ``tuning.json``); the events (collisions, floor violations,
failures in avoidable cases) counted per controller and actuator, default against tuned.

The sets enter the suite as SI fields of its laws (:func:`aev_ocp.safety.run.run_suite` ``law_overrides``): an
OV-type law's coefficients at its tuned scales, the IDM's T, a and b (its desired speed stays the suite's: the case's
speed), the MPC's traffic-formulation weights and target time gap. The default sets are the drive-cycle tuning's
defaults; for the OV-type laws and the MPC they are the suite's own, for the IDM the suite uses T = 1.5 s where the
drive cycles' default is 1.0 s, so the default row runs the drive cycles' IDM.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

from ..params import ParameterError

#: Files written beside the tuning's.
SAFETY_FILES = ("safety.md", "safety.json")
#: The controllers of the suite that the tuning tunes.
SUITE_TUNED = ("proposed", "ovfl", "idm", "mpc")
#: OV-type laws' SI coefficients and their dimensionless field.
_OV = {"alpha_per_s": "alpha", "beta_m2ps": "beta", "kappa_per_m": "kappa", "eps_m2ps2": "eps"}


def suite_overrides(controller: str, values: Mapping[str, float]) -> dict[str, float]:
    """The suite law's fields that set ``values`` (the tuning's SI parameters of ``controller``): an OV-type law's
    dimensionless coefficients at the scales in ``values`` (its untuned SI coefficients as the suite's law has them,
    so the SI law is the tuned one), the IDM's SI fields as they are."""
    if controller == "idm":
        return {k: float(v) for k, v in values.items()}
    from ..models.carfollowing import OVFL, Proposed
    from ..safety.run import LAW_SCALE_M, LAW_SCALE_MPS
    from ..scenarios.followers import SI_COEFFICIENTS

    base = (Proposed if controller == "proposed" else OVFL)(h_scale_m=LAW_SCALE_M, v_scale_mps=LAW_SCALE_MPS)
    si = {**base.si_coefficients(), **{k: float(v) for k, v in values.items()}}
    ell, u = si["h_scale_m"], si["v_scale_mps"]
    out = {"h_scale_m": ell, "v_scale_mps": u}
    for key, coeff in _OV.items():
        if hasattr(base, coeff) and key in si:
            out[coeff] = SI_COEFFICIENTS[key][1](si[key], ell, u)
    return out


def _sets(tuning: Mapping[str, Any], which: str) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
    """(law overrides, MPC traffic parameters) of the tuning's ``which`` ('default' or 'tuned') sets."""
    laws: dict[str, dict[str, float]] = {}
    mpc: dict[str, float] = {}
    for c, info in tuning["controllers"].items():
        vals = {p["name"]: p[which] for p in info["parameters"]}
        if any(v is None for v in vals.values()):
            continue  # no feasible trial: the default stays
        if c == "mpc":
            mpc = {k: float(v) for k, v in vals.items()}
        elif c in SUITE_TUNED:
            laws[c] = suite_overrides(c, vals)
    return laws, mpc


def run_safety(
    folder: str | Path, workers: int | None = None, quick: bool = False, progress: Any = None
) -> dict[str, Any]:
    """Run the suite with the default and the tuned sets of the drive-cycle tuning in ``folder`` (its
    ``tuning.json``) and write :data:`SAFETY_FILES` there. Returns {'default': summary, 'tuned': summary,
    'controllers': [...], 'sets': {...}} (summaries as :func:`aev_ocp.safety.report.summary`)."""
    from ..ocp.formulation import traffic_formulation
    from ..ocp.traffic import TrafficParams
    from ..results import to_jsonable, write_atomic, write_json
    from ..safety.report import summary
    from ..safety.run import LAYER, run_suite

    path = Path(folder) / "tuning.json"
    if not path.is_file():
        raise ParameterError(f"tune --safety-suite: {path} does not exist: run the drive-cycle tuning there first")
    tuning = json.loads(path.read_text())
    ctrls = [c for c in SUITE_TUNED if c in tuning["controllers"]]
    controllers = [*ctrls, *(c + LAYER for c in ctrls)]
    out: dict[str, Any] = {"controllers": controllers, "sets": {}}
    for which in ("default", "tuned"):
        laws, mpc = _sets(tuning, which)
        form = traffic_formulation(TrafficParams(**mpc)) if mpc else None
        res = run_suite(
            None, controllers, formulation=form, quick=quick, workers=workers, progress=progress, law_overrides=laws
        )
        out[which] = summary(res)
        out["sets"][which] = {"laws": laws, "mpc": mpc}
        out[f"{which}_cases"] = len(res.cases)
    write_json(Path(folder) / "safety.json", to_jsonable(out))
    write_atomic(Path(folder) / "safety.md", safety_markdown(out))
    return out


def event_rows(out: Mapping[str, Any]) -> list[list[str]]:
    """Per controller and actuator: collisions, floor violations (all labels) and failures (avoidable cases with
    either), default → tuned; the cases that fail at the default only and at the tuned set only."""
    rows = []
    for key in out["default"]:
        d, t = out["default"][key], out["tuned"].get(key)
        if t is None:
            continue
        cells = [d["controller"], d["actuator"]]
        for what in ("collisions", "floor_violations"):
            cells.append(f"{sum(d[what].values())} → {sum(t[what].values())}")
        cells.append(f"{len(d['failures'])} → {len(t['failures'])}")
        cells.append(", ".join(sorted(set(d["failures"]) - set(t["failures"]))) or "–")
        cells.append(", ".join(sorted(set(t["failures"]) - set(d["failures"]))) or "–")
        rows.append(cells)
    return rows


def safety_markdown(out: Mapping[str, Any]) -> str:
    """``safety.md``: the events of the default and the tuned sets over the whole suite."""
    from ..report import markdown_table

    head = ["controller", "actuator", "collisions", "floor violations", "failures (avoidable)", "fixed by tuning"]
    head.append("new with tuning")
    return "\n".join(
        [
            "# The drive-cycle tuned sets through the safety suite",
            "",
            f"Every case of the suite ({out['default_cases']}), both actuators; default → tuned. A failure is a "
            "collision or a floor violation in a case the braking bound labels avoidable.",
            "",
            markdown_table(head, event_rows(out)),
            "",
        ]
    )

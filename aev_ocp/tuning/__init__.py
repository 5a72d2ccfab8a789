"""Equal tuning effort: every controller gets the same budget of closed-loop evaluations on a
training set, chosen by one optimiser (optuna's TPE sampler with a fixed seed), and is reported at its default and
tuned, side by side, on the training set and on held-out scenarios.

* drive cycles (:mod:`.core`, :mod:`.cycles`, :mod:`.write`): the MPC and the laws on UDDS/HWFET segments, held-out
  US06 and four safety cases; ``aev-ocp tune``;
* the ring (:mod:`.ring`): one AEV among the calibrated drivers, trained on two seeds, held out on ten;
  ``aev-ocp tune --ring``;
* the safety suite (:mod:`.safety`): the drive-cycle tuned sets through every case of :mod:`aev_ocp.safety`;
  ``aev-ocp tune --safety-suite``.

>>> from aev_ocp.tuning import run_tuning
>>> out = run_tuning(["proposed", "idm"], budget=12, out="results/tune", workers=2)
"""

from __future__ import annotations

from .cli import build_parser, cli_tune
from .core import (
    CONSTRAINTS,
    FILES,
    HELDOUT_SAFETY,
    HELDOUT_SEGMENTS,
    LIMITS,
    MOVING_MPS,
    PENALTY_KWH_PER_100KM,
    SAFETY_BASE,
    TRAIN_SEGMENTS,
    TUNING_TABLE,
    Case,
    Evaluator,
    Param,
    Space,
    TrialRecord,
    Tuner,
    TuningOutput,
    case_document,
    check_budget,
    check_spaces,
    cycle_case,
    default_values,
    feasible,
    heldout_cases,
    optimise,
    run_summary,
    safety_case,
    scenario_overrides,
    score,
    time_gaps_s,
    training_cases,
    tune_rounds,
)
from .cycles import check_seed, run_tuning
from .ring import RING_TABLE, run_ring_tuning

__all__ = [
    "CONSTRAINTS",
    "FILES",
    "HELDOUT_SAFETY",
    "HELDOUT_SEGMENTS",
    "LIMITS",
    "MOVING_MPS",
    "PENALTY_KWH_PER_100KM",
    "RING_TABLE",
    "SAFETY_BASE",
    "TRAIN_SEGMENTS",
    "TUNING_TABLE",
    "Case",
    "Evaluator",
    "Param",
    "Space",
    "TrialRecord",
    "Tuner",
    "TuningOutput",
    "build_parser",
    "case_document",
    "check_budget",
    "check_seed",
    "check_spaces",
    "cli_tune",
    "cycle_case",
    "default_values",
    "feasible",
    "heldout_cases",
    "optimise",
    "run_ring_tuning",
    "run_summary",
    "run_tuning",
    "safety_case",
    "scenario_overrides",
    "score",
    "time_gaps_s",
    "training_cases",
    "tune_rounds",
]

"""The drive-cycle tuning (:func:`run_tuning`): every controller of :data:`aev_ocp.tuning.core.TUNING_TABLE` tuned
with the same budget on the training drive-cycle segments, then default and tuned run on the training and held-out
cases (:mod:`aev_ocp.tuning.core`) and written (:mod:`aev_ocp.tuning.write`).

>>> from aev_ocp.tuning import run_tuning
>>> out = run_tuning(["proposed", "idm"], budget=12, out="results/tune", workers=2)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

from ..params import ParameterError, echo
from .core import (
    FILES,
    TUNING_TABLE,
    Case,
    Evaluator,
    Space,
    Tuner,
    TuningOutput,
    check_budget,
    check_spaces,
    default_values,
    heldout_cases,
    score,
    training_cases,
    tune_rounds,
)
from .write import TuningRun, write_tuning


def check_seed(seed: Any) -> int:
    """The sampler's ``seed`` as an int ≥ 0; ParameterError naming it otherwise."""
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ParameterError(f"tuning: seed = {echo(seed)} is not allowed: must be an integer >= 0")
    return seed


def run_tuning(
    controllers: Sequence[str] = tuple(TUNING_TABLE),
    budget: int = 16,
    out: str | Path | None = None,
    *,
    seed: int = 1,
    batch: int = 4,
    bounds: Mapping[str, Mapping[str, tuple[float, float]]] | None = None,
    executor: str = "pool",
    workers: int | None = None,
    scheduler: str | None = None,
    progress_stream: Any = None,
    command: str | None = None,
) -> TuningOutput:
    """Tune each controller with ``budget`` trials (each trial one run per training case), ``batch`` trials per
    controller per study execution, sampler seed ``seed``; then run default and tuned on the training and held-out
    cases and write :data:`FILES` into ``out`` (default results/tune). executor, workers, scheduler: as
    :func:`aev_ocp.study.runner.execute`."""
    from ..results import claim_output_dir, output_lock
    from ..study.runner import check_executor

    spaces = check_spaces(list(controllers), bounds)
    budget = check_budget(budget)
    batch = check_budget(batch, "batch")
    seed = check_seed(seed)
    check_executor(executor, workers, scheduler)
    folder = Path(out) if out is not None else Path("results") / "tune"
    train, held = training_cases(), heldout_cases()
    with output_lock(folder):
        claim_output_dir(folder, "tune", "tuning", None, list(FILES))
        ev = Evaluator(folder, executor, workers, scheduler, progress_stream)
        defaults = {s.label: default_values(s, train[0].document, train[0].file) for s in spaces}
        tuners = {s.label: Tuner(s.params, defaults[s.label], budget, seed) for s in spaces}
        tune_rounds(
            spaces,
            tuners,
            batch,
            lambda pairs, rnd: ev.run([(s, v, train) for s, v in pairs], name=f"tune round {rnd}"),
            lambda runs: score(runs, train),
        )
        tuned_evals = dict(ev.counts)
        # default and tuned on every case, each one SI parameter set (the default: the first training scenario's, so a
        # scenario's own law scales, e.g. US06's ℓ = 20 m, u = 22 m/s, do not make the default differ between cases);
        # the default's training runs are trial 0's: the store has them
        best = {s.label: tuners[s.label].best() for s in spaces}
        jobs2: list[tuple[Space, Mapping[str, float] | None, Sequence[Case]]] = []
        for s in spaces:
            b = best[s.label]
            jobs2.append((s, defaults[s.label], train + held))  # one SI set on every case, as the tuned one
            jobs2.append((s, b.values if b is not None else None, train + held))
        final = ev.run(jobs2, name="tune: default and tuned")
        run = TuningRun(spaces, tuners, defaults, best, final, train, held, budget, seed, batch, tuned_evals, command)
        return write_tuning(folder, run)

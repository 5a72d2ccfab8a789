"""The size of a platoon run against the memory budget (:mod:`aev_ocp.limits`): refuse it with the key to change
(:func:`check_run_size`), or thin its output grid just enough that it fits (:func:`thinned_dt_out`)."""

from __future__ import annotations

import math
import warnings

from ..limits import BYTES_PER_SAMPLE, estimate_run_bytes, memory_limit_bytes, n_samples
from ..params import SimOptions
from .tables import ScenarioError, ScenarioWarning

MIN_SAMPLES = 100  # thinning never leaves fewer output intervals than this
MAX_SAMPLES = 1_000_000  # samples per follower (t_end/dt_out); shipped scenarios need 7 001 ... 70 001


def _round_up(x: float) -> float:
    """The smallest number of 3 significant digits >= x (x > 0)."""
    step = 10.0 ** (math.floor(math.log10(x)) - 2)
    y = math.ceil(x / step - 1e-9) * step
    return float(f"{y:.3g}") if float(f"{y:.3g}") >= x else y


def _gb(x: float) -> str:
    return f"{x / 1e9:.3g} GB"


def check_run_size(n_followers: int, t_end: float, dt_out: float, file: str = "<scenario>") -> float:
    """Raise ScenarioError (naming the key to change) if a run needs more than :func:`memory_limit_bytes`.
    Returns the estimate [bytes]."""
    need, limit = estimate_run_bytes(n_followers, t_end, dt_out), memory_limit_bytes()
    if need <= limit:
        return need
    per_vehicle = BYTES_PER_SAMPLE * n_samples(t_end, dt_out)
    max_followers = int(limit // per_vehicle)
    k_max = limit / (BYTES_PER_SAMPLE * n_followers)
    if k_max - 1 < MIN_SAMPLES or max_followers < 1 and t_end / SimOptions().chunk > k_max:
        fix = f"lower platoon.followers to at most {max_followers}" if max_followers >= 1 else "lower simulation.t_end"
    else:
        fix = f"raise simulation.dt_out to at least {_round_up(t_end / (k_max - 1)):.3g}" + (
            " or lower platoon.followers" if n_followers > 1 else " or lower simulation.t_end"
        )
    raise ScenarioError(
        f"{file}: the run needs about {_gb(need)} ({n_followers} followers x "
        f"{n_samples(t_end, dt_out):.3g} samples, simulation.t_end = {t_end:g}, simulation.dt_out = "
        f"{dt_out:g}), more than the limit of {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): {fix}"
    )


def thinned_dt_out(n_followers: int, t_end: float, dt_out: float, file: str = "<scenario>") -> float:
    """dt_out, raised (with a ScenarioWarning) just enough that the run fits the memory budget when at
    least MIN_SAMPLES output intervals remain; otherwise :func:`check_run_size` refuses the run."""
    chunk = SimOptions().chunk
    if n_samples(t_end, dt_out) > MAX_SAMPLES:  # not a large platoon but an absurd grid: refuse, never thin
        if t_end / chunk + 1 > MAX_SAMPLES:
            raise ScenarioError(
                f"{file}: simulation.t_end = {t_end:g} is not allowed: the integrator samples "
                f"at least every {chunk:g} time units, {t_end / chunk:.3g} samples per follower, "
                f"more than {MAX_SAMPLES}; lower simulation.t_end to at most {MAX_SAMPLES * chunk:g}"
            )
        raise ScenarioError(
            f"{file}: simulation.dt_out = {dt_out:g} is not allowed: {n_samples(t_end, dt_out):.3g} "
            f"samples per follower over simulation.t_end = {t_end:g}, more than {MAX_SAMPLES}; raise "
            f"simulation.dt_out to at least {_round_up(t_end / (MAX_SAMPLES - 2)):.3g}"
        )
    limit = memory_limit_bytes()
    if estimate_run_bytes(n_followers, t_end, dt_out) <= limit:
        return dt_out
    k_max = limit / (BYTES_PER_SAMPLE * n_followers) - 2
    new = _round_up(t_end / math.floor(k_max)) if k_max >= MIN_SAMPLES else dt_out
    if k_max >= MIN_SAMPLES and new < SimOptions().chunk and estimate_run_bytes(n_followers, t_end, new) <= limit:
        warnings.warn(
            ScenarioWarning(
                f"{file}: simulation.dt_out raised from {dt_out:g} to {new:g} so that {n_followers} followers over "
                f"t_end = {t_end:g} fit in {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB; {_gb(estimate_run_bytes(n_followers, t_end, dt_out))} "
                f"were needed); ω, ∫Q and the RMS metrics are integrated by the solver and do not depend on dt_out, "
                f"min gap and min speed are taken from the coarser samples"
            ),
            stacklevel=3,
        )
        return new
    check_run_size(n_followers, t_end, dt_out, file)
    return dt_out  # pragma: no cover - check_run_size raised

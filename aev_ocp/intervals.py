"""Seeds and intervals: the mean of a metric over seeds with a 95 % interval, and a "better/worse"
verdict only when the interval of the difference excludes zero ("tie" otherwise).

Tables of runs with randomness (noise, sensor draws, SUMO's drivers) report :func:`summarize` of each metric over
their seeds (:data:`DEFAULT_SEEDS` by default) and :func:`compare` between controllers. Intervals by Student's t
(exact quantile, computed here from the regularized incomplete beta function: NumPy only, no SciPy at run time) or
by a percentile bootstrap with a seeded generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from .params import ParameterError

#: seeds a table with randomness runs by default (at least 10)
DEFAULT_SEEDS: tuple[int, ...] = tuple(range(10))
LEVEL = 0.95  # the intervals' confidence level


@dataclass(frozen=True)
class Interval:
    """Mean of n values and its interval [lo, hi] at ``level`` by ``method`` ('t' or 'bootstrap')."""

    mean: float
    lo: float
    hi: float
    n: int
    level: float
    method: str

    def excludes_zero(self) -> bool:
        """Whether 0 lies outside [lo, hi]."""
        return self.lo > 0.0 or self.hi < 0.0

    def as_dict(self) -> dict[str, float | int | str]:
        return {
            "mean": self.mean,
            "lo": self.lo,
            "hi": self.hi,
            "n": self.n,
            "level": self.level,
            "method": self.method,
        }


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz; Numerical Recipes §6.4)."""
    tiny, qab, qap, qam = 1e-300, a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 400):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    """The regularized incomplete beta function I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    ln = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    front = math.exp(ln)
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def t_cdf(t: float, df: float) -> float:
    """Student's t distribution function with ``df`` degrees of freedom."""
    x = df / (df + t * t)
    tail = 0.5 * _betainc(0.5 * df, 0.5, x)
    return 1.0 - tail if t > 0 else tail


def t_quantile(p: float, df: float) -> float:
    """The p-quantile of Student's t with ``df`` > 0 degrees of freedom (bisection on :func:`t_cdf`)."""
    if not (0.0 < p < 1.0) or not (df > 0 and math.isfinite(df)):
        raise ParameterError(f"t_quantile: p = {p!r} must be in (0, 1) and df = {df!r} finite and > 0")
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    lo, hi = 0.0, 1.0
    while t_cdf(hi, df) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-14 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)


def _values(x: Sequence[float] | np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float).ravel()
    if a.size < 2:
        raise ParameterError(f"{what}: needs at least 2 values (one per seed), got {a.size}")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"{what}: values must be finite, got {a.tolist()!r:.120}")
    return a


def summarize(
    x: Sequence[float] | np.ndarray,
    level: float = LEVEL,
    method: Literal["t", "bootstrap"] = "t",
    resamples: int = 10_000,
    seed: int = 0,
) -> Interval:
    """Mean of ``x`` (one value per seed) with its ``level`` interval: Student's t (mean ± t s/√n) or the
    percentile bootstrap of the mean (``resamples`` draws, generator seeded with ``seed``)."""
    a = _values(x, "summarize")
    if not 0.0 < level < 1.0:
        raise ParameterError(f"summarize: level = {level!r} is not allowed: must be in (0, 1)")
    n, m = a.size, float(a.mean())
    if method == "t":
        half = t_quantile(0.5 + 0.5 * level, n - 1) * float(a.std(ddof=1)) / math.sqrt(n)
        return Interval(m, m - half, m + half, n, level, "t")
    if method == "bootstrap":
        rng = np.random.default_rng(seed)
        means = a[rng.integers(0, n, size=(int(resamples), n))].mean(axis=1)
        lo, hi = np.quantile(means, [0.5 - 0.5 * level, 0.5 + 0.5 * level])
        return Interval(m, float(lo), float(hi), n, level, "bootstrap")
    raise ParameterError(f"summarize: method = {method!r} is not allowed: must be 't' or 'bootstrap'")


def difference(
    a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray, paired: bool = True, level: float = LEVEL
) -> Interval:
    """The interval of mean(a) − mean(b): paired (the same seeds, a t interval of a_i − b_i) or Welch's (independent
    samples, Welch–Satterthwaite degrees of freedom)."""
    x, y = _values(a, "difference: a"), _values(b, "difference: b")
    if paired:
        if x.size != y.size:
            raise ParameterError(
                f"difference: paired values need as many a as b (one per seed), got {x.size} and {y.size}"
            )
        return summarize(x - y, level)
    vx, vy = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    se = math.sqrt(vx + vy)
    df = (vx + vy) ** 2 / (vx**2 / (x.size - 1) + vy**2 / (y.size - 1)) if se > 0 else float(x.size + y.size - 2)
    m = float(x.mean() - y.mean())
    half = t_quantile(0.5 + 0.5 * level, df) * se
    return Interval(m, m - half, m + half, min(x.size, y.size), level, "welch")


def verdict(diff: Interval, lower_is_better: bool = True) -> str:
    """'better' / 'worse' for a (the first of :func:`difference`) when the interval of a − b excludes zero, else
    'tie'. ``lower_is_better``: whether a smaller metric is better (energy, heat, speed std)."""
    if not diff.excludes_zero():
        return "tie"
    return "better" if (diff.hi < 0.0) == lower_is_better else "worse"


def compare(
    a: Sequence[float] | np.ndarray,
    b: Sequence[float] | np.ndarray,
    lower_is_better: bool = True,
    paired: bool = True,
    level: float = LEVEL,
) -> dict[str, object]:
    """a against b over seeds: each one's mean and interval, the difference's, and the verdict (a table row)."""
    d = difference(a, b, paired, level)
    return {
        "a": summarize(a, level).as_dict(),
        "b": summarize(b, level).as_dict(),
        "difference": d.as_dict(),
        "verdict": verdict(d, lower_is_better),
    }

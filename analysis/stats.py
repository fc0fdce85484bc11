"""Small statistics shared by the analysis commands and the experiments."""

from __future__ import annotations

import dataclasses
import functools
import importlib
import itertools
import math
from collections.abc import Sequence
from types import ModuleType

import numpy as np
import polars as pl


@functools.cache
def _scipy(name: str) -> ModuleType:
    # imported by name on first use: one loader for the scipy modules vdc computes with
    return importlib.import_module(f"scipy.{name}")


def scipy_stats() -> ModuleType:
    """``scipy.stats``, imported on first use. It costs 0.6 s of CPU to import, which every
    command paid at start-up, most of them (the measuring ones) without computing a statistic:
    5 % of the test suite's CPU."""
    return _scipy("stats")


def scipy_special() -> ModuleType:
    """``scipy.special``, imported on first use: 0.55 s of CPU on its own (it loads scipy's
    compiled core), paid by every process that imported the boundary fit or the predictors'
    statistics, and by every pool worker of a campaign, before any fit."""
    return _scipy("special")


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman rank correlation (average ranks for ties) of the pairs as given (polars ranks a
    NaN as a value: :func:`analysis.predictors.statistics.finite_spearman` drops such pairs);
    NaN if either side is constant."""
    df = pl.DataFrame({"x": x, "y": y})
    if df["x"].n_unique() < 2 or df["y"].n_unique() < 2:
        return float("nan")
    return float(df.select(pl.corr("x", "y", method="spearman")).item())


# Claims across seeds (reproduce, collision-study): a claim "holds" only when it holds at this
# confidence across seeds, never on one run's point estimate.
CONFIDENCE = 0.95
ALPHA = 1.0 - CONFIDENCE
HOLDS, PARTLY, FAILS = "holds", "partly", "does not hold"


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A mean across seeds with its two-sided ``CONFIDENCE`` interval (Student's t); the
    interval is NaN with fewer than two finite values."""

    mean: float
    low: float
    high: float
    n: int

    def text(self, fmt: str = "{:.1f}", scale: float = 1.0) -> str:
        """``12.3 [10.1, 14.5]``; ``12.3 (n = 1)`` when there is no interval."""
        m = fmt.format(self.mean * scale)
        if not math.isfinite(self.low):
            return f"{m} (n = {self.n})"
        return f"{m} [{fmt.format(self.low * scale)}, {fmt.format(self.high * scale)}]"


def mean_ci(
    values: Sequence[float] | np.ndarray,
    confidence: float = CONFIDENCE,
    bounds: tuple[float, float] = (-math.inf, math.inf),
) -> Estimate:
    """Mean and t-interval of the finite ``values`` (one per seed), the interval clipped to
    the quantity's possible range ``bounds`` (a share cannot leave [0, 1]: with few seeds the
    t-interval of a share near 0 or 1 reaches past it)."""

    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    n = len(v)
    if n == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    mean = float(v.mean())
    if n < 2:
        return Estimate(mean, math.nan, math.nan, n)
    half = float(scipy_stats().t.ppf(0.5 + confidence / 2, n - 1) * v.std(ddof=1) / math.sqrt(n))
    lo, hi = bounds
    return Estimate(mean, max(lo, mean - half), min(hi, mean + half), n)


def share_ci(
    successes: Sequence[int] | np.ndarray,
    trials: Sequence[int] | np.ndarray,
    confidence: float = CONFIDENCE,
) -> Estimate:
    """A share (e.g. the success rate) across seeds: the mean of the per-seed shares, with the
    wider of their t-interval (spread between seeds) and the exact Clopper–Pearson interval
    of the pooled counts (counting noise within runs). Seeds that all score 100 % on a few
    events would otherwise give a zero-width interval."""

    k = np.asarray(successes, dtype=np.int64)
    n = np.asarray(trials, dtype=np.int64)
    keep = n > 0
    k, n = k[keep], n[keep]
    if len(n) == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    between = mean_ci(k / n, confidence, (0.0, 1.0))
    pooled = (
        scipy_stats()
        .binomtest(int(k.sum()), int(n.sum()))
        .proportion_ci(confidence, method="exact")
    )
    if not math.isfinite(between.low):
        return Estimate(between.mean, pooled.low, pooled.high, between.n)
    return Estimate(
        between.mean, min(between.low, pooled.low), max(between.high, pooled.high), between.n
    )


def condition_share_bounds(
    x: Sequence[float], k: Sequence[float], n: Sequence[float], phi: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per condition (runs at one complexity): (complexity, lower, upper) 95 % bounds of its
    success that count the spread between its seeds: :func:`analysis.stats.share_ci` (the
    wider of the seeds' t-interval and the pooled exact interval); a lone run, whose seed
    spread cannot be seen, the exact interval of its counts divided by the fit's dispersion
    ``phi`` (its effective number of trials). One run's exact bound alone made a seed that
    differed by chance "clearly fail"."""

    x_a, k_a, n_a = (np.asarray(v, float) for v in (x, k, n))
    ok = n_a > 0
    xs, lows, highs = [], [], []
    for c in np.unique(x_a[ok]):
        sel = ok & (x_a == c)
        if sel.sum() >= 2:
            e = share_ci(k_a[sel].astype(int), n_a[sel].astype(int))
            lo, hi = e.low, e.high
        else:
            kk, nn = k_a[sel][0] / phi, n_a[sel][0] / phi
            lo = 0.0 if kk <= 0 else float(scipy_stats().beta.ppf(0.025, kk, nn - kk + 1))
            hi = 1.0 if kk >= nn else float(scipy_stats().beta.ppf(0.975, kk + 1, nn - kk))
        xs.append(c)
        lows.append(lo)
        highs.append(hi)
    return np.array(xs), np.array(lows), np.array(highs)


@dataclasses.dataclass(frozen=True)
class Trend:
    """A one-sided test that a quantity rises along ordered conditions, seeds as blocks."""

    p_value: float
    method: str
    n: int  # seeds (blocks) used
    min_p: float  # the smallest p-value this test can give with n seeds

    def text(self) -> str:
        note = (
            f"; with {self.n} seeds this test cannot reach p < {ALPHA:g}"
            if self.min_p >= ALPHA
            else ""
        )
        return f"{self.method}, p = {self.p_value:.3g}{note}"


def rising_trend(table: np.ndarray) -> Trend:
    """Test ``table`` (n_seeds, k_conditions), conditions in their stated order, for a rise.

    The same seed drives the same trajectory in every condition of an open-loop profiling run
    (the walls only drift), so seeds are blocks: Page's L test (exact for small tables) for
    k ≥ 3 conditions, the sign test of the paired differences for k = 2. Rows with a NaN are
    dropped."""

    t = np.asarray(table, dtype=np.float64)
    t = t[np.isfinite(t).all(axis=1)]
    n, k = t.shape
    if n == 0 or k < 2:
        return Trend(math.nan, "no complete seeds", n, 1.0)
    if k == 2:
        d = t[:, 1] - t[:, 0]
        d = d[d != 0]
        if len(d) == 0:
            return Trend(1.0, "sign test", n, 0.5**n)
        res = scipy_stats().binomtest(int((d > 0).sum()), len(d), 0.5, alternative="greater")
        return Trend(float(res.pvalue), "sign test", n, 0.5**n)
    if n < 2:
        return Trend(math.nan, "Page's L test needs 2 seeds", n, 1.0)
    res = scipy_stats().page_trend_test(t)
    return Trend(float(res.pvalue), "Page's L test", n, float(math.factorial(k)) ** -n)


def trend_verdict(means: Sequence[float], trend: Trend) -> str:
    """Holds: the means rise strictly and the test is significant; partly: one of the two;
    does not hold: neither."""
    rising = len(means) >= 2 and all(b > a for a, b in itertools.pairwise(means))
    significant = math.isfinite(trend.p_value) and trend.p_value < ALPHA
    if rising and significant:
        return HOLDS
    return PARTLY if rising or significant else FAILS


def above_verdict(est: Estimate, threshold: float) -> str:
    """Holds: the whole interval is above ``threshold``; partly: only the mean is (or there is
    no interval); does not hold: the mean is not."""
    if math.isfinite(est.low) and est.low > threshold:
        return HOLDS
    return PARTLY if est.mean > threshold else FAILS


def below_verdict(est: Estimate, threshold: float) -> str:
    """The mirror of :func:`above_verdict`."""
    if math.isfinite(est.high) and est.high < threshold:
        return HOLDS
    return PARTLY if est.mean < threshold else FAILS


def combine(verdicts: Sequence[str]) -> str:
    """A claim made of parts: holds if every part holds, does not hold if none even partly
    does, partly otherwise."""
    if verdicts and all(v == HOLDS for v in verdicts):
        return HOLDS
    if all(v == FAILS for v in verdicts):
        return FAILS
    return PARTLY

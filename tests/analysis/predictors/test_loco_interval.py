"""The held-out balanced accuracy's interval (issue 43: intervals on every bar that estimates).

Truths come from a population the statistic never sees (``analysis.predictors.synthetic``);
the full table, with the Beta-posterior reference, is ``benchmarks/bench_loco_interval.py``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest

from analysis.predictors.held_out import loco_bootstrap, loco_interval, loco_threshold
from analysis.predictors.synthetic import conditions, loco_truth


class _Identity:
    """A 'resample' that draws every condition once: the bootstrap's fold logic must then
    reproduce the statistic itself."""

    def multinomial(self, n: int, p: np.ndarray, size: int) -> np.ndarray:
        return np.ones((size, len(p)), int)


def test_an_unresampled_draw_is_the_statistic_itself() -> None:
    rng = np.random.default_rng(4)
    for _ in range(200):
        n = int(rng.integers(4, 30))
        x = np.round(rng.normal(size=n), 1)  # ties too
        fails = rng.random(n) < rng.uniform(0.2, 0.8)
        if min(fails.sum(), (~fails).sum()) < 2:
            continue
        got = loco_bootstrap(x, fails, _Identity(), 1)  # type: ignore[arg-type]
        assert got[0] == pytest.approx(loco_threshold(x, fails), abs=1e-12)  # one sum's rounding


@pytest.mark.parametrize(
    "n, beta",
    [(24, 0.0), (24, 30.0), (12, 3.0)],
    ids=["unrelated measure", "near separation", "few conditions"],
)
def test_the_interval_covers_known_truths(n: int, beta: float) -> None:
    rng = np.random.default_rng(int(n * 100 + beta))
    truth = loco_truth(n, beta, -1.0, rng, training_sets=1000)
    hits = k = 0
    while k < 120:
        x, fails = conditions(n, beta, -1.0, rng)
        if min(fails.sum(), (~fails).sum()) < 2:
            continue
        k += 1
        lo, hi = loco_interval(x, fails, rng, 300)
        assert lo <= loco_threshold(x, fails) + 0.25 and hi >= loco_threshold(x, fails) - 0.25
        hits += lo <= truth <= hi
    # the interval is conservative (92-100 % in the benchmark): it must reach 95 %; 120 draws
    # at a true 95 % fall below 90 % with probability under 1 %
    assert binomtest(hits, k).proportion_ci(0.98).high >= 0.95, f"{hits} of {k}"
    assert hits / k >= 0.90, f"{hits} of {k}"


def test_separated_classes_keep_a_width() -> None:
    """Perfect separation must not give [1, 1] (issue 42's complaint about AUROC)."""
    x = np.concatenate([np.arange(10.0), np.arange(20.0, 30.0)])  # a wide gap
    fails = x >= 20
    lo, hi = loco_interval(x, fails, np.random.default_rng(0))
    assert loco_threshold(x, fails) == 1.0 and lo < 0.95 and hi == 1.0

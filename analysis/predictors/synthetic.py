"""Known truths for the held-out balanced accuracy's interval (its coverage benchmark and test).

Conditions carry a measure x ~ N(0, 1) and fail with probability logistic(alpha + beta x):
beta = 0 is a measure unrelated to failure, a large beta separates the classes. The truth that
:func:`analysis.predictors.statistics.loco_threshold` estimates on N conditions is the
balanced accuracy on new conditions of a threshold fitted on N - 1 of them, averaged over
training sets: :func:`loco_truth`, by simulation against a large population."""

from __future__ import annotations

import numpy as np

from analysis.predictors.held_out import fit_thresholds


def conditions(
    n: int, beta: float, alpha: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """x (n,) float and fails (n,) bool of ``n`` conditions drawn from the population."""
    x = rng.normal(size=n)
    return x, rng.random(n) < 1.0 / (1.0 + np.exp(-(alpha + beta * x)))


def loco_truth(
    n: int,
    beta: float,
    alpha: float,
    rng: np.random.Generator,
    training_sets: int = 2000,
    population: int = 200_000,
) -> float:
    """The expected balanced accuracy, on the population, of the threshold
    :func:`fit_thresholds` fits on ``n - 1`` conditions (training sets without both classes
    are left out: the statistic is refused on them)."""
    xp, fp = conditions(population, beta, alpha, rng)
    fail_x, pass_x = np.sort(xp[fp]), np.sort(xp[~fp])
    x, f = conditions(training_sets * (n - 1), beta, alpha, rng)
    x, f = x.reshape(training_sets, n - 1), f.reshape(training_sets, n - 1)
    both = f.any(1) & ~f.all(1)
    t = fit_thresholds(x[both], f[both])
    sens = 1.0 - np.searchsorted(fail_x, t, side="right") / len(fail_x)
    spec = np.searchsorted(pass_x, t, side="right") / len(pass_x)
    return float(np.mean((sens + spec) / 2))

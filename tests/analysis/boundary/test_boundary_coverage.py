"""Coverage of the fitted boundary's 95 % interval (:func:`analysis.boundary.fit.fit_crossing`)
on three known truths, 200 repeats each (issue 42): no extra variation; seeds that differ
more than binomially (a per-run effect, sd 0.4 on the log-odds); and whole conditions that
depart from the curve (a per-condition effect, sd 0.5 on the log-odds, shared by every seed
of the condition, as LGMD+'s scenes do). Each must cover in at least 90 % of the repeats whose
interval is bounded; undetermined intervals are counted apart (they claim nothing). 200
repeats: a binomial standard error of 1.5 points at 95 %. The fit without the condition's
dispersion covered 35-65 % under the third truth, with grid-snapped ends 69 %."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special

from analysis.boundary.fit import fit_crossing

TARGET = 0.9
TRUTH = 16.0  # deg/s: where the population curve crosses the target
DOMAIN = (4.0, 30.0)
REPEATS = 200


def campaign(rng, run_sd=0.0, condition_sd=0.0, conditions=6, seeds=4, slope=0.3):
    """An arena-like grid: ``conditions`` complexities over the domain, ``seeds`` runs each of
    60-140 approaches; logit p = logit(target) - slope (x - truth) + the effects."""
    xc = np.linspace(*DOMAIN, conditions)
    x = np.repeat(xc, seeds)
    n = rng.integers(60, 140, x.size)
    eta = (
        scipy.special.logit(TARGET)
        - slope * (x - TRUTH)
        + np.repeat(rng.normal(0, condition_sd, conditions), seeds)
        + rng.normal(0, run_sd, x.size)
    )
    return x, rng.binomial(n, scipy.special.expit(eta)), n


@pytest.mark.parametrize(
    ("truth", "effects"),
    [("none", {}), ("per run", {"run_sd": 0.4}), ("per condition", {"condition_sd": 0.5})],
)
def test_the_boundary_interval_covers_under_each_truth(truth, effects) -> None:
    rng = np.random.default_rng(42)
    covered = bounded = 0
    widths = []
    for _ in range(REPEATS):
        x, k, n = campaign(rng, **effects)
        fit = fit_crossing(x, k, n, TARGET, DOMAIN, band=False)
        if fit.state != "within":
            continue
        bounded += 1
        covered += fit.low <= TRUTH <= fit.high
        widths.append(fit.width)
    cover = covered / max(bounded, 1)
    print(
        f"boundary, {truth}: coverage {cover:.3f} of {bounded} bounded intervals "
        f"({REPEATS - bounded} undetermined), median width {np.median(widths):.1f} deg/s"
    )
    assert bounded >= REPEATS // 2  # the design can place it: the test is not vacuous
    assert cover >= 0.90


def test_a_scene_that_departs_widens_the_interval() -> None:
    """The same counts, once with every run its own condition and once as 6 conditions of 4
    seeds whose departures are shared: the condition's dispersion widens the interval."""
    rng = np.random.default_rng(3)
    x, k, n = campaign(rng, condition_sd=0.8)
    as_runs = fit_crossing(x, k, n, TARGET, DOMAIN, np.arange(x.size), band=False)
    as_conditions = fit_crossing(x, k, n, TARGET, DOMAIN, band=False)
    assert as_conditions.dispersion > as_runs.dispersion
    assert as_conditions.width > as_runs.width


def test_interval_ends_are_interpolated_not_grid_points() -> None:
    rng = np.random.default_rng(8)
    x, k, n = campaign(rng)
    fit = fit_crossing(x, k, n, TARGET, DOMAIN, band=False)
    step = fit.t_grid[1] - fit.t_grid[0]
    off = [
        abs((v - fit.t_grid[0]) / step - round((v - fit.t_grid[0]) / step))
        for v in (fit.low, fit.high)
    ]
    assert max(off) > 1e-6  # an end between grid points (both on one by chance: ~1e-12)

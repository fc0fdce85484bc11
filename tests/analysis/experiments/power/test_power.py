"""The plan's sample sizes (analysis.experiments.power.sizes), checked by simulation: at the n they
give, the test they stand for rejects about ``power`` of the time."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm, rankdata

from analysis.experiments.power.sizes import (
    auroc_difference_power,
    clips_for_auroc_difference,
    conditions_for_correlation_difference,
)

REPEATS = 2000  # a simulated power of 0.8 has a binomial SE of 0.009


def meng_z(r1: np.ndarray, r2: np.ndarray, r12: np.ndarray, n: int) -> np.ndarray:
    r2bar = (r1**2 + r2**2) / 2
    f = np.minimum(1.0, (1 - r12) / (2 * (1 - r2bar)))
    h = (1 - f * r2bar) / (1 - r2bar)
    return (np.arctanh(r1) - np.arctanh(r2)) * np.sqrt((n - 3) / (2 * (1 - r12) * h))


def test_the_reference_sizes_for_two_dependent_correlations() -> None:
    """Separating rho 0.71 from 0.31 (the method's pair) needs about 24-47 conditions as the
    two measures correlate 0.7-0.3 (Steiger 1980's test; the issue's figures)."""
    assert conditions_for_correlation_difference(0.71, 0.31, 0.7) == pytest.approx(24, abs=1)
    assert conditions_for_correlation_difference(0.71, 0.31, 0.3) == pytest.approx(47, abs=1)


@pytest.mark.parametrize("rho12", [0.3, 0.7])
def test_the_conditions_reach_the_power_in_simulation(rho12: float) -> None:
    """Pearson correlations of trivariate normal conditions; the two-sided 5 % test at the n
    given rejects at least 0.8 of the time (less 0.03: 3 SE of 2000 repeats) and not much
    more: the formula is conservative where the measures correlate strongly (measured 0.90 at
    rho12 0.7, n 23; 0.8 at 0.3, n 45), so it is held to at most 0.92."""
    n = conditions_for_correlation_difference(0.71, 0.31, rho12, spearman=False)
    cov = np.array([[1, 0.71, 0.31], [0.71, 1, rho12], [0.31, rho12, 1]])
    rng = np.random.default_rng(5)
    x = rng.multivariate_normal(np.zeros(3), cov, size=(REPEATS, n))
    c = np.einsum("rni,rnj->rij", x - x.mean(1, keepdims=True), x - x.mean(1, keepdims=True))
    d = np.sqrt(np.einsum("rii->ri", c))
    r = c / d[:, :, None] / d[:, None, :]
    z = meng_z(r[:, 0, 1], r[:, 0, 2], r[:, 1, 2], n)
    rejected = np.mean(np.abs(z) > norm.ppf(0.975))
    assert 0.77 <= rejected <= 0.92, (n, rejected)


def delong_z(m1: np.ndarray, m2: np.ndarray, fail: np.ndarray) -> float:
    """DeLong's paired z for the AUROCs of measures ``m1``, ``m2`` (a higher measure: a
    failure more likely)."""
    comps = []
    for m in (m1, m2):
        pos, neg = m[fail], m[~fail]
        both = rankdata(np.concatenate([pos, neg]))
        v10 = (both[: len(pos)] - rankdata(pos)) / len(neg)  # placement of each failure
        v01 = 1 - (both[len(pos) :] - rankdata(neg)) / len(pos)
        comps.append((v10.mean(), v10, v01))
    (a1, p1, q1), (a2, p2, q2) = comps
    s10 = np.cov(np.stack([p1, p2]))
    s01 = np.cov(np.stack([q1, q2]))
    var = (s10[0, 0] + s10[1, 1] - 2 * s10[0, 1]) / len(p1) + (
        s01[0, 0] + s01[1, 1] - 2 * s01[0, 1]
    ) / len(q1)
    return (a1 - a2) / math.sqrt(var)


def test_the_clips_reach_the_power_in_simulation() -> None:
    """Binormal clips (AUROC 0.75 against 0.66, the measures correlated 0.6 within each class,
    40 % failing): at the clips the Hanley-McNeil variance asks for, given the correlation of
    the two AUROC estimates measured in the same simulation, DeLong's test rejects at the
    predicted rate within 0.06 (Hanley-McNeil's variance is exact for exponential, not
    binormal, scores: a few points apart)."""
    auc1, auc2, share, rho = 0.75, 0.66, 0.4, 0.6
    mu1, mu2 = math.sqrt(2) * norm.ppf(auc1), math.sqrt(2) * norm.ppf(auc2)
    clips, failures = clips_for_auroc_difference(auc1, auc2, 0.5, share)
    assert 100 < clips < 1000 and failures == round(clips * share)
    rng = np.random.default_rng(11)
    fail = np.arange(clips) < failures
    cov = np.array([[1, rho], [rho, 1]])
    zs, a = [], []
    for _ in range(600):  # DeLong per repeat is the cost: 600 keep it a few seconds
        m = rng.multivariate_normal([0, 0], cov, size=clips)
        m[fail] += [mu1, mu2]
        zs.append(delong_z(m[:, 0], m[:, 1], fail))
        a.append([np.mean(m[fail, k][:, None] > m[~fail, k][None, :]) for k in (0, 1)])
    a = np.array(a)
    r_auc = float(np.corrcoef(a[:, 0], a[:, 1])[0, 1])
    predicted = auroc_difference_power(auc1, auc2, r_auc, clips, share)
    rejected = float(np.mean(np.abs(zs) > norm.ppf(0.975)))
    assert rejected == pytest.approx(predicted, abs=0.06), (clips, r_auc, predicted, rejected)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match="rho1 equals rho2"):
        conditions_for_correlation_difference(0.5, 0.5, 0.3)
    with pytest.raises(ValueError, match="AUROCs must differ"):
        clips_for_auroc_difference(0.7, 0.7, 0.5, 0.4)


def test_footage_outcomes_score_the_failure_modes_apart() -> None:
    from analysis.experiments.power.sizes import footage_outcome

    fps, onset, contact = 25.0, 50, 149
    alert = np.zeros(150)

    def at(frame: int) -> np.ndarray:
        a = alert.copy()
        a[frame:] = 1
        return a

    assert footage_outcome(at(40), fps, contact, onset) == "early alert"
    assert footage_outcome(at(100), fps, contact, onset) == "hit"
    # 0.5 s at 25 fps = 12.5 frames: frame 136 leaves 13 frames (0.52 s), 137 only 0.48 s
    assert footage_outcome(at(136), fps, contact, onset) == "hit"
    assert footage_outcome(at(137), fps, contact, onset) == "miss"
    assert footage_outcome(alert, fps, contact, onset) == "miss"
    assert footage_outcome(at(100), fps, None, onset) == "false alarm"
    assert footage_outcome(alert, fps, None, onset) == "correct rejection"
    assert footage_outcome(at(100), fps, None, None) == "early alert"  # nothing ever in view


def test_the_design_effect_of_scenes_against_a_simulated_mean() -> None:
    """Units in scenes of m with a scene effect of variance ICC (total 1): the variance of the
    mean of G m units is DE / (G m), DE = 1 + (m - 1) ICC (Kish), checked on 4000 simulated
    samples (the variance ratio's SE is about 2.2 %; 0.08 is 3.5 SE)."""
    from analysis.experiments.power.sizes import design_effect

    rng = np.random.default_rng(11)
    g, m, icc = 20, 6, 0.3
    scene = rng.normal(0, math.sqrt(icc), (4000, g, 1))
    units = scene + rng.normal(0, math.sqrt(1 - icc), (4000, g, m))
    ratio = units.mean(axis=(1, 2)).var() * g * m
    assert ratio == pytest.approx(design_effect(m, icc), rel=0.08)
    assert design_effect(1, 0.9) == 1.0 and design_effect(m, 0.0) == 1.0


def test_scenes_and_units_per_scene_for_the_amended_plan() -> None:
    """The amended plan's sizes (docs/findings/power_plan_amendment.md): arena, the 37
    independent conditions of rho 0.71 against 0.31 (measures correlated 0.5) from 23 scenes
    of 3 TFs hold up to ICC 0.43; footage, 229 independent clips from 21 photographs need 23
    clips each at ICC 0.05 (483 clips) and cannot be had at ICC 0.1 (21 / 0.1 = 210 < 229)."""
    from analysis.experiments.power.sizes import effective_units, per_scene_for, scenes_for

    arena = conditions_for_correlation_difference(0.71, 0.31, 0.5)
    assert arena == 37
    assert effective_units(23, 3, 0.43) >= arena > effective_units(23, 3, 0.45)
    assert scenes_for(arena, 3, 0.5) == 25 and scenes_for(24, 3, 0.3) == 20  # the floor
    clips = clips_for_auroc_difference(0.75, 0.66, 0.6, 0.4)[0]
    assert clips == 229
    m = per_scene_for(clips, 21, 0.05)
    assert m == 23 and effective_units(21, m, 0.05) >= clips > effective_units(21, m - 1, 0.05)
    assert per_scene_for(clips, 21, 0.1) is None
    assert per_scene_for(10, 21, 0.5) == 1

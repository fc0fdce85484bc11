"""The held-out balanced accuracy (statistic ``loco_balanced_accuracy`` of
:mod:`analysis.predictors.statistics`) and its interval over conditions.

Each condition's "fails the target" is predicted by a threshold on the measure fitted on the
other conditions (:func:`loco_threshold`); the interval (:func:`loco_interval`) is the union
of a bootstrap of the conditions, each held out with all its copies, and a Beta posterior of
the held-out counts; its coverage on known truths: ``benchmarks/bench_loco_interval.py``."""

from __future__ import annotations

import math

import numpy as np

from analysis.predictors.inference import BOOTSTRAP
from analysis.stats import ALPHA


def balanced_accuracy(predicted: np.ndarray, truth: np.ndarray) -> float:
    """(sensitivity + specificity) / 2; NaN without both classes in ``truth``."""
    p, t = np.asarray(predicted, bool), np.asarray(truth, bool)
    return float(_balanced(p[None], t[None])[0])


def _balanced(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Balanced accuracy along the last axis of boolean arrays (broadcast): NaN without both
    classes."""
    pos = truth.sum(-1)
    neg = truth.shape[-1] - pos
    tp = (pred & truth).sum(-1)
    tn = (~pred & ~truth).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((pos > 0) & (neg > 0), (tp / pos + tn / neg) / 2, math.nan)


def loco_threshold(x: np.ndarray, fails: np.ndarray) -> float:
    """Leave-one-condition-out: each unit predicted by the threshold fitted on the others;
    the balanced accuracy of those predictions. x (N,) float, fails (N,) bool."""
    x, fails = np.asarray(x, float), np.asarray(fails, bool)
    ok = np.isfinite(x)
    return float(loco_rows(x[None, ok], fails[None, ok])[0])


def loco_rows(x: np.ndarray, fails: np.ndarray) -> np.ndarray:
    """:func:`loco_threshold` of each row of x, fails (B, N) at once: (B,).

    On the training units the threshold t ("x > t fails") is the one of best balanced
    accuracy among the midpoints between sorted values (and beyond both ends), the middle
    of the best ones on a tie; all training units failing: everything fails (and the
    reverse)."""
    if x.shape[1] < 3:
        return np.full(x.shape[0], math.nan)
    return _balanced(loco_predictions(x, fails), fails)


def loco_predictions(x: np.ndarray, fails: np.ndarray) -> np.ndarray:
    """Each unit's held-out prediction ("fails"), from the threshold fitted on the others:
    x, fails (B, N) -> (B, N) bool."""
    b, n = x.shape
    pred = np.zeros((b, n), bool)
    for i in range(n):
        rest = np.arange(n) != i
        xr, fr = x[:, rest], fails[:, rest]
        p = x[:, i] > fit_thresholds(xr, fr)
        pred[:, i] = np.where(fr.all(1), True, np.where(~fr.any(1), False, p))
    return pred


def fit_thresholds(x: np.ndarray, fails: np.ndarray) -> np.ndarray:
    """The threshold t ("x > t fails") of best balanced accuracy on each row of x, fails
    (B, N): among the midpoints between sorted values and beyond both ends, the middle of the
    best ones on a tie. (B,) float."""
    xs = np.sort(x, axis=1)
    cands = np.concatenate([xs[:, :1] - 1.0, (xs[:, 1:] + xs[:, :-1]) / 2, xs[:, -1:] + 1.0], 1)
    ba = _balanced(x[:, None, :] > cands[:, :, None], fails[:, None, :])  # (B, C)
    ba = np.where(np.isfinite(ba), ba, -1.0)
    return cands[np.arange(len(x)), _middle_of_best(ba)]


def _middle_of_best(ba: np.ndarray) -> np.ndarray:
    """Per row of ``ba`` (B, C), the column in the middle of those tied for the best; equal
    balanced accuracies reached by different sums differ in their last bit, so a tie is
    within 1e-12. (B,) int."""
    tie = ba >= ba.max(1, keepdims=True) - 1e-12
    k = tie.sum(1) // 2
    return np.argmax(np.cumsum(tie, 1) > k[:, None], axis=1)


def loco_bootstrap(
    x: np.ndarray,
    fails: np.ndarray,
    rng: np.random.Generator,
    n_boot: int = BOOTSTRAP,
    cluster: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`loco_threshold` on ``n_boot`` resamples of the conditions, (n_boot,) finite.

    Conditions are drawn with replacement; each distinct condition is then held out with all
    its copies (a copy left in training would predict itself), its threshold fitted on the
    others as in :func:`loco_rows` (midpoints between the training values, the middle of tied
    best ones), and the balanced accuracy weighs each condition by its copies. x (N,) float
    (finite), fails (N,) bool. Resamples without both classes are left out. With ``cluster``
    (N,) labels (the conditions' scenes) the scenes are drawn instead, each condition weighed
    by its scene's draws (conditions that share a scene are not independent)."""
    order = np.argsort(x, kind="stable")
    x, fails = np.asarray(x, float)[order], np.asarray(fails, bool)[order]
    n = len(x)
    if cluster is None:
        w_all = rng.multinomial(n, np.full(n, 1 / n), size=n_boot).astype(float)  # (B, N)
    else:
        _, inv = np.unique(np.asarray(cluster)[order], return_inverse=True)
        k = int(inv.max()) + 1
        w_all = rng.multinomial(k, np.full(k, 1 / k), size=n_boot)[:, inv].astype(float)
    pred = np.zeros((n_boot, n), bool)
    rows = np.arange(n_boot)
    for i in range(n):
        w = w_all.copy()
        w[:, i] = 0.0
        wf, wp = w * fails, w * ~fails
        nf, np_ = wf.sum(1), wp.sum(1)
        # cut k: units k.. predicted failing (k = n: none); training BA at every cut
        tp = np.concatenate([np.cumsum(wf[:, ::-1], 1)[:, ::-1], np.zeros((n_boot, 1))], 1)
        tn = np.concatenate([np.zeros((n_boot, 1)), np.cumsum(wp, 1)], 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            ba = (tp / nf[:, None] + tn / np_[:, None]) / 2
        # the distinct thresholds: midway between a training unit and the one below it (or
        # beyond both ends), as loco_rows' midpoints; a cut beside a unit not in training
        # would repeat its neighbour's
        canonical = np.concatenate([w > 0, np.ones((n_boot, 1), bool)], 1)  # (B, N + 1)
        below = np.where(w > 0, np.arange(n), -1)
        below = np.maximum.accumulate(np.concatenate([np.full((n_boot, 1), -1), below], 1), 1)
        hi_x = np.concatenate([np.broadcast_to(x, (n_boot, n)), np.full((n_boot, 1), np.inf)], 1)
        lo_x = np.where(below >= 0, x[np.maximum(below, 0)], -np.inf)
        with np.errstate(invalid="ignore"):
            t = np.where(
                np.isinf(lo_x), hi_x - 1.0, np.where(np.isinf(hi_x), lo_x + 1.0, (lo_x + hi_x) / 2)
            )
        # a threshold fails the units above it: tied values fall on one side together
        ba = np.take_along_axis(ba, np.searchsorted(x, t, side="right"), 1)
        ba = np.where(canonical & np.isfinite(ba), ba, -1.0)
        cut = _middle_of_best(ba)
        p = x[i] > t[rows, cut]
        pred[:, i] = np.where(np_ == 0, True, np.where(nf == 0, False, p))
    wf, wp = w_all * fails, w_all * ~fails
    with np.errstate(invalid="ignore", divide="ignore"):
        ba = ((wf * pred).sum(1) / wf.sum(1) + (wp * ~pred).sum(1) / wp.sum(1)) / 2
    return ba[np.isfinite(ba)]


def loco_interval(
    x: np.ndarray,
    fails: np.ndarray,
    rng: np.random.Generator,
    n_boot: int = BOOTSTRAP,
    cluster: np.ndarray | None = None,
) -> tuple[float, float]:
    """95 % interval of :func:`loco_threshold` over conditions: the union of the percentile
    interval of :func:`loco_bootstrap` and a Beta posterior of the held-out counts
    (sensitivity and specificity each Beta(k + 1/2, n - k + 1/2), their mean's central 95 %;
    Brodersen et al. 2010). The posterior alone covers too little (83-95 % on known truths):
    the held-out predictions share their thresholds. The bootstrap alone collapses to [1, 1]
    where the classes separate, as every resample separates too. Their union is conservative,
    98-100 % and about 1.1-1.6x the posterior's width (``benchmarks/bench_loco_interval.py``).
    ``cluster``: the conditions' scenes, resampled in place of the conditions."""
    ok = np.isfinite(x)
    x, fails = np.asarray(x, float)[ok], np.asarray(fails, bool)[ok]
    cl = None if cluster is None else np.asarray(cluster)[ok]
    boot = loco_bootstrap(x, fails, rng, n_boot, cl)
    if len(boot) < n_boot // 2:
        return math.nan, math.nan
    lo, hi = np.quantile(boot, [ALPHA / 2, 1 - ALPHA / 2])
    post_lo, post_hi = posterior_interval(x, fails, rng)
    return float(min(lo, post_lo)), float(max(hi, post_hi))


def posterior_interval(
    x: np.ndarray, fails: np.ndarray, rng: np.random.Generator
) -> tuple[float, float]:
    """The held-out predictions' sensitivity and specificity as independent Beta(k + 1/2,
    n - k + 1/2) posteriors; their mean's central 95 % (4000 draws). x (N,) finite, fails (N,)."""
    pred = loco_predictions(x[None], fails[None])[0]
    tp, fn = int((pred & fails).sum()), int((~pred & fails).sum())
    tn, fp = int((~pred & ~fails).sum()), int((pred & ~fails).sum())
    post = (rng.beta(tp + 0.5, fn + 0.5, 4000) + rng.beta(tn + 0.5, fp + 0.5, 4000)) / 2
    lo, hi = np.quantile(post, [ALPHA / 2, 1 - ALPHA / 2])
    return float(lo), float(hi)

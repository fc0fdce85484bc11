"""Which complexity measure predicts where a detector breaks (issues 32, 42, 57).

``vdc-analyse boundary`` finds where a detector's success falls; this module asks which of the
complexity measures vdc computes (:data:`MEASURES`) orders the cases as the detector fails
them. One table, ``predictors.parquet``, one row per measure, parameter value and statistic
(:data:`PREDICTOR_COLUMNS`): the estimate, its 95 % interval, ``n`` (the conditions, clips or
frames the statistic used), ``n_failing`` and ``n_correct`` (those the detector fails and gets
right: conditions below and at or above the target, clips, frames), ``unit`` and ``n_units``
(what the interval resamples or clusters on, and how many), and for comparisons ``p_value``,
``p_holm``, ``role``, ``survives`` and ``verdict``.

**The scene is the unit** (issue 57). Clips that share a photograph, place or session, and
arena conditions that share a wall scene, share that scene's effect on the measures and on
the failures: they are not independent, and an interval over them as if they were is too
narrow (on null truths with a photograph effect of sd 0.5, 8 photographs x 60 clips covered
89 % and gave 10.5 % false verdicts; sd 1: 61 % and 39 %). So every interval and p over clips
or conditions is over the scenes: ``unit`` is ``scene`` and ``n_units`` the scenes, where the
labels name each clip's ``scene`` (footage) or the runs their wall scene (arena) and there are
at least two; else ``unit`` is ``clip`` or ``condition``, taken as independent, and
:func:`table_note` says so in one line. Why these methods
(:mod:`analysis.predictors.inference`):

* AUROCs and their paired differences: Obuchowski's (1997) clustered DeLong variance (the
  scenes' summed placement values; DeLong's with clusters of one), or the delete-one-scene
  jackknife's where wider (it is, with few scenes: it errs wide where Obuchowski's errs
  narrow); analytic, no resampling.
* Spearman ρ over conditions: a cluster bootstrap (scenes drawn with replacement, each with all
  its conditions; resampling the top stage alone carries the variance of everything below it:
  Davison & Hinkley 1997, §3.8; Field & Welsh 2007). A permutation of conditions is not valid
  when conditions share a scene.
* Means of per-unit values (held-out losses, within-clip AUROCs): the cluster-robust variance.
* With few clusters a normal reference over-rejects (Cameron, Gelbach & Miller 2008; Cameron &
  Miller 2015): every clustered interval and test is referred to t on scenes − 1 degrees of
  freedom, at any number of scenes (it tends to the normal as they grow).

Arena (:mod:`analysis.predictors.arena`): ``rho_failure`` (Spearman ρ between the measure and
the failure rate, 1 − success, across conditions; p one-sided, a higher measure with more
failure) and
``loco_balanced_accuracy`` ("fails the target" predicted for each condition by a threshold on
the measure fitted on the others; refused below 2 failing or 2 passing conditions).

Footage: ``clip_auroc`` (the AUROC of the clip's measure for a clip the detector gets wrong);
with a ``failure`` column, ``clip_auroc_miss``, ``clip_auroc_early`` and
``clip_auroc_false_alarm`` score the failure modes apart (:data:`FAILURE_MODES`; their
``n_correct`` counts the correct clips of the class each is told from);
``frame_auroc_pooled`` (frames clustered by scene, or by clip without scenes) and
``frame_auroc_within_clip`` (the mean of the clips' own; frames counted): frames where the
detector alerts with no collision near against quiet frames
(:func:`analysis.boundary.footage_predictors.frame_classes`).

Both modes: ``paired_<statistic>_vs_<avdm>`` (the AVDM's statistic minus the measure's, same
units), and ``cv_logloss`` / ``cv_logloss_gain_vs_si_p910+ti_p910`` (a ridge-logistic model of
the failure rate on sets of measures, :data:`COMBINED`, each scene, or unit, held out).

**Verdicts** (:mod:`analysis.predictors.verdicts`). One comparison is primary
(:data:`PRIMARY`), judged at 5 %; the rest are Holm-corrected. None is judged on fewer
independent units than ``MIN_CONDITIONS`` (arena) or ``MIN_SCENES`` (footage), nor on footage
with a smaller class than ``MIN_FAILURES``: "8 scenes: too few to judge (20 needed)". A
measure is "better" only when it predicts failure beyond chance itself, in the expected
direction (its own interval clear of chance); two measures both against the expected sign are
"both against the expected sign": less inverted is not better.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.predictors.inference import (
    auroc_difference,
    auroc_interval,
    cluster_mean,
    newcombe_interval,
    spearman_rows,
)
from analysis.predictors.verdicts import Units, judge, units_of
from analysis.stats import scipy_special, scipy_stats

RIDGE = 0.1  # the combined logistic's L2 penalty on standardised coefficients (few units)
# every measure, its column in the measures tables, in the order the reports list them
MEASURES = {
    "avdm": "the paper's AVDM (avdm), mean angular velocity, deg/s",
    "avdm_natural": "avdm-natural, mean angular velocity, deg/s",
    "si_p910": "P.910 spatial information",
    "ti_p910": "P.910 temporal information",
    "si_legacy": "legacy SI (P.910 1999)",
    "ti_legacy": "legacy TI (P.910 1999)",
    "mafd": "mean absolute frame difference",
    "flow_dps": "DIS optic flow, mean |horizontal|, deg/s",
    "edge_density": "Canny edge density",
    "jpeg_bpp": "JPEG bits per pixel",
    "codec_bpp": "codec (H.264) bits per pixel",
    "zlib_ratio": "zlib compression ratio",
}
AVDMS = ("avdm", "avdm_natural")
BASELINE = ("si_p910", "ti_p910")
COMBINED = (
    BASELINE,
    (*BASELINE, "avdm"),
    (*BASELINE, "avdm_natural"),
    ("si_p910", "avdm"),
    ("si_p910", "avdm_natural"),
    ("avdm",),
    ("avdm_natural",),
)
PREDICTOR_COLUMNS = (
    *("measure", "value", "statistic", "estimate", "ci_low", "ci_high", "n", "n_failing"),
    *("n_correct", "unit", "n_units", "p_value", "p_holm", "role", "survives", "verdict"),
)
HEADLINE = {  # the statistic each mode ranks measures by
    "arena": "rho_failure",
    "footage": "clip_auroc",
}
# The paper's question, named before any data: does the paper's AVDM predict failure better
# than P.910 TI? Judged at 5 % alone; every other comparison is Holm-corrected.
PRIMARY = ("avdm", "ti_p910")
# Footage failures scored apart (issue 42): statistic and the clips each is told from. The
# sign is fixed in advance and the same for each: a higher measure, more of that failure (the
# paper's hypothesis); a measure that goes the other way scores below 0.5.
FAILURE_MODES = {
    "miss": ("clip_auroc_miss", ("hit",)),  # collision clips: missed (or too late) vs hit
    # alerted before the object was in view (the labels' onset; without one, earlier than the
    # window before a collision: judge_clip) against the collision clips that were not
    "early": ("clip_auroc_early", ("hit", "miss")),
    "false_alarm": ("clip_auroc_false_alarm", ("quiet",)),  # no collision: alerted vs quiet
}


# --- the statistics ---------------------------------------------------------------------------


def auroc(score: np.ndarray, positive: np.ndarray) -> float:
    """P(score of a random positive > that of a random negative), ties counting half: the
    Mann–Whitney U / (n₁ n₀). NaN without both classes. score (N,) float, positive (N,) bool."""
    score = np.asarray(score, float)
    positive = np.asarray(positive, bool)
    ok = np.isfinite(score)
    return float(auroc_columns(score[ok, None], positive[ok])[0])


def auroc_columns(scores: np.ndarray, positive: np.ndarray) -> np.ndarray:
    """:func:`auroc` of every column of ``scores`` (N, M) (finite values) at once: (M,)."""

    positive = np.asarray(positive, bool)
    n1 = int(positive.sum())
    n0 = len(positive) - n1
    if n1 == 0 or n0 == 0 or scores.shape[1] == 0:
        return np.full(scores.shape[1], math.nan)
    ranks = scipy_stats().rankdata(scores, axis=0)
    return (ranks[positive].sum(0) - n1 * (n1 + 1) / 2) / (n1 * n0)


def auroc_matrix(scores: np.ndarray, positive: np.ndarray) -> np.ndarray:
    """:func:`auroc` of every column of ``scores`` (N, M), NaN values left out per column."""
    scores = np.asarray(scores, float)
    fin = np.isfinite(scores).all(0)
    out = np.full(scores.shape[1], math.nan)
    out[fin] = auroc_columns(scores[:, fin], positive)
    for j in np.flatnonzero(~fin):
        out[j] = auroc(scores[:, j], positive)
    return out


def finite_spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman ρ of the finite pairs (a NaN or inf on either side drops the pair, unlike
    :func:`analysis.stats.spearman`); NaN if either side is constant or < 3 pairs."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    return float(spearman_rows(x[None, ok], y[None, ok])[0])


def fit_logistic(X: np.ndarray, y: np.ndarray, ridge: float = RIDGE) -> np.ndarray:
    """Ridge logistic regression of fractional outcomes y (N,) in [0, 1] on X (N, K), an
    intercept added (not penalised); Newton's method. Returns (K + 1,) coefficients."""
    A = np.column_stack([np.ones(len(X)), X])
    beta = np.zeros(A.shape[1])
    pen = np.full(A.shape[1], ridge)
    pen[0] = 0.0
    for _ in range(50):
        p = scipy_special().expit(A @ beta)
        grad = A.T @ (p - y) + pen * beta
        hess = (A * (p * (1 - p))[:, None]).T @ A + np.diag(pen) + 1e-9 * np.eye(len(beta))
        step = np.linalg.solve(hess, grad)
        beta -= step
        if np.abs(step).max() < 1e-8:
            break
    return beta


def cv_logistic_losses(
    X: np.ndarray, y: np.ndarray, ridge: float = RIDGE, cluster: np.ndarray | None = None
) -> np.ndarray:
    """Held-out cross-entropy of :func:`fit_logistic` per unit (N,), each unit held out (with
    ``cluster``: each cluster, all its units at once: a unit's scene-mates would otherwise
    teach the model its scene), measures standardised on the training units. X (N, K), y (N,)
    failure rates in [0, 1]."""
    n = len(y)
    losses = np.full(n, math.nan)
    groups = np.arange(n) if cluster is None else np.asarray(cluster)
    for g in dict.fromkeys(groups.tolist()):
        held = groups == g
        rest = ~held
        if not rest.any():
            continue
        mu, sd = X[rest].mean(0), X[rest].std(0)
        sd = np.where(sd > 0, sd, 1.0)
        beta = fit_logistic((X[rest] - mu) / sd, y[rest], ridge)
        p = scipy_special().expit(beta[0] + ((X[held] - mu) / sd) @ beta[1:])
        p = np.clip(p, 1e-6, 1 - 1e-6)
        losses[held] = -(y[held] * np.log(p) + (1 - y[held]) * np.log(1 - p))
    return losses


def _row(
    measure: str,
    value: float,
    statistic: str,
    est: float,
    lo: float,
    hi: float,
    n: int,
    units: Units,
    n_units: int,
    n_failing: int | None = None,
    n_correct: int | None = None,
    p: float = math.nan,
    role: str | None = None,
    counted: str | None = None,
) -> dict[str, Any]:
    return {
        "measure": measure,
        "value": float(value),
        "statistic": statistic,
        "estimate": float(est),
        "ci_low": float(lo),
        "ci_high": float(hi),
        "n": int(n),
        "n_failing": n_failing,
        "n_correct": n_correct,
        "unit": units.unit,
        "n_units": int(n_units),
        "p_value": float(p),
        "role": role,
        "counted": counted or units.counted,  # what n_failing / n_correct count (not a column)
    }


def _role(ref: str, measure: str, statistic: str) -> str:
    """The paper's question, named before any data: the AVDM against P.910 TI on the mode's
    headline statistic; everything else is secondary (Holm-corrected)."""
    head = statistic.removeprefix("paired_").removesuffix(f"_vs_{ref}")
    primary = (ref, measure) == PRIMARY and head in HEADLINE.values()
    return "primary" if primary else "secondary"


def _mean_row(
    measure: str,
    value: float,
    statistic: str,
    d: np.ndarray,
    units: Units,
    cluster: np.ndarray | None,
    counts: tuple[int, int],
    role: str | None = None,
    bounds: tuple[float, float] | None = None,
    counted: str | None = None,
) -> dict[str, Any]:
    """A mean of per-unit values ``d`` with its interval and two-sided p
    (:func:`~analysis.predictors.inference.cluster_mean`, clustered on ``cluster``)."""
    d = np.asarray(d, float)
    ok = np.isfinite(d)
    est, lo, hi, p, k = cluster_mean(d, cluster)
    if bounds is not None and math.isfinite(lo):
        lo, hi = max(lo, bounds[0]), min(hi, bounds[1])
    return _row(
        measure, value, statistic, est, lo, hi, int(ok.sum()), units, k, *counts, p, role, counted
    )


def _combined_rows(
    unit_measures: pl.DataFrame,
    failure: np.ndarray,
    value: float,
    units: Units,
    counts: tuple[int, int],
) -> list[dict[str, Any]]:
    """The combined logistic models on units (rows of ``unit_measures``) with failure rates:
    each set's mean held-out loss (each scene held out at once where the units share scenes),
    and its gain over SI/TI (the mean of the per-unit loss differences; interval and p
    clustered on the scenes)."""
    rows = []
    losses: dict[str, np.ndarray] = {}
    n = len(failure)
    enough = n >= 4 and (units.cluster is None or units.n_units() >= 3)
    for combo in COMBINED:
        if not all(c in unit_measures.columns for c in combo):
            continue
        X = unit_measures.select(combo).to_numpy().astype(float)
        if not enough or not np.isfinite(X).all():
            continue
        losses["+".join(combo)] = cv_logistic_losses(X, failure, cluster=units.cluster)
    base = losses.get("+".join(BASELINE))
    for name, loss in losses.items():
        rows.append(_mean_row(name, value, "cv_logloss", loss, units, units.cluster, counts))
        rows[-1]["p_value"] = math.nan  # a loss is not tested against 0
        if base is not None and name != "+".join(BASELINE):
            stat = f"cv_logloss_gain_vs_{'+'.join(BASELINE)}"
            rows.append(
                _mean_row(name, value, stat, base - loss, units, units.cluster, counts, "secondary")
            )
    return rows


def measures_present(columns: Sequence[str]) -> list[str]:
    """The measures of :data:`MEASURES` among ``columns``, in its order."""
    return [m for m in MEASURES if m in columns]


TABLE_SCHEMA = {
    "measure": pl.String,
    "value": pl.Float64,
    "statistic": pl.String,
    "estimate": pl.Float64,
    "ci_low": pl.Float64,
    "ci_high": pl.Float64,
    "n": pl.Int64,
    "n_failing": pl.Int64,
    "n_correct": pl.Int64,
    "unit": pl.String,
    "n_units": pl.Int64,
    "p_value": pl.Float64,
    "p_holm": pl.Float64,
    "role": pl.String,
    "survives": pl.Boolean,
    "verdict": pl.String,
}


def _table(rows: list[dict[str, Any]], mode: str) -> pl.DataFrame:
    """The rows judged, as :data:`PREDICTOR_COLUMNS`."""
    rows = judge(rows, mode)
    full = [{k: r.get(k) for k in TABLE_SCHEMA} for r in rows]
    return pl.DataFrame(full, schema=TABLE_SCHEMA).with_columns(
        pl.col("estimate", "ci_low", "ci_high", "p_value", "p_holm").fill_nan(None)
    )


# --- footage ----------------------------------------------------------------------------------


def footage_predictors(
    clips: pl.DataFrame,
    frames: pl.DataFrame,
    param: str,
    *,
    seed: int = 0,
) -> pl.DataFrame:
    """The predictor table of a labelled collection; its units are the scenes (the labels'
    ``scene`` column: the photograph, place or session clips share), or the clips, taken as
    independent, without one.

    ``clips``: one row per clip and value (clip, ``param``, correct, optionally ``scene`` and
    ``failure``: :data:`FAILURE_MODES` or ``hit``/``quiet``, and one column per measure: its
    mean over the scene the detector faced); ``frames``: one row per frame and value (clip,
    ``param``, frame, positive, keep, one column per measure). AUROC intervals: Newcombe's on
    the design effect of Obuchowski's clustered DeLong variance, clustered on the scenes (on
    the clips for frames without scenes), t on clusters − 1 degrees of freedom
    (:func:`~analysis.predictors.inference.auroc_interval`); paired differences by the
    clustered DeLong covariance. Returns :data:`PREDICTOR_COLUMNS`."""
    del seed  # every interval here is analytic: nothing is drawn
    names = measures_present(clips.columns)
    rows: list[dict[str, Any]] = []
    for (value,), g in clips.group_by(param, maintain_order=True):
        scene = g["scene"].to_list() if "scene" in g.columns else None
        units = units_of(scene, "clips", g.height)
        wrong = ~g["correct"].to_numpy().astype(bool)
        X = g.select(names).to_numpy().astype(float)
        rows += _auroc_rows(names, X, wrong, value, "clip_auroc", units, units.cluster)
        if "failure" in g.columns:
            kind = g["failure"].to_numpy()
            for mode, (stat, pool) in FAILURE_MODES.items():
                sel = np.isin(kind, (mode, *pool))
                if sel.any():
                    cl = None if units.cluster is None else units.cluster[sel]
                    right = np.isin(kind[sel], ("hit", "quiet"))  # the correct clips in the pool
                    rows += _auroc_rows(
                        names, X[sel], kind[sel] == mode, value, stat, units, cl, correct=right
                    )
        f = frames.filter((pl.col(param) == value) & pl.col("keep"))
        names_f = [m for m in names if m in f.columns]
        if f.height:
            fx = f.select(names_f).to_numpy().astype(float)
            pos = f["positive"].to_numpy().astype(bool)
            clip = f["clip"].to_numpy()
            if units.cluster is not None:  # frames clustered on their clip's scene
                of = dict(zip(g["clip"].to_list(), units.cluster.tolist(), strict=True))
                frame_units = dataclasses.replace(units, counted="frames")
                frame_cl = np.array([of[c] for c in clip])
            else:  # on their clip
                frame_units = Units("clip", clip, "frames", len(clip))
                frame_cl = clip
            rows += _auroc_rows(
                names_f, fx, pos, value, "frame_auroc_pooled", frame_units, frame_cl
            )
            scene_of = None
            if units.cluster is not None:
                scene_of = dict(zip(g["clip"].to_list(), units.cluster.tolist(), strict=True))
            rows += _within_clip_rows(names_f, fx, pos, clip, value, units, scene_of)
        rows += _combined_rows(
            g.select(names),
            wrong.astype(float),
            value,
            units,
            (int(wrong.sum()), int((~wrong).sum())),
        )
    return _table(rows, "footage")


def _auroc_rows(
    names: list[str],
    X: np.ndarray,
    pos: np.ndarray,
    value: float,
    stat: str,
    units: Units,
    cluster: np.ndarray | None,
    correct: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Each measure's AUROC (X (N, M), pos (N,)) with its interval, and (for the headline
    and the frame statistics) each AVDM against the others, paired on the same units.
    ``cluster`` (N,): each unit's cluster (None: units independent); ``correct`` (N,): the
    units that are correct (default: those not ``pos``)."""
    rows = []
    right = ~pos if correct is None else np.asarray(correct, bool)

    def counts(ok: np.ndarray) -> tuple[int, int, int]:
        k = int(ok.sum()) if cluster is None else len(np.unique(cluster[ok]))
        return k, int(pos[ok].sum()), int(right[ok].sum())

    for j, name in enumerate(names):
        ok = np.isfinite(X[:, j])
        a, lo, hi = auroc_interval(X[:, j], pos, cluster)
        rows.append(_row(name, value, stat, a, lo, hi, int(ok.sum()), units, *counts(ok)))
    if stat not in ("clip_auroc", "frame_auroc_pooled"):
        return rows
    for ref, i, j, name in _avdm_pairs(names):
        ok = np.isfinite(X[:, i]) & np.isfinite(X[:, j])
        d, lo, hi, p = auroc_difference(X[:, i], X[:, j], pos, cluster)
        st = f"paired_{stat}_vs_{ref}"
        rows.append(
            _row(
                name,
                value,
                st,
                d,
                lo,
                hi,
                int(ok.sum()),
                units,
                *counts(ok),
                p,
                _role(ref, name, st),
            )
        )
    return rows


def _within_clip_rows(
    names: list[str],
    fx: np.ndarray,
    pos: np.ndarray,
    clip: np.ndarray,
    value: float,
    units: Units,
    scene_of: dict[str, str] | None,
) -> list[dict[str, Any]]:
    """The mean over clips (with both kinds of frame) of each clip's own frame AUROC, with its
    interval over the clips' scenes (cluster-robust, t on scenes − 1 degrees of freedom) or
    the clips; each AVDM against the others by the same mean of their per-clip differences.
    ``n_failing`` / ``n_correct``: the alerting and quiet frames of those clips."""
    ids = list(dict.fromkeys(clip.tolist()))
    per, used = [], []
    fail_frames = quiet_frames = 0
    for c in ids:
        sel = clip == c
        if pos[sel].any() and not pos[sel].all():
            per.append(auroc_matrix(fx[sel], pos[sel]))
            used.append(c)
            fail_frames += int(pos[sel].sum())
            quiet_frames += int((~pos[sel]).sum())
    per_clip = np.array(per).reshape(len(per), len(names))
    cl = None if scene_of is None else np.array([scene_of[c] for c in used])
    rows = []
    stat = "frame_auroc_within_clip"
    counts = (fail_frames, quiet_frames)
    for j, name in enumerate(names):
        v = per_clip[:, j]
        r = _mean_row(name, value, stat, v, units, cl, counts, bounds=(0.0, 1.0), counted="frames")
        r["p_value"] = math.nan
        # clips that all score alike give an interval of no width: at least Newcombe's for
        # one pair per clip, the least information the clips could hold
        n_eff = r["n_units"]
        if n_eff >= 1 and math.isfinite(r["estimate"]):
            lo, hi = newcombe_interval(r["estimate"], n_eff, n_eff)
            low = float(lo) if not math.isfinite(r["ci_low"]) else min(r["ci_low"], float(lo))
            high = float(hi) if not math.isfinite(r["ci_high"]) else max(r["ci_high"], float(hi))
            r["ci_low"], r["ci_high"] = low, high
        rows.append(r)
    for ref, i, j, name in _avdm_pairs(names):
        d = per_clip[:, i] - per_clip[:, j]
        st = f"paired_{stat}_vs_{ref}"
        rows.append(
            _mean_row(name, value, st, d, units, cl, counts, _role(ref, name, st), counted="frames")
        )
    return rows


def _avdm_pairs(names: list[str]) -> Iterator[tuple[str, int, int, str]]:
    """(ref, i, j, name): each AVDM among ``names`` (at ``i``) against every other measure
    (``name`` at ``j``), each pair of AVDMs once."""
    for ref in AVDMS:
        if ref not in names:
            continue
        i = names.index(ref)
        for j, name in enumerate(names):
            if j != i and not (name in AVDMS and j < i):
                yield ref, i, j, name

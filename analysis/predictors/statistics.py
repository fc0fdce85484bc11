"""Which complexity measure predicts where a detector breaks (issue 32).

``vdc-analyse boundary`` finds where a detector's success falls; this module asks which of the
complexity measures vdc computes (the AVDM, paper ``avdm`` and ``avdm-natural``, P.910 and
legacy SI/TI, MAFD, DIS flow, edge density, JPEG/codec/zlib compression) orders the cases as
the detector fails them. One table, ``predictors.parquet``, one row per measure, parameter
value and statistic: ``measure``, ``value``, ``statistic``, ``estimate``, ``ci_low``,
``ci_high``, ``n`` and (paired and combined rows) ``verdict``.

Arena (units: conditions; every interval a percentile bootstrap over seeds, resampled within
each condition: the detector's runs and the profiling runs each, the same resamples for every
measure so differences are paired):

* ``rho_failure``: Spearman ρ between the measure and the failure rate (1 − success) across
  conditions: 1 = it orders the conditions exactly as the detector fails them;
* ``loco_balanced_accuracy``: "fails the target" (mean success below it) predicted for each
  condition by a threshold on the measure (higher = fails) fitted on the other conditions
  (the threshold of best balanced accuracy); the balanced accuracy of those held-out
  predictions (NaN when all conditions fail or all pass).

Footage (units: clips):

* ``clip_auroc``: the AUROC of the clip's measure (the scene before the alert window) for a
  clip the detector gets wrong (a miss or a false alarm), stratified bootstrap over clips;
* ``frame_auroc_pooled`` and ``frame_auroc_within_clip``: per frame, frames where the detector
  alerts with no collision in the window (or after it) against frames where it stays quiet
  (frames inside the window and after the collision, and the start-up's, are left out of
  both: :func:`frame_classes`), pooled over clips
  and per clip (the mean over clips with both kinds of frame); bootstrap over clips. A measure
  that ranks clips but not moments scores well pooled and near 0.5 within clips.

Both modes:

* paired comparisons ``paired_<statistic>_vs_<avdm>``: the AVDM's statistic minus the
  measure's on the same resamples, with the verdict for the AVDM (``better``, ``worse``,
  ``no difference`` at 95 %);
* combined: a ridge-logistic model (standardised measures, λ = :data:`RIDGE`) of the failure
  rate on SI/TI, on SI/TI + an AVDM, and on other sets (:data:`COMBINED`), fitted with the held-out
  unit (condition or clip) left out; ``cv_logloss`` is the mean held-out cross-entropy per unit,
  and ``cv_logloss_gain_vs_si_p910+ti_p910`` the loss of SI/TI minus that of the set (positive:
  the set predicts better), its interval a bootstrap over the held-out units' losses.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import polars as pl
import scipy.special
import scipy.stats

from analysis.stats import CONFIDENCE

BOOTSTRAP = 1000  # resamples for every interval
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
COLUMNS = ("measure", "value", "statistic", "estimate", "ci_low", "ci_high", "n", "verdict")
HEADLINE = {  # the statistic each mode ranks measures by
    "arena": "rho_failure",
    "footage": "clip_auroc",
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
    ranks = scipy.stats.rankdata(scores, axis=0)
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


def spearman_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman ρ of each row pair of x, y (B, N) (finite): (B,); NaN where a row is constant
    or N < 3."""
    if x.shape[1] < 3:
        return np.full(len(x), math.nan)
    rx = scipy.stats.rankdata(x, axis=1)
    ry = scipy.stats.rankdata(y, axis=1)
    rx -= rx.mean(1, keepdims=True)
    ry -= ry.mean(1, keepdims=True)
    den = np.sqrt((rx**2).sum(1) * (ry**2).sum(1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (rx * ry).sum(1) / np.where(den > 0, den, 1.0), math.nan)


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
    b, n = x.shape
    if n < 3:
        return np.full(b, math.nan)
    pred = np.zeros((b, n), bool)
    for i in range(n):
        rest = np.arange(n) != i
        xr, fr = x[:, rest], fails[:, rest]
        order = np.argsort(xr, axis=1)
        xs = np.take_along_axis(xr, order, 1)
        cands = np.concatenate([xs[:, :1] - 1.0, (xs[:, 1:] + xs[:, :-1]) / 2, xs[:, -1:] + 1.0], 1)
        ba = _balanced(xr[:, None, :] > cands[:, :, None], fr[:, None, :])  # (B, C)
        ba = np.where(np.isfinite(ba), ba, -1.0)
        best = ba.max(1, keepdims=True)
        tie = ba == best
        k = tie.sum(1) // 2
        pick = np.argmax(np.cumsum(tie, 1) > k[:, None], axis=1)
        t = cands[np.arange(b), pick]
        p = x[:, i] > t
        p = np.where(fr.all(1), True, np.where(~fr.any(1), False, p))
        pred[:, i] = p
    return _balanced(pred, fails)


def fit_logistic(X: np.ndarray, y: np.ndarray, ridge: float = RIDGE) -> np.ndarray:
    """Ridge logistic regression of fractional outcomes y (N,) in [0, 1] on X (N, K), an
    intercept added (not penalised); Newton's method. Returns (K + 1,) coefficients."""
    A = np.column_stack([np.ones(len(X)), X])
    beta = np.zeros(A.shape[1])
    pen = np.full(A.shape[1], ridge)
    pen[0] = 0.0
    for _ in range(50):
        p = scipy.special.expit(A @ beta)
        grad = A.T @ (p - y) + pen * beta
        hess = (A * (p * (1 - p))[:, None]).T @ A + np.diag(pen) + 1e-9 * np.eye(len(beta))
        step = np.linalg.solve(hess, grad)
        beta -= step
        if np.abs(step).max() < 1e-8:
            break
    return beta


def cv_logistic_losses(X: np.ndarray, y: np.ndarray, ridge: float = RIDGE) -> np.ndarray:
    """Leave-one-unit-out held-out cross-entropy of :func:`fit_logistic` per unit (N,),
    measures standardised on the training units. X (N, K), y (N,) failure rates in [0, 1]."""
    n = len(y)
    losses = np.full(n, math.nan)
    for i in range(n):
        rest = np.arange(n) != i
        mu, sd = X[rest].mean(0), X[rest].std(0)
        sd = np.where(sd > 0, sd, 1.0)
        beta = fit_logistic((X[rest] - mu) / sd, y[rest], ridge)
        p = scipy.special.expit(beta[0] + ((X[i] - mu) / sd) @ beta[1:])
        p = float(np.clip(p, 1e-6, 1 - 1e-6))
        losses[i] = -(y[i] * math.log(p) + (1 - y[i]) * math.log(1 - p))
    return losses


def _ci(samples: np.ndarray) -> tuple[float, float]:
    s = np.asarray(samples, float)
    s = s[np.isfinite(s)]
    if len(s) < 10:
        return math.nan, math.nan
    a = (1 - CONFIDENCE) / 2
    return float(np.quantile(s, a)), float(np.quantile(s, 1 - a))


def _verdict(low: float, high: float) -> str:
    if not (math.isfinite(low) and math.isfinite(high)):
        return "undetermined"
    return "better" if low > 0 else "worse" if high < 0 else "no difference"


def _row(measure: str, value: float, statistic: str, est: float, boots: np.ndarray, n: int,
         verdict: str | None = None) -> dict[str, Any]:  # fmt: skip
    lo, hi = _ci(boots)
    return {
        "measure": measure,
        "value": float(value),
        "statistic": statistic,
        "estimate": float(est),
        "ci_low": lo,
        "ci_high": hi,
        "n": int(n),
        "verdict": verdict,
    }


def _paired_rows(
    point: dict[str, dict[str, float]],
    boots: dict[str, dict[str, np.ndarray]],
    value: float,
    n: int,
) -> list[dict[str, Any]]:
    """Each AVDM against every other measure, per statistic: AVDM minus measure."""
    rows = []
    for stat, per in point.items():
        for ref in AVDMS:
            if ref not in per or not math.isfinite(per[ref]):
                continue
            for m in per:
                if m == ref or not math.isfinite(per[m]):
                    continue
                diff = boots[stat][ref] - boots[stat][m]
                lo, hi = _ci(diff)
                rows.append(
                    _row(m, value, f"paired_{stat}_vs_{ref}", per[ref] - per[m], diff, n)
                    | {"verdict": _verdict(lo, hi)}
                )
    return rows


def _combined_rows(
    unit_measures: pl.DataFrame, failure: np.ndarray, value: float, rng: np.random.Generator
) -> list[dict[str, Any]]:
    """The combined logistic models on units (rows of ``unit_measures``) with failure rates."""
    rows = []
    losses: dict[str, np.ndarray] = {}
    n = len(failure)
    for combo in COMBINED:
        if not all(c in unit_measures.columns for c in combo):
            continue
        X = unit_measures.select(combo).to_numpy().astype(float)
        if n < 4 or not np.isfinite(X).all():
            continue
        losses["+".join(combo)] = cv_logistic_losses(X, failure)
    idx = rng.integers(0, n, size=(BOOTSTRAP, n)) if n else np.zeros((0, 0), int)
    base = losses.get("+".join(BASELINE))
    for name, loss in losses.items():
        rows.append(_row(name, value, "cv_logloss", loss.mean(), loss[idx].mean(1), n))
        if base is not None and name != "+".join(BASELINE):
            gain = base - loss
            g = gain[idx].mean(1)
            lo, hi = _ci(g)
            rows.append(
                _row(name, value, f"cv_logloss_gain_vs_{'+'.join(BASELINE)}", gain.mean(), g, n)
                | {"verdict": _verdict(lo, hi)}
            )
    return rows


def measures_present(columns: Sequence[str]) -> list[str]:
    """The measures of :data:`MEASURES` among ``columns``, in its order."""
    return [m for m in MEASURES if m in columns]


# --- arena ------------------------------------------------------------------------------------


def arena_predictors(
    runs: pl.DataFrame,
    measures: pl.DataFrame,
    param: str,
    target: float,
    *,
    seed: int = 0,
) -> pl.DataFrame:
    """The predictor table of an arena grid.

    ``runs``: one row per closed-loop run (condition, ``param``, seed, avoidances, crashes);
    ``measures``: one row per profiling run (condition, seed, one column per measure in
    :data:`MEASURES`, the condition's scene as the run saw it). A condition's success is the
    mean of its seeds' shares (as ``boundary`` computes it); its measure the mean over its
    profiling runs. Returns :data:`COLUMNS`."""
    names = measures_present(measures.columns)
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    conds = [c for c in measures["condition"].unique(maintain_order=True)]
    mtab = {c: measures.filter(pl.col("condition") == c).select(names).to_numpy().astype(float)
            for c in conds}  # fmt: skip
    for (value,), g in runs.group_by(param, maintain_order=True):
        shares, used = [], []
        for c in conds:
            r = g.filter(pl.col("condition") == c)
            n = (r["avoidances"] + r["crashes"]).to_numpy()
            k = r["avoidances"].to_numpy()
            if (n > 0).any() and len(mtab[c]):
                shares.append(k[n > 0] / n[n > 0])
                used.append(c)
        if len(used) < 3:
            continue
        m = len(used)

        def stats(succ: np.ndarray, meas: np.ndarray) -> dict[str, np.ndarray]:
            """succ (B, C), meas (B, C, M) → statistic: (B, M)."""
            fail, fails = 1 - succ, succ < target
            out = {"rho_failure": [], "loco_balanced_accuracy": []}
            for j in range(len(names)):
                x = meas[:, :, j]
                ok = np.isfinite(x).all(1)
                rho = np.full(len(x), math.nan)
                loco = np.full(len(x), math.nan)
                rho[ok] = spearman_rows(x[ok], fail[ok])
                loco[ok] = loco_rows(x[ok], fails[ok])
                out["rho_failure"].append(rho)
                out["loco_balanced_accuracy"].append(loco)
            return {k: np.stack(v, 1) for k, v in out.items()}

        succ0 = np.array([s.mean() for s in shares])
        meas0 = np.array([np.nanmean(mtab[c], 0) for c in used])
        point = {k: v[0] for k, v in stats(succ0[None], meas0[None]).items()}
        succ_b = np.stack(
            [s[rng.integers(0, len(s), (BOOTSTRAP, len(s)))].mean(1) for s in shares], 1
        )
        meas_b = np.stack(
            [
                np.nanmean(mtab[c][rng.integers(0, len(mtab[c]), (BOOTSTRAP, len(mtab[c])))], 1)
                for c in used
            ],
            1,
        )
        boot = stats(succ_b, meas_b)
        for k in point:
            for j, name in enumerate(names):
                rows.append(_row(name, value, k, point[k][j], boot[k][:, j], m))
        rows += _paired_rows(
            {k: dict(zip(names, point[k], strict=True)) for k in point},
            {k: {n: boot[k][:, j] for j, n in enumerate(names)} for k in boot},
            value,
            m,
        )
        unit = pl.DataFrame(meas0, schema=names, orient="row")
        rows += _combined_rows(unit, 1 - succ0, value, rng)
    return _table(rows)


def _table(rows: list[dict[str, Any]]) -> pl.DataFrame:
    schema = {
        "measure": pl.String,
        "value": pl.Float64,
        "statistic": pl.String,
        "estimate": pl.Float64,
        "ci_low": pl.Float64,
        "ci_high": pl.Float64,
        "n": pl.Int64,
        "verdict": pl.String,
    }
    return pl.DataFrame(rows, schema=schema).with_columns(
        pl.col("estimate", "ci_low", "ci_high").fill_nan(None)
    )


# --- footage ----------------------------------------------------------------------------------


def frame_classes(
    frames: np.ndarray,
    alert: np.ndarray,
    collision_frame: int | None,
    window_frames: int,
    warmup_frames: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: (positive, keep). Positive: the detector alerts with no collision in the
    window; negative: it stays quiet; frames inside the window and after the collision are not
    kept (the object, not the scene, drives the detector there), nor the first
    ``warmup_frames`` (the measures' and the detector's start-up: the AVDM rises from 0 over
    its first frames while a detector that needs a run of frames cannot alert yet, so a busy
    clip's only quiet frames would be those, and every AVDM would "predict" them exactly)."""
    frames = np.asarray(frames)
    keep = frames >= warmup_frames
    if collision_frame is not None:
        keep &= frames < collision_frame - window_frames
    return (np.asarray(alert) > 0) & keep, keep


def footage_predictors(
    clips: pl.DataFrame,
    frames: pl.DataFrame,
    param: str,
    *,
    seed: int = 0,
) -> pl.DataFrame:
    """The predictor table of a labelled collection.

    ``clips``: one row per clip and value (clip, ``param``, correct, and one column per
    measure: its mean over the scene the detector faced); ``frames``: one row per frame and
    value (clip, ``param``, frame, positive, keep, one column per measure). Returns
    :data:`COLUMNS`."""
    names = measures_present(clips.columns)
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    for (value,), g in clips.group_by(param, maintain_order=True):
        wrong = ~g["correct"].to_numpy().astype(bool)
        X = g.select(names).to_numpy().astype(float)
        point = {"clip_auroc": auroc_matrix(X, wrong)}
        pos, neg = np.flatnonzero(wrong), np.flatnonzero(~wrong)
        boot = {"clip_auroc": np.full((BOOTSTRAP, len(names)), math.nan)}
        if len(pos) and len(neg):
            for b in range(BOOTSTRAP):  # stratified: wrong and right clips resampled apart
                idx = np.concatenate(
                    [
                        pos[rng.integers(0, len(pos), len(pos))],
                        neg[rng.integers(0, len(neg), len(neg))],
                    ]
                )
                boot["clip_auroc"][b] = auroc_matrix(X[idx], wrong[idx])
        n_clips = g.height
        f = frames.filter((pl.col(param) == value) & pl.col("keep"))
        names_f = [m for m in names if m in f.columns]
        if f.height:
            clip_ids = f["clip"].unique(maintain_order=True).to_list()
            parts = [f.filter(pl.col("clip") == c) for c in clip_ids]
            fx = [
                (p.select(names_f).to_numpy().astype(float), p["positive"].to_numpy())
                for p in parts
            ]

            within_clip = np.array([auroc_matrix(x, y) for x, y in fx])  # (clips, M)

            fpoint = _frame_stats(fx, within_clip, range(len(fx)))
            fboot = {k: np.full((BOOTSTRAP // 2, len(names_f)), math.nan) for k in fpoint}
            for b in range(BOOTSTRAP // 2):  # over clips: a clip's frames are not independent
                for k, v in _frame_stats(
                    fx, within_clip, rng.integers(0, len(fx), len(fx))
                ).items():
                    fboot[k][b] = v
            n_within = sum(1 for x, y in fx if y.any() and not y.all())
            for k in fpoint:
                for j, name in enumerate(names_f):
                    n = len(fx) if k == "frame_auroc_pooled" else n_within
                    rows.append(_row(name, value, k, fpoint[k][j], fboot[k][:, j], n))
            rows += _paired_rows(
                {k: dict(zip(names_f, fpoint[k], strict=True)) for k in fpoint},
                {k: {n: fboot[k][:, j] for j, n in enumerate(names_f)} for k in fboot},
                value,
                len(fx),
            )
        for j, name in enumerate(names):
            rows.append(_row(name, value, "clip_auroc", point["clip_auroc"][j],
                             boot["clip_auroc"][:, j], n_clips))  # fmt: skip
        rows += _paired_rows(
            {"clip_auroc": dict(zip(names, point["clip_auroc"], strict=True))},
            {"clip_auroc": {n: boot["clip_auroc"][:, j] for j, n in enumerate(names)}},
            value,
            n_clips,
        )
        rows += _combined_rows(g.select(names), wrong.astype(float), value, rng)
    return _table(rows)


def _frame_stats(
    fx: list[tuple[np.ndarray, np.ndarray]], within_clip: np.ndarray, sel: Sequence[int]
) -> dict[str, np.ndarray]:
    """Per-frame AUROCs of the clips ``sel`` (with repeats): pooled over their frames, and the
    mean of the clips' own (``within_clip`` (clips, M), NaN where a clip lacks a class)."""
    xs = np.concatenate([fx[i][0] for i in sel])
    ys = np.concatenate([fx[i][1] for i in sel])
    with warnings.catch_warnings():  # a mean over clips that all lack a class is NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        within = np.nanmean(within_clip[list(sel)], 0)
    return {"frame_auroc_pooled": auroc_matrix(xs, ys), "frame_auroc_within_clip": within}

"""Which complexity measure predicts where a detector breaks (issues 32, 42).

``vdc-analyse boundary`` finds where a detector's success falls; this module asks which of the
complexity measures vdc computes (:data:`MEASURES`) orders the cases as the detector fails
them. One table, ``predictors.parquet``, one row per measure, parameter value and statistic
(:data:`PREDICTOR_COLUMNS`): the estimate, its 95 % interval, ``n`` (the units the statistic used),
``n_failures`` (the failing units, or the fewer class), ``unit`` (``condition``, ``clip`` or
``frame``), and for comparisons ``p_value``, ``p_holm``, ``role``, ``survives`` and ``verdict``.
Intervals and tests: :mod:`analysis.predictors.inference`, over the units that vary.

Arena (units: conditions):

* ``rho_failure``: Spearman ρ between the measure and the failure rate (1 − success) across
  conditions, with an exact one-sided permutation p over the conditions;
* ``loco_balanced_accuracy``: "fails the target" predicted for each condition by a threshold
  on the measure fitted on the others; refused (NaN) below 2 failing or 2 passing conditions.

Footage (units: clips):

* ``clip_auroc``: the AUROC of the clip's measure for a clip the detector gets wrong; with a
  ``failure`` column, ``clip_auroc_miss``, ``clip_auroc_early`` and ``clip_auroc_false_alarm``
  score the failure modes apart (:data:`FAILURE_MODES`);
* ``frame_auroc_pooled`` (frames clustered by clip) and ``frame_auroc_within_clip`` (the mean
  of the clips' own): frames where the detector alerts with no collision near against quiet
  frames (:func:`analysis.boundary.footage_predictors.frame_classes`).

Both modes: ``paired_<statistic>_vs_<avdm>`` (the AVDM's statistic minus the measure's, same
units), and ``cv_logloss`` / ``cv_logloss_gain_vs_si_p910+ti_p910`` (a ridge-logistic model of
the failure rate on sets of measures, :data:`COMBINED`, each unit held out). One comparison is
primary (:data:`PRIMARY`); the rest are Holm-corrected; none is judged on fewer units than
:data:`MIN_CONDITIONS` or :data:`MIN_FAILURES`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.predictors.held_out import loco_interval, loco_threshold
from analysis.predictors.inference import (
    BOOTSTRAP,
    auroc_difference,
    auroc_interval,
    hierarchical_means,
    holm,
    newcombe_interval,
    permutation_p,
    rho_difference,
    rho_interval,
)
from analysis.stats import ALPHA, mean_ci, scipy_special, scipy_stats

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
    *("measure", "value", "statistic", "estimate", "ci_low", "ci_high", "n", "n_failures"),
    *("unit", "p_value", "p_holm", "role", "survives", "verdict"),
)
HEADLINE = {  # the statistic each mode ranks measures by
    "arena": "rho_failure",
    "footage": "clip_auroc",
}
# The paper's question, named before any data: does the paper's AVDM predict failure better
# than P.910 TI? Judged at 5 % alone; every other comparison is Holm-corrected.
PRIMARY = ("avdm", "ti_p910")
# Below these no comparison gets a verdict ("too few ... to judge"): the units that give 80 %
# power at two-sided 5 % for the effects the question is about (docs/method/boundary.md, "How many
# conditions and clips"). Arena: two dependent Spearman rho of 0.71 and 0.31 (the default
# grid's TI and AVDM) whose measures correlate 0.7 need 24 conditions (Steiger's test; 47 at
# 0.3). Footage: an AUROC difference of 0.10 between measures correlated 0.6 needs 46 failing
# clips, and as many that do not fail (Hanley & McNeil; 94 at 0.3).
MIN_CONDITIONS = 24
MIN_FAILURES = 46
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


def spearman_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman ρ of each row pair of x, y (B, N) (finite): (B,); NaN where a row is constant
    or N < 3."""

    if x.shape[1] < 3:
        return np.full(len(x), math.nan)
    rx = scipy_stats().rankdata(x, axis=1)
    ry = scipy_stats().rankdata(y, axis=1)
    rx -= rx.mean(1, keepdims=True)
    ry -= ry.mean(1, keepdims=True)
    den = np.sqrt((rx**2).sum(1) * (ry**2).sum(1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (rx * ry).sum(1) / np.where(den > 0, den, 1.0), math.nan)


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
        p = scipy_special().expit(beta[0] + ((X[i] - mu) / sd) @ beta[1:])
        p = float(np.clip(p, 1e-6, 1 - 1e-6))
        losses[i] = -(y[i] * math.log(p) + (1 - y[i]) * math.log(1 - p))
    return losses


def _row(measure: str, value: float, statistic: str, est: float, lo: float, hi: float, n: int,
         unit: str, n_failures: int | None = None, p: float = math.nan,
         role: str | None = None) -> dict[str, Any]:  # fmt: skip
    return {
        "measure": measure,
        "value": float(value),
        "statistic": statistic,
        "estimate": float(est),
        "ci_low": float(lo),
        "ci_high": float(hi),
        "n": int(n),
        "n_failures": n_failures,
        "unit": unit,
        "p_value": float(p),
        "role": role,
    }


def _role(ref: str, measure: str, statistic: str) -> str:
    """The paper's question, named before any data: the AVDM against P.910 TI on the mode's
    headline statistic; everything else is secondary (Holm-corrected)."""
    head = statistic.removeprefix("paired_").removesuffix(f"_vs_{ref}")
    primary = (ref, measure) == PRIMARY and head in HEADLINE.values()
    return "primary" if primary else "secondary"


def _t_row(measure: str, value: float, statistic: str, d: np.ndarray, unit: str,
           n_failures: int | None, role: str = "secondary") -> dict[str, Any]:  # fmt: skip
    """A mean of per-unit differences ``d`` with its t-interval and two-sided paired-t p."""

    d = np.asarray(d, float)
    d = d[np.isfinite(d)]
    n = len(d)
    if n < 2:
        return _row(measure, value, statistic, d.mean() if n else math.nan, math.nan, math.nan,
                    n, unit, n_failures, role=role)  # fmt: skip
    est = mean_ci(d)
    sd = d.std(ddof=1)
    p = (
        float(2 * scipy_stats().t.sf(abs(d.mean()) / (sd / math.sqrt(n)), n - 1))
        if sd > 0
        else (1.0 if d.mean() == 0 else 0.0)
    )
    return _row(measure, value, statistic, est.mean, est.low, est.high, n, unit, n_failures, p,
                role)  # fmt: skip


def _combined_rows(
    unit_measures: pl.DataFrame, failure: np.ndarray, value: float, unit: str, n_failures: int
) -> list[dict[str, Any]]:
    """The combined logistic models on units (rows of ``unit_measures``) with failure rates:
    each set's mean held-out loss, and its gain over SI/TI (the mean of the per-unit loss
    differences, t-interval and paired-t p over the held-out units)."""
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
    base = losses.get("+".join(BASELINE))
    for name, loss in losses.items():
        e = mean_ci(loss)
        rows.append(_row(name, value, "cv_logloss", e.mean, e.low, e.high, n, unit, n_failures))
        if base is not None and name != "+".join(BASELINE):
            stat = f"cv_logloss_gain_vs_{'+'.join(BASELINE)}"
            rows.append(_t_row(name, value, stat, base - loss, unit, n_failures))
    return rows


def measures_present(columns: Sequence[str]) -> list[str]:
    """The measures of :data:`MEASURES` among ``columns``, in its order."""
    return [m for m in MEASURES if m in columns]


# --- arena ------------------------------------------------------------------------------------


def _padded(parts: Sequence[np.ndarray]) -> np.ndarray:
    """Per-condition arrays (S_c, ...) stacked into (C, max S_c, ...), NaN-padded."""
    s_max = max(len(p) for p in parts)
    out = np.full((len(parts), s_max, *parts[0].shape[1:]), np.nan)
    for i, p in enumerate(parts):
        out[i, : len(p)] = p
    return out


def arena_predictors(
    runs: pl.DataFrame,
    measures: pl.DataFrame,
    param: str,
    target: float,
    *,
    seed: int = 0,
) -> pl.DataFrame:
    """The predictor table of an arena grid; its units are the conditions.

    ``runs``: one row per closed-loop run (condition, ``param``, seed, avoidances, crashes);
    ``measures``: one row per profiling run (condition, seed, one column per measure in
    :data:`MEASURES`, the condition's scene as the run saw it). A condition's success is the
    mean of its seeds' shares (as ``boundary`` computes it); its measure the mean over its
    profiling runs. ρ's interval: :func:`~analysis.predictors.inference.rho_interval` on the
    hierarchical bootstrap (conditions, then seeds within them, the same draws for every
    measure); its p: the exact permutation p over conditions. Returns :data:`PREDICTOR_COLUMNS`."""
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
        succ0 = np.array([s.mean() for s in shares])
        meas0 = np.array([np.nanmean(mtab[c], 0) for c in used])
        fails = succ0 < target
        n_fail = int(fails.sum())
        succ_b, drawn = hierarchical_means(_padded(shares), rng, BOOTSTRAP)
        meas_b, _ = hierarchical_means(_padded([mtab[c] for c in used]), rng, BOOTSTRAP, drawn)
        rho: dict[str, float] = {}
        ci: dict[str, tuple[float, float]] = {}
        for j, name in enumerate(names):
            x = meas0[:, j]
            ok = np.isfinite(x)
            r, p = permutation_p(x, 1 - succ0, rng)
            xb = meas_b[:, :, j]
            fin = np.isfinite(xb).all(1)
            boot = spearman_rows(xb[fin], 1 - succ_b[fin]) if ok.all() else None
            rho[name], ci[name] = r, rho_interval(r, int(ok.sum()), boot)
            rows.append(_row(name, value, "rho_failure", r, *ci[name], int(ok.sum()),
                             "condition", n_fail, p))  # fmt: skip
            # leave-one-condition-out needs >= 2 failing and >= 2 passing conditions: with
            # one, the held-out failing condition leaves no failure to fit a threshold on,
            # and a perfect predictor would score 0.5
            enough = min(int(fails[ok].sum()), int((~fails[ok]).sum())) >= 2
            loco = loco_threshold(x, fails) if enough else math.nan
            loco_ci = loco_interval(x, fails, rng) if enough else (math.nan, math.nan)
            rows.append(_row(name, value, "loco_balanced_accuracy", loco, *loco_ci,
                             int(ok.sum()), "condition", n_fail))  # fmt: skip
        for ref in AVDMS:
            if ref not in rho:
                continue
            for j, name in enumerate(names):
                if name == ref or (name in AVDMS and names.index(name) < names.index(ref)):
                    continue
                r12 = finite_spearman(meas0[:, names.index(ref)], meas0[:, j])
                d, lo, hi, p = rho_difference(rho[ref], ci[ref], rho[name], ci[name], r12, m)
                stat = f"paired_rho_failure_vs_{ref}"
                rows.append(_row(name, value, stat, d, lo, hi, m, "condition", n_fail, p,
                                 _role(ref, name, stat)))  # fmt: skip
        unit = pl.DataFrame(meas0, schema=names, orient="row")
        rows += _combined_rows(unit, 1 - succ0, value, "condition", n_fail)
    return _table(rows, "arena")


def _judged(rows: list[dict[str, Any]], mode: str) -> list[dict[str, Any]]:
    """Verdicts: comparison rows (a ``role``) with fewer units than the power calculation
    asks for (:data:`MIN_CONDITIONS`, :data:`MIN_FAILURES`) get "too few ... to judge"; the
    primary comparison is judged at 5 %; the rest by Holm's adjusted p over the whole table
    (every value of the parameter), each saying whether it survives."""
    cmp = [r for r in rows if r["role"] is not None]
    for r in cmp:
        if mode == "arena" and r["n"] < MIN_CONDITIONS:
            r["verdict"] = f"too few conditions to judge ({r['n']}; {MIN_CONDITIONS} needed)"
        elif mode == "footage" and (r["n_failures"] or 0) < MIN_FAILURES:
            r["verdict"] = f"too few failures to judge ({r['n_failures']}; {MIN_FAILURES} needed)"
        elif not math.isfinite(r["p_value"]):
            r["verdict"] = "undetermined"
    family = [r for r in cmp if r.get("verdict") is None and r["role"] == "secondary"]
    adj = holm(np.array([r["p_value"] for r in family]))
    for r, a in zip(family, adj, strict=True):
        r["p_holm"] = float(a)
    for r in cmp:
        if r.get("verdict") is not None:
            continue
        p = r["p_value"] if r["role"] == "primary" else r["p_holm"]  # the primary: uncorrected
        r["survives"] = bool(p < ALPHA)
        r["verdict"] = (
            ("better" if r["estimate"] > 0 else "worse") if r["survives"] else "no difference shown"
        )
    return rows


def _table(rows: list[dict[str, Any]], mode: str) -> pl.DataFrame:
    schema = {
        "measure": pl.String,
        "value": pl.Float64,
        "statistic": pl.String,
        "estimate": pl.Float64,
        "ci_low": pl.Float64,
        "ci_high": pl.Float64,
        "n": pl.Int64,
        "n_failures": pl.Int64,
        "unit": pl.String,
        "p_value": pl.Float64,
        "p_holm": pl.Float64,
        "role": pl.String,
        "survives": pl.Boolean,
        "verdict": pl.String,
    }
    rows = _judged(rows, mode)
    full = [{k: r.get(k) for k in schema} for r in rows]
    return pl.DataFrame(full, schema=schema).with_columns(
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
    """The predictor table of a labelled collection; its units are the clips.

    ``clips``: one row per clip and value (clip, ``param``, correct, optionally ``failure``:
    :data:`FAILURE_MODES` or ``hit``/``quiet``, and one column per measure: its mean over the
    scene the detector faced); ``frames``: one row per frame and value (clip, ``param``,
    frame, positive, keep, one column per measure). AUROC intervals: Newcombe's, frames
    clustered by clip (:func:`~analysis.predictors.inference.auroc_interval`); paired
    differences by the (clustered) DeLong covariance. Returns :data:`PREDICTOR_COLUMNS`."""
    del seed  # every interval here is analytic: nothing is drawn
    names = measures_present(clips.columns)
    rows: list[dict[str, Any]] = []
    for (value,), g in clips.group_by(param, maintain_order=True):
        wrong = ~g["correct"].to_numpy().astype(bool)
        X = g.select(names).to_numpy().astype(float)
        rows += _auroc_rows(names, X, wrong, value, "clip_auroc", "clip")
        if "failure" in g.columns:
            kind = g["failure"].to_numpy()
            for mode, (stat, pool) in FAILURE_MODES.items():
                sel = np.isin(kind, (mode, *pool))
                if sel.any():
                    rows += _auroc_rows(names, X[sel], kind[sel] == mode, value, stat, "clip")
        f = frames.filter((pl.col(param) == value) & pl.col("keep"))
        names_f = [m for m in names if m in f.columns]
        if f.height:
            fx = f.select(names_f).to_numpy().astype(float)
            pos = f["positive"].to_numpy().astype(bool)
            clip = f["clip"].to_numpy()
            rows += _auroc_rows(names_f, fx, pos, value, "frame_auroc_pooled", "frame", clip)
            rows += _within_clip_rows(names_f, fx, pos, clip, value)
        rows += _combined_rows(g.select(names), wrong.astype(float), value, "clip",
                               int(min(wrong.sum(), (~wrong).sum())))  # fmt: skip
    return _table(rows, "footage")


def _auroc_rows(names: list[str], X: np.ndarray, pos: np.ndarray, value: float, stat: str,
                unit: str, cluster: np.ndarray | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Each measure's AUROC (X (N, M), pos (N,)) with its interval, and (for the headline
    and the frame statistics) each AVDM against the others, paired on the same units."""
    rows = []
    for j, name in enumerate(names):
        ok = np.isfinite(X[:, j])
        a, lo, hi = auroc_interval(X[:, j], pos, cluster)
        fewer = int(min(pos[ok].sum(), (~pos[ok]).sum()))
        rows.append(_row(name, value, stat, a, lo, hi, int(ok.sum()), unit, fewer))
    if stat not in ("clip_auroc", "frame_auroc_pooled"):
        return rows
    for ref, i, j, name in _avdm_pairs(names):
        ok = np.isfinite(X[:, i]) & np.isfinite(X[:, j])
        d, lo, hi, p = auroc_difference(X[:, i], X[:, j], pos, cluster)
        fewer = int(min(pos[ok].sum(), (~pos[ok]).sum()))
        st = f"paired_{stat}_vs_{ref}"
        rows.append(_row(name, value, st, d, lo, hi, int(ok.sum()), unit, fewer, p,
                         _role(ref, name, st)))  # fmt: skip
    return rows


def _within_clip_rows(names: list[str], fx: np.ndarray, pos: np.ndarray, clip: np.ndarray,
                      value: float) -> list[dict[str, Any]]:  # fmt: skip
    """The mean over clips (with both kinds of frame) of each clip's own frame AUROC: a
    t-interval over those clips; each AVDM against the others by a paired t over them."""
    ids = list(dict.fromkeys(clip.tolist()))
    per = []
    for c in ids:
        sel = clip == c
        if pos[sel].any() and not pos[sel].all():
            per.append(auroc_matrix(fx[sel], pos[sel]))
    per_clip = np.array(per).reshape(len(per), len(names))
    rows = []
    stat = "frame_auroc_within_clip"
    for j, name in enumerate(names):
        v = per_clip[:, j]
        e = mean_ci(v, bounds=(0.0, 1.0))
        # clips that all score alike give a t-interval of no width: at least Newcombe's for
        # one pair per clip, the least information the clips could hold
        lo, hi = newcombe_interval(e.mean, e.n, e.n)
        lo, hi = min(e.low, float(lo)), max(e.high, float(hi))
        rows.append(_row(name, value, stat, e.mean, lo, hi, e.n, "clip", e.n))
    for ref, i, j, name in _avdm_pairs(names):
        d = per_clip[:, i] - per_clip[:, j]
        st = f"paired_{stat}_vs_{ref}"
        n = int(np.isfinite(d).sum())
        rows.append(_t_row(name, value, st, d, "clip", n, _role(ref, name, st)))
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

"""The boundary as a fitted crossing with a 95 % interval (issue #34).

Success against complexity is modelled, per parameter value, as a **monotone logistic curve**
that falls as complexity rises (a psychometric function without lapses)::

    p(x) = f + (1 - f) * expit(logit((target - f) / (1 - f)) - b * (x - t) / span),   b >= 0

so ``t`` *is* the boundary (the complexity where the curve crosses the target), ``b`` the
steepness (log-odds per span of the data) and ``f`` a floor the success falls to and not below
(LGMD+ keeps avoiding some approaches on the busiest walls: without a floor a steep fall to a
plateau of 50 % is fitted as a shallow fall to 0, and misplaced). Each run contributes its
counts (``k`` successes of ``n`` trials: avoidances of avoidances + crashes in the arena, one
hit or miss per clip in footage mode), a binomial likelihood.

* **The fit** is exact on a grid: ``t`` on 401 points over the design's range widened by half
  its span on each side, ``b`` on 0 and 60 log-spaced steepnesses up to a step (500 log-odds
  per span), ``f`` on 0 to 0.75 (below the target) in steps of 0.15, profiled out as ``b``
  is; every likelihood evaluated in NumPy (``scipy.special`` for the stable logs).
  Seeds of one condition often differ by more than binomial noise, and a whole scene can
  depart from the curve (LGMD+'s do): the likelihood is divided by the Pearson dispersion
  ``phi`` (at least 1) of the *conditions'* pooled counts about the best fit, the
  quasi-likelihood correction with the condition as the unit (:func:`dispersion`; runs with
  one trial each, as clips, have none); with ``phi`` estimated, the cut-offs below are F
  quantiles with ``conditions - 2`` degrees of freedom in place of chi2's. (A per-run
  dispersion treated a condition's seeds as independent: 35-65 % coverage under a condition
  effect of sd 0.5 on the log-odds.) The steepness is profiled continuously (a parabola
  through the grid's best and its neighbours), and the interval's ends are interpolated
  between grid points.
* **The scene is the unit** where runs name 2 or more scenes (``scene``): the conditions of
  one scene (its TFs) share the scene's departure from the curve, which no dispersion over
  conditions sees (0.875 coverage on the default 2 x 3 grid under a scene effect of sd 0.5,
  0.765 with 10-minute runs, 0.765 on 8 x 6). The scale is then the scenes' jackknife
  (:func:`scene_dispersion`: the crossing's variance with each scene left out, over its
  model variance), never below the conditions' ``phi``, with F(1, scenes - 1) as the
  cut-off; the wider of this and the conditions' interval is kept. Why this and not the
  alternatives: a dispersion of the scenes' pooled counts has scenes - 2 (to 3) degrees of
  freedom, none on the default grid of 2 scenes; a GLMM's scene variance rests on 1 degree
  of freedom too, and where it is estimated as 0 its interval is the conditions'; a
  bootstrap over 2 (or 8) scenes has 2 (8) distinct draws. The jackknife needs only the
  per-scene scores and information at the fit (one Newton step per scene left out, no
  refit: the fit costs the same), and its t reference on scenes - 1 degrees of freedom is
  the few-cluster rule (Cameron, Gelbach & Miller 2008); the floor at ``phi`` keeps two
  scenes that agree by chance (1 degree of freedom) from making the interval narrower
  than the conditions show. With 2 scenes the cut-off is F(1, 1) = 161: the interval is wide,
  often unbounded, which is what 2 scenes know about the population of scenes; 8 scenes of
  6 TFs place it to 2.8 deg/s. What is estimated is the population's boundary: where the
  success averaged over scenes, conditions and seeds crosses the target (a pooled binomial
  fit's estimand), 0.3 deg/s below the median scene's under a scene effect of sd 0.5.
* **The 95 % interval** is the profile-likelihood interval of ``t``: every ``t`` whose best
  curve is within ``chi2(1, 0.95) / 2`` (deviance 3.84, scaled by ``phi``) of the best one.
  Where that set reaches an edge of the widened range, that side is unbounded.
* **The band** drawn with the curve is the range of every curve in the joint 95 % set of
  ``(t, b, f)`` (deviance 5.99): pointwise, at most as wide as a simultaneous band.
* **States.** ``within``: the interval is bounded on both sides; ``beyond``: its lower end lies
  above the design's most complex point (success is above the target at 95 % confidence
  everywhere on it); ``below``: its upper end lies below the least complex point; else
  ``undetermined`` ("more seeds or runs needed", with the interval as far as it goes). A flat
  curve at the target (``b = 0``) fits every ``t`` equally, so data that cannot tell a
  crossing from no crossing leave the interval unbounded: undetermined, never "beyond".
* **Where to run next** (:meth:`CrossingFit.sample`): ``t`` drawn from the normalised
  likelihood over the grid (flat prior on ``t`` and on log ``b``), i.e. runs go where the
  crossing still plausibly is, in proportion to how plausible.

Why scipy and not scikit-learn or a Bayesian package: scipy is already a dependency; a
two-parameter monotone curve on one axis needs no more than a likelihood on a grid, which is
exact (no Laplace approximation, as scikit-learn's GP classifier uses) and takes milliseconds;
scikit-learn's ``LogisticRegression`` cannot constrain the slope's sign and gives no interval
for the crossing; AEPsych would bring PyTorch.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.stats import scipy_special, scipy_stats

N_T = 401  # boundary candidates over the widened range
SLOPES = np.concatenate([[0.0], np.geomspace(0.05, 500.0, 60)])  # log-odds per span
FLOORS = np.array([0.0, 0.15, 0.3, 0.45, 0.6, 0.75])  # the success complexity cannot lower
WIDEN = 0.5  # the widened range: half the design's span on each side
# chi-square quantiles, as scipy.stats.chi2.ppf(0.95, 1 and 2) gives them (a test holds them
# to it, bit for bit): written out so that importing the fit does not import scipy.stats
DEVIANCE_1 = 3.841458820694124  # the boundary's interval
DEVIANCE_2 = 5.991464547107979  # the band of curves
UNDETERMINED = "undetermined: more seeds or runs needed"
UNDETERMINED_STATE = "undetermined"


@dataclasses.dataclass(frozen=True)
class CrossingFit:
    """One fitted curve. Complexity in the caller's units (deg/s or Hz)."""

    state: str  # "within", "beyond", "below" or "undetermined"
    boundary: float  # the best fit's crossing (NaN when nothing was fitted)
    low: float  # the 95 % interval's ends; -inf / inf where unbounded
    high: float
    domain: tuple[float, float]  # the design's range
    dispersion: float  # phi, >= 1
    runs: int
    t_grid: np.ndarray  # (N_T,) candidate crossings
    weights: np.ndarray  # (N_T,) normalised likelihood of each (sums to 1)
    curve_x: np.ndarray  # (M,) the curve drawn over the domain
    curve_p: np.ndarray  # (M,) the best fit's success
    band_low: np.ndarray  # (M,) the 95 % band
    band_high: np.ndarray
    unit: str = "run"  # what the interval's scale treats as independent: run, condition, scene
    n_units: int = 0  # how many of them
    scene_dispersion: float = math.nan  # the scenes' jackknife scale (NaN: fewer than 2 scenes)

    @property
    def width(self) -> float:
        return self.high - self.low

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """``size`` crossings drawn from the normalised likelihood, clipped to the domain:
        where the next runs go."""
        t = rng.choice(self.t_grid, size=size, p=self.weights)
        return np.clip(t, *self.domain)

    def success(self, x: np.ndarray | float) -> np.ndarray:
        """The best fit's success at complexity ``x``."""
        return np.interp(x, self.curve_x, self.curve_p)


def fit_crossing(
    x: Sequence[float] | np.ndarray,
    k: Sequence[float] | np.ndarray,
    n: Sequence[float] | np.ndarray,
    target: float,
    domain: tuple[float, float] | None = None,
    condition: Sequence[Any] | np.ndarray | None = None,
    *,
    scene: Sequence[Any] | np.ndarray | None = None,
    band: bool = True,
) -> CrossingFit:
    """Fit the monotone logistic curve to runs at complexity ``x`` (R,) with ``k`` successes of
    ``n`` trials each and find where it crosses ``target``; ``domain`` is the range the design
    could visit (default: the runs' own range). Runs with no trial are left out.

    ``condition`` (R,) names the condition (scene and TF) of each run, default: runs at the
    same complexity share one. The dispersion is the conditions' (their pooled counts about
    the curve, :func:`dispersion`), so a condition that departs from the curve as a whole
    widens the interval, not only seeds that differ. ``scene`` (R,) names each run's scene:
    with 2 or more, the scene is the unit (:func:`scene_dispersion`, F(1, scenes - 1)), so a
    scene whose conditions all depart from the curve widens it too; the fit's ``unit`` and
    ``n_units`` say which unit it took (scene, condition or run). ``band=False`` skips the
    95 % band of curves (the coverage tests need only the interval)."""
    x, k, n = (np.asarray(v, float).ravel() for v in (x, k, n))
    keep = (n > 0) & np.isfinite(x) & np.isfinite(k)
    cond = np.asarray(x if condition is None else condition).ravel()[keep]
    sc = None if scene is None else np.asarray(scene).ravel()[keep]
    x, k, n = x[keep], k[keep], n[keep]
    lo, hi = domain if domain is not None else ((x.min(), x.max()) if x.size else (0.0, 1.0))
    lo, hi = float(min(lo, hi)), float(max(lo, hi))
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    t_grid = np.linspace(lo - WIDEN * span, hi + WIDEN * span, N_T)
    curve_x = np.linspace(lo, hi, 101)
    if x.size == 0 or np.ptp(x) == 0:  # nothing, or one complexity: no slope to fit
        flat = np.full(curve_x.shape, float(k.sum() / n.sum()) if n.size else math.nan)
        return CrossingFit(
            UNDETERMINED_STATE,
            math.nan,
            -math.inf,
            math.inf,
            (lo, hi),
            1.0,
            int(x.size),
            t_grid,
            np.full(N_T, 1.0 / N_T),
            curve_x,
            flat,
            np.zeros_like(flat),
            np.ones_like(flat),
        )
    u = (x - lo) / span
    tu = (t_grid - lo) / span
    floors = FLOORS[FLOORS < target - 0.05]
    floor_of = np.repeat(floors, SLOPES.size)  # (S,) every (floor, steepness) pair
    slope_of = np.tile(SLOPES, floors.size)
    # The likelihood depends on a run only through its complexity: runs at one complexity
    # (the seeds of a condition) pool their counts, so the (N_T, slopes, X) arrays below span
    # the distinct complexities X, not the runs R (a grid's seeds: R / X times less work)
    ux, at = np.unique(u, return_inverse=True)
    kx, fx = np.bincount(at, k, ux.size), np.bincount(at, n - k, ux.size)
    ll = np.empty((N_T, slope_of.size))
    for j0 in range(0, slope_of.size, SLOPES.size):  # one floor at a time: (N_T, slopes, X)
        g = floor_of[j0]
        e = _eta(target, g, SLOPES[None, :, None], ux[None, None, :], tu[:, None, None])
        log_e = scipy_special().log_expit(e)
        log_q = math.log1p(-g) + log_e - e  # log(1 - g) + log expit(-e)
        log_p = log_e if g == 0 else np.logaddexp(math.log(g), math.log1p(-g) + log_e)
        ll[:, j0 : j0 + SLOPES.size] = log_p @ kx + log_q @ fx
    best = np.unravel_index(np.argmax(ll), ll.shape)
    p_best = _curve(target, floor_of[best[1]], slope_of[best[1]], u, tu[best[0]])
    p_best = np.clip(p_best, 0.01, 0.99)  # a step's 1 - 1e-9 would make one crash a 'misfit'
    phi, df = dispersion(k, n, p_best, cond)
    phi_conditions = phi
    if df > 0:  # phi is estimated: the F quantiles in place of chi2's (quasi-likelihood)
        cut_1 = float(scipy_stats().f.ppf(0.95, 1, df))
        cut_2 = 2.0 * float(scipy_stats().f.ppf(0.95, 2, df))
    else:
        cut_1, cut_2 = DEVIANCE_1, DEVIANCE_2
    unit, n_units = ("condition", int(np.unique(cond).size)) if df > 0 else ("run", int(x.size))
    n_scenes = 0 if sc is None else int(np.unique(sc).size)
    phi_s = math.nan
    if n_scenes >= 2:  # the scene is the unit: its jackknife scale, F(1, scenes - 1)
        phi_s = scene_dispersion(
            u, k, n, target, floor_of[best[1]], _refined_slope(ll, best), tu[best[0]], sc
        )
        cut_s = float(scipy_stats().f.ppf(0.95, 1, n_scenes - 1))
        # never below the conditions' scale (a floor: see scene_dispersion), and the wider
        # of the two intervals
        if max(phi, phi_s) * cut_s > phi * cut_1:
            phi, cut_1 = max(phi, phi_s), cut_s
            cut_2 = 2.0 * float(scipy_stats().f.ppf(0.95, 2, n_scenes - 1))
        unit, n_units = "scene", n_scenes
    top = _refined_max(ll, floors.size)  # (N_T,) the profile over a continuous steepness
    dev = 2.0 * (max(top.max(), ll.max()) - ll) / phi  # (N_T, S)
    profile = 2.0 * (max(top.max(), ll.max()) - np.maximum(top, ll.max(1))) / phi
    low, high = _crossings(t_grid, profile, cut_1)
    plateau = np.flatnonzero(profile <= profile.min() + 1e-9)  # a step leaves a flat optimum
    boundary = float(t_grid[plateau].mean())
    w = np.exp(-0.5 * profile)
    weights = w / w.sum()
    if low > hi:
        state = "beyond"
    elif high < lo:
        state = "below"
    elif math.isinf(low) or math.isinf(high):
        state = UNDETERMINED_STATE
    else:
        state = "within"
    cu = (curve_x - lo) / span
    curve_p = _curve(target, floor_of[best[1]], slope_of[best[1]], cu, tu[best[0]])
    band_low, band_high = np.ones_like(cu), np.zeros_like(cu)
    ti, sj = np.nonzero(dev <= cut_2) if band else (np.zeros(0, int), np.zeros(0, int))
    for start in range(0, ti.size, 4096):  # every curve of the joint 95 % set
        sl = slice(start, start + 4096)
        g, b = floor_of[sj[sl], None], slope_of[sj[sl], None]
        p = _curve(target, g, b, cu[None, :], tu[ti[sl], None])
        band_low = np.minimum(band_low, p.min(0))
        band_high = np.maximum(band_high, p.max(0))
    if not band:
        band_low, band_high = curve_p.copy(), curve_p.copy()
    return CrossingFit(
        state,
        boundary,
        low,
        high,
        (lo, hi),
        phi_conditions,
        int(x.size),
        t_grid,
        weights,
        curve_x,
        curve_p,
        band_low,
        band_high,
        unit,
        n_units,
        phi_s,
    )


def dispersion(k: np.ndarray, n: np.ndarray, p: np.ndarray, cond: np.ndarray) -> tuple[float, int]:
    """The Pearson dispersion ``phi`` (at least 1) and its degrees of freedom, of the
    conditions' pooled counts about the fitted success ``p`` (R,): χ² over C conditions /
    (C − 2). Runs of one condition share its departure from the curve (a scene effect), so
    the condition, not the run, is the unit; seeds that differ more than binomially inflate
    their condition's count too. Fewer than 3 conditions: the runs' own dispersion (R − 2
    degrees of freedom); runs of one trial each (clips) carry none: (1, 0)."""
    _, inv = np.unique(cond, return_inverse=True)
    c = inv.max() + 1
    kc = np.bincount(inv, k, c)
    nc = np.bincount(inv, n, c)
    pc = np.bincount(inv, n * p, c) / nc  # the curve's success, trial-weighted
    if c > 2 and (nc > 1).any():
        chi2 = ((kc - nc * pc) ** 2 / np.maximum(nc * pc * (1 - pc), 1e-12)).sum()
        return max(1.0, float(chi2 / (c - 2))), int(c - 2)
    if k.size > 2 and (n > 1).any():
        chi2 = ((k - n * p) ** 2 / np.maximum(n * p * (1 - p), 1e-12)).sum()
        return max(1.0, float(chi2 / (k.size - 2))), int(k.size - 2)
    return 1.0, 0


def scene_dispersion(
    u: np.ndarray,
    k: np.ndarray,
    n: np.ndarray,
    target: float,
    floor: float,
    slope: float,
    tu: float,
    scene: np.ndarray,
) -> float:
    """The scenes' scale for the crossing's interval: the delete-one-scene jackknife variance
    of the crossing ``t`` over its model (binomial) variance, (G - 1) / G sum_g (d_g - mean)^2
    / (J^-1)_tt, where d_g is the change in (t, log b) with scene g left out, one Newton step
    from the fit: (J - J_g)^-1 S_g (S_g, J_g: scene g's score and information at the fit, the
    floor held at its fitted value). Used with F(1, G - 1) (:func:`fit_crossing`). ``u``,
    ``tu``: complexity and crossing in spans from the domain's start; ``slope``: per span.
    inf where leaving a scene out leaves a curve the others cannot place."""
    _, inv = np.unique(scene, return_inverse=True)
    g = int(inv.max()) + 1
    sp = scipy_special()
    s = sp.expit(_eta(target, floor, slope, u, tu))
    p = floor + (1 - floor) * s
    # d log-likelihood / d eta = (k - n p) s / p; its Fisher weight n (1 - f) s^2 (1 - s) / p
    # (1 - p = (1 - f)(1 - s): stable where p is near 1)
    score_eta = (k - n * p) * s / np.maximum(p, 1e-12)
    weight = n * (1 - floor) * s**2 * (1 - s) / np.maximum(p, 1e-12)
    deriv = np.column_stack([np.full_like(u, slope), -slope * (u - tu)])  # d eta / d(t, log b)
    scores = np.zeros((g, 2))
    np.add.at(scores, inv, score_eta[:, None] * deriv)
    infos = np.zeros((g, 2, 2))
    np.add.at(infos, inv, weight[:, None, None] * deriv[:, :, None] * deriv[:, None, :])
    info = infos.sum(0)
    try:
        bread = np.linalg.inv(info)
        # each scene left out, one Newton step from the fit: the jackknife's pseudo-fits
        shifts = np.stack([np.linalg.solve(info - infos[i], scores[i]) for i in range(g)])
    except np.linalg.LinAlgError:  # the scenes left cannot place a curve: nothing known
        return math.inf
    shifts -= shifts.mean(0)
    robust = (g - 1) / g * float((shifts[:, 0] ** 2).sum())
    model = bread[0, 0]
    return float(robust / model) if model > 0 and math.isfinite(robust) else math.inf


def _refined_slope(ll: np.ndarray, best: tuple[Any, ...]) -> float:
    """The steepness of the best fit off the grid: the vertex of the parabola (in log
    steepness) through the best grid steepness at the best crossing and its neighbours."""
    s = SLOPES.size
    j = int(best[1]) % s
    row = ll[best[0], (int(best[1]) // s) * s : (int(best[1]) // s + 1) * s]
    if j < 2 or j > s - 2:
        return float(SLOPES[j])
    y0, y1, y2 = row[j - 1], row[j], row[j + 1]
    curv = y2 - 2 * y1 + y0
    step = math.log(SLOPES[2] / SLOPES[1])
    off = float(np.clip(0.5 * (y0 - y2) / curv, -1, 1)) if curv < 0 else 0.0
    return float(SLOPES[j] * math.exp(off * step))


def _refined_max(ll: np.ndarray, floors: int) -> np.ndarray:
    """Per boundary candidate, the log-likelihood maximised over a continuous steepness: the
    vertex of the parabola through the best grid steepness and its two neighbours (in log
    steepness, where the grid is even). The grid's 17 % steps alone made the profile jagged
    with many trials, and its interval too narrow (a nuisance on a coarse grid)."""
    s = SLOPES.size
    a = ll.reshape(ll.shape[0], floors, s)[:, :, 1:]  # the log-spaced steepnesses (not 0)
    j = np.clip(a.argmax(2), 1, s - 3)
    y0, y1, y2 = (np.take_along_axis(a, (j + d)[..., None], 2)[..., 0] for d in (-1, 0, 1))
    curv = y2 - 2 * y1 + y0
    with np.errstate(invalid="ignore", divide="ignore"):
        vertex = np.where(curv < 0, y1 - (y2 - y0) ** 2 / (8 * curv), y1)
    vertex = np.minimum(vertex, y1 + np.abs(y2 - y0))  # a flat, noisy top: no overshoot
    return np.maximum(vertex, a.max(2)).max(1)


def _crossings(t: np.ndarray, profile: np.ndarray, cut: float) -> tuple[float, float]:
    """The interval's ends: where the profile deviance crosses ``cut``, interpolated
    linearly between grid points (the ends snapped to the grid covered 69 % with long runs);
    ±inf where the set reaches an end of the widened range."""
    inside = np.flatnonzero(profile <= cut)
    i, j = inside[0], inside[-1]

    def between(a: int, b: int) -> float:
        pa, pb = profile[a], profile[b]
        f = (cut - pa) / (pb - pa) if pb != pa else 0.5
        return float(t[a] + f * (t[b] - t[a]))

    low = -math.inf if i == 0 else between(i - 1, i)
    high = math.inf if j == len(t) - 1 else between(j, j + 1)
    return low, high


def _eta(target: float, floor: Any, slope: Any, u: Any, t: Any) -> Any:
    """The logistic part's log-odds: it makes floor + (1 - floor) expit(eta) = target at t."""
    return scipy_special().logit((target - floor) / (1 - floor)) - slope * (u - t)


def _curve(target: float, floor: Any, slope: Any, u: Any, t: Any) -> Any:
    """Success at ``u`` (the complexity in spans from the domain's start) of one curve."""
    return floor + (1 - floor) * scipy_special().expit(_eta(target, floor, slope, u, t))


# --- units: wall TF <-> profile ------------------------------------------------------------


def tf_to_dps(tf_hz: Any, profile_tf: Sequence[float], profile_dps: Sequence[float]) -> Any:
    """The profile's complexity (deg/s) at wall TF ``tf_hz``: linear interpolation between
    the measured profile points (one scene), extrapolated linearly past its ends."""
    tf, dps = _monotone(profile_tf, profile_dps)
    x = np.asarray(tf_hz, float)
    if tf.size == 1:
        return np.full_like(x, dps[0]) if x.ndim else float(dps[0])
    out = np.interp(x, tf, dps)
    lo_slope = (dps[1] - dps[0]) / (tf[1] - tf[0])
    hi_slope = (dps[-1] - dps[-2]) / (tf[-1] - tf[-2])
    out = np.where(x < tf[0], dps[0] + lo_slope * (x - tf[0]), out)
    out = np.where(x > tf[-1], dps[-1] + hi_slope * (x - tf[-1]), out)
    return float(out) if np.ndim(out) == 0 else out


def dps_to_tf(dps_value: Any, profile_tf: Sequence[float], profile_dps: Sequence[float]) -> Any:
    """The wall TF (Hz) at which the profile reaches ``dps_value``: the inverse of
    :func:`tf_to_dps` (the profile made non-decreasing first); NaN for a flat profile; ±inf
    stay ±inf."""
    tf, dps = _monotone(profile_tf, profile_dps)
    v = np.asarray(dps_value, float)
    if tf.size < 2 or dps[-1] <= dps[0]:
        out = np.full(v.shape, math.nan)
    else:
        dense_tf = np.linspace(tf[0] - 10 * (tf[-1] - tf[0]), tf[-1] + 10 * (tf[-1] - tf[0]), 4001)
        dense = np.maximum.accumulate(tf_to_dps(dense_tf, tf, dps))
        out = np.interp(v, dense, dense_tf)
        out = np.where(np.isinf(v), v, out)
    return float(out) if np.ndim(out) == 0 else out


def _monotone(tf: Sequence[float], dps: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Profile points sorted by TF, repeated TFs averaged, made non-decreasing (a running
    maximum: noise between close TFs must not fold the map back)."""
    tf_a, dps_a = np.asarray(tf, float), np.asarray(dps, float)
    ok = np.isfinite(tf_a) & np.isfinite(dps_a)
    tf_a, dps_a = tf_a[ok], dps_a[ok]
    uniq = np.unique(tf_a)
    mean = np.array([dps_a[tf_a == v].mean() for v in uniq])
    return uniq, np.maximum.accumulate(mean) if mean.size else mean


# --- the boundary table's columns and phrase -------------------------------------------------


def fit_columns(fit: CrossingFit, to_tf: Any = None) -> dict[str, Any]:
    """The fitted boundary as ``boundary.parquet`` columns: ``fit_state``, ``boundary_dps``
    with ``boundary_dps_low``/``_high`` (±inf where unbounded), the same in wall TF
    (``boundary_tf_hz``, ``boundary_tf_low``, ``boundary_tf_high``; NaN without a profile
    map ``to_tf``: deg/s → Hz), ``fit_runs`` and ``fit_dispersion``."""
    # a speed is never negative: the logistic extrapolated below the least complex point
    # gave "< -0.3 deg/s" on footage whose simplest clips already fail; such an end is 0
    # (an unbounded low end stays -inf: "at or below the least complex point")
    speeds = [v if not math.isfinite(v) else max(v, 0.0) for v in (fit.boundary, fit.low, fit.high)]
    row = {
        "fit_state": fit.state,
        "boundary_dps": speeds[0],
        "boundary_dps_low": speeds[1],
        "boundary_dps_high": speeds[2],
    }
    names = ("boundary_tf_hz", "boundary_tf_low", "boundary_tf_high")
    tf = [
        float(to_tf(v)) if to_tf is not None and not math.isnan(v) else math.nan
        for v in (fit.boundary, fit.low, fit.high)
    ]
    # a wall TF is a drift speed, never below 0 Hz: the profile's line extrapolated past its
    # lowest TF gave "wall TF < -0.05 Hz". An interval wholly below 0 Hz lies below the
    # scene's complexity at rest: no TF of this scene is the boundary (NaN, not a number that
    # cannot be run); otherwise the ends stop at 0
    if tf[2] < 0:
        tf = [math.nan] * 3
    tf = [max(v, 0.0) if not math.isnan(v) else v for v in tf]
    return (
        row
        | dict(zip(names, tf, strict=True))
        | {"fit_runs": fit.runs, "fit_dispersion": fit.dispersion}
        | {"unit": fit.unit, "n_units": fit.n_units}
    )


def with_fit(bounds: pl.DataFrame, fitted: pl.DataFrame, by: str, design: str) -> pl.DataFrame:
    """The bracketing boundaries (:func:`analysis.boundary.statistics.boundaries`: ``where``,
    ``boundary_low_dps``, ``boundary_high_dps``; its interpolated point renamed
    ``bracket_dps``) with the fitted columns (:func:`fit_columns`) beside them, and the
    ``design``."""
    return (
        bounds.rename({"boundary_dps": "bracket_dps"})
        .join(fitted, on=by, how="left")
        .with_columns(pl.lit(design).alias("design"))
    )


def grid_fits(
    runs: pl.DataFrame,
    complexity: pl.DataFrame,
    by: str,
    target: float,
    scene: str | None = None,
) -> tuple[pl.DataFrame, dict[float, CrossingFit]]:
    """The fitted boundary per value of ``by`` from a grid's runs (condition, ``by``,
    avoidances, crashes; scene and tf_hz for the TF columns) and its conditions' complexity
    (condition, complexity_dps): each run at its condition's complexity. The TF columns map
    deg/s to wall TF through ``scene``'s conditions (default: the first scene's)."""
    data = runs.join(complexity.select("condition", "complexity_dps"), on="condition", how="left")
    domain = (float(data["complexity_dps"].min()), float(data["complexity_dps"].max()))
    to_tf = None
    if "scene" in data.columns and "tf_hz" in data.columns:
        scene = scene or str(data["scene"][0])
        prof = data.filter(pl.col("scene") == scene).unique("condition")
        tf_pts, dps_pts = prof["tf_hz"].to_numpy(), prof["complexity_dps"].to_numpy()
        if np.unique(tf_pts).size >= 2:

            def to_tf(d: float) -> float:
                return float(dps_to_tf(d, tf_pts, dps_pts))

    rows, fits = [], {}
    for (value,), g in data.group_by(by, maintain_order=True):
        f = fit_crossing(
            g["complexity_dps"].to_numpy(),
            g["avoidances"].to_numpy(),
            (g["avoidances"] + g["crashes"]).to_numpy(),
            target,
            domain,
            g["condition"].to_numpy(),  # its seeds share the condition's departure
            scene=g["scene"].to_numpy() if "scene" in g.columns else None,  # and its scene's
        )
        fits[value] = f
        rows.append({by: value} | fit_columns(f, to_tf))
    return pl.DataFrame(rows), fits


def draw_fit(ax: Any, fit: CrossingFit, color: str, ls: str = "-") -> None:
    """The fitted curve (success, %; line style ``ls``) with its 95 % band and the boundary's
    interval (shaded, to the edge of the axis where unbounded) and estimate (dashed) on a
    matplotlib axis."""
    ax.plot(fit.curve_x, 100 * fit.curve_p, color=color, lw=2, ls=ls)
    ax.fill_between(fit.curve_x, 100 * fit.band_low, 100 * fit.band_high, color=color, alpha=0.12)
    lo, hi = fit.domain
    a = max(fit.low, lo - 0.5 * (hi - lo))
    b = min(fit.high, hi + 0.5 * (hi - lo))
    if a < b:
        ax.axvspan(a, b, ymin=0.0, ymax=0.04, color=color, alpha=0.5)
    if fit.state == "within":
        ax.axvline(fit.boundary, color=color, ls="--", lw=1)

"""Intervals and tests over the units that vary (issues 42, 57), for the predictors.

A prediction question's independent units are its **scenes** where its conditions (arena) or
clips (footage) share them, else the conditions or clips; seeds and frames are nested inside
them. Every interval here is over those units:

* Spearman ρ over conditions: a Fisher-z interval whose standard error is the wider of
  Bonett & Wright's (2000) over conditions and a bootstrap's: over scenes, the cluster
  bootstrap (:func:`cluster_draws`: scenes drawn with all their conditions; Davison & Hinkley
  1997, §3.8; Field & Welsh 2007) with t on scenes − 1 degrees of freedom and a one-sided p
  from the same standard error (:func:`rho_p_clustered`); over conditions, the hierarchical
  bootstrap (conditions, then seeds within each) and an exact permutation p (one-sided, the
  sign fixed in advance: a higher measure, more failure): every permutation up to
  :data:`EXACT_UP_TO` conditions, else :data:`PERMUTATIONS` random ones.
* AUROC: Newcombe's (2006, Stat. Med. 25:559, method 5) score interval, which keeps its width
  when the classes separate (a percentile bootstrap collapses to [1, 1] there and missed a
  true 0.993 in half of the repeats at n = 30); with units clustered (clips in scenes, frames
  in clips or scenes), its sample sizes divided by the design effect of Obuchowski's (1997,
  Biometrics 53:567) clustered DeLong variance (or the delete-one-cluster jackknife's,
  :func:`jackknife_cov`, where wider) and its quantile t on clusters − 1 degrees of freedom.
* Two measures on the same units: paired AUROCs by the (clustered) DeLong covariance of their
  difference; two dependent Spearman ρ by Steiger's (1980) Z on Fisher's z (the Bonett–Wright
  variance, or the cluster bootstrap's where wider) with Zou's (2007, Psychol. Methods 12:399)
  interval for the difference.
* Means of per-unit values: the cluster-robust variance (:func:`cluster_mean`).
* With few clusters a normal reference over-rejects (Cameron, Gelbach & Miller 2008; Cameron &
  Miller 2015): every clustered interval and test is referred to t on clusters − 1 degrees of
  freedom (:func:`t_quantile`).
* Many comparisons: Holm's (1979) step-down adjustment, valid under any dependence.

Everything is NumPy, vectorised over measures or repeats (the coverage tests run thousands).
"""

from __future__ import annotations

import math

import numpy as np

from analysis.stats import ALPHA, scipy_stats

# scipy.stats.norm.ppf(0.5 + analysis.stats.CONFIDENCE / 2) (a test holds it to it, bit for
# bit): written out so that importing the predictors does not import scipy.stats
Z = 1.959963984540054
BOOTSTRAP = 1000  # resamples for every bootstrap interval of the predictors
EXACT_UP_TO = 8  # 8! = 40,320 permutations: exact; beyond, Monte Carlo
PERMUTATIONS = 20_000  # Monte Carlo permutations: p's own standard error <= 0.0035
RHO_CAP = 0.999  # |rho| = 1 has an infinite Fisher z: capped (an interval end near +-1)


# --- AUROC -------------------------------------------------------------------------------------


def newcombe_interval(
    a: np.ndarray | float, n1: np.ndarray | float, n0: np.ndarray | float, z: float = Z
) -> tuple[np.ndarray, np.ndarray]:
    """Newcombe's score interval for an AUROC ``a`` from ``n1`` positives and ``n0``
    negatives (arrays broadcast; float sample sizes allowed: effective sizes). The ends are the
    θ where (a − θ)² = z² V(θ), V the Hanley–McNeil variance with n₁ − 1 and n₀ − 1 replaced by
    N − 1, N = (n₁ + n₀)/2; found by bisection (60 halvings: 1e-18 of the unit interval). NaN
    where a is NaN or a class is empty. ``z``: the quantile (a t quantile over few clusters)."""
    a, n1, n0 = np.broadcast_arrays(*(np.asarray(v, float) for v in (a, n1, n0)))
    ok = np.isfinite(a) & (n1 > 0) & (n0 > 0)
    a_ = np.where(ok, a, 0.5)
    n1_, n0_ = np.where(ok, n1, 1.0), np.where(ok, n0, 1.0)
    big_n = (n1_ + n0_) / 2

    def excess(theta: np.ndarray) -> np.ndarray:  # > 0 outside the interval
        var = (
            theta
            * (1 - theta)
            / (n1_ * n0_)
            * (1 + (big_n - 1) * (1 - theta) / (2 - theta) + (big_n - 1) * theta / (1 + theta))
        )
        return (a_ - theta) ** 2 - z**2 * var

    def root(outer: np.ndarray) -> np.ndarray:  # between outer (excess >= 0) and a (<= 0)
        lo, hi = outer.copy(), a_.copy()
        for _ in range(60):
            mid = (lo + hi) / 2
            out = excess(mid) > 0
            lo, hi = np.where(out, mid, lo), np.where(out, hi, mid)
        return (lo + hi) / 2

    low, high = root(np.zeros_like(a_)), root(np.ones_like(a_))
    return np.where(ok, low, np.nan), np.where(ok, high, np.nan)


def placements(x: np.ndarray, positive: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DeLong's placement values of each column of x (N, M) (finite): per positive, the share
    of negatives it outscores (ties half), (N₁, M); per negative, the share of positives that
    outscore it, (N₀, M). Their means are the AUROC."""

    positive = np.asarray(positive, bool)
    n1, n0 = int(positive.sum()), int((~positive).sum())
    r_all = scipy_stats().rankdata(x, axis=0)
    r_pos = scipy_stats().rankdata(x[positive], axis=0)
    r_neg = scipy_stats().rankdata(x[~positive], axis=0)
    v10 = (r_all[positive] - r_pos) / n0
    v01 = 1.0 - (r_all[~positive] - r_neg) / n1
    return v10, v01


def delong_cov(
    x: np.ndarray, positive: np.ndarray, cluster: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The AUROCs of the columns of x (N, M) (finite) and their covariance (M, M): DeLong's,
    or with ``cluster`` (N,) labels Obuchowski's clustered form, each cluster (clip) a unit
    whose frames' placements are summed. Needs both classes and 2 clusters; else NaN."""
    positive = np.asarray(positive, bool)
    m = x.shape[1]
    n1, n0 = int(positive.sum()), int((~positive).sum())
    if n1 == 0 or n0 == 0:
        return np.full(m, np.nan), np.full((m, m), np.nan)
    v10, v01 = placements(x, positive)
    a = v10.mean(0)
    if cluster is None:
        s10 = np.atleast_2d(np.cov(v10, rowvar=False)) if n1 > 1 else np.zeros((m, m))
        s01 = np.atleast_2d(np.cov(v01, rowvar=False)) if n0 > 1 else np.zeros((m, m))
        return a, s10 / n1 + s01 / n0
    _, inv = np.unique(np.asarray(cluster), return_inverse=True)
    k = inv.max() + 1
    if k < 2:
        return a, np.full((m, m), np.nan)
    sum10 = np.zeros((k, m))
    sum01 = np.zeros((k, m))
    np.add.at(sum10, inv[positive], v10)
    np.add.at(sum01, inv[~positive], v01)
    m_i = np.bincount(inv[positive], minlength=k)[:, None]
    n_i = np.bincount(inv[~positive], minlength=k)[:, None]
    d10 = sum10 - m_i * a  # (K, M)
    d01 = sum01 - n_i * a
    f = k / (k - 1)
    s10 = f * d10.T @ d10 / n1
    s01 = f * d01.T @ d01 / n0
    s11 = f * d10.T @ d01
    return a, s10 / n1 + s01 / n0 + (s11 + s11.T) / (n1 * n0)


def jackknife_cov(x: np.ndarray, positive: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """The delete-one-cluster jackknife covariance (M, M) of the AUROCs of the columns of x
    (N, M) (finite): each cluster left out in turn, the AUROC of the rest from the pair sums
    (all pairs, less the cluster's positives' and negatives' pairs, plus its own pairs, counted
    twice). ((K − 1)/K Σ (A₍g₎ − Ā)(A₍g₎ − Ā)ᵀ; NaN where a cluster holds a whole class.)
    Wider than Obuchowski's with few clusters, as the jackknife is (CR3 against CR1)."""
    positive = np.asarray(positive, bool)
    m = x.shape[1]
    _, inv = np.unique(np.asarray(cluster), return_inverse=True)
    k = int(inv.max()) + 1
    n1, n0 = int(positive.sum()), int((~positive).sum())
    v10, v01 = placements(x, positive)
    pos_sum = np.zeros((k, m))
    neg_sum = np.zeros((k, m))
    np.add.at(pos_sum, inv[positive], v10 * n0)  # pairs of a cluster's positives with all
    np.add.at(neg_sum, inv[~positive], v01 * n1)  # pairs of all positives with its negatives
    # each cluster's own pairs: ranks within the cluster, all at once (a key that sorts by
    # cluster, then value; equal only for equal values in one cluster), less the ranks of the
    # clusters before it
    n = len(inv)
    dense = scipy_stats().rankdata(x, method="dense", axis=0)
    key = inv[:, None] * (n + 1.0) + dense
    before_all = np.concatenate([[0], np.cumsum(np.bincount(inv, minlength=k))])[inv]
    before_pos = np.concatenate([[0], np.cumsum(np.bincount(inv[positive], minlength=k))])
    r_all = scipy_stats().rankdata(key, axis=0) - before_all[:, None]
    r_pos = scipy_stats().rankdata(key[positive], axis=0) - before_pos[inv[positive]][:, None]
    own = np.zeros((k, m))
    np.add.at(own, inv[positive], r_all[positive] - r_pos)
    m1 = np.bincount(inv[positive], minlength=k)[:, None]
    m0 = np.bincount(inv[~positive], minlength=k)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        left = (n1 * n0 * v10.mean(0) - pos_sum - neg_sum + own) / ((n1 - m1) * (n0 - m0))
    if not np.isfinite(left).all() or k < 2:
        return np.full((m, m), np.nan)
    d = left - left.mean(0)
    return (k - 1) / k * d.T @ d


def t_quantile(clusters: int) -> float:
    """The two-sided 95 % quantile of Student's t on ``clusters`` − 1 degrees of freedom: the
    reference of every clustered interval and test here (Cameron & Miller 2015); NaN below 2."""
    if clusters < 2:
        return math.nan
    return float(scipy_stats().t.ppf(1 - ALPHA / 2, clusters - 1))


def auroc_interval(
    x: np.ndarray, positive: np.ndarray, cluster: np.ndarray | None = None
) -> tuple[float, float, float]:
    """One measure's AUROC (x (N,), NaN rows left out) with its 95 % interval: Newcombe's, on
    sample sizes divided by the design effect of the clusters (clustered DeLong variance over
    the unclustered; where both are 0, at separation, the units per cluster of each class),
    with a t quantile on K − 1 degrees of freedom for K clusters (a normal one without)."""
    x, positive = np.asarray(x, float), np.asarray(positive, bool)
    ok = np.isfinite(x)
    x, positive = x[ok], positive[ok]
    n1, n0 = int(positive.sum()), int((~positive).sum())
    if n1 == 0 or n0 == 0:
        return math.nan, math.nan, math.nan
    a, var_iid = delong_cov(x[:, None], positive)
    deff, z = 1.0, Z
    if cluster is not None:
        cl = np.asarray(cluster)[ok]
        k = len(np.unique(cl))
        if k < 2:  # one cluster: no interval over clusters
            return float(a[0]), math.nan, math.nan
        z = t_quantile(k)
        _, var_c = delong_cov(x[:, None], positive, cl)
        var_c = np.fmax(var_c, jackknife_cov(x[:, None], positive, cl))  # the wider
        if var_iid[0, 0] > 0 and np.isfinite(var_c[0, 0]):
            deff = max(1.0, float(var_c[0, 0] / var_iid[0, 0]))
        else:
            k1 = len(np.unique(cl[positive]))
            k0 = len(np.unique(cl[~positive]))
            deff = max(1.0, n1 / k1, n0 / k0)
    lo, hi = newcombe_interval(a[0], n1 / deff, n0 / deff, z)
    return float(a[0]), float(lo), float(hi)


def auroc_difference(
    x1: np.ndarray, x2: np.ndarray, positive: np.ndarray, cluster: np.ndarray | None = None
) -> tuple[float, float, float, float]:
    """AUROC of x1 minus that of x2 on the same units (rows where both are finite), with its
    95 % interval and two-sided p from the (clustered) DeLong covariance: with ``cluster``,
    Obuchowski's, referred to t on K − 1 degrees of freedom (K clusters). (estimate, low, high,
    p); a zero variance with a zero difference gives p = 1."""

    x = np.column_stack([x1, x2]).astype(float)
    ok = np.isfinite(x).all(1)
    pos = np.asarray(positive, bool)[ok]
    if pos.all() or not pos.any():
        return math.nan, math.nan, math.nan, math.nan
    cl = None if cluster is None else np.asarray(cluster)[ok]
    a, cov = delong_cov(x[ok], pos, cl)
    d = float(a[0] - a[1])
    var = float(cov[0, 0] + cov[1, 1] - 2 * cov[0, 1])
    if cl is not None:  # the wider of Obuchowski's and the jackknife's
        jack = jackknife_cov(x[ok], pos, cl)
        var = float(np.fmax(var, jack[0, 0] + jack[1, 1] - 2 * jack[0, 1]))
    if not math.isfinite(var):
        return d, math.nan, math.nan, math.nan
    se = math.sqrt(max(var, 0.0))
    if se == 0:
        return d, d, d, 1.0 if d == 0 else 0.0
    if cl is None:
        return d, d - Z * se, d + Z * se, float(2 * scipy_stats().norm.sf(abs(d) / se))
    k = len(np.unique(cl))
    q = t_quantile(k)
    return d, d - q * se, d + q * se, float(2 * scipy_stats().t.sf(abs(d) / se, k - 1))


# --- means over clusters ------------------------------------------------------------------------


def cluster_mean(
    v: np.ndarray, cluster: np.ndarray | None = None
) -> tuple[float, float, float, float, int]:
    """The mean of per-unit values ``v`` (N,) (NaN left out) with its 95 % interval and the
    two-sided p of a zero mean: with ``cluster`` (N,) labels the cluster-robust variance (CR1:
    the clusters' summed residuals, × K/(K − 1)) on t with K − 1 degrees of freedom (Cameron &
    Miller 2015); without, Student's t over the units. (mean, low, high, p, units or clusters)."""
    v = np.asarray(v, float)
    ok = np.isfinite(v)
    v = v[ok]
    n = len(v)
    if cluster is None:
        cl = np.arange(n)
    else:
        cl = np.asarray(cluster)[ok]
    if n == 0:
        return math.nan, math.nan, math.nan, math.nan, 0
    _, inv = np.unique(cl, return_inverse=True)
    k = int(inv.max()) + 1
    mean = float(v.mean())
    if k < 2:
        return mean, math.nan, math.nan, math.nan, k
    resid = np.bincount(inv, weights=v - mean, minlength=k)
    se = math.sqrt(k / (k - 1) * float((resid**2).sum())) / n
    q = t_quantile(k)
    if se == 0:
        return mean, mean, mean, 1.0 if mean == 0 else 0.0, k
    p = float(2 * scipy_stats().t.sf(abs(mean) / se, k - 1))
    return mean, mean - q * se, mean + q * se, p, k


def cluster_draws(cluster: np.ndarray, rng: np.random.Generator, boots: int) -> np.ndarray:
    """The cluster bootstrap's draws (Davison & Hinkley 1997, §3.8, resampling the top stage;
    Field & Welsh 2007): K clusters drawn with replacement, each with all its units.
    ``cluster`` (N,) labels; returns (B, K × the largest cluster) unit indices, −1 where a
    drawn cluster has fewer units than the largest (no unit)."""
    _, inv = np.unique(np.asarray(cluster), return_inverse=True)
    k = int(inv.max()) + 1
    sizes = np.bincount(inv, minlength=k)
    members = np.full((k, sizes.max()), -1)
    for g in range(k):
        members[g, : sizes[g]] = np.flatnonzero(inv == g)
    drawn = rng.integers(0, k, (boots, k))
    return members[drawn].reshape(boots, -1)


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


def spearman_masked(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman ρ of each row pair of x, y (B, L), NaN entries left out of both: (B,); NaN
    where a row holds fewer than 3 pairs or is constant."""
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.all() and x.shape[1] >= 3:  # nothing left out (clusters of one size): plain ranks
        return spearman_rows(x, y)
    x, y = np.where(ok, x, np.nan), np.where(ok, y, np.nan)
    rx = scipy_stats().rankdata(x, axis=1, nan_policy="omit")
    ry = scipy_stats().rankdata(y, axis=1, nan_policy="omit")
    with np.errstate(invalid="ignore", divide="ignore"):
        rx = rx - np.nanmean(rx, 1, keepdims=True)
        ry = ry - np.nanmean(ry, 1, keepdims=True)
        den = np.sqrt(np.nansum(rx**2, 1) * np.nansum(ry**2, 1))
        rho = np.nansum(rx * ry, 1) / np.where(den > 0, den, 1.0)
    return np.where((den > 0) & (ok.sum(1) >= 3), rho, math.nan)


# --- Spearman rho over conditions ---------------------------------------------------------------


def _z(rho: np.ndarray | float) -> np.ndarray:
    return np.arctanh(np.clip(rho, -RHO_CAP, RHO_CAP))


def rho_se(rho: np.ndarray | float, n: int) -> np.ndarray:
    """Bonett & Wright's (2000) standard error of Fisher's z of a Spearman ρ over n units."""
    return np.sqrt((1 + np.asarray(rho, float) ** 2 / 2) / max(n - 3, 1))


def _rho_z_se(rho: float, n: int, boot: np.ndarray | None) -> tuple[float, float]:
    """Fisher's z of ρ and its standard error: the wider of Bonett–Wright's over ``n`` units
    and the standard deviation of z over the bootstrap's ρ (``boot``)."""
    se = float(rho_se(rho, n))
    # |rho| = 1 has no finite z: capped half a step below it (Spearman's values step by
    # 12 / (n (n^2 - 1)) next to 1), so a perfect order on few conditions keeps a width
    cap = 1 - 6 / (n * (n**2 - 1))
    if boot is not None:
        b = np.asarray(boot, float)
        b = b[np.isfinite(b)]
        if len(b) >= 10:
            se = max(se, float(np.arctanh(np.clip(b, -cap, cap)).std(ddof=1)))
    return float(np.arctanh(np.clip(rho, -cap, cap))), se


def rho_interval(
    rho: float, n: int, boot: np.ndarray | None = None, clusters: int | None = None
) -> tuple[float, float]:
    """The 95 % interval of a Spearman ρ over ``n`` conditions: Fisher z ± q × the wider of
    the Bonett–Wright standard error and the standard deviation of z over the bootstrap's ρ
    (``boot``: conditions then seeds resampled, or with ``clusters`` scenes). q: 1.96, or with
    ``clusters`` K the t quantile on K − 1 degrees of freedom. NaN below 4 conditions or 2
    clusters."""
    if not math.isfinite(rho) or n < 4 or (clusters is not None and clusters < 2):
        return math.nan, math.nan
    z, se = _rho_z_se(rho, n, boot)
    q = Z if clusters is None else t_quantile(clusters)
    return float(np.tanh(z - q * se)), float(np.tanh(z + q * se))


def rho_p_clustered(rho: float, n: int, boot: np.ndarray, clusters: int) -> float:
    """One-sided p of a Spearman ρ over ``n`` conditions in ``clusters`` scenes (a higher
    measure, more failure): Fisher's z over its cluster-bootstrap standard error
    (:func:`rho_interval`'s) on t with K − 1 degrees of freedom. A permutation of conditions
    is not valid here: conditions that share a scene are not exchangeable."""
    if not math.isfinite(rho) or n < 4 or clusters < 2:
        return math.nan
    z, se = _rho_z_se(rho, n, boot)
    return float(scipy_stats().t.sf(z / se, clusters - 1))


def permutation_p(
    x: np.ndarray, y: np.ndarray, rng: np.random.Generator | None = None
) -> tuple[float, float]:
    """Spearman ρ of x and y (N,) (finite pairs) and its one-sided permutation p (a higher x
    goes with a higher y): the share of orderings of y over the units with a ρ at least the
    observed (the observed ordering counted), by ``scipy.stats.permutation_test`` (pairings):
    exact up to :data:`EXACT_UP_TO` units, else :data:`PERMUTATIONS` random orderings drawn
    from ``rng`` (None: ``default_rng(0)``, so a call without one repeats its p), with p =
    (1 + at least as high) / (1 + PERMUTATIONS). The orderings drawn are ``rng.permuted``'s
    on the tiled indices, the ones this function drew itself before it called scipy: the same
    ``rng`` gives the same p as it did then."""

    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    rx, ry = scipy_stats().rankdata(x[ok]), scipy_stats().rankdata(y[ok])
    n = len(rx)
    rx, ry = rx - rx.mean(), ry - ry.mean()
    den = math.sqrt((rx**2).sum() * (ry**2).sum())
    if n < 3 or den == 0:
        return math.nan, math.nan
    rho = float(rx @ ry / den)
    # each ordering's ρ · den · 4, from ranks doubled: whole numbers, exact in float64, so an
    # ordering whose ρ equals the observed counts as at least it (scipy's own tolerance is
    # relative, none at ρ = 0)
    rx2 = 2 * rx
    res = scipy_stats().permutation_test(
        (2 * ry,),
        lambda r, axis: r @ rx2,
        permutation_type="pairings",
        vectorized=True,
        n_resamples=math.factorial(n) if n <= EXACT_UP_TO else PERMUTATIONS,
        alternative="greater",
        rng=rng or np.random.default_rng(0),
    )
    return rho, float(res.pvalue)


def rho_difference(
    r1: float,
    ci1: tuple[float, float],
    r2: float,
    ci2: tuple[float, float],
    r12: float,
    n: int,
    boot: tuple[np.ndarray, np.ndarray] | None = None,
    clusters: int | None = None,
) -> tuple[float, float, float, float]:
    """Two Spearman ρ with one variable in common (the failure rate), over the same ``n``
    conditions: (r1 − r2, low, high, two-sided p). The interval is Zou's from each ρ's own
    interval; p is Steiger's Z on Fisher's z (the correlation between the two estimates from
    r12, the two measures' own ρ, Bonett–Wright's variance factor). With ``clusters`` (K
    scenes) and ``boot`` (the two ρ over the same cluster-bootstrap draws): the z difference's
    standard error is the wider of Steiger's and the bootstrap's, referred to t on K − 1
    degrees of freedom, and Zou's correlation of the two estimates is the bootstrap's."""

    vals = (r1, r2, r12, *ci1, *ci2)
    if n < 4 or not all(math.isfinite(v) for v in vals):
        return r1 - r2, math.nan, math.nan, math.nan
    rbar2 = ((r1 + r2) / 2) ** 2
    s = (r12 * (1 - 2 * rbar2) - 0.5 * rbar2 * (1 - 2 * rbar2 - r12**2)) / (1 - rbar2) ** 2
    var = 2 * (1 - s) * (1 + rbar2 / 2) / (n - 3)
    zdiff = float(_z(r1) - _z(r2))
    c = ((r12 - r1 * r2 / 2) * (1 - r1**2 - r2**2 - r12**2) + r12**3) / max(
        (1 - r1**2) * (1 - r2**2), 1e-12
    )
    if clusters is None or boot is None:
        p = float(2 * scipy_stats().norm.sf(abs(zdiff) / math.sqrt(var))) if var > 0 else 1.0
    else:
        b1, b2 = (np.asarray(b, float) for b in boot)
        fin = np.isfinite(b1) & np.isfinite(b2)
        if fin.sum() >= 10:
            var = max(var, float((_z(b1[fin]) - _z(b2[fin])).var(ddof=1)))
            if b1[fin].std() > 0 and b2[fin].std() > 0:
                c = float(np.corrcoef(b1[fin], b2[fin])[0, 1])
        p = (
            float(2 * scipy_stats().t.sf(abs(zdiff) / math.sqrt(var), clusters - 1))
            if var > 0 and clusters >= 2
            else math.nan
        )
    c = min(max(c, -1.0), 1.0)
    l1, u1 = ci1
    l2, u2 = ci2
    d = r1 - r2
    low = d - math.sqrt(max((r1 - l1) ** 2 + (u2 - r2) ** 2 - 2 * c * (r1 - l1) * (u2 - r2), 0))
    high = d + math.sqrt(max((u1 - r1) ** 2 + (r2 - l2) ** 2 - 2 * c * (u1 - r1) * (r2 - l2), 0))
    return d, low, high, p


# --- many comparisons ---------------------------------------------------------------------------


def holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (NaN stays NaN, left out of the family): reject at α
    where the adjusted p < α; family-wise error ≤ α under any dependence."""
    p = np.asarray(p, float)
    out = np.full(p.shape, np.nan)
    idx = np.flatnonzero(np.isfinite(p))
    m = len(idx)
    if not m:
        return out
    order = idx[np.argsort(p[idx], kind="stable")]
    adj = np.maximum.accumulate((m - np.arange(m)) * p[order])
    out[order] = np.minimum(adj, 1.0)
    return out


# --- the hierarchical bootstrap -----------------------------------------------------------------


def hierarchical_means(
    per_seed: np.ndarray, rng: np.random.Generator, boots: int, conditions: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Two-stage resampling of a (C, S, ...) array of per-seed values (NaN-padded where a
    condition has fewer seeds): conditions drawn with replacement (``conditions`` (B, C) if
    given, so that several tables share them), then seeds with replacement within each drawn
    condition. Returns the (B, C, ...) means of the drawn seeds and the conditions drawn."""
    v = np.asarray(per_seed, float)
    c = v.shape[0]
    counts = np.isfinite(v.reshape(c, v.shape[1], -1)).all(2).sum(1)  # seeds per condition
    if conditions is None:
        conditions = rng.integers(0, c, (boots, c))
    cnt = counts[conditions]  # (B, C)
    seeds = np.floor(rng.random((*conditions.shape, v.shape[1])) * cnt[..., None]).astype(int)
    use = np.arange(v.shape[1]) < cnt[..., None]  # the first cnt draws of each condition
    drawn = v[conditions[..., None], seeds]  # (B, C, S, ...)
    mask = use.reshape(*use.shape, *([1] * (v.ndim - 2)))
    with np.errstate(invalid="ignore"):
        means = np.where(mask, drawn, 0.0).sum(2) / cnt.reshape(*cnt.shape, *([1] * (v.ndim - 2)))
    return means, conditions

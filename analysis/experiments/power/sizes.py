"""How many arena conditions and footage clips the plan needs (docs/findings/power_plan.md).

Two comparisons, each of the AVDM against P.910 TI on the same units:

* **arena**: Spearman ρ between a condition's measure and its failure rate, the AVDM's ρ₁
  against TI's ρ₂ over the same conditions, the two measures correlated ρ₁₂ with each other.
  A test of two dependent correlations sharing one variable (Meng, Rosenthal & Rubin 1992,
  Psychol. Bull. 111:172, the Fisher-z form of Steiger 1980): ``z = (z₁ − z₂) ·
  sqrt((n − 3) / (2 (1 − ρ₁₂) h))`` with ``h = (1 − f r̄²) / (1 − r̄²)``, ``f = min(1,
  (1 − ρ₁₂) / (2 (1 − r̄²)))`` and ``r̄²`` the mean of ρ₁² and ρ₂². For Spearman's ρ the
  Fisher-z variance is ``1.06 / (n − 3)`` (Fieller, Hartley & Pearson 1957), so n − 3 grows by
  1.06.
* **footage**: AUROC of each measure for a clip's failure, the AVDM's A₁ against TI's A₂ on the
  same clips, the two AUROC estimates correlated r. Each AUROC's variance is Hanley & McNeil's
  (1982, Radiology 143:29): ``(A(1 − A) + (n₁ − 1)(Q₁ − A²) + (n₀ − 1)(Q₂ − A²)) / (n₁ n₀)``,
  ``Q₁ = A / (2 − A)``, ``Q₂ = 2A² / (1 + A)``; the difference's is ``V₁ + V₂ − 2r√(V₁V₂)``
  (Hanley & McNeil 1983, Radiology 148:839).

Both are two-sided at ``alpha`` with power ``power``; the smallest n that reaches it is
returned. The tests check both by simulation.
"""

from __future__ import annotations

import math

import numpy as np

from analysis.boundary.footage import judge_clip
from analysis.stats import scipy_stats

SPEARMAN_Z_VARIANCE = 1.06  # Fieller, Hartley & Pearson 1957: var(z of Spearman) ≈ 1.06/(n-3)


def conditions_for_correlation_difference(
    rho1: float,
    rho2: float,
    rho12: float,
    *,
    alpha: float = 0.05,
    power: float = 0.8,
    spearman: bool = True,
) -> int:
    """Independent conditions needed to tell correlation ``rho1`` from ``rho2`` (both with the
    same outcome, the two measures correlated ``rho12``), two-sided ``alpha``, ``power``."""

    for name, v in (("rho1", rho1), ("rho2", rho2), ("rho12", rho12)):
        if not -1 < v < 1:
            raise ValueError(f"{name} must be between -1 and 1, got {v}")
    if rho1 == rho2:
        raise ValueError("rho1 equals rho2: no sample tells them apart")
    r2bar = (rho1**2 + rho2**2) / 2
    f = min(1.0, (1 - rho12) / (2 * (1 - r2bar)))
    h = (1 - f * r2bar) / (1 - r2bar)
    dz = math.atanh(rho1) - math.atanh(rho2)
    k = (scipy_stats().norm.ppf(1 - alpha / 2) + scipy_stats().norm.ppf(power)) ** 2
    scale = SPEARMAN_Z_VARIANCE if spearman else 1.0
    return math.ceil(3 + scale * k * 2 * (1 - rho12) * h / dz**2)


def auroc_variance(auc: float, failures: int, passes: int) -> float:
    """Hanley & McNeil's variance of an AUROC ``auc`` over ``failures`` and ``passes`` clips."""
    q1 = auc / (2 - auc)
    q2 = 2 * auc**2 / (1 + auc)
    return (auc * (1 - auc) + (failures - 1) * (q1 - auc**2) + (passes - 1) * (q2 - auc**2)) / (
        failures * passes
    )


def auroc_difference_power(
    auc1: float, auc2: float, r: float, clips: int, failure_share: float, alpha: float = 0.05
) -> float:
    """Power of the paired two-sided test of ``auc1`` against ``auc2`` on ``clips`` clips of
    which ``failure_share`` fail, the two AUROC estimates correlated ``r``."""

    n1 = max(1, round(clips * failure_share))
    n0 = max(1, clips - n1)
    v1, v2 = auroc_variance(auc1, n1, n0), auroc_variance(auc2, n1, n0)
    sd = math.sqrt(max(v1 + v2 - 2 * r * math.sqrt(v1 * v2), 1e-300))
    z = abs(auc1 - auc2) / sd
    crit = scipy_stats().norm.ppf(1 - alpha / 2)
    return float(scipy_stats().norm.cdf(z - crit) + scipy_stats().norm.cdf(-z - crit))


def clips_for_auroc_difference(
    auc1: float,
    auc2: float,
    r: float,
    failure_share: float,
    *,
    alpha: float = 0.05,
    power: float = 0.8,
) -> tuple[int, int]:
    """(clips, failures among them) needed to tell AUROC ``auc1`` from ``auc2``."""
    if not (0.5 <= auc1 < 1 and 0.5 <= auc2 < 1 and auc1 != auc2):
        raise ValueError(f"AUROCs must differ and lie in [0.5, 1), got {auc1}, {auc2}")
    if not (0 < failure_share < 1 and -1 < r < 1):
        raise ValueError("failure_share must be in (0, 1) and r in (-1, 1)")

    def enough(n: int) -> bool:
        return auroc_difference_power(auc1, auc2, r, n, failure_share, alpha) >= power

    hi = 4
    while not enough(hi):  # power grows with the clips: double, then bisect
        hi *= 2
        if hi > 10_000_000:
            raise ValueError("more than ten million clips: the difference is too small to test")
    lo = hi // 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if enough(mid) else (mid, hi)
    clips = hi
    return clips, max(1, round(clips * failure_share))


# --- what counts as a failure (docs/findings/power_plan.md) -------------------------------

MIN_TTC_S = 0.5  # an alert later than this before contact is a miss: no time left to turn
OUTCOMES = ("hit", "miss", "early alert", "false alarm", "correct rejection")
# footage mode's ``failure`` column, as the plan names each outcome
OUTCOME_OF_FAILURE = dict(
    zip(("hit", "miss", "early", "false_alarm", "quiet"), OUTCOMES, strict=True)
)


def footage_outcome(
    alert: np.ndarray,
    fps: float,
    collision_frame: int | None,
    hazard_onset_frame: int | None,
    min_ttc_s: float = MIN_TTC_S,
) -> str:
    """A clip's outcome for a detector's ``alert`` (T,) (> 0: alert), by the plan's rules:

    * an alert before the hazard's onset (or anywhere, when nothing is ever in view) on a clip
      with a hazard is an **early alert** (the scene alone set it off);
    * collision: the first alert from the onset on is a **hit** when it leaves at least
      ``min_ttc_s`` before contact, else (late, or none) a **miss**;
    * near miss (no collision frame): any alert from the onset on is a **false alarm**, none a
      **correct rejection**.

    The rules are footage mode's (``analysis.boundary.footage.judge_clip``, with the onset),
    so the plan's pilot and the boundary runs the study makes judge a clip alike."""
    onset = hazard_onset_frame if hazard_onset_frame is not None else len(alert)
    frames = np.arange(len(alert))
    # the window is not used where the onset is given
    row = judge_clip(frames, alert, fps, collision_frame, math.inf, min_ttc_s, onset)
    return OUTCOME_OF_FAILURE[row["failure"]]


# --- clustered scenes (the amended plan, docs/findings/power_plan_amendment.md) -----------
#
# Units that share a scene are not independent: n units in scenes of m each carry the
# information of n / DE independent ones, DE = 1 + (m - 1) ICC (Kish 1965; Donner & Klar
# 2000, ch. 5), ICC the share of a unit's variance that its scene sets. So G scenes of m
# units are worth at most G m / (1 + (m - 1) ICC) < G / ICC independent units, however many
# units each scene has: past that, only more scenes add power.


def design_effect(per_scene: float, icc: float) -> float:
    """Kish's design effect of ``per_scene`` units per scene at intra-scene correlation
    ``icc``."""
    if per_scene < 1 or not 0 <= icc <= 1:
        raise ValueError(f"need per_scene >= 1 and icc in [0, 1], got {per_scene}, {icc}")
    return 1 + (per_scene - 1) * icc


def effective_units(scenes: int, per_scene: int, icc: float) -> float:
    """The independent units ``scenes`` scenes of ``per_scene`` units each are worth."""
    return scenes * per_scene / design_effect(per_scene, icc)


def scenes_for(independent: int, per_scene: int, icc: float, min_scenes: int = 20) -> int:
    """Scenes of ``per_scene`` units each that carry ``independent`` independent units at
    ``icc`` (at least ``min_scenes``, the floor of a clustered test's validity)."""
    return max(min_scenes, math.ceil(independent * design_effect(per_scene, icc) / per_scene))


def per_scene_for(independent: int, scenes: int, icc: float) -> int | None:
    """Units per scene that make ``scenes`` scenes carry ``independent`` independent units at
    ``icc``; None where no number can (``independent`` >= scenes / icc)."""
    if independent <= scenes:
        return 1
    if icc > 0 and independent * icc >= scenes:
        return None
    # G m / (1 + (m - 1) icc) >= n  <=>  m (G - n icc) >= n (1 - icc)
    return math.ceil(independent * (1 - icc) / (scenes - independent * icc))

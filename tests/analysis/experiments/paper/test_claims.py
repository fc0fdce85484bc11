"""Claims across seeds: intervals, trend tests and verdicts on constructed tables."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest

from analysis.experiments.paper.claims import (
    CALIBRATED,
    PROFILE_CONDITIONS,
    RELEASED,
    claims_frame,
    collision_claims,
    profiling_claims,
)
from analysis.experiments.paper.report import fig6_table_markdown
from analysis.stats import (
    FAILS,
    HOLDS,
    PARTLY,
    Estimate,
    above_verdict,
    below_verdict,
    combine,
    mean_ci,
    rising_trend,
    share_ci,
    trend_verdict,
)


def test_mean_ci_is_students_t_interval() -> None:
    est = mean_ci([1.0, 2.0, 3.0])
    # t(0.975, 2) = 4.302653; s = 1; n = 3 (tables to 6 digits)
    assert est.mean == 2.0 and est.n == 3
    assert est.high - est.mean == pytest.approx(4.302653 / math.sqrt(3), rel=1e-6)
    assert mean_ci([0.01, 0.02, 0.6], bounds=(0.0, 1.0)).low == 0.0  # a share stays in [0, 1]
    one = mean_ci([5.0, float("nan")])
    assert one.n == 1 and math.isnan(one.low) and one.text() == "5.0 (n = 1)"


def test_share_ci_is_never_narrower_than_the_pooled_binomial_interval() -> None:
    # three seeds, each 4 avoidances and no crash: the t-interval alone has zero width
    est = share_ci([4, 4, 4], [4, 4, 4])
    assert est.mean == 1.0 and est.high == 1.0
    # Clopper–Pearson for 12/12 at 95 %: lower bound (0.025)^(1/12) = 0.7354
    assert est.low == pytest.approx(0.025 ** (1 / 12), rel=1e-6)
    assert above_verdict(est, 0.9) == PARTLY  # 12 events cannot establish > 90 %
    many = share_ci([400, 390, 410], [400, 391, 410])
    assert above_verdict(many, 0.9) == HOLDS


def test_trend_tests_are_exact_for_small_tables() -> None:
    perfect = np.tile([1.0, 2.0, 3.0], (5, 1)) + np.arange(5)[:, None]
    t = rising_trend(perfect)
    assert t.method == "Page's L test" and t.n == 5
    assert t.p_value == pytest.approx(1 / 6**5, rel=1e-9)  # every seed ranks the TFs 1 < 2 < 3
    assert t.min_p == pytest.approx(1 / 6**5)
    two = rising_trend(np.array([[1.0, 2.0], [1.0, 3.0], [2.0, 2.5]]))
    assert two.method == "sign test" and two.p_value == pytest.approx(0.125)
    assert "cannot reach p < 0.05" in two.text()  # 3 pairs can never give p < 0.05
    # a seed with a missing condition is left out
    assert rising_trend(np.vstack([perfect, [1.0, np.nan, 3.0]])).n == 5


@pytest.mark.parametrize(
    ("means", "p", "verdict"),
    [
        ([1.0, 2.0, 3.0], 0.001, HOLDS),
        ([1.0, 2.0, 3.0], 0.2, PARTLY),  # rising means, not significant
        ([1.0, 0.9, 3.0], 0.03, PARTLY),  # significant, not strictly rising
        ([3.0, 2.0, 1.0], 0.9, FAILS),
    ],
)
def test_trend_verdict(means: list[float], p: float, verdict: str) -> None:
    from analysis.stats import Trend

    assert trend_verdict(means, Trend(p, "test", 5, 0.0)) == verdict


def test_interval_verdicts_and_combination() -> None:
    assert above_verdict(Estimate(1.5, 1.1, 1.9, 5), 1.0) == HOLDS
    assert above_verdict(Estimate(1.5, 0.8, 2.2, 5), 1.0) == PARTLY
    assert above_verdict(Estimate(1.5, math.nan, math.nan, 1), 1.0) == PARTLY  # no interval
    assert above_verdict(Estimate(0.9, 0.5, 1.3, 5), 1.0) == FAILS
    assert below_verdict(Estimate(0.5, 0.3, 0.7, 5), 0.9) == HOLDS
    assert combine([HOLDS, HOLDS]) == HOLDS
    assert combine([HOLDS, FAILS]) == PARTLY
    assert combine([FAILS, FAILS]) == FAILS


def _summary(value, seeds: int = 5) -> pl.DataFrame:
    """A profiling summary as reproduce writes it: one row per (recording, model, motion);
    ``value(scene, tf, model, motion, seed)`` gives (frac_over_100, mean, near/centre ratio)."""
    rows = []
    for seed in range(1, seeds + 1):
        for scene, tf in PROFILE_CONDITIONS:
            for model in (CALIBRATED, RELEASED):
                for motion in ("all", "straight", "turning"):
                    frac, mean, ratio = value(scene, tf, model, motion, seed)
                    rows.append(
                        {
                            "recording_id": f"{scene}-{tf:g}-{seed}",
                            "scene": scene,
                            "seed": seed,
                            "wall_tf_hz": tf,
                            "model": model,
                            "motion": motion,
                            "frac_over_100": frac,
                            "mean": mean,
                            "near_wall_centre_ratio": ratio,
                        }
                    )
    return pl.DataFrame(rows)


def _by_claim(claims) -> dict[str, str]:
    return {c.claim.split(",")[0].split(" (")[0]: c.verdict for c in claims}


def test_profiling_claims_hold_partly_hold_or_fail_from_the_numbers() -> None:
    rng = np.random.default_rng(0)

    def rising(scene, tf, model, motion, seed):
        # every seed rises with TF, with seed-to-seed noise smaller than the steps
        base = 0.1 + 0.2 * tf + 0.02 * rng.random()
        return min(base, 1.0), 10 + 5 * tf + rng.random(), 2.0 + 0.1 * rng.random()

    summary = _summary(rising)
    claims = profiling_claims(summary)
    assert {c.verdict for c in claims} == {HOLDS}
    released = next(c for c in claims if "released code's units" in c.claim)
    assert released.p_value == pytest.approx(1 / 6**5) and released.seeds == 5
    tf3 = summary.filter(
        (pl.col("model") == RELEASED)
        & (pl.col("motion") == "all")
        & (pl.col("wall_tf_hz") == 3)
        & (pl.col("scene") == "grating")
    )
    row = next(q for q in released.quantities if q.condition == "TF 3 Hz")
    # the same mean, scaled to % (one division and a sum of 5 values apart)
    assert row.estimate == pytest.approx(100 * tf3["frac_over_100"].mean(), rel=1e-12)
    assert row.quantity == f"pct_over_100 · {RELEASED} · all" and row.n_seeds == 5

    def mixed(scene, tf, model, motion, seed):
        # the means still rise, but two of five seeds rank the TFs backwards: not significant
        up = seed <= 3
        frac = 0.1 + (0.2 * tf if up else 0.2 * (3 - tf) * 0.5)
        ratio = 1.5 if seed != 5 else 0.2  # one seed far below 1: the interval includes 1
        return frac, 10 + frac, ratio

    verdicts = _by_claim(profiling_claims(_summary(mixed)))
    assert verdicts["The count of 'AVDM > 100' rises with the walls' TF"] == PARTLY
    assert verdicts["The response"] == PARTLY

    def flat(scene, tf, model, motion, seed):
        return 0.3 - 0.01 * tf, 20.0 - tf, 0.8

    assert {c.verdict for c in profiling_claims(_summary(flat))} == {FAILS}


def test_fig6_table_lists_every_reading_with_its_test() -> None:
    """The report's Fig. 6 table is rendered from the claims' rows: the three readings that
    decide claims and the three shown beside them, each with its own trend test."""
    summary = _summary(lambda *a: (0.1 * a[1] + 0.01 * a[4], 5.0 + a[1], 1.2))
    md = fig6_table_markdown(claims_frame(profiling_claims(summary)))
    assert md.count("Page's L test") == 6 and "| TF 0 Hz | TF 1 Hz | TF 3 Hz |" in md
    assert "over 5 seeds" in md and f"pct_over_100 · {CALIBRATED} · turning" in md
    assert "natural" not in md  # the grating's readings only


def _collision(success: dict[str, tuple[int, int]], seeds: int = 5) -> pl.DataFrame:
    """A per-run collision summary: (avoidances, crashes) per phase, the same every seed."""
    rows = []
    for seed in range(1, seeds + 1):
        for phase, (a, c) in success.items():
            rows.append(
                {
                    "recording_id": f"{phase}-{seed}",
                    "phase": phase,
                    "seed": seed,
                    "detector": "lgmd-plus-arena",
                    "wall_tf_hz": 3.0 if phase.startswith("tf3") else 0.0,
                    "minutes": 30.0,
                    "avoidances": a + seed % 2,
                    "crashes": c,
                    "success_rate": (a + seed % 2) / (a + seed % 2 + c),
                    "false_alarms": 1,
                    "false_alarms_per_30min": 1.0,
                    "avoidances_per_30min": float(a + seed % 2),
                    "crashes_per_30min": float(c),
                }
            )
    return pl.DataFrame(rows)


def test_collision_claims_from_constructed_runs() -> None:
    paper_like = {
        "tf0": (229, 2),
        "tf3": (100, 80),
        "tf3-adjusted": (233, 3),
        "tf3-adaptive": (225, 2),
    }
    claims = collision_claims(_collision(paper_like))
    assert [c.verdict for c in claims] == [HOLDS, HOLDS]
    tf0 = next(
        q for q in claims[0].quantities if (q.condition, q.quantity) == ("tf0", "success_rate")
    )
    assert f"{100 * tf0.estimate:.1f}" == "99.1" and tf0.ci_low < tf0.estimate < tf0.ci_high
    # TF 3 does not break down: the protocol's claim is only partly reproduced
    no_break = {**paper_like, "tf3": (229, 2)}
    assert collision_claims(_collision(no_break))[0].verdict == PARTLY
    # a detector that crashes everywhere fails every part
    crashes = {k: (10, 90) for k in paper_like}
    claims = collision_claims(_collision(crashes))
    assert claims[0].verdict == PARTLY  # it does "break down" at TF 3, and nothing else
    assert claims[1].verdict == PARTLY  # avoidances match TF 0's, success does not
    assert (
        collision_claims(_collision({k: (10, 90) for k in ("tf0", "tf3-adaptive")}))[0].verdict
        == PARTLY
    )


def test_claims_carry_their_numbers_in_long_form() -> None:
    """claims.parquet rows: one per claim, condition and quantity, with the mean across seeds
    and its interval as numbers (here checked against the constructed runs themselves)."""
    from analysis.experiments.paper.claims import claims_frame

    runs = _collision({"tf0": (229, 2), "tf3": (100, 80), "tf3-adjusted": (233, 3)})
    table = claims_frame(collision_claims(runs))
    row = table.filter((pl.col("condition") == "tf0") & (pl.col("quantity") == "success_rate")).row(
        0, named=True
    )
    seeds = runs.filter(pl.col("phase") == "tf0")
    assert row["estimate"] == pytest.approx(float(seeds["success_rate"].mean()), rel=1e-12)
    assert row["ci_low"] < row["estimate"] < row["ci_high"]
    assert row["n_seeds"] == seeds.height and row["verdict"] in ("holds", "partly")
    assert set(table["condition"]) == {"tf0", "tf3", "tf3-adjusted"}
    assert set(table["quantity"]) == {
        "success_rate",
        "avoidances_per_30min",
        "crashes_per_30min",
        "false_alarms_per_30min",
    }

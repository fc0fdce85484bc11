"""The paper's claims, decided from the tables ``reproduce`` writes (nothing else): each claim's
text, its verdict, and the numbers behind it in long form (``claims.parquet``: one row per
claim, condition and quantity, with the mean across seeds, its 95 % interval and the test)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import polars as pl

from analysis.collision import phase_estimate, phase_statistics
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
    trend_verdict,
)

# the calibrated decoder (deg/s) and the released code's decoding (the paper's units)
CALIBRATED, RELEASED = "avdm", "avdm-released-units"
PROFILE_MODELS = (CALIBRATED, RELEASED)

PROFILE_CONDITIONS = (
    ("grating", 0.0),
    ("grating", 1.0),
    ("grating", 3.0),
    ("natural", 0.0),
    ("natural", 3.0),
)


@dataclasses.dataclass
class Quantity:
    """One number behind a claim: a quantity under one condition, its mean and 95 % interval
    across seeds, and the test the claim's verdict used (with its p-value, where it has one)."""

    condition: str  # e.g. "grating TF 3 Hz", "tf3-adjusted"
    quantity: str  # e.g. "frac_over_100", "success_rate" (in the table's units)
    estimate: float
    ci_low: float
    ci_high: float
    n_seeds: int
    test: str = ""
    p_value: float = math.nan

    @classmethod
    def of(cls, condition: str, quantity: str, e: Estimate, test: str = "", p: float = math.nan,
           scale: float = 1.0) -> Quantity:  # fmt: skip
        return cls(condition, quantity, e.mean * scale, e.low * scale, e.high * scale, e.n, test, p)


@dataclasses.dataclass
class Claim:
    claim: str
    paper: str
    measured: str
    verdict: str  # holds | partly | does not hold
    p_value: float = math.nan  # of the claim's trend test, where it has one
    seeds: int = 1  # runs per condition behind the numbers (1 for deterministic steps)
    quantities: list[Quantity] = dataclasses.field(default_factory=list)


CLAIM_COLUMNS = ("claim", "paper", "measured", "verdict", "seeds")


def claims_frame(claims: Sequence[Claim]) -> pl.DataFrame:
    """claims.parquet, in long form: one row per claim, condition and quantity (``estimate``,
    ``ci_low``, ``ci_high``, ``n_seeds``, ``test``, ``p_value``) beside the claim's text and
    verdict; a claim without numbers has one row with nulls. ``claim_index`` keeps the order."""
    rows = []
    for i, c in enumerate(claims):
        base = {"claim_index": i, **{k: getattr(c, k) for k in CLAIM_COLUMNS}}
        quantities = c.quantities or [None]
        for q in quantities:
            values = (
                dataclasses.asdict(q)
                if q is not None
                else {f.name: None for f in dataclasses.fields(Quantity)}
            )
            if q is not None and not math.isfinite(q.p_value):
                values["p_value"] = c.p_value if math.isfinite(c.p_value) else None
            rows.append({**base, **values})
    schema = {
        "claim_index": pl.Int64, "claim": pl.String, "paper": pl.String, "measured": pl.String,
        "verdict": pl.String, "seeds": pl.Int64, "condition": pl.String, "quantity": pl.String,
        "estimate": pl.Float64, "ci_low": pl.Float64, "ci_high": pl.Float64,
        "n_seeds": pl.Int64, "test": pl.String, "p_value": pl.Float64,
    }  # fmt: skip
    return pl.DataFrame(rows, schema=schema).with_columns(pl.col(pl.Float64).fill_nan(None))


def _verdict(all_ok: bool, any_ok: bool = False) -> str:
    return HOLDS if all_ok else (PARTLY if any_ok else FAILS)


def evaluate_claims(out: Path) -> list[Claim]:
    """Every claim, from the tables in ``out`` (nothing else)."""
    claims = []
    mono = pl.read_parquet(out / "sweep" / "monotonicity.parquet")
    tf_rows = mono.filter(pl.col("along") == "tf")
    sf_cols = mono.filter(pl.col("along") == "sf")
    valid_rows = tf_rows.filter(pl.col("fixed_value") < 50)
    ok_rows = bool((valid_rows["rho"] > 0.5).all())
    ok_cols = bool((sf_cols["rho"] < -0.5).all())
    rho_txt = ", ".join(f"{r['fixed']}: ρ = {r['rho']:+.2f}" for r in mono.iter_rows(named=True))
    claims.append(
        Claim(
            "The AVDM response maps monotonically onto SF–TF (Fig. 3)",
            "monotonic: rises with TF, falls with SF",
            f"Spearman ρ of ω̂ along each row/column: {rho_txt}. SF = 50 upc (2 px period, the "
            "Nyquist limit: counter-phase flicker) is not a valid motion stimulus and is excluded.",
            _verdict(ok_rows and ok_cols, ok_rows or ok_cols),
        )
    )

    ap = pl.read_parquet(out / "approach" / "approach.parquet")
    near = (
        ap.filter(pl.col("distance_m") < 0.10)
        .group_by("tf_hz")
        .agg(pl.col("omega_dps").mean().alias("near"))
        .sort("tf_hz")
    )
    far = (
        ap.filter(pl.col("distance_m") > 0.40)
        .group_by("tf_hz")
        .agg(pl.col("omega_dps").mean().alias("far"))
        .sort("tf_hz")
    )
    j = near.join(far, on="tf_hz")
    rises = bool((j["near"] > j["far"]).all())
    by_tf = ap.group_by("tf_hz").agg(pl.col("omega_dps").mean().alias("m")).sort("tf_hz")
    tf_up = bool((by_tf["m"].diff().drop_nulls() > 0).all())
    claims.append(
        Claim(
            "Approaching a wall raises the AVDM response, more so at higher wall TF (Fig. 4)",
            "response grows as the robot nears the wall, and with TF",
            "mean ω̂ > 40 cm / < 10 cm from the wall: "
            + ", ".join(
                f"TF {r['tf_hz']:g}: {r['far']:.1f} → {r['near']:.1f} deg/s"
                for r in j.iter_rows(named=True)
            )
            + "; whole-approach mean by TF: "
            + ", ".join(f"{r['m']:.1f}" for r in by_tf.iter_rows(named=True)),
            _verdict(rises and tf_up, rises or tf_up),
        )
    )

    claims += profiling_claims(pl.read_parquet(out / "profiling" / "summary.parquet"))
    claims += collision_claims(pl.read_parquet(out / "collision" / "collision_summary.parquet"))
    return claims


def per_seed(
    summary: pl.DataFrame, scene: str, model: str, motion: str, metric: str
) -> pl.DataFrame:
    """(seed × wall TF) table of one summary ``metric``: a ``seed`` column, then one column
    per wall TF in rising order (named by polars' pivot, e.g. ``"3.0"``)."""
    rows = summary.filter(
        (pl.col("scene") == scene) & (pl.col("model") == model) & (pl.col("motion") == motion)
    )
    return (
        rows.select("seed", "wall_tf_hz", metric)
        .sort("wall_tf_hz")
        .pivot(on="wall_tf_hz", index="seed", values=metric)
        .sort("seed")
    )


def tf_columns(table: pl.DataFrame) -> list[float]:
    return [float(c) for c in table.columns if c != "seed"]


def estimates(table: pl.DataFrame, bounds: tuple[float, float] = (0.0, math.inf)) -> list[Estimate]:
    """Per wall TF; every quantity read here (shares, means of ω̂, ratios) is ≥ 0."""
    return [mean_ci(table[c].to_numpy(), bounds=bounds) for c in table.columns if c != "seed"]


def bounds_of(metric: str) -> tuple[float, float]:
    """The possible range of a summary metric: shares in [0, 1], the rest ≥ 0."""
    return (0.0, 1.0) if metric.startswith("frac_") else (0.0, math.inf)


def rise_claim(
    claim: str,
    paper: str,
    table: pl.DataFrame,
    metric: str,
    what: str,
    fmt: str,
    scale: float = 1.0,
) -> Claim:
    """A claim that ``table`` (from :func:`per_seed`) rises with the wall TF: the mean and
    95 % interval per TF and the trend test across seeds decide it."""
    est = estimates(table, bounds_of(metric))
    values = table.select([c for c in table.columns if c != "seed"]).to_numpy()
    trend = rising_trend(values)
    measured = (
        f"{what}: "
        + ", ".join(
            f"TF {tf:g}: {e.text(fmt, scale)}" for tf, e in zip(tf_columns(table), est, strict=True)
        )
        + f" (mean [95 % interval] over {table.height} seeds); {trend.text()}"
    )
    verdict = trend_verdict([e.mean for e in est], trend)
    quantities = [
        Quantity.of(
            f"TF {tf:g} Hz", metric, e, f"rise with TF: {trend.method}", trend.p_value, scale
        )
        for tf, e in zip(tf_columns(table), est, strict=True)
    ]
    return Claim(claim, paper, measured, verdict, trend.p_value, table.height, quantities)


def profiling_claims(summary: pl.DataFrame) -> list[Claim]:
    """The Figs. 6–7 claims from the profiling summary (one row per recording, model and
    motion; columns scene, seed, wall_tf_hz, model, motion, frac_over_100, mean,
    near_wall_centre_ratio)."""
    claims = []
    ratios = []
    verdicts = []
    ratio_q = []
    for scene, tf in PROFILE_CONDITIONS:
        t = per_seed(summary, scene, CALIBRATED, "all", "near_wall_centre_ratio")
        col = str(float(tf))  # polars names pivoted Float64 columns like "3.0"
        if col not in t.columns:
            continue
        est = mean_ci(t[col].to_numpy(), bounds=(0.0, math.inf))
        ratios.append(f"{scene} TF {tf:g}: {est.text('{:.2f}')}")
        verdicts.append(above_verdict(est, 1.0))
        ratio_q.append(
            Quantity.of(f"{scene} TF {tf:g} Hz", "near_wall_centre_ratio", est, "95 % interval > 1")
        )
    n = int(summary["seed"].n_unique())
    claims.append(
        Claim(
            "The response (visual dynamic complexity) is stronger near the walls (Figs. 6–7)",
            "higher near the walls than in the centre",
            "near-wall / centre mean ω̂, mean [95 % interval] over seeds: " + ", ".join(ratios),
            combine(verdicts),
            math.nan,
            n,
            ratio_q,
        )
    )
    paper = "more 'AVDM > 100' responses at higher TF (Fig. 6 histograms)"
    claims.append(
        rise_claim(
            "The count of 'AVDM > 100' rises with the walls' TF (Fig. 6), in the released "
            "code's units",
            paper,
            per_seed(summary, "grating", RELEASED, "all", "frac_over_100"),
            "frac_over_100",
            f"% of frames over 100 with {RELEASED} (100·λ̂·√R̄), grating, all frames",
            "{:.1f}",
            100.0,
        )
    )
    claims.append(
        rise_claim(
            "The same count in calibrated deg/s, all frames",
            paper,
            per_seed(summary, "grating", CALIBRATED, "all", "frac_over_100"),
            "frac_over_100",
            "% of frames over 100 deg/s (calibrated ω̂), grating, all frames; in deg/s, 100 is "
            "above the walls' drift and mostly counts the robot's own 120 °/s turns",
            "{:.1f}",
            100.0,
        )
    )
    claims.append(
        rise_claim(
            "Without the robot's own turns, the calibrated response rises with the walls' TF",
            "complexity rises with TF",
            per_seed(summary, "grating", CALIBRATED, "straight", "mean"),
            "mean",
            "mean ω̂ while driving straight (deg/s), grating",
            "{:.1f}",
        )
    )
    nat = rise_claim(
        "A drifting natural scene behaves like the grating",
        "same trends: complexity rises with TF, stronger near walls",
        per_seed(summary, "natural", CALIBRATED, "all", "mean"),
        "mean",
        "natural scene, mean ω̂ (deg/s), all frames",
        "{:.1f}",
    )
    near = [
        v for (scene, _), v in zip(PROFILE_CONDITIONS, verdicts, strict=False) if scene == "natural"
    ]
    nat.verdict = combine([nat.verdict, *near])
    nat.measured += "; near-wall / centre: " + ", ".join(
        r for r in ratios if r.startswith("natural")
    )
    nat.quantities += [q for q in ratio_q if q.condition.startswith("natural")]
    claims.append(nat)
    return claims


def collision_claims(summary: pl.DataFrame) -> list[Claim]:
    """The Fig. 8 claims from the per-recording collision summary (one row per phase and
    seed): success rates and avoidances as means with 95 % intervals across seeds."""
    phases = {r["phase"]: r for r in phase_statistics(summary).iter_rows(named=True)}

    def est(phase: str, name: str) -> Estimate:
        return phase_estimate(phases[phase], name)

    def txt(phase: str) -> str:
        return (
            f"success {est(phase, 'success_rate').text('{:.1f}', 100.0)} %, "
            f"{est(phase, 'avoidances_per_30min').text('{:.0f}')} avoidances and "
            f"{est(phase, 'crashes_per_30min').text('{:.1f}')} crashes per 30 min"
        )

    def numbers(*names: str) -> list[Quantity]:
        test = "95 % interval vs 90 % success"
        return [
            Quantity.of(p, q, est(p, q), test if q == "success_rate" else "")
            for p in names
            if p in phases
            for q in ("success_rate", "avoidances_per_30min", "crashes_per_30min")
        ]

    claims = []
    n = int(summary["seed"].n_unique()) if summary.height else 0
    if {"tf0", "tf3", "tf3-adjusted"} <= set(phases):
        works = above_verdict(est("tf0", "success_rate"), 0.9)
        breaks = below_verdict(est("tf3", "success_rate"), 0.9)
        recovers = above_verdict(est("tf3-adjusted", "success_rate"), 0.9)
        claims.append(
            Claim(
                "The collision detector works on static walls, breaks down at TF 3 Hz, and "
                "recovers with an adjusted threshold (Fig. 8)",
                "success > 90 % in all three phases; 229 → 432 avoidances at TF 3 (extra alerts), "
                "233 with the adjusted threshold",
                f"TF 0: {txt('tf0')}; TF 3: {txt('tf3')}; TF 3 adjusted: {txt('tf3-adjusted')} "
                f"(mean [95 % interval] over {n} seeds). Works (TF 0 > 90 %): {works}; breaks "
                f"down (TF 3 < 90 %): {breaks}; recovers (adjusted > 90 %): {recovers}. Our "
                "breakdown is blindness (crashes) rather than extra avoidances; see README.",
                combine([works, breaks, recovers]),
                math.nan,
                n,
                numbers("tf0", "tf3", "tf3-adjusted"),
            )
        )
    if {"tf0", "tf3-adaptive"} <= set(phases):
        ok_s = above_verdict(est("tf3-adaptive", "success_rate"), 0.9)
        a = est("tf3-adaptive", "avoidances_per_30min")
        b = est("tf0", "avoidances_per_30min")
        # "restores TF 0 performance": within 25 % of TF 0's avoidances
        close = abs(a.mean - b.mean) <= 0.25 * max(1.0, b.mean)
        ok_n = HOLDS if close else FAILS
        claims.append(
            Claim(
                "Beyond the paper: the complexity-adaptive detector restores TF 0 performance at "
                "TF 3 Hz without hand tuning",
                "(not in the paper)",
                f"TF 3 adaptive: {txt('tf3-adaptive')} vs TF 0: {txt('tf0')}"
                + (f"; TF 0 adaptive: {txt('tf0-adaptive')}" if "tf0-adaptive" in phases else "")
                + f". Success > 90 %: {ok_s}; avoidances within 25 % of TF 0's: {ok_n}.",
                combine([ok_s, ok_n]),
                math.nan,
                n,
                numbers("tf3-adaptive", "tf0", "tf0-adaptive"),
            )
        )
    return claims

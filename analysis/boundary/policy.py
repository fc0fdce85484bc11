"""A learnt policy from a boundary grid: per condition, the parameter value that keeps the
target success rate, against the condition's online complexity (``policy.csv``)."""

from __future__ import annotations

import polars as pl

from analysis.boundary.statistics import run_statistics
from avdm.policy import Policy


def fit_policy(
    runs: pl.DataFrame,
    param: str,
    target: float,
    profile_model: str = "avdm",
    window_s: float = 60.0,
) -> Policy:
    """The parameter as a function of the online complexity, from a grid's runs (columns
    condition, ``param``, avoidances, crashes, avoidances_per_30min, online_median_dps).

    1. The **anchor** is the value that keeps the target (the lower end of the success
       interval across seeds at or above it) on the most conditions; ties go to the fewest
       avoidances over the grid.
    2. Per condition, the anchor stays unless the evidence says otherwise at 95 %: where it does
       not keep the target, the value with the best lower success bound replaces it; where it
       does, a value that also keeps the target replaces it only if its avoidances' interval
       lies wholly below the anchor's (fewer turns, for certain).
    3. A row's complexity is the online complexity (the running **median** of the AVDM over the
       window, which the robot's own turns, brief spikes of ω̂, barely move) of the runs with
       that value: what the policy reads when it has set it. Rows of equal complexity keep the
       larger value.

    (A first design took, per condition, the value with the fewest mean avoidances among those
    whose mean success kept the target, against the running mean: noisy choices on a measure
    that the robot's turning, which the choice itself changes, dominated; see
    docs/findings/boundary.md.)
    """
    stats = _value_statistics(runs, param)
    keeps = stats.filter(pl.col("success_low") >= target)
    counts = keeps.group_by(param).agg(pl.len().alias("kept"))
    total = stats.group_by(param).agg(pl.col("avoidances_per_30min").sum().alias("turns"))
    ranked = counts.join(total, on=param).sort(["kept", "turns"], descending=[True, False])
    anchor = float(ranked[param][0]) if ranked.height else float(stats[param].min())
    rows = []
    for (cond,), g in stats.group_by("condition", maintain_order=True):
        a = g.filter(pl.col(param) == anchor).row(0, named=True)
        best, why = a, "anchor"
        ok = g.filter(pl.col("success_low") >= target)
        if a["success_low"] < target:
            best = g.sort("success_low", descending=True).row(0, named=True)
            why = "keeps the target" if best["success_low"] >= target else "least bad"
        else:
            fewer = ok.filter(pl.col("avoidances_per_30min_high") < a["avoidances_per_30min_low"])
            if fewer.height:
                best, why = fewer.sort("avoidances_per_30min").row(0, named=True), "fewer turns"
        rows.append(
            {
                "complexity_dps": round(float(best["online_median_dps"]), 3),
                param: float(best[param]),
                "success_rate": round(float(best["success_rate"]), 4),
                "success_low": round(float(best["success_low"]), 4),
                "avoidances_per_30min": round(float(best["avoidances_per_30min"]), 1),
                "runs": int(best["seeds"]),
                "condition": cond,
                "why": why,
            }
        )
    df = pl.DataFrame(rows).sort("complexity_dps", param)
    df = df.group_by("complexity_dps", maintain_order=True).agg(pl.all().last())  # larger value
    return Policy(
        param,
        tuple(df["complexity_dps"].to_list()),
        tuple(df[param].to_list()),
        window_s,
        profile_model,
        df.drop("complexity_dps", param),
        statistic="median",
    )


def _value_statistics(runs: pl.DataFrame, param: str) -> pl.DataFrame:
    """:func:`run_statistics` per condition and value, with the online complexity (median) of
    those runs; with one seed (no interval) an interval's ends are its mean."""
    median = runs.group_by("condition", param).agg(pl.col("online_median_dps").mean())
    stats = run_statistics(runs, ["condition", param]).join(median, on=["condition", param])
    ends = ["success_low", "avoidances_per_30min_low", "avoidances_per_30min_high"]
    means = ["success_rate", "avoidances_per_30min", "avoidances_per_30min"]
    return stats.with_columns(
        pl.when(pl.col(e).is_nan()).then(pl.col(m)).otherwise(pl.col(e)).alias(e)
        for e, m in zip(ends, means, strict=True)
    )

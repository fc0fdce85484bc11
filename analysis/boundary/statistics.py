"""The statistics of ``vdc-analyse boundary``: one run measured (:func:`run_row`), performance
per condition with 95 % intervals across seeds (:func:`run_statistics`,
:func:`condition_statistics`, :func:`condition_complexity`) and the boundary
(:func:`find_boundary`, :func:`boundaries`).

The boundary, per parameter value, with conditions in order of complexity: the first condition
whose success is below the target at 95 % confidence (the upper end of its interval is below
it) is the first *failing* one; the boundary lies between the condition before it and it
(``boundary_low_dps`` < boundary ≤ ``boundary_high_dps``), and the point estimate is where the
mean success crosses the target by linear interpolation inside that interval. No failing
condition: the boundary lies beyond the grid (``> boundary_low_dps``); the first condition
fails: it lies at or below the grid's least complex condition.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.collision import CollisionSettings, collision_metrics
from analysis.recordings.loading import load_recording
from analysis.stats import mean_ci, share_ci

ROW_VERSION = 2  # what run_row measures; a cached row of another version is measured again
WARMUP_FRAMES = 60  # the AVDM's and the running means' start-up, left out of every mean


# --- one run measured ----------------------------------------------------------------------


def run_row(path: str | Path, kind: str, false_alarm_m: float = 0.30) -> dict[str, Any]:
    """The measurements of one recorded run. ``kind`` "collision": the collision metrics
    (``analysis.collision``) plus the on-board AVDM's mean over all frames after the warm-up
    (``online_dps``) and over straight driving (``straight_dps``); "profile": the online AVDM's
    mean over straight driving (``profile_dps``)."""

    loaded = load_recording(path)
    fr = loaded.frames.select("frame", "turning").filter(pl.col("frame") >= WARMUP_FRAMES)
    row: dict[str, Any] = {"recording_id": loaded.recording_id}
    if kind == "collision":
        metrics, _ = collision_metrics(loaded, CollisionSettings(false_alarm_m=false_alarm_m))
        row |= {k: v for k, v in metrics.items() if not k.startswith("paper_")}
        profiler = loaded.props.get("model", {}).get("name", "avdm")
    else:
        profiler = loaded.online_model or "avdm"
    omega = loaded.logged[profiler].select("frame", "omega_dps").join(fr, on="frame")
    straight = omega.filter(pl.col("turning").not_())["omega_dps"]
    if kind == "collision":
        row["online_dps"] = float(omega["omega_dps"].mean() or math.nan)
        row["online_median_dps"] = float(omega["omega_dps"].median() or math.nan)
        row["straight_dps"] = float(straight.mean()) if straight.len() else math.nan
    else:
        row["profile_dps"] = float(straight.mean()) if straight.len() else math.nan
    return row


# --- performance against complexity, and the boundary -------------------------------------


def run_statistics(runs: pl.DataFrame, by: Sequence[str]) -> pl.DataFrame:
    """One row per group of runs (``by``: e.g. condition and parameter value): the number of
    seeds, the success rate with its 95 % interval across seeds (``analysis.stats.share_ci``),
    and the means with 95 % intervals of avoidances and crashes per 30 min, false alarms per
    30 min and the median distance to collision."""
    rows = []
    for keys, g in runs.group_by(*by, maintain_order=True):
        row = dict(zip(by, keys, strict=True)) | {"seeds": g.height}
        est = share_ci(g["avoidances"].to_numpy(), (g["avoidances"] + g["crashes"]).to_numpy())
        row |= {"success_rate": est.mean, "success_low": est.low, "success_high": est.high}
        for name in (
            "avoidances_per_30min",
            "crashes_per_30min",
            "false_alarms_per_30min",
            "dtc_median_m",
        ):
            e = mean_ci(g[name].cast(pl.Float64).to_numpy(), bounds=(0.0, math.inf))
            row |= {name: e.mean, f"{name}_low": e.low, f"{name}_high": e.high}
        rows.append(row)
    return pl.DataFrame(rows)


def condition_statistics(
    runs: pl.DataFrame, complexity: pl.DataFrame, by: Sequence[str]
) -> pl.DataFrame:
    """:func:`run_statistics` per condition and parameter value (``by``), with the condition's
    complexity (from ``complexity``: condition, complexity_dps, _low, _high)."""
    return (
        run_statistics(runs, by)
        .join(complexity, on="condition", how="left")
        .sort(by[-1], "complexity_dps")
    )


def condition_complexity(rows: pl.DataFrame, column: str) -> pl.DataFrame:
    """Per condition: the mean of ``column`` across its runs with the 95 % interval."""
    out = []
    for (cond,), g in rows.group_by("condition", maintain_order=True):
        # a speed (deg/s) is not negative: the t-interval stops at 0
        e = mean_ci(g[column].cast(pl.Float64).to_numpy(), bounds=(0.0, math.inf))
        out.append(
            {
                "condition": cond,
                "complexity_dps": e.mean,
                "complexity_low": e.low,
                "complexity_high": e.high,
            }
        )
    return pl.DataFrame(out)


def find_boundary(
    complexity: Sequence[float],
    success: Sequence[float],
    success_high: Sequence[float],
    target: float,
) -> dict[str, Any]:
    """The boundary of one curve (see the module): ``boundary_dps`` (point estimate),
    ``boundary_low_dps`` < boundary ≤ ``boundary_high_dps``, and ``where``: "within" the
    grid, "beyond" its most complex condition or "below" its least complex one."""
    c = np.asarray(complexity, float)
    s = np.asarray(success, float)
    hi = np.asarray(success_high, float)
    order = np.argsort(c)
    c, s, hi = c[order], s[order], hi[order]
    # a condition with no interval (one seed) fails when its success itself is below
    failing = np.where(np.isfinite(hi), hi < target, s < target)
    if not failing.any():
        return {
            "where": "beyond",
            "boundary_dps": math.nan,
            "boundary_low_dps": float(c[-1]),
            "boundary_high_dps": math.inf,
        }
    k = int(np.argmax(failing))
    if k == 0:
        return {
            "where": "below",
            "boundary_dps": math.nan,
            "boundary_low_dps": -math.inf,
            "boundary_high_dps": float(c[0]),
        }
    c0, c1, s0, s1 = c[k - 1], c[k], s[k - 1], s[k]
    if s0 <= target or s0 == s1:
        point = c0
    else:  # where the mean success crosses the target, inside the interval
        point = c0 + (s0 - target) / (s0 - s1) * (c1 - c0)
    point = float(min(max(point, c0), c1))
    return {
        "where": "within",
        "boundary_dps": point,
        "boundary_low_dps": float(c0),
        "boundary_high_dps": float(c1),
    }


def boundaries(conditions: pl.DataFrame, by: str, target: float) -> pl.DataFrame:
    """One boundary per value of ``by`` (the parameter) from :func:`condition_statistics`."""
    rows = []
    for (value,), g in conditions.group_by(by, maintain_order=True):
        b = find_boundary(g["complexity_dps"], g["success_rate"], g["success_high"], target)
        rows.append({by: value, "target": target, **b})
    return pl.DataFrame(rows)

"""What the whole dataset decides about each episode: blur against the camera's own
sharpness, each camera's motion learnt against the robot's state and the shifts it leaves
unexplained (``analysis.dataset.camera_motion``), the cameras' lag against each other
(``analysis.dataset.lag.camera_lags``), and the flags with their evidence and thresholds
(docs/guides/dataset.md says why each is where it is)."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import polars as pl

from analysis.dataset.camera_motion import Z95, camera_motions, view_shifts
from analysis.dataset.lag import camera_lags

# flag, the column it shows, the column of its evidence, its threshold, the threshold's unit
# (what it means: _MEANINGS): an episode is flagged when its evidence >= the threshold. The
# evidence is the value itself where the value is counted or read exactly (frames, a run's
# length, the idle head: the shorter of the image's and the state's, both must be still),
# and the near end of the value's 95 % interval where it is an estimate (a shift, the lag,
# the drift, a share of frames), so that no flag fires on a point estimate its interval does
# not carry past the threshold. One row a flag, read into FLAGS below; docs/guides/dataset.md says
# why each is where.
_FLAG_TABLE = """
frozen       frozen_longest_s   frozen_longest_s    0.2  s
dropped      dropped            dropped             1    frames
drift        drift_abs_ms       drift_low_ms        20.0 ms
moved        shift_px           shift_low_px        2.0  px
moved_within shift_within_px    shift_within_low_px 2.0  px
lag          lag_abs_ms         lag_clear_ms        50.0 ms
idle         idle_head_s        idle_head_s         0.5  s
idle_tail    idle_tail_s        idle_tail_s         0.5  s
blurred      blurred_share      blurred_low         0.5  share
underexposed underexposed_share underexposed_low    0.5  share
overexposed  overexposed_share  overexposed_low     0.5  share
short        frames_missing     frames_missing      1    frames
"""
_MEANINGS = {
    "frozen": "the image stood still while the state moved",
    "dropped": "frames missing from the video's times",
    "drift": "the video's clock and the data's disagree",
    "moved": "the view moved against its reference, beyond the robot's motion",
    "moved_within": "the view moved in the episode, beyond the robot's motion",
    "lag": "the camera's motion lags the state's",
    "idle": "nothing moves at the start",
    "idle_tail": "nothing moves at the end",
    "blurred": "most frames far less sharp than usual",
    "underexposed": "most frames clipped dark",
    "overexposed": "most frames clipped bright",
    "short": "fewer frames decoded than stated",
}


class FlagRule(NamedTuple):
    """One flag: the column it shows, its threshold, the threshold's unit, what it means, and
    the column of its evidence (compared with the threshold)."""

    column: str
    threshold: float
    unit: str
    meaning: str
    evidence: str


FLAGS: dict[str, FlagRule] = {
    name: FlagRule(column, float(thr) if "." in thr else int(thr), unit, _MEANINGS[name], evidence)
    for name, column, evidence, thr, unit in (
        row.split() for row in _FLAG_TABLE.strip().splitlines()
    )
}
FLOAT_COLUMNS = (
    "from_s",
    "to_s",
    "drift_start_ms",
    "drift_end_ms",
    "lag_ms",
    "lag_low_ms",
    "lag_high_ms",
    "lag_peak_ms",
    "lag_camera_ms",
    "lag_camera_low_ms",
    "lag_camera_high_ms",
    "lag_camera_clear_ms",
    "lag_r",
    "shift_deg",
    "shift_within_deg",
    "shift_px",
    "shift_within_px",
    "shift_dx_px",
    "shift_dy_px",
    "frozen_longest_s",
    "frozen_total_s",
    "idle_head_s",
    "idle_tail_s",
    "shift_low_px",
    "shift_within_low_px",
    "shift_step_px",
    "camera_motion_r2",
    "camera_motion_px",
)
# a frame is blurred when its sharpness (variance of the Laplacian) is below this share of the
# camera's median over the dataset: a focus or motion blur of 2 px divides it by 10 or more,
# while a clean episode's frames stay within a factor of 2 of the median
BLUR_SHARE_OF_MEDIAN = 0.3
# a share of frames (blurred, clipped) is an estimate from frames that are not independent
# (blur and exposure last): its interval counts one unit per SHARE_BLOCK_S of the episode
# (Wilson's score interval, 95 %), so a 3-s episode all blurred has 6 units and a lower end
# of 0.61, while one with 60 % of its frames blurred does not clear a 0.5 threshold
SHARE_BLOCK_S = 0.5
# the drift is read off two clocks' timestamps, each rounded: an MP4 time base (1/90000 to
# 1/1000 s) and the data's float32 seconds; its interval is ± this (ms)
DRIFT_RESOLUTION_MS = 1.0


def flag_thresholds(overrides: dict[str, float | None] | None = None) -> dict[str, float | None]:
    """Each flag's threshold: the default of :data:`FLAGS`, or ``overrides``' (None: off)."""
    out: dict[str, float | None] = {n: f.threshold for n, f in FLAGS.items()}
    out.update(overrides or {})
    return out


def wilson_low(share: float, n: float) -> float:
    """The lower end of Wilson's 95 % score interval for ``share`` of ``n`` units."""
    if not n or share is None or share != share:
        return math.nan
    z2 = Z95 * Z95
    centre = share + z2 / (2 * n)
    half = Z95 * math.sqrt(max(share * (1 - share), 0.0) / n + z2 / (4 * n * n))
    return max(0.0, (centre - half) / (1 + z2 / n))


def _longest(flags: pl.Series) -> int:
    """The longest run of True in ``flags``."""
    best = run = 0
    for f in flags:
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def finish(
    rows: list[dict[str, Any]],
    frames: pl.DataFrame,
    views: dict[tuple[int, str], list[np.ndarray]],
    widths: dict[str, int],
    fov_deg: float | None,
    pose_deltas: dict[tuple[int, str], np.ndarray | None] | None = None,
    moving_cameras: tuple[str, ...] = (),
    thresholds: dict[str, float | None] | None = None,
    camera_order: tuple[str, ...] = (),
) -> tuple[pl.DataFrame, pl.DataFrame, dict[str, dict[str, Any]]]:
    """(episodes, frames, cameras) with the dataset's measures and the flags added: ``blurred``
    per frame and ``blurred_share``; each camera's motion learnt against the robot's state
    (:func:`camera_motions`: the third value, per camera); the shifts (:func:`view_shifts`);
    each estimate's evidence (:data:`FLAGS`); ``flags`` (comma-separated names) and
    ``flag_count``. ``widths``: each camera's frame width (px) at which the shifts are stated;
    ``thresholds``: :func:`flag_thresholds`' (None: a flag off)."""
    pose_deltas = pose_deltas or {}
    thr_of = flag_thresholds(thresholds)
    med = frames.group_by("camera").agg(pl.col("sharpness").median().alias("_med"))
    frames = (
        frames.join(med, on="camera")
        .with_columns(
            (pl.col("sharpness") < BLUR_SHARE_OF_MEDIAN * pl.col("_med")).alias("blurred")
        )
        .drop("_med")
    )
    # frozen is judged on sharp frames only: a blurred view hides small motion (on the test
    # datasets a blurred moving object changed no block by the still threshold for 0.43 s)
    # each camera's own frame interval: the cameras' rates may differ
    dt = frames.group_by("camera").agg(pl.col("dt_s").median().fill_null(1.0).alias("_dt"))
    frames = frames.with_columns((pl.col("frozen") & ~pl.col("blurred")).alias("frozen"))
    blur = (
        frames.sort("episode_index", "camera", "frame")
        .join(dt, on="camera")
        .group_by("episode_index", "camera")
        .agg(
            pl.col("blurred").mean().alias("blurred_share"),
            pl.col("frozen").alias("_fz"),
            pl.col("_dt").first(),
        )
        .with_columns(
            (pl.col("_fz").map_elements(_longest, return_dtype=pl.Int64) * pl.col("_dt")).alias(
                "frozen_longest_s"
            ),
            (pl.col("_fz").list.sum() * pl.col("_dt")).alias("frozen_total_s"),
        )
        .drop("_fz", "_dt")
    )
    if "view_dx_px" not in frames.columns:  # (results kept by an older version are re-measured)
        frames = frames.with_columns(view_dx_px=pl.lit(math.nan), view_dy_px=pl.lit(math.nan))
    motions = camera_motions(frames, pose_deltas, moving_cameras)
    view_shifts(rows, frames, views, pose_deltas, widths, fov_deg, motions)
    against = camera_lags(frames, camera_order)
    none = dict.fromkeys(
        (
            "lag_camera_ms",
            "lag_camera_low_ms",
            "lag_camera_high_ms",
            "lag_camera_note",
            "lag_camera_ref",
        )
    )
    # a delay between two cameras is the late one's: its evidence (how far the interval lies
    # from 0) goes to the camera behind, this one or the first
    late: dict[tuple[int, str], float] = {}
    for (e, cam), lag in against.items():
        if lag["lag_camera_ms"] is None:
            continue
        low, high = lag["lag_camera_low_ms"], lag["lag_camera_high_ms"]
        behind, clear = (cam, low) if low > 0 else (lag["lag_camera_ref"], -high)
        if clear > 0:
            late[(e, behind)] = max(clear, late.get((e, behind), 0.0))
    for r in rows:
        key = (r["episode_index"], r["camera"])
        r.update(against.get(key, none))
        r["lag_camera_clear_ms"] = late.get(key, 0.0)
    eps = pl.DataFrame(rows, infer_schema_length=None)
    # a column every row of which is None (no lag measurable, no field of view) keeps its type
    eps = eps.with_columns(
        *[
            pl.col(c).cast(pl.Float64)
            for c in eps.columns
            if c in FLOAT_COLUMNS or c.endswith("_mean")
        ],
        *[
            pl.col(c).cast(pl.String)
            for c in ("lag_note", "video_path", "lag_camera_note", "lag_camera_ref")
            if c in eps.columns
        ],
    )
    eps = eps.join(blur, on=["episode_index", "camera"], how="left")
    units = ((pl.col("frames_decoded") / pl.col("fps")) / SHARE_BLOCK_S).clip(1)
    share_low = {
        f"{n}_low": pl.struct(pl.col(f"{n}_share").alias("s"), units.alias("n")).map_elements(
            lambda x: wilson_low(x["s"], x["n"]), return_dtype=pl.Float64
        )
        for n in ("blurred", "underexposed", "overexposed")
    }
    eps = eps.with_columns(
        pl.max_horizontal(pl.col("drift_start_ms").abs(), pl.col("drift_end_ms").abs()).alias(
            "drift_abs_ms"
        ),
        pl.col("lag_ms").abs().alias("lag_abs_ms"),
        # the lag's evidence: how far its whole interval lies from 0 (0 where it holds 0),
        # against the state or against the episode's first camera
        pl.max_horizontal(
            pl.when(pl.col("lag_ms").is_null())
            .then(0.0)
            .otherwise(pl.max_horizontal(pl.col("lag_low_ms"), -pl.col("lag_high_ms"))),
            pl.col("lag_camera_clear_ms"),
            pl.lit(0.0),
        ).alias("lag_clear_ms"),
        (pl.col("length") - pl.col("frames_decoded") - pl.col("dropped"))
        .clip(0)
        .alias("frames_missing"),
        **share_low,
    )
    eps = eps.with_columns(
        (pl.col("drift_abs_ms") - DRIFT_RESOLUTION_MS).clip(0).alias("drift_low_ms"),
    )
    named = [
        pl.when(pl.col(f.evidence).fill_null(0).fill_nan(0) >= thr_of[name])
        .then(pl.lit(name))
        .otherwise(None)
        for name, f in FLAGS.items()
        if thr_of.get(name) is not None
    ]
    eps = eps.with_columns(
        pl.concat_list(named).list.drop_nulls().alias("_f")
        if named
        else pl.lit([], dtype=pl.List(pl.String)).alias("_f")
    )
    eps = eps.with_columns(
        pl.col("_f").list.join(",").alias("flags"), pl.col("_f").list.len().alias("flag_count")
    ).drop("_f")
    return eps.sort("episode_index", "camera"), frames, motions


def severity(eps: pl.DataFrame, thresholds: dict[str, float | None] | None = None) -> pl.DataFrame:
    """``eps`` worst first: most flags, then the largest excess of a flag's evidence over its
    threshold."""
    thr_of = flag_thresholds(thresholds)
    excess = [
        (pl.col(f.evidence).fill_null(0).fill_nan(0).abs() / thr_of[n])
        for n, f in FLAGS.items()
        if thr_of.get(n)
    ]
    return eps.with_columns(
        (pl.max_horizontal(excess) if excess else pl.lit(0.0)).alias("severity")
    ).sort(["flag_count", "severity"], descending=True)


def flagged_frame(flag: str, fr: pl.DataFrame, row: dict[str, Any]) -> int:
    """The frame (index into the episode's decoded frames) that shows ``flag`` best, from
    the episode's frame table ``fr`` (in order) and its row."""
    n = len(fr)
    if flag == "frozen":
        runs = fr["frozen"].to_list()
        best, start, k0 = 0, 0, None
        for i, v in enumerate([*runs, False]):
            if v and k0 is None:
                k0 = i
            elif not v and k0 is not None:
                if i - k0 > best:
                    best, start = i - k0, k0
                k0 = None
        return start
    if flag == "dropped":
        hit = fr["dropped_before"].arg_max()
        return int(hit or 0)
    if flag in ("blurred",):
        return int(fr["sharpness"].arg_min() or 0)
    if flag in ("overexposed", "underexposed"):
        hit = fr[flag].arg_max()
        return int(hit or 0)
    if flag == "idle":
        t = row.get("idle_head_s") or 0.0
        return int(min(n - 1, (fr["t_s"] <= t).sum()))
    if flag == "lag":
        return int(fr["mafd"].fill_nan(None).arg_max() or 0)
    if flag == "moved_within" and row.get("shift_frame") is not None:
        return int(min(n - 1, row["shift_frame"]))  # the step's first frame
    if flag == "moved":
        return 0
    return n - 1  # drift, moved_within without a step, idle_tail, short: the episode's end


def first_flags(eps: pl.DataFrame, frames: pl.DataFrame) -> dict[tuple[int, str], tuple[str, int]]:
    """(episode, camera) → (its first flag, the frame that shows it) for flagged episodes."""
    out = {}
    for row in eps.filter(pl.col("flag_count") > 0).iter_rows(named=True):
        key = (row["episode_index"], row["camera"])
        fr = frames.filter((pl.col("episode_index") == key[0]) & (pl.col("camera") == key[1])).sort(
            "frame"
        )
        flag = row["flags"].split(",")[0]
        out[key] = (flag, flagged_frame(flag, fr, row))
    return out

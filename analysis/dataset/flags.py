"""What the whole dataset decides about each episode: blur against the camera's own
sharpness, the camera's shift against its reference view, and the flags with their
thresholds (docs/guides/dataset.md says why each is where it is)."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import polars as pl

# flag, the column it reads, its threshold, the threshold's unit, what it means: an episode is
# flagged when |value| >= threshold. One row a flag, read into FLAGS below.
_FLAG_TABLE = """
frozen        frozen_longest_s    0.2   s       the image stood still while the state moved
dropped       dropped             1     frames  frames missing from the video's times
drift         drift_abs_ms        20.0  ms      the video's clock and the data's disagree
moved         shift_px            2.0   px      the camera moved against its reference view
moved_within  shift_within_px     2.0   px      the camera moved during the episode
lag           lag_abs_ms          50.0  ms      the camera's motion lags the state's
idle          idle_head_s         0.5   s       nothing moves at the start
idle_tail     idle_tail_s         0.5   s       nothing moves at the end
blurred       blurred_share       0.5   share   most frames far less sharp than the camera's
underexposed  underexposed_share  0.5   share   most frames clipped dark
overexposed   overexposed_share   0.5   share   most frames clipped bright
short         frames_missing      1     frames  fewer frames decoded than the episode states
"""
# flag -> (column, threshold, unit, meaning)
FLAGS: dict[str, tuple[str, float, str, str]] = {
    name: (column, float(thr) if "." in thr else int(thr), unit, meaning)
    for name, column, thr, unit, meaning in (
        row.split(maxsplit=4) for row in _FLAG_TABLE.strip().splitlines()
    )
}
FLOAT_COLUMNS = (
    "from_s", "to_s", "drift_start_ms", "drift_end_ms", "lag_ms", "lag_low_ms", "lag_high_ms",
    "lag_r", "shift_deg", "shift_within_deg", "shift_px", "shift_within_px", "shift_dx_px",
    "shift_dy_px", "frozen_longest_s", "frozen_total_s", "idle_head_s", "idle_tail_s",
)  # fmt: skip
# a frame is blurred when its sharpness (variance of the Laplacian) is below this share of the
# camera's median over the dataset: a focus or motion blur of 2 px divides it by 10 or more,
# while a clean episode's frames stay within a factor of 2 of the median
BLUR_SHARE_OF_MEDIAN = 0.3
PRE_BLUR_PX = 1.5  # sigma of the views' common blur before their shift is measured


def _longest(flags: pl.Series) -> int:
    """The longest run of True in ``flags``."""
    best = run = 0
    for f in flags:
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def phase_shift(ref: np.ndarray, img: np.ndarray) -> tuple[float, float]:
    """(dx, dy) px that moves ``ref`` onto ``img`` (phase correlation, Hanning window)."""
    if ref.shape != img.shape:
        return math.nan, math.nan
    win = cv2.createHanningWindow((ref.shape[1], ref.shape[0]), cv2.CV_32F)
    # both blurred alike first: phase correlation whitens the spectrum, so a blurred or
    # heavily compressed view's empty high frequencies (codec noise) would vote as loudly as
    # the scene's structure; a common blur of PRE_BLUR_PX leaves only the structure
    a = cv2.GaussianBlur(ref, (0, 0), PRE_BLUR_PX)
    b = cv2.GaussianBlur(img, (0, 0), PRE_BLUR_PX)
    (dx, dy), _ = cv2.phaseCorrelate(a, b, win)
    return float(dx), float(dy)


def finish(
    rows: list[dict[str, Any]],
    frames: pl.DataFrame,
    views: dict[tuple[int, str], list[np.ndarray]],
    widths: dict[str, int],
    fov_deg: float | None,
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """(episodes, frames) with the dataset's measures and the flags added: ``blurred`` per
    frame and ``blurred_share``; ``shift_px``/``shift_deg`` of each episode's first view
    against the camera's reference view (its first episode's first), ``shift_within_px``/
    ``_deg`` of its last view against its first; ``flags`` (comma-separated names of
    :data:`FLAGS`) and ``flag_count``. ``widths``: each camera's frame width (px) at which
    the views' shifts are stated."""
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
    fps = 1.0 / float(frames["dt_s"].median() or 1.0)
    frames = frames.with_columns((pl.col("frozen") & ~pl.col("blurred")).alias("frozen"))
    blur = (
        frames.sort("episode_index", "camera", "frame")
        .group_by("episode_index", "camera")
        .agg(
            pl.col("blurred").mean().alias("blurred_share"),
            pl.col("frozen").alias("_fz"),
        )
        .with_columns(
            pl.col("_fz").map_elements(lambda f: _longest(f) / fps, return_dtype=pl.Float64)
            .alias("frozen_longest_s"),
            (pl.col("_fz").list.sum() / fps).alias("frozen_total_s"),
        )
        .drop("_fz")
    )  # fmt: skip
    refs: dict[str, np.ndarray] = {}
    for (_, cam), v in sorted(views.items()):
        refs.setdefault(cam, v[0])
    for r in rows:
        v = views.get((r["episode_index"], r["camera"]))
        scale = widths[r["camera"]] / v[0].shape[1] if v else math.nan
        dx, dy = phase_shift(refs[r["camera"]], v[0]) if v else (math.nan, math.nan)
        wx, wy = phase_shift(v[0], v[-1]) if v else (math.nan, math.nan)
        r["shift_px"] = math.hypot(dx, dy) * scale
        r["shift_dx_px"], r["shift_dy_px"] = dx * scale, dy * scale
        r["shift_within_px"] = math.hypot(wx, wy) * scale
        deg = fov_deg / widths[r["camera"]] if fov_deg else None
        r["shift_deg"] = r["shift_px"] * deg if deg else None
        r["shift_within_deg"] = r["shift_within_px"] * deg if deg else None
    eps = pl.DataFrame(rows, infer_schema_length=None)
    # a column every row of which is None (no lag measurable, no field of view) keeps its type
    eps = eps.with_columns(
        *[
            pl.col(c).cast(pl.Float64)
            for c in eps.columns
            if c in FLOAT_COLUMNS or c.endswith("_mean")
        ],
        *[pl.col(c).cast(pl.String) for c in ("lag_note", "video_path") if c in eps.columns],
    )
    eps = eps.join(blur, on=["episode_index", "camera"], how="left")
    eps = eps.with_columns(
        pl.max_horizontal(pl.col("drift_start_ms").abs(), pl.col("drift_end_ms").abs())
        .alias("drift_abs_ms"),
        pl.col("lag_ms").abs().alias("lag_abs_ms"),
        (pl.col("length") - pl.col("frames_decoded") - pl.col("dropped")).clip(0)
        .alias("frames_missing"),
    )  # fmt: skip
    named = [
        pl.when(pl.col(col).fill_null(0).fill_nan(0) >= thr).then(pl.lit(name)).otherwise(None)
        for name, (col, thr, _, _) in FLAGS.items()
    ]
    eps = eps.with_columns(pl.concat_list(named).list.drop_nulls().alias("_f"))
    eps = eps.with_columns(
        pl.col("_f").list.join(",").alias("flags"), pl.col("_f").list.len().alias("flag_count")
    ).drop("_f")
    return eps.sort("episode_index", "camera"), frames


def severity(eps: pl.DataFrame) -> pl.DataFrame:
    """``eps`` worst first: most flags, then the largest excess over a threshold."""
    excess = [
        (pl.col(col).fill_null(0).fill_nan(0).abs() / thr) for col, thr, _, _ in FLAGS.values()
    ]
    return eps.with_columns(pl.max_horizontal(excess).alias("severity")).sort(
        ["flag_count", "severity"], descending=True
    )


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
    if flag == "moved":
        return 0
    return n - 1  # drift, moved_within, idle_tail, short: the episode's end


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

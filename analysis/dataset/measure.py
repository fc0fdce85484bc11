"""One camera of one episode measured (one executor task): every frame of its window decoded
once, through the same batcher as every other vdc source (``vdc.frame_batches``), beside the
episode's rows of data. The measures that need the whole dataset (blur against the camera's
own sharpness, the camera's motion against the state and its shifts) are finished by the
caller (``analysis.dataset.flags``)."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import polars as pl

from analysis.complexity.meter import ComplexityMeter
from analysis.dataset.lag import lag_of
from analysis.dataset.layout import EpisodeVideo, read_episode_data
from analysis.dataset.window import WindowReader
from avdm.jit import kernel
from vdc.errors import UserError
from vdc.frame_batches import FrameBatcher
from vdc.recording import NATIVE_METRICS, camera_model_context, working_size
from vdc.sources import frames_missing_in, open_reader

# a frame is under-exposed when this share of its pixels is at most DARK (full-range grey),
# over-exposed when this share is at least BRIGHT: a fifth of the view clipped is detail lost
# that no gain brings back (a well-lit synthetic view clips 0-2 % of its pixels)
CLIPPED_SHARE, DARK, BRIGHT = 0.2, 10, 245
# the state moves when its speed is above this share of the episode's peak speed: a robot's
# encoders jitter by far less, and a real motion passes it within a frame or two of starting
STATE_MOVING_SHARE = 0.02
# frozen: the image still while the state moves at least this share of its peak speed (a
# motion the camera must show: slower, an object may move less than a block's noise)
FROZEN_STATE_SHARE = 0.25
# idle: the image moves from the first run of at least this many frames that each differ
# from the frames before (STILL_LEVELS): a key frame coded again changes an unchanged view
# by up to 12 levels in a block with H.264 at CRF 30 (the v2.1 example), once, between
# copies that change nothing, while a motion changes frame after frame
IDLE_RUN_FRAMES = 3
# a frame shows nothing new (still) when no block of BLOCK_PX px changed by more than
# STILL_LEVELS on average: an unchanged image coded again as a key frame (LeRobot's encoders
# make every second frame one) changes its blocks by up to 8.2 levels with H.264 at CRF 30 on
# the test datasets (up to 4 with AV1), while the object moving at a quarter of its peak speed
# changes its block by 12 or more
BLOCK_PX, STILL_LEVELS = 16, 10.0
VIEW_MAX_WIDTH = 320  # the first and last views kept for the camera's shift, px wide at most
# the view's motion from frame to frame (phase correlation) is read on the frame made at most
# this wide: a pan of a few px a frame is still seen at a fifth of a px, at a quarter of the
# cost of the full view (about 0.2 ms a frame at 160 × 120)
MOTION_MAX_WIDTH = 160
# and against the frame this many before: a knock shows in every such comparison that spans
# it (this many in a row), while a misread (two motions in the view: a gripper that stays put
# while the background pans) is a single frame's (analysis.dataset.flags takes the median)
MOTION_SPAN_FRAMES = 5
PRE_BLUR_PX = 1.5  # sigma of the views' common blur before their shift is measured


def _vertex(minus: float, centre: float, plus: float) -> float:
    """The offset (-0.5..0.5) of the parabola's vertex through three samples around a peak."""
    curve = minus - 2 * centre + plus
    return float(np.clip(0.5 * (minus - plus) / curve, -0.5, 0.5)) if curve < 0 else 0.0


def phase_shift(
    ref: np.ndarray, img: np.ndarray, win: np.ndarray | None = None
) -> tuple[float, float]:
    """(dx, dy) px that moves ``ref`` onto ``img``: phase correlation (Hanning window), its
    peak refined by a parabola through its neighbours along each axis. Not OpenCV's
    ``phaseCorrelate``, whose centroid over the 5 × 5 px around the peak mixes in a second
    peak 2-3 px away: a camera on the arm whose gripper (or object) stays put in its view
    read its 2.5-px pan as 1.2 px, and as 3 px on a frame now and then."""
    if ref.shape != img.shape:
        return math.nan, math.nan
    if win is None:
        win = cv2.createHanningWindow((ref.shape[1], ref.shape[0]), cv2.CV_32F)
    return spectra_shift(spectrum(ref, win), spectrum(img, win), ref.shape)


def spectrum(img: np.ndarray, win: np.ndarray) -> np.ndarray:
    """The view's spectrum for :func:`spectra_shift` (kept from frame to frame: each frame's
    is taken once)."""
    # blurred first: phase correlation whitens the spectrum, so a blurred or heavily
    # compressed view's empty high frequencies (codec noise) would vote as loudly as the
    # scene's structure; a common blur of PRE_BLUR_PX leaves only the structure
    return np.fft.rfft2(cv2.GaussianBlur(img, (0, 0), PRE_BLUR_PX) * win)


def spectra_shift(a: np.ndarray, b: np.ndarray, shape: tuple[int, ...]) -> tuple[float, float]:
    """:func:`phase_shift` from the two views' :func:`spectrum`."""
    cross = b * np.conj(a)
    corr = np.fft.irfft2(cross / (np.abs(cross) + 1e-12), s=shape)
    h, w = corr.shape
    iy, ix = np.unravel_index(int(np.argmax(corr)), corr.shape)
    c = corr[iy, ix]
    fx = _vertex(corr[iy, (ix - 1) % w], c, corr[iy, (ix + 1) % w])
    fy = _vertex(corr[(iy - 1) % h, ix], c, corr[(iy + 1) % h, ix])
    dx = (ix + w // 2) % w - w // 2 + fx  # wrapped: a shift of w - 1 is one of -1
    dy = (iy + h // 2) % h - h // 2 + fy
    return float(dx), float(dy)


def _small(grey: np.ndarray) -> np.ndarray:
    """The frame at most :data:`MOTION_MAX_WIDTH` px wide, float32, for its motion."""
    h, w = grey.shape
    if w > MOTION_MAX_WIDTH:
        grey = cv2.resize(
            grey,
            (MOTION_MAX_WIDTH, max(1, round(h * MOTION_MAX_WIDTH / w))),
            interpolation=cv2.INTER_AREA,
        )
    return grey.astype(np.float32)


def _view(grey: np.ndarray) -> np.ndarray:
    """A view for the shift, at most :data:`VIEW_MAX_WIDTH` px wide (float32)."""
    h, w = grey.shape
    if w > VIEW_MAX_WIDTH:
        grey = cv2.resize(
            grey, (VIEW_MAX_WIDTH, round(h * VIEW_MAX_WIDTH / w)), interpolation=cv2.INTER_AREA
        )
    return grey.astype(np.float32)


def local_change(grey: np.ndarray, prev: np.ndarray | None) -> float:
    """The largest mean |difference| from ``prev`` over :data:`BLOCK_PX` square blocks (8-bit
    grey levels; NaN without a previous frame): a small object that moves changes its block
    by tens of levels, while a codec's noise on an unchanged image stays spread thin. (The
    reference for :func:`grey_stats`, which takes it with the frame's other statistics in one
    pass; this one also takes images smaller than a block.)"""
    if prev is None or prev.shape != grey.shape:
        return math.nan
    diff = cv2.absdiff(grey, prev)  # uint8: each block's mean rounds to a level, ample at 10
    h, w = diff.shape
    bh, bw = max(1, h // BLOCK_PX), max(1, w // BLOCK_PX)
    blocks = cv2.resize(
        diff[: bh * BLOCK_PX, : bw * BLOCK_PX], (bw, bh), interpolation=cv2.INTER_AREA
    )
    return float(blocks.max())


def frame_stats(grey: np.ndarray) -> tuple[float, float, float, float]:
    """(sharpness: variance of the Laplacian, mean grey, share <= DARK, share >= BRIGHT) with
    OpenCV: the reference for :func:`grey_stats`."""
    lap = cv2.Laplacian(grey, cv2.CV_16S, ksize=3)  # exact for 8-bit input, half float's cost
    _, sd = cv2.meanStdDev(lap)
    hist = cv2.calcHist([grey], [0], None, [256], [0, 256]).ravel() / grey.size
    return float(sd[0, 0]) ** 2, *_hist_stats(hist)


def _hist_stats(hist: np.ndarray) -> tuple[float, float, float]:
    """(mean grey, share <= DARK, share >= BRIGHT) from the (256,) float32 shares."""
    mean = float(np.dot(hist, np.arange(256)))
    return mean, float(hist[: DARK + 1].sum()), float(hist[BRIGHT:].sum())


@kernel(nogil=True)
def _add_abs_diff(r, p, col):  # pragma: no cover - compiled
    """col += |r - p| over one row (int32: a block row's column sum is at most 16 × 255)."""
    for j in range(col.shape[0]):
        col[j] += abs(np.int32(r[j]) - np.int32(p[j]))


@kernel(nogil=True)
def _largest_block(col, block, bw):  # pragma: no cover - compiled
    """The largest Σ over ``bw`` blocks of ``block`` columns of ``col``, which is then zeroed."""
    m = np.int64(-1)
    for b in range(bw):
        t = np.int64(0)
        for j in range(b * block, (b + 1) * block):
            t += col[j]
        m = max(m, t)
    col[:] = 0
    return m


@kernel(nogil=True)
def _lap_row(ru, r, rd, w):  # pragma: no cover - compiled
    """Σ and Σ² of one row's 3×3 Laplacian (interior columns; int32 terms: |lap| <= 2040)."""
    s = np.int64(0)
    sq = np.int64(0)
    for j in range(1, w - 1):
        a = np.int32(ru[j - 1]) + np.int32(ru[j + 1]) + np.int32(rd[j - 1]) + np.int32(rd[j + 1])
        lap = 2 * a - 8 * np.int32(r[j])
        s += lap
        sq += lap * lap
    return s, sq


@kernel(nogil=True)
def _grey_sums(g, p1, p2, have1, have2, block):  # pragma: no cover - compiled
    """One pass over ``g`` (H, W) uint8: Σ and Σ² of its 3×3
    Laplacian (OpenCV's ksize=3 kernel [[2,0,2],[0,-8,0],[2,0,2]], borders reflected about
    the edge pixel as OpenCV's default), and the largest Σ|g - p| over ``block``-px square
    blocks against ``p1`` and ``p2`` (-1 where not ``have1``/``have2``). H and W at least
    ``block``."""
    h, w = g.shape
    s = np.int64(0)
    sq = np.int64(0)
    bh, bw = h // block, w // block
    col1 = np.zeros(w, np.int32)  # a block row's column sums of |g - p1|, |g - p2|
    col2 = np.zeros(w, np.int32)
    m1 = np.int64(-1)
    m2 = np.int64(-1)
    for i in range(h):
        ru = g[i - 1] if i > 0 else g[1]
        rd = g[i + 1] if i < h - 1 else g[h - 2]
        r = g[i]
        rs, rsq = _lap_row(ru, r, rd, w)
        # the edges: column -1 is column 1, column w is column w - 2
        e0 = 4 * (np.int64(ru[1]) + np.int64(rd[1])) - 8 * np.int64(r[0])
        e1 = 4 * (np.int64(ru[w - 2]) + np.int64(rd[w - 2])) - 8 * np.int64(r[w - 1])
        s += rs + e0 + e1
        sq += rsq + e0 * e0 + e1 * e1
        if i < bh * block:
            if have1:
                _add_abs_diff(r, p1[i], col1)
            if have2:
                _add_abs_diff(r, p2[i], col2)
            if i % block == block - 1:
                if have1:
                    m1 = max(m1, _largest_block(col1, block, bw))
                if have2:
                    m2 = max(m2, _largest_block(col2, block, bw))
    return s, sq, m1, m2


def grey_stats(
    grey: np.ndarray, prev: np.ndarray | None, prev2: np.ndarray | None
) -> tuple[float, float, float, float, float, float]:
    """:func:`frame_stats` of ``grey`` and :func:`local_change` against ``prev`` and ``prev2``
    (None: none yet), the same values from one compiled pass over the image instead of six
    OpenCV calls (measured on 480×640: about 0.5 against 1.0 ms of CPU). Images smaller than a
    block go to the two reference functions."""
    h, w = grey.shape
    if h < BLOCK_PX or w < BLOCK_PX:
        return (*frame_stats(grey), local_change(grey, prev), local_change(grey, prev2))
    have1 = prev is not None and prev.shape == grey.shape
    have2 = prev2 is not None and prev2.shape == grey.shape
    p1 = prev if have1 else grey
    p2 = prev2 if have2 else grey
    s, sq, m1, m2 = _grey_sums(grey, p1, p2, have1, have2, BLOCK_PX)
    # OpenCV's meanStdDev: the exact integer sums, scaled by 1/n, the root of the variance
    scale = 1.0 / grey.size
    mean = s * scale
    sd = math.sqrt(max(sq * scale - mean * mean, 0.0))
    # (OpenCV's histogram: faster than a compiled loop's, each count waiting on the last)
    hist = cv2.calcHist([grey], [0], None, [256], [0, 256]).ravel() / grey.size
    # a block's mean as OpenCV's INTER_AREA gives it: Σ / area rounded half to even; the
    # largest block's rounded mean is the rounded largest mean (rounding keeps the order)
    area = BLOCK_PX * BLOCK_PX
    c1 = float(np.rint(np.float32(m1) * np.float32(1.0 / area))) if have1 else math.nan
    c2 = float(np.rint(np.float32(m2) * np.float32(1.0 / area))) if have2 else math.nan
    return sd**2, *_hist_stats(hist), c1, c2


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of each run of True in ``mask``."""
    out, start = [], None
    for i, m in enumerate(np.append(mask, False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            out.append((start, i - start))
            start = None
    return out


def measure_episode(
    video: EpisodeVideo, settings: Any, fps: float, data_fps: float | None = None
) -> dict[str, Any]:
    """Measure one camera of one episode at its ``fps``, its data's rows at ``data_fps`` (None:
    ``fps``), see the module. Returns ``row`` (dict: the episode's measures), ``frames`` (polars
    DataFrame: one row per decoded frame) and ``views`` (first, last: float32 grey images for
    the camera's shift). Unreadable input raises UserError naming the file."""
    data = read_episode_data(video.data_path, video.episode)

    def opened() -> Any:
        if video.kind == "video":
            return WindowReader(video.path, video.from_s, video.to_s, fps)
        return open_reader(video.path, fps)

    reader = opened()
    stats: list[tuple[float, float, float, float]] = []
    change: list[tuple[float, float]] = []  # against the frame before, and the one before it
    first_last: list[np.ndarray] = []
    motions: list[tuple[float, float]] = []  # (dx, dy) px of the frame's view on the last's
    spans: list[tuple[float, float]] = []  # ... and on the view MOTION_SPAN_FRAMES before
    small_last: list[Any] = [None, None, []]  # the small frame's shape, window, last spectra
    try:
        h, w = reader.info["src_height_px"], reader.info["src_width_px"]
        size = working_size(h, w, settings.fov_deg, settings.width) if settings.fov_deg else None
        frames_it = reader.frames
        last: list[Any] = [None, None]

        def observed():  # each frame's grey seen once, on its way to the batcher
            for fr in frames_it():
                *st, c1, c2 = grey_stats(fr.luma, last[0], last[1])
                stats.append(st)
                change.append((c1, c2))
                if not first_last:
                    first_last.append(_view(fr.luma))
                small = _small(fr.luma)
                if small_last[0] != small.shape:  # the first frame (or a new size)
                    small_last[1] = cv2.createHanningWindow(small.shape[::-1], cv2.CV_32F)
                    small_last[0], small_last[2] = small.shape, []
                spec = spectrum(small, small_last[1])
                kept = small_last[2]
                nan = (math.nan, math.nan)
                motions.append(spectra_shift(kept[-1], spec, small.shape) if kept else nan)
                spans.append(
                    spectra_shift(kept[0], spec, small.shape)
                    if len(kept) == MOTION_SPAN_FRAMES
                    else nan
                )
                small_last[2] = [*kept, spec][-MOTION_SPAN_FRAMES:]
                last[:] = [fr.luma, last[0]]
                yield fr

        reader.frames = observed  # type: ignore[method-assign]
        # reopen: a stream whose colour range is not tagged (H.264 or HEVC without one) is
        # measured in limited range until a frame leaves it; the frames before are then read
        # again in full range (the same values), where without it SI/TI are computed in both
        # ranges on every frame (measured at 480x640: 1.29 against 0.70 ms per frame)
        batcher = FrameBatcher(
            reader,
            size,
            fps,
            metrics=settings.native_metrics(),
            repeat_tol=settings.repeat_tol,
            max_repeats=settings.max_repeats,
            reopen=opened,
        )
        meter = None
        if size is not None:
            ctx = camera_model_context(size[1], size[0], fps, settings.fov_deg)
            meter = ComplexityMeter(
                fps, float(ctx["deg_per_px"]), settings, ctx, metrics=settings.model_metrics()
            )
        parts = []
        while (b := batcher.next_batch()) is not None:
            cols = {
                "frame": b.frame,
                "t_s": b.t_s,
                "dt_s": b.dt_s,
                "repeat": b.repeat,
                "dropped_before": b.dropped_before,
            }
            for m in settings.native_metrics():
                cols[m] = b.native_metrics[:, NATIVE_METRICS.index(m)]
            if meter is not None:
                out = meter.update(b.images, b.t_s, b.repeat)
                for m in settings.model_metrics():
                    cols[m] = out[m]
            parts.append(pl.DataFrame(cols))
        if last[0] is not None:
            first_last.append(_view(last[0]))
        error = reader.error
    finally:
        reader.close()
    if error:
        raise UserError(error)
    frames = pl.concat(parts)
    st = np.asarray(stats, dtype=np.float64).reshape(-1, 4)
    ch = np.asarray(change, dtype=np.float64).reshape(-1, 2)
    frames = frames.with_columns(
        pl.Series("sharpness", st[:, 0]),
        pl.Series("mean_grey", st[:, 1]),
        pl.Series("change_max", ch[:, 0]),
        pl.Series("change2_max", ch[:, 1]),
        pl.Series("underexposed", st[:, 2] >= CLIPPED_SHARE),
        pl.Series("overexposed", st[:, 3] >= CLIPPED_SHARE),
    )
    # the view's motion in source px (the small frame's scaled back)
    scale = w / min(w, MOTION_MAX_WIDTH)
    vm = np.asarray(motions, dtype=np.float64).reshape(-1, 2) * scale
    vk = np.asarray(spans, dtype=np.float64).reshape(-1, 2) * scale
    frames = frames.with_columns(
        pl.Series("view_dx_px", vm[:, 0]),
        pl.Series("view_dy_px", vm[:, 1]),
        pl.Series("view_span_dx_px", vk[:, 0]),
        pl.Series("view_span_dy_px", vk[:, 1]),
    )
    problems: list[str] = []
    row, extra, pose_delta = episode_measures(
        video, data, frames, (fps, data_fps or fps), batcher, problems
    )
    frames = frames.with_columns(*extra)
    return {
        "row": row,
        "frames": frames,
        "views": first_last,
        "problems": problems,
        "pose_delta": pose_delta,
    }


def clock_rows(ts: np.ndarray) -> int:
    """How many of the data's first rows keep a clock: the rows before the first timestamp
    that is not finite or not later than the one before it."""
    bad = ~np.isfinite(ts)
    bad[1:] |= ~(np.diff(ts) > 0)  # (a NaN's difference is not > 0 either)
    return int(np.argmax(bad)) if bad.any() else len(ts)


def _clock_problem(ts: np.ndarray, k: int) -> str:
    """What breaks the data's clock at row ``k`` (:func:`clock_rows`)."""
    if not np.isfinite(ts[k]):
        what = f"timestamp {ts[k]} at row {k} is not a time"
    else:
        what = f"timestamp goes backwards at row {k} ({ts[k - 1]:.4f} s, then {ts[k]:.4f} s)"
    kept = f"the first {ts[k - 1] - ts[0]:.3f} s" if k > 1 else "nothing"
    return (
        f"{what}: the measures on the data's clock (lag, frozen, idle, drift at the end) use "
        f"{kept} before it"
    )


def episode_measures(
    video, data, frames: pl.DataFrame, rates: tuple[float, float], batcher, problems: list[str]
) -> tuple:
    """(the episode's row, the per-frame columns ``still`` and ``state_moving``, the pose's
    change at each frame: (frames, D) float32, the state at the frame's time less the state at
    the frame before's, on the data's rows; the first row is the pose at the first frame, and
    None without a state or action); what is wrong with the episode's data is added to
    ``problems`` (a timestamp that is not a time or goes backwards: the data's clock is then
    used up to it, :func:`clock_rows`). ``rates``: (the camera's frames/s, the data's rows/s)."""
    fps, data_fps = rates
    t_v = frames["t_s"].to_numpy()
    mafd = frames["mafd"].to_numpy()
    ts = data.timestamp
    pose = data.state if data.state is not None else data.action
    k = clock_rows(ts)
    clock_cut = k < len(ts)
    if clock_cut:
        problems.append(_clock_problem(ts, k))
        if k < 2:
            raise UserError(f"{video.data_path}: episode {video.episode}: {problems[-1]}")
        ts = ts[:k]
        pose = pose[:k] if pose is not None else None
    if pose is not None and len(pose) > 1:
        speed = np.concatenate(([0.0], np.linalg.norm(np.diff(pose, axis=0), axis=1)))
    else:
        speed = np.zeros(len(ts))
    peak = float(speed.max()) if len(speed) else 0.0
    moving_data = speed > STATE_MOVING_SHARE * peak if peak > 0 else np.zeros(len(ts), bool)
    # each frame at its own time on the data's clock: the state moved in the interval before
    idx = np.clip(np.searchsorted(ts, t_v - 0.5 / data_fps), 0, len(ts) - 1)
    # frames past the data's clock (cut where it broke) have no state to be judged against
    on_clock = t_v <= ts[-1] + 1 / fps if clock_cut else np.ones(len(t_v), bool)
    state_moving = moving_data[idx] & on_clock
    # still: unchanged since the frame before and the one before that (within STILL_LEVELS):
    # an encoder that skips every other frame's small changes (AV1 on a blurred view) shows
    # no change for one interval, never for two while the scene moves
    c1 = np.nan_to_num(frames["change_max"].to_numpy(), nan=np.inf) <= STILL_LEVELS
    # (the second frame has no frame two before it: judged on the one before alone)
    c2 = np.nan_to_num(frames["change2_max"].to_numpy(), nan=0.0) <= STILL_LEVELS
    still = c1 & c2
    fast = speed[idx] >= FROZEN_STATE_SHARE * peak if peak > 0 else np.zeros(len(t_v), bool)
    fast &= on_clock
    frozen_frame = still & fast
    # a run's first repeated frame passes only the one-interval test: counted back in
    frozen = [(s - 1, n + 1) if s > 0 and c1[s - 1] else (s, n) for s, n in _runs(frozen_frame)]
    for s, _ in frozen:
        frozen_frame[s] = True
    # frames that start (end) a run of IDLE_RUN_FRAMES frames each differing from the ones
    # before: a single changed frame between copies is a key frame coded again, not motion
    moving_img = ~still
    moving_img[0] = False  # the first frame has nothing before it to differ from
    k_run = min(IDLE_RUN_FRAMES, max(1, len(moving_img) - 1))
    runs_img = [(s0, n0) for s0, n0 in _runs(moving_img) if n0 >= k_run]
    image_moves = np.array([runs_img[0][0], sum(runs_img[-1]) - 1] if runs_img else [], int)
    state_moves = np.flatnonzero(moving_data)
    end = ts[-1] if len(ts) else 0.0
    head_img = t_v[image_moves[0] - 1] if len(image_moves) else t_v[-1]
    tail_img = t_v[-1] - t_v[image_moves[-1]] if len(image_moves) else t_v[-1]
    head_state = ts[state_moves[0] - 1] if len(state_moves) else end
    tail_state = end - ts[state_moves[-1]] if len(state_moves) else end
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = mafd / (frames["dt_s"].to_numpy() * fps)  # change per nominal interval
    rate[frozen_frame] = np.nan  # a frozen frame says nothing of the scene's motion
    # the lag on the data's clock, the drift between the clocks taken out (a linear map making
    # the first and last frames agree): a fast clock is the drift's, a constant delay the lag's
    last_ts, length = (ts[-1] if len(ts) else None), video.length
    if fps != data_fps:  # the camera's own frames over the episode; its frame at the data's end
        length = math.ceil(video.length * fps / data_fps - 1e-6)
        last_ts = ts[0] + math.floor((last_ts - ts[0]) * fps + 1e-3) / fps if len(ts) else None
    t_c = t_v
    if clock_cut and len(t_v):  # no last timestamp to map: the first frames agree, the rates
        t_c = t_v + (ts[0] - t_v[0])  # taken as equal
    elif len(t_v) > 1 and len(ts) > 1 and t_v[-1] > t_v[0]:
        t_c = ts[0] + (t_v - t_v[0]) * (last_ts - ts[0]) / (t_v[-1] - t_v[0])
    half = 0.5 / fps - 0.5 / data_fps  # each change at its interval's middle, as the state's
    motion = np.interp(ts, t_c[1:] - half, rate[1:]) if len(t_v) > 1 else np.zeros(len(ts))
    lag = lag_of(speed[1:], motion[1:], data_fps)  # on the data's rows
    if pose is None:
        lag |= {"lag_note": "not measurable: the dataset has no state or action"}
    elif clock_cut and lag["lag_note"]:
        lag["lag_note"] += f" (on the {ts[-1] - ts[0]:.2f} s before the data's clock breaks)"
    tail_gap = (video.to_s - video.from_s) - t_v[-1] - 1 / fps if video.to_s is not None else 0
    dropped = batcher.dropped_total + frames_missing_in(max(tail_gap, 0.0), fps)
    row = {
        "episode_index": video.episode,
        "camera": video.camera,
        "video_path": video.path,
        "from_s": video.from_s,
        "to_s": video.to_s,
        "frames_decoded": len(t_v),
        "length": length,
        "data_timestamps": len(data.timestamp),
        "drift_start_ms": (t_v[0] - ts[0]) * 1000 if len(ts) else None,
        "drift_end_ms": (t_v[-1] - last_ts) * 1000 if len(ts) and not clock_cut else None,
        "fps": float(fps),
        "dropped": int(dropped),
        "repeated": int(batcher.repeats_total),
        "idle_head_s": float(min(head_img, head_state)),
        "idle_tail_s": float(min(tail_img, tail_state)),
        "underexposed_share": float(frames["underexposed"].mean()),
        "overexposed_share": float(frames["overexposed"].mean()),
        "sharpness_median": float(frames["sharpness"].median()),
        **lag,
    }
    for m in frames.columns:
        if m in (
            "si_p910",
            "ti_p910",
            "mafd",
            "codec_bpp",
            "si_legacy",
            "ti_legacy",
            "edge_density",
            "jpeg_bpp",
            "omega_dps",
            "flow_dps",
            "zlib_ratio",
        ):
            v = frames[m].fill_nan(None).mean()
            row[f"{m}_mean"] = None if v is None else float(v)
    pose_delta = None
    if pose is not None and len(pose):
        at = np.asarray(pose, dtype=np.float64)[idx]
        at[~on_clock] = np.nan  # frames past a broken clock have no pose
        pose_delta = np.vstack([at[:1], np.diff(at, axis=0)]).astype(np.float32)
    extra = [
        pl.Series("still", still),
        pl.Series("state_moving", state_moving),
        pl.Series("frozen", frozen_frame),
    ]
    return row, extra, pose_delta

"""What the whole dataset decides about each episode: blur against the camera's own
sharpness, each camera's motion learnt against the robot's state and the shifts it leaves
unexplained, the cameras' lag against each other, and the flags with their evidence and
thresholds (docs/guides/dataset.md says why each is where it is)."""

from __future__ import annotations

import math
import warnings
from typing import Any, NamedTuple

import numpy as np
import polars as pl

from analysis.dataset.lag import lag_of
from analysis.dataset.measure import MOTION_SPAN_FRAMES, phase_shift

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
    "from_s", "to_s", "drift_start_ms", "drift_end_ms", "lag_ms", "lag_low_ms", "lag_high_ms",
    "lag_peak_ms", "lag_camera_ms", "lag_camera_low_ms", "lag_camera_high_ms",
    "lag_camera_clear_ms",
    "lag_r", "shift_deg", "shift_within_deg", "shift_px", "shift_within_px", "shift_dx_px",
    "shift_dy_px", "frozen_longest_s", "frozen_total_s", "idle_head_s", "idle_tail_s",
    "shift_low_px", "shift_within_low_px", "shift_step_px", "camera_motion_r2",
    "camera_motion_px",
)  # fmt: skip
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
Z95 = 1.959964
# a camera moves with the robot where a linear map of the state's change explains at least
# this share of the view's frame-to-frame motion (R², no intercept) ...
MOVING_MIN_R2 = 0.5
# ... and that motion is at least this (px a frame, root mean square). A fixed camera's view
# moves by its codec's noise and by its moving objects' pull on the whole-frame phase
# correlation (0.17-0.22 px a frame on the test datasets, R² 0.65: the object moves with the
# state), a camera on the arm by 0.5-1 px and more. Taking a fixed camera for a moving one
# costs little: only the part of its motion the state explains is taken out, a bump stays
# whole; the other way, every pan would be a fault
MOVING_MIN_PX = 0.3
# a step of the view: each frame's view against the one MOTION_SPAN_FRAMES before, less what
# the state's change over those frames explains; the median of that over the frames from t on
# (a knock at t lasts: it is in each of them; a frozen run caught up, or one frame's misread,
# is in a few). Its noise: the median of k draws varies by about 1.2533 / √k of one draw
STEP_MEDIAN_SD = 1.2533 / math.sqrt(MOTION_SPAN_FRAMES)


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


def _sigma(x: np.ndarray) -> float:
    """A robust standard deviation (1.4826 × the median absolute deviation), NaNs left out."""
    x = x[np.isfinite(x)]
    if not len(x):
        return math.nan
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def _motion_pairs(
    keys: list[tuple[int, str]],
    frames: dict[tuple[int, str], pl.DataFrame],
    pose_deltas: dict[tuple[int, str], np.ndarray | None],
) -> tuple[np.ndarray, np.ndarray]:
    """(view motion (n, 2) px, pose change (n, D)) over the episodes ``keys`` of one camera,
    frame by frame (each episode's first frame left out: it has no frame before it)."""
    d, s = [], []
    for k in keys:
        pd = pose_deltas.get(k)
        fr = frames[k]
        if pd is None or len(pd) != fr.height:
            continue
        d.append(fr.select("view_dx_px", "view_dy_px").to_numpy()[1:])
        s.append(np.asarray(pd, np.float64)[1:])
    if not d or len({x.shape[1] for x in s}) != 1:
        return np.zeros((0, 2)), np.zeros((0, 0))
    return np.vstack(d), np.vstack(s)


def learn_camera_motion(d: np.ndarray, s: np.ndarray) -> dict[str, Any]:
    """How a camera's view moves with the robot's state: the least-squares linear map (no
    intercept) of the pose's change from frame to frame (``s``, (n, D)) onto the view's motion
    (``d``, (n, 2) px), refitted twice without the frames more than 5 robust standard
    deviations off (a knock, a frozen run caught up). Returns ``map`` ((D, 2)), ``r2`` (the
    share of the view's motion the map explains), ``px`` (the explained motion's root mean
    square, px a frame) and ``frames`` (those fitted); ``moving``: both past their minimums
    (:data:`MOVING_MIN_R2`, :data:`MOVING_MIN_PX`)."""
    ok = np.isfinite(d).all(axis=1) & np.isfinite(s).all(axis=1) if s.size else np.zeros(0, bool)
    if ok.sum() < 2 * max(1, s.shape[1] if s.ndim == 2 else 1):
        return {"map": None, "r2": math.nan, "px": math.nan, "frames": int(ok.sum()),
                "moving": False}  # fmt: skip
    keep = ok.copy()
    for _ in range(3):
        b, *_ = np.linalg.lstsq(s[keep], d[keep], rcond=None)
        res = d - s @ b
        sig = np.array([_sigma(res[keep, 0]), _sigma(res[keep, 1])])
        keep = ok & (np.abs(np.nan_to_num(res)) <= 5 * sig + 0.05).all(axis=1)
    pred = s[keep] @ b
    total = float((d[keep] ** 2).sum())
    r2 = 1 - float(((d[keep] - pred) ** 2).sum()) / total if total > 0 else 0.0
    px = float(np.sqrt((pred**2).sum(axis=1).mean()))
    return {"map": b, "r2": r2, "px": px, "frames": int(keep.sum()),
            "moving": r2 >= MOVING_MIN_R2 and px >= MOVING_MIN_PX}  # fmt: skip


def _steps(r: np.ndarray, k: int) -> np.ndarray:
    """(n, 2): at each frame t the median of ``r`` (the residual of each frame's view against
    the view ``k`` frames before) over frames t..t+k-1: a step at t is in all k of them, a
    single frame's misread in one (NaN where the window leaves the episode)."""
    n = len(r)
    out = np.full((n, 2), np.nan)
    if n < k or k < 1:
        return out
    win = np.lib.stride_tricks.sliding_window_view(r, k, axis=0)  # (n - k + 1, 2, k)
    with warnings.catch_warnings():  # a window of NaNs (the first frames) is a NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        out[: n - k + 1] = np.nanmedian(win, axis=2)
    return out


def camera_motions(
    frames: pl.DataFrame,
    pose_deltas: dict[tuple[int, str], np.ndarray | None],
    moving_cameras: tuple[str, ...] = (),
) -> dict[str, dict[str, Any]]:
    """Each camera's motion learnt over the dataset's episodes (:func:`learn_camera_motion`),
    with ``kind`` ("fixed" or "moves with the robot") and ``evidence`` (a line: what it was
    taken for, from what). A camera of ``moving_cameras`` moves with the robot as the user
    says (its map still learnt, to take its motion out)."""
    parts = frames.sort("frame").partition_by("episode_index", "camera", as_dict=True)
    out = {}
    for cam in sorted(frames["camera"].unique().to_list()):
        keys = sorted(k for k in parts if k[1] == cam)
        d, s = _motion_pairs(keys, parts, pose_deltas)
        fit = learn_camera_motion(d, s)
        told = cam in moving_cameras
        moving = told or fit["moving"]
        if fit["map"] is None:
            why = "no state or action to learn its motion from"
        else:
            why = (f"the state's change explains R² {fit['r2']:.2f} of the view's motion "
                   f"({fit['px']:.2f} px a frame, {fit['frames']} frames)")  # fmt: skip
        kind = "moves with the robot" if moving else "fixed"
        said = "as --moving-cameras says" if told else f"learnt: {why}"
        out[cam] = fit | {"kind": kind, "told": told, "moving": moving,
                          "evidence": f"{cam}: {kind} ({said})"}  # fmt: skip
    return out


def _view_shifts(
    rows: list[dict[str, Any]],
    frames: pl.DataFrame,
    views: dict[tuple[int, str], list[np.ndarray]],
    pose_deltas: dict[tuple[int, str], np.ndarray | None],
    widths: dict[str, int],
    fov_deg: float | None,
    motions: dict[str, dict[str, Any]],
) -> None:
    """Each row's shifts, with their intervals' near ends, in place: ``shift_px`` (the episode's
    first view against the camera's reference view: its first episode's first), and
    ``shift_within_px`` (the larger of the view's lasting step within the episode and its
    last view against its first), each less what the state's change explains where the
    camera moves with the robot; ``shift_frame`` the frame of the step."""
    parts = frames.sort("frame").partition_by("episode_index", "camera", as_dict=True)
    k = MOTION_SPAN_FRAMES
    refs: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
    for (e, cam), v in sorted(views.items()):
        pd = pose_deltas.get((e, cam))
        refs.setdefault(cam, (v[0], None if pd is None else np.asarray(pd[0], np.float64)))
    # per camera: the residual motion of every frame, and the steps, for their spreads
    resid: dict[tuple[int, str], np.ndarray] = {}
    steps: dict[tuple[int, str], np.ndarray] = {}
    for key, fr in parts.items():
        m = motions[key[1]]
        d = fr.select("view_dx_px", "view_dy_px").to_numpy().astype(np.float64)
        if "view_span_dx_px" in fr.columns:
            span = fr.select("view_span_dx_px", "view_span_dy_px").to_numpy().astype(np.float64)
        else:
            span = np.full_like(d, np.nan)
        pd = pose_deltas.get(key)
        if m["moving"] and m["map"] is not None and pd is not None and len(pd) == len(d):
            step_pose = np.asarray(pd, np.float64).copy()
            step_pose[0] = 0.0  # the first row is the pose itself, not a change
            d = d - step_pose @ m["map"]
            over_k = np.cumsum(step_pose, axis=0)
            over_k[k:] = over_k[k:] - over_k[:-k]  # the pose's change over the k frames before
            span = span - over_k @ m["map"]
        resid[key] = span
        steps[key] = _steps(span, k)
    spread = {}
    for cam in motions:
        r = np.vstack([v for k, v in resid.items() if k[1] == cam] or [np.zeros((0, 2))])
        st = np.vstack([v for k, v in steps.items() if k[1] == cam] or [np.zeros((0, 2))])
        # one comparison's spread (the views' against the reference, the last against the
        # first), and the step's: the median of k of them
        pair = math.hypot(_sigma(r[:, 0]), _sigma(r[:, 1])) if len(r) else 0.0
        spread[cam] = (pair, pair * STEP_MEDIAN_SD)
    for r in rows:
        key = (r["episode_index"], r["camera"])
        cam = r["camera"]
        m = motions[cam]
        v = views.get(key)
        pd = pose_deltas.get(key)
        scale = widths[cam] / v[0].shape[1] if v and widths.get(cam) else 1.0
        explained = m["moving"] and m["map"] is not None and pd is not None
        dx, dy = (c * scale for c in phase_shift(refs[cam][0], v[0])) if v else (math.nan,) * 2
        wx, wy = (c * scale for c in phase_shift(v[0], v[-1])) if v else (math.nan,) * 2
        if explained:
            pose0 = np.asarray(pd[0], np.float64)
            ref_pose = refs[cam][1]
            if ref_pose is not None and len(ref_pose) == len(pose0):
                px, py = (pose0 - ref_pose) @ m["map"]
                dx, dy = dx - px, dy - py
            qx, qy = np.nansum(np.asarray(pd[1:], np.float64), axis=0) @ m["map"]
            wx, wy = wx - qx, wy - qy
        pair_sd, step_sd = spread[cam]
        pair_sd = 0.0 if pair_sd != pair_sd else pair_sd
        step_sd = 0.0 if step_sd != step_sd else step_sd
        st = steps.get(key)
        mag = np.hypot(st[:, 0], st[:, 1]) if st is not None else np.zeros(0)
        t = int(np.nanargmax(mag)) if np.isfinite(mag).any() else None
        step = float(mag[t]) if t is not None else 0.0
        r["shift_px"] = math.hypot(dx, dy)
        r["shift_dx_px"], r["shift_dy_px"] = dx, dy
        r["shift_low_px"] = max(0.0, r["shift_px"] - Z95 * pair_sd)
        end = math.hypot(wx, wy)
        end_low = max(0.0, end - Z95 * pair_sd)
        step_low = max(0.0, step - Z95 * step_sd)
        # the within-episode shift: the step where it is the better evidence, else the end's
        r["shift_within_px"], r["shift_within_low_px"] = (
            (step, step_low) if step_low > end_low else (end, end_low)
        )
        r["shift_step_px"] = step
        # the step's frame, where the step clears its noise (else no frame: the largest step
        # of a steady view is a place in its noise)
        r["shift_frame"] = t if step_low > 0 else None
        r["camera_motion"] = m["kind"]
        r["camera_motion_r2"] = m["r2"]
        r["camera_motion_px"] = m["px"]
        deg = fov_deg / widths[cam] if fov_deg and widths.get(cam) else None
        r["shift_deg"] = r["shift_px"] * deg if deg else None
        r["shift_within_deg"] = r["shift_within_px"] * deg if deg else None


def camera_lags(
    frames: pl.DataFrame, order: tuple[str, ...] = ()
) -> dict[tuple[int, str], dict[str, Any]]:
    """Each episode's cameras checked against each other for lag: the delay of each camera's
    image motion behind the episode's first camera's (``order``: the dataset's cameras; ms,
    positive: this camera late), as :func:`analysis.dataset.lag.lag_of` reads the image's
    against the state's, on the first camera's frame times (the other's motion interpolated
    there: the cameras' rates and sizes may differ; a mean difference per pixel and frame
    interval does not depend on either). Keyed by (episode, camera) for every camera but the
    first: ``lag_camera_ms`` (None where it cannot tell), ``lag_camera_low_ms``,
    ``lag_camera_high_ms``, ``lag_camera_note``, ``lag_camera_ref`` (the first camera)."""
    rank = {c: i for i, c in enumerate(order)}
    parts = frames.sort("frame").partition_by("episode_index", "camera", as_dict=True)
    by_ep: dict[int, list[str]] = {}
    for e, cam in parts:
        by_ep.setdefault(e, []).append(cam)

    def motion(fr: pl.DataFrame) -> tuple[np.ndarray, np.ndarray, float]:
        t = fr["t_s"].to_numpy().astype(np.float64)
        dt = fr["dt_s"].to_numpy().astype(np.float64)
        fps = 1.0 / float(np.nanmedian(dt)) if np.isfinite(dt).any() else math.nan
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = fr["mafd"].to_numpy().astype(np.float64) / (dt * fps)
        rate[fr["frozen"].to_numpy()] = np.nan  # a frozen frame says nothing of the motion
        # each change at its interval's middle: the cameras' intervals differ with their rates
        return t - 0.5 / fps, rate, fps

    out: dict[tuple[int, str], dict[str, Any]] = {}
    for e, cams in by_ep.items():
        if len(cams) < 2:
            continue
        cams.sort(key=lambda c: (rank.get(c, len(rank)), c))
        t0, x, fps = motion(parts[(e, cams[0])])
        for cam in cams[1:]:
            t1, y, _ = motion(parts[(e, cam)])
            ok = np.isfinite(y)
            if len(t0) < 3 or ok.sum() < 3 or not math.isfinite(fps):
                continue
            # the other camera's motion where the first's frames are (NaN outside its times)
            yy = np.interp(t0, t1[ok], y[ok], left=np.nan, right=np.nan)
            lag = lag_of(x[1:], yy[1:], fps)
            out[(e, cam)] = {
                "lag_camera_ms": lag["lag_ms"], "lag_camera_low_ms": lag["lag_low_ms"],
                "lag_camera_high_ms": lag["lag_high_ms"], "lag_camera_note": lag["lag_note"],
                "lag_camera_ref": cams[0],
            }  # fmt: skip
    return out


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
    (:func:`camera_motions`: the third value, per camera); the shifts (:func:`_view_shifts`);
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
            (pl.col("_fz").map_elements(_longest, return_dtype=pl.Int64) * pl.col("_dt"))
            .alias("frozen_longest_s"),
            (pl.col("_fz").list.sum() * pl.col("_dt")).alias("frozen_total_s"),
        )
        .drop("_fz", "_dt")
    )  # fmt: skip
    if "view_dx_px" not in frames.columns:  # (results kept by an older version are re-measured)
        frames = frames.with_columns(view_dx_px=pl.lit(math.nan), view_dy_px=pl.lit(math.nan))
    motions = camera_motions(frames, pose_deltas, moving_cameras)
    _view_shifts(rows, frames, views, pose_deltas, widths, fov_deg, motions)
    against = camera_lags(frames, camera_order)
    none = dict.fromkeys(("lag_camera_ms", "lag_camera_low_ms", "lag_camera_high_ms",
                          "lag_camera_note", "lag_camera_ref"))  # fmt: skip
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
        pl.max_horizontal(pl.col("drift_start_ms").abs(), pl.col("drift_end_ms").abs())
        .alias("drift_abs_ms"),
        pl.col("lag_ms").abs().alias("lag_abs_ms"),
        # the lag's evidence: how far its whole interval lies from 0 (0 where it holds 0),
        # against the state or against the episode's first camera
        pl.max_horizontal(
            pl.when(pl.col("lag_ms").is_null()).then(0.0)
            .otherwise(pl.max_horizontal(pl.col("lag_low_ms"), -pl.col("lag_high_ms"))),
            pl.col("lag_camera_clear_ms"),
            pl.lit(0.0),
        ).alias("lag_clear_ms"),
        (pl.col("length") - pl.col("frames_decoded") - pl.col("dropped")).clip(0)
        .alias("frames_missing"),
        **share_low,
    )  # fmt: skip
    eps = eps.with_columns(
        (pl.col("drift_abs_ms") - DRIFT_RESOLUTION_MS).clip(0).alias("drift_low_ms"),
    )  # fmt: skip
    named = [
        pl.when(pl.col(f.evidence).fill_null(0).fill_nan(0) >= thr_of[name])
        .then(pl.lit(name))
        .otherwise(None)
        for name, f in FLAGS.items()
        if thr_of.get(name) is not None
    ]
    eps = eps.with_columns(pl.concat_list(named).list.drop_nulls().alias("_f") if named
                           else pl.lit([], dtype=pl.List(pl.String)).alias("_f"))  # fmt: skip
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

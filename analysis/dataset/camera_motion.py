"""Each camera's motion learnt against the robot's state (:func:`learn_camera_motion`,
:func:`camera_motions`: a camera fixed or moving with the robot), and the shifts of its view
the state does not explain (``view_shifts``: a bump between episodes, a knock within one),
with their intervals: what ``analysis.dataset.flags`` decides the shift flags on."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import polars as pl

from analysis.dataset.measure import MOTION_SPAN_FRAMES, phase_shift

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
        return {
            "map": None,
            "r2": math.nan,
            "px": math.nan,
            "frames": int(ok.sum()),
            "moving": False,
        }
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
    return {
        "map": b,
        "r2": r2,
        "px": px,
        "frames": int(keep.sum()),
        "moving": r2 >= MOVING_MIN_R2 and px >= MOVING_MIN_PX,
    }


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
            why = (
                f"the state's change explains R² {fit['r2']:.2f} of the view's motion "
                f"({fit['px']:.2f} px a frame, {fit['frames']} frames)"
            )
        kind = "moves with the robot" if moving else "fixed"
        said = "as --moving-cameras says" if told else f"learnt: {why}"
        out[cam] = fit | {
            "kind": kind,
            "told": told,
            "moving": moving,
            "evidence": f"{cam}: {kind} ({said})",
        }
    return out


def view_shifts(
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

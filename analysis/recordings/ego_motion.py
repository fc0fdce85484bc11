"""The robot's own rotation, from its poses: so responses to self-motion can be told apart
from the scene's own dynamics.

A robot that turns in place at 120 °/s sweeps its whole view across the camera: a faithful
angular-velocity decoder reads ~120 deg/s whatever the walls do. The ``frames`` table therefore
carries the robot's yaw rate (``robot_omega_dps``, from the simulator's exact poses or the
overhead tracker's) and a ``turning`` flag, and ``--exclude-turns`` keeps only straight driving.

* yaw rate: least-squares slope of the unwrapped heading over a centred window of ±k frames,
  k = round(fps · ``YAW_WINDOW_S`` / 2) ≥ 1. The simulator's poses are exact, but the
  tracker's heading jitters (about 0.2° for a well-lit marker, more when it is small or
  blurred); a 0.3 s slope (PROPOSED) keeps 1.5° of jitter to ~5 °/s, a sixth of the threshold,
  and blurs the edges of a 0.7 s turn by 0.15 s. Both sources use the same window.
* turning: |yaw rate| > ``turn_threshold_dps`` (30 °/s, a quarter of the arena robot's turn
  rate: well above straight driving, PROPOSED), held for ``turn_hold_frames`` after the turn
  ends, because the AVDM averages its detectors over T_w = 10 frames and still "sees" the turn
  that long.
* a frame without a pose (marker not seen) has a null yaw rate and a null flag: it is neither
  turning nor known to be straight.
"""

from __future__ import annotations

import math

import numpy as np

from vdc.errors import UserError

YAW_WINDOW_S = 0.3


def yaw_rate_dps(
    t_s: np.ndarray, heading_rad: np.ndarray, window_s: float = YAW_WINDOW_S
) -> np.ndarray:
    """The robot's yaw rate (N,) float64 in deg/s, positive counter-clockwise.

    ``t_s`` (N,) seconds and ``heading_rad`` (N,) radians (wrapped or not; NaN where unknown).
    NaN where fewer than k + 1 of the window's frames have a pose."""
    t = np.asarray(t_s, dtype=np.float64)
    h = np.asarray(heading_rad, dtype=np.float64)
    n = len(h)
    out = np.full(n, np.nan)
    dt = np.diff(t)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    if n < 2 or len(dt) == 0:
        return out
    k = max(1, round(window_s / float(np.median(dt)) / 2))
    known = np.isfinite(h)
    unwrapped = np.zeros(n)
    # unwrap across gaps too: a gap shorter than half a turn cannot hide a full revolution
    unwrapped[known] = np.unwrap(h[known])
    # sums over the window of (Δt, Δh) relative to the centre frame: no cancellation on long
    # runs, and frames without a pose simply do not count
    sw = np.zeros(n)
    st = np.zeros(n)
    sh = np.zeros(n)
    stt = np.zeros(n)
    sth = np.zeros(n)
    idx = np.arange(n)
    for off in range(-k, k + 1):
        j = idx + off
        ok = (j >= 0) & (j < n)
        jj = np.where(ok, j, 0)
        w = (ok & known[jj]).astype(np.float64)
        d_t = np.where(w > 0, t[jj] - t, 0.0)
        d_h = np.where(w > 0, unwrapped[jj] - unwrapped, 0.0)
        sw += w
        st += d_t
        sh += d_h
        stt += d_t * d_t
        sth += d_t * d_h
    den = sw * stt - st * st
    ok = (sw >= k + 1) & (den > 0)
    out[ok] = np.degrees((sw[ok] * sth[ok] - st[ok] * sh[ok]) / den[ok])
    return out


def turning_flags(
    omega_dps: np.ndarray, threshold_dps: float = 30.0, hold_frames: int = 10
) -> np.ndarray:
    """Per frame (N,) float64: 1.0 turning, 0.0 straight, NaN unknown.

    A frame turns when |``omega_dps``| > ``threshold_dps``, or did within the previous
    ``hold_frames`` frames (the model's memory of the turn)."""
    w = np.asarray(omega_dps, dtype=np.float64)
    if not (math.isfinite(threshold_dps) and threshold_dps > 0):
        raise UserError(f"turn_threshold_dps must be > 0, got {threshold_dps}.")
    rotating = np.abs(np.nan_to_num(w, nan=0.0)) > threshold_dps
    held = rotating.copy()
    last = -(10**9)
    for i, r in enumerate(rotating):  # a forward dilation; N is a run's frame count
        if r:
            last = i
        elif i - last <= hold_frames:
            held[i] = True
    out = held.astype(np.float64)
    out[~np.isfinite(w) & ~held] = np.nan
    return out


# how far back an alert looks for a turn already under way (PROPOSED): 0.15 s, five frames at
# 33 Hz, long enough to average pose jitter, short enough to end before the alert
TURNING_BEFORE_S = 0.15


def turning_before(
    t_s: np.ndarray,
    heading_rad: np.ndarray,
    at: np.ndarray,
    threshold_dps: float = 30.0,
    window_s: float = TURNING_BEFORE_S,
) -> np.ndarray:
    """Whether the robot was already turning just before each frame index in ``at`` (M,):
    bool (M,), from poses strictly before it only.

    The mean |yaw rate| over the ``window_s`` that end one frame before the event exceeds
    ``threshold_dps``. Unlike the per-frame ``turning`` flag (a centred slope plus a hold),
    it cannot see the turn that the event itself triggers. False where the window has no pose.
    """
    t = np.asarray(t_s, dtype=np.float64)
    h = np.asarray(heading_rad, dtype=np.float64)
    at = np.asarray(at, dtype=np.int64)
    out = np.zeros(len(at), dtype=bool)
    if len(t) < 2:
        return out
    for i, k in enumerate(at):
        end = k - 1  # the last frame before the event
        start = int(np.searchsorted(t, t[end] - window_s)) if 0 < end < len(t) else -1
        if start < 0 or start >= end:
            continue
        seg_t, seg_h = t[start : end + 1], h[start : end + 1]
        ok = np.isfinite(seg_h)
        if ok.sum() < 2:
            continue
        turned = np.diff(np.unwrap(seg_h[ok]))
        span = seg_t[ok][-1] - seg_t[ok][0]
        out[i] = span > 0 and abs(np.degrees(turned.sum()) / span) > threshold_dps
    return out

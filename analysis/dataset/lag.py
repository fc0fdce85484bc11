"""The delay of a camera's image behind the robot's state (``lag_ms``), with its 95 % interval:
the two motions cross-correlated on the data's frame grid (:func:`lag_of`); and the same
delay between an episode's cameras (:func:`camera_lags`). Its constants are
the search's reach and the interval's blocks, measured on known delays."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import polars as pl

from analysis.stats import scipy_stats

# lag: the camera's motion against the state's, cross-correlated over at most this (s) either
# way; measurable only where the peak correlation reaches LAG_MIN_R (below it the motions do
# not match well enough for a peak to mean a delay)
LAG_SEARCH_S, LAG_MIN_R = 0.4, 0.5
# and only in episodes of at least LAG_MIN_S (2.9 s): the search leaves out LAG_SEARCH_S at
# either end, and what is left (2.1 s) must hold strokes enough for a peak
LAG_MIN_S = 2 * LAG_SEARCH_S + 2.1
SMOOTH_FRAMES = 3
# an interval covering at least this share of the search (2 × LAG_SEARCH_S) says nothing
# of the delay: "cannot tell", no lag reported and none flagged
LAG_CANNOT_TELL_SHARE = 0.9
# idle: the image moves from the first run of at least this many frames that each differ
# the interval: a delete-one-block jackknife over contiguous blocks of at least LAG_BLOCK_S,
# with Student's t on blocks - 1 degrees of freedom. Measured on known delays
# (benchmarks/bench_lag_interval.py: arm strokes, codec-like noise, lost frames, 3-30 s at
# 15-60 fps) it covers 93-97 %, where the moving-block bootstrap it replaced (1.5-s blocks)
# covered 57-92 %. Blocks of 0.75 s: 1.5-s ones left a 3-s episode 2 blocks, whose t on one
# degree of freedom made its interval 170 ms wide against 64 ms, covering no more often;
# 0.5-s ones covered 92 % on long low-noise episodes (neighbouring blocks' noise correlates)
LAG_BLOCK_S = 0.75


def lag_peaks(speed_state: np.ndarray, motion: np.ndarray, fps: float) -> tuple[Any, int]:
    """``(peak, m)``: ``peak(idx)`` gives (delay ms, correlation) at the peak of the two
    signals' cross-correlation over the aligned frames ``idx`` (int array into ``range(m)``);
    every delay's pairs (x[i], y[i + k]) share the same frames i, so leaving frames out (or
    resampling them) never changes the delay between the signals. Inputs as :func:`lag_of`'s,
    smoothed here; m = 0 where the episode is too short for the search."""
    # the same three-frame box on both (it delays neither against the other): a stream with
    # a key frame every 2 frames alternates its noise from frame to frame, which the box
    # averages away (clean episodes' lags: within 60 ms unsmoothed, 13 ms smoothed)
    box = np.ones(SMOOTH_FRAMES) / SMOOTH_FRAMES
    x = np.convolve(speed_state, box, "same")
    y = np.convolve(motion, box, "same")
    k_max = max(1, round(LAG_SEARCH_S * fps))
    i = np.arange(k_max, len(x) - k_max)
    ks = np.arange(-k_max, k_max + 1)
    xs = np.broadcast_to(x[i], (len(ks), len(i)))
    ys = y[i[None, :] + ks[:, None]] if len(i) else np.zeros((len(ks), 0))
    w0 = (np.isfinite(xs) & np.isfinite(ys)).astype(np.float64)
    xs, ys = np.nan_to_num(xs), np.nan_to_num(ys)

    def peak(idx: np.ndarray) -> tuple[float, float]:
        w, a, b = w0[:, idx], xs[:, idx], ys[:, idx]
        n = np.maximum(w.sum(axis=1, keepdims=True), 1)
        a = (a - (w * a).sum(axis=1, keepdims=True) / n) * w
        b = (b - (w * b).sum(axis=1, keepdims=True) / n) * w
        den = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
        r = np.where(den > 0, (a * b).sum(axis=1) / np.where(den > 0, den, 1), -1.0)
        j = int(np.argmax(r))
        off = 0.0
        if 0 < j < len(r) - 1:  # the parabola's vertex through the peak and its neighbours
            curve = r[j - 1] - 2 * r[j] + r[j + 1]
            off = 0.5 * (r[j - 1] - r[j + 1]) / curve if curve < 0 else 0.0
        return (ks[j] + off) / fps * 1000, float(r[j])

    return peak, len(i)


def lag_of(speed_state: np.ndarray, motion: np.ndarray, fps: float) -> dict:
    """The delay of the image's motion behind the state's (ms; positive: the camera late):
    the peak of their cross-correlation on the data's frame grid, refined by a parabola
    through its neighbours (:func:`lag_peaks`), and a 95 % interval from a delete-one-block
    jackknife over the frames (:data:`LAG_BLOCK_S`), kept within the search
    (±:data:`LAG_SEARCH_S`). Both (N,) float64, per frame interval; NaN where a signal is
    unknown (a frozen or lost frame), left out of every sum. ``lag_note`` says why there is no
    value."""

    none = {
        "lag_ms": None,
        "lag_low_ms": None,
        "lag_high_ms": None,
        "lag_r": None,
        "lag_peak_ms": None,
    }
    if len(speed_state) < LAG_MIN_S * fps:
        return none | {"lag_note": f"not measurable: shorter than {LAG_MIN_S:g} s"}
    if np.nanstd(speed_state) == 0 or np.nanstd(motion) == 0:
        return none | {"lag_note": "not measurable: nothing moves"}
    peak, m = lag_peaks(speed_state, motion, fps)
    lag, r = peak(np.arange(m))
    if r < LAG_MIN_R:
        return none | {
            "lag_r": r,
            "lag_peak_ms": lag,
            "lag_note": f"not measurable: motions match poorly (r {r:.2f})",
        }
    # contiguous blocks, each left out in turn: neighbouring frames' noise stays together
    blocks = max(2, m // max(2, round(LAG_BLOCK_S * fps)))
    edges = np.linspace(0, m, blocks + 1).round().astype(int)
    left_out = np.array([peak(np.r_[0 : edges[g], edges[g + 1] : m])[0] for g in range(blocks)])
    se = math.sqrt((blocks - 1) / blocks * ((left_out - left_out.mean()) ** 2).sum())
    half = float(scipy_stats().t.ppf(0.975, blocks - 1)) * se
    reach = LAG_SEARCH_S * 1000  # no delay beyond the search can be read: the interval ends there
    low, high = max(lag - half, -reach), min(lag + half, reach)
    if high - low >= LAG_CANNOT_TELL_SHARE * 2 * reach:
        # the interval is the search itself: the peak is one of many the data allow
        return none | {
            "lag_low_ms": low,
            "lag_high_ms": high,
            "lag_r": r,
            "lag_peak_ms": lag,
            "lag_note": f"cannot tell: the interval [{low:.0f}, {high:.0f}] ms "
            f"fills the search (peak at {lag:.0f} ms, r {r:.2f})",
        }
    return {
        "lag_ms": lag,
        "lag_low_ms": low,
        "lag_high_ms": high,
        "lag_r": r,
        "lag_peak_ms": lag,
        "lag_note": None,
    }


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
                "lag_camera_ms": lag["lag_ms"],
                "lag_camera_low_ms": lag["lag_low_ms"],
                "lag_camera_high_ms": lag["lag_high_ms"],
                "lag_camera_note": lag["lag_note"],
                "lag_camera_ref": cams[0],
            }
    return out

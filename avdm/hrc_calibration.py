"""The HRC's response-to-speed curve for a camera: measured on pans over 1/f clutter, cached.

An HRC reads temporal frequency; Dror, O'Carroll & Laughlin (2001) showed that natural images,
whose amplitude spectra fall as 1/f alike, give it a consistent mean response per speed below
its peak. So the curve is measured on what natural scenes have in common, 1/f clutter with
random phases (the seeds of ``avdm.calibration``, which ``avdm-natural`` is fitted on too),
never on the validation photographs: a camera with this fps and pitch and a 70° field of view
pans across it at 0.5–600 deg/s (``clutter_pan``); the mean R̄ after the warm-up per speed is fitted
(least squares on log R̄, speeds up to twice the measured peak) with
``R(v) = r_peak · (2x^k / (1 + x^(2k)))^(1/k)``, x = v / v_peak; the non-directional change
C̄ at v_peak is kept as ``change_max``, the validity flag's bound.

A fit takes seconds (more at a video pitch); it is cached in the user's cache folder
(``avdm.calibration_store.cache_dir``) under a key of everything that changes it.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from avdm.calibration import CLUTTER_SEEDS, VIEW_FRACTION
from avdm.calibration_store import cache_path, read_cached, write_cached
from avdm.errors import ParameterError
from avdm.hrc import Hrc, HrcParams, response_curve
from avdm.stimuli import clutter_image
from avdm.version import __version__

# the decoding constants and the validity threshold do not change the measured curve
NOT_HRC_DYNAMICS = frozenset({"r_peak", "v_peak_dps", "knee", "change_max", "valid_fraction"})
CAL_SPEEDS_DPS = tuple(float(v) for v in np.geomspace(0.5, 600.0, 19))
CAL_FOV_DEG = 70.0
CAL_ASPECT = 72.0 / 99.0  # H/W of the calibration raster (the robot camera's)
_MEMO: dict[str, dict[str, Any]] = {}


def calibration_raster(deg_per_px: float) -> tuple[int, int]:
    """(H, W) of the calibration camera: 70° across at this pitch (32–640 px wide)."""
    w = int(min(640, max(32, round(CAL_FOV_DEG / deg_per_px))))
    return max(8, round(w * CAL_ASPECT)), w


def clutter_pan(
    size: tuple[int, int], fps: float, deg_per_px: float, omega_dps: float, n_frames: int, seed: int
) -> np.ndarray:
    """A camera of ``size`` (H, W) uint8 panning at ``omega_dps`` across 1/f clutter (image
    motion toward +x): frames (T, H, W). The clutter (``avdm.stimuli.clutter_image``, periodic)
    is made at the camera's pitch, ``1/VIEW_FRACTION`` times the view's width, and shifted by
    exact sub-pixel Fourier shifts; levels 0–255 rounded, as a camera delivers them."""

    h, w = size
    wide = math.ceil(w / VIEW_FRACTION)
    scene = (clutter_image((h, wide), seed=seed) + 1.0) * 127.5
    spectrum = np.fft.rfft(scene, axis=1)
    k = np.fft.rfftfreq(wide) * wide
    out = np.empty((n_frames, h, w), dtype=np.uint8)
    for i in range(n_frames):
        shift = omega_dps * i / fps / deg_per_px  # px the image has moved toward +x
        moved = np.fft.irfft(spectrum * np.exp(-2j * np.pi * k * shift / wide), n=wide, axis=1)
        out[i] = np.clip(np.rint(moved[:, :w]), 0, 255)
    return out


def measure_curve(
    params: HrcParams, speeds_dps: tuple[float, ...] = CAL_SPEEDS_DPS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speeds (S,), mean R̄ (S,), mean C̄ (S,) over the clutter seeds): the raw response and
    the non-directional change of an HRC of ``params`` (decoding constants ignored) to image
    motion toward +x at each speed."""

    size = calibration_raster(params.deg_per_px)
    probe = params.replace(r_peak=1.0, v_peak_dps=1.0, knee=1.0, change_max=1.0)
    warm = 2 * params.tw
    n = warm + max(20, round(params.fps))
    resp = np.zeros(len(speeds_dps))
    change = np.zeros(len(speeds_dps))
    for seed in CLUTTER_SEEDS:
        for i, v in enumerate(speeds_dps):
            frames = clutter_pan(size, params.fps, params.deg_per_px, float(v), n, seed)
            out = Hrc(probe).run(frames)
            resp[i] += out["response"][warm:].mean()
            change[i] += out["change"][warm:].mean()
    k = len(CLUTTER_SEEDS)
    return np.asarray(speeds_dps, dtype=np.float64), resp / k, change / k


def fit_curve(speeds: np.ndarray, resp: np.ndarray, change: np.ndarray) -> dict[str, Any]:
    """Least squares of log R̄ against ``response_curve`` over the speeds up to twice the
    measured peak with a positive response: r_peak, v_peak_dps, knee and the fit's quality;
    and ``change_max``, C̄ at v_peak (log-log interpolated): a scene changing faster than
    the clutter at the peak is past the peak, where a reading cannot be trusted."""
    from scipy.optimize import least_squares  # lazy: start-up

    i_peak = int(np.argmax(resp))
    if resp[i_peak] <= 0:
        raise ParameterError("the hrc gave no positive response on the calibration clutter.")
    use = (speeds <= 2.0 * speeds[i_peak]) & (resp > 0)
    v, y = speeds[use], np.log(resp[use])

    def resid(theta: np.ndarray) -> np.ndarray:
        r_p, v_p, k = np.exp(theta)
        return np.log(response_curve(v, r_p, v_p, k)) - y

    start = np.log([resp[i_peak], speeds[i_peak], 1.0])
    span = np.array([3.0, 3.0, 2.0])  # e^±3 around the measured peak, knee e^±2
    fit = least_squares(resid, start, bounds=(start - span, start + span))
    r_p, v_p, k = (float(x) for x in np.exp(fit.x))
    rising = use & (speeds <= speeds[i_peak])
    err = response_curve(speeds[rising], r_p, v_p, k) / resp[rising] - 1.0
    change_max = float(np.exp(np.interp(np.log(v_p), np.log(speeds), np.log(change))))
    return {
        "r_peak": r_p,
        "v_peak_dps": v_p,
        "knee": k,
        "change_max": change_max,
        "n_points": int(use.sum()),
        "rms_log_error": float(np.sqrt(np.mean(fit.fun**2))),
        "max_rel_error_rising": float(np.abs(err).max()) if err.size else math.nan,
        "speeds_dps": [float(s) for s in speeds],
        "response": [float(r) for r in resp],
        "change": [float(c) for c in change],
    }


def hrc_key(params: HrcParams) -> dict[str, Any]:
    dyn = {k: v for k, v in params.to_dict().items() if k not in NOT_HRC_DYNAMICS}
    dyn["fps"] = float(f"{params.fps:.9g}")
    dyn["deg_per_px"] = float(f"{params.deg_per_px:.9g}")
    return {
        "model": "hrc",
        "curve": sorted(NOT_HRC_DYNAMICS - {"valid_fraction"}),  # what an entry holds
        "dynamics": dyn,
        "speeds_dps": list(CAL_SPEEDS_DPS),
        "raster_hw": list(calibration_raster(params.deg_per_px)),
        "vdc_version": __version__,
    }


def hrc_calibration(params: HrcParams) -> dict[str, Any]:
    """The response curve for ``params``' camera and dynamics: remembered, cached on disk, or
    measured now and cached. ``source`` says which (``memo``, ``cache`` or ``fitted``)."""

    key = hrc_key(params)
    text = json.dumps(key, sort_keys=True)
    if text in _MEMO:
        return {**_MEMO[text], "source": "memo"}
    path = cache_path(key, f"hrc-{params.fps:g}Hz")
    cached = read_cached(path, key)
    if cached is not None:
        entry = {**cached, "source": "cache"}
    else:
        entry = {"key": key, **fit_curve(*measure_curve(params)), "source": "fitted"}
        write_cached(path, entry)
    _MEMO[text] = entry
    return entry

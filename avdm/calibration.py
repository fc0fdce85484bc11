"""Least-squares calibration of the AVDM decoding constants (a, b) on drifting gratings.

The decoding layer is ``ω̂ = a · λ̂^b · g(C) · √R̄`` with ``g(C) = (1+C)/(2C)``. Taking logs,
``log ω − log(g·√R̄) = log a + b · log λ̂``: an ordinary least-squares line over grating cells
whose true ω is known. Only the *valid band* is used:

* at least 2 periods across the image (the texture pathway needs them) and at least 4 px per
  period (≤ 90° of phase between neighbouring detectors: no spatial aliasing);
* TF ≤ fps / 4 (≤ 90° of phase per frame: far from temporal aliasing);
* a response in every frame after warm-up (no dead zone).

A cell's value is the mean over its frames after ``2·Tw`` warm-up frames.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from avdm.avdm_model import Avdm, AvdmParams
from avdm.avdm_multiscale import AvdmMultiScale
from avdm.errors import ParameterError
from avdm.stimuli import clutter_image, grating, panned_image

MIN_PERIODS_ACROSS = 2.0
MIN_PERIOD_PX = 4.0
MAX_TF_FRACTION = 0.25


@dataclasses.dataclass(frozen=True)
class CellResponse:
    """Time-averaged AVDM outputs for one grating (after warm-up)."""

    period_px: float
    tf_hz: float
    contrast: float
    omega_true_dps: float
    lambda_px: float
    motion: float
    gain_term: float  # mean of g(C)·motion, the part of ω̂ that a and b do not touch
    responsive: bool  # motion > 0 in every frame after warm-up


@dataclasses.dataclass(frozen=True)
class CalibrationResult:
    a: float
    b: float
    r2: float  # of the log-log fit
    rms_rel_error: float  # RMS of (ω̂ − ω)/ω over the cells, after the fit
    max_rel_error: float
    n_points: int
    fps: float
    deg_per_px: float
    width: int
    height: int
    cells: tuple[CellResponse, ...]

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("cells")
        return d


def valid_periods_px(width: int) -> np.ndarray:
    """Log-spaced spatial periods (px) inside the valid band for an image ``width`` px wide."""
    hi = width / MIN_PERIODS_ACROSS
    if hi < MIN_PERIOD_PX:
        raise ParameterError(f"images {width} px wide are too narrow to calibrate (need >= 8 px).")
    return np.geomspace(MIN_PERIOD_PX, hi, 8)


def valid_tfs_hz(fps: float) -> np.ndarray:
    """Log-spaced temporal frequencies (Hz) inside the valid band at ``fps``."""
    return np.geomspace(fps / 300.0, fps * MAX_TF_FRACTION, 8)


def measure_cell(
    params: AvdmParams,
    *,
    size: tuple[int, int],
    period_px: float,
    tf_hz: float,
    contrast: float = 1.0,
    deg_per_px: float | None = None,
    dtype: type | np.dtype = np.uint8,
) -> CellResponse:
    """Run a fresh AVDM (with ``params``) on one drifting grating and average its outputs.

    The grating lasts one temporal cycle (so every phase is seen) but at least ``3·Tw`` frames
    after warm-up, and at most 2 s.
    """
    warm = 2 * params.tw
    n = int(np.clip(round(params.fps / tf_hz), 3 * params.tw, 2 * params.fps)) + warm
    frames = grating(
        size=size,
        fps=params.fps,
        tf_hz=tf_hz,
        period_px=period_px,
        n_frames=n,
        contrast=contrast,
        direction=params.direction,  # the model's preferred direction
        dtype=dtype,
    )
    unit = params.replace(a=1.0, b=1.0)  # ω̂ with a = b = 1 is λ̂·g·√R̄
    out = Avdm(unit).run(frames)  # type: ignore[arg-type]
    sl = slice(warm, None)
    lam = out["lambda_px"][sl]
    gain_term = out["omega_dps"][sl] / lam
    dpp = params.deg_per_px if deg_per_px is None else deg_per_px
    return CellResponse(
        period_px=float(period_px),
        tf_hz=float(tf_hz),
        contrast=float(contrast),
        omega_true_dps=float(tf_hz * period_px * dpp),
        lambda_px=float(lam.mean()),
        motion=float(out["motion"][sl].mean()),
        gain_term=float(gain_term.mean()),
        responsive=bool((out["motion"][sl] > 0).all()),
    )


def fit_decoding(
    params: AvdmParams,
    *,
    size: tuple[int, int],
    periods_px: np.ndarray | None = None,
    tfs_hz: np.ndarray | None = None,
    contrasts: tuple[float, ...] = (0.5, 1.0),
    progress: Any = None,
) -> CalibrationResult:
    """Fit (a, b) for ``params.fps`` and ``params.deg_per_px`` on frames of ``size`` (H, W).

    ``progress`` (optional) is called with no arguments after each grating cell.
    """
    h, w = size
    periods = valid_periods_px(w) if periods_px is None else np.asarray(periods_px, float)
    tfs = valid_tfs_hz(params.fps) if tfs_hz is None else np.asarray(tfs_hz, float)
    cells = []
    for period in periods:
        for tf in tfs:
            for c in contrasts:
                cells.append(
                    measure_cell(params, size=size, period_px=period, tf_hz=tf, contrast=c)
                )
                if progress is not None:
                    progress()
    used = [
        c
        for c in cells
        if c.responsive
        and c.period_px >= MIN_PERIOD_PX
        and w / c.period_px >= MIN_PERIODS_ACROSS
        and c.tf_hz <= params.fps * MAX_TF_FRACTION
    ]
    if len(used) < 3:
        raise ParameterError(
            f"only {len(used)} grating cells are in the valid band (responsive, no aliasing); "
            "widen the grid or check the model parameters."
        )
    x = np.log([c.lambda_px for c in used])
    y = np.log([c.omega_true_dps for c in used]) - np.log([c.gain_term for c in used])
    design = np.column_stack([np.ones_like(x), x])
    (log_a, b), *_ = np.linalg.lstsq(design, y, rcond=None)
    resid = y - design @ np.array([log_a, b])
    r2 = 1.0 - float(resid @ resid) / float(((y - y.mean()) ** 2).sum())
    a = float(np.exp(log_a))
    predicted = np.array([a * c.lambda_px**b * c.gain_term for c in used])
    truth = np.array([c.omega_true_dps for c in used])
    rel = (predicted - truth) / truth
    return _result(a, float(b), r2, rel, params, (h, w), tuple(cells))


def _result(
    a: float,
    b: float,
    r2: float,
    rel: np.ndarray,
    params: Any,
    size: tuple[int, int],
    cells: tuple[CellResponse, ...] = (),
) -> CalibrationResult:
    """A fit's result from its constants and the relative errors of the points it used."""
    return CalibrationResult(
        a=a,
        b=b,
        r2=r2,
        rms_rel_error=float(np.sqrt(np.mean(rel**2))),
        max_rel_error=float(np.max(np.abs(rel))),
        n_points=len(rel),
        fps=params.fps,
        deg_per_px=params.deg_per_px,
        width=size[1],
        height=size[0],
        cells=cells,
    )


# -- the multi-scale AVDM (avdm-natural): fitted on drifting 1/f clutter --------------------
#
# Its decoding is calibrated on what it is meant for, natural-image statistics, but not on
# photographs: the validation protocol (benchmarks/bench_avdm_truth.py) pans real photographs,
# which the fit never sees. The clutter has a 1/f amplitude spectrum (that of natural scenes
# on average) with random phases from fixed seeds.

CLUTTER_SEEDS = (11, 12, 13)
CLUTTER_SIZE = (256, 768)  # (H, W) of the panorama; the camera sees VIEW_FRACTION of it
VIEW_FRACTION = 0.4


@dataclasses.dataclass(frozen=True)
class PanResponse:
    """The time-averaged reading of one pan over clutter (after warm-up)."""

    omega_true_dps: float
    omega_dps: float  # with the params' decoding (a = b = 1 while fitting)
    seed: int


def clutter_pans(
    params: Any,
    *,
    size: tuple[int, int],
    speeds_dps: np.ndarray,
    seeds: tuple[int, ...] = CLUTTER_SEEDS,
    progress: Any = None,
) -> list[PanResponse]:
    """Pan a camera of ``size`` (H, W) at ``params.deg_per_px`` across 1/f clutter at each
    speed and read it with a multi-scale AVDM of ``params``. Returns one response per (speed,
    seed)."""

    fov = size[1] * params.deg_per_px
    warm = 2 * params.tw
    n = warm + max(30, round(params.fps))  # at least one second of readings
    out = []
    # a tall raster (a portrait video) needs a panorama tall enough for the camera's window
    rows = max(CLUTTER_SIZE[0], math.ceil(VIEW_FRACTION * CLUTTER_SIZE[1] * size[0] / size[1]) + 2)
    for seed in seeds:
        scene = (clutter_image((rows, CLUTTER_SIZE[1]), seed=seed) + 1.0) * 127.5
        for v in speeds_dps:
            frames = panned_image(
                scene,
                size=size,
                fov_deg=fov,
                image_deg=fov / VIEW_FRACTION,
                fps=params.fps,
                omega_dps=float(v),
                n_frames=n,
            )
            reading = AvdmMultiScale(params).run(frames)["omega_dps"][warm:]
            out.append(PanResponse(float(v), float(reading.mean()), seed))
            if progress is not None:
                progress()
    return out


def fit_multiscale(
    params: Any,
    *,
    size: tuple[int, int],
    speeds_dps: np.ndarray | None = None,
    progress: Any = None,
) -> CalibrationResult:
    """Fit (a, b) of ``ω̂ = a·ν^b`` for the multi-scale AVDM (``params`` with any a, b) at its
    fps and deg/px, on camera pans over 1/f clutter from 1 deg/s to ``params.max_dps``."""
    speeds = np.geomspace(1.0, params.max_dps, 10) if speeds_dps is None else speeds_dps
    # Two passes: the scale choice compares calibrated speeds with each scale's range, so the
    # second pass refits the residual of the first with the first's constants in place.
    a, b = 1.0, 1.0
    for _ in range(2):
        pans = clutter_pans(
            params.replace(a=a, b=b),
            size=size,
            speeds_dps=speeds,
            progress=progress,
        )
        used = [p for p in pans if p.omega_dps > 0]
        if len(used) < 3:
            raise ParameterError(
                f"only {len(used)} clutter pans gave a reading; check the model parameters."
            )
        x = np.log([p.omega_dps for p in used])
        y = np.log([p.omega_true_dps for p in used])
        design = np.column_stack([np.ones_like(x), x])
        (c, d), *_ = np.linalg.lstsq(design, y, rcond=None)
        # true ≈ e^c · (a·ν^b)^d  →  a' = e^c · a^d, b' = b·d
        a, b = float(np.exp(c) * a**d), float(b * d)
    resid = y - design @ np.array([c, d])
    r2 = 1.0 - float(resid @ resid) / float(((y - y.mean()) ** 2).sum())
    rel = np.exp(design @ np.array([c, d]) - y) - 1.0
    return _result(a, b, r2, rel, params, size)

"""Offline stimuli: drifting gratings and drifting natural scenes, as frame stacks.

Conventions (docs/architecture.md, "Units and frames"):

* a stimulus image of width W px stands for a full 360° circle, so deg/px = 360 / W;
* spatial frequency SF is in **units per circle (upc)** = cycles across the image; the spatial
  period is ``W / SF`` px; temporal frequency TF is in Hz; the true angular velocity is
  ``ω = TF · 360 / SF`` deg/s (``TF · period_px · deg_per_px`` in general);
* pixels sample the pattern at their centres, columns j = 0 … W−1, frames n = 0 … T−1 at ``fps``;
* intensities are on [0, 1]. ``normalisation="peak"`` keeps the peak at 1 (mean 1/(1+C)): the
  condition under which the AVDM's (1+C)/(2C) factor removes contrast exactly;
  ``"mean"`` keeps the mean at 0.5.
* ``dtype=np.uint8`` rounds intensities to 0–255 (what a camera or a recording holds).

Every function returns ``frames`` of shape (T, H, W).
"""

from __future__ import annotations

import math

import numpy as np

from avdm.errors import ParameterError

NORMALISATIONS = ("peak", "mean")
WAVEFORMS = ("sine", "square")


def period_px_from_sf(sf_upc: float, width: int) -> float:
    """Spatial period in px of ``sf_upc`` cycles across an image ``width`` px wide."""
    if not sf_upc > 0:
        raise ParameterError(f"spatial frequency must be > 0 upc, got {sf_upc}.")
    return width / sf_upc


def omega_true_dps(sf_upc: float, tf_hz: float) -> float:
    """True angular velocity ω = TF · 360 / SF, deg/s, of a grating on a full-circle image."""
    return tf_hz * 360.0 / sf_upc


def _n_frames(fps: float, duration_s: float | None, n_frames: int | None) -> int:
    if not (math.isfinite(fps) and fps > 0):
        raise ParameterError(f"fps must be a positive number, got {fps}.")
    if n_frames is None:
        if duration_s is None or not (math.isfinite(duration_s) and duration_s > 0):
            raise ParameterError(
                f"duration must be a positive number of seconds, got {duration_s}."
            )
        n_frames = round(duration_s * fps)
    if n_frames < 1:
        raise ParameterError(f"a stimulus needs at least one frame, got {n_frames}.")
    return int(n_frames)


def _check_size(size: tuple[int, int]) -> tuple[int, int]:
    h, w = (int(s) for s in size)
    if h < 1 or w < 2:
        raise ParameterError(
            f"a stimulus must be at least 2x1 px (W x H), got {w}x{h} px (size {size}, H, W)."
        )
    return h, w


def _levels(contrast: float, normalisation: str) -> tuple[float, float]:
    """(mean, amplitude) of intensities for Michelson ``contrast`` under ``normalisation``."""
    if not (math.isfinite(contrast) and 0.0 <= contrast <= 1.0):
        raise ParameterError(f"contrast must be between 0 and 1, got {contrast}.")
    if normalisation == "peak":
        mean = 1.0 / (1.0 + contrast)
    elif normalisation == "mean":
        mean = 0.5
    else:
        raise ParameterError(
            f"normalisation must be one of {NORMALISATIONS}, got {normalisation!r}."
        )
    return mean, mean * contrast


def _finish(intensity: np.ndarray, dtype: type | np.dtype) -> np.ndarray:
    intensity = np.clip(intensity, 0.0, 1.0)
    dt = np.dtype(dtype)
    if dt == np.uint8:
        return np.rint(intensity * 255.0).astype(np.uint8)
    if dt in (np.float32, np.float64):
        return intensity.astype(dt)
    raise ParameterError(f"dtype must be uint8, float32 or float64, got {dt}.")


def grating(
    *,
    size: tuple[int, int] = (100, 100),
    fps: float = 300.0,
    tf_hz: float = 1.0,
    sf_upc: float | None = None,
    period_px: float | None = None,
    duration_s: float | None = 1.0,
    n_frames: int | None = None,
    contrast: float = 1.0,
    normalisation: str = "peak",
    waveform: str = "sine",
    direction: int = 1,
    phase_rad: float = 0.0,
    dtype: type | np.dtype = np.uint8,
) -> np.ndarray:
    """A vertical grating drifting horizontally, frames (T, H, W).

    Give the spatial frequency either as ``sf_upc`` (cycles across the image) or as
    ``period_px``. ``direction=+1`` drifts toward +x (increasing column index), the AVDM's
    default preferred direction. ``n_frames`` overrides ``duration_s``.

    Intensity at column j, frame n: ``mean · (1 + C · s(2π (j − d·v·n) / period + phase))``
    with ``v = TF · period / fps`` px/frame and ``s`` = sin or the sign of sin (square wave).
    """
    h, w = _check_size(size)
    t = _n_frames(fps, duration_s, n_frames)
    if (sf_upc is None) == (period_px is None):
        raise ParameterError("give exactly one of sf_upc and period_px.")
    period = period_px_from_sf(sf_upc, w) if sf_upc is not None else float(period_px)  # type: ignore[arg-type]
    if not (math.isfinite(period) and period > 0):
        raise ParameterError(f"spatial period must be a positive number of px, got {period}.")
    if not (math.isfinite(tf_hz) and tf_hz >= 0):
        raise ParameterError(f"temporal frequency must be >= 0 Hz, got {tf_hz}.")
    if direction not in (1, -1):
        raise ParameterError(f"direction must be 1 or -1, got {direction}.")
    if waveform not in WAVEFORMS:
        raise ParameterError(f"waveform must be one of {WAVEFORMS}, got {waveform!r}.")
    mean, amp = _levels(contrast, normalisation)
    # phase in cycles; computed per frame and column only (rows are identical)
    cols = np.arange(w, dtype=np.float64) / period
    shift = direction * tf_hz * np.arange(t, dtype=np.float64) / fps
    phase = 2.0 * np.pi * (cols[None, :] - shift[:, None]) + phase_rad
    wave = np.sin(phase)
    if waveform == "square":
        wave = np.where(wave >= 0.0, 1.0, -1.0)
    rows = _finish(mean + amp * wave, dtype)  # (T, W)
    return np.ascontiguousarray(np.broadcast_to(rows[:, None, :], (t, h, w)))


def clutter_image(size: tuple[int, int], *, seed: int = 0, exponent: float = 1.0) -> np.ndarray:
    """A natural-scene-like image with a 1/f^exponent amplitude spectrum, (H, W) float64.

    Random phases from ``seed``; periodic in both axes (so it can drift around the circle
    without a seam); scaled so its minimum is −1 and maximum +1.
    """
    h, w = _check_size(size)
    if not (math.isfinite(exponent) and exponent >= 0):
        raise ParameterError(f"spectral exponent must be >= 0, got {exponent}.")
    rng = np.random.default_rng(seed)
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    radius = np.sqrt(fx**2 + fy**2)
    radius[0, 0] = np.inf  # no DC: the mean is set by the normalisation
    amplitude = radius**-exponent
    phases = rng.uniform(0.0, 2.0 * np.pi, size=amplitude.shape)
    img = np.fft.irfft2(amplitude * np.exp(1j * phases), s=(h, w))
    lo, hi = img.min(), img.max()
    if hi - lo < 1e-12:
        return np.zeros((h, w))
    return 2.0 * (img - lo) / (hi - lo) - 1.0


def resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resample a 2-D image to ``size`` (H, W) by area averaging (down) / linear (up), float64."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or img.shape[0] < 1 or img.shape[1] < 2:
        raise ParameterError(
            f"an image must be 2-D with at least 2x1 px (W x H), got shape {img.shape} (H, W)."
        )
    h, w = _check_size(size)

    return _area_matrix(img.shape[0], h) @ img @ _area_matrix(img.shape[1], w).T


def _area_matrix(n_in: int, n_out: int) -> np.ndarray:
    """Area-averaging weights (n_out, n_in): overlap of output cells with input cells."""
    edges_in = np.linspace(0.0, 1.0, n_in + 1)
    edges_out = np.linspace(0.0, 1.0, n_out + 1)
    lo = np.maximum(edges_out[:-1, None], edges_in[None, :-1])
    hi = np.minimum(edges_out[1:, None], edges_in[None, 1:])
    weights = np.clip(hi - lo, 0.0, None)
    return weights / weights.sum(axis=1, keepdims=True)


def drifting_image(
    image: np.ndarray,
    *,
    size: tuple[int, int] | None = None,
    fps: float = 300.0,
    speed_px_s: float = 10.0,
    duration_s: float | None = 1.0,
    n_frames: int | None = None,
    contrast: float = 1.0,
    normalisation: str = "peak",
    direction: int = 1,
    dtype: type | np.dtype = np.uint8,
) -> np.ndarray:
    """An image drifting horizontally around the circle at ``speed_px_s``, frames (T, H, W).

    ``image`` (2-D, any range) is resampled to ``size`` if given, rescaled to [−1, 1], then
    shown as ``mean · (1 + C · z)``. Sub-pixel shifts are exact (Fourier shift along x, the image
    wrapping around the circle); a non-periodic photograph therefore shows a seam where its
    left and right edges meet.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ParameterError(f"an image must be 2-D (grayscale), got shape {img.shape}.")
    if not np.isfinite(img).all():
        raise ParameterError("the image contains NaN or infinite values.")
    if size is not None:
        img = resize_image(img, size)
    h, w = _check_size(img.shape)
    t = _n_frames(fps, duration_s, n_frames)
    if not math.isfinite(speed_px_s):
        raise ParameterError(f"drift speed must be finite, got {speed_px_s}.")
    if direction not in (1, -1):
        raise ParameterError(f"direction must be 1 or -1, got {direction}.")
    lo, hi = img.min(), img.max()
    z = 2.0 * (img - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros_like(img)
    mean, amp = _levels(contrast, normalisation)
    spectrum = np.fft.rfft(z, axis=1)  # (H, W//2+1)
    k = np.fft.rfftfreq(w) * w  # cycles across the image
    shifts = direction * speed_px_s * np.arange(t) / fps  # px, toward +x for direction +1
    out = np.empty((t, h, w), dtype=np.dtype(dtype))
    chunk = 256  # bound the complex temporaries
    for s in range(0, t, chunk):
        ph = np.exp(-2j * np.pi * k[None, :] * shifts[s : s + chunk, None] / w)  # (c, K)
        moved = np.fft.irfft(spectrum[None, :, :] * ph[:, None, :], n=w, axis=2)
        out[s : s + chunk] = _finish(mean + amp * moved, dtype)
    return out


def natural_scene(
    *,
    size: tuple[int, int] = (100, 100),
    fps: float = 300.0,
    tf_hz: float = 1.0,
    nominal_period_px: float = 10.0,
    duration_s: float | None = 1.0,
    n_frames: int | None = None,
    seed: int = 0,
    exponent: float = 1.0,
    image: np.ndarray | None = None,
    contrast: float = 1.0,
    normalisation: str = "peak",
    direction: int = 1,
    dtype: type | np.dtype = np.uint8,
) -> np.ndarray:
    """A drifting natural scene, frames (T, H, W).

    The scene is 1/f clutter generated from ``seed`` or, if given, ``image`` (a 2-D array a
    caller read from a file). Like the arena's natural-scene walls (docs/architecture.md), it
    drifts at ``tf_hz · nominal_period_px`` px/s, so "TF" means the same speed a grating of that
    period would have.
    """
    if not (math.isfinite(nominal_period_px) and nominal_period_px > 0):
        raise ParameterError(f"nominal period must be > 0 px, got {nominal_period_px}.")
    base = clutter_image(size, seed=seed, exponent=exponent) if image is None else image
    return drifting_image(
        base,
        size=size,
        fps=fps,
        speed_px_s=tf_hz * nominal_period_px,
        duration_s=duration_s,
        n_frames=n_frames,
        contrast=contrast,
        normalisation=normalisation,
        direction=direction,
        dtype=dtype,
    )


def panned_image(
    image: np.ndarray,
    *,
    size: tuple[int, int],
    fov_deg: float,
    image_deg: float,
    fps: float,
    omega_dps: float,
    n_frames: int,
    direction: int = 1,
    dtype: type | np.dtype = np.uint8,
) -> np.ndarray:
    """A camera panning across a photograph at a known angular velocity, frames (T, H, W).

    ``image`` (2-D, 0–255 or 0–1 scale kept as given, then clipped) is a panorama whose full
    width spans ``image_deg`` degrees and wraps around; the camera sees ``fov_deg`` of it
    (its centre rows, square pixels) and samples that window onto ``size`` (H, W) by area
    averaging, like a real sensor's pixels. The view turns by ``omega_dps · n / fps`` degrees
    at frame n (toward +x of the image for ``direction`` +1: the scene then moves toward −x on the
    sensor). Sub-pixel positions are exact: a Fourier shift of the panorama's rows.

    Intensities: an image on 0–255 gives uint8 levels directly; pass ``dtype`` float32 or
    float64 to keep them unrounded (divided by 255)."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ParameterError(f"an image must be 2-D (grayscale), got shape {img.shape}.")
    h, w = _check_size(size)
    n = _n_frames(fps, None, n_frames)
    if direction not in (1, -1):
        raise ParameterError(f"direction must be 1 or -1, got {direction}.")
    if not (0 < fov_deg < image_deg):
        raise ParameterError(f"the camera's field of view ({fov_deg}°) must be under {image_deg}°.")
    src_h, src_w = img.shape
    src_dpp = image_deg / src_w
    win_w = max(2, round(fov_deg / src_dpp))
    win_h = max(1, round(win_w * h / w))
    if win_h > src_h:
        raise ParameterError(
            f"the image is {src_h} px high but the camera's window needs {win_h} rows: "
            "use a wider field of view in the image or a taller image."
        )
    r0 = (src_h - win_h) // 2
    rows, cols = _area_matrix(win_h, h), _area_matrix(win_w, w).T
    spectrum = np.fft.rfft(img[r0 : r0 + win_h], axis=1)
    # The sensor's rows average the window's rows, and the pan shifts along the rows: the two
    # commute, so a camera with fewer rows than its window averages them once, on the
    # spectrum, and each frame's inverse transform has h rows, not win_h (a calibration's
    # clutter pans: 1.7x faster for a 99x72 camera, the same frames)
    fewer = h < win_h
    if fewer:
        spectrum = rows @ spectrum
    k = np.fft.rfftfreq(src_w) * src_w
    out = np.empty((n, h, w), dtype=np.dtype(dtype))
    for i in range(n):
        shift = direction * omega_dps * i / fps / src_dpp  # source px the view has turned
        moved = np.fft.irfft(spectrum * np.exp(2j * np.pi * k * shift / src_w), n=src_w, axis=1)
        view = moved[:, :win_w] @ cols if fewer else rows @ moved[:, :win_w] @ cols
        if np.dtype(dtype) == np.uint8:
            out[i] = np.clip(np.rint(view), 0, 255).astype(np.uint8)
        else:
            out[i] = np.clip(view / 255.0, 0.0, 1.0)
    return out

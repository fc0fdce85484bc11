"""Looming at a known time to contact, rendered over a photograph: the truth the flow
time-to-contact detector (:mod:`avdm.flow_ttc`) is tested against and the frames the footage
generator (``analysis.experiments.collision.looming_footage``) encodes.

Geometry (a pinhole camera of horizontal field of view ``hfov_deg`` on a ``(H, W)`` raster,
focal length ``f = (W / 2) / tan(hfov / 2)`` px):

* an object of radius ``R`` approaches at constant speed ``v``; its distance at frame ``t`` is
  ``d(t) = v · τ(t)`` with ``τ(t) = (contact_frame − t) / fps`` s, so its image radius is
  ``f · (R / v) / τ(t)`` px (``rv_s = R / v``, in seconds) and its time to contact is ``τ(t)``
  exactly. A near miss passes ``miss_radii · R`` to the side: its image centre is
  ``f · tan(atan(miss_radii · R / d))`` px off the axis and it leaves the view.
* the camera yaws at ``rotation_dps`` (deg/s, positive to the right): the background (a far
  photograph, read as a cylinder) pans left by ``rotation_dps / fps`` deg per frame, and the
  object, whose bearing is fixed in the world, moves with it; it is on the axis at contact.
* the object wears a second photograph (a disc of it); nothing of it is drawn before the
  **hazard onset**, the first frame from ``enter_frame`` on at which its image radius reaches
  1 px with its centre in view.
* light and contrast: ``out = 255 · light · (0.5 + contrast · (image − 0.5))`` with images on
  [0, 1]; then Gaussian sensor noise of ``noise_sd`` grey levels; rounded to uint8.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from avdm.errors import ParameterError


@dataclasses.dataclass(frozen=True)
class Looming:
    """One rendered approach: frames (T, H, W) uint8 and the truth per frame."""

    frames: np.ndarray  # (T, H, W) uint8
    tau_s: np.ndarray  # (T,) float64 time to contact of the object (s; inf once it is past)
    radius_px: np.ndarray  # (T,) float64 image radius of the object (0 before the onset)
    hazard_onset_frame: int | None  # first frame the object is drawn (None: never in view)


def focal_px(width: int, hfov_deg: float) -> float:
    """Pinhole focal length in px of a raster ``width`` px wide seeing ``hfov_deg``."""
    return (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)


def grey01(image: np.ndarray) -> np.ndarray:
    """A photograph (H, W) or (H, W, 3), uint8 or float on [0, 1], as float32 grey on [0, 1]."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    return np.clip(img.astype(np.float32), 0.0, 1.0)


def _panorama(background: np.ndarray, h: int, width_px: int) -> np.ndarray:
    """The background photograph resized to height ``h`` and tiled (mirrored, so seams match)
    to at least ``width_px`` columns."""
    bg = grey01(background)
    w0 = max(1, round(bg.shape[1] * h / bg.shape[0]))
    bg = cv2.resize(bg, (w0, h), interpolation=cv2.INTER_AREA)
    reps = math.ceil(width_px / w0) + 1
    tiles = [bg if k % 2 == 0 else bg[:, ::-1] for k in range(reps)]
    return np.ascontiguousarray(np.concatenate(tiles, axis=1))


def render_looming(
    background: np.ndarray,
    texture: np.ndarray,
    *,
    size: tuple[int, int],
    fps: float,
    hfov_deg: float,
    n_frames: int,
    contact_frame: int,
    rv_s: float,
    miss_radii: float = 0.0,
    rotation_dps: float = 0.0,
    contrast: float = 1.0,
    light: float = 1.0,
    noise_sd: float = 0.0,
    seed: int = 0,
    enter_frame: int = 0,
) -> Looming:
    """Render an object approaching over ``background`` (see the module for the geometry).

    ``background``, ``texture``: photographs (H, W[, 3]); ``size``: (H, W) of the frames;
    ``contact_frame``: the frame at which the object reaches the camera (may lie beyond the
    clip); ``rv_s``: object radius over approach speed (s); ``miss_radii``: lateral offset in
    object radii (0: a collision); ``enter_frame``: the object is not in the scene before this
    frame (it enters it, e.g. from behind a corner). Returns :class:`Looming`."""
    h, w = size
    if h < 4 or w < 4 or n_frames < 1 or not (fps > 0 and rv_s > 0 and 0 < hfov_deg < 180):
        raise ParameterError(
            "render_looming needs a raster of at least 4x4, frames, fps > 0, "
            "rv_s > 0 and 0 < hfov_deg < 180."
        )
    f = focal_px(w, hfov_deg)
    deg_per_px = hfov_deg / w  # of the background cylinder
    shift_px = rotation_dps / fps / deg_per_px
    pano = _panorama(background, h, w + math.ceil(abs(shift_px) * n_frames) + 2)
    tex = grey01(texture)
    tr = min(tex.shape) // 2  # the object's disc: the texture's largest centred circle
    tex = tex[
        tex.shape[0] // 2 - tr : tex.shape[0] // 2 + tr,
        tex.shape[1] // 2 - tr : tex.shape[1] // 2 + tr,
    ]
    yy, xx = np.mgrid[0 : 2 * tr, 0 : 2 * tr].astype(np.float32)
    disc = (((yy - tr + 0.5) ** 2 + (xx - tr + 0.5) ** 2) <= tr * tr).astype(np.float32)
    rng = np.random.default_rng(seed)
    frames = np.empty((n_frames, h, w), np.uint8)
    tau = np.empty(n_frames)
    radius = np.zeros(n_frames)
    onset: int | None = None
    start = 0.0 if shift_px >= 0 else abs(shift_px) * n_frames
    for t in range(n_frames):
        s = start + shift_px * t  # background pans left for a right yaw
        i = math.floor(s)
        a = s - i
        img = (1 - a) * pano[:, i : i + w] + a * pano[:, i + 1 : i + 1 + w]
        tau_t = (contact_frame - t) / fps
        tau[t] = tau_t if tau_t > 0 else math.inf
        if tau_t > 0:
            r = f * rv_s / tau_t
            # bearing off the axis: the miss offset, then the yaw still to come before contact
            side = math.atan(miss_radii * rv_s / tau_t) if miss_radii else 0.0
            yaw_left = math.radians(rotation_dps * (contact_frame - t) / fps)
            ang = side + yaw_left
            cx = w / 2 + f * math.tan(ang) if abs(ang) < math.radians(89) else math.inf
            visible = r >= 1.0 and abs(cx - w / 2) < w / 2 and t >= enter_frame
            if onset is None and visible:
                onset = t
            if onset is not None and math.isfinite(cx):
                radius[t] = r
                scale = r / tr
                src = tex
                if scale < 1:  # pre-blur so that the shrunk texture does not alias
                    src = cv2.GaussianBlur(tex, (0, 0), 0.5 / scale)
                m = np.array([[scale, 0, cx - tr * scale], [0, scale, h / 2 - tr * scale]])
                obj = cv2.warpAffine(src, m, (w, h), flags=cv2.INTER_LINEAR)
                alpha = cv2.warpAffine(disc, m, (w, h), flags=cv2.INTER_LINEAR)
                img = img * (1 - alpha) + obj * alpha
        out = 255.0 * light * (0.5 + contrast * (img - 0.5))
        if noise_sd > 0:
            out = out + rng.normal(0.0, noise_sd, size=out.shape)
        frames[t] = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return Looming(frames, tau, radius, onset)

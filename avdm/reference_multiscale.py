"""The multi-scale AVDM (``avdm-natural``) written plainly in NumPy: the test oracle of the
fast kernel in ``avdm.avdm_multiscale``. Same layers, same order; whole arrays per frame."""

from __future__ import annotations

import numpy as np

from avdm.avdm_multiscale import (
    MULTISCALE_OUTPUT_NAMES,
    VALID_SHIFT,
    AvdmMultiScaleParams,
    scale_geometry,
)
from avdm.base import run_by_steps

BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0


def low_pass(img: np.ndarray, hole: int, decimate: bool) -> np.ndarray:
    """5-tap binomial along both axes with taps ``hole`` apart (mirror borders without
    repeating the edge sample), then every 2nd sample if ``decimate``."""
    out = img
    for axis in (1, 0):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (2 * hole, 2 * hole)
        p = np.pad(out, pad, mode="reflect")
        n = out.shape[axis]
        acc = np.zeros_like(out)
        for t, wgt in zip(range(-2, 3), BINOMIAL, strict=True):
            sl = [slice(None), slice(None)]
            sl[axis] = slice(2 * hole + t * hole, 2 * hole + t * hole + n)
            acc = acc + wgt * p[tuple(sl)]
        out = acc
    return out[::2, ::2] if decimate else out


class AvdmMultiScaleReference:
    """``step(frame)`` → the model's outputs; float64 throughout (the kernel uses float32
    images, so the two agree to ~1e-5 relative)."""

    def __init__(self, params: AvdmMultiScaleParams) -> None:
        assert params.a is not None and params.b is not None
        self.p = params
        self.prev: list[np.ndarray] | None = None
        self.q: list[tuple[np.ndarray, np.ndarray]] = []
        self.r: list[np.ndarray] = []
        self.s: list[np.ndarray] = []

    def step(self, frame: np.ndarray) -> dict[str, float]:
        p = self.p
        img = frame.astype(np.float64) / (255.0 if frame.dtype == np.uint8 else 1.0)
        geo = scale_geometry(p, *img.shape)
        levels = [low_pass(img, 1, False)]
        for k in range(1, len(geo)):
            levels.append(low_pass(levels[-1], int(geo[k, 4]), bool(geo[k, 5])))
        if self.prev is None:
            self.prev = levels
            self.q = [(np.zeros_like(v), np.zeros_like(v)) for v in levels]
        r_k, s_k = [], []
        for k, (cur, old) in enumerate(zip(levels, self.prev, strict=True)):
            s = int(geo[k, 3])
            change = cur - old  # retina: one-frame difference
            on, off = np.maximum(change, 0), np.maximum(-change, 0)  # lamina
            on_p, off_p = self.q[k]
            # medulla: both mirror-image delay-and-correlate detectors, ON and OFF
            e = (
                on[:, :-s] * on_p[:, s:]
                + on[:, s:] * on_p[:, :-s]
                + off[:, :-s] * off_p[:, s:]
                + off[:, s:] * off_p[:, :-s]
            )
            r_k.append(e.mean())  # lobula: mean over the field
            d = cur[:, s:] - cur[:, :-s]  # texture: pooled spatial contrast
            s_k.append(2.0 * (d * d).mean())
            self.q[k] = (on, off)
        self.prev = levels
        self.r.append(np.array(r_k))
        self.s.append(np.array(s_k))
        rb = np.sum(self.r[-p.tw :], axis=0) / p.tw  # zeros before the first frame
        sb = np.sum(self.s[-p.tw :], axis=0) / p.tw
        factor = geo[:, 6].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where((sb > 0) & (rb > 0), np.sqrt(rb / sb), 0.0)
        nu = ratio * factor * p.deg_per_px * p.fps
        omega = np.where(nu > 0, p.a * nu**p.b, 0.0)
        floor = 2.0 * (p.min_texture / 255.0) ** 2
        finer_max = np.concatenate([[0.0], np.maximum.accumulate(sb)[:-1]])
        usable = (sb >= floor) & (sb >= p.min_texture_ratio**2 * finer_max)
        warm = 1.0 if len(self.r) >= p.tw else 0.0
        if not usable.any():
            return dict(
                zip(
                    MULTISCALE_OUTPUT_NAMES,
                    (0.0, factor[0] * p.deg_per_px, 0.0, np.sqrt(rb[0]), np.sqrt(sb[0]), 0.0),
                    strict=True,
                )
            )
        top = int(np.flatnonzero(usable)[-1])
        est, used = omega[top], top
        valid = warm if est / (factor[top] * p.deg_per_px * p.fps) <= VALID_SHIFT else 0.0
        for k in range(top - 1, -1, -1):  # coarse to fine
            if not usable[k]:
                continue
            shift = est / (factor[k] * p.deg_per_px * p.fps)
            w = min(1.0, (p.v_high - shift) / (p.v_high - p.v_low))
            if w <= 0:
                break
            est, used = w * omega[k] + (1 - w) * est, k
        values = (
            est,
            factor[used] * p.deg_per_px,
            est / (factor[used] * p.deg_per_px * p.fps),
            np.sqrt(rb[used]),
            np.sqrt(sb[used]),
            valid,
        )
        return dict(zip(MULTISCALE_OUTPUT_NAMES, (float(v) for v in values), strict=True))

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        return run_by_steps(self.step, frames, MULTISCALE_OUTPUT_NAMES, min_w=4)

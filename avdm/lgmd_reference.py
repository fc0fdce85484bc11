"""Plain NumPy LGMD collision detectors, layer by layer: the readable versions and test oracles.

* ``LgmdPlusReference``: LGMD+ as released (Fu et al. 2020, IEEE Access; lgmd_colias.md §2);
* ``LgmdColiasReference``: the Colias-IV firmware port "LGMD-Plus" (2019-08; lgmd_colias.md §3).

Both take 8-bit grey frames (uint8, or floats on [0, 1] which are scaled to 0–255 and rounded:
the models are defined on integer luminance). 3×3 operations replicate the image edge.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, ClassVar

import numpy as np

from avdm.base import Output, check_frames, run_by_steps
from avdm.lgmd_params import (
    LGMD_OUTPUT_NAMES,
    LGMD_OUTPUTS,
    bias_matrix,
    frame_interval_ms,
    lowpass_alpha,
)

# 3×3 Gaussian, σ = 1 (released code's weights)
GAUSS_CENTRE, GAUSS_EDGE, GAUSS_CORNER = 0.20418, 0.12384, 0.07511
RING = np.array([[2, 1, 2], [1, 0, 1], [2, 1, 2]])  # 0 centre, 1 nearest, 2 diagonal


def to_levels(frame: np.ndarray) -> np.ndarray:
    """(H, W) → int64 luminance 0–255 (floats on [0, 1] are scaled and rounded)."""
    if frame.dtype == np.uint8:
        return frame.astype(np.int64)
    return np.rint(np.clip(frame, 0.0, 1.0) * 255.0).astype(np.int64)


def neighbours(a: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """The 9 shifted copies of ``a`` (edge replicated): [(di, dj, a[y+di, x+dj]), ...]."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return [
        (di, dj, p[1 + di : 1 + di + h, 1 + dj : 1 + dj + w])
        for di in (-1, 0, 1)
        for dj in (-1, 0, 1)
    ]


def gaussian_blur_truncated(p: np.ndarray, truncate: bool = True) -> np.ndarray:
    """3×3 Gaussian of the integer photoreceptor output; each weighted term is truncated toward
    zero before summing, as in the released code (``truncate=False`` sums floats)."""
    out = np.zeros(p.shape)
    for di, dj, shifted in neighbours(p.astype(np.float64)):
        w = (GAUSS_CENTRE, GAUSS_EDGE, GAUSS_CORNER)[RING[di + 1, dj + 1]]
        term = w * shifted
        out += np.trunc(term) if truncate else term
    return out


def delayed_inhibition(
    now: np.ndarray,
    prev: np.ndarray,
    weights: tuple[float, float, float],
    alphas: tuple[float, float, float],
    truncate: bool = False,
) -> np.ndarray:
    """Σ over the 3×3 ring of W_k · (α_k·X(t) + (1−α_k)·X(t−1)) at each pixel."""
    out = np.zeros(now.shape)
    pairs = zip(neighbours(now), neighbours(prev), strict=True)
    for (di, dj, a_now), (_, _, a_prev) in pairs:
        k = RING[di + 1, dj + 1]
        term = weights[k] * (alphas[k] * a_now + (1.0 - alphas[k]) * a_prev)
        out += np.trunc(term) if truncate else term
    return out


def box_mean(a: np.ndarray) -> np.ndarray:
    return sum(s for _, _, s in neighbours(a)) / 9.0


def sfa_step(smp: float, smp_prev: float, sfa_prev: float, h: float, t_sfa: float) -> float:
    """Spike-frequency adaptation: a high-pass of the sigmoid membrane potential, floor 0.5."""
    d = smp - smp_prev
    return max(0.5, h * (sfa_prev + d)) if d <= t_sfa else max(0.5, h * smp)


class _ReferenceBase:
    """What both references share: the output names, the spike window, the first frame's
    layers at 0, and ``run`` as a sequence of steps."""

    outputs: ClassVar[tuple[Output, ...]] = LGMD_OUTPUTS
    default_name: ClassVar[str] = ""  # each reference's own: its registry name + "-reference"

    def __init__(self, params: Any, name: str | None = None) -> None:
        self.name = self.default_name if name is None else name
        self.params = params
        self.reset()

    def reset(self) -> None:
        self._prev: dict[str, np.ndarray] | None = None
        self._smp = 0.0
        self._sfa = 0.0
        self._spikes: deque[int] = deque([0] * self.params.n_ts, maxlen=self.params.n_ts)

    def _begin(
        self, frame: np.ndarray, layers: tuple[str, ...], dtype: type
    ) -> tuple[np.ndarray, float, dict[str, np.ndarray]]:
        """The frame as levels, the frame interval (ms) and the previous frame's layers (before
        the first frame: the same frame, every layer at 0)."""
        lum = to_levels(check_frames(np.asarray(frame)[None], min_h=1, min_w=1)[0])
        if self._prev is None:
            z = np.zeros(lum.shape, dtype=dtype)
            self._prev = {"lum": lum, **{k: z for k in layers}}
        return lum, frame_interval_ms(self.params.fps), self._prev

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        return run_by_steps(self.step, frames, LGMD_OUTPUT_NAMES, min_h=1, min_w=1)


class LgmdPlusReference(_ReferenceBase):
    """LGMD+ one frame at a time (float64 NumPy)."""

    default_name: ClassVar[str] = "lgmd-plus-reference"

    def reset(self) -> None:
        super().reset()
        self._f = 0.0

    def step(self, frame: np.ndarray) -> dict[str, float]:
        p = self.params
        lum, dt, prev = self._begin(frame, ("on", "off", "g"), np.float64)
        h, w = lum.shape
        photo = lum - prev["lum"]  # 1. photoreceptors (integer)
        blurred = gaussian_blur_truncated(photo, p.blur_truncate)  # 2.
        f_raw = float(np.abs(photo).mean())  # 3. feed-forward inhibition
        self._f = (
            lowpass_alpha(dt, p.tau_ffi_ms) * f_raw
            + (1 - lowpass_alpha(dt, p.tau_ffi_ms)) * self._f
        )
        sigma = 1.0 - self._f / p.t_ffi  # 4. FFI-tuned G latency
        if sigma < 0:
            sigma = p.delta_c
        alpha_g = lowpass_alpha(dt, p.tau_g_ms * sigma)
        beta = max(self._f / p.t_ffi, p.w_base)  # 5. adaptive inhibition bias
        on = np.where(blurred >= p.clip_point, blurred, 0.0) + p.dc * prev["on"]  # 6.
        off = np.where(blurred < p.clip_point, np.abs(blurred), 0.0) + p.dc * prev["off"]
        alphas = tuple(lowpass_alpha(dt, p.tau_e_ms * k) for k in (1, 2, 3))
        kernel = (1.0, 0.25, 0.125)
        i_on = delayed_inhibition(on, prev["on"], kernel, alphas)  # 7.
        i_off = delayed_inhibition(off, prev["off"], kernel, alphas)
        w_loc = bias_matrix(h, w, p.std_w, p.w_min)  # 8.
        s_on = np.maximum(on - w_loc * beta * i_on, 0.0)  # 9.
        s_off = np.maximum(off - w_loc * beta * i_off, 0.0)
        s = p.w_on * s_on + p.w_off * s_off + p.w_onoff * s_on * s_off
        ce = box_mean(s)  # 10. grouping
        omega = p.delta_c + np.abs(ce).max() / p.c_w
        g_tilde = s * ce / omega
        g_tilde = np.where(g_tilde * p.c_de >= p.t_de, g_tilde, 0.0)
        g = alpha_g * g_tilde + (1 - alpha_g) * prev["g"]
        mp = float(g.sum())  # 11.
        smp = 1.0 / (1.0 + math.exp(-mp / (h * w * p.c_sig)))
        h_sfa = p.tau_hp_ms / (p.tau_hp_ms + dt)  # 12.
        self._sfa = sfa_step(smp, self._smp, self._sfa, h_sfa, p.t_sfa)
        self._smp = smp
        spikes = math.floor(math.exp(p.k_sp * (self._sfa - p.t_sp)))  # 13.
        self._spikes.append(spikes)
        rate = 1000.0 * sum(self._spikes) / (p.n_ts * dt)  # 14.
        self._prev = {"lum": lum, "on": on, "off": off, "g": g}
        values = (rate, float(rate >= p.t_sr), float(spikes), mp, smp, self._sfa, self._f)
        return dict(zip(LGMD_OUTPUT_NAMES, values, strict=True))


class LgmdColiasReference(_ReferenceBase):
    """The Colias firmware "LGMD-Plus" port one frame at a time (integer layers as on the MCU)."""

    default_name: ClassVar[str] = "lgmd-colias-reference"

    def reset(self) -> None:
        super().reset()
        self._f_raw_prev = 0.0
        self._count = 0

    def step(self, frame: np.ndarray) -> dict[str, float]:
        p = self.params
        lum, dt, prev = self._begin(frame, ("on", "off"), np.int64)
        h, w = lum.shape
        photo = np.clip(np.floor_divide(lum - prev["lum"], 2), -127, 127)  # 1.
        f_raw = float(np.abs(photo).mean())  # 2.
        a2 = lowpass_alpha(dt, p.tau_pm_ms)
        f = a2 * f_raw + (1 - a2) * self._f_raw_prev
        self._f_raw_prev = f_raw
        w1 = max(f / p.t_pm, p.w_on_base)
        w2 = max(f / p.t_pm, p.w_off_base)
        on = np.where(photo >= 0, photo, 0)  # 3.
        off = np.where(photo < 0, -photo, 0)
        a_on = tuple(lowpass_alpha(dt, p.tau_on_ms * k) for k in (1, 2, 3))  # 4.
        a_off = tuple(lowpass_alpha(dt, p.tau_off_ms * k) for k in (1, 2, 3))
        i_on = np.floor(delayed_inhibition(on, prev["on"], (2.0, 0.5, 0.25), a_on, True))
        i_off = np.floor(delayed_inhibition(off, prev["off"], (1.0, 0.25, 0.125), a_off, True))
        s = np.floor(
            p.o1 * np.maximum(on - w1 * i_on, 0) + p.o2 * np.maximum(off - w2 * i_off, 0)
        )  # 5.
        s = np.minimum(s, 255)
        ce = np.floor(sum(x for _, _, x in neighbours(s)) / 9.0)  # 6.
        scale = p.delta_c + ce.max() / p.c_w
        g = np.minimum(np.floor(s * ce / scale), 255)
        g = np.where(g < p.cde_tde, 0, g)
        b = p.border
        region = g[b : h - b, b : w - b] if b > 0 else g  # 7.
        n_cells = region.size
        mp = float(region.sum())
        smp = 1.0 / (1.0 + math.exp(-mp / (n_cells * p.k_spi)))  # 8.
        h_sfa = p.tau_sfa_ms / (p.tau_sfa_ms + dt)
        self._sfa = sfa_step(smp, self._smp, self._sfa, h_sfa, p.t_sfa)
        self._smp = smp
        spikes = math.floor(math.exp(p.a4 * (self._sfa - p.t_spi)))
        alert = 0.0  # 9. consecutive-spike counter
        if spikes > 0:
            self._count += spikes
            if self._count >= p.n_alert:
                alert = 1.0
                self._count = 0
        else:
            self._count = 0
        self._spikes.append(spikes)
        rate = 1000.0 * sum(self._spikes) / (p.n_ts * dt)
        self._prev = {"lum": lum, "on": on, "off": off}
        values = (rate, alert, float(spikes), mp, smp, self._sfa, f)
        return dict(zip(LGMD_OUTPUT_NAMES, values, strict=True))

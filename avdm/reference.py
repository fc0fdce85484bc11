"""A plain, layer-by-layer NumPy AVDM: the readable version and the test oracle.

Every layer is a small function on arrays, in float64, one frame at a time. The fast path in
``avdm.avdm_model`` must agree with it (to float32 rounding: the fast path multiplies in float32).
It is slow (≈ 5–10k frames/s at 99×72) and meant for reading and testing, not for recordings.
"""

from __future__ import annotations

import math
from collections import deque
from typing import ClassVar

import numpy as np

from avdm.avdm_model import AVDM_OUTPUTS, LAYER_OUTPUT_NAMES, MIN_CONTRAST, AvdmParams
from avdm.base import Output, check_frames, run_by_steps
from avdm.errors import ParameterError


def to_intensity(frame: np.ndarray) -> np.ndarray:
    """(H, W) uint8 → float64 on [0, 1] (divided by 255); floats are taken as already on [0, 1]."""
    if frame.dtype == np.uint8:
        return frame.astype(np.float64) * (1.0 / 255.0)
    return frame.astype(np.float64)


def photoreceptor(current: np.ndarray, lagged: np.ndarray, sign: int = 1) -> np.ndarray:
    """Retina: P = sign · (I(t) − I(t − lag)), (H, W) float64."""
    return sign * (current - lagged)


def lamina(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ON = [P]+ and OFF = [−P]+ (half-wave rectification at 0)."""
    return np.maximum(p, 0.0), np.maximum(-p, 0.0)


def medulla(
    q_now: np.ndarray, q_delayed: np.ndarray, beta: float, sd: int, direction: int
) -> np.ndarray:
    """Imbalanced correlators between pixels ``sd`` apart along rows, (H, W − sd).

    E = Q_A(t−d)·Q_B(t) − β·Q_A(t)·Q_B(t−d), with A = x, B = x + sd for direction +1
    (preferred motion toward +x) and swapped for −1.
    """
    left_now, right_now = q_now[:, :-sd], q_now[:, sd:]
    left_old, right_old = q_delayed[:, :-sd], q_delayed[:, sd:]
    if direction > 0:
        return left_old * right_now - beta * left_now * right_old
    return right_old * left_now - beta * right_now * left_old


def lobula(e: np.ndarray, theta_e: float, pooling: str) -> float:
    """Spatial pooling: mean of E > θ_E with denominator 1 + count, or mean of [E]+ over all."""
    if pooling == "all_mean":
        return float(np.maximum(e, 0.0).sum() / e.size)
    active = e > theta_e
    return float(e[active].sum() / (1.0 + active.sum()))


def texture_threshold_and_contrast(intensity: np.ndarray) -> tuple[float, float]:
    """(min + max)/2 of a frame, and its Michelson contrast (max − min)/(max + min)."""
    lo, hi = float(intensity.min()), float(intensity.max())
    contrast = (hi - lo) / (hi + lo) if hi + lo > 0 else 0.0
    return (lo + hi) / 2.0, contrast


def count_transitions(row: np.ndarray, threshold: float) -> int:
    """Number of bright/dark transitions along one row binarised at ``threshold``."""
    binary = row > threshold
    return int(np.count_nonzero(binary[1:] != binary[:-1]))


def spatial_period(n_bar: float, width: int) -> float:
    """λ̂ = 2W / n̄ px, or the released code's fallback floor(2W/10) when n̄ ≤ 1."""
    return 2.0 * width / n_bar if n_bar > 1.0 else float((2 * width) // 10)


def decode(lam: float, motion: float, contrast: float, a: float, b: float, term: bool) -> float:
    """ω̂ = a · λ̂^b · (1+C)/(2C) · motion, deg/s; 0 for a uniform image (C < 1e-6)."""
    if contrast < MIN_CONTRAST:
        return 0.0
    gain = a * lam**b
    if term:
        gain *= (1.0 + contrast) / (2.0 * contrast)
    return gain * motion


class AvdmReference:
    """The AVDM one frame at a time in plain NumPy; same interface as ``avdm.Avdm``."""

    outputs: ClassVar[tuple[Output, ...]] = AVDM_OUTPUTS

    def __init__(self, params: AvdmParams, name: str = "avdm-reference") -> None:
        if params.a is None or params.b is None:
            raise ParameterError("AvdmReference needs a and b (see avdm.registry.make_params).")
        self.name = name
        self.params = params
        self.reset()

    def reset(self) -> None:
        p = self.params
        self._t = 0
        self._intensities: deque[np.ndarray] = deque(maxlen=p.photoreceptor_lag)
        self._p_history: deque[np.ndarray] = deque(maxlen=p.delay)
        self._r_on: deque[float] = deque([0.0] * p.tw, maxlen=p.tw)
        self._r_off: deque[float] = deque([0.0] * p.tw, maxlen=p.tw)
        self._transitions: deque[int] = deque([0] * p.tw, maxlen=p.tw)
        self._threshold = 0.0
        self._contrast = 0.0

    def step(self, frame: np.ndarray) -> dict[str, float]:
        p = self.params
        frame = check_frames(np.asarray(frame)[None])[0]
        h, w = frame.shape
        if p.texture_row >= h:
            raise ParameterError(f"frames have {h} rows but texture_row={p.texture_row}.")
        intensity = to_intensity(frame)
        if not self._intensities:  # history before the first frame = the first frame
            self._intensities.extend([intensity] * p.photoreceptor_lag)
            self._p_history.extend([np.zeros_like(intensity)] * p.delay)

        pr = photoreceptor(intensity, self._intensities[0], p.photoreceptor_sign)
        self._intensities.append(intensity)
        on_now, off_now = lamina(pr)
        on_old, off_old = lamina(self._p_history[0])
        self._p_history.append(pr)
        self._r_on.append(
            lobula(medulla(on_now, on_old, p.beta, p.sd, p.direction), p.theta_e, p.pooling)
        )
        self._r_off.append(
            lobula(medulla(off_now, off_old, p.beta, p.sd, p.direction), p.theta_e, p.pooling)
        )
        r_on = sum(self._r_on) / p.tw
        r_off = sum(self._r_off) / p.tw

        if self._t % p.tw == 0:
            self._threshold, self._contrast = texture_threshold_and_contrast(intensity)
        self._transitions.append(count_transitions(intensity[p.texture_row], self._threshold))
        lam = spatial_period(sum(self._transitions) / p.tw, w)

        m_on, m_off = math.sqrt(r_on), math.sqrt(r_off)
        motion = {"on": m_on, "off": m_off, "on_off_mean": 0.5 * (m_on + m_off)}[p.channel]
        omega = decode(lam, motion, self._contrast, p.a, p.b, p.contrast_term)  # type: ignore[arg-type]
        self._t += 1
        values = (omega, lam, motion, self._contrast, r_on, r_off)
        return dict(zip(LAYER_OUTPUT_NAMES, values, strict=True))

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        return run_by_steps(self.step, frames, LAYER_OUTPUT_NAMES)

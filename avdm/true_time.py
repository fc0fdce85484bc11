"""Models on real camera streams: repeated frames and uneven timestamps.

Real cameras repeat frames (pulldown, screen capture, frame-rate conversion, webcams that
deliver faster than their sensor) and drop them. A one-frame delay correlator fed a repeated
frame sees no change, so the AVDM would read half the true motion (or none, every other frame)
on a clip whose frames are each shown twice. :class:`TrueTimeModel` feeds the model only the
frames that are new, holds its outputs over the repeats, and converts the angular outputs
(unit ``deg/s``) from the model's nominal frame interval to the true time between the new frames:

    ω_true = ω_model · (1 / fps_model) / Δt_true

The decoding is calibrated at ``fps_model`` so that ω_model ≈ (displacement per frame) ·
fps_model; dividing that displacement by the true interval gives true angular velocity. A
clip doubled at twice the rate therefore gives the original's profile, and the same clip
played as slow motion (each frame twice at the original rate) half of it, never zero.
"""

from __future__ import annotations

import numpy as np

from avdm.base import Model

ANGULAR_UNIT = "deg/s"


def repeat_flags(
    frames: np.ndarray,
    previous: np.ndarray | None = None,
    run_before: int = 0,
    tol: float = 0.5,
    max_repeats: int = 3,
) -> np.ndarray:
    """Which frames repeat the one before: (T,) bool.

    A frame repeats the previous one when the mean absolute difference of their 8-bit values
    is at most ``tol`` grey levels (0.5: equal up to codec rounding and sensor noise averaged
    over the frame). Up to ``max_repeats`` repeats in a row are repeats; a longer still stretch
    is a still scene, and from then on its frames count as new (the models then see no motion,
    as they should). ``previous`` is the frame before ``frames[0]`` and ``run_before`` the number
    of repeats that ended there, so a stream can be processed in batches.

    frames: (T, H, W) uint8.
    """
    t = len(frames)
    if t == 0:
        return np.zeros(0, dtype=bool)
    f = frames.astype(np.int16)
    mad = np.empty(t)
    mad[0] = np.inf if previous is None else np.abs(f[0] - previous.astype(np.int16)).mean()
    if t > 1:
        mad[1:] = np.abs(np.diff(f, axis=0)).mean(axis=(1, 2))
    return repeats_of(mad, run_before, tol, max_repeats)


def repeats_of(
    mad: np.ndarray, run_before: int = 0, tol: float = 0.5, max_repeats: int = 3
) -> np.ndarray:
    """:func:`repeat_flags` from each frame's mean absolute difference from the one before
    (``mad`` (T,), 8-bit levels; inf or NaN where there is no previous frame): a source with
    native frames measures it there, where real slow motion is not averaged away."""
    t = len(mad)
    flags = np.zeros(t, dtype=bool)
    run = run_before
    for i in range(t):
        if mad[i] <= tol and run < max_repeats:
            flags[i] = True
            run += 1
        else:
            run = 0
    return flags


def new_frame_rate(fps: float, repeat: np.ndarray, max_repeats: int = 3) -> float:
    """The rate of new frames in a stream at ``fps`` Hz whose frames ``repeat`` (T,) bool
    flags (its first batch): the rate the models are built for, whatever the container says.

    A clip whose every frame is shown k times at k times the rate (k = 2, 3, ...; also 2.5,
    3:2 pulldown) brings a new frame every k container frames: its models run at fps / k,
    and so see what they see on the original (docs/video.md: repeated frames). The rate stays
    ``fps`` for sporadic repeats (a camera that now and then delivers a frame twice:
    :class:`TrueTimeModel` then scales the angular outputs by the true time between new
    frames), for a mix that is no regular pattern, and where the runs reach ``max_repeats``
    (a still scene, whose frames :func:`repeat_flags` calls new after that many)."""
    n = len(repeat)
    new = n - int(np.count_nonzero(repeat))
    if n < 4 or new == 0:
        return float(fps)
    ratio = n / new
    k = round(ratio * 2) / 2  # whole and half repeats per new frame (3:2 pulldown: 2.5)
    if k < 1.5 or abs(ratio - k) > 0.1 or k - 1 >= max_repeats:
        return float(fps)
    return float(fps) / k


class TrueTimeModel:
    """A model that sees only new frames and reports angular outputs in true deg/s.

    ``run(frames, t_s, repeat)`` processes a batch (frames (T, H, W), times (T,) in seconds,
    repeat flags (T,) bool) and continues from the state of earlier batches; outputs for
    repeated frames hold the last new frame's values. Without repeats and with evenly spaced
    times at the model's own ``fps`` the outputs equal ``model.run(frames)`` exactly.
    """

    def __init__(self, model: Model) -> None:
        self.model = model
        self.name = model.name
        self.outputs = model.outputs
        self.params = model.params
        self.fps = float(getattr(model.params, "fps", 0.0) or 0.0)
        self._angular = [o.name for o in model.outputs if o.unit == ANGULAR_UNIT]
        self._last: dict[str, float] | None = None
        self._last_t: float | None = None

    def reset(self) -> None:
        self.model.reset()
        self._last, self._last_t = None, None

    def run(self, frames: np.ndarray, t_s: np.ndarray, repeat: np.ndarray) -> dict[str, np.ndarray]:
        t_s = np.asarray(t_s, dtype=np.float64)
        repeat = np.asarray(repeat, dtype=bool)
        new = np.flatnonzero(~repeat)
        out = {o.name: np.zeros(len(frames), dtype=np.float64) for o in self.outputs}
        res = self.model.run(frames[new]) if len(new) else {k: np.zeros(0) for k in out}
        if len(new) and self.fps > 0:
            # true time since the previous new frame (the first frame ever: nominal interval)
            prev_t = np.concatenate(([np.nan if self._last_t is None else self._last_t], t_s[new]))
            dt = np.diff(prev_t)
            nominal = 1.0 / self.fps
            dt = np.where(np.isfinite(dt) & (dt > 0), dt, nominal)
            scale = nominal / dt
            for k in self._angular:
                res[k] = res[k] * scale
        # hold: each frame takes the outputs of the latest new frame at or before it
        idx = np.searchsorted(new, np.arange(len(frames)), side="right") - 1
        for k in out:
            vals = res[k]
            held = vals[np.clip(idx, 0, None)] if len(vals) else np.zeros(len(frames))
            if self._last is not None:
                held = np.where(idx < 0, self._last[k], held)
            else:
                held = np.where(idx < 0, 0.0, held)
            out[k] = held
        if len(frames):
            self._last = {k: float(v[-1]) for k, v in out.items()}
        if len(new):
            self._last_t = float(t_s[new[-1]])
        return out

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

import dataclasses

import numpy as np

from avdm.base import Model
from avdm.errors import PluginError

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


# a cadence holds where at least this share of the gaps between new frames keep it, over the
# stream and in each of its quarters (a still moment or a lost frame breaks it locally); gaps
# fewer than MIN_GAPS are too few to tell a cadence from chance (3:2 pulldown repeats every 5
# frames: 16 gaps are 40 container frames, 8 of its cycles)
CADENCE_SHARE, QUARTER_SHARE, MIN_GAPS = 0.9, 0.75, 16
# below this share for every cadence the repeats come and go (motion, a codec's skips): no note
AMBIGUOUS_SHARE = 0.5


@dataclasses.dataclass(frozen=True)
class ModelRate:
    """The rate the models of a stream are built at, and why.

    ``fps``: the rate (Hz); ``repeats_per_frame``: container frames per new frame (1 at the
    container's rate; 2, 3, ... or 2.5 for 3:2 pulldown); ``reason``: a short phrase, the
    ``model_fps_reason`` column (:data:`RATE_REASONS`); ``note``: the one line a command says
    about it, None where the container's rate stands without doubt."""

    fps: float
    repeats_per_frame: float
    reason: str
    note: str | None = None


RATE_REASONS = (
    "no repeats",  # the container's rate
    "repeats without a cadence",  # the container's rate: true time scales the outputs
    "ambiguous cadence",  # the container's rate, with a note
    "too few frames to judge",  # the container's rate, with a note where there are repeats
    "regular cadence",  # fps / k: every frame shown k times (k = 2, 3, ...; 2.5: 3:2 pulldown)
    "camera frames",  # a camera (live, simulated, a robot's): its own rate, nothing judged
)


def _cadence_share(gaps: np.ndarray, k: float) -> np.ndarray:
    """Which gaps between new frames (container frames, (G,) int) keep a cadence of ``k``
    container frames per new frame: all equal to k, or for k = m + 0.5 alternating m and
    m + 1 (each gap checked against its neighbours)."""
    if k == int(k):
        return gaps == int(k)
    lo, hi = int(k), int(k) + 1
    ok = np.zeros(len(gaps), dtype=bool)
    pair = ((gaps[:-1] == lo) & (gaps[1:] == hi)) | ((gaps[:-1] == hi) & (gaps[1:] == lo))
    ok[:-1] |= pair
    ok[1:] |= pair
    return ok


def _best_cadence(gaps: np.ndarray, max_repeats: int) -> tuple[float, np.ndarray]:
    """The cadence (container frames per new frame) most gaps keep, and which keep it."""
    # runs of max_repeats repeats are a still scene's (repeat_flags): k - 1 < max_repeats
    ks = [k / 2 for k in range(3, 2 * max_repeats + 2)]
    best = max(ks, key=lambda k: (_cadence_share(gaps, k).mean(), -k))
    return best, _cadence_share(gaps, best)


def model_rate(
    fps: float, repeat: np.ndarray, max_repeats: int = 3, decided_on: int | None = None
) -> ModelRate:
    """The rate the models of a stream at ``fps`` Hz are built at, on the evidence of the
    whole stream's repeat flags ``repeat`` (T,) bool (:func:`repeat_flags`).

    A clip whose every frame is shown k times at k times the rate (k = 2, 3, ...; 2.5 for 3:2
    pulldown) brings a new frame every k container frames, in a regular cadence from start to
    end: its models run at fps / k and so see what they see on the original (docs/guides/video.md).
    The gaps between new frames must keep that cadence (:data:`CADENCE_SHARE` of them over
    the stream and :data:`QUARTER_SHARE` in each quarter): repeats that come and go with the
    motion (a slow or stopping scene through a lossy codec, whose encoder had nothing to code)
    never do, and leave the container's rate, with true time doing the rest
    (:class:`TrueTimeModel`). Where a cadence holds over part of the stream only, or the
    stream is too short to tell, the container's rate stands and the result's ``note`` says
    so. ``decided_on``: the frames the decision was taken on where a stream is too long to
    hold (the rest only checks it: a note where it breaks there); None: all of them."""
    fps = float(fps)
    repeat = np.asarray(repeat, dtype=bool)
    head = repeat if decided_on is None else repeat[:decided_on]
    container = f"the models run at the container's {fps:.6g} fps"
    if not head.any():
        return ModelRate(fps, 1.0, "no repeats")
    gaps = np.diff(np.flatnonzero(~head))
    n_rep = int(head.sum())
    if len(gaps) < MIN_GAPS:
        note = (
            f"{n_rep} repeated frame(s) in {len(head)} are too few new frames to tell a "
            f"cadence of repeats from chance: {container}"
        )
        return ModelRate(fps, 1.0, "too few frames to judge", note)
    k, keeps = _best_cadence(gaps, max_repeats)
    share = float(keeps.mean())
    quarters = [float(q.mean()) for q in np.array_split(keeps, 4)]
    what = (
        f"every frame shown {k:g} times"
        if k == int(k)
        else f"frames shown {int(k)} and {int(k) + 1} times in turn"
        + (" (3:2 pulldown)" if k == 2.5 else "")
    )
    if share >= CADENCE_SHARE and min(quarters) >= QUARTER_SHARE:
        rate = ModelRate(
            fps / k,
            k,
            "regular cadence",
            f"the models run at {fps / k:.6g} fps, the rate of new frames, not the container's "
            f"{fps:.6g}: {what} across the stream ({share:.0%} of {len(gaps)} gaps keep it)",
        )
        if decided_on is not None and decided_on < len(repeat):
            rest = np.diff(np.flatnonzero(~repeat[decided_on:]))
            if len(rest) >= MIN_GAPS and _cadence_share(rest, k).mean() < QUARTER_SHARE:
                rate = dataclasses.replace(
                    rate,
                    note=f"{rate.note}; decided on the first {decided_on} frames, and the "
                    "cadence breaks after them",
                )
        return rate
    if share >= AMBIGUOUS_SHARE:
        note = (
            f"repeats keep a cadence of {what} in {share:.0%} of the clip but not across it "
            f"(each quarter: {', '.join(f'{q:.0%}' for q in quarters)}): ambiguous, so {container}"
        )
        return ModelRate(fps, 1.0, "ambiguous cadence", note)
    return ModelRate(fps, 1.0, "repeats without a cadence")


def new_frame_rate(fps: float, repeat: np.ndarray, max_repeats: int = 3) -> float:
    """The models' rate for a stream at ``fps`` Hz whose frames ``repeat`` (T,) bool flags:
    :func:`model_rate`'s ``fps``."""
    return model_rate(fps, repeat, max_repeats).fps


class TrueTimeModel:
    """A model that sees only new frames and reports angular outputs in true deg/s.

    ``run(frames, t_s, repeat)`` processes a batch (frames (T, H, W), times (T,) in seconds,
    repeat flags (T,) bool) and continues from the state of earlier batches; outputs for
    repeated frames hold the last new frame's values. Without repeats and with evenly spaced
    times at the model's own ``fps`` the outputs equal ``model.run(frames)`` exactly.

    ``cadence`` True: the new frames are a regular cadence's (:func:`model_rate`: every frame
    shown k times, 3:2 pulldown), whose originals were evenly spaced at the model's rate; the
    true time between them is taken in whole model intervals (3:2 pulldown shows them 2 and 3
    container frames apart, 0.8 and 1.2 intervals, which would read the original's motion
    alternately 25 % fast and 17 % slow), and a lost frame still counts as an interval.
    """

    def __init__(self, model: Model, cadence: bool = False) -> None:
        self.model = model
        self.cadence = cadence
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
        try:
            res = self.model.run(frames[new]) if len(new) else {k: np.zeros(0) for k in out}
        except PluginError as exc:  # its place among the new frames -> among these frames
            if exc.offset is not None:
                exc.offset = int(new[exc.offset])
            raise
        if len(new) and self.fps > 0:
            # true time since the previous new frame (the first frame ever: nominal interval)
            prev_t = np.concatenate(([np.nan if self._last_t is None else self._last_t], t_s[new]))
            dt = np.diff(prev_t)
            nominal = 1.0 / self.fps
            dt = np.where(np.isfinite(dt) & (dt > 0), dt, nominal)
            if self.cadence:
                dt = np.maximum(np.rint(dt / nominal), 1.0) * nominal
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

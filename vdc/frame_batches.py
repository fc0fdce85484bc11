"""A source's frames in batches, as every reader of footage takes them (``vdc-capture
video``, ``vdc-analyse complexity``): resized to the models' raster, measured on their native
luma, with repeats and dropped frames flagged (:class:`FrameBatcher`), and the working camera a
clip is profiled with (:func:`working_camera`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from avdm.true_time import ModelRate, model_rate, repeats_of
from vdc.errors import UserError
from vdc.frame_metrics import NativeMeter, decide_ranges, full_range_p910
from vdc.pipeline import ordered_map, pipelined
from vdc.recording import NATIVE_METRICS, camera_model_context, working_size
from vdc.resize import area_resize

# images and camera frames: 8-bit grey, full range
from vdc.sources import Reader, SourceFrame
from vdc.stream_counts import end_fields

# a frame given a neighbour's time leaves its own time slot empty this close (frames)
DISPLACED_WITHIN = 4


@dataclasses.dataclass
class FrameBatch:
    """Consecutive frames of a source, ready for the models and the metrics.

    frame (N,) int64 indices; t_s (N,) float64 seconds since the first frame, in whole
    nanoseconds (as a recording stores them); images (N, h, w) uint8 grey on the working
    raster; native_metrics (N, len(NATIVE_METRICS)) float64 on the native frames; repeat
    (N,) bool (judged on the native frames); dropped_before (N,) int64 frames the timestamps
    say are missing just before each (before a source's first frame: those between the
    stream's start and it, ``Reader.lost_before_first``); dt_s (N,) seconds since the
    previous frame (NaN for the first); notes: what was lost inside the source just before
    each frame, or None."""

    frame: np.ndarray
    t_s: np.ndarray
    images: np.ndarray
    native_metrics: np.ndarray
    repeat: np.ndarray
    dropped_before: np.ndarray
    dt_s: np.ndarray
    notes: list[str | None]


class FrameBatcher:
    """A source's frames in batches of ``batch_frames``: resized by area to ``size`` (H, W)
    for the models (``vdc.resize.area_resize``), measured on their native luma
    (``vdc.frame_metrics.NativeMeter``), with repeats (a native mean |difference| from the
    previous frame of at most ``repeat_tol`` 8-bit levels, at most ``max_repeats`` in a row)
    and dropped frames (a gap of more than 1.5 nominal intervals at ``fps``, in a stream whose
    own times keep a constant rate; before the first frame, the frames between the stream's
    start and it; and those the reader knows it lost that no gap shows: a second frame at
    one time, or in a variable-rate stream its packets that gave no frame).
    ``vdc-capture video`` and ``vdc-analyse complexity`` both read sources through it, so
    both see the same frames, times, flags and counts: ``dropped_total`` counts the frames
    lost before and between the frames read, :meth:`end_fields` those lost after the last
    one too.

    ``metrics``: the native metrics to compute (default all; the MAFD always, for the
    repeats); ``size`` None: no working raster (``images`` then (N, 0, 0)). ``threads`` > 1:
    decoding, the native metrics and the resize run as a pipeline of threads
    (``vdc.pipeline``), with the same results bit for bit; call :meth:`close` (or read to the
    end) to stop them. ``measure_on_threads`` (the default) measures several frames at once
    (:meth:`_on_threads`: one thread decodes, with FFmpeg's own decoder threads as the
    reader set them, so a damaged stream yields the same frames); False: one thread per
    stage (decode, measure, resize).

    ``color_range`` (``auto``, ``limited``, ``full``) decides the range of the SI/TI variants
    (``vdc.frame_metrics.decide_ranges``). In an untagged stream the P.910 variant is limited
    until a frame's luma leaves that range: a batch's own earlier frames are then corrected
    before it is returned, and :meth:`p910_late_corrections` gives those of earlier batches.
    ``reopen`` (a file or an image sequence: a function that opens the source again) spares
    the second SI/TI pass a detecting meter otherwise makes on every frame for these
    corrections: only when a frame leaves the limited range, the frames before it are read
    again and measured in full range (the same bits; a clip that stays inside costs nothing)."""

    def __init__(
        self,
        reader: Reader,
        size: tuple[int, int] | None,
        fps: float,
        *,
        batch_frames: int = 128,
        repeat_tol: float = 0.5,
        max_repeats: int = 3,
        metrics: tuple[str, ...] | None = None,
        threads: int = 1,
        measure_on_threads: bool = True,
        jpeg_quality: int = 75,
        color_range: str = "auto",
        reopen: Callable[[], Reader] | None = None,
    ) -> None:
        self.reader, self.size, self.fps = reader, size, float(fps)
        self.batch_frames, self.repeat_tol, self.max_repeats = batch_frames, repeat_tol, max_repeats
        self._tag = reader.info.get("color_range_tag", reader.info["color_range"])
        self.requested_range = color_range
        ranges = decide_ranges(self._tag, color_range)
        native = NATIVE_METRICS if metrics is None else (*metrics, "mafd")
        self.meter = NativeMeter(
            reader.info["bit_depth"],
            ranges["color_range_legacy"],
            jpeg_quality,
            tuple(native),
            p910_range=ranges["color_range_p910"] or "detect",
            full_alternative=reopen is None,
        )
        self._reopen = reopen
        self.meter.copy_previous = not reader.planes_persist
        reader.grey = size is not None  # no working raster: no grey conversion (0.3 ms at 720p)
        if threads > 1 and measure_on_threads:
            self._it: Iterator[tuple] = self._on_threads(threads)
        elif threads > 1:  # the default: decoding, measuring and resize as one thread each
            if size is None:  # no resize: the metrics are the only stage after decoding
                stages = [lambda fr: self._resize(self._measure(fr))]
            else:
                stages = [self._measure, self._resize]
            self._it = pipelined(reader.frames(), stages)
        else:
            self._it = (self._resize(self._measure(fr)) for fr in reader.frames())
        self._index = 0
        self._run = 0
        self._prev_t: float | None = None
        self.dropped_total = 0
        self._pending = self._pending_age = 0  # frames dropped for their time, not yet placed
        self.repeats_total = 0
        self.last_t_s: float | None = None
        self.ended = False

    def _on_threads(self, threads: int) -> Iterator[tuple]:
        """What the plain loop yields, with decoding in a thread of its own and each frame's
        measuring and resize on ``threads`` threads at once (``vdc.pipeline.ordered_map``: a
        frame's metrics depend only on it and the frame before it), then finished in frame
        order (``NativeMeter.finish``: the range decision): the same bits as the plain loop,
        with one clip spread over every core."""
        persist = self.reader.planes_persist

        def paired() -> Iterator[tuple]:
            prev = None
            for fr in self.reader.frames():
                # a reader whose buffers are reused: the plane kept for the next frame's TI
                y = fr.native if persist else fr.native.copy()
                yield fr, y, prev
                prev = y

        def work(item: tuple) -> tuple:
            fr, y, prev = item
            m = self.meter.measure(y, prev, fr.packet_bytes)
            small = None if self.size is None else area_resize(fr.luma, self.size)
            return fr, m, small

        measured = ordered_map(work, pipelined(paired(), []), threads)
        try:
            for fr, m, small in measured:
                got = self.meter.finish(m)
                row = np.array([got[k] for k in NATIVE_METRICS])
                yield small, fr.t_s, fr.note, row, fr.lost_before
        finally:
            measured.close()

    def _measure(self, fr: SourceFrame) -> tuple[SourceFrame, np.ndarray]:
        """A frame's native metrics (one frame after another: the meter keeps the previous)."""
        return fr, self.meter.row(fr.native, fr.packet_bytes)

    def _resize(self, item: tuple[SourceFrame, np.ndarray]) -> tuple:
        """(working-raster image or None, t_s, note, native metrics, frames lost before it
        that no gap shows): the large planes let go."""
        fr, row = item
        if self.size is None:
            return None, fr.t_s, fr.note, row, fr.lost_before

        return area_resize(fr.luma, self.size), fr.t_s, fr.note, row, fr.lost_before

    def close(self) -> None:
        """Stop the pipeline's threads (the reader is the caller's to close)."""
        close = getattr(self._it, "close", None)
        if close is not None:
            close()

    def next_batch(self) -> FrameBatch | None:
        images, times, notes, native, known = [], [], [], [], []
        for small, t, note, row, lost in self._it:
            images.append(small)
            known.append(lost)
            times.append(t)
            notes.append(note)
            native.append(row)
            if len(images) >= self.batch_frames:
                break
        else:
            self.ended = True
        if not images:
            return None
        metrics = np.stack(native)
        self._correct_p910(metrics, self._index)
        t_s = np.rint(np.asarray(times, dtype=np.float64) * 1e9) / 1e9
        mafd = metrics[:, NATIVE_METRICS.index("mafd")]
        repeat = repeats_of(mafd, self._run, self.repeat_tol, self.max_repeats)
        for r in repeat:  # the run of repeats that ends this batch carries into the next
            self._run = self._run + 1 if r else 0
        dt = np.diff(np.concatenate(([np.nan if self._prev_t is None else self._prev_t], t_s)))
        with np.errstate(invalid="ignore"):
            missing = np.where(np.isfinite(dt), np.rint(dt * self.fps) - 1, 0)
            # a gap of more than half a frame interval beyond the nominal one: dropped frames
            dropped = np.where(dt * self.fps > 1.5, np.maximum(missing, 1), 0).astype(np.int64)
        if self._prev_t is None:  # the source's first frame: those lost before it
            dropped[0] = self.reader.lost_before_first
        # what the source itself knows it lost (vdc.sources.SourceFrame.lost_before): in a
        # variable-rate stream all there is (its gaps say nothing: no assumed rate); else a
        # frame whose time did not advance, which leaves a gap beside it where it displaced
        # its neighbour's time (counted once) and none where it was one frame too many
        lost = np.asarray(known, dtype=np.int64)
        if self.reader.info.get("variable_rate"):
            dropped = lost + np.where(np.arange(len(lost)) == 0, dropped, 0)
        else:
            dropped = self._reconcile(dropped, lost)
        frame = np.arange(self._index, self._index + len(images), dtype=np.int64)
        self._index += len(images)
        self._prev_t = self.last_t_s = float(t_s[-1])
        self.dropped_total += int(dropped.sum())
        self.repeats_total += int(repeat.sum())
        stacked = (
            np.stack(images) if self.size is not None else np.zeros((len(images), 0, 0), np.uint8)
        )
        return FrameBatch(frame, t_s, stacked, metrics, repeat, dropped, dt, notes)

    def _reconcile(self, gaps: np.ndarray, lost: np.ndarray) -> np.ndarray:
        """(N,) int64 dropped frames of a constant-rate stream from its ``gaps`` (empty time
        slots before each frame) and the frames the reader dropped because their time did not
        advance (``lost``, on the frame delivered next). A frame given a neighbour's time
        leaves its own slot empty within a few frames (the reorder buffer's depth): that gap
        counts it, once; one that leaves none within :data:`DISPLACED_WITHIN` frames was one
        frame too many, and is counted where that is known (and at the stream's end)."""
        out = gaps.copy()
        for i in range(len(out)):
            self._pending += int(lost[i])
            if gaps[i] > 0:
                self._pending -= min(int(gaps[i]), self._pending)
            if self._pending:
                self._pending_age += 1
                if self._pending_age > DISPLACED_WITHIN:
                    out[i] += self._pending
                    self._pending = 0
            if not self._pending:
                self._pending_age = 0
        if self.ended and self._pending and len(out):
            out[-1] += self._pending
            self._pending = 0
        return out

    def end_fields(self, ended: bool | None = None) -> dict[str, Any]:
        """The clip's counts once read (``vdc.stream_counts.end_fields``): ``dropped_frames``
        (before, between and, where the source states its count, after the frames read),
        ``container_frames``, ``lost_after_last``, ``header_duration_s``, ``missing_s`` and
        ``cut_note``. ``ended`` (default: read to the source's end) False: a source read in
        part (a capture stopped by a signal), nothing counted after its last frame."""

        done = self.ended if ended is None else ended
        return end_fields(
            self.reader.info, self.last_t_s, self.fps, self._index, self.dropped_total, done
        )

    def _correct_p910(self, metrics: np.ndarray, first: int) -> None:
        """Full-range P.910 values for this batch's frames that were measured in limited
        range before a later frame of the batch left it (in place)."""

        fix = self.p910_late_corrections()
        k = np.arange(first, min(len(fix), first + len(metrics)))
        if len(k):
            metrics[k - first, NATIVE_METRICS.index("si_p910")] = fix[k, 0]
            metrics[k - first, NATIVE_METRICS.index("ti_p910")] = fix[k, 1]

    def p910_late_corrections(self) -> np.ndarray:
        """(K, 2) float64 ``si_p910``, ``ti_p910`` in full range for frames 0..K-1 returned in
        earlier batches in limited range (an untagged stream whose luma left the limited
        range only after them); K = 0 when none need it."""
        if self._reopen is not None and self.meter.lacks_full_alternative:
            again = self._reopen()
            try:
                again.grey = False  # the native planes only
                natives = (fr.native for fr in again.frames())
                self.meter.set_full_alternative(
                    full_range_p910(natives, self.meter.bit_depth, self.meter.left_limited_at)
                )
            finally:
                again.close()
        return self.meter.p910_corrections()

    def color_ranges(self) -> dict[str, str | None]:
        """The range each SI/TI variant read and how it was decided
        (``vdc.frame_metrics.decide_ranges``), once the frames so far are seen."""

        return decide_ranges(self._tag, self.requested_range, self.meter.left_limited_range)


def working_camera(
    info: dict[str, Any], source: str, fov_deg: float, width: int | None
) -> tuple[tuple[int, int], float, dict[str, Any]]:
    """The clip's working raster (H, W), frame rate and model context, as ``vdc-capture
    video`` derives them from the source's own facts."""

    fps = float(info["nominal_fps"])
    if not (math.isfinite(fps) and fps > 0):
        raise UserError(f"{source!r} states no frame rate.")
    h, w = working_size(info["src_height_px"], info["src_width_px"], fov_deg, width)
    return (h, w), fps, camera_model_context(w, h, fps, fov_deg)


# the working-raster frames held while the models' rate is decided on the stream's evidence:
# 64 MB is 16 000 frames of the default 85 x 48 raster (9 min at 30 fps); a longer stream is
# decided on what that holds and only checked after it
LOOKAHEAD_BYTES = 64 * 2**20
LOOKAHEAD_FRAMES = 20_000


class RateLookahead:
    """A :class:`FrameBatcher`'s batches, the first of them read ahead and held until the
    rate the models are built at is decided on the stream's evidence
    (``avdm.true_time.model_rate``): the whole stream where its working-raster frames fit in
    ``limit_bytes`` (and ``limit_frames``), else as many as do, with the rest only checking
    the decision (:meth:`final_rate`). A live camera (``live``) runs at its own rate: its
    frames are stamped on arrival and nothing is read ahead. ``next_batch`` hands out the held
    batches, then the rest, as the batcher would; ``progress`` hears of each batch as it is
    decoded (most of a clip's time is spent there while it is read ahead)."""

    def __init__(
        self,
        batcher: FrameBatcher,
        max_repeats: int,
        live: bool = False,
        limit_bytes: int = LOOKAHEAD_BYTES,
        limit_frames: int = LOOKAHEAD_FRAMES,
        progress: Callable[[int], Any] | None = None,
    ) -> None:
        self.batcher, self.max_repeats, self.progress = batcher, max_repeats, progress
        self._held: list[FrameBatch] = []
        self._flags: list[np.ndarray] = []
        held_bytes = held_frames = 0
        while not live and held_bytes < limit_bytes and held_frames < limit_frames:
            fb = batcher.next_batch()
            if fb is None:
                break
            self._held.append(fb)
            self._flags.append(fb.repeat)
            if progress is not None:
                progress(len(fb.frame))
            held_bytes += fb.images.nbytes + fb.native_metrics.nbytes
            held_frames += len(fb.frame)
        # None: the decision saw the whole stream
        self.decided_on: int | None = None if batcher.ended else held_frames
        fps = batcher.fps
        self.rate = (
            ModelRate(fps, 1.0, "camera frames")
            if live
            else model_rate(fps, self.flags(), max_repeats, self.decided_on)
        )

    def flags(self) -> np.ndarray:
        """(T,) bool: the repeat flags of the frames read so far."""
        return np.concatenate(self._flags) if self._flags else np.zeros(0, dtype=bool)

    def next_batch(self) -> FrameBatch | None:
        if self._held:
            return self._held.pop(0)
        fb = self.batcher.next_batch()
        if fb is not None:
            self._flags.append(fb.repeat)
            if self.progress is not None:
                self.progress(len(fb.frame))
        return fb

    def final_rate(self) -> Any:
        """The decision (``avdm.true_time.ModelRate``) once the stream is read: the same rate,
        with a note where the stream was longer than the frames it was decided on and its
        cadence breaks after them."""
        if self.decided_on is None or self.rate.reason == "camera frames":
            return self.rate
        later = model_rate(self.batcher.fps, self.flags(), self.max_repeats, self.decided_on)
        return later if later.fps == self.rate.fps else self.rate

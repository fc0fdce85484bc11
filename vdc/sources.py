"""Reading any video file, image sequence or camera, frame by frame, with true times.

Files are decoded with PyAV (FFmpeg) packet by packet for their true presentation timestamps;
image sequences (``frames/%05d.png``) are timed by their number and a frame rate; cameras (an
index such as ``0``) are read with OpenCV and stamped with the host's clock. Each frame comes
with its grey image as displayed (the models' input) and its native luma as coded (the
standard metrics' input, ``vdc.frame_metrics``). Lost frames (bad packets, missing or
unreadable images) are counted and named, never a silent end. Both ``vdc-capture video`` and
``vdc-analyse complexity`` read sources here, so both see the same frames.

Each frame a source should hold is measured or counted lost, once: frames lost in the middle
are gaps in the times (``vdc.frame_batches.FrameBatcher``); those lost before the first frame
that decodes are the gap from the stream's start time to it (:attr:`Reader.lost_before_first`);
those lost after the last are the frames the container states it holds less those measured and
counted (``vdc.stream_counts``; unknown, None, where the container states no count).
"""

from __future__ import annotations

import collections
import heapq
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vdc.errors import UserError
from vdc.frame_metrics import luma_plane, require_frame_size, stream_format
from vdc.image_sources import CameraReader, ImageSequenceReader
from vdc.matroska_index import declared_start_s
from vdc.source_frame import Reader, SourceFrame
from vdc.source_names import source_kind
from vdc.stream_counts import frames_missing_in

# frames held back to reorder a codec's output when it does not state its delay
REORDER_DEPTH_UNKNOWN = 16
VIDEO_SUFFIXES = (
    ".mp4",
    ".mov",
    ".m4v",
    ".mkv",
    ".avi",
    ".webm",
    ".mpg",
    ".mpeg",
    ".ts",
    ".mts",
    ".y4m",
    ".wmv",
    ".flv",
    ".3gp",
    ".ogv",
)


def open_video(path: str, decoder_threads: int | None = None) -> tuple[Any, Any]:
    """The video file ``path`` opened with PyAV: its container (close it) and first video
    stream, set to decode with FFmpeg's frame threads except in a pool worker (one core each:
    vdc.executors; one thread set, as libdav1d, the AV1 decoder, ignores the thread type). A
    missing, empty or unreadable file, or one with no video stream, raises UserError naming
    it. A decoded frame's plane views the frame's reference-counted buffer, which FFmpeg's
    pools hand out again only when no frame references it: a reader sets ``planes_persist``.
    ``decoder_threads`` 1: FFmpeg decodes on the calling thread alone, as in a pool worker
    (its frame threads cost 20-30 % more CPU per frame, measured on 720p H.264; but the
    thread count changes which frames a damaged stream yields, so vdc's commands all read
    files with the same setting). With PyAV's Python log callback on, every file decodes on
    one thread (see below), and a damaged stream may yield other frames than with it off."""
    import av  # lazy: start-up

    p = Path(path)
    if not p.exists():
        raise UserError(f"video {path!r}: no such file.")
    if p.stat().st_size == 0:
        raise UserError(f"video {path!r} is empty.")
    try:
        container = av.open(path)
    except av.FFmpegError as exc:
        raise UserError(f"cannot read {path!r} as a video: {_ffmpeg_reason(exc)}") from None
    if not container.streams.video:
        container.close()
        raise UserError(f"{path!r} holds no video stream.")
    stream = container.streams.video[0]
    # PyAV's Python log callback (the user's av.logging.set_level with a level) makes FFmpeg's
    # frame threads wait for the GIL to log, while a container being freed holds it and waits
    # for them: a deadlock. With it on, FFmpeg decodes on the calling thread alone.
    python_logging = av.logging.get_level() is not None
    single = os.environ.get("VDC_WORKER_THREADS") == "1" or decoder_threads == 1 or python_logging
    stream.thread_type, stream.codec_context.thread_count = ("NONE", 1) if single else ("AUTO", 0)
    return container, stream


class _PyAvReader(Reader):
    planes_persist = True  # PyAV's planes: see open_video

    def __init__(self, path: str, decoder_threads: int | None = None) -> None:
        self.container, self.stream = open_video(path, decoder_threads)
        rate = self.stream.average_rate or self.stream.guessed_rate or self.stream.base_rate
        tb = self.stream.time_base
        start = self.stream.start_time
        # the stream's first presentation time (s): a file need not start at 0 (an edit, an
        # MP4 edit list's B-frame delay, an MPEG-TS clock); a frame that decodes later than
        # it follows lost frames
        self._start_s = float(start * tb) if start is not None and tb else None
        if "matroska" in self.container.format.name:  # FFmpeg's is the first frame it read
            declared = declared_start_s(path)  # the file's own index: damage cannot move it
            if declared is not None and (self._start_s is None or declared < self._start_s):
                self._start_s = declared
        self.info = {
            "kind": "file",
            "codec": self.stream.codec_context.name,
            "nominal_fps": float(rate) if rate else float("nan"),
            "src_width_px": self.stream.codec_context.width,
            "src_height_px": self.stream.codec_context.height,
            "n_frames_header": int(self.stream.frames or 0),
            "rotation_deg": 0,
            # the duration the container's header states, from the stream's start (s); a file
            # cut short ends before it
            "duration_s": self._header_duration_s(),
            "first_frame_s": 0.0,
        }
        self.info["variable_rate"] = self._variable_rate(path)
        self.info["container_frames"] = self._container_frames()
        self._unseen: collections.Counter = collections.Counter()  # pts demuxed, not shown
        self._sizes: dict[int, int] = {}  # packet size by pts: frames leave the decoder reordered
        self._frames = self._decode()
        try:
            first = next(self._frames, None)  # a file with no decodable frame fails here
        except UserError as exc:  # a pixel format vdc does not read (stream_format)
            self.container.close()
            raise UserError(f"{path!r}: {exc}") from None
        if first is None:
            self.container.close()
            why = f": {self.error}" if self.error else ""
            raise UserError(f"{path!r} holds no decodable video frame{why}.")
        self._first = first
        self.info["src_height_px"], self.info["src_width_px"] = first.luma.shape[:2]

    def _header_duration_s(self) -> float:
        """The stream's duration as the container's header states it, from the stream's
        start (s; 0.0 where it states none). FFmpeg reads a Matroska (WebM) Segment's Duration
        as it stands, which is its end on a timeline that starts at 0 (a file whose first frame
        is at 0.48 s states 2.48 s for 2 s of frames): the start is taken off there."""
        stated = (self.container.duration or 0) / 1e6
        if "matroska" in self.container.format.name and self._start_s and stated > self._start_s:
            stated -= self._start_s
        return stated

    def _container_frames(self) -> int | None:
        """The frames the container states the stream holds: its count (MP4, MOV, AVI: the
        sample table; less the packets an edit list discards, counted while demuxing), else
        its header's duration times a constant rate (Matroska and WebM state a duration, not
        a count: constant when FFmpeg's average rate equals the stream's base rate; or the
        frames a whole demux of it found, where they are more: times that go backwards), else
        None: unknown (a variable rate; MPEG-TS and raw streams, which state neither and
        whose duration FFmpeg can only estimate)."""
        if self.stream.frames:
            return int(self.stream.frames)
        avg, base = self.stream.average_rate, self.stream.base_rate
        duration_s = self.info["duration_s"]
        if "matroska" not in self.container.format.name or not (avg and base and duration_s > 0):
            return None
        # the frames in the file where it was demuxed whole: more than its duration holds
        # where its timestamps go backwards (its duration is its latest time, not its length)
        packets = self._packets_demuxed or 0
        if abs(float(avg) / float(base) - 1) > 1e-3 or self.info["variable_rate"]:
            # a variable rate: no count from it (its packets are no count of a file cut short)
            return None
        return max(round(duration_s * float(base)), packets)

    def _variable_rate(self, path: str) -> bool:
        """Whether the stream's own timestamps (every packet's, demuxed without decoding)
        keep no constant rate: some interval between consecutive times is not a whole number
        of the most common one (within 10 %). A constant-rate stream with holes in its times
        (a capture that lost frames) keeps it; a variable one does not, and its gaps then say
        nothing about lost frames (its container's rate is an average or a guess)."""
        import av  # lazy: start-up

        times = []
        self._packets_demuxed: int | None = None  # a whole demux's frames (None: it failed)
        try:
            with av.open(path) as c:
                st = c.streams.video[0]
                times = [p.pts for p in c.demux(st) if p.pts is not None and p.size]
            self._packets_demuxed = len(times)
        except av.FFmpegError:  # damage: the times before it are the evidence
            pass
        if len(times) < 4:
            return False
        dt = np.diff(np.unique(np.asarray(times, dtype=np.float64)))
        values, counts = np.unique(dt, return_counts=True)
        ratio = dt / values[np.argmax(counts)]
        return bool(np.any((ratio < 0.9) | (np.abs(ratio - np.rint(ratio)) > 0.1)))

    def _decoded(self, note: list[str]) -> Iterator[Any]:
        """The decoder's frames in the order it hands them over, packet by packet, so that
        one packet that will not decode costs its own frames only: its error is appended to
        ``note`` and decoding goes on (a whole-stream decode stops at the first bad packet). A
        container that cannot be demuxed further ends here (``error``)."""
        import av  # lazy: start-up

        try:
            for packet in self.container.demux(self.stream):
                if packet.is_discard and self.info.get("container_frames"):
                    # before an edit list's start: in the sample table, never shown
                    self.info["container_frames"] -= 1
                if packet.pts is not None and packet.size:
                    self._sizes[packet.pts] = packet.size
                    self._unseen[packet.pts] += 1
                try:
                    decoded = packet.decode()
                except av.FFmpegError as exc:
                    note.append(self._problem(f"a packet would not decode: {_ffmpeg_reason(exc)}"))
                    continue
                yield from decoded
        except av.FFmpegError as exc:  # a cut or corrupt container: keep what came before
            self.error = _ffmpeg_reason(exc)

    def reorder_depth(self) -> int:
        """Frames held back to put them in presentation order: the codec's own reorder delay
        (FFmpeg's ``has_b_frames``: 2 for libx264's default B-pyramid; it can grow while
        decoding), at least 1; :data:`REORDER_DEPTH_UNKNOWN` where the codec does not say."""
        depth = getattr(self.stream.codec_context, "reorder_depth", None)
        return REORDER_DEPTH_UNKNOWN if depth is None else max(int(depth), 1)

    def _decode(self) -> Iterator[SourceFrame]:
        """The frames in presentation order. A decoder hands frames over in its own order,
        and a damaged stream can make it hand over a later frame before an earlier one (pts
        24, 33, 25, 34, ...): a reorder buffer as deep as the codec's delay puts them back in
        order; a frame that comes after a later one was delivered (or a second frame at the
        same time) is dropped, counted (``late_frames``, a problem) and never delivered, so
        time never runs backwards. What a frame cost shows as a gap in the times (the
        batcher's dropped frames): each lost frame is counted there, once; what no gap shows
        (a second frame at a time already shown; in a variable-rate stream, every loss) is
        counted on the next frame delivered (``SourceFrame.lost_before``)."""

        variable = bool(self.info.get("variable_rate"))
        tb = float(self.stream.time_base or 0)
        shown: set[int] = set()  # the times delivered (µs): a second frame at one is lost
        # packets counted lost by their timing (a variable rate, below) whose frames the decoder
        # may still hand over, late: each is counted once, there
        counted: collections.Counter = collections.Counter()
        lost = 0  # frames lost since the last frame delivered that no gap shows

        def settle(frame: Any) -> None:  # its packet is accounted for: shown or counted
            if frame.pts is not None and self._unseen[frame.pts] > 0:
                self._unseen[frame.pts] -= 1

        def discard(t: float, frame: Any, why: str) -> None:
            nonlocal lost
            self.late_frames += 1
            note.append(self._problem(f"a frame at {t:.3f} s {why}: dropped"))
            if frame.pts is not None and counted[frame.pts] > 0:
                # its packet was already counted lost, while the frame was still inside the
                # decoder (below): it is the same frame, not a second loss
                counted[frame.pts] -= 1
                return
            settle(frame)
            if variable or round(t * 1e6) in shown:  # no gap in the times shows it
                lost += 1

        note: list[str] = []
        held: list[tuple[float, int, Any]] = []  # (time, arrival, frame): a min-heap
        fps = self.info["nominal_fps"]
        last_t: float | None = None  # the time of the last frame delivered
        t0: float | None = None
        arrival = 0

        def deliver(t: float, frame: Any) -> SourceFrame:
            nonlocal t0, lost
            if t0 is None:  # the first frame: how far after the stream's start
                t0 = t
                if frame.time is not None and self._start_s is not None:
                    self.info["first_frame_s"] = max(0.0, t - self._start_s)
                    # a variable rate's frames before its first are counted by their
                    # packets (below), never from an assumed rate
                    if not variable:
                        self.lost_before_first = frames_missing_in(self.info["first_frame_s"], fps)
            rot = round(float(getattr(frame, "rotation", 0) or 0))
            self.info["rotation_deg"] = rot
            if "bit_depth" not in self.info:
                self.info |= stream_format(frame)
            native = luma_plane(frame, self.info["bit_depth"])
            luma = display_grey(frame, native) if self.grey else native
            if rot % 360:  # the display matrix's counter-clockwise angle
                luma = np.ascontiguousarray(np.rot90(luma, k=round(rot / 90)))
            size = self._sizes.pop(frame.pts, None) if frame.pts is not None else None
            settle(frame)
            if variable and tb:  # packets before it that gave no frame: lost, by its timing
                gone = [p for p in self._unseen if p * tb < t - 1e-6]
                for p in gone:
                    k = self._unseen.pop(p)
                    counted[p] += k
                    lost += k
            shown.add(round(t * 1e6))
            out = SourceFrame(luma, float(t - t0), "; ".join(note) or None, native, size, lost)
            lost = 0
            return out

        for frame in self._decoded(note):
            t = frame.time
            if t is None:  # no timestamp: the decoder's order is all there is
                t = (last_t + 1 / fps) if last_t is not None else arrival / fps
            if last_t is not None and t <= last_t:
                discard(t, frame, "came after a later one (out of time order)")
                continue
            heapq.heappush(held, (float(t), arrival, frame))
            arrival += 1
            while len(held) > self.reorder_depth():
                t_next, _, first = heapq.heappop(held)
                if last_t is not None and t_next <= last_t:  # a second frame at one time
                    discard(t_next, first, "repeats the time of the one before")
                    continue
                yield deliver(t_next, first)
                note.clear()
                last_t = t_next
        while held:  # the end: the frames still held, in order
            t_next, _, first = heapq.heappop(held)
            if last_t is not None and t_next <= last_t:
                discard(t_next, first, "repeats the time of the one before")
                continue
            yield deliver(t_next, first)
            note.clear()
            last_t = t_next

    def frames(self) -> Iterator[SourceFrame]:
        yield self._first
        yield from self._frames

    def close(self) -> None:
        self.container.close()


def _ffmpeg_reason(exc: Exception) -> str:
    return str(getattr(exc, "strerror", None) or exc).strip().rstrip(".")


# 8-bit limited-range luma to full-range grey, as FFmpeg's swscale converts it to "gray"
# (round((Y - 16) * 255 / 219), clipped): checked equal for all 256 codes
_LIMITED_TO_FULL = np.clip(np.rint((np.arange(256) - 16) * 255 / 219), 0, 255).astype(np.uint8)
_PLANAR_8BIT = ("yuv420p", "yuv422p", "yuv444p", "yuv440p", "yuv411p", "yuv410p")


def display_grey(frame: Any, native: np.ndarray) -> np.ndarray:
    """(H, W) uint8 full-range grey of a decoded frame, as ``frame.to_ndarray(format="gray")``
    gives it, read from its Y plane ``native`` where that is exact (8-bit planar YUV: a
    lookup, several times cheaper than a conversion of the whole frame), else converted."""
    name = frame.format.name
    if name.startswith("yuvj") and name[:3] + name[4:] in _PLANAR_8BIT:
        return np.ascontiguousarray(native)  # full range already
    if name in _PLANAR_8BIT and int(getattr(frame, "color_range", 0) or 0) != 2:
        return cv2.LUT(np.ascontiguousarray(native), _LIMITED_TO_FULL)
    return frame.to_ndarray(format="gray")


def open_reader(
    source: str, fps: float | None = None, decoder_threads: int | None = None
) -> Reader:
    """The reader of ``source``: a video file, an image-sequence pattern (needs ``fps``) or a
    camera index. A missing, empty or unreadable source, or one with frames too small for the
    metrics (``require_frame_size``), raises UserError in one line naming it.
    ``decoder_threads``: a video file's decoding threads (:func:`open_video`)."""
    kind = source_kind(source)
    if kind == "file":
        reader: Reader = _PyAvReader(source, decoder_threads)
    elif kind == "camera":
        reader = CameraReader(source, fps)
    else:
        reader = ImageSequenceReader(source, fps)
    require_frame_size(reader, source)  # before any frame is measured, naming the source
    return reader

"""An episode's frames: the window ``from_s`` .. ``to_s`` of a (shared) video file, decoded
with PyAV from the key frame before it, with each frame's true time."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import av

from vdc.errors import UserError
from vdc.frame_metrics import luma_plane, stream_format
from vdc.sources import Reader, SourceFrame, display_grey, frames_missing_in, open_video

# a frame belongs to a window when its time is at least from_s - this (s): LeRobot's own
# tolerance for a frame's timestamp (tolerance_s = 1e-4) is finer than any frame interval
EDGE_S = 1e-4


class WindowReader(Reader):
    """The frames of ``path`` whose presentation time lies in [from_s, to_s) (to_s None: to
    the end), in order, their ``t_s`` counted from ``from_s`` (not from the first frame, so
    a late first frame shows as drift and lost frames, not hidden). ``times_s`` collects the
    times delivered; ``first_grey``/``last_grey`` keep the first and last display images (the
    camera's view, for its shift). A window that ends past the file raises UserError when
    opened; a file that will not open raises UserError naming it."""

    planes_persist = True  # PyAV's planes: see vdc.sources.open_video

    def __init__(self, path: str, from_s: float, to_s: float | None, fps: float) -> None:

        self.path, self.from_s, self.to_s, self.fps = path, from_s, to_s, fps
        self.container, self.stream = open_video(path)
        s = self.stream
        end = None
        if self.container.duration is not None:
            end = self.container.duration / 1e6
        elif s.duration is not None and s.time_base:
            end = float(s.duration * s.time_base)
        # a window past its file: beyond the container's end by more than a frame interval
        if to_s is not None and end is not None and to_s > end + 1.0 / fps:
            self.container.close()
            raise UserError(
                f"{path}: the episode's window ends at {to_s:.3f} s, past the file's end "
                f"({end:.3f} s)."
            )
        self.file_end_s = end
        self.info = {
            "kind": "file",
            "codec": s.codec_context.name,
            "nominal_fps": fps,
            "src_width_px": s.codec_context.width,
            "src_height_px": s.codec_context.height,
            "n_frames_header": 0,
            "rotation_deg": 0,
            "duration_s": None,
            "first_frame_s": 0.0,
            "container_frames": None,
        }
        self.times_s: list[float] = []
        self.first_grey: Any = None
        self.last_grey: Any = None
        self._frames = self._decode()
        try:
            self._first = next(self._frames)
        except StopIteration:
            self.container.close()
            raise UserError(
                f"{path}: no frame in the episode's window {from_s:.3f}-{to_s} s."
            ) from None

    def _decode(self) -> Iterator[SourceFrame]:

        s = self.stream
        if self.from_s > 0:  # the key frame at or before the window
            self.container.seek(int(self.from_s / s.time_base), stream=s, backward=True)
        sizes: dict[int, int] = {}
        last_t: float | None = None
        try:
            for packet in self.container.demux(s):
                if packet.pts is not None and packet.size:
                    sizes[packet.pts] = packet.size
                for frame in packet.decode():
                    t = frame.time
                    if t is None or t < self.from_s - EDGE_S:
                        continue
                    if self.to_s is not None and t >= self.to_s - EDGE_S:
                        return
                    if last_t is not None and t <= last_t:
                        self.late_frames += 1
                        self._problem(f"a frame at {t:.3f} s came after a later one: dropped")
                        continue
                    yield self._deliver(frame, t, sizes.pop(frame.pts, None), last_t is None)
                    last_t = t
        except av.FFmpegError as exc:  # a cut or corrupt file: what came before is kept
            self.error = f"{self.path}: decoding stopped at {last_t or self.from_s:.3f} s ({exc})"

    def _deliver(self, frame: Any, t: float, size: int | None, first: bool) -> SourceFrame:
        if "bit_depth" not in self.info:
            self.info |= stream_format(frame)
        if first:  # frames missing between the window's start and its first frame
            self.info["first_frame_s"] = max(0.0, t - self.from_s)
            self.lost_before_first = frames_missing_in(self.info["first_frame_s"], self.fps)
        native = luma_plane(frame, self.info["bit_depth"])
        grey = display_grey(frame, native)
        if self.first_grey is None:
            self.first_grey = grey.copy()
        self.last_grey = grey
        self.times_s.append(t - self.from_s)
        return SourceFrame(grey, t - self.from_s, None, native, size)

    def frames(self) -> Iterator[SourceFrame]:
        yield self._first
        yield from self._frames

    def close(self) -> None:
        self.container.close()

"""What every source reader gives (``vdc.sources``): :class:`SourceFrame`, one decoded frame
with its time, and :class:`Reader`, the interface of a file's, an image sequence's and a
camera's reader; with the format every image and camera frame has (:data:`IMAGE_FORMAT`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np

# images and camera frames: 8-bit grey, full range
IMAGE_FORMAT = {"bit_depth": 8, "color_range": "full", "color_range_tag": "full", "luma": True}


@dataclasses.dataclass
class SourceFrame:
    """One decoded frame.

    ``luma`` (H, W) uint8: grey as displayed (rotation metadata applied), the models' input
    before resizing; ``t_s``: seconds since the first frame; ``note``: what was lost just
    before it, or None; ``native`` (H, W) uint8/uint16: the stream's own luma code values
    (its Y plane, at its bit depth and colour range, unrotated); ``packet_bytes``: the size
    the source's codec spent on it (None where unknown); ``lost_before``: frames the source
    itself knows were lost just before it that no gap in the times shows (a second frame at
    the same time; in a variable-rate stream, whose gaps say nothing, every frame lost: a
    packet that gave no frame, a frame out of time order)."""

    luma: np.ndarray
    t_s: float
    note: str | None
    native: np.ndarray
    packet_bytes: int | None = None
    lost_before: int = 0


class Reader:
    """Frames and their times (s) from one source, in presentation order (times strictly
    increasing); ``info`` describes it. ``error``: why the source ended early (None when it
    ended normally); ``problems``: what went wrong inside it (missing or unreadable images,
    packets that would not decode, frames out of time order), counted. The frames these cost
    show as gaps in the times, where :class:`FrameBatcher` counts them as dropped, once; a
    problem is the reason, not a second count.

    ``info["container_frames"]``: the frames the source states it holds (a file's container,
    an image sequence's numbers from the first file to the last), None where it states none
    (a camera; a file whose container states neither a count nor a trustworthy duration);
    ``info["first_frame_s"]``: the first frame's time after the stream's start (s), whose
    frames :attr:`lost_before_first` counts."""

    info: dict[str, Any]
    lost_before_first: int = 0  # frames the source should hold before its first frame
    error: str | None = None
    problems: int = 0
    first_problem: str | None = None
    late_frames: int = 0  # frames the decoder handed over after a later one: dropped
    # False: a reader may leave ``luma`` as the native plane (no grey conversion) where no
    # one reads it (FrameBatcher without a working raster: native metrics only)
    grey: bool = True
    # True: a frame's ``native`` array stays unchanged while anyone holds it (no buffer reuse)
    planes_persist: bool = False

    def frames(self) -> Iterator[SourceFrame]:  # pragma: no cover - interface
        raise NotImplementedError

    def _problem(self, text: str) -> str:
        self.problems += 1
        self.first_problem = self.first_problem or text
        return text

    def close(self) -> None:
        pass


def grey_8bit(grey16: np.ndarray) -> np.ndarray:
    """(H, W) uint8 of a full-range 16-bit grey image, each value scaled by 255/65535 and
    rounded: the models' 8-bit intensity scale (not the low byte, nor a floor)."""
    return ((grey16.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)

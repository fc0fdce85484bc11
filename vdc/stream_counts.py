"""What a source's frames add up to: the frames lost before its first frame, between and after
its last, and the seconds its header states that the frames do not cover. ``vdc-capture
video`` and ``vdc-analyse complexity`` count each lost frame once, through these
(``vdc.frame_batches.FrameBatcher.end_fields``); a video recording's ``video`` property keeps
the keys a reader's ``info`` has, so a recording is counted the same way."""

from __future__ import annotations

import math
from typing import Any


def frames_missing_in(gap_s: float, fps: float) -> int:
    """Frames missing in ``gap_s`` seconds between the stream's start and its first frame, by
    the rule :class:`vdc.frame_batches.FrameBatcher` counts gaps between frames with (a frame
    is missing where the first comes more than half a frame interval late): 0 for a whole
    start, round(``gap_s`` × ``fps``) otherwise."""
    if not (math.isfinite(gap_s) and math.isfinite(fps) and fps > 0) or gap_s * fps <= 0.5:
        return 0
    return max(round(gap_s * fps), 1)


def frames_lost_after(container_frames: int | None, frames: int, dropped: int) -> int | None:
    """Frames lost after a source's last frame: the ``container_frames`` it states it holds
    less the ``frames`` measured and those ``dropped`` before and between them (never
    negative); None, unknown, where the source states no count. A file cut short loses its
    frames here: they are dropped frames, and ``missing_s`` (:func:`header_shortfall`) says
    the same frames in seconds, not a second count."""
    if container_frames is None:
        return None
    return max(0, int(container_frames) - int(frames) - int(dropped))


def header_shortfall(
    header_duration_s: float | None, last_t_s: float | None, fps: float
) -> float | None:
    """Seconds of a file its header states but its frames do not reach: the header's
    duration less the last frame's time since the stream's start (``last_t_s``) and one frame
    interval (``1 / fps``), 0.0 for a whole file (frames that end within two intervals of the
    header's duration), None where no header states a duration (image sequences, cameras) or
    no frame was read."""
    stated = float(header_duration_s or 0.0)
    if stated <= 0 or last_t_s is None or not (math.isfinite(fps) and fps > 0):
        return None
    if last_t_s + 2.0 / fps >= stated:
        return 0.0
    return stated - (last_t_s + 1.0 / fps)


def cut_short_note(
    header_duration_s: float | None,
    last_t_s: float | None,
    fps: float,
    lost_after: int | None = None,
) -> str | None:
    """The one line ``vdc-capture video`` and ``vdc-analyse complexity`` say about a file
    that ends well before the duration its header states (see :func:`header_shortfall`;
    ``last_t_s`` since the stream's start), else None; with the ``lost_after`` frames
    (:func:`frames_lost_after`) it says they are counted among the dropped ones."""
    if not header_shortfall(header_duration_s, last_t_s, fps):
        return None
    counted = f"; its {lost_after} frame(s) after it are counted as dropped" if lost_after else ""
    return (
        f"the file ends at {last_t_s:.2f} s but its header says {header_duration_s:.2f} s "
        f"(cut short?){counted}"
    )


def end_fields(
    info: dict[str, Any],
    last_t_s: float | None,
    fps: float,
    frames: int,
    dropped: int,
    ended: bool = True,
) -> dict[str, Any]:
    """What a clip's row says about its end (``clips.parquet``), from a source's ``info``
    (:attr:`Reader.info`, or a video recording's ``video`` property, which keeps the same
    keys), its last frame's time since its first (``last_t_s``), and the ``frames`` measured
    and ``dropped`` before and between them: ``dropped_frames`` (with those lost after the
    last frame), ``container_frames`` (the count the source states, None where it states
    none), ``lost_after_last`` (None: unknown), ``header_duration_s``, ``missing_s`` (the
    seconds the header states that the frames do not cover: the lost end,
    :func:`header_shortfall`, and the lost start, ``first_frame_s``) and ``cut_note``.
    ``ended``: False for a source read only in part (a capture stopped by a signal): nothing
    is lost after it."""
    container = info.get("container_frames")
    after = frames_lost_after(container, frames, dropped) if ended else None
    header_s = info.get("header_duration_s", info.get("duration_s")) or None
    first_s = float(info.get("first_frame_s") or 0.0)
    end_s = None if last_t_s is None else last_t_s + first_s
    missing = header_shortfall(header_s, end_s, fps)
    if missing is not None and frames_missing_in(first_s, fps):  # and the lost start
        missing += first_s
    return {
        "dropped_frames": int(dropped) + (after or 0),
        "container_frames": container,
        "lost_after_last": after,
        "header_duration_s": header_s,
        "missing_s": missing,
        "cut_note": cut_short_note(header_s, end_s, fps, after) if ended else None,
    }

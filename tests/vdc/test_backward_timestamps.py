"""A clip whose presentation timestamps go backwards (issue 56): its frames are delivered in
time order and each of the container's frames is measured or counted dropped exactly once.
Real files: a 50-frame libx264 clip (B-frames on) muxed with its packets' times rewritten, so
that from one frame on they jump back."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from analysis.complexity.command import ComplexitySettings, complexity
from vdc.frame_batches import FrameBatcher
from vdc.sources import open_reader

N_FRAMES, FPS, TICKS = 50, 25, 4  # time base 1/100 s: 4 ticks a frame


def write_backwards(path: Path, at: int, back_ticks: int) -> Path:
    """50 frames at 25 fps whose times, from frame ``at`` on, are ``back_ticks`` (1/100 s)
    earlier than their place: the container holds 50 frames whatever their times say."""
    tex = np.random.default_rng(56).integers(0, 255, (48, 400), dtype=np.uint8)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        stream.codec_context.time_base = stream.time_base = Fraction(1, 100)
        packets = []
        for i in range(N_FRAMES):
            img = np.ascontiguousarray(tex[:, 3 * i : 3 * i + 64])
            frame = av.VideoFrame.from_ndarray(img, format="gray").reformat(format="yuv420p")
            frame.pts, frame.time_base = TICKS * i, Fraction(1, 100)
            packets += stream.encode(frame)
        packets += stream.encode()
        for packet in packets:
            if packet.pts >= TICKS * at:
                packet.pts -= back_ticks
            packet.dts -= 100 * TICKS  # decoding times stay increasing and before the new pts
            out.mux(packet)
    return path


def counts(path: Path) -> tuple[int, dict, list[float]]:
    """Frames measured, the clip's end fields, and the times, as every command reads them."""
    reader = open_reader(str(path))
    batcher = FrameBatcher(reader, None, FPS)
    frames, times = 0, []
    while (batch := batcher.next_batch()) is not None:
        frames += len(batch.frame)
        times += batch.t_s.tolist()
    reader.close()
    return frames, batcher.end_fields(), times


@pytest.mark.parametrize(
    ("name", "at", "back_ticks"),
    [
        # the last 10 frames 1.3 s back, off the frame grid (a variable rate): their packets
        # were counted lost while the frames were inside the decoder, then again when they
        # came out late (40 + 20)
        ("late.mp4", 40, 130),
        # 10 frames back on the grid in Matroska, which states a duration, not a count: the
        # duration (its latest time) held 40 frames, the file 50
        ("back.mkv", 20, 40),
    ],
)
def test_frames_and_dropped_add_up_to_the_container(tmp_path, name, at, back_ticks) -> None:
    clip = write_backwards(tmp_path / name, at, back_ticks)
    frames, end, times = counts(clip)
    assert (np.diff(times) > 0).all(), times  # time never runs backwards
    assert end["container_frames"] == N_FRAMES
    assert frames < N_FRAMES  # frames were dropped for their times ...
    assert frames + end["dropped_frames"] == N_FRAMES  # ... each counted once


def test_the_clip_table_says_the_same(tmp_path) -> None:
    clip = write_backwards(tmp_path / "late.mp4", 40, 130)
    frames, end, _ = counts(clip)
    row = complexity([clip], ComplexitySettings(), tmp_path / "cx").clips.row(0, named=True)
    assert (row["frames"], row["dropped_frames"]) == (frames, end["dropped_frames"])
    assert row["frames"] + row["dropped_frames"] == N_FRAMES

"""Frames against the container's own clock (issue 44 §1): a variable-rate stream counts a
frame as dropped only where its own timing says one is missing, never from an assumed rate,
and times strictly increase: a frame whose time does not advance (a repeated or backward
timestamp) is dropped and counted, so that ``frames + dropped_frames`` equals the frames the
container states. Real H.264 files written and re-timed by the tests with PyAV."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from tests.analysis.complexity.test_lost_frames import measured, zero_packets

N, FPS = 60, 25


def texture(n: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    return cv2.GaussianBlur(rng.integers(0, 255, (120, 160 + 2 * n), dtype=np.uint8), (0, 0), 3)


def write_vfr(path: Path, n: int = N) -> Path:
    """A 160x120 H.264 clip whose frames come 20 to 67 ms apart (a phone's variable rate),
    times in ms, a key frame every 10 frames."""
    rng = np.random.default_rng(5)
    pts = np.concatenate(([0], np.cumsum(rng.choice([20, 33, 40, 50, 67], n - 1))))
    tex = texture(n)
    with av.open(str(path), "w") as out:
        st = out.add_stream("libx264", rate=30)
        st.width, st.height, st.pix_fmt = 160, 120, "yuv420p"
        st.codec_context.time_base = st.time_base = Fraction(1, 1000)
        st.codec_context.gop_size = 10
        for i in range(n):
            img = np.ascontiguousarray(tex[:, 2 * i : 2 * i + 160])
            frame = av.VideoFrame.from_ndarray(img, format="gray").reformat(format="yuv420p")
            frame.pts, frame.time_base = int(pts[i]), Fraction(1, 1000)
            for p in st.encode(frame):
                out.mux(p)
        for p in st.encode():
            out.mux(p)
    return path


@pytest.mark.parametrize("suffix", [".mp4", ".mkv"])
def test_a_variable_rate_clip_that_lost_nothing_drops_nothing(tmp_path, suffix):
    info = measured(write_vfr(tmp_path / f"vfr{suffix}"))
    assert (info["frames"], info["dropped_frames"]) == (N, 0), info
    # MP4 states its count (the sample table); Matroska a duration, which at a variable
    # rate gives none: unknown, not guessed
    assert info["container_frames"] == (N if suffix == ".mp4" else None)


def test_a_variable_rate_clip_counts_what_its_own_packets_lost(tmp_path):
    """Its first key frame unreadable: the 10 frames of that group are lost, counted by the
    packets that gave no frame (not by the gap to the first frame at an assumed rate)."""
    bad = zero_packets(write_vfr(tmp_path / "vfr.mp4"), tmp_path / "bad.mp4", True, False)
    info = measured(bad)
    assert info["frames"] < N and info["container_frames"] == N
    assert info["frames"] + info["dropped_frames"] == N, info


def retimed(src: Path, dst: Path, shifts: dict[int, int]) -> Path:
    """``src`` (no B-frames) muxed again with packet i's time moved back by ``shifts[i]``
    frame intervals: 1 repeats the time of the frame before, 3 goes back before it."""
    with av.open(str(src)) as c, av.open(str(dst), "w") as out:
        ist = c.streams.video[0]
        ost = out.add_stream_from_template(ist)
        step = round(1 / (FPS * ist.time_base))
        for i, p in enumerate(q for q in c.demux(ist) if q.size):
            # decode times stay increasing (a muxer refuses others); the shown times move
            p.pts, p.dts = (i + 5 - shifts.get(i, 0)) * step, i * step
            p.stream = ost
            out.mux(p)
    return dst


@pytest.mark.parametrize("suffix", [".mkv", ".mp4"])
def test_times_that_repeat_or_go_backwards_are_dropped_and_counted(tmp_path, suffix):
    n = 40
    src = tmp_path / "intra.mkv"
    tex = texture(n)
    with av.open(str(src), "w") as out:
        st = out.add_stream("libx264", rate=FPS)
        st.width, st.height, st.pix_fmt = 160, 120, "yuv420p"
        st.options = {"bf": "0"}  # decode order = display order: times set per packet
        for i in range(n):
            img = np.ascontiguousarray(tex[:, 2 * i : 2 * i + 160])
            for p in st.encode(av.VideoFrame.from_ndarray(img, format="gray")):
                out.mux(p)
        for p in st.encode():
            out.mux(p)
    bad = retimed(src, tmp_path / f"bad{suffix}", {11: 1, 21: 3})
    with av.open(str(bad)) as c:  # the file is what the test means: a repeat, a step back
        times = [round(float(f.time), 3) for f in c.decode(video=0)]
    assert times[11] == times[10] and times[21] < times[20]
    from analysis.complexity.command import ComplexitySettings
    from analysis.complexity.source_metrics import measure_video

    m = measure_video(str(bad), ComplexitySettings(metrics="si_p910,mafd"), "t")
    t = m.table["t_s"].to_numpy()
    assert np.all(np.diff(t) > 0)  # no two frames at one time reach the models
    info = m.info
    assert (info["frames"], info["container_frames"]) == (n - 2, n)
    assert info["frames"] + info["dropped_frames"] == n, info
    assert info["source_problems"] == 2  # each named: "repeats the time", "out of time order"


def test_two_clips_with_one_stem_in_one_folder_keep_apart(tmp_path):
    """``take.mp4`` and ``take.mkv`` side by side (and a ``take.mp4`` in another folder): each
    gets its own recording id, rows, figure and ``.rrd``; nothing overwrites another's."""
    from analysis.complexity.command import ComplexitySettings, complexity
    from tests.analysis.complexity.test_lost_frames import N as FRAMES
    from tests.analysis.complexity.test_lost_frames import write_clip

    folder = tmp_path / "day1"
    folder.mkdir()
    (tmp_path / "day2").mkdir()
    write_clip(folder / "take.mp4")
    write_clip(folder / "take.mkv", first_pts=3)  # another clip: not the same file twice
    write_clip(tmp_path / "day2" / "take.mp4", n=FRAMES - 4)
    res = complexity(
        [tmp_path], ComplexitySettings(metrics="si_p910,mafd", rrd=True), tmp_path / "out"
    )
    ids = res.clips["recording_id"].to_list()
    assert len(ids) == 3 and len(set(ids)) == 3, ids
    per_id = res.table.group_by("recording_id").len()
    assert sorted(per_id["len"].to_list()) == [FRAMES - 4, FRAMES, FRAMES]
    for suffix in ("png", "rrd"):
        written = {p.name for p in (tmp_path / "out").glob(f"complexity_*.{suffix}")}
        written.discard("complexity_collection.png")  # the collection's, not a clip's
        assert written == {f"complexity_{i}.{suffix}" for i in ids}

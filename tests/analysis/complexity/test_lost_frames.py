"""Each frame a source should hold is measured or counted lost, once (issue 37 §1): frames lost
before the first frame that decodes (damage at the start), between frames, and after the last
(damage at the end, a file cut short), so that ``frames + dropped_frames`` equals the count the
container states, and a clean file that starts at a non-zero time loses none. Real files: small
libx264 clips (B-frames on, a GOP of 10) in MP4, Matroska and MPEG-TS that the tests write and
damage in their bytes; ``vdc-capture video``, ``vdc-analyse complexity`` and the Python API
report the same counts for the same file."""

from __future__ import annotations

import re
from pathlib import Path

import av
import cv2
import numpy as np
import polars as pl
import pytest

from tests.helpers import flags

N, FPS, GOP = 30, 25, 10
PIXEL_METRICS = "si_p910,mafd"  # no model needed: cheap, and the counts do not depend on it


def write_clip(path: Path, n: int = N, first_pts: int = 0, gop: int = GOP) -> Path:
    """A 1.2-s 160x120 25-fps H.264 clip of a blurred texture panning 2 px per frame, with
    libx264's B-frames and a keyframe every ``GOP`` frames; its frames' pts start at
    ``first_pts`` (in frames: a file cut from a longer one starts late; negative: an MP4 edit
    list hides the frames before 0)."""
    rng = np.random.default_rng(7)
    tex = cv2.GaussianBlur(rng.integers(0, 255, (120, 160 + 2 * n), dtype=np.uint8), (0, 0), 3)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = 160, 120, "yuv420p"
        stream.codec_context.gop_size = gop
        for i in range(n):
            img = np.ascontiguousarray(tex[:, 2 * i : 2 * i + 160])
            frame = av.VideoFrame.from_ndarray(img, format="gray").reformat(format="yuv420p")
            frame.pts = i + first_pts
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def packets(path: Path) -> list[av.Packet]:
    """The video packets of a file in decode order (those with data)."""
    with av.open(str(path)) as c:
        return [p for p in c.demux(c.streams.video[0]) if p.size]


def zero_packets(src: Path, dst: Path, first: bool, last_gop: bool) -> Path:
    """``src`` with the payload of its first packet (the first keyframe: its whole GOP then
    fails to decode) and/or of every packet from its last keyframe on set to zero in the
    file's bytes, the container's own structure untouched: frames lost at the start and at
    the end of a stream the container still describes whole."""
    data = bytearray(src.read_bytes())
    pk = packets(src)
    last_key = max(i for i, p in enumerate(pk) if p.is_keyframe)
    chosen = ([0] if first else []) + (list(range(last_key, len(pk))) if last_gop else [])
    for i in chosen:
        payload = bytes(pk[i])
        at = data.find(payload)
        assert at >= 0 and data.find(payload, at + 1) < 0, f"packet {i} is not unique"
        data[at : at + len(payload)] = bytes(len(payload))
    dst.write_bytes(bytes(data))
    return dst


def measured(path: Path) -> dict:
    """What the Python API's per-source measurement says of a file (its clip row's counts)."""
    from analysis.complexity.command import ComplexitySettings
    from analysis.complexity.source_metrics import measure_video

    return measure_video(str(path), ComplexitySettings(metrics=PIXEL_METRICS), "t").info


@pytest.mark.parametrize(
    ("suffix", "first_pts", "states"),
    [
        (".mp4", 12, N),  # starts at 0.48 s: an edit list, the count in the sample table
        (".mkv", 12, N),  # starts at 0.48 s: Matroska states 1.68 s, the end, not the length
        (".ts", 12, None),  # MPEG-TS states no count (nor a duration): unknown, not 0
        (".mp4", -3, N - 3),  # an edit list hides the first 3 samples: 27 frames, none lost
    ],
)
def test_a_clean_file_that_starts_late_loses_no_frame(tmp_path, suffix, first_pts, states):
    path = write_clip(tmp_path / f"clean{suffix}", first_pts=first_pts)
    with av.open(str(path)) as c:  # the files are what the test means them to be
        s = c.streams.video[0]
        start_s = float(s.start_time * s.time_base)
    assert start_s >= 0.48 if first_pts > 0 else start_s == 0.0
    info = measured(path)
    assert info["dropped_frames"] == 0, info
    assert info["frames"] == states if states else info["frames"] == N
    assert info["container_frames"] == states
    assert info["lost_after_last"] == (0 if states else None)  # None: unknown, not 0
    assert info["missing_s"] == 0.0 and info["cut_note"] is None


@pytest.mark.parametrize("suffix", [".mp4", ".mkv"])
def test_frames_lost_at_the_start_and_at_the_end_are_counted_once(tmp_path, suffix):
    clean = write_clip(tmp_path / f"clean{suffix}")
    for first, last_gop in ((True, False), (False, True), (True, True)):
        bad = zero_packets(
            clean, tmp_path / f"bad{int(first)}{int(last_gop)}{suffix}", first, last_gop
        )
        info = measured(bad)
        assert info["container_frames"] == N
        assert info["frames"] < N  # the damage cost frames ...
        assert info["frames"] + info["dropped_frames"] == N, info  # ... each counted once
        if first:  # the first GOP does not decode: the first frame is frame 10 or later
            from vdc.sources import open_reader

            reader = open_reader(str(bad))
            try:
                assert reader.lost_before_first >= GOP
                assert reader.info["first_frame_s"] == pytest.approx(reader.lost_before_first / FPS)
            finally:
                reader.close()
        if last_gop:  # the last GOP does not decode: lost after the last frame, in seconds too
            assert info["lost_after_last"] >= N - 2 * GOP
            # the same frames, as time: the header's end less the last frame's and one
            # interval, and the lost start (the first frame's time after the stream's start)
            lost = info["lost_after_last"] + (GOP if first else 0)
            assert info["missing_s"] == pytest.approx(lost / FPS, abs=1e-6)
            assert "counted as dropped" in info["cut_note"]
        else:
            assert info["lost_after_last"] == 0
            assert info["missing_s"] == pytest.approx(GOP / FPS if first else 0.0, abs=1e-6)


def test_a_damaged_clip_measured_on_threads_counts_as_on_one(tmp_path):
    """A clip damaged at both ends read as ``complexity`` reads it on several cores (each
    frame measured on 3 threads while one decodes ahead, with FFmpeg's own decoder threads)
    and on one thread: the same frames, times, drops, metrics and end counts. Decoding ahead
    on one FFmpeg thread had counted 12 frames lost after the last against 10."""
    from vdc.frame_batches import FrameBatcher
    from vdc.sources import open_reader

    clean = write_clip(tmp_path / "clean.mp4")
    bad = zero_packets(clean, tmp_path / "bad.mp4", first=True, last_gop=True)
    seen = {}
    for threads in (1, 3):
        reader = open_reader(str(bad))
        b = FrameBatcher(
            reader, None, FPS, batch_frames=8, metrics=("si_p910", "ti_p910"), threads=threads
        )
        batches = list(iter(b.next_batch, None))
        seen[threads] = (
            np.concatenate([fb.t_s for fb in batches]),
            np.concatenate([fb.dropped_before for fb in batches]),
            np.concatenate([fb.native_metrics for fb in batches]),
            b.end_fields(),
        )
        b.close()
        reader.close()
    for a, b in zip(seen[3][:3], seen[1][:3], strict=True):
        np.testing.assert_array_equal(a, b)
    assert seen[3][3] == seen[1][3]
    frames = len(seen[1][0])
    assert frames + seen[1][3]["dropped_frames"] == N and seen[1][3]["lost_after_last"] >= GOP
    info = measured(bad)  # the Python API, on every core the machine gives it
    assert (info["frames"], info["dropped_frames"]) == (frames, seen[1][3]["dropped_frames"])
    assert info["lost_after_last"] == seen[1][3]["lost_after_last"]


def zero_first_cluster(src: Path, dst: Path) -> Path:
    """A Matroska file with its whole first Cluster (its ID, timestamp and blocks: the first
    key frame's group) set to zero in the file's bytes: FFmpeg then reads the stream as
    starting at the second cluster; the file's index (Cues) still names the first."""
    data = bytearray(src.read_bytes())
    cluster = b"\x1f\x43\xb6\x75"  # the Cluster element's ID
    first = data.find(cluster)
    second = data.find(cluster, first + 1)
    assert 0 < first < second, "the clip has two clusters"
    data[first:second] = bytes(second - first)
    dst.write_bytes(bytes(data))
    return dst


def test_an_mkv_whose_first_cluster_is_unreadable_counts_its_lost_start(tmp_path):
    """Issue 44: 100 frames whose first 2 s (a key frame every 50 frames: one cluster) are
    unreadable: 50 frames measured, 50 dropped and 2 s missing, by the complexity and by
    the capture, not a whole 2-s clip."""
    from capture.video import VideoSettings, record_video

    clean = write_clip(tmp_path / "clean.mkv", n=100, gop=50)
    bad = zero_first_cluster(clean, tmp_path / "bad.mkv")
    with av.open(str(bad)) as c:  # the damage is what the test means: FFmpeg starts at 2 s
        assert c.start_time == 2_000_000
    info = measured(bad)
    assert (info["frames"], info["dropped_frames"], info["container_frames"]) == (50, 50, 100)
    assert info["header_duration_s"] == pytest.approx(4.0)
    assert info["missing_s"] == pytest.approx(2.0, abs=1e-6)  # the lost start, in seconds
    rec = record_video(
        VideoSettings(source=str(bad), fov_deg=70.0, model="avdm"), tmp_path / "bad.rrd"
    )
    assert (rec.record.frames, rec.dropped, rec.container_frames) == (50, 50, 100)


def test_unreadable_first_and_last_images_are_counted(tmp_path):
    """An image sequence's numbers are its count: images lost before the first readable one
    and after the last are dropped frames too."""
    for k in range(8):
        cv2.imwrite(str(tmp_path / f"img_{k:03d}.png"), np.full((24, 32), 30 * k, np.uint8))
    for k in (0, 7):
        (tmp_path / f"img_{k:03d}.png").write_bytes(b"not a png")
    from analysis.complexity.command import ComplexitySettings
    from analysis.complexity.source_metrics import measure_video

    pattern = str(tmp_path / "img_%03d.png")
    s = ComplexitySettings(metrics=PIXEL_METRICS, fps=FPS)
    info = measure_video(pattern, s, "t").info
    assert (info["frames"], info["dropped_frames"], info["container_frames"]) == (6, 2, 8)
    assert info["lost_after_last"] == 1


COUNTS = re.compile(r"\((\d+) frames, \d+ repeated, (\d+) dropped")


def _three_entry_points(path: Path, out: Path, capsys) -> list[tuple]:
    """(frames, dropped) of ``path`` by the Python API, ``vdc-analyse complexity`` and
    ``vdc-capture video`` (in this process), and by the API on the capture's recording; the
    API's row, and the capture's stderr."""
    import vdc
    from analysis.cli import main as analyse
    from capture.cli import main as capture

    s = vdc.ComplexitySettings(metrics=PIXEL_METRICS)
    api = vdc.complexity([path], s, out / "api").clips.row(0, named=True)
    assert (
        analyse(["complexity", str(path), "--metrics", PIXEL_METRICS, "--out", str(out / "cli")])
        == 0
    )
    cli = pl.read_parquet(out / "cli" / "clips.parquet").row(0, named=True)
    capsys.readouterr()
    rrd = out / "clip.rrd"
    assert (
        capture(
            ["video", str(path), "--fov-deg", "70", "--model", "avdm", "--out", str(rrd), "--quiet"]
        )
        == 0
    )
    said = capsys.readouterr()
    m = COUNTS.search(said.out)
    assert m, said.out
    rec = vdc.complexity([rrd], s, out / "rec").clips.row(0, named=True)
    counts = [
        (api["frames"], api["dropped_frames"]),
        (cli["frames"], cli["dropped_frames"]),
        (int(m.group(1)), int(m.group(2))),
        (rec["frames"], rec["dropped_frames"]),
    ]
    for row in (cli, rec):  # the rows say the same of the end
        for key in ("container_frames", "lost_after_last", "header_duration_s", "missing_s"):
            assert row[key] == pytest.approx(api[key], abs=1e-9), (key, row[key], api[key])
    return counts, api, said.err


def test_the_three_entry_points_count_the_same(tmp_path, capsys):
    # an MP4 damaged at both ends: 10 frames lost before the first, 10 or more after the last
    clean = write_clip(tmp_path / "clean.mp4")
    bad = zero_packets(clean, tmp_path / "bad.mp4", first=True, last_gop=True)
    counts, api, _ = _three_entry_points(bad, tmp_path / "bad", capsys)
    assert len(set(counts)) == 1, counts
    frames, dropped = counts[0]
    assert frames < N - 2 * GOP + 1 and frames + dropped == N == api["container_frames"]
    assert api["lost_after_last"] >= GOP
    from analysis.recordings.reader import Recording

    events = Recording(tmp_path / "bad" / "clip.rrd").events()
    first = events.filter((pl.col("kind") == "dropped_frames") & (pl.col("frame") == 0))
    # the recording says where the first frames went (the first GOP: 10 frames, 0.4 s)
    assert first["text"].to_list() == [
        "10 frame(s) missing before frame 0 (it comes 0.400 s after the stream's start)"
    ]

    # a Matroska file cut in half: its header still states 1.20 s (30 frames); the frames
    # after the cut are dropped ones, and missing_s says the same frames in seconds
    whole = write_clip(tmp_path / "whole.mkv").read_bytes()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(whole[: len(whole) // 2])
    counts, api, err = _three_entry_points(cut, tmp_path / "cut", capsys)
    assert len(set(counts)) == 1, counts
    frames, dropped = counts[0]
    assert frames < N and frames + dropped == N == api["container_frames"]
    assert api["missing_s"] == pytest.approx(api["lost_after_last"] / FPS, abs=1e-6)
    assert f"its {api['lost_after_last']} frame(s) after it are counted as dropped" in err, err


def test_a_file_that_states_no_count_is_said_once_not_guessed(tmp_path, capsys):
    """MPEG-TS states neither a frame count nor a duration: nothing is counted after the last
    frame, the row's count is null, and each command says so in one line."""
    import vdc
    from capture.cli import main as capture

    clip = write_clip(tmp_path / "clip.ts")
    seen: list[str] = []
    s = vdc.ComplexitySettings(metrics=PIXEL_METRICS)
    row = vdc.complexity([clip], s, tmp_path / "cx", notice=seen.append).clips.row(0, named=True)
    assert (row["frames"], row["dropped_frames"]) == (N, 0)
    assert row["container_frames"] is None and row["lost_after_last"] is None
    said = [n for n in seen if "states no frame count" in n]
    assert len(said) == 1 and "1 file(s)" in said[0] and str(clip) in said[0], seen
    capsys.readouterr()
    assert (
        capture(
            [
                "video",
                str(clip),
                *flags("--fov-deg 70 --model avdm --quiet", out=tmp_path / "clip.rrd"),
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert len([ln for ln in err.splitlines() if "states no frame count" in ln]) == 1, err

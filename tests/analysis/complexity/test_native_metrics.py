"""The standard metrics as their standards define them, checked against the reference tools on
real encoded files the tests write (limited and full range): siti-tools' own ``calculate()``
for P.910 (2022) SI/TI, FFmpeg's ``siti`` filter through PyAV for the legacy definition; and
collections of clips in one command."""

from __future__ import annotations

from pathlib import Path

import av
import av.filter
import cv2
import numpy as np
import polars as pl
import pytest
from siti_tools.siti import ColorRange, SiTiCalculator
from skimage import data

from analysis.complexity.command import ComplexitySettings, complexity
from tests.helpers import SITI_TOOLS_PRINTED_ATOL, assert_one_line_error, ffmpeg_siti, write_pan
from tests.in_process import run_in_process
from vdc.frame_metrics import NativeMeter, luma_plane, stream_format
from vdc.source_names import source_name
from vdc.sources import display_grey, open_reader

FOV = 70.0


@pytest.fixture(scope="module")
def coded(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("coded")
    # 384 px: a width whose Y plane has no padding, which siti-tools' reader needs (issue #17)
    return {r: write_pan(d / f"{r}.mp4", 384, 240, 24, color_range=r) for r in ("limited", "full")}


def ours(path: Path) -> tuple[dict, list[dict[str, float]]]:
    meter, rows = None, []
    with av.open(str(path)) as c:
        for frame in c.decode(video=0):
            fmt = stream_format(frame)
            meter = meter or NativeMeter(fmt["bit_depth"], fmt["color_range"])
            rows.append(meter.update(luma_plane(frame, fmt["bit_depth"])))
    return fmt, rows


@pytest.mark.parametrize("color_range", ["limited", "full"])
def test_p910_si_ti_equal_siti_tools_on_the_file(coded, color_range: str) -> None:
    fmt, rows = ours(coded[color_range])
    assert fmt["color_range"] == color_range  # read from the stream, not assumed
    calc = SiTiCalculator(
        color_range=ColorRange.FULL if color_range == "full" else ColorRange.LIMITED
    )
    si, ti, n = calc.calculate(str(coded[color_range]))
    assert n == len(rows) == 24
    # to the precision siti-tools prints (3 decimals): vdc's float32 against its float64
    # (tests.helpers.SITI_TOOLS_PRINTED_ATOL says why)
    tol = {"rtol": 0, "atol": SITI_TOOLS_PRINTED_ATOL}
    np.testing.assert_allclose([r["si_p910"] for r in rows], si, **tol)
    np.testing.assert_allclose([r["ti_p910"] for r in rows][1:], ti, **tol)
    assert np.isnan(rows[0]["ti_p910"])  # no TI on the first frame, as siti-tools


@pytest.mark.parametrize("color_range", ["limited", "full"])
def test_legacy_si_ti_equal_ffmpegs_siti_filter(coded, color_range: str) -> None:
    _, rows = ours(coded[color_range])
    oracle_si, oracle_ti = ffmpeg_siti(coded[color_range]).T
    # FFmpeg prints its values with 2 decimals: equal within that rounding (0.005) plus float
    # noise; its first frame's TI is 0 where ours is null
    np.testing.assert_allclose([r["si_legacy"] for r in rows], oracle_si, atol=0.0051)
    np.testing.assert_allclose([r["ti_legacy"] for r in rows][1:], oracle_ti[1:], atol=0.0051)
    # and the two definitions differ: limited range is stretched, PQ compresses
    assert np.mean([r["si_legacy"] for r in rows]) > 1.5 * np.mean([r["si_p910"] for r in rows])


@pytest.mark.parametrize("pix_fmt", ["yuv420p", "yuvj420p"])
def test_display_grey_from_the_y_plane_equals_ffmpegs_conversion(pix_fmt: str) -> None:
    """Every 8-bit code value: the lookup that replaces a whole-frame conversion is exact."""
    frame = av.VideoFrame(256, 16, pix_fmt)
    frame.planes[0].update(np.tile(np.arange(256, dtype=np.uint8), (16, 1)).tobytes())
    for plane in frame.planes[1:]:
        plane.update(bytes([128]) * plane.buffer_size)
    grey = display_grey(frame, luma_plane(frame, 8))
    assert np.array_equal(grey, frame.to_ndarray(format="gray"))


def test_a_collection_in_one_command_with_a_corrupt_clip(coded, tmp_path: Path) -> None:
    """A folder of clips (two share a file name), a cut file and an image sequence: one task
    each on two workers; the corrupt one is listed and the rest complete; a re-run resumes."""
    folder = tmp_path / "footage"
    (folder / "a").mkdir(parents=True)
    (folder / "b").mkdir()
    (folder / "a" / "clip.mp4").write_bytes(coded["limited"].read_bytes())
    (folder / "b" / "clip.mp4").write_bytes(coded["full"].read_bytes())
    (folder / "cut.mp4").write_bytes(coded["limited"].read_bytes()[:3000])
    shots = tmp_path / "shots"
    shots.mkdir()
    with av.open(str(coded["full"])) as c:
        for i, frame in enumerate(c.decode(video=0)):
            cv2.imwrite(str(shots / f"img_{i:05d}.png"), frame.to_ndarray(format="gray"))
    out = tmp_path / "cx"
    args = ("complexity", str(folder), str(shots / "img_%05d.png"), "--fov-deg", str(FOV))
    proc = run_in_process("analysis", *args, "--fps", "25", "--jobs", "2", "--out", str(out))
    assert proc.returncode == 1, proc.stderr  # one source failed
    assert "FAILED" in proc.stderr and "cut.mp4" in proc.stderr
    fails = pl.read_parquet(out / "failures.parquet")
    assert fails["source"].to_list() == [str(folder / "cut.mp4")]
    clips = pl.read_parquet(out / "clips.parquet")
    assert sorted(clips["recording_id"]) == ["video-a-clip", "video-b-clip", "video-shots-img"]
    row = clips.filter(pl.col("recording_id") == "video-a-clip").row(0, named=True)
    assert (row["codec"], row["width_px"], row["height_px"], row["fps"]) == ("h264", 384, 240, 25)
    assert row["frames"] == 24 and row["repeated_frames"] == 0 and row["dropped_frames"] == 0
    assert row["duration_s"] == pytest.approx(23 / 25)
    for stat in ("mean", "max", "p95"):
        assert row[f"si_p910_{stat}"] > 0 and row[f"omega_dps_{stat}"] > 0
    frames = pl.read_parquet(out / "complexity.parquet")
    a = frames.filter(pl.col("recording_id") == "video-a-clip")
    assert row["ti_p910_max"] == a["ti_p910"].max()
    assert row["si_p910_p95"] == pytest.approx(a["si_p910"].quantile(0.95, "linear"), rel=1e-12)
    # the PNG sequence of the full-range clip's frames: the same pictures, so SI within 1 %
    # (PNG holds the decoded grey: full range, lossless)
    img = clips.filter(pl.col("recording_id") == "video-shots-img").row(0, named=True)
    b = clips.filter(pl.col("recording_id") == "video-b-clip").row(0, named=True)
    assert img["si_p910_mean"] == pytest.approx(b["si_p910_mean"], rel=0.01)
    assert img["codec"] == "image files" and b["codec_bpp_mean"] < img["codec_bpp_mean"]
    html = (out / "complexity.html").read_text()
    assert html.count("data:image/png;base64") == 1 and "video-b-clip" in html
    assert not list(out.glob("complexity_video-*.rrd"))  # per-clip .rrd only with --rrd
    # a re-run measures nothing again; the cut file still fails
    again = run_in_process("analysis", *args, "--fps", "25", "--jobs", "2", "--out", str(out))
    assert again.returncode == 1 and "3 of 4 source(s) already measured" in again.stderr


def test_bad_collections_are_one_line(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no video here")
    proc = run_in_process("analysis", "complexity", str(empty), "--out", str(tmp_path / "o"))
    assert_one_line_error(proc, "holds no videos")
    proc = run_in_process("analysis", "complexity", str(tmp_path / "x_%05d.png"), "--fps", "25")
    assert_one_line_error(proc, "matches no files")
    single = tmp_path / "bad.mp4"
    single.write_bytes(b"\x00" * 5000)
    proc = run_in_process("analysis", "complexity", str(single), "--fov-deg", "70")
    assert_one_line_error(proc, "cannot read")


def test_names_come_from_the_file_not_the_pattern() -> None:
    assert source_name("shots/take1/img_%05d.png") == "take1-img"
    assert source_name("clips/Walk in the park.MP4") == "Walk_in_the_park"
    assert source_name("frames/%05d.png") == "frames"


def test_a_folder_without_its_field_of_view_gives_the_pixel_metrics(coded, tmp_path: Path) -> None:
    """No --fov-deg: the pixel metrics of every clip, the angular ones left out with one note
    before any decoding; asking only for angular ones of videos is one line, exit 2."""
    folder = tmp_path / "footage"
    folder.mkdir()
    for r, p in coded.items():
        (folder / f"{r}.mp4").write_bytes(p.read_bytes())
    notes: list[str] = []
    res = complexity([folder], ComplexitySettings(), tmp_path / "o", notice=notes.append)
    assert len(notes) == 1 and "omega_dps, flow_dps left out for the 2 video" in notes[0]
    assert res.table.height == 48 and not res.failures
    assert {"si_p910", "ti_p910", "mafd", "codec_bpp"} <= set(res.table.columns)
    assert "omega_dps" not in res.table.columns and "flow_dps" not in res.table.columns
    assert res.clips["si_p910_mean"].min() > 0
    out = tmp_path / "o2"
    proc = run_in_process(
        "analysis", "complexity", str(folder), "--metrics", "omega_dps", "--out", str(out)
    )
    assert_one_line_error(proc, "--fov-deg")
    assert not out.exists()  # refused before anything was decoded or written
    proc = run_in_process("analysis", "complexity", str(folder), "--metrics", "si_p910,nope")
    assert_one_line_error(proc, "unknown nope")
    reader = open_reader(str(coded["full"]))
    assert reader.info["color_range"] == "full" and reader.info["bit_depth"] == 8
    reader.close()


def test_repeats_are_judged_on_native_frames_not_on_the_thumbnail(tmp_path: Path) -> None:
    """Real slow motion (a photograph panned 0.15 px per frame at 640 px: a mean |difference|
    of ~0.8 levels) with 5 frames truly shown twice: the native frames find exactly those 5;
    on the 91-px working raster the same motion differs by ~0.4 levels, under the 0.5-level
    tolerance, and most frames would be called repeats."""
    from avdm.stimuli import panned_image
    from avdm.true_time import repeat_flags
    from vdc.frame_batches import FrameBatcher

    photo = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY).astype(np.float64)
    fov, width, fps = 64.0, 640, 25.0
    deg_per_px = fov / width
    frames = panned_image(
        np.tile(photo, (1, 4)),
        size=(360, width),
        fov_deg=fov,
        image_deg=300.0,
        fps=fps,
        omega_dps=0.15 * deg_per_px * fps,
        n_frames=55,
    )
    doubled = sorted((7, 15, 23, 31, 39))
    shown = np.concatenate(
        [np.repeat(f[None], 2 if i in doubled else 1, 0) for i, f in enumerate(frames)]
    )
    path = tmp_path / "slow.mp4"
    out = av.open(str(path), "w")
    st = out.add_stream("libx264", rate=int(fps))
    st.width, st.height, st.pix_fmt = width, 360, "yuv420p"
    st.options = {"crf": "10", "bf": "0"}
    for f in shown:
        for p in st.encode(av.VideoFrame.from_ndarray(f, format="gray")):
            out.mux(p)
    for p in st.encode():
        out.mux(p)
    out.close()
    reader = open_reader(str(path))
    batcher = FrameBatcher(reader, (51, 91), fps)  # the working raster of a 64° camera
    thumbs, native_flags = [], []
    while (fb := batcher.next_batch()) is not None:
        thumbs.append(fb.images)
        native_flags.append(fb.repeat)
    reader.close()
    flags = np.concatenate(native_flags)
    expected = np.zeros(len(shown), bool)
    expected[[i + k + 1 for k, i in enumerate(doubled)]] = True  # the second showing of each
    assert flags.tolist() == expected.tolist()
    assert batcher.repeats_total == 5
    on_thumbnails = repeat_flags(np.concatenate(thumbs))
    assert on_thumbnails.sum() > 20  # the old judgement: slow real motion read as repeats

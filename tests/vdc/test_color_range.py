"""SI/TI in the colour range each reference tool reads (issue #31 §2), on real files the tests
encode: limited and full range, tagged and untagged, with super-whites. The P.910 columns
equal siti-tools' ``calculate()`` in the one range siti-tools accepts (it refuses limited on
luma outside 16..235); the legacy columns equal FFmpeg's ``siti`` filter, which takes an
untagged stream as limited; ``clips.parquet`` names the range and how it was decided."""

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

from tests.helpers import SITI_TOOLS_PRINTED_ATOL, assert_one_line_error, ffmpeg_siti
from tests.in_process import run_in_process
from vdc.frame_batches import FrameBatcher
from vdc.frame_metrics import decide_ranges
from vdc.recording import NATIVE_METRICS
from vdc.sources import open_reader

W, H = 384, 240  # a width whose Y plane has no padding, which siti-tools' reader needs
SITI = {"limited": ColorRange.LIMITED, "full": ColorRange.FULL}
# AVColorRange codes: 1 limited (MPEG), 2 full (JPEG), None: left unspecified
CASES = {
    "limited-tagged": (1, 20, 230),
    "full-tagged": (2, 0, 255),
    "untagged-super-whites": (None, 44, 246),  # the real clips of the issue: luma 44-246
    "untagged-inside-limited": (None, 20, 230),
}
EXPECTED = {  # (P.910 range, its source, legacy range, its source)
    "limited-tagged": ("limited", "tagged", "limited", "tagged"),
    "full-tagged": ("full", "tagged", "full", "tagged"),
    "untagged-super-whites": ("full", "detected", "limited", "assumed"),
    "untagged-inside-limited": ("limited", "detected", "limited", "assumed"),
}


def encode_luma(path: Path, levels: list[tuple[int, int]], tag: int | None, fps: int = 25) -> Path:
    """A real photograph (scikit-image's astronaut, grey) panned 6 px per frame, its Y plane
    written directly with frame i's levels spanning ``levels[i]`` (lo, hi) code values, then
    H.264 lossless (qp 0: the decoder returns these codes exactly). ``tag``: the colour range
    the stream declares (x264 writes it only with the other colour fields set)."""
    img = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY).astype(np.float64) / 255
    pano = cv2.resize(img, (W * 3, H), interpolation=cv2.INTER_AREA)
    out = av.open(str(path), "w")
    st = out.add_stream("libx264", rate=fps)
    st.width, st.height, st.pix_fmt = W, H, "yuv420p"
    st.options = {"qp": "0", "preset": "ultrafast"}
    if tag is not None:
        cc = st.codec_context
        cc.color_range, cc.colorspace, cc.color_primaries, cc.color_trc = tag, 1, 1, 1
    for i, (lo, hi) in enumerate(levels):
        x = (6 * i) % (2 * W)
        view = pano[:, x : x + W]
        view = (view - view.min()) / (view.max() - view.min())
        y = np.rint(lo + view * (hi - lo)).astype(np.uint8)
        frame = av.VideoFrame(W, H, "yuv420p")
        frame.planes[0].update(y.tobytes())
        for plane in frame.planes[1:]:
            plane.update(bytes([128]) * plane.buffer_size)
        if tag is not None:
            frame.color_range = tag
        for p in st.encode(frame):
            out.mux(p)
    for p in st.encode():
        out.mux(p)
    out.close()
    return path


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("ranges")
    return {
        name: encode_luma(d / f"{name}.mp4", [(lo, hi)] * 8, tag)
        for name, (tag, lo, hi) in CASES.items()
    }


def native_metrics(path: Path, batch_frames: int = 128, color_range: str = "auto"):
    """Every frame's native metrics as ``vdc-analyse complexity`` reads them (late P.910
    corrections applied), and the ranges the batcher decided."""
    reader = open_reader(str(path))
    try:
        batcher = FrameBatcher(
            reader, (62, 99), 25.0, batch_frames=batch_frames, color_range=color_range
        )
        rows = []
        while (fb := batcher.next_batch()) is not None:
            rows.append(fb.native_metrics)
        rows = np.concatenate(rows)
        fix = batcher.p910_late_corrections()
        rows[: len(fix), NATIVE_METRICS.index("si_p910")] = fix[:, 0]
        rows[: len(fix), NATIVE_METRICS.index("ti_p910")] = fix[:, 1]
        return {m: rows[:, k] for k, m in enumerate(NATIVE_METRICS)}, batcher.color_ranges()
    finally:
        reader.close()


def siti_tools(path: Path, color_range: str) -> tuple[list[float], list[float]]:
    si, ti, _ = SiTiCalculator(color_range=SITI[color_range]).calculate(str(path))
    return si, ti


def assert_equal_to_references(ours: dict, path: Path, p910: str, legacy_force=None) -> None:
    si, ti = siti_tools(path, p910)
    # to the precision siti-tools prints (3 decimals): vdc's float32 against its float64
    # (tests.helpers.SITI_TOOLS_PRINTED_ATOL says why)
    tol = {"rtol": 0, "atol": SITI_TOOLS_PRINTED_ATOL}
    np.testing.assert_allclose(ours["si_p910"], si, **tol)
    np.testing.assert_allclose(ours["ti_p910"][1:], ti, **tol)
    oracle = ffmpeg_siti(path, legacy_force)
    # FFmpeg prints 2 decimals: equal within that rounding (0.005) plus float noise
    np.testing.assert_allclose(ours["si_legacy"], oracle[:, 0], atol=0.0051)
    np.testing.assert_allclose(ours["ti_legacy"][1:], oracle[1:, 1], atol=0.0051)


@pytest.mark.parametrize("case", list(CASES))
def test_each_variant_reads_the_range_its_reference_tool_reads(clips, case: str) -> None:
    path = clips[case]
    ours, ranges = native_metrics(path)
    p910, p910_src, legacy, legacy_src = EXPECTED[case]
    assert ranges == {
        "color_range_p910": p910,
        "color_range_p910_source": p910_src,
        "color_range_legacy": legacy,
        "color_range_legacy_source": legacy_src,
    }
    assert_equal_to_references(ours, path, p910)
    lo, hi = CASES[case][1:]
    if lo < 16 or hi > 235:  # siti-tools refuses limited range on this luma
        with pytest.raises(RuntimeError, match="appears to be full range"):
            siti_tools(path, "limited")


def test_super_whites_read_as_limited_would_be_a_fifth_higher(clips) -> None:
    """The issue's finding: an untagged clip with luma 44..246 read as limited (clipped and
    stretched) gives P.910 SI/TI well above siti-tools' full-range values: what the range
    decision prevents."""
    path = clips["untagged-super-whites"]
    auto, _ = native_metrics(path)
    forced, ranges = native_metrics(path, color_range="limited")
    assert ranges["color_range_p910_source"] == ranges["color_range_legacy_source"] == "user"
    assert np.mean(forced["si_p910"]) > 1.1 * np.mean(auto["si_p910"])
    # legacy is unchanged: FFmpeg reads this stream as limited either way
    np.testing.assert_array_equal(forced["si_legacy"], auto["si_legacy"])


def test_a_late_excursion_corrects_earlier_batches(tmp_path: Path) -> None:
    """Untagged, inside 16..235 for 10 frames, then super-whites: siti-tools refuses limited
    at frame 10, so every frame is read in full, including the 8 returned (two batches of 4)
    before the excursion was seen, and the 2 of the batch it lands in."""
    levels = [(20, 230)] * 10 + [(44, 246)] * 3
    path = encode_luma(tmp_path / "late.mp4", levels, None)
    ours, ranges = native_metrics(path, batch_frames=4)
    assert ranges["color_range_p910"] == "full" and ranges["color_range_legacy"] == "limited"
    assert_equal_to_references(ours, path, "full")


def test_the_command_names_the_ranges_and_takes_color_range(tmp_path: Path) -> None:
    """``vdc-analyse complexity`` on an untagged clip whose luma leaves 16..235 only at its
    130th frame (after the first batch of 128): clips.parquet names each variant's range and
    its source; every frame's P.910 equals siti-tools in full range; a bad ``--color-range``
    is one line, exit 2. The faithful AVDM at 33 fps and the robot's pitch: a shipped
    calibration, no fit."""
    levels = [(20, 230)] * 130 + [(44, 246)] * 4
    path = encode_luma(tmp_path / "late.mp4", levels, None, fps=33)
    args = ("complexity", str(path), "--fov-deg", "70", "--model", "avdm", "--metrics", "all")
    proc = run_in_process("analysis", *args, "--out", str(tmp_path / "auto"))
    assert proc.returncode == 0, proc.stderr
    clip = pl.read_parquet(tmp_path / "auto" / "clips.parquet").row(0, named=True)
    assert clip["color_range_p910"] == "full" and clip["color_range_p910_source"] == "detected"
    assert clip["color_range_legacy"] == "limited"
    assert clip["color_range_legacy_source"] == "assumed"
    table = pl.read_parquet(tmp_path / "auto" / "complexity.parquet")
    ours = {m: table[m].fill_null(np.nan).to_numpy() for m in NATIVE_METRICS}
    assert_equal_to_references(ours, path, "full")

    proc = run_in_process("analysis", *args, "--color-range", "pc", "--out", str(tmp_path / "bad"))
    assert_one_line_error(proc, "--color-range")


def test_a_range_the_user_gives_wins_for_both_variants(clips) -> None:
    """``--color-range full`` on an untagged clip inside 16..235: P.910 as siti-tools in full
    range, legacy as FFmpeg after ``setparams=range=pc``; both named as the user's."""
    path = clips["untagged-inside-limited"]
    ours, ranges = native_metrics(path, color_range="full")
    assert ranges == {
        "color_range_p910": "full",
        "color_range_p910_source": "user",
        "color_range_legacy": "full",
        "color_range_legacy_source": "user",
    }
    assert_equal_to_references(ours, path, "full", legacy_force="full")


def test_the_decision_rules() -> None:
    """The table of docs/guides/video.md, case by case."""
    assert decide_ranges("limited", "auto", True)["color_range_p910"] == "limited"  # tag wins
    assert decide_ranges(None, "auto", None)["color_range_p910"] is None  # not seen yet
    assert decide_ranges(None, "full", False)["color_range_legacy"] == "full"
    with pytest.raises(ValueError, match="colour range"):
        decide_ranges(None, "tv")

"""Video deeper than 8 bits is read at its own depth (issue 56): a 16-bit stream's code values,
never its bytes, through P.910's range for that depth; a deep format whose luma is not a plane
of its own is refused in one line. Real files the tests encode losslessly with FFV1 (the code
values written are the code values decoded), checked against siti-tools' own ``calculate()``
at 10 and 12 bits and against its arithmetic at 16 bits (which its reader does not take)."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pytest
import siti_tools.siti
from siti_tools.siti import ColorRange, SiTiCalculator

from tests.helpers import SITI_TOOLS_PRINTED_ATOL, assert_one_line_error
from tests.in_process import run_in_process
from vdc.frame_batches import FrameBatcher
from vdc.recording import NATIVE_METRICS
from vdc.sources import open_reader

# 384 px wide: a Y plane without padding at 8 and 16 bits, which siti-tools' reader needs
W, H, N_FRAMES, FPS = 384, 64, 6, 25
SI, TI = NATIVE_METRICS.index("si_p910"), NATIVE_METRICS.index("ti_p910")


def grating(i: int) -> np.ndarray:
    """(H, W) float in [0.1, 0.9]: a sine grating of 16 px drifting 2 px per frame."""
    x = np.arange(W)
    return np.broadcast_to(0.5 + 0.4 * np.sin(2 * np.pi * (x + 2 * i) / 16), (H, W))


def photo(i: int) -> np.ndarray:
    """(H, W) float in [0, 1]: a strip of a real photograph (scikit-image's astronaut, grey)
    panning 5 px per frame: the texture and edges of real footage, not a pure tone."""
    from skimage import data

    grey = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)[200:328].astype(np.float64) / 255
    strip = cv2.resize(grey, (2 * W, H), interpolation=cv2.INTER_AREA)
    return strip[:, 5 * i : 5 * i + W]


def codes(i: int, bits: int, color_range: str, picture=grating) -> np.ndarray:
    """Frame ``i``'s luma as code values at ``bits`` in ``color_range``."""
    g = picture(i)
    scale = 2 ** (bits - 8)
    if color_range == "limited":
        return np.rint((16 + 219 * g) * scale).astype(np.uint16)
    return np.rint(g * (2**bits - 1)).astype(np.uint16)


def write_ffv1(path: Path, pix_fmt: str, bits: int, color_range: str, picture=grating) -> Path:
    """FFV1 (lossless) in Matroska: the ``picture``'s code values at ``bits`` in its luma,
    mid-grey chroma, the range tagged."""
    with av.open(str(path), "w") as out:
        stream = out.add_stream("ffv1", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = W, H, pix_fmt
        stream.codec_context.color_range = 2 if color_range == "full" else 1
        for i in range(N_FRAMES):
            frame = av.VideoFrame(W, H, pix_fmt)
            itemsize = 1 if bits == 8 else 2
            dtype = np.uint8 if bits == 8 else np.dtype("<u2")
            for k, plane in enumerate(frame.planes):
                rows = plane.buffer_size // plane.line_size
                buf = np.zeros((rows, plane.line_size // itemsize), dtype)
                if k == 0:  # the luma
                    buf[:H, :W] = codes(i, bits, color_range, picture)
                else:  # grey: chroma at its middle (G and B share the luma in gbrp)
                    grey = codes(i, bits, color_range, picture)
                    buf[:] = grey if "gbr" in pix_fmt else 2 ** (bits - 1)
                plane.update(buf.tobytes())
            frame.pts = i
            frame.color_range = 2 if color_range == "full" else 1
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def read(path: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    """The clip as every command reads it: its reader's info, the native metrics and the
    working-raster grey the models see."""
    reader = open_reader(str(path))
    try:
        batch = FrameBatcher(reader, (H // 4, W // 4), FPS, batch_frames=64).next_batch()
        assert batch is not None
        return reader.info, batch.native_metrics, batch.images
    finally:
        reader.close()


@pytest.mark.parametrize(
    ("pix_fmt", "bits", "color_range", "picture"),
    [
        ("yuv420p10le", 10, "limited", grating),
        ("yuv444p12le", 12, "full", grating),
        # a real photograph at 10 bits in both ranges: float32 P.910 holds on real texture
        ("yuv420p10le", 10, "limited", photo),
        ("yuv420p10le", 10, "full", photo),
    ],
)
def test_10_and_12_bit_equal_siti_tools(
    tmp_path, pix_fmt: str, bits: int, color_range: str, picture
) -> None:
    path = write_ffv1(tmp_path / f"{pix_fmt}.mkv", pix_fmt, bits, color_range, picture)
    info, metrics, _ = read(path)
    assert (info["bit_depth"], info["color_range"]) == (bits, color_range)
    calc = SiTiCalculator(
        color_range=ColorRange.FULL if color_range == "full" else ColorRange.LIMITED,
        bit_depth=bits,
    )
    si, ti, n = calc.calculate(str(path))
    assert n == len(metrics) == N_FRAMES
    # to the precision siti-tools prints (3 decimals): vdc's float32 against its float64
    # (tests.helpers.SITI_TOOLS_PRINTED_ATOL says why)
    np.testing.assert_allclose(metrics[:, SI], si, rtol=0, atol=SITI_TOOLS_PRINTED_ATOL)
    np.testing.assert_allclose(metrics[1:, TI], ti, rtol=0, atol=SITI_TOOLS_PRINTED_ATOL)


def siti_tools_at(path: Path, bits: int, monkeypatch) -> tuple[list[float], list[float]]:
    """siti-tools' own P.910 pipeline (normalisation, BT.1886, PQ, Sobel) at ``bits`` in full
    range, on frames PyAV converts to arrays itself: siti-tools' reader takes YUV of 8, 10 and
    12 bits only, and its settings the same depths, so both are widened here."""

    def frames(p: str):
        with av.open(p) as c:
            for frame in c.decode(video=0):
                yield frame.to_ndarray().astype(np.int64)

    monkeypatch.setattr(siti_tools.siti, "read_container", frames)
    calc = SiTiCalculator(color_range=ColorRange.FULL)
    calc.bit_depth = bits  # full range: normalised by 2^bits - 1
    si, ti, _ = calc.calculate(str(path))
    return si, ti


def test_16_bit_is_read_at_16_bits_not_as_bytes(tmp_path, monkeypatch) -> None:
    """The issue's grating: SI 18.5 at 16 bits against 37.3 at 8, its bytes read as pixels."""
    deep = write_ffv1(tmp_path / "g16.mkv", "gray16le", 16, "full")
    info, metrics, images = read(deep)
    assert info["bit_depth"] == 16
    si, ti = siti_tools_at(deep, 16, monkeypatch)
    np.testing.assert_allclose(metrics[:, SI], si, rtol=0, atol=SITI_TOOLS_PRINTED_ATOL)
    np.testing.assert_allclose(metrics[1:, TI], ti, rtol=0, atol=SITI_TOOLS_PRINTED_ATOL)
    # the same picture at 8 bits: the same SI but for 8-bit rounding (measured 0.7 % apart;
    # reading the bytes of the 16-bit samples as pixels gave +60 %)
    _, metrics8, images8 = read(write_ffv1(tmp_path / "g8.mkv", "gray", 8, "full"))
    np.testing.assert_allclose(metrics[:, SI], metrics8[:, SI], rtol=0.02)
    # the models see the same frames on their 8-bit scale: within a level of rounding
    assert np.abs(images.astype(int) - images8.astype(int)).max() <= 1


def test_a_16_bit_image_sequence_is_read_at_16_bits(tmp_path, monkeypatch) -> None:
    """16-bit PNGs: their 16 bits measured (the same values as the 16-bit video of the same
    codes), and their grey scaled to 8 bits for the models, rounded, not their top byte."""
    shots = tmp_path / "shots"
    shots.mkdir()
    for i in range(N_FRAMES):
        cv2.imwrite(str(shots / f"f_{i:03d}.png"), codes(i, 16, "full"))
    reader = open_reader(str(shots / "f_%03d.png"), FPS)
    try:
        assert reader.info["bit_depth"] == 16
        batch = FrameBatcher(reader, None, FPS).next_batch()
        first = next(iter(open_reader(str(shots / "f_%03d.png"), FPS).frames()))
    finally:
        reader.close()
    deep = write_ffv1(tmp_path / "g16.mkv", "gray16le", 16, "full")
    _, video, _ = read(deep)
    np.testing.assert_array_equal(batch.native_metrics[:, SI], video[:, SI])
    expected = np.rint(codes(0, 16, "full").astype(np.float64) * 255 / 65535).astype(np.uint8)
    np.testing.assert_array_equal(first.luma, expected)


def test_a_deep_format_without_a_luma_plane_is_refused_in_one_line(tmp_path) -> None:
    """10-bit planar RGB: its first plane is green, not luma; read as luma it was misread."""
    rgb = write_ffv1(tmp_path / "rgb10.mkv", "gbrp10le", 10, "full")
    with av.open(str(rgb)) as c:
        assert next(c.decode(video=0)).format.name == "gbrp10le"
    out = str(tmp_path / "o")
    proc = run_in_process("analysis", "complexity", str(rgb), "--fov-deg", "70", "--out", out)
    assert_one_line_error(proc, "rgb10.mkv", "gbrp10le")

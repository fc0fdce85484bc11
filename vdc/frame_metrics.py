"""Per-frame complexity metrics on a source's native luma, as their standards define them.

* ``si_p910`` / ``ti_p910``: ITU-T P.910 (07/2022 and later) SI and TI, as its reference
  implementation siti-tools computes them: the luma code values of the stream's bit depth and
  colour range normalised to [0, 1], through the BT.1886 display model (gamma 2.4, 0.1 to
  300 cd/m²) and the PQ curve, then ×255; SI is the population standard deviation of the
  Sobel magnitude over the interior (H−2)×(W−2), TI that of the frame difference;
* ``si_legacy`` / ``ti_legacy``: the definition before 2022 on code values, as FFmpeg's
  ``siti`` filter computes it (limited range stretched to full with FFmpeg's integer
  arithmetic; 10-bit values kept on their 10-bit scale, as the filter does, and deeper
  ones, which the filter does not take, on theirs likewise);
* ``mafd``: mean absolute difference from the previous frame, in 8-bit levels;
* ``edge_density``: share of Canny edge pixels (thresholds 100/200 on 8-bit luma);
* ``jpeg_bpp``: bits per pixel of the frame as a JPEG at quality 75 (OpenCV);
* ``codec_bpp``: bits per pixel the source's own codec spent on the frame (its packet), where
  the source has packets.

A stream is read at its own bit depth (8 to 16: a 16-bit stream's code values, never its bytes;
P.910's ranges scale with the depth as siti-tools scales them for 10 and 12 bits). Temporal
metrics are null on a source's first frame. Each SI/TI variant reads the colour
range as its reference tool does (:func:`decide_ranges`): a range the stream tags (or a
``yuvj`` format) is used by both; where the stream leaves it unspecified, the legacy variant
takes limited (FFmpeg's ``siti``), and the P.910 variant takes full if any frame's luma
leaves the limited range (below 16 or above 235 at 8 bits: siti-tools refuses limited range
on such input, "Input appears to be full range"), else limited. A range the user gives wins
for both. One fused Numba pass (``vdc.siti_kernel``)
reads each pixel once for both SI/TI variants and the MAFD: the display and PQ curves are a
lookup table over the 2^B code values (siti-tools' float64 arithmetic, evaluated once per
code value instead of once per pixel). P.910's table and its sums are then float32: within
about 1e-8 relative of siti-tools' values, far inside the three decimals it prints.

:meth:`NativeMeter.measure` (a frame against the frame before it: any thread, any order) and
:meth:`NativeMeter.finish` (in frame order) let one clip's frames be measured side by side on
several cores, with the same bits as :meth:`NativeMeter.update` frame after frame.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable
from typing import Any

import cv2
import numpy as np

from vdc.errors import UserError
from vdc.recording import NATIVE_METRICS
from vdc.siti_kernel import chosen_sums

# the smallest frame side the native metrics take: SI's 3x3 Sobel filter (P.910) needs an
# interior pixel, which a frame of 2 px or less on a side does not have
MIN_SIDE_PX = 3


def require_frame_size(reader: Any, source: str) -> None:
    """UserError, in one line naming ``source`` and the size needed, when the frames of
    ``reader`` (a ``vdc.sources.Reader``: its ``info`` sizes) are smaller than the native
    metrics take; the reader is closed first."""
    h, w = reader.info["src_height_px"], reader.info["src_width_px"]
    if min(h, w) < MIN_SIDE_PX:
        reader.close()
        raise UserError(
            f"{source!r} is {w}x{h} px (WxH): its frames must be at least {MIN_SIDE_PX}x"
            f"{MIN_SIDE_PX} px (the SI/TI metrics' 3x3 Sobel filter needs an interior pixel)."
        )


# the luma depths read (vdc.frame_metrics.stream_format): siti-tools takes 8, 10 and 12; the
# P.910 ranges scale the same way to the others (limited 16..235 x 2^(B-8), full 0..2^B-1)
BIT_DEPTHS = tuple(range(8, 17))
RANGES = ("limited", "full")
RANGE_CHOICES = ("auto", *RANGES)  # --color-range
# how a variant's range was decided: the stream's tag, detected from the luma (P.910 in an
# untagged stream), assumed as FFmpeg does (legacy in an untagged stream: limited), or given
RANGE_SOURCES = ("tagged", "detected", "assumed", "user")
# clips.parquet: the colour range each SI/TI variant read and how it was decided
RANGE_COLUMNS = (
    "color_range_p910",
    "color_range_p910_source",
    "color_range_legacy",
    "color_range_legacy_source",
)

# P.910 (2022) display model and PQ, as siti-tools' defaults (BT.1886, SDR)
GAMMA, L_MAX, L_MIN = 2.4, 300.0, 0.1
PQ_M1, PQ_M2 = 0.1593017578125, 78.84375
PQ_C1, PQ_C2, PQ_C3 = 0.8359375, 18.8515625, 18.6875


def leaves_limited(y: np.ndarray, bit_depth: int) -> bool:
    """Whether luma ``y`` (code values at ``bit_depth``) has a value outside the limited range
    (16..235 scaled to the bit depth): siti-tools' test, frame by frame, before it refuses
    limited range ("Input appears to be full range ... Specify the range as full instead")."""
    scale = 2 ** (bit_depth - 8)
    lo, hi = float(y.min()), float(y.max())  # numpy's SIMD reductions: ~0.1 ms at 720p
    return lo < 16 * scale or hi > 235 * scale


def decide_ranges(
    tagged: str | None, requested: str = "auto", leaves_limited_range: bool | None = None
) -> dict[str, str | None]:
    """The colour range each SI/TI variant reads, and how it was decided.

    ``tagged``: the range the stream declares (``limited``, ``full``; None: unspecified);
    ``requested``: ``--color-range`` (``auto``, ``limited``, ``full``);
    ``leaves_limited_range``: whether any frame's luma left the limited range (None: not
    known yet). Returns ``color_range_p910``, ``color_range_p910_source``,
    ``color_range_legacy``, ``color_range_legacy_source`` (sources: :data:`RANGE_SOURCES`);
    the P.910 range is None while an untagged stream's luma is not fully seen.

    * user: the requested range for both variants (FFmpeg after ``setparams=range=...``;
      siti-tools' ``--color-range``);
    * tagged: the tag for both;
    * unspecified: legacy limited (FFmpeg's ``siti``: an unspecified range is limited unless
      the format is ``yuvj``); P.910 full when the luma leaves the limited range (the only
      range siti-tools then accepts), else limited (siti-tools' default)."""
    if requested not in RANGE_CHOICES:
        raise UserError(
            f"colour range must be one of {', '.join(RANGE_CHOICES)}, got {requested!r}."
        )
    if tagged not in (None, *RANGES):
        raise UserError(f"a stream's colour range is limited, full or None, got {tagged!r}.")
    if requested != "auto":
        return {
            "color_range_p910": requested,
            "color_range_p910_source": "user",
            "color_range_legacy": requested,
            "color_range_legacy_source": "user",
        }
    if tagged is not None:
        return {
            "color_range_p910": tagged,
            "color_range_p910_source": "tagged",
            "color_range_legacy": tagged,
            "color_range_legacy_source": "tagged",
        }
    p910 = None if leaves_limited_range is None else "full" if leaves_limited_range else "limited"
    return {
        "color_range_p910": p910,
        "color_range_p910_source": "detected",
        "color_range_legacy": "limited",
        "color_range_legacy_source": "assumed",
    }


def p910_lut(bit_depth: int, color_range: str) -> np.ndarray:
    """(2^B,) float64: each code value through P.910's chain, ×255 (the SI/TI scale). Codes
    outside the limited range are clipped to it (siti-tools refuses such frames)."""
    codes = np.arange(2**bit_depth, dtype=np.float64)
    scale = 2 ** (bit_depth - 8)
    if color_range == "limited":
        y = (np.clip(codes, 16 * scale, 235 * scale) - 16 * scale) / (219 * scale)
    else:
        y = codes / (2**bit_depth - 1)
    light = (L_MAX - L_MIN) * np.power(y, GAMMA) + L_MIN
    p = np.power(light / 10000.0, PQ_M1)
    v = np.power((PQ_C1 + PQ_C2 * p) / (1.0 + PQ_C3 * p), PQ_M2)
    return v * 255.0


def legacy_lut(bit_depth: int, color_range: str) -> np.ndarray:
    """(2^B,) float64: FFmpeg ``siti``'s code values (limited range to full, integer floor)."""
    codes = np.arange(2**bit_depth, dtype=np.int64)
    if color_range != "limited":
        return codes.astype(np.float64)
    scale = 2 ** (bit_depth - 8)
    top = (2**bit_depth - 1) if bit_depth > 8 else 255
    full = (top * np.clip(codes - 16 * scale, 0, 219 * scale)) // (219 * scale)
    return full.astype(np.float64)


def _every_code(lut: np.ndarray) -> np.ndarray:
    """A lookup table over 2^B codes extended to every code its frames' type holds (2^16
    for a deep stream), the top code's value repeated: a damaged 10-bit frame with a code
    past 1023 reads the top value, never memory past the table (the kernels do not check)."""
    size = 256 if len(lut) <= 256 else 65536
    return np.concatenate((lut, np.full(size - len(lut), lut[-1])))


def p910_table(bit_depth: int, color_range: str) -> np.ndarray:
    """:func:`p910_lut` over every code the frames' type holds (:func:`_every_code`), in
    float32: the P.910 kernel computes in 32-bit floats (the table, the Sobel, its square
    root and each column's sums over a block of rows; then float64: ``vdc.siti_kernel``).
    That keeps SI and TI within
    about 1e-8 relative of siti-tools' float64 values on real clips (the tests hold them to
    the 3 decimals siti-tools prints), at about half the float64 kernel's cost."""
    return _every_code(p910_lut(bit_depth, color_range)).astype(np.float32)


def _std(s: float, ss: float, n: float) -> float:
    """Population standard deviation from Σx and Σx² (float64; the mean is small beside the
    spread here, so no cancellation worth a second pass)."""
    mean = s / n
    return math.sqrt(max(ss / n - mean * mean, 0.0))


@dataclasses.dataclass
class NativeMeter:
    """Streams native luma frames through :data:`NATIVE_METRICS`.

    ``bit_depth`` 8 (uint8 frames) or 9 to 16 (uint16: the code values at that depth);
    ``color_range`` ``limited`` or ``full``: the legacy variant's (and the P.910 variant's
    unless ``p910_range`` says otherwise); ``p910_range`` ``limited``, ``full``, None
    (= ``color_range``) or ``detect`` (an untagged stream with ``--color-range auto``:
    limited until a frame's luma leaves the limited range, full from that frame on, as
    siti-tools accepts it; :meth:`p910_corrections` then gives the earlier frames' values in
    full range). While detecting, each frame's full-range values are computed beside (a
    second SI/TI pass) unless ``full_alternative`` is False: then a caller that can read the
    source again gives them once a frame leaves the limited range
    (:meth:`set_full_alternative`; ``vdc.frame_batches.FrameBatcher`` does
    for files). ``update(y, packet_bytes)`` takes
    one frame (H, W) and the size of its packet in the source (None: no ``codec_bpp``) and
    returns its metrics (temporal ones NaN on the first frame). Only the names in ``metrics``
    are computed (the others are NaN); the MAFD always is (repeats are judged on it), and a
    metric's value is the same bits whichever others are computed beside it."""

    bit_depth: int = 8
    color_range: str = "limited"
    jpeg_quality: int = 75
    metrics: tuple[str, ...] = NATIVE_METRICS
    p910_range: str | None = None
    full_alternative: bool = True
    # False: the caller's frames stay unchanged while referenced (PyAV's frames are reference
    # counted: a decoder reuses a buffer only once no one holds it), so the previous frame is
    # kept as given instead of copied (0.1 ms per 720p frame)
    copy_previous: bool = True

    def __post_init__(self) -> None:
        if self.bit_depth not in BIT_DEPTHS:
            raise UserError(f"bit depth must be 8 to 16, got {self.bit_depth}.")
        if self.color_range not in RANGES:
            raise UserError(f"colour range must be limited or full, got {self.color_range!r}.")
        if self.p910_range not in (None, "detect", *RANGES):
            raise UserError(
                f"P.910 range must be limited, full or detect, got {self.p910_range!r}."
            )
        self._detect = self.p910_range == "detect"
        # the P.910 range in use: while detecting, limited until the luma leaves it
        self.p910_now = "limited" if self._detect else (self.p910_range or self.color_range)
        self._p910 = p910_table(self.bit_depth, self.p910_now)
        self._p910_full = p910_table(self.bit_depth, "full") if self._detect else None
        self._legacy = _every_code(legacy_lut(self.bit_depth, self.color_range))
        unknown = set(self.metrics) - set(NATIVE_METRICS)
        if unknown:
            raise UserError(f"not native metrics: {', '.join(sorted(unknown))}")
        self._want_p910 = bool({"si_p910", "ti_p910"} & set(self.metrics))
        self._want_legacy = bool({"si_legacy", "ti_legacy"} & set(self.metrics))
        self._prev: np.ndarray | None = None
        self._mafd_scale = 1.0 / 2 ** (self.bit_depth - 8)  # to 8-bit levels
        self.frames_seen = 0
        self.left_limited_at: int | None = None  # detect: the first frame outside it
        self._full_alt: list[tuple[float, float]] = []  # detect: (si, ti) in full range

    @property
    def left_limited_range(self) -> bool | None:
        """Detecting: whether a frame so far left the limited range; else None."""
        return (self.left_limited_at is not None) if self._detect else None

    @property
    def lacks_full_alternative(self) -> bool:
        """Whether a frame left the limited range and the full-range values of the frames
        before it are still to be given (:meth:`set_full_alternative`)."""
        k = self.left_limited_at
        return bool(k) and len(self._full_alt) < k

    def set_full_alternative(self, values: np.ndarray) -> None:
        """(K, 2) ``si_p910``, ``ti_p910`` in full range of the first K = ``left_limited_at``
        frames, computed elsewhere (``full_alternative`` False: a second reading of the
        source through a meter in full range gives the same bits)."""
        k = self.left_limited_at
        if k is None or len(values) != k:
            raise UserError(f"expected the full-range values of {k} frames, got {len(values)}.")
        self._full_alt = [(float(a), float(b)) for a, b in values]

    def p910_corrections(self) -> np.ndarray:
        """(K, 2) float64: ``si_p910``, ``ti_p910`` in full range of the first K frames,
        which were given in limited range before frame K left it (K = 0: none to correct)."""
        if self.left_limited_at is None:
            return np.zeros((0, 2))
        if len(self._full_alt) < self.left_limited_at:
            raise RuntimeError("full-range values of the frames before the excursion not given")
        return np.array(self._full_alt[: self.left_limited_at], dtype=np.float64).reshape(-1, 2)

    def row(self, y: np.ndarray, packet_bytes: int | None = None) -> np.ndarray:
        """:meth:`update` as a (len(NATIVE_METRICS),) float64 row."""
        m = self.update(y, packet_bytes)
        return np.array([m[k] for k in NATIVE_METRICS])

    def update(self, y: np.ndarray, packet_bytes: int | None = None) -> dict[str, float]:
        """One frame after the last: :meth:`finish` of :meth:`measure` against the previous
        frame this meter kept."""
        prev = self._prev
        out = self.finish(self.measure(y, prev, packet_bytes))
        # another reader may reuse the buffer a frame views
        self._prev = y.copy() if self.copy_previous else y
        return out

    def measure(
        self, y: np.ndarray, prev: np.ndarray | None, packet_bytes: int | None = None
    ) -> FrameMeasure:
        """The work on one frame that depends only on it and the frame before it (``prev``;
        None for a source's first frame): the kernel's sums, Canny, the JPEG. Safe to call
        from several threads at once on different frames (the kernels release the GIL), in
        any order: :meth:`finish`, called in frame order, makes the values the same bits as
        :meth:`update` frame after frame (it measures a frame again where the range in use
        changed after this was called)."""
        want = np.uint8 if self.bit_depth == 8 else np.uint16
        if y.ndim != 2 or y.dtype != want or min(y.shape) < MIN_SIDE_PX:
            raise UserError(f"expected ({self.bit_depth}-bit) luma (H, W) {want.__name__}.")
        if prev is not None and prev.shape != y.shape:
            raise UserError(f"the frame size changed from {prev.shape} to {y.shape}.")
        lut = self._p910  # the range in use now (a later frame may change it: finish checks)
        detecting = self._want_p910 and self._detect and self.left_limited_at is None
        s = self._sums(y, prev, lut, detecting)
        alt = None
        if detecting and self.full_alternative:  # the full-range values, in case one leaves
            alt = self._full_sums(y, prev)
        n_all = float(y.size)
        edge = jpeg = math.nan
        if "edge_density" in self.metrics or "jpeg_bpp" in self.metrics:
            y8 = y if self.bit_depth == 8 else (y >> (self.bit_depth - 8)).astype(np.uint8)
            if "edge_density" in self.metrics:
                edge = float(np.count_nonzero(cv2.Canny(y8, 100, 200))) / n_all
            if "jpeg_bpp" in self.metrics:
                ok, jpg = cv2.imencode(".jpg", y8, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
                jpeg = 8.0 * len(jpg) / n_all if ok else math.nan
        codec = math.nan
        if "codec_bpp" in self.metrics and packet_bytes:
            codec = 8.0 * packet_bytes / n_all
        return FrameMeasure(y, prev, lut, detecting, s, alt, edge, jpeg, codec)

    def _sums(self, y: np.ndarray, prev: np.ndarray | None, lut: np.ndarray, scan: bool):
        have = prev is not None
        return chosen_sums(
            y,
            prev if have else y,
            lut,
            self._legacy,
            have,
            self._want_p910,
            self._want_legacy,
            scan,
        )

    def _full_sums(self, y: np.ndarray, prev: np.ndarray | None) -> tuple[float, float]:
        """(si, ti) of P.910 in full range (ti NaN without a previous frame)."""
        have = prev is not None
        # the same call as a meter in full range makes (types and all: another signature is
        # another compiled kernel, whose float32 sums may be grouped otherwise)
        a = chosen_sums(
            y, prev if have else y, self._p910_full, self._legacy, have, True, False, False
        )
        n_int, n_all = (y.shape[0] - 2) * (y.shape[1] - 2), float(y.size)
        return _std(a[0], a[1], n_int), _std(a[2], a[3], n_all) if have else math.nan

    def finish(self, m: FrameMeasure) -> dict[str, float]:
        """A frame's metrics from its :meth:`measure`, the frames in order (the range
        decision carries from frame to frame)."""
        y, prev = m.y, m.prev
        have = prev is not None
        want_a, want_b = self._want_p910, self._want_legacy
        n_int, n_all = (y.shape[0] - 2) * (y.shape[1] - 2), float(y.size)
        nan = math.nan
        detecting = want_a and self._detect and self.left_limited_at is None
        s = m.sums
        if detecting and not m.detecting:  # cannot happen: a range is never left again
            raise RuntimeError("a frame measured without its range scan")
        if m.lut is not self._p910:  # the range changed after it was measured: again
            s = self._sums(y, prev, self._p910, False)
        if detecting:
            scale = 2 ** (self.bit_depth - 8)
            if s[10] < 16 * scale or s[11] > 235 * scale:  # leaves_limited: full from here on,
                self.left_limited_at = self.frames_seen  # as siti-tools reads it
                self.p910_now = "full"
                self._p910 = self._p910_full
                s = self._sums(y, prev, self._p910, False)
            elif self.full_alternative:
                self._full_alt.append(m.full_alt or self._full_sums(y, prev))
        out = {
            "si_p910": _std(s[0], s[1], n_int) if want_a else nan,
            "ti_p910": _std(s[2], s[3], n_all) if have and want_a else nan,
            "si_legacy": _std(s[4], s[5], n_int) if want_b else nan,
            "ti_legacy": _std(s[6], s[7], n_all) if have and want_b else nan,
            "mafd": s[8] / n_all * self._mafd_scale if have else nan,
            "edge_density": m.edge_density,
            "jpeg_bpp": m.jpeg_bpp,
            "codec_bpp": m.codec_bpp,
        }
        self.frames_seen += 1
        return out


@dataclasses.dataclass
class FrameMeasure:
    """:meth:`NativeMeter.measure` of one frame: the frame and the one before it (None: the
    first), the P.910 table it was measured with, whether its range was scanned
    (``detecting``), the kernel's (12,) sums, the full-range (si, ti) while detecting (where
    the meter keeps them), and the metrics of the frame alone (NaN where not asked)."""

    y: np.ndarray
    prev: np.ndarray | None
    lut: np.ndarray
    detecting: bool
    sums: np.ndarray
    full_alt: tuple[float, float] | None
    edge_density: float
    jpeg_bpp: float
    codec_bpp: float


# the luma of these formats is one plane of 2-byte samples holding the code value in its low
# bits (planar YUV and grey, 9 to 16 bits, little- or big-endian): read at the stream's depth.
# Other deep formats (semi-planar p010/nv20, packed y210/xv30, deep RGB) keep their luma in
# a layout or colour space vdc does not read directly, and are refused rather than misread
_DEEP_PLANE = re.compile(r"^(?:yuva?j?\d{3}p|gray)(9|10|12|14|16)(le|be)$")
# 8-bit formats whose first plane is the luma, one byte per sample
_BYTE_PLANE = ("yuv", "gray", "nv12", "nv21", "nv16", "nv24", "nv42")


def stream_format(frame: Any) -> dict[str, Any]:
    """Bit depth and colour range a decoded PyAV video frame declares, and whether its luma
    can be read directly (a YUV or grey format).

    ``bit_depth``: the luma's own (8 to 16; a deep stream is never read as bytes);
    ``color_range_tag``: the range the frame tags (``full`` also for an untagged ``yuvj``
    format, as FFmpeg reads it, and for RGB, whose grey is full range), None where
    unspecified; ``color_range``: the range FFmpeg's ``siti`` reads (an unspecified one is
    limited, the MPEG default); ``luma``: False where the grey is converted from colour
    (8-bit RGB and packed formats, through FFmpeg's own conversion, at 8 bits). A deep format
    whose luma is not a plane of its own (p010, y210, 10-bit RGB, ...) raises UserError
    naming it."""
    name = frame.format.name
    depth = max(c.bits for c in frame.format.components if not c.is_alpha)
    deep = _DEEP_PLANE.match(name)
    if depth > 8 and not deep:
        raise UserError(
            f"pixel format {name} ({depth}-bit): vdc reads deep video as planar YUV or grey "
            "(yuv420p10le, gray16le, ...); convert it first, e.g. ffmpeg -i IN -pix_fmt "
            "yuv444p16le OUT.mkv."
        )
    planar = bool(deep) or (depth == 8 and name.startswith(_BYTE_PLANE))
    code = int(getattr(frame, "color_range", 0) or 0)  # AVColorRange: 1 MPEG, 2 JPEG
    tag = "full" if code == 2 else "limited" if code == 1 else None
    if tag is None and (name.startswith("yuvj") or not planar):
        tag = "full"
    return {
        "bit_depth": int(deep.group(1)) if deep else 8,
        "color_range": tag or "limited",
        "color_range_tag": tag,
        "luma": planar,
    }


def luma_plane(frame: Any, bit_depth: int) -> np.ndarray:
    """The Y plane of a decoded PyAV frame as (H, W) uint8/uint16 code values at
    ``bit_depth`` (:func:`stream_format`), honouring the line size (no copy for 8 bits, nor
    for a little-endian deep plane on a little-endian machine); the grey of a format with no
    Y plane (RGB, packed YUV; 8-bit) as FFmpeg converts it."""
    name = frame.format.name
    if bit_depth == 8 and not name.startswith(_BYTE_PLANE):
        return frame.to_ndarray(format="gray")
    plane = frame.planes[0]
    dtype = (
        np.dtype(np.uint8) if bit_depth == 8 else np.dtype(">u2" if name.endswith("be") else "<u2")
    )
    per_line = plane.line_size // dtype.itemsize
    rows = np.frombuffer(plane, dtype).reshape(-1, per_line)[: frame.height, : frame.width]
    return rows if dtype.isnative else rows.astype(np.uint16)


def full_range_p910(natives: Iterable[np.ndarray], bit_depth: int, frames: int) -> np.ndarray:
    """(``frames``, 2) float64 ``si_p910``, ``ti_p910`` in full range of the first ``frames``
    native luma planes of ``natives`` (a second reading of a source): the same bits as a
    detecting :class:`NativeMeter` computes beside its limited-range values. Fewer planes
    than ``frames`` raise ValueError."""
    meter = NativeMeter(bit_depth, "full", metrics=("si_p910", "ti_p910", "mafd"))
    out = np.full((frames, 2), np.nan)
    seen = 0
    for y in natives:
        if seen == frames:
            break
        m = meter.update(y)
        out[seen] = m["si_p910"], m["ti_p910"]
        seen += 1
    if seen < frames:
        raise UserError(f"the source gave {seen} frames on a second reading, not {frames}.")
    return out

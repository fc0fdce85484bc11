"""The Colias ↔ host serial protocol: packet layout, encoding, and a resynchronising parser.

Every packet (both directions), little-endian::

    offset  size  field
    0       2     sync: 0xAA 0x55
    2       2     length L of type + payload (u16)
    4       1     type
    5       L-1   payload
    4+L     2     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over bytes 2 … 4+L-1

Robot → host, type 0x01 FRAME (payload)::

    u32 frame index, u64 robot time (µs), u8 flags (bit 0: image present),
    u8 width, u8 height, u8 n outputs, n × f32 on-board model outputs,
    width × height × u8 raw grey image (only if bit 0 is set)

Robot → host, type 0x02 END (no payload): the run is over.

Robot → host, type 0x03 ANNOUNCE (payload), once after every START and before the first FRAME:
what the robot runs (the handshake; firmware that never sends it is recorded as unverified)::

    u8 version (1), f64 camera fps (Hz), u16 width px, u16 height px,
    f64 deg/px at the image centre, u16 texture row, u8 n outputs,
    u8 S, S bytes UTF-8 model spec (e.g. ``avdm`` or ``lgmd-plus:t_sr=80``),
    n × (u8 N, N bytes UTF-8 output name, u8 U, U bytes UTF-8 unit), in FRAME's output order

Host → robot: 0x10 START, 0x11 STOP (no payload), 0x12 PARAMS (UTF-8 ``name:key=value,...``:
the model the host asks the robot to run; sent just before every START).

Raw 99×72 frames at 33 Hz are 7,152 bytes a packet, 236 kB/s: at 8N1 that needs at least
2.4 Mbaud (3,000,000 is the nearest standard rate). Slower links send the image every Nth frame
(``decimation``; the outputs still every frame): at the Colias extension board's 115,200 baud,
N ≥ 21 (≈ 1.6 images/s).
"""

from __future__ import annotations

import binascii
import dataclasses
import math
import struct
from collections.abc import Iterator

import numpy as np

from vdc.errors import UserError

SYNC = b"\xaa\x55"
TYPE_FRAME = 0x01
TYPE_END = 0x02  # robot → host: the run is over (no payload; a real robot may never send it)
TYPE_ANNOUNCE = 0x03  # robot → host: what it runs (model, outputs, camera), after each START
TYPE_START = 0x10
TYPE_STOP = 0x11
TYPE_PARAMS = 0x12
KNOWN_TYPES = {TYPE_FRAME, TYPE_END, TYPE_ANNOUNCE, TYPE_START, TYPE_STOP, TYPE_PARAMS}
# allowed type + payload lengths per type: checked as soon as the header is in, so a false sync
# word in noise is dropped at once instead of stalling the packets behind it
LENGTH_RANGE = {
    TYPE_FRAME: (1 + 16, 1 + 16 + 4 * 255 + 255 * 255),
    TYPE_END: (1, 1),
    TYPE_ANNOUNCE: (1 + 25, 1 + 25 + 255 + 255 * 512),
    TYPE_START: (1, 1),
    TYPE_STOP: (1, 1),
    TYPE_PARAMS: (1, 1 + 4096),
}
FLAG_IMAGE = 0x01
_FRAME_HEAD = struct.Struct("<IQBBBB")  # index, time µs, flags, width, height, n outputs
ANNOUNCE_VERSION = 1
# version, fps, width, height, deg/px, texture row, n outputs, spec length
_ANNOUNCE_HEAD = struct.Struct("<BdHHdHBB")


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (the check value of b"123456789" is 0x29B1)."""
    return binascii.crc_hqx(data, 0xFFFF)


def encode(ptype: int, payload: bytes = b"") -> bytes:
    """A complete packet of ``ptype`` carrying ``payload``."""
    body = struct.pack("<HB", len(payload) + 1, ptype) + payload
    return SYNC + body + struct.pack("<H", crc16(body))


@dataclasses.dataclass(frozen=True)
class FramePacket:
    """One camera frame as the robot reports it."""

    index: int
    robot_time_us: int
    outputs: tuple[float, ...]
    image: np.ndarray | None  # (H, W) uint8, None when the link decimates it away
    width: int
    height: int


def encode_frame(
    index: int,
    robot_time_us: int,
    outputs: tuple[float, ...] | list[float],
    image: np.ndarray | None,
    shape: tuple[int, int],
) -> bytes:
    """A FRAME packet; ``shape`` (H, W) is sent even when the image is omitted."""
    h, w = shape
    flags = FLAG_IMAGE if image is not None else 0
    payload = _FRAME_HEAD.pack(index, robot_time_us, flags, w, h, len(outputs))
    payload += struct.pack(f"<{len(outputs)}f", *outputs)
    if image is not None:
        img = np.ascontiguousarray(image, dtype=np.uint8)
        if img.shape != (h, w):
            raise UserError(f"image shape {img.shape} is not {(h, w)}.")
        payload += img.tobytes()
    return encode(TYPE_FRAME, payload)


def decode_frame(payload: bytes) -> FramePacket:
    """Parse a FRAME payload; raises ValueError if its length does not match its header."""
    if len(payload) < _FRAME_HEAD.size:
        raise UserError("FRAME payload shorter than its header.")
    index, t_us, flags, w, h, n = _FRAME_HEAD.unpack_from(payload)
    expected = _FRAME_HEAD.size + 4 * n + (w * h if flags & FLAG_IMAGE else 0)
    if len(payload) != expected:
        raise UserError(f"FRAME payload of {len(payload)} bytes, header says {expected}.")
    outputs = struct.unpack_from(f"<{n}f", payload, _FRAME_HEAD.size)
    image = None
    if flags & FLAG_IMAGE:
        start = _FRAME_HEAD.size + 4 * n
        image = np.frombuffer(payload, np.uint8, w * h, start).reshape(h, w).copy()
    return FramePacket(index, t_us, tuple(float(v) for v in outputs), image, w, h)


@dataclasses.dataclass(frozen=True)
class Announcement:
    """What the robot says it runs (the ANNOUNCE packet): its model, the model's outputs in
    FRAME order with their units, and its camera."""

    model: str  # the model spec, e.g. "avdm" or "lgmd-plus:t_sr=80"
    outputs: tuple[tuple[str, str], ...]  # (name, unit) per output, in FRAME order
    fps: float  # camera frame rate, Hz
    width_px: int
    height_px: int
    deg_per_px: float  # angular pitch at the image centre
    texture_row: int  # the image row the AVDM counts texture on

    def problem(self) -> str | None:
        """Why this camera cannot be the robot's (one line), or None when it is sane: a size
        of 1-255 px a side (a FRAME's u8 fields), a texture row inside the frame, a finite
        positive rate and angular pitch."""
        if not (1 <= self.width_px <= 255 and 1 <= self.height_px <= 255):
            return f"a {self.width_px}x{self.height_px} px camera (a FRAME carries 1-255 px a side)"
        if not 0 <= self.texture_row < self.height_px:
            return (
                f"texture row {self.texture_row}, outside its {self.height_px} px high frame "
                f"(rows 0-{self.height_px - 1})"
            )
        if not (math.isfinite(self.fps) and self.fps > 0):
            return f"a camera rate of {self.fps!r} Hz (must be finite and positive)"
        if not (math.isfinite(self.deg_per_px) and self.deg_per_px > 0):
            return f"{self.deg_per_px!r} deg/px (must be finite and positive)"
        return None

    def model_context(self) -> dict[str, float | int]:
        """The robot's camera as ``vdc.recording.camera_model_context`` gives a camera's:
        what the host builds (and analysis rebuilds) the model with."""
        return {
            "fps": self.fps,
            "deg_per_px": self.deg_per_px,
            "texture_row": self.texture_row,
            "width_px": self.width_px,
            "height_px": self.height_px,
        }


def _short_text(text: str, what: str) -> bytes:
    raw = text.encode("utf-8")
    if len(raw) > 255:
        raise UserError(f"{what} {text!r} is longer than 255 bytes.")
    return bytes([len(raw)]) + raw


def encode_announce(a: Announcement) -> bytes:
    """An ANNOUNCE packet carrying ``a``."""
    if len(a.outputs) > 255:
        raise UserError("more than 255 outputs.")
    spec = a.model.encode("utf-8")
    if len(spec) > 255:
        raise UserError(f"model spec {a.model!r} is longer than 255 bytes.")
    payload = _ANNOUNCE_HEAD.pack(
        ANNOUNCE_VERSION,
        a.fps,
        a.width_px,
        a.height_px,
        a.deg_per_px,
        a.texture_row,
        len(a.outputs),
        len(spec),
    )
    payload += spec
    for name, unit in a.outputs:
        payload += _short_text(name, "output name") + _short_text(unit, "unit")
    return encode(TYPE_ANNOUNCE, payload)


def decode_announce(payload: bytes) -> Announcement:
    """Parse an ANNOUNCE payload; ValueError if it is malformed or of another version."""
    if len(payload) < _ANNOUNCE_HEAD.size:
        raise UserError("ANNOUNCE payload shorter than its header.")
    version, fps, w, h, dpp, row, n, s = _ANNOUNCE_HEAD.unpack_from(payload)
    if version != ANNOUNCE_VERSION:
        raise UserError(f"ANNOUNCE version {version}, this host reads {ANNOUNCE_VERSION}.")
    pos = _ANNOUNCE_HEAD.size

    def text() -> str:
        nonlocal pos
        if pos >= len(payload) or pos + 1 + payload[pos] > len(payload):
            raise UserError("ANNOUNCE payload ends inside a text field.")
        k = payload[pos]
        out = payload[pos + 1 : pos + 1 + k].decode("utf-8")
        pos += 1 + k
        return out

    if pos + s > len(payload):
        raise UserError("ANNOUNCE payload ends inside the model spec.")
    spec = payload[pos : pos + s].decode("utf-8")
    pos += s
    outputs = tuple((text(), text()) for _ in range(n))
    if pos != len(payload):
        raise UserError(f"ANNOUNCE payload has {len(payload) - pos} bytes after its outputs.")
    return Announcement(spec, outputs, float(fps), w, h, float(dpp), row)


@dataclasses.dataclass
class LinkStats:
    """What the parser saw: good packets, CRC failures, bytes skipped to resynchronise."""

    packets: int = 0
    bad_crc: int = 0
    bad_length: int = 0
    garbage_bytes: int = 0


class PacketParser:
    """Turns a byte stream into (type, payload) packets.

    Bytes that do not start a valid packet are skipped until the next sync word; a packet whose
    CRC fails is dropped and counted, and the search resumes one byte after its sync word, so a
    corrupted length field cannot swallow the packets after it."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.stats = LinkStats()

    def feed(self, data: bytes) -> Iterator[tuple[int, bytes]]:
        self.buf += data
        while True:
            start = self.buf.find(SYNC)
            if start < 0:
                keep = 1 if self.buf.endswith(SYNC[:1]) else 0
                self.stats.garbage_bytes += len(self.buf) - keep
                del self.buf[: len(self.buf) - keep]
                return
            if start:
                self.stats.garbage_bytes += start
                del self.buf[:start]
            if len(self.buf) < 5:
                return
            (length,) = struct.unpack_from("<H", self.buf, 2)
            lo, hi = LENGTH_RANGE.get(self.buf[4], (1, 0))  # unknown type: empty range
            if not lo <= length <= hi:
                # a false sync word (or a damaged header): do not wait for a length it made up
                self.stats.bad_length += 1
                del self.buf[:1]
                continue
            end = 4 + length + 2
            if len(self.buf) < end:
                return
            body = bytes(self.buf[2 : 4 + length])
            (crc,) = struct.unpack_from("<H", self.buf, 4 + length)
            if crc != crc16(body) or body[2] not in KNOWN_TYPES:
                self.stats.bad_crc += 1
                del self.buf[:1]
                continue
            del self.buf[:end]
            self.stats.packets += 1
            yield body[2], body[3:]

    def _complete_packet_at(self, k: int) -> bool:
        """A whole packet with a good CRC starts at ``buf[k]``."""
        if len(self.buf) < k + 5:
            return False
        (length,) = struct.unpack_from("<H", self.buf, k + 2)
        lo, hi = LENGTH_RANGE.get(self.buf[k + 4], (1, 0))
        end = k + 4 + length + 2
        if not lo <= length <= hi or len(self.buf) < end:
            return False
        body = bytes(self.buf[k + 2 : k + 4 + length])
        (crc,) = struct.unpack_from("<H", self.buf, k + 4 + length)
        return crc == crc16(body) and body[2] in KNOWN_TYPES

    def salvage(self) -> list[tuple[int, bytes]]:
        """Packets stuck behind a damaged header, for a line that has gone quiet.

        A corrupted length that is still in range makes :meth:`feed` wait for bytes that are
        really the packets after it; mid-stream they come and the CRC check frees them, but at
        the end of a run nothing more comes, and the robot's END would wait for ever. So when
        the line is quiet and a whole, CRC-valid packet lies inside the span the first header
        claims, that header is taken as damaged (counted in ``bad_length``) and parsing
        resumes one byte after its sync word. A packet that is only incomplete (the rest still
        on its way) holds no whole packet after its header, and is kept."""
        out: list[tuple[int, bytes]] = []
        while len(self.buf) >= 5:
            k = self.buf.find(SYNC, 1)
            while k >= 0 and not self._complete_packet_at(k):
                k = self.buf.find(SYNC, k + 1)
            if k < 0:
                break
            self.stats.bad_length += 1
            del self.buf[:1]
            out += self.feed(b"")
        return out

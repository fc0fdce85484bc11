"""The start a Matroska (WebM) file declares, read from its own index, not from its first
readable frame.

FFmpeg gives a Matroska stream's start time as the time of the first packet it could read:
a file whose first cluster is unreadable then seems to start where the damage ends, and the
frames lost there are counted nowhere (the Segment's Duration, the end on a timeline from 0,
then looks like the length of what is left). The file's Cues (its index of key frames,
written by every muxer that makes a seekable file) still name the first key frame's time:
:func:`declared_start_s` reads it, through the SeekHead that points at the Cues, so that no
byte of the damaged clusters is needed. Only the few elements on that path are parsed (EBML:
RFC 8794; Matroska: RFC 9559).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import BinaryIO

SEGMENT, SEEK_HEAD, SEEK, SEEK_ID, SEEK_POSITION = 0x18538067, 0x114D9B74, 0x4DBB, 0x53AB, 0x53AC
INFO, TIMESTAMP_SCALE, CUES, CUE_POINT, CUE_TIME = 0x1549A966, 0x2AD7B1, 0x1C53BB6B, 0xBB, 0xB3
EBML_HEADER = 0x1A45DFA3
# a Cues element larger than this is not read (a 4-hour file's index is a few hundred kB)
MAX_ELEMENT = 16 * 2**20


def _vint(fh: BinaryIO, keep_marker: bool) -> int | None:
    """One EBML variable-length integer (an element ID with its marker bit kept, a size
    without it); None at the end of the file or on a byte that starts none (zeroed data)."""
    first = fh.read(1)
    if not first or first[0] == 0:
        return None
    length = 8 - first[0].bit_length() + 1
    value = first[0] if keep_marker else first[0] & (0xFF >> length)
    rest = fh.read(length - 1)
    if len(rest) != length - 1:
        return None
    for b in rest:
        value = (value << 8) | b
    return value


def _children(data: bytes) -> list[tuple[int, bytes]]:
    """The (ID, payload) elements in ``data``, up to the first that does not parse."""
    fh, out = io.BytesIO(data), []
    while True:
        eid, size = _vint(fh, True), _vint(fh, False)
        if eid is None or size is None:
            return out
        payload = fh.read(size)
        if len(payload) != size:
            return out
        out.append((eid, payload))


def _uint(data: bytes) -> int:
    return int.from_bytes(data, "big") if data else 0


def declared_start_s(path: str | Path) -> float | None:
    """The time (s) of the first key frame a Matroska file's Cues index, on the file's own
    timeline; None where the file has no readable SeekHead, Cues or cue point (a live or
    streamed file: its start is then FFmpeg's)."""
    try:
        with open(path, "rb") as fh:
            if _vint(fh, True) != EBML_HEADER:
                return None
            size = _vint(fh, False)
            if size is None:
                return None
            fh.seek(size, 1)
            if _vint(fh, True) != SEGMENT or _vint(fh, False) is None:
                return None
            seg = fh.tell()  # SeekPositions count from the Segment's data
            scale_ns, cues_at = 1_000_000, None
            # the elements before the first Cluster: SeekHead, Info, ... (each small)
            for _ in range(16):
                eid, size = _vint(fh, True), _vint(fh, False)
                if eid is None or size is None or size > MAX_ELEMENT:
                    break
                payload = fh.read(size)
                if eid == SEEK_HEAD:
                    for sid, seek in _children(payload):
                        fields = dict(_children(seek)) if sid == SEEK else {}
                        if _uint(fields.get(SEEK_ID, b"")) == CUES and SEEK_POSITION in fields:
                            cues_at = seg + _uint(fields[SEEK_POSITION])
                elif eid == INFO:
                    fields = dict(_children(payload))
                    scale_ns = _uint(fields.get(TIMESTAMP_SCALE, b"")) or scale_ns
                elif eid == CUES:  # written before the clusters: read here
                    return _first_cue(payload, scale_ns)
            if cues_at is None:
                return None
            fh.seek(cues_at)
            if _vint(fh, True) != CUES:
                return None
            size = _vint(fh, False)
            if size is None or size > MAX_ELEMENT:
                return None
            return _first_cue(fh.read(size), scale_ns)
    except OSError:
        return None


def _first_cue(cues: bytes, scale_ns: int) -> float | None:
    """The earliest CueTime of a Cues payload, in seconds."""
    times = [
        _uint(dict(_children(point)).get(CUE_TIME, b""))
        for eid, point in _children(cues)
        if eid == CUE_POINT and CUE_TIME in dict(_children(point))
    ]
    return min(times) * scale_ns / 1e9 if times else None

"""Reading vdc recordings: the only module that knows Rerun's read API (rerun-sdk 0.41).

* frames come back as numpy ``(N, H, W) uint8`` in chunks, in frame order (bounded memory);
* scalar signals, events and properties come back as numpy / polars;
* a recording without a footer (cut by a crash or SIGKILL) is read by a sequential scan, and
  ``Recording.notice`` says so.

Entity paths are the recording contract's, defined once in ``vdc.recording``.
"""

from __future__ import annotations

import dataclasses
import os
import struct
import tempfile
import time
import warnings
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa
import rerun as rr

from vdc.errors import UserError
from vdc.folders import not_found
from vdc.recording import (
    CAMERA,
    DESCRIPTION,
    EVENTS,
    MODEL_ROOT,
    PARTIAL_SUFFIX,
    POSE,
    WALL_TF,
    capture_writing,
    entity_name,
)

RRD_MAGIC = b"RRF2"
RRD_FILE_HEADER = 12  # magic, version, options
RRD_MESSAGE_HEADER = 16  # kind (u64 LE), payload length (u64 LE)


class RecordingError(UserError):
    """A file that is not a readable vdc recording (printed as one line at the CLI)."""


@dataclasses.dataclass(frozen=True)
class FrameChunk:
    """Consecutive camera frames: ``frame`` (N,) int64 indices, ``images`` (N, H, W) uint8."""

    frame: np.ndarray
    images: np.ndarray


def _check_path(path: Path) -> None:
    if not path.exists():
        raise RecordingError(not_found(path))
    if path.is_dir():
        raise RecordingError(f"{str(path)!r} is a directory, not an .rrd recording")
    try:
        with path.open("rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise RecordingError(f"cannot read {str(path)!r}: {exc.strerror}") from None
    if head != RRD_MAGIC:
        what = "is empty" if not head else "is not a Rerun recording (.rrd)"
        raise RecordingError(f"{str(path)!r} {what}")


def _scalar_columns(rb: pa.RecordBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame, t_s, values (N, K)) of one Scalars record batch (t_s = NaN without ``time``)."""
    col = rb.column("Scalars:scalars")
    k = len(col[0]) if len(col) else 1
    frame = rb.column("frame").to_numpy()
    if "time" in rb.schema.names:
        t_s = rb.column("time").cast(pa.int64()).to_numpy() / 1e9
    else:
        t_s = np.full(rb.num_rows, np.nan)
    return frame, t_s, col.flatten().to_numpy(zero_copy_only=False).reshape(-1, k)


def _merge_sorted(
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not parts:
        return np.empty(0, np.int64), np.empty(0), np.empty((0, 1))
    f = np.concatenate([p[0] for p in parts])
    order = np.argsort(f, kind="stable")
    t = np.concatenate([p[1] for p in parts])[order]
    return f[order], t, np.concatenate([p[2] for p in parts])[order]


def complete_prefix(path: Path) -> tuple[int, int]:
    """(bytes of complete messages, messages) at the start of an ``.rrd`` file.

    Walks the message headers only (seeks past payloads). A file cut by a crash or a copy that
    stopped early ends inside a message; everything before it is intact."""
    size = path.stat().st_size
    pos, count = RRD_FILE_HEADER, 0
    with path.open("rb") as fh:
        while pos + RRD_MESSAGE_HEADER <= size:
            fh.seek(pos)
            _kind, length = struct.unpack("<QQ", fh.read(RRD_MESSAGE_HEADER))
            end = pos + RRD_MESSAGE_HEADER + length
            if end > size:
                break
            pos, count = end, count + 1
    return pos, count


def _repaired_copy(path: Path, snapshot: bool = False) -> tuple[int, Path, str] | None:
    """An unnamed temporary copy of the complete messages of a truncated file: (its open file
    descriptor, a path that reads it, a note), or None if the file is not truncated
    mid-message (or holds no complete message).

    The copy goes to the temporary folder (``TMPDIR``) and is unlinked the moment it is
    created, so it is gone on every exit path, a SIGKILL included; the reader opens it through
    ``/proc/self/fd``. A copy that does not fit raises RecordingError naming the folder."""
    good, count = complete_prefix(path)
    size = path.stat().st_size
    if (good >= size and not snapshot) or count == 0:
        return None
    folder = tempfile.gettempdir()
    fd, tmp = tempfile.mkstemp(suffix=".rrd", prefix="vdc-repaired-", dir=folder)
    os.unlink(tmp)  # nameless from here: freed when the descriptor closes, however we exit
    try:
        with path.open("rb") as src, os.fdopen(fd, "wb", closefd=False) as out:
            remaining = good
            while remaining:
                block = src.read(min(remaining, 1 << 22))
                out.write(block)  # raises on a full disk (ENOSPC) or a size limit (EFBIG)
                remaining -= len(block)
    except OSError as exc:
        os.close(fd)
        raise RecordingError(
            f"cannot repair the truncated {str(path)!r}: no room for its {good / 1e6:.0f} MB "
            f"copy in {folder} ({exc.strerror}); set TMPDIR to a folder with room"
        ) from None
    note = (
        f"{path.name} is still being written: read as a snapshot of its first {count} "
        f"messages ({good / 1e6:.1f} MB)"
        if snapshot
        else f"{path.name} is truncated ({size - good} bytes of an incomplete message at the "
        f"end): repaired by reading its {count} complete messages"
    )
    return fd, Path(f"/proc/self/fd/{fd}"), note


def _growing(path: Path, wait_s: float = 0.3) -> bool:
    """Whether a file without a footer is still being written by someone (it grows)."""
    before = path.stat().st_size
    time.sleep(wait_s)
    return path.stat().st_size != before


class Recording:
    """One ``.rrd`` recording opened for analysis."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        _check_path(self.path)
        self.notice: str | None = None
        # a capture still writing it (its claim names a live pid): read a snapshot, so that
        # every table comes from the same bytes
        if self.path.name.endswith(PARTIAL_SUFFIX) and capture_writing(self.path) is not None:
            self._open_copy(snapshot=True)
        else:
            try:
                self._reader = self._open(self.path)
            except Exception as exc:  # the SDK raises several types for damaged files
                # a file cut inside a message (a copy that stopped early, a crash mid-write):
                # read the complete messages before the cut from a temporary copy
                self._open_copy(snapshot=False, cause=exc)
        self._check_entries()
        try:
            self._store = self._reader.store()  # lazy: reads the footer's manifest only
        except Exception:
            self._store = None
            if self._snapshot is None and _growing(self.path):  # written by another tool
                self._open_copy(snapshot=True)
                self._check_entries()
            else:
                # no footer: the capture was killed. A sequential scan reads every chunk.
                self.notice = self.notice or (
                    f"{self.path.name} has no footer (the capture was cut short): "
                    "read it by a sequential scan; every complete chunk is used"
                )
        self._props: dict[str, dict[str, Any]] | None = None

    _snapshot: Path | None = None

    def _open_copy(self, snapshot: bool, cause: Exception | None = None) -> None:
        """Read from an unnamed copy of the complete messages (see ``_repaired_copy``)."""
        copy = _repaired_copy(self.path, snapshot)
        if copy is None:
            raise RecordingError(f"{str(self.path)!r} is damaged: {cause}") from None
        fd, source, self.notice = copy
        self._snapshot = source
        weakref.finalize(self, os.close, fd)
        try:
            self._reader = self._open(source)
        except Exception as exc2:
            raise RecordingError(f"{str(self.path)!r} is damaged: {exc2}") from None

    def _check_entries(self) -> None:
        entries = [e for e in self._reader.recordings() if e.kind == "recording"]
        if not entries:
            raise RecordingError(f"{str(self.path)!r} holds no recording (cut too early?)")
        self.application_id = entries[0].application_id
        self.recording_id = entries[0].recording_id

    @staticmethod
    def _open(path: Path) -> Any:
        with warnings.catch_warnings():  # a missing footer is reported by self.notice
            warnings.filterwarnings("ignore", message=".*no footer.*")
            reader = rr.chunk.RrdReader(str(path))
            reader.recordings()  # enumerates the file: fails here if a message is cut
        return reader

    # -- chunks --------------------------------------------------------------------------
    def _chunks(self, content: str) -> Iterator[Any]:
        try:
            source = self._store.stream() if self._store is not None else self._reader.stream()
            yield from source.filter(content=content)
        except RecordingError:
            raise
        except Exception as exc:
            raise RecordingError(f"{str(self.path)!r} is damaged: {exc}") from None

    def _batches(self, content: str) -> Iterator[tuple[str, pa.RecordBatch]]:
        for ch in self._chunks(content):
            yield ch.entity_path, ch.to_record_batch()

    # -- properties ------------------------------------------------------------------------
    def properties(self) -> dict[str, dict[str, Any]]:
        """``{section: {field: value}}`` from the recording properties (``run``, ``wall``, ...)."""
        if self._props is None:
            props: dict[str, dict[str, Any]] = {}
            for entity, rb in self._batches("/__properties/**"):
                section = entity.rsplit("/", 1)[-1] if entity != "/__properties" else "info"
                values = props.setdefault(section, {})
                for name in rb.column_names:
                    if name.startswith("rerun.controls"):
                        continue
                    v = rb.column(name).to_pylist()[-1]
                    values[name.split(":")[-1]] = v[0] if isinstance(v, list) and len(v) == 1 else v
            self._props = props
        return self._props

    def description(self) -> str | None:
        """The capture's description of the recording (markdown: what, model, camera, how to
        analyse it), or None for a recording that has none (an older one)."""
        text = None
        for _, rb in self._batches(DESCRIPTION):
            if "TextDocument:text" in rb.schema.names:
                v = rb.column("TextDocument:text").to_pylist()[-1]
                text = v[0] if isinstance(v, list) else v
        return text

    # -- frames ----------------------------------------------------------------------------
    def iter_frames(self, entity: str = CAMERA) -> Iterator[FrameChunk]:
        """Camera frames chunk by chunk, in frame order; memory stays at one chunk.

        Raises RecordingError if the recording holds no frames on ``entity``."""
        shape: tuple[int, int] | None = None
        last = -1
        pending: list[tuple[np.ndarray, np.ndarray]] = []
        any_frames = False
        for _, rb in self._batches(entity):
            cols = rb.schema.names
            if "Image:format" in cols and shape is None:
                fmt = rb.column("Image:format").to_pylist()[0]
                fmt = fmt[0] if isinstance(fmt, list) else fmt
                shape = (int(fmt["height"]), int(fmt["width"]))
            if "Image:buffer" in cols and "frame" in cols:
                idx = rb.column("frame").to_numpy()
                flat = rb.column("Image:buffer").flatten().flatten()
                pending.append((idx, flat.to_numpy(zero_copy_only=False)))
            if shape is None:
                continue  # the static format chunk may come later: hold the data until then
            for idx_p, flat_p in pending:
                images = flat_p.reshape(len(idx_p), *shape)
                order = np.argsort(idx_p, kind="stable")
                idx_p = idx_p[order]
                if idx_p[0] <= last:
                    raise RecordingError(
                        f"{str(self.path)!r}: camera frames are stored out of order "
                        f"(frame {idx_p[0]} after {last}); run `rerun rrd optimize` on it"
                    )
                last = int(idx_p[-1])
                any_frames = True
                yield FrameChunk(idx_p, images[order])
            pending = []
        if pending and shape is None:
            # the static format chunk was lost (a file cut before it was written): the camera
            # size recorded in the properties gives the frame shape
            cam = self.properties().get("camera", {})
            if "height_px" in cam and "width_px" in cam:
                shape = (int(cam["height_px"]), int(cam["width_px"]))
                for idx_p, flat_p in pending:
                    if flat_p.size != len(idx_p) * shape[0] * shape[1]:
                        break
                    order = np.argsort(idx_p, kind="stable")
                    any_frames = True
                    yield FrameChunk(idx_p[order], flat_p.reshape(len(idx_p), *shape)[order])
        if not any_frames:
            raise RecordingError(f"{str(self.path)!r} holds no camera frames at {entity}")

    def read_frames(self, entity: str = CAMERA) -> FrameChunk:
        """All frames at once (for short recordings and tests)."""
        parts = list(self.iter_frames(entity))
        return FrameChunk(
            np.concatenate([p.frame for p in parts]), np.concatenate([p.images for p in parts])
        )

    # -- scalars and events ----------------------------------------------------------------
    def scalars(self, entity: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(frame (N,), t_s (N,), values (N, K))`` of a Scalars entity, sorted by frame."""
        parts = [
            _scalar_columns(rb)
            for _, rb in self._batches(entity)
            if "Scalars:scalars" in rb.schema.names and "frame" in rb.schema.names
        ]
        return _merge_sorted(parts)

    def signals(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Every Scalars entity in one pass over the file (images skipped):
        ``{entity: (frame (N,), t_s (N,), values (N, K))}``, each sorted by frame."""
        parts: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
        try:
            source = self._store.stream() if self._store is not None else self._reader.stream()
            for ch in source.filter(components="Scalars:scalars"):
                rb = ch.to_record_batch()
                if "frame" in rb.schema.names and "Scalars:scalars" in rb.schema.names:
                    parts.setdefault(ch.entity_path, []).append(_scalar_columns(rb))
        except Exception as exc:
            raise RecordingError(f"{str(self.path)!r} is damaged: {exc}") from None
        return {entity: _merge_sorted(items) for entity, items in parts.items()}

    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(frame, t_s, poses (N, 3) [x_m, y_m, heading_rad])``."""
        return self.scalars(POSE)

    def wall_tf(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.scalars(WALL_TF)

    def model_outputs(self, model_name: str, outputs: list[str]) -> dict[str, np.ndarray]:
        """Logged online outputs of ``model_name``: ``{"frame": ..., output: (N,)}``."""
        out: dict[str, np.ndarray] = {}
        for name in outputs:
            f, _, v = self.scalars(f"{MODEL_ROOT}/{entity_name(model_name)}/{name}")
            out.setdefault("frame", f)
            out[name] = v[:, 0] if v.size else v.reshape(0)
        return out

    def events(self) -> pl.DataFrame:
        """All events: frame, t_s, kind, text, x_m, y_m (NaN where no position was logged)."""
        texts, places = [], []
        for entity, rb in self._batches(f"{EVENTS}/**"):
            names = rb.schema.names
            if "frame" not in names:
                continue
            kind = entity.rsplit("/", 1)[-1]
            frames = rb.column("frame").to_numpy()
            if "TextLog:text" in names:
                t = rb.column("time").cast(pa.int64()).to_numpy() / 1e9
                for f, ts, txt in zip(
                    frames, t, rb.column("TextLog:text").to_pylist(), strict=True
                ):
                    text = txt[0] if isinstance(txt, list) else txt
                    texts.append({"frame": int(f), "t_s": float(ts), "kind": kind, "text": text})
            if "Points3D:positions" in names:
                for f, p in zip(frames, rb.column("Points3D:positions").to_pylist(), strict=True):
                    if p:
                        places.append(
                            {
                                "frame": int(f),
                                "kind": kind,
                                "x_m": float(p[0][0]),
                                "y_m": float(p[0][1]),
                            }
                        )
        schema = {"frame": pl.Int64, "t_s": pl.Float64, "kind": pl.String, "text": pl.String}
        ev = pl.DataFrame(texts, schema=schema)
        pos = pl.DataFrame(
            places,
            schema={"frame": pl.Int64, "kind": pl.String, "x_m": pl.Float64, "y_m": pl.Float64},
        )
        pos = pos.unique(subset=["frame", "kind"], keep="first", maintain_order=True)
        ev = ev.join(pos, on=["frame", "kind"], how="left").with_columns(
            pl.col("x_m").fill_null(float("nan")), pl.col("y_m").fill_null(float("nan"))
        )
        return ev.select("frame", "t_s", "kind", "text", "x_m", "y_m").sort("frame", "kind")

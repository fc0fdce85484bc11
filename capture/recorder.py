"""The Rerun recorder: writes the recording contract, batch by batch, to its file (and to the
live view of ``capture.live_view``).

The entity paths, timelines and property sections are defined in ``vdc.recording``
(shared with the reader); the recorder modules (this one and ``capture.live_view``) are the
only ones that write with the Rerun SDK.
"""

from __future__ import annotations

import math
import os
import resource
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdc.recording import RERUN_LOG

# The SDK's own log lines for a viewer that went away or a file it could not write would repeat
# every batch; the recorder watches both sinks itself and says so in one line. Set before the
# SDK starts its logger; a RUST_LOG the user set wins.
os.environ.setdefault("RUST_LOG", RERUN_LOG)
import rerun as rr
import rerun.blueprint as rrb

from avdm.base import Output
from capture.config import ArenaConfig
from capture.live_view import LiveView, Tee, warn_line
from vdc.errors import UserError
from vdc.recording import (
    APP_ID,
    ARENA_RING,
    ARENA_WALLS,
    CAMERA,
    CAPTURE_TIME_TIMELINE,
    DESCRIPTION,
    EVENT_KINDS,
    FRAME_TIMELINE,
    FRAME_TIMING,
    FRAME_TIMING_NAMES,
    LINK_STATS,
    MODEL_ROOT,
    NATIVE_METRICS,
    NATIVE_METRICS_PATH,
    OVERHEAD,
    POSE,
    POSE_NAMES,
    PROPERTY_SECTIONS,
    ROBOT,
    ROBOT_BODY,
    ROBOT_HEADING,
    ROBOT_PATH,
    TIME_TIMELINE,
    WALL_TF,
    entity_name,
    event_path,
)

EVENT_COLORS = {
    "ring_turn": (255, 200, 0),
    "avoidance": (0, 200, 255),
    "crash": (255, 40, 40),
    "link_error": (255, 0, 255),
    "tracker_lost": (160, 160, 160),
}
EVENT_LEVELS = {
    "crash": "WARN",
    "link_error": "ERROR",
    "tracker_lost": "WARN",
    "dropped_frames": "WARN",
    "decode_error": "ERROR",
}


class RecordingWriteError(RuntimeError):
    """The file sink cannot write (disk full, file size limit): stop, keep what fitted."""


# room kept free for the run_end property and the footer after the last batch
_CLOSE_RESERVE_BYTES = 1 << 20


def free_bytes(path: Path) -> int:
    """Bytes ``path`` can still grow by: the free space of its file system (for this user)
    and the process's file size limit (RLIMIT_FSIZE), whichever is smaller."""
    st = os.statvfs(path.parent)
    room = st.f_bavail * st.f_frsize
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    if soft != resource.RLIM_INFINITY:
        size = path.stat().st_size if path.exists() else 0
        room = min(room, soft - size)
    return int(room)


def _time_indexes(
    frame: np.ndarray, t_s: np.ndarray, capture_ns: np.ndarray | None = None
) -> list[rr.TimeColumn]:
    t_ns = np.rint(np.asarray(t_s, dtype=np.float64) * 1e9).astype("timedelta64[ns]")
    out = [
        rr.TimeColumn(FRAME_TIMELINE, sequence=np.asarray(frame, dtype=np.int64)),
        rr.TimeColumn(TIME_TIMELINE, duration=t_ns),
    ]
    if capture_ns is not None:  # hardware runs: the host clock at reception
        stamps = np.asarray(capture_ns, dtype=np.int64).astype("datetime64[ns]")
        out.append(rr.TimeColumn(CAPTURE_TIME_TIMELINE, timestamp=stamps))
    return out


def _quaternions_z(heading: np.ndarray) -> np.ndarray:
    h = np.asarray(heading, dtype=np.float64) / 2
    z = np.zeros_like(h)
    return np.column_stack([z, z, np.sin(h), np.cos(h)])  # x, y, z, w


class Recorder:
    """Writes one run to an ``.rrd`` file (and optionally a live viewer) per the contract.

    The file is the primary sink: a viewer that is missing, unreachable or closed costs only the
    live view (:class:`LiveView`). Before each batch :meth:`reserve` checks that it fits on the
    disk and under the file size limit, and :meth:`end_batch` flushes it, so a capture that
    cannot write stops at once with a readable file of what fitted."""

    def __init__(
        self,
        path: Path,
        recording_id: str,
        *,
        blueprint: rrb.Blueprint | None = None,
        live_url: str | None = None,
        warn: Callable[[str], None] = warn_line,
    ) -> None:
        self.path = Path(path)
        self.recording_id = recording_id
        self.live = LiveView(live_url, recording_id, blueprint, warn) if live_url else None
        self.file_stream = rr.RecordingStream(APP_ID, recording_id=recording_id)
        self.file_stream.set_sinks(rr.FileSink(str(self.path)), default_blueprint=blueprint)
        self.rec = Tee(self.file_stream, self.live)
        self._image_shapes: dict[str, tuple[int, int]] = {}
        self._closed = False
        self._link_names_logged = False
        self._timing_names_logged = False
        self._native_names_logged = False
        self.frames_logged = 0  # camera frames written (the claim keeps a file that has any)
        self.write_error: str | None = None  # why the capture stopped writing, for the user
        self._raw_reserved = 0  # raw bytes of the batches reserved so far
        self._writer_failed = False  # the SDK's file writer died (cannot flush again)
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log(POSE, rr.SeriesLines(names=list(POSE_NAMES)), static=True)

    @property
    def closed(self) -> bool:
        return self._closed

    def flush(self) -> None:
        """Write everything sent so far to the file; RecordingWriteError if it cannot."""
        if self._writer_failed:
            raise RecordingWriteError(self.write_error)
        try:
            # bounded: a file writer that died can make an unbounded flush wait for ever
            self.file_stream.flush(timeout_sec=60.0)
        except RuntimeError as exc:
            self._writer_failed = True
            room = free_bytes(self.path)
            self.write_error = (
                f"cannot write {self.path.parent}: {'no space left' if room < (1 << 20) else exc}"
            )
            raise RecordingWriteError(self.write_error) from None

    def reserve(self, nbytes: int) -> None:
        """Raise RecordingWriteError, before anything of it is sent, when about ``nbytes`` more
        (plus the footer) would not fit on the disk or under RLIMIT_FSIZE. ``nbytes`` is the
        batch's raw size; after the first batch it is scaled by the compression seen so far."""
        raw = nbytes
        if self._raw_reserved > 0:  # the file sink compresses: scale by what it has done
            ratio = 1.5 * self.path.stat().st_size / self._raw_reserved  # 1.5: noisier frames
            nbytes = int(nbytes * min(1.0, ratio))
        room = free_bytes(self.path)
        if nbytes + _CLOSE_RESERVE_BYTES > room:
            disk = os.statvfs(self.path.parent)
            what = (
                "disk" if room >= disk.f_bavail * disk.f_frsize else "file size limit (ulimit -f)"
            )
            self.write_error = (
                f"no room left in {self.path.parent.resolve()} under the {what}: "
                f"{max(room, 0) / 1e6:.1f} MB left, the next batch needs ~{nbytes / 1e6:.1f} MB"
            )
            raise RecordingWriteError(self.write_error)
        self._raw_reserved += raw

    def end_batch(self) -> None:
        """After each batch: the file holds it (or RecordingWriteError), the viewer is there."""
        self.flush()
        if self.live is not None:
            self.live.check()

    # -- static and metadata -------------------------------------------------------------
    def send_properties(self, sections: Mapping[str, Mapping[str, Any]]) -> None:
        """One recording property per section, e.g. ``arena``, ``wall``, ``model_params``.

        The SDK types a field by its name across all sections (the first section to use a name
        sets its type): a field whose name an earlier section used with text (e.g. the
        collision section's ``threshold: default`` and a plug-in's ``threshold`` parameter) is
        sent as text too, rather than dropped. A section the contract does not know
        (``vdc.recording.PROPERTY_SECTIONS``) is refused with ValueError, before any is sent."""
        unknown = [name for name in sections if name not in PROPERTY_SECTIONS]
        if unknown:
            raise UserError(
                f"property section(s) {', '.join(map(repr, unknown))} are not in the recording "
                f"contract; allowed: {', '.join(PROPERTY_SECTIONS)} (vdc.recording)."
            )
        text_names: set[str] = set()
        for name, values in sections.items():
            # None and "" are left out, always: the SDK drops an empty string only until the
            # process has sent that field name with text, so the same run's properties
            # differed with what was recorded before it in the process (a natural scene's
            # image_path, then a grating's "")
            clean = {
                k: (str(v) if k in text_names and not isinstance(v, str) else v)
                for k, v in values.items()
                if v is not None and not (isinstance(v, str) and v == "")
            }
            text_names |= {k for k, v in clean.items() if isinstance(v, str)}
            if clean:  # an empty section (a plug-in without parameters) is no property: the
                # SDK warns "No valid component batches" and drops it anyway
                self.rec.send_property(name, rr.AnyValues(**clean))

    def log_description(self, markdown: str) -> None:
        """The recording's description (what, model, camera, how to analyse), static, as a
        markdown text document at ``vdc.recording.DESCRIPTION``."""
        self.rec.log(
            DESCRIPTION, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True
        )

    def log_arena(self, arena: ArenaConfig, robot_radius_m: float) -> None:
        hx, hy = arena.half_extent
        h = arena.wall_height_m

        def rect(ix: float, iy: float, z: float) -> list[list[float]]:
            return [[-ix, -iy, z], [ix, -iy, z], [ix, iy, z], [-ix, iy, z], [-ix, -iy, z]]

        walls = [rect(hx, hy, 0.0), rect(hx, hy, h)]
        walls += [
            [[sx * hx, sy * hy, 0.0], [sx * hx, sy * hy, h]] for sx in (-1, 1) for sy in (-1, 1)
        ]
        self.rec.log(
            ARENA_WALLS, rr.LineStrips3D(walls, colors=[(150, 150, 150)], radii=0.003), static=True
        )
        ri, ro = arena.ring_inner_m, arena.ring_inset_m
        ring = [rect(hx - ro, hy - ro, 0.001), rect(hx - ri, hy - ri, 0.001)]
        self.rec.log(
            ARENA_RING, rr.LineStrips3D(ring, colors=[(255, 255, 255)], radii=0.002), static=True
        )
        self.rec.log(
            ROBOT_BODY,
            rr.Ellipsoids3D(
                half_sizes=[[robot_radius_m, robot_radius_m, 0.01]],
                centers=[[0, 0, 0.01]],
                colors=[(80, 160, 255)],
                fill_mode="solid",
            ),
            static=True,
        )
        self.rec.log(
            ROBOT_HEADING,
            rr.Arrows3D(
                vectors=[[2.5 * robot_radius_m, 0, 0]],
                origins=[[0, 0, 0.02]],
                colors=[(255, 80, 80)],
            ),
            static=True,
        )

    def log_model_meta(
        self, model_name: str, outputs: Sequence[Output], *, root: str = MODEL_ROOT
    ) -> None:
        """Static series names carrying each output's unit, e.g. ``omega_dps [deg/s]``."""
        base = f"{root}/{entity_name(model_name)}"
        for o in outputs:
            self.rec.log(
                f"{base}/{o.name}", rr.SeriesLines(names=[f"{o.name} [{o.unit}]"]), static=True
            )

    # -- per frame data, in columns ------------------------------------------------------
    def _image_format(self, entity: str, h: int, w: int) -> None:
        if self._image_shapes.get(entity) == (h, w):
            return
        fmt = rr.components.ImageFormat(width=w, height=h, color_model="L", channel_datatype="U8")
        self.rec.log(entity, rr.Image.from_fields(format=fmt), static=True)
        self._image_shapes[entity] = (h, w)
        # static data goes through the SDK's batcher, frame columns straight to the file: flush
        # so that a file cut by a crash still holds the properties and the image format
        self.flush()

    def log_frames(
        self,
        frame: np.ndarray,
        t_s: np.ndarray,
        images: np.ndarray,
        capture_ns: np.ndarray | None = None,
    ) -> None:
        """Raw camera frames (N, H, W) uint8, never compressed lossily."""
        n, h, w = images.shape
        if n == 0:
            return
        self._image_format(CAMERA, h, w)
        self.rec.send_columns(
            CAMERA,
            indexes=_time_indexes(frame, t_s, capture_ns),
            columns=rr.Image.columns(buffer=images.reshape(n, h * w)),
        )
        self.frames_logged += n

    def log_poses(
        self,
        frame: np.ndarray,
        t_s: np.ndarray,
        poses: np.ndarray,
        capture_ns: np.ndarray | None = None,
    ) -> None:
        """Poses (N, 3) [x_m, y_m, heading_rad] as scalars, transforms and a trail. Rows with
        NaN (the tracker lost the robot) are left out: a gap, never an invented pose."""
        ok = np.isfinite(poses).all(axis=1)
        if not ok.any():
            return
        frame, t_s, poses = np.asarray(frame)[ok], np.asarray(t_s)[ok], poses[ok]
        capture_ns = None if capture_ns is None else np.asarray(capture_ns)[ok]
        idx = _time_indexes(frame, t_s, capture_ns)
        self.rec.send_columns(POSE, indexes=idx, columns=rr.Scalars.columns(scalars=poses))
        xyz = np.column_stack([poses[:, 0], poses[:, 1], np.zeros(len(poses))])
        self.rec.send_columns(
            ROBOT,
            indexes=idx,
            columns=rr.Transform3D.columns(translation=xyz, quaternion=_quaternions_z(poses[:, 2])),
        )
        self.rec.send_columns(
            ROBOT_PATH,
            indexes=idx,
            columns=rr.Points3D.columns(
                positions=xyz + np.array([0.0, 0.0, 0.002]),
                radii=np.full(len(poses), 0.003, np.float32),
            ),
        )

    def log_frame_timing(
        self,
        frame: np.ndarray,
        t_s: np.ndarray,
        repeat: np.ndarray,
        dropped_before: np.ndarray,
        dt_s: np.ndarray,
    ) -> None:
        """Per frame of a real camera: repeats the previous frame (0/1), frames missing just
        before it, and the true seconds since the previous frame."""
        if not self._timing_names_logged:
            self.rec.log(FRAME_TIMING, rr.SeriesLines(names=list(FRAME_TIMING_NAMES)), static=True)
            self._timing_names_logged = True
        values = np.column_stack(
            [repeat.astype(np.float64), dropped_before.astype(np.float64), dt_s]
        )
        self.rec.send_columns(
            FRAME_TIMING,
            indexes=_time_indexes(frame, t_s, None),
            columns=rr.Scalars.columns(scalars=values),
        )

    def log_native_metrics(self, frame: np.ndarray, t_s: np.ndarray, values: np.ndarray) -> None:
        """Per frame of a source with native frames: the standard metrics on its native luma,
        (N, len(NATIVE_METRICS)), one series each (vdc.frame_metrics)."""
        if not self._native_names_logged:
            self.rec.log(
                NATIVE_METRICS_PATH, rr.SeriesLines(names=list(NATIVE_METRICS)), static=True
            )
            self._native_names_logged = True
        self.rec.send_columns(
            NATIVE_METRICS_PATH,
            indexes=_time_indexes(frame, t_s, None),
            columns=rr.Scalars.columns(scalars=values),
        )

    def log_link_stats(
        self, frame: int, t_s: float, stats: Mapping[str, int], capture_ns: int | None = None
    ) -> None:
        """The serial link's running counts (packets, bad CRC, lost frames, ...)."""
        if not self._link_names_logged:
            self.rec.log(LINK_STATS, rr.SeriesLines(names=list(stats)), static=True)
            self._link_names_logged = True
        idx = _time_indexes(
            np.array([frame]),
            np.array([t_s]),
            None if capture_ns is None else np.array([capture_ns]),
        )
        values = np.array([[float(v) for v in stats.values()]])
        self.rec.send_columns(LINK_STATS, indexes=idx, columns=rr.Scalars.columns(scalars=values))

    def log_wall_tf(
        self,
        frame: np.ndarray,
        t_s: np.ndarray,
        tf_hz: np.ndarray,
        capture_ns: np.ndarray | None = None,
    ) -> None:
        self.rec.send_columns(
            WALL_TF,
            indexes=_time_indexes(frame, t_s, capture_ns),
            columns=rr.Scalars.columns(scalars=np.asarray(tf_hz, np.float64)),
        )

    def log_model_outputs(
        self,
        model_name: str,
        frame: np.ndarray,
        t_s: np.ndarray,
        outputs: Mapping[str, np.ndarray],
        *,
        root: str = MODEL_ROOT,
        capture_ns: np.ndarray | None = None,
    ) -> None:
        idx = _time_indexes(frame, t_s, capture_ns)
        base = f"{root}/{entity_name(model_name)}"
        for name, values in outputs.items():
            self.rec.send_columns(
                f"{base}/{name}",
                indexes=idx,
                columns=rr.Scalars.columns(scalars=np.asarray(values, float)),
            )

    def log_events(
        self,
        kind: str,
        frame: np.ndarray,
        t_s: np.ndarray,
        xy: np.ndarray,
        texts: Sequence[str],
        capture_ns: np.ndarray | None = None,
    ) -> None:
        """Sparse events of one ``kind``; those with a known arena position (N, 2) are also
        drawn there. A ``kind`` outside ``vdc.recording.EVENT_KINDS`` is refused (ValueError)."""
        if kind not in EVENT_KINDS:
            raise UserError(
                f"event kind {kind!r} is not in the recording contract; allowed: "
                f"{', '.join(EVENT_KINDS)} (vdc.recording)."
            )
        if len(frame) == 0:
            return
        level = EVENT_LEVELS.get(kind, "INFO")
        color = EVENT_COLORS.get(kind, (255, 255, 255))
        self.rec.send_columns(
            event_path(kind),
            indexes=_time_indexes(frame, t_s, capture_ns),
            columns=rr.TextLog.columns(text=list(texts), level=[level] * len(texts)),
        )
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ok = np.isfinite(xy).all(axis=1)
        if ok.any():
            idx = _time_indexes(
                np.asarray(frame)[ok],
                np.asarray(t_s)[ok],
                None if capture_ns is None else np.asarray(capture_ns)[ok],
            )
            self.rec.send_columns(
                event_path(kind),
                indexes=idx,
                columns=rr.Points3D.columns(
                    positions=np.column_stack([xy[ok], np.full(int(ok.sum()), 0.01)]),
                    radii=np.full(int(ok.sum()), 0.008, np.float32),
                    colors=np.tile(np.array(color, np.uint8), (int(ok.sum()), 1)),
                ),
            )

    def log_overhead(
        self, frames: Sequence[int], t_s: Sequence[float], images: Sequence[np.ndarray]
    ) -> None:
        if not images:
            return
        stack = np.stack(images)
        n, h, w = stack.shape
        self._image_format(OVERHEAD, h, w)
        self.rec.send_columns(
            OVERHEAD,
            indexes=_time_indexes(np.asarray(frames), np.asarray(t_s)),
            columns=rr.Image.columns(buffer=stack.reshape(n, h * w)),
        )

    def close(self, **run_end: Any) -> None:
        """Write the ``run_end`` property (frames, stop reason, ...), flush, write the footer.
        After a write error only what is safe is done: the reserve kept room for the footer,
        but a file writer that died cannot be flushed again."""
        if self._closed:
            return
        self._closed = True
        if self.live is not None:
            self.live.close()
        clean = {
            k: (v if not (isinstance(v, float) and math.isnan(v)) else None)
            for k, v in run_end.items()
        }
        self.send_properties({"run_end": clean})
        try:
            self.flush()
        except RecordingWriteError:
            return  # the file holds what was flushed before; readers repair it
        self.file_stream.disconnect()

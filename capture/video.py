"""Any video, image sequence or camera as a capture device (``vdc-capture video``).

Files are decoded with PyAV (FFmpeg) for their true presentation timestamps: the ``time``
timeline is the time of each frame since the first, so variable-frame-rate video and dropped
frames keep their real timing. Image sequences (``frames/%05d.png``) take their rate from
``fps``; cameras (an index such as ``0``) are read with OpenCV, stamped with the host's clock,
and run until Ctrl-C. Rotation metadata of phone videos is honoured.

Frames are converted to luma and area-resized to a working raster whose angular pitch is the
robot camera's (70°/99 px, the resolution the models were designed and calibrated for):
``width = round(fov_deg / (70/99))`` unless given, height from the aspect ratio.

Repeated frames (each frame shown twice, pulldown, webcams faster than their sensor) and
dropped frames (gaps in the timestamps) are detected per frame and recorded; the online model
sees only new frames, over true time (avdm.true_time). The device has no pose, arena or walls:
its batches carry None there and the recording holds none of those entities.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avdm.true_time import repeat_flags
from capture.device import Batch, Event
from capture.run import RecordResult
from vdc.cli_support import (
    API_ONLY,
    non_negative_float,
    non_negative_int,
    option,
    positive_float,
)
from vdc.recording import FOOTAGE_MODEL, camera_model_context, working_size


@dataclasses.dataclass(frozen=True)
class VideoSettings:
    """``vdc-capture video``: one field per flag, same names and defaults."""

    source: str = option(
        help="a video file, an image sequence such as frames/%05d.png, or a camera index",
        positional=True,
    )
    fov_deg: float = option(
        help="the camera's horizontal field of view, degrees", type=positive_float, required=True
    )
    fps: float | None = option(
        None, "frame rate of an image sequence (or a camera), Hz", type=positive_float
    )
    width: int | None = option(
        None, "working width, px (default: fov / (70/99 deg), the robot camera's pitch)"
    )
    model: str = option(
        FOOTAGE_MODEL,
        "the model to run (default: {default}, the AVDM valid 1-300 deg/s on real footage; "
        "avdm is the paper's, valid up to about 1 px of motion per frame)",
    )
    repeat_tol: float = option(
        0.5,
        "a frame whose mean |difference| from the previous is at most this (8-bit levels) "
        "repeats it",
        type=non_negative_float,
    )
    max_repeats: int = option(
        3, "longer still stretches are a still scene, not repeats", type=non_negative_int
    )
    batch_frames: int = dataclasses.field(default=128, metadata=API_ONLY)  # frames per batch

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fov_deg) and 1.0 <= self.fov_deg <= 360.0):
            raise ValueError(f"--fov-deg must be between 1 and 360 degrees, got {self.fov_deg:g}")
        if self.fps is not None and not (math.isfinite(self.fps) and 0 < self.fps <= 10_000):
            raise ValueError(f"--fps must be between 0 and 10000 Hz, got {self.fps:g}")
        if self.width is not None and not 8 <= self.width <= 4096:
            raise ValueError(f"--width must be between 8 and 4096 px, got {self.width}")
        if not (self.repeat_tol >= 0 and self.max_repeats >= 0):
            raise ValueError("--repeat-tol and --max-repeats must be >= 0")

    @property
    def kind(self) -> str:
        """``file`` (an existing file wins, even one named ``2024`` or ``clip 100%.mkv``),
        ``camera`` (an index such as ``0``) or ``images`` (a pattern with ``%``)."""
        if Path(self.source).is_file():
            return "file"
        if self.source.isdigit():
            return "camera"
        return "images" if "%" in self.source else "file"

    def working_size(self, src_h: int, src_w: int) -> tuple[int, int]:
        """(H, W) of the frames the models see (``vdc.recording.working_size``)."""
        return working_size(src_h, src_w, self.fov_deg, self.width)


# (luma (H, W) uint8, time since the first frame in s, what went wrong just before it or None)
SourceFrame = tuple[np.ndarray, float, str | None]


class _Reader:
    """Frames and their times (s) from one source; ``info`` describes it. ``error``: why the
    source ended early (None when it ended normally); ``problems``: frames lost inside it
    (missing or unreadable images, packets that would not decode), counted."""

    info: dict[str, Any]
    error: str | None = None
    problems: int = 0
    first_problem: str | None = None

    def frames(self) -> Iterator[SourceFrame]:  # pragma: no cover - interface
        raise NotImplementedError

    def _problem(self, text: str) -> str:
        self.problems += 1
        self.first_problem = self.first_problem or text
        return text

    def close(self) -> None:
        pass


class _PyAvReader(_Reader):
    def __init__(self, path: str) -> None:
        import av

        p = Path(path)
        if not p.exists():
            raise ValueError(f"video {path!r}: no such file")
        if p.stat().st_size == 0:
            raise ValueError(f"video {path!r} is empty")
        try:
            self.container = av.open(path)
        except av.FFmpegError as exc:
            raise ValueError(f"cannot read {path!r} as a video: {_ffmpeg_reason(exc)}") from None
        if not self.container.streams.video:
            self.container.close()
            raise ValueError(f"{path!r} holds no video stream")
        self.stream = self.container.streams.video[0]
        self.stream.thread_type = "AUTO"
        rate = self.stream.average_rate or self.stream.guessed_rate or self.stream.base_rate
        self.info = {
            "kind": "file",
            "codec": self.stream.codec_context.name,
            "nominal_fps": float(rate) if rate else float("nan"),
            "src_width_px": self.stream.codec_context.width,
            "src_height_px": self.stream.codec_context.height,
            "n_frames_header": int(self.stream.frames or 0),
            "rotation_deg": 0,
            # what the container's header says (µs); a file cut short ends before it
            "duration_s": (self.container.duration or 0) / 1e6,
        }
        self._frames = self._decode()
        first = next(self._frames, None)  # a file with no decodable frame fails here
        if first is None:
            self.container.close()
            why = f": {self.error}" if self.error else ""
            raise ValueError(f"{path!r} holds no decodable video frame{why}")
        self._first = first
        self.info["src_height_px"], self.info["src_width_px"] = first[0].shape[:2]

    def _decode(self) -> Iterator[SourceFrame]:
        """Packet by packet, so that one packet that will not decode costs its own frames
        only: the error is noted on the next frame and decoding goes on (a whole-stream decode
        stops at the first bad packet). A container that cannot be demuxed further ends here."""
        import av

        t0: float | None = None
        i = 0
        note: list[str] = []
        try:
            for packet in self.container.demux(self.stream):
                try:
                    decoded = packet.decode()
                except av.FFmpegError as exc:
                    note.append(self._problem(f"a packet would not decode: {_ffmpeg_reason(exc)}"))
                    continue
                for frame in decoded:
                    t = frame.time
                    if t is None:
                        t = i / self.info["nominal_fps"]
                    t0 = t if t0 is None else t0
                    rot = round(float(getattr(frame, "rotation", 0) or 0))
                    self.info["rotation_deg"] = rot
                    luma = frame.to_ndarray(format="gray")
                    if rot % 360:  # the display matrix's counter-clockwise angle
                        luma = np.ascontiguousarray(np.rot90(luma, k=round(rot / 90)))
                    yield luma, float(t - t0), ("; ".join(note) or None)
                    note, i = [], i + 1
        except av.FFmpegError as exc:  # a cut or corrupt container: keep what came before
            self.error = _ffmpeg_reason(exc)

    def frames(self) -> Iterator[SourceFrame]:
        yield self._first
        yield from self._frames

    def close(self) -> None:
        self.container.close()


class _CameraReader(_Reader):
    """A camera by index, read with OpenCV and stamped with the host's clock."""

    def __init__(self, source: str, fps: float | None) -> None:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        self.cap = cv2.VideoCapture(int(source))
        if not self.cap.isOpened():
            raise ValueError(f"camera {source} cannot be opened (no such camera)")
        ok, first = self.cap.read()
        if not ok or first is None:
            self.cap.release()
            raise ValueError(f"camera {source} gives no frame")
        self.first = first
        cam_fps = self.cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps or (cam_fps if cam_fps and cam_fps > 0 else 30.0)
        h, w = first.shape[:2]
        self.info = {
            "kind": "camera",
            "codec": "camera",
            "nominal_fps": float(self.fps),
            "src_width_px": w,
            "src_height_px": h,
            "n_frames_header": 0,
            "rotation_deg": 0,
        }

    def frames(self) -> Iterator[SourceFrame]:
        t0 = time.monotonic()
        img = self.first
        while img is not None:
            yield _luma(img), time.monotonic() - t0, None
            ok, img = self.cap.read()
            img = img if ok else None

    def close(self) -> None:
        self.cap.release()


def _luma(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


_PATTERN_FIELD = re.compile(r"%(0?)(\d*)d")


def _jpeg_cut(path: Path) -> bool:
    """A JPEG without its end-of-image marker was cut short (OpenCV decodes it anyway, with
    the missing part grey); trailing padding after the marker is allowed."""
    with path.open("rb") as fh:
        fh.seek(max(0, path.stat().st_size - 4096))
        tail = fh.read().rstrip(b"\x00")
    return not tail.endswith(b"\xff\xd9")


class _ImageSequenceReader(_Reader):
    """Numbered images (``frames/%05d.png``), timed by their number and ``fps``.

    Every number from the first file to the last is a frame: a missing number, a file that
    will not decode or a JPEG cut short is a lost frame, noted on the next good one (and so
    recorded as a dropped frame with its reason), never a silent end of the sequence."""

    def __init__(self, pattern: str, fps: float | None) -> None:
        if fps is None:
            raise ValueError("an image sequence needs --fps (its frame rate)")
        fields = list(_PATTERN_FIELD.finditer(pattern))
        if len(fields) != 1:
            raise ValueError(
                f"image sequence {pattern!r}: give one number field such as %05d "
                "(a file with % in its name is read as a video when it exists)"
            )
        field = fields[0]
        head, tail = pattern[: field.start()], pattern[field.end() :]
        folder_text, _, prefix = head.rpartition("/")
        folder, suffix = Path(folder_text or "."), tail
        number = re.compile(re.escape(prefix) + r"(\d+)" + re.escape(suffix) + "$")
        found: dict[int, Path] = {}
        if folder.is_dir():
            for entry in folder.iterdir():
                m = number.match(entry.name)
                if m and (not field.group(2) or len(m.group(1)) >= int(field.group(2))):
                    found.setdefault(int(m.group(1)), entry)
        if not found:
            raise ValueError(f"image sequence {pattern!r} cannot be opened (no matching files)")
        width = f"{field.group(1)}{field.group(2)}d"
        self.name_of = lambda k: Path(head + format(k, width) + tail).name
        self.paths = found
        self.first_index, self.last_index = min(found), max(found)
        self.fps = float(fps)
        first = None
        for k in range(self.first_index, self.last_index + 1):  # the first readable image
            first = self._read(k)
            if first is not None:
                break
        if first is None:
            raise ValueError(f"image sequence {pattern!r}: no image in it can be read")
        self.problems, self.first_problem = 0, None  # counted again when the frames are read
        h, w = first.shape
        self.info = {
            "kind": "images",
            "codec": "image files",
            "nominal_fps": self.fps,
            "src_width_px": w,
            "src_height_px": h,
            "n_frames_header": self.last_index - self.first_index + 1,
            "rotation_deg": 0,
        }
        self.size = (h, w)

    def _read(self, k: int) -> np.ndarray | None:
        path = self.paths.get(k)
        if path is None:
            return None
        if path.suffix.lower() in (".jpg", ".jpeg") and _jpeg_cut(path):
            return None
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim not in (2, 3):
            return None
        if img.dtype != np.uint8:  # 16-bit PNG/TIFF: the top 8 bits
            img = (img >> 8).astype(np.uint8) if img.dtype == np.uint16 else None
            if img is None:
                return None
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        return _luma(img)

    def frames(self) -> Iterator[SourceFrame]:
        note: list[str] = []
        k0: int | None = None  # the first image read: time 0
        for k in range(self.first_index, self.last_index + 1):
            img = self._read(k)
            path = self.paths.get(k)
            why = (
                None
                if img is not None and img.shape == self.size
                else "missing"
                if path is None
                else "of another size"
                if img is not None
                else "unreadable or cut short"
            )
            if why is not None:
                name = path.name if path is not None else self.name_of(k)
                note.append(self._problem(f"image {name} {why}"))
                continue
            k0 = k if k0 is None else k0
            yield img, (k - k0) / self.fps, ("; ".join(note) or None)
            note = []


def _ffmpeg_reason(exc: Exception) -> str:
    return str(getattr(exc, "strerror", None) or exc).strip().rstrip(".")


def open_source(settings: VideoSettings) -> _Reader:
    if settings.kind == "file":
        return _PyAvReader(settings.source)
    if settings.kind == "camera":
        return _CameraReader(settings.source, settings.fps)
    return _ImageSequenceReader(settings.source, settings.fps)


class VideoSource:
    """A video, image sequence or camera as a capture device (connect / read / disconnect).

    The source is opened by the constructor, so a missing or unreadable one fails before any
    file is written; ``info`` then holds its codec, nominal fps, size and rotation."""

    def __init__(self, settings: VideoSettings) -> None:
        self.settings = settings
        self.reader = open_source(settings)
        self.info = self.reader.info
        fps = settings.fps or self.info["nominal_fps"]
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"{settings.source!r} states no frame rate: pass --fps")
        self.fps = float(fps)
        self._it: Iterator[SourceFrame] | None = None
        self._size: tuple[int, int] | None = None
        self._index = 0
        self._prev: np.ndarray | None = None
        self._prev_t: float | None = None
        self._run = 0
        self.dropped_total = 0
        self.repeats_total = 0
        self.last_t_s: float | None = None

    def working_size(self) -> tuple[int, int]:
        if self._size is None:
            self._size = self.settings.working_size(
                self.info["src_height_px"], self.info["src_width_px"]
            )
        return self._size

    def connect(self) -> None:
        if self._it is None:
            self._it = self.reader.frames()

    def read(self) -> Batch | None:
        assert self._it is not None, "connect() first"
        images, times, notes = [], [], []
        h, w = self.working_size()
        for luma, t, note in self._it:
            images.append(cv2.resize(luma, (w, h), interpolation=cv2.INTER_AREA))
            times.append(t)
            notes.append(note)
            if len(images) >= self.settings.batch_frames:
                break
        if not images:
            return None
        frames = np.stack(images)
        # whole nanoseconds, as the recording stores them: recomputation from the file then
        # sees exactly the times the online model saw
        t_s = np.rint(np.asarray(times, dtype=np.float64) * 1e9) / 1e9
        repeat = repeat_flags(
            frames, self._prev, self._run, self.settings.repeat_tol, self.settings.max_repeats
        )
        run = self._run
        for r in repeat:  # the run of repeats that ends this batch carries into the next
            run = run + 1 if r else 0
        self._run = run
        prev_t = np.concatenate(([np.nan if self._prev_t is None else self._prev_t], t_s))
        dt = np.diff(prev_t)
        with np.errstate(invalid="ignore"):
            missing = np.where(np.isfinite(dt), np.rint(dt * self.fps) - 1, 0)
        # a gap of more than half a frame interval beyond the nominal one is a dropped frame
        dropped = np.where(dt * self.fps > 1.5, np.maximum(missing, 1), 0).astype(np.int64)
        frame = np.arange(self._index, self._index + len(frames), dtype=np.int64)
        events = [
            Event(
                "dropped_frames",
                int(f),
                math.nan,
                math.nan,
                math.nan,
                f"{n} frame(s) missing before frame {f} ({dt_i * 1000:.1f} ms gap)",
            )
            for f, n, dt_i in zip(frame, dropped, dt, strict=True)
            if n > 0
        ]
        events += [  # frames lost inside the source, with the reason
            Event("decode_error", int(f), math.nan, math.nan, math.nan, f"before frame {f}: {n}")
            for f, n in zip(frame, notes, strict=True)
            if n
        ]
        self._index += len(frames)
        self._prev, self._prev_t = frames[-1], float(t_s[-1])
        self.last_t_s = self._prev_t
        self.dropped_total += int(dropped.sum())
        self.repeats_total += int(repeat.sum())
        err = self.reader.error
        if err and len(images) < self.settings.batch_frames:
            events.append(
                Event(
                    "decode_error",
                    int(frame[-1]),
                    math.nan,
                    math.nan,
                    math.nan,
                    f"decoding stopped after frame {int(frame[-1])}: {err}",
                )
            )
        return Batch(
            frame=frame,
            t_s=t_s,
            images=frames,
            poses=None,
            wall_tf_hz=None,
            events=events,
            repeat=repeat,
            dropped_before=dropped,
        )

    def disconnect(self) -> None:
        self.reader.close()

    def __enter__(self) -> VideoSource:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


@dataclasses.dataclass
class VideoRecordResult:
    """A video recording, with what was found about the source's frames."""

    record: RecordResult
    info: dict[str, Any]  # the source: codec, nominal fps, size, rotation
    repeats: int  # frames that repeated the previous one
    dropped: int  # frames missing according to the timestamps
    decode_error: str | None  # why decoding stopped early, if it did
    calibration: dict[str, Any]
    lost: int = 0  # frames lost inside the source (bad packets, missing or bad images)
    first_loss: str | None = None  # the first of them, named


def recording_id(settings: VideoSettings) -> str:
    """``video-<name>-<8 hex>``: the hex covers the source (path, size, modification time) and
    every setting, so a changed file or setting never reuses an old id."""
    src = settings.source
    stem = "camera" + src if settings.kind == "camera" else Path(src).stem.replace("%", "")
    p = Path(src)
    stat = (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else ()
    text = repr((str(p.resolve()) if p.exists() else src, stat, dataclasses.astuple(settings)))
    safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in stem)[:40] or "video"
    if settings.kind == "camera":  # a live camera: every run is new
        text += time.strftime("%Y%m%d-%H%M%S")
    return f"video-{safe}-{hashlib.sha1(text.encode()).hexdigest()[:8]}"


def _calibrated(model: Any) -> Any:
    """The params whose calibration the recording reports (the AVDM kinds), else None."""
    from avdm.avdm_model import AvdmParams
    from avdm.avdm_multiscale import AvdmMultiScaleParams

    p = model.params
    return p if isinstance(p, AvdmParams | AvdmMultiScaleParams) else None


def record_video(
    settings: VideoSettings,
    out: str | Path | None = None,
    *,
    force: bool = False,
    live_url: str | None = None,
    spawn: bool = False,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
    calibration_progress: Callable[[int], Any] | None = None,
) -> VideoRecordResult:
    """Profile a video, image sequence or camera into ``out`` (default
    ``recordings/<recording id>.rrd``). A missing, empty or unreadable source raises
    ValueError before the file exists; a file cut short keeps the frames before the cut."""
    from avdm.calibration_store import calibration_for
    from avdm.registry import make_model
    from avdm.true_time import TrueTimeModel
    from capture.output import claim_output
    from capture.recorder import Recorder, spawn_viewer, video_blueprint
    from capture.run import finish_output, run_capture
    from vdc.provenance import machine_info, package_versions

    rid = recording_id(settings)
    path = Path(out) if out else Path("recordings") / f"{rid}.rrd"
    src = Path(settings.source)
    if settings.kind == "file" and path.exists() and src.exists() and src.samefile(path):
        raise ValueError(
            f"the output {str(path)!r} is the source video: writing it would destroy the input; "
            "choose another --out"
        )
    device = VideoSource(settings)  # opens the source: bad input fails here
    claim = claim_output(path, force)  # exclusive from here; bad folders fail here
    recorder = None
    try:
        h, w = device.working_size()
        # the one context every model of this recording is built with, online and offline
        context = camera_model_context(w, h, device.fps, settings.fov_deg)
        deg_per_px = float(context["deg_per_px"])
        built = make_model(settings.model, **context)
        cal = calibration_for(
            device.fps, deg_per_px, progress=calibration_progress, params=_calibrated(built)
        )
        model = TrueTimeModel(built)
        live = spawn_viewer() if spawn else live_url
        recorder = Recorder(
            claim.partial, rid, blueprint=video_blueprint(model.name, model.outputs), live_url=live
        )
        info = device.info
        recorder.send_properties(
            {
                "run": {"recording_id": rid, "source": "video", "behaviour": "video"},
                "video": {
                    "path": settings.source,
                    "kind": info["kind"],
                    "codec": info["codec"],
                    "nominal_fps": info["nominal_fps"],
                    "src_width_px": info["src_width_px"],
                    "src_height_px": info["src_height_px"],
                    "fov_deg": settings.fov_deg,
                    "rotation_deg": info["rotation_deg"],
                    "repeat_tol": settings.repeat_tol,
                    "max_repeats": settings.max_repeats,
                },
                "camera": {
                    "fps": device.fps,
                    "width_px": w,
                    "height_px": h,
                    "hfov_deg": settings.fov_deg,
                },
                "model": {"name": model.name, "true_time": True},
                "model_context": dict(context),
                "model_params": {k: v for k, v in model.params.to_dict().items() if v is not None},
                "calibration": {
                    k: cal[k]
                    for k in (
                        "a",
                        "b",
                        "r2",
                        "rms_rel_error",
                        "max_rel_error",
                        "n_points",
                        "source",
                    )
                    if k in cal
                },
                "provenance": {**package_versions(), **machine_info()},
            }
        )
        recorder.log_model_meta(model.name, model.outputs)
        if log is not None:
            log(
                f"recording {rid}: {settings.source} ({info['codec']}, {info['src_width_px']}x"
                f"{info['src_height_px']}, {device.fps:.6g} fps) as {w}x{h} px luma at "
                f"{deg_per_px:.4g} deg/px, model {model.name}"
            )
        total = info["n_frames_header"] or None
        result = run_capture(device, model, recorder, total_frames=total, progress=progress)
    finally:
        finish_output(claim, recorder)
    error = getattr(device.reader, "error", None)
    stated = float(info.get("duration_s") or 0.0)
    finished = result.stop_reason == "finished"  # a signal or a full disk is not a cut file
    if error is None and finished and stated > 0 and device.last_t_s is not None:
        # the frames end well before the duration the header states: the file was cut
        if device.last_t_s + 2.0 / device.fps < stated:
            error = (
                f"the file ends at {device.last_t_s:.2f} s but its header says {stated:.2f} s "
                "(cut short?)"
            )
    return VideoRecordResult(
        RecordResult.of(path, rid, result, total),
        info,
        device.repeats_total,
        device.dropped_total,
        error,
        cal,
        device.reader.problems,
        device.reader.first_problem,
    )

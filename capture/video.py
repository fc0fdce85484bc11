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
dropped frames (gaps in the timestamps; before the first frame, the gap from the stream's start
to it) are detected per frame and recorded, and the frames lost after the last one are those the
container states less those read and dropped (``vdc.stream_counts.end_fields``); the online model
sees only new frames, over true time (avdm.true_time). The device has no pose, arena or walls:
its batches carry None there and the recording holds none of those entities.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from avdm.avdm_model import AvdmParams
from avdm.avdm_multiscale import AvdmMultiScaleParams
from avdm.calibration_store import FitNote, calibration_for, fit_progress
from avdm.registry import make_model
from avdm.true_time import TrueTimeModel
from capture.device import Batch, DeviceContext, Event
from capture.output import claim_output
from capture.recording_start import start_recording
from capture.run import DEFAULT_CAPTURE, CaptureOptions, RecordResult, finish_output, run_capture
from vdc.blueprints import video_blueprint
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.frame_batches import FrameBatcher, RateLookahead
from vdc.heartbeat import Count
from vdc.parquet_io import WroteFiles
from vdc.recording import FOOTAGE_MODEL, camera_model_context, working_size
from vdc.settings import API_ONLY, AT_LEAST_0, AT_LEAST_1, RANGE, Settings, between
from vdc.source_names import source_kind, source_name
from vdc.sources import Reader, open_reader


@dataclasses.dataclass(frozen=True)
class VideoSettings(Settings):
    """``vdc-capture video``: one field per flag, same names and defaults."""

    source: str = option(
        help="a video file, an image sequence such as frames/%05d.png, or a camera index",
        positional=True,
    )
    fov_deg: float = option(
        help="the camera's horizontal field of view, degrees",
        range=between(1, 360),
        required=True,
    )
    fps: float | None = option(
        None,
        "frame rate of an image sequence (or a camera), Hz",
        range=between(0, 10_000, lo_open=True),
    )
    width: int | None = option(
        None,
        "working width, px (default: fov / (70/99 deg), the robot camera's pitch)",
        range=between(8, 4096),
    )
    model: str = option(
        FOOTAGE_MODEL,
        "the model to run (default: {default}, the AVDM valid 1-300 deg/s on real footage; "
        "avdm is the paper's, valid up to about 1 px of motion per frame)",
    )
    repeat_tol: float = option(
        0.5,
        "a frame whose mean |difference| from the previous, on the native frames, is at most "
        "this (8-bit levels) "
        "repeats it",
        range=AT_LEAST_0,
    )
    max_repeats: int = option(
        3, "longer still stretches are a still scene, not repeats", range=AT_LEAST_0
    )
    batch_frames: int = dataclasses.field(
        default=128, metadata={**API_ONLY, RANGE: AT_LEAST_1}
    )  # frames per batch

    @property
    def kind(self) -> str:
        """``file``, ``camera`` or ``images`` (``vdc.source_names.source_kind``)."""
        return source_kind(self.source)

    def working_size(self, src_h: int, src_w: int) -> tuple[int, int]:
        """(H, W) of the frames the models see (``vdc.recording.working_size``)."""
        return working_size(src_h, src_w, self.fov_deg, self.width)


def open_source(settings: VideoSettings) -> Reader:
    """The reader of ``settings.source`` (a video file, an image sequence or a camera)."""
    return open_reader(settings.source, settings.fps)


class VideoSource(DeviceContext):
    """A video, image sequence or camera as a capture device (connect / read / disconnect).

    The source is opened by the constructor, so a missing or unreadable one fails before any
    file is written; ``info`` then holds its codec, nominal fps, size and rotation."""

    def __init__(self, settings: VideoSettings) -> None:
        self.settings = settings
        self.reader = open_source(settings)
        self.info = self.reader.info
        fps = settings.fps or self.info["nominal_fps"]
        if not (math.isfinite(fps) and fps > 0):
            raise UserError(f"{settings.source!r} states no frame rate: pass --fps.")
        self.fps = float(fps)
        self._batches: FrameBatcher | None = None
        self._ahead: RateLookahead | None = None
        self._size: tuple[int, int] | None = None

    def working_size(self) -> tuple[int, int]:
        if self._size is None:
            self._size = self.settings.working_size(
                self.info["src_height_px"], self.info["src_width_px"]
            )
        return self._size

    def properties(self) -> dict[str, dict[str, Any]]:
        """The recording's ``video`` and ``camera`` property sections: what this source is."""
        info, settings = self.info, self.settings
        h, w = self.working_size()
        video = {k: info[k] for k in ("kind", "codec", "nominal_fps", "src_width_px")}
        video |= {"src_height_px": info["src_height_px"], "fov_deg": settings.fov_deg}
        video |= {
            "rotation_deg": info["rotation_deg"],
            # the duration the file's header states (s, from the stream's start): a cut file
            # ends before it; the frames it states it holds (None: it states none); its first
            # frame's time after the stream's start (s)
            "header_duration_s": info.get("duration_s") or None,
            "container_frames": info.get("container_frames"),
            "first_frame_s": info.get("first_frame_s", 0.0),
            "bit_depth": info["bit_depth"],
            "color_range": info["color_range"],
            "repeat_tol": settings.repeat_tol,
            "max_repeats": settings.max_repeats,
        }
        rate = self.model_rate()  # the rate the models run at, and why (RATE_REASONS)
        video |= {"model_fps": rate.fps, "model_fps_reason": rate.reason}
        camera = {"fps": self.fps, "width_px": w, "height_px": h, "hfov_deg": settings.fov_deg}
        return {"video": {"path": settings.source, **video}, "camera": camera}

    def description(self) -> str:
        """What a recording of this source holds, in a sentence (its ``/description``)."""
        info, settings = self.info, self.settings
        h, w = self.working_size()
        return (
            f"the {settings.kind} {settings.source} ({info['codec']}, "
            f"{info['src_width_px']}x{info['src_height_px']}, {self.fps:.6g} fps, "
            f"{settings.fov_deg:g} deg wide) as {w}x{h} px luma; per frame its timing "
            "(repeats, drops) and the standard metrics on the native frames"
        )

    def connect(self) -> None:
        if self._batches is None:
            s = self.settings
            self._batches = FrameBatcher(
                self.reader,
                self.working_size(),
                self.fps,
                batch_frames=s.batch_frames,
                repeat_tol=s.repeat_tol,
                max_repeats=s.max_repeats,
            )

    @property
    def dropped_total(self) -> int:
        """Frames lost before and between the frames read so far (the times' gaps)."""
        return self._batches.dropped_total if self._batches else 0

    def end_fields(self, finished: bool) -> dict[str, Any]:
        """The counts of the source once read (``vdc.frame_batches.FrameBatcher.end_fields``):
        with those lost after its last frame where it was read to its end (``finished``)."""
        assert self._batches is not None, "connect() first"
        return self._batches.end_fields(ended=finished and self._batches.ended)

    @property
    def repeats_total(self) -> int:
        return self._batches.repeats_total if self._batches else 0

    @property
    def last_t_s(self) -> float | None:
        return self._batches.last_t_s if self._batches else None

    def model_rate(self) -> Any:
        """The rate the models are built at and why (``avdm.true_time.ModelRate``), decided
        before the model is built on the stream's repeats: the source is read ahead
        (``vdc.frame_batches.RateLookahead``, the whole of it where it fits) and its frames
        handed out again by :meth:`read`. A live camera runs at its own rate."""
        self.connect()
        assert self._batches is not None
        if self._ahead is None:
            live = self.info["kind"] == "camera"
            # the read-ahead decodes the clip (the whole of it where it fits), most of a
            # file's time: its frames counted on the command's heartbeat line (vdc.heartbeat)
            total = None if live else self.info.get("container_frames")
            with Count(total, f"decoding {self.settings.source}", "frame") as decoded:
                self._ahead = RateLookahead(
                    self._batches, self.settings.max_repeats, live, progress=decoded.update
                )
        return self._ahead.rate

    def final_rate(self) -> Any:
        """:meth:`model_rate` once read: a note where a stream longer than the frames it was
        decided on breaks its cadence later."""
        return self._ahead.final_rate() if self._ahead is not None else None

    def read(self) -> Batch | None:
        return self._next()

    def _next(self) -> Batch | None:
        assert self._batches is not None, "connect() first"
        fb = (self._ahead or self._batches).next_batch()
        if fb is None:
            return None
        frame, dropped, dt, notes = fb.frame, fb.dropped_before, fb.dt_s, fb.notes
        start_s = float(self.info.get("first_frame_s") or 0.0)
        events = [
            Event(
                "dropped_frames",
                int(f),
                math.nan,
                math.nan,
                math.nan,
                f"{n} frame(s) missing before frame {f} ("
                + (
                    f"{dt_i * 1000:.1f} ms gap)"
                    if math.isfinite(dt_i)
                    else f"it comes {start_s:.3f} s after the stream's start)"
                ),
            )
            for f, n, dt_i in zip(frame, dropped, dt, strict=True)
            if n > 0
        ]
        events += [  # frames lost inside the source, with the reason
            Event("decode_error", int(f), math.nan, math.nan, math.nan, f"before frame {f}: {n}")
            for f, n in zip(frame, notes, strict=True)
            if n
        ]
        err = self.reader.error
        if err and self._batches.ended:
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
            t_s=fb.t_s,
            images=fb.images,
            poses=None,
            wall_tf_hz=None,
            events=events,
            repeat=fb.repeat,
            dropped_before=dropped,
            native_metrics=fb.native_metrics,
        )

    def disconnect(self) -> None:
        self.reader.close()


@dataclasses.dataclass(kw_only=True)
class VideoRecordResult(WroteFiles):
    """A video recording, with what was found about the source's frames."""

    record: RecordResult
    info: dict[str, Any]  # the source: codec, nominal fps, size, rotation
    repeats: int  # frames that repeated the previous one
    dropped: int  # frames lost: before, between (the timestamps' gaps) and after the frames
    decode_error: str | None  # why decoding stopped early, if it did
    calibration: dict[str, Any]
    lost: int = 0  # frames lost inside the source (bad packets, missing or bad images)
    first_loss: str | None = None  # the first of them, named
    # the frames the source states it holds (None: it states none, or a live camera) and
    # those of them lost after the last frame read (counted in ``dropped``; None: unknown)
    container_frames: int | None = None
    lost_after_last: int | None = None
    # the rate the models ran at and why (``avdm.true_time.RATE_REASONS``), and the one line
    # said about it (None: the container's rate, without doubt)
    model_fps: float | None = None
    model_fps_reason: str | None = None
    model_fps_note: str | None = None

    @property
    def paths(self) -> list[Path]:  # type: ignore[override]
        """The files it wrote: the recording (a calibration it fitted is a per-user cache)."""
        return [self.record.path]


def recording_id(settings: VideoSettings, out: str | Path | None = None) -> str:
    """``video-<name>-<8 hex>``: the name is ``out``'s file name when given, else the source's
    (``vdc.source_names.source_name``); the hex covers the source (path, size, modification time)
    and every setting, so a changed file or setting never reuses an old id."""
    src = settings.source
    p = Path(src)
    stat = (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else ()
    text = repr((str(p.resolve()) if p.exists() else src, stat, dataclasses.astuple(settings)))
    safe = (source_name(str(out)) if out else source_name(src))[:40]
    if settings.kind == "camera":  # a live camera: every run is new
        text += time.strftime("%Y%m%d-%H%M%S")
    return f"video-{safe}-{hashlib.sha1(text.encode()).hexdigest()[:8]}"


def _calibrated(model: Any) -> Any:
    """The params whose calibration the recording reports (the AVDM kinds), else None."""

    p = model.params
    return p if isinstance(p, AvdmParams | AvdmMultiScaleParams) else None


def record_video(
    settings: VideoSettings,
    out: str | Path | None = None,
    options: CaptureOptions = DEFAULT_CAPTURE,
    *,
    calibration_progress: Callable[[int], Any] | None = None,
) -> VideoRecordResult:
    """Profile a video, image sequence or camera into ``out`` (default
    ``recordings/<recording id>.rrd``), as ``options`` say; ``calibration_progress`` counts
    the cells of a calibration fit when this camera needs one. A missing, empty or unreadable
    source raises ValueError before the file exists; a file cut short keeps the frames before
    the cut."""

    rid = recording_id(settings, out)
    path = options.output_path(out, rid)
    src = Path(settings.source)
    if settings.kind == "file" and path.exists() and src.exists() and src.samefile(path):
        raise UserError(
            f"the output {str(path)!r} is the source video: writing it would destroy the input; "
            "choose another --out."
        )
    device = VideoSource(settings)  # opens the source: bad input fails here
    claim = claim_output(path, options.force)  # exclusive from here; bad folders fail here
    recorder = None
    try:
        h, w = device.working_size()
        # the models follow the rate of new frames where the whole stream's repeats keep a
        # cadence: a clip whose every frame is shown twice at 50 Hz is profiled as the 25-Hz
        # original; repeats that come and go with the motion leave the container's rate
        # (docs/guides/video.md)
        rate = device.model_rate()
        model_fps = rate.fps
        if rate.note and options.log is not None:
            options.log(f"{settings.source}: {rate.note}")
        # the one context every model of this recording is built with, online and offline
        context = camera_model_context(w, h, model_fps, settings.fov_deg)
        deg_per_px = float(context["deg_per_px"])
        # a new camera's fit runs inside make_model: count its steps there
        steps = None
        if calibration_progress is not None:

            def steps(note: FitNote) -> None:
                if note.stage == "step":
                    calibration_progress(1)

        with fit_progress(steps):
            built = make_model(settings.model, **context)
        cal = calibration_for(model_fps, deg_per_px, params=_calibrated(built))
        model = TrueTimeModel(built, cadence=rate.reason == "regular cadence")
        live = options.viewer_url()
        info = device.info
        recorder = start_recording(
            claim.partial,
            rid,
            blueprint=video_blueprint(model.name, model.outputs),
            live_url=live,
            model=model,
            context=context,
            model_fields={"true_time": True},
            model_note="run on the new frames over true time: repeats are held, not re-counted",
            device=device,
            analyse=[
                "vdc-analyse complexity REC --out results/complexity",
                "vdc-analyse tables REC --out results/tables",
                f"vdc-analyse compare REC --model {model.name} --model avdm --out results/compare",
            ],
            sections={
                "run": {"source": "video", "behaviour": "video"},
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
            },
        )
        if options.log is not None:
            options.log(
                f"recording {rid}: {settings.source} ({info['codec']}, {info['src_width_px']}x"
                f"{info['src_height_px']}, {device.fps:.6g} fps) as {w}x{h} px luma at "
                f"{deg_per_px:.4g} deg/px, model {model.name}."
            )
        total = info["n_frames_header"] or None
        result = run_capture(device, model, recorder, total_frames=total, progress=options.progress)
    finally:
        finish_output(claim, recorder)
    if result.plugin_error is not None:  # the one line names the clip too
        result.plugin_error.on(settings.source)
    error = getattr(device.reader, "error", None)
    finished = result.stop_reason == "finished"  # a signal or a full disk is not a cut file
    ends = device.end_fields(finished)
    final = device.final_rate() or rate
    if final.note != rate.note and options.log is not None:  # the cadence broke later
        options.log(f"{settings.source}: {final.note}")
    if error is None and finished:
        # the frames end well before the duration the header states: the file was cut
        error = ends["cut_note"]
    return VideoRecordResult(
        record=RecordResult.of(path, rid, result, total),
        info=info,
        repeats=device.repeats_total,
        dropped=ends["dropped_frames"],
        decode_error=error,
        calibration=cal,
        lost=device.reader.problems,
        first_loss=device.reader.first_problem,
        container_frames=ends["container_frames"],
        lost_after_last=ends["lost_after_last"],
        model_fps=model_fps,
        model_fps_reason=final.reason,
        model_fps_note=final.note,
    )

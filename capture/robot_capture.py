"""Capture from a real Colias-IV: serial packets + overhead tracker poses, joined on capture time.

The robot sends its frames and on-board model outputs over the serial link (capture.serial_link);
an overhead camera (a device index, a video file, or an image sequence such as
``frames/%05d.png``) gives poses through the ArUco tracker (capture.tracker). Every robot frame
gets the host's receive time (``capture_time``); its pose is the tracker sample nearest in host
time if one lies within ``max_gap_s``, otherwise none (a gap, logged as ``tracker_lost``; a pose
is never invented). Repeated frame indices are dropped (each frame is logged once), missing ones
are counted as lost and logged as ``link_error`` events with the parser's counts.

The handshake: the host sends the model it was given (PARAMS) with START, and the robot answers
with what it runs (ANNOUNCE: the model spec, its outputs and units, its camera). A robot running
another model, or sending other outputs, is refused before any file is written; a robot that
never announces (older firmware) is recorded with its model marked unverified.

This module holds the command (``vdc-capture robot``'s :class:`RobotSettings` and
:func:`record_robot`); the device itself, the link and the handshake, is
``capture.robot_device``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import sys
import time
from collections.abc import Callable
from pathlib import Path

from avdm.registry import make_model
from capture.config import SCENES, RobotConfig, WallConfig, parse_schedule
from capture.output import claim_output
from capture.recording_start import camera_line, start_recording
from capture.robot_device import ColiasRobotDevice, RobotCaptureConfig
from capture.run import DEFAULT_CAPTURE, CaptureOptions, RecordResult, finish_output, run_capture
from capture.tracker import save_calibration
from capture.wall_controller import WallController as WallController  # re-exported
from vdc.blueprints import default_blueprint
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.parquet_io import WroteFiles
from vdc.recording import LINK_STATS
from vdc.settings import AT_LEAST_0, AT_LEAST_1, POSITIVE, Settings


def _warn(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class RobotSettings(Settings):
    """``vdc-capture robot`` as a settings object (one field per flag, same names)."""

    port: str = option(help="the robot's serial device", required=True)
    camera: str = option(
        help="overhead camera: a device index, a video file or an image sequence such as "
        "frames/%05d.png",
        required=True,
    )
    calibration: str | None = option(
        None, "saved tracker homography (default: calibrate on the first overhead frame)"
    )
    camera_fps: float = option(10.0, "pace of a video file or image sequence", range=POSITIVE)
    tf_hz: float = option(0.0, "wall TF, Hz", range=AT_LEAST_0, exclusive="tf")
    tf_schedule: str | None = option(
        None,
        "e.g. 0:30m,3:30m, or a file with one TF:DURATION per line",
        metavar="S",
        exclusive="tf",
    )
    save_calibration: str | None = option(
        None, "save the tracker's homography (calibrated on the first frame)", metavar="FILE"
    )
    period_m: float = option(0.1, "wall period, m", range=POSITIVE)
    scene: str = option("grating", "what the walls show", choices=SCENES)
    wall_port: str | None = option(None, "LED wall controller's serial port (line protocol)")
    baud: int = option(3_000_000, "serial rate", range=AT_LEAST_1)
    model: str = option(
        "avdm",
        "the model the robot is to run: sent to it (PARAMS) with START; a robot that announces "
        "another model is refused",
    )

    def wall(self) -> WallConfig:
        schedule: tuple[tuple[float, float], ...] = ((self.tf_hz, 48 * 3600.0),)
        if self.tf_schedule:
            text = self.tf_schedule
            if Path(text).is_file():  # a schedule file: the same syntax, one segment a line
                lines = Path(text).read_text().splitlines()
                text = ",".join(ln.strip() for ln in lines if ln.strip() and ln.strip()[0] != "#")
            schedule = parse_schedule(text)
        return WallConfig(tf_schedule=schedule, period_m=self.period_m, scene=self.scene)


@dataclasses.dataclass(kw_only=True)
class RobotRecordResult(WroteFiles):
    """A robot recording and the serial link's counts; ``paths``: the recording, and the
    tracker's calibration when it was saved."""

    record: RecordResult
    link_stats: dict[str, int]
    # why the run ended early, when the robot broke what it announced (a frame of another
    # size or output count, another announcement mid-run); the frames before it are kept
    link_error: str | None = None

    calibration_file: Path | None = None

    @property
    def paths(self) -> list[Path]:  # type: ignore[override]
        return [self.record.path, *([self.calibration_file] if self.calibration_file else [])]


def record_robot(
    settings: RobotSettings,
    out: str | Path | None = None,
    options: CaptureOptions = DEFAULT_CAPTURE,
    *,
    warn: Callable[[str], None] | None = None,
) -> RobotRecordResult:
    """Record a real Colias-IV until it ends its run, the link is lost for good, or a signal
    (default ``recordings/robot-<time>-<hash>.rrd``), as ``options`` say. A missing port or
    camera, or a robot that announces another model than ``settings.model`` (or other
    outputs), raises ValueError before the file exists. A robot that does not announce itself
    is recorded with ``model.verified`` false, and ``warn`` (default: stderr) says so in one
    line."""

    wall = settings.wall()
    cfg = RobotCaptureConfig(
        port=settings.port,
        camera=settings.camera,
        baud=settings.baud,
        calibration=settings.calibration or "",
        camera_fps=settings.camera_fps,
        wall=wall,
        model=settings.model,
        wall_port=settings.wall_port or "",
    )
    wall_ctl = WallController(settings.wall_port, wall) if settings.wall_port else None
    device = ColiasRobotDevice(cfg, on_wall_tf=wall_ctl.update if wall_ctl else None)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    digest = hashlib.sha1(f"{settings.port}{settings.camera}{stamp}".encode()).hexdigest()[:8]
    rid = f"robot-{stamp}-{digest}"
    path = options.output_path(out, rid)
    claim = claim_output(path, options.force)  # exclusive from here; bad folders fail here
    recorder = None
    try:
        # a missing port or camera, or a robot running another model, fails here: no file yet
        device.connect()
        verified = device.announced is not None
        context = device.model_context  # the robot's announced camera, else the defaults
        if not verified:
            (warn or _warn)(
                f"warning: the robot did not announce its model ({device.link.no_announce}; "
                f"older firmware?): recording its outputs as "
                f"{settings.model}'s on a {camera_line(context)} camera, marked unverified"
            )
        live = options.viewer_url()
        model = make_model(device.model_name, **context)
        recorder = start_recording(
            claim.partial,
            rid,
            live_url=live,
            blueprint=default_blueprint(
                model.name, model.outputs, [("serial link counts", [LINK_STATS])]
            ),
            model=model,
            context=context,
            model_fields={"on_board": True, "verified": verified},
            model_note=(
                "run on board; the robot announced it"
                if verified
                else "run on board; UNVERIFIED: the robot did not announce its model"
            ),
            device=device,
            analyse=[
                "vdc-analyse tables REC --out results/tables",
                "vdc-analyse profile REC --out results/profile",
                "vdc-analyse complexity REC --out results/complexity",
            ],
        )
        recorder.log_arena(device.arena, RobotConfig().radius_m)
        if settings.save_calibration:
            h = device.calibrate_tracker()
            if h is None:
                raise UserError("no overhead frame yet to calibrate from.")
            save_calibration(h, Path(settings.save_calibration))
        if options.log is not None:
            options.log(
                f"recording {rid} from {settings.port} (camera {settings.camera}) -> {path}."
            )
        result = run_capture(device, None, recorder, total_frames=None, progress=options.progress)
    finally:
        finish_output(claim, recorder)
    return RobotRecordResult(
        record=RecordResult.of(path, rid, result, None),
        link_stats=device.link_stats(),
        calibration_file=Path(settings.save_calibration) if settings.save_calibration else None,
        link_error=device.link_error,
    )

"""The simulated arena and robot as a capture device.

Like LeRobot's devices, a config plus one interface that the simulated and the real robot both
implement: ``connect()``, ``read()`` (the next ``Batch`` of frames, or None at the end),
``disconnect()``, and use as a context manager. Capture code does not care which it has.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from avdm.base import Output
from avdm.registry import make_model
from capture.closed_loop import CONTROLLER, CONTROLLER_OUTPUTS, ClosedLoopRobot
from capture.config import (
    SCENES,
    ArenaConfig,
    CameraConfig,
    CollisionConfig,
    OverheadConfig,
    RobotConfig,
    SimConfig,
    WallConfig,
    format_schedule,
    parse_schedule,
)
from capture.output import claim_output
from capture.recording_start import start_recording
from capture.run import DEFAULT_CAPTURE, CaptureOptions, RecordResult, finish_output, run_capture
from capture.sim_robot import SimulatedRobot, load_wall_image, ring_turn_event  # noqa: F401
from vdc.blueprints import default_blueprint
from vdc.cli_support import check_below_nyquist, option
from vdc.errors import UserError
from vdc.recording import model_path
from vdc.settings import AT_LEAST_0, POSITIVE, Settings, between


@dataclasses.dataclass(frozen=True)
class SimSettings(Settings):
    """``vdc-capture sim`` as a settings object: one field per flag, same names and defaults.

    ``to_config()`` turns it into the full :class:`SimConfig` (where every value is checked);
    ``tf_schedule`` (e.g. ``"0:30m,3:30m"``) replaces ``tf_hz``; ``minutes`` defaults to 30,
    or to the schedule's total."""

    scene: str = option("grating", "what the walls show", choices=SCENES)
    period_m: float = option(
        0.1,
        "grating period along the wall, m; a natural scene drifts at TF x this",
        range=POSITIVE,
    )
    tf_hz: float = option(
        0.0, "wall drift temporal frequency, Hz", range=AT_LEAST_0, exclusive="tf"
    )
    tf_schedule: str | None = option(
        None,
        "TF over time as TF:DURATION,... with s, m or h, e.g. 0:30m,3:30m (replaces --tf-hz)",
        metavar="S",
        exclusive="tf",
    )
    minutes: float | None = option(
        None, "run length (default: 30, or the schedule's total)", range=POSITIVE
    )
    seed: int = option(0, "random seed", range=AT_LEAST_0)
    behaviour: str = option(
        "profile",
        "profile: ring turns, online AVDM; collision: the robot avoids walls with an on-board "
        "LGMD detector, ring off, wall contact = crash",
        choices=("profile", "collision"),
    )
    model: str | None = option(
        None,
        "online model (default: avdm); in collision mode the detector, lgmd-plus (default) "
        "or lgmd-colias",
    )
    profile_model: str = option("avdm", "collision mode: the complexity model running alongside")
    threshold: float | None = option(
        None,
        "collision mode: alert threshold in the detector's units (lgmd-plus: spikes/s, "
        "default 56; lgmd-colias: consecutive spikes, default 4)",
        range=POSITIVE,
    )
    adaptive: bool = option(
        False,
        "collision mode, lgmd-plus: let its FFI threshold T_ffi follow the on-board AVDM's "
        "running mean response (beyond the paper)",
    )
    adaptive_gain: float = option(
        1.0,
        "collision mode: T_ffi = max(12, gain x mean AVDM deg/s over the last 60 s)",
        range=AT_LEAST_0,
    )
    phase: str | None = option(None, "collision mode: a label for the study's tables")
    contrast: float = option(1.0, "wall pattern contrast, 0-1", range=between(0, 1, lo_open=True))
    image: str | None = option(None, "natural-scene wall from an image file", metavar="PATH")
    noise_sd: float = option(0.0, "camera noise, 8-bit levels", range=AT_LEAST_0)
    overhead: bool = option(False, "also log an overhead camera")
    overhead_fps: float = option(5.0, "overhead camera rate, Hz", range=POSITIVE)

    def __post_init__(self) -> None:
        check_below_nyquist(self.tf_hz, "--tf-hz")  # before any run: a faster wall aliases

    def to_config(self) -> SimConfig:
        if self.tf_schedule is not None:
            schedule = parse_schedule(self.tf_schedule)
            total = sum(d for _, d in schedule)
            duration = self.minutes * 60 if self.minutes is not None else total
        else:
            duration = (self.minutes if self.minutes is not None else 30.0) * 60
            schedule = ((self.tf_hz, duration),)
        if self.image and self.scene != "natural":
            raise UserError("--image gives a natural scene: use it with --scene natural.")
        wall = WallConfig(
            scene=self.scene,
            period_m=self.period_m,
            contrast=self.contrast,
            tf_schedule=schedule,
            nominal_period_m=self.period_m,
            image_path=self.image or "",
        )
        collision = self.behaviour == "collision"
        if collision:
            col = CollisionConfig(
                detector=self.model or "lgmd-plus",  # validated by CollisionConfig
                threshold=self.threshold if self.threshold is not None else float("nan"),
                adaptive=self.adaptive,
                adaptive_gain=self.adaptive_gain,
                phase=self.phase or "",
            )
            model = self.profile_model
        else:
            for flag, given in (
                ("--threshold", self.threshold is not None),
                ("--adaptive", self.adaptive),
                ("--phase", bool(self.phase)),
            ):
                if given:
                    raise UserError(f"{flag} belongs to --behaviour collision.")
            col = CollisionConfig()
            model = self.model or "avdm"
        return SimConfig(
            arena=ArenaConfig(ring_enabled=not collision),
            wall=wall,
            robot=RobotConfig(),
            camera=CameraConfig(noise_sd=self.noise_sd),
            overhead=OverheadConfig(enabled=self.overhead, fps=self.overhead_fps),
            duration_s=duration,
            seed=self.seed,
            model=model,
            behaviour=self.behaviour,
            collision=col,
        )


def record_sim(
    settings: SimSettings,
    out: str | Path | None = None,
    options: CaptureOptions = DEFAULT_CAPTURE,
) -> RecordResult:
    """Simulate a run and write it to ``out`` (default ``recordings/<run id>.rrd``), as
    ``options`` say (replace, stream live, a count of frames, a line of log). Ctrl-C or
    SIGTERM (in the main thread) ends the run cleanly: the result says so and the file is
    valid."""

    config = settings.to_config()
    ctx = config.camera.model_context()
    model = make_model(config.model, **ctx)
    collision = config.behaviour == "collision"
    detector = make_model(config.collision.detector_spec(), **ctx) if collision else None
    # the device reads a wall image now, so a bad one fails before anything is written
    device = ClosedLoopRobot(config) if collision else SimulatedRobot(config)
    run_id = config.run_id()
    path = options.output_path(out, run_id)
    claim = claim_output(path, options.force)  # exclusive from here; bad folders fail here
    recorder = None
    try:
        live = options.viewer_url()
        if detector is not None:
            main = detector
            names = {o.name for o in detector.outputs}
            extra = [("AVDM omega_dps (deg/s), on board", [model_path(model.name, "omega_dps")])]
            if "spike_rate_hz" in names:  # the LGMD detectors: rate against its threshold
                extra.append(
                    (
                        "spike rate and alert threshold (spikes/s)",
                        [
                            model_path(CONTROLLER, "threshold"),
                            model_path(detector.name, "spike_rate_hz"),
                        ],
                    )
                )
            if "ffi" in names:
                extra.append(
                    (
                        "FFI and its threshold T_ffi in force",
                        [model_path(CONTROLLER, "t_ffi"), model_path(detector.name, "ffi")],
                    )
                )
            if "policy_complexity_dps" in names:  # a learnt policy: what it read
                extra.append(
                    (
                        "the policy's complexity (deg/s)",
                        [model_path(detector.name, "policy_complexity_dps")],
                    )
                )
        else:
            main, extra = model, []
        analyse = [
            "vdc-analyse tables REC --out results/tables",
            "vdc-analyse profile REC --out results/profile",
            "vdc-analyse complexity REC --out results/complexity",
        ]
        if detector is not None:
            analyse.insert(0, "vdc-analyse collision REC --out results/collision")
        else:
            analyse.append(f"vdc-analyse compare REC --model {model.name} --out results/compare")
        recorder = start_recording(
            claim.partial,
            run_id,
            blueprint=default_blueprint(main.name, main.outputs, extra),
            live_url=live,
            device=device,
            model=model,
            context=ctx,
            analyse=analyse,
        )
        recorder.log_arena(config.arena, config.robot.radius_m)
        if detector is not None:
            recorder.log_model_meta(detector.name, detector.outputs)
            recorder.log_model_meta(
                CONTROLLER, tuple(Output(k, u, d) for k, (u, d) in CONTROLLER_OUTPUTS.items())
            )
        if options.log is not None:
            what = (
                f"collision mode, detector {detector.name}"
                + (" (adaptive threshold)" if config.collision.adaptive else "")
                if detector
                else f"model {model.name}"
            )
            options.log(
                f"recording {run_id}: {config.wall.scene} walls, TF schedule "
                f"{format_schedule(config.wall.tf_schedule)}, {config.duration_s / 60:g} min "
                f"({config.n_frames} frames at {config.camera.fps:g} Hz), {what}."
            )
        result = run_capture(
            device,
            None if collision else model,
            recorder,
            total_frames=config.n_frames,
            progress=options.progress,
        )
    finally:
        finish_output(claim, recorder)
    return RecordResult.of(path, run_id, result, config.n_frames)

"""The simulated arena and robot as a capture device.

Like LeRobot's devices, a config plus one interface that the simulated and the real robot both
implement: ``connect()``, ``read()`` (the next ``Batch`` of frames, or None at the end),
``disconnect()``, and use as a context manager. Capture code does not care which it has.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avdm import __version__
from avdm.base import Model
from avdm.stimuli import clutter_image, resize_image
from capture.config import SimConfig
from capture.device import Batch, Event
from capture.render import CameraRenderer, OverheadRenderer
from capture.robot import RobotMotion, TurnEvent
from capture.run import RecordResult
from contract.provenance import machine_info, package_versions


def load_wall_image(path: str, texture_px: tuple[int, int]) -> np.ndarray:
    """Read an image file as the wall panorama, resized to ``texture_px`` (H, W), on [−1, 1].

    Raises ValueError if the file is missing or not an image."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"wall image {path!r} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError(f"wall image {path!r} is not a readable image (PNG, JPEG, ...)")
    small = resize_image(img.astype(np.float64), texture_px)
    lo, hi = small.min(), small.max()
    if hi - lo < 1e-9:
        raise ValueError(f"wall image {path!r} is uniform: it has no pattern to show")
    return 2.0 * (small - lo) / (hi - lo) - 1.0


def ring_turn_event(turn: TurnEvent) -> Event:
    side = "left" if turn.angle_deg > 0 else "right"
    forced = " (forced: about to touch the wall)" if turn.forced else ""
    text = (
        f"ring turn {turn.angle_deg:+.1f} deg ({side}) at x={turn.x_m:.3f} m, "
        f"y={turn.y_m:.3f} m, heading={turn.heading_rad:.3f} rad{forced}"
    )
    return Event("ring_turn", turn.frame, turn.x_m, turn.y_m, turn.heading_rad, text)


class SimulatedRobot:
    """A Colias-IV in the simulated arena: renders its camera, moves, reports ring turns."""

    def __init__(self, config: SimConfig, batch_size: int = 1000) -> None:
        self.config = config
        self.batch_size = batch_size
        seeds = np.random.SeedSequence(config.seed).spawn(3)
        self._motion_rng = np.random.default_rng(seeds[0])
        self._noise_rng = np.random.default_rng(seeds[1])
        self._texture_seed = int(seeds[2].generate_state(1)[0])
        self._connected = False
        # validate what can fail now, before anything is written
        self._texture = None
        if config.wall.scene == "natural":
            if config.wall.image_path:
                self._texture = load_wall_image(config.wall.image_path, config.wall.texture_px)
            else:
                self._texture = clutter_image(config.wall.texture_px, seed=self._texture_seed)

    def connect(self) -> None:
        c = self.config
        self._renderer = CameraRenderer(c.arena, c.wall, c.camera, self._texture)
        self._motion = self._make_motion()
        self._overhead = (
            OverheadRenderer(c.arena, c.robot.radius_m, c.overhead.px_per_m)
            if c.overhead.enabled
            else None
        )
        self._next = 0
        self._offset_m = 0.0
        self._connected = True

    def _make_motion(self):  # -> RobotMotion, or a subclass's own body model
        c = self.config
        return RobotMotion(c.arena, c.robot, c.camera.fps, self._motion_rng)

    def _batch_length(self) -> int:
        """Frames in the next batch (0 at the end of the run)."""
        if not self._connected:
            raise RuntimeError("read() before connect()")
        return min(self.batch_size, max(0, self.config.n_frames - self._next))

    def read(self) -> Batch | None:
        n = self._batch_length()
        if n == 0:
            return None
        c = self.config
        frame = np.arange(self._next, self._next + n, dtype=np.int64)
        t_s = frame / c.camera.fps
        tf = np.array([c.wall.tf_at(t) for t in t_s])
        # the pattern's drift accumulates so that a TF change never makes it jump
        step_m = tf * c.wall.drift_period_m / c.camera.fps
        offsets = self._offset_m + np.concatenate(([0.0], np.cumsum(step_m[:-1])))
        self._offset_m = float(offsets[-1] + step_m[-1])
        poses, turns = self._motion.advance(n)
        events = [ring_turn_event(t) for t in turns]
        images = self._renderer.render(poses, offsets)
        if c.camera.noise_sd > 0:
            noise = self._noise_rng.normal(0.0, c.camera.noise_sd, size=images.shape)
            images = np.clip(np.rint(images + noise), 0, 255).astype(np.uint8)
        overhead = []
        if self._overhead is not None:
            ratio = c.overhead.fps / c.camera.fps
            for i in range(n):
                f = self._next + i
                if f == 0 or int(f * ratio) != int((f - 1) * ratio):
                    overhead.append((f, self._overhead.render(poses[i])))
        self._next += n
        return Batch(frame, t_s, images, poses, tf, events, overhead)

    def disconnect(self) -> None:
        self._connected = False

    def __enter__(self) -> SimulatedRobot:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


def recording_properties(
    config: SimConfig, model: Model, detector: Model | None = None
) -> dict[str, dict[str, Any]]:
    """Recording properties of a simulated run: every config value, the model(s) and versions."""
    sections = config.to_sections()
    sections["run"].update(
        recording_id=config.run_id(),
        source="simulation",
        vdc_version=__version__,
        numpy_version=np.__version__,
    )
    sections["provenance"] = {**package_versions(), **machine_info()}
    sections["model"] = {
        "name": model.name,
        "outputs": json.dumps({o.name: o.unit for o in model.outputs}),
    }
    sections["model_params"] = {k: v for k, v in model.params.to_dict().items() if v is not None}
    if detector is not None:
        sections["detector"] = {
            "name": detector.name,
            "outputs": json.dumps({o.name: o.unit for o in detector.outputs}),
        }
        sections["detector_params"] = detector.params.to_dict()
    return sections


@dataclasses.dataclass(frozen=True)
class SimSettings:
    """``vdc-capture sim`` as a settings object: one field per flag, same names and defaults.

    ``to_config()`` turns it into the full :class:`SimConfig` (where every value is checked);
    ``tf_schedule`` (e.g. ``"0:30m,3:30m"``) replaces ``tf_hz``; ``minutes`` defaults to 30,
    or to the schedule's total."""

    scene: str = "grating"
    period_m: float = 0.1
    tf_hz: float = 0.0
    tf_schedule: str | None = None
    minutes: float | None = None
    seed: int = 0
    behaviour: str = "profile"
    model: str | None = None  # online model (default avdm); collision mode: the detector
    profile_model: str = "avdm"  # collision mode: the complexity model running alongside
    threshold: float | None = None  # collision mode: alert threshold in the detector's units
    adaptive: bool = False
    adaptive_gain: float = 1.0
    phase: str | None = None
    contrast: float = 1.0
    image: str | None = None
    noise_sd: float = 0.0
    overhead: bool = False
    overhead_fps: float = 5.0

    def to_config(self) -> SimConfig:
        from capture.config import (
            ArenaConfig,
            CameraConfig,
            CollisionConfig,
            OverheadConfig,
            RobotConfig,
            WallConfig,
            parse_schedule,
        )

        if self.tf_schedule is not None:
            schedule = parse_schedule(self.tf_schedule)
            total = sum(d for _, d in schedule)
            duration = self.minutes * 60 if self.minutes is not None else total
        else:
            duration = (self.minutes if self.minutes is not None else 30.0) * 60
            schedule = ((self.tf_hz, duration),)
        if self.image and self.scene != "natural":
            raise ValueError("--image gives a natural scene: use it with --scene natural")
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
                    raise ValueError(f"{flag} belongs to --behaviour collision")
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

    def default_path(self) -> Path:
        """``recordings/<run id>.rrd``: the run id is a function of the configuration."""
        return Path("recordings") / f"{self.to_config().run_id()}.rrd"


def record_sim(
    settings: SimSettings,
    out: str | Path | None = None,
    *,
    force: bool = False,
    live_url: str | None = None,
    spawn: bool = False,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> RecordResult:
    """Simulate a run and write it to ``out`` (default ``recordings/<run id>.rrd``).

    ``live_url`` also streams to a running viewer, ``spawn`` to a new one; ``progress`` shows a
    bar on stderr; ``log`` gets a one-line description before the run starts. Ctrl-C or SIGTERM
    (in the main thread) ends the run cleanly: the result says so and the file is valid."""
    from avdm.registry import make_model
    from capture.collision import CONTROLLER, CONTROLLER_OUTPUTS, ClosedLoopRobot
    from capture.output import claim_output
    from capture.recorder import Recorder, default_blueprint, spawn_viewer
    from capture.run import finish_output, run_capture
    from contract.recording import model_path

    config = settings.to_config()
    ctx = config.camera.model_context()
    model = make_model(config.model, **ctx)
    collision = config.behaviour == "collision"
    detector = make_model(config.collision.detector_spec(), **ctx) if collision else None
    # the device reads a wall image now, so a bad one fails before anything is written
    device = ClosedLoopRobot(config) if collision else SimulatedRobot(config)
    run_id = config.run_id()
    path = Path(out) if out else Path("recordings") / f"{run_id}.rrd"
    claim = claim_output(path, force)  # exclusive from here; bad folders fail here
    recorder = None
    try:
        live = spawn_viewer() if spawn else live_url
        if detector is not None:
            main = detector
            extra = [
                ("AVDM omega_dps (deg/s), on board", [model_path(model.name, "omega_dps")]),
                (
                    "spike rate and alert threshold (spikes/s)",
                    [
                        model_path(CONTROLLER, "threshold"),
                        model_path(detector.name, "spike_rate_hz"),
                    ],
                ),
                (
                    "FFI and its threshold T_ffi in force",
                    [model_path(CONTROLLER, "t_ffi"), model_path(detector.name, "ffi")],
                ),
            ]
        else:
            main, extra = model, []
        recorder = Recorder(
            claim.partial,
            run_id,
            blueprint=default_blueprint(main.name, main.outputs, extra),
            live_url=live,
        )
        recorder.send_properties(recording_properties(config, model, detector))
        recorder.log_arena(config.arena, config.robot.radius_m)
        recorder.log_model_meta(model.name, model.outputs)
        if detector is not None:
            from avdm.base import Output

            recorder.log_model_meta(detector.name, detector.outputs)
            recorder.log_model_meta(
                CONTROLLER, tuple(Output(k, u, d) for k, (u, d) in CONTROLLER_OUTPUTS.items())
            )
        if log is not None:
            what = (
                f"collision mode, detector {detector.name}"
                + (" (adaptive threshold)" if config.collision.adaptive else "")
                if detector
                else f"model {model.name}"
            )
            schedule = config.to_sections()["wall"]["tf_schedule_text"]
            log(
                f"recording {run_id}: {config.wall.scene} walls, TF schedule "
                f"{schedule}, {config.duration_s / 60:g} min "
                f"({config.n_frames} frames at {config.camera.fps:g} Hz), {what}"
            )
        result = run_capture(
            device,
            None if collision else model,
            recorder,
            total_frames=config.n_frames,
            progress=progress,
        )
    finally:
        finish_output(claim, recorder)
    return RecordResult.of(path, run_id, result, config.n_frames)

"""The simulated robot in the arena as a capture device: the renderer, the robot's motion and
the ring turns, batch by batch (``capture.sim`` records it; ``capture.closed_loop`` closes its
loop with a collision detector)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avdm.stimuli import clutter_image, resize_image
from avdm.version import __version__
from capture.config import SimConfig, format_schedule
from capture.device import Batch, DeviceContext, Event
from capture.render import CameraRenderer, OverheadRenderer
from capture.robot import RobotMotion, TurnEvent
from vdc.errors import UserError


def load_wall_image(path: str, texture_px: tuple[int, int]) -> np.ndarray:
    """Read an image file as the wall panorama, resized to ``texture_px`` (H, W), on [−1, 1].

    Raises ValueError if the file is missing or not an image."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"wall image {path!r} does not exist.")
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise UserError(f"wall image {path!r} is not a readable image (PNG, JPEG, ...).")
    small = resize_image(img.astype(np.float64), texture_px)
    lo, hi = small.min(), small.max()
    if hi - lo < 1e-9:
        raise UserError(f"wall image {path!r} is uniform: it has no pattern to show.")
    return 2.0 * (small - lo) / (hi - lo) - 1.0


def ring_turn_event(turn: TurnEvent) -> Event:
    side = "left" if turn.angle_deg > 0 else "right"
    forced = " (forced: about to touch the wall)" if turn.forced else ""
    text = (
        f"ring turn {turn.angle_deg:+.1f} deg ({side}) at x={turn.x_m:.3f} m, "
        f"y={turn.y_m:.3f} m, heading={turn.heading_rad:.3f} rad{forced}"
    )
    return Event("ring_turn", turn.frame, turn.x_m, turn.y_m, turn.heading_rad, text)


class SimulatedRobot(DeviceContext):
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

    def properties(self) -> dict[str, dict[str, Any]]:
        """The recording's property sections of the run: every config value (``run``,
        ``arena``, ``wall``, ``camera``, ...), the run's id and the versions that made it."""
        sections = self.config.to_sections()
        sections["run"].update(
            recording_id=self.config.run_id(),
            source="simulation",
            vdc_version=__version__,
            numpy_version=np.__version__,
        )
        return sections

    def description(self) -> str:
        """What a recording of this run holds, in a sentence (its ``/description``)."""
        c = self.config
        return (
            f"a simulated Colias-IV in the {c.arena.length_m:g} x {c.arena.width_m:g} m arena "
            f"({c.behaviour}), {c.wall.scene} walls, TF schedule "
            f"{format_schedule(c.wall.tf_schedule)}, {c.duration_s / 60:g} min "
            f"({c.n_frames} frames), seed {c.seed}"
        )

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

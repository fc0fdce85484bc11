"""The simulated Colias-IV's motion: forward at constant speed, turning in place at the ring.

Behaviour (paper brief; PROPOSED details in capture.config): the robot drives forward; when one
of its two floor light sensors is on the white ring (or between the ring and the wall) while the
robot heads toward that wall, it stops and turns in place by U(turn_min, turn_max) degrees,
left or right at random, at ``turn_speed_dps``, then goes on; if it still heads into the ring
it turns again (an optional refractory time delays that). As a last guard the robot never
drives its body into a wall: a step that would touch a wall triggers a turn instead (logged
as a ring turn with ``forced=True``; it does not happen with the paper's geometry).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from capture.config import ArenaConfig, RobotConfig

FORWARD, TURNING = 0, 1


@dataclasses.dataclass(frozen=True)
class TurnEvent:
    """A ring turn starting at ``frame``."""

    frame: int
    x_m: float
    y_m: float
    heading_rad: float
    angle_deg: float  # signed: + left (counter-clockwise), − right
    forced: bool


class RobotMotion:
    """Integrates the robot's pose frame by frame. Deterministic for a given ``rng``."""

    def __init__(
        self, arena: ArenaConfig, robot: RobotConfig, fps: float, rng: np.random.Generator
    ) -> None:
        self.arena = arena
        self.cfg = robot
        self.dt = 1.0 / fps
        self.rng = rng
        hx, hy = arena.half_extent
        lim_x = hx - arena.ring_inner_m - robot.radius_m
        lim_y = hy - arena.ring_inner_m - robot.radius_m
        x = robot.start_x_m if not math.isnan(robot.start_x_m) else rng.uniform(-lim_x, lim_x)
        y = robot.start_y_m if not math.isnan(robot.start_y_m) else rng.uniform(-lim_y, lim_y)
        hd = (
            robot.start_heading_rad
            if not math.isnan(robot.start_heading_rad)
            else rng.uniform(-math.pi, math.pi)
        )
        self.x, self.y, self.heading = float(x), float(y), float(hd)
        self.state = FORWARD
        self.turn_left_rad = 0.0  # remaining signed turn
        self.since_turn_s = math.inf
        self.frame = 0

    def _wall_gaps(self, px: float, py: float) -> tuple[float, float, float, float]:
        hx, hy = self.arena.half_extent
        return hx - px, px + hx, hy - py, py + hy  # to +x, −x, +y, −y walls

    def _heading_into_ring(self) -> bool:
        """A floor sensor is at or beyond the ring's inner edge, toward a wall we head for."""
        c = self.cfg
        ch, sh = math.cos(self.heading), math.sin(self.heading)
        ring_inner = self.arena.ring_inner_m
        normals = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))
        for side in (1.0, -1.0):
            px = self.x + c.sensor_forward_m * ch - side * c.sensor_lateral_m * sh
            py = self.y + c.sensor_forward_m * sh + side * c.sensor_lateral_m * ch
            for gap, (nx, ny) in zip(self._wall_gaps(px, py), normals, strict=True):
                if gap <= ring_inner and ch * nx + sh * ny > 0.0:
                    return True
        return False

    def _start_turn(self, forced: bool) -> TurnEvent:
        c = self.cfg
        angle = self.rng.uniform(c.turn_min_deg, c.turn_max_deg)
        if self.rng.random() < 0.5:
            angle = -angle
        self.state = TURNING
        self.turn_left_rad = math.radians(angle)
        return TurnEvent(self.frame, self.x, self.y, self.heading, angle, forced)

    def step(self) -> TurnEvent | None:
        """Advance one frame; return the turn that starts in this frame, if any."""
        c = self.cfg
        event = None
        if self.state == TURNING:
            rate = math.radians(c.turn_speed_dps) * self.dt
            delta = max(-rate, min(rate, self.turn_left_rad))
            self.heading = math.remainder(self.heading + delta, math.tau)
            self.turn_left_rad -= delta
            if abs(self.turn_left_rad) < 1e-12:
                self.state = FORWARD
                self.since_turn_s = 0.0
        else:
            self.since_turn_s += self.dt
            if self.since_turn_s >= c.refractory_s and self._heading_into_ring():
                event = self._start_turn(forced=False)
            else:
                step = c.speed_mps * self.dt
                nx = self.x + step * math.cos(self.heading)
                ny = self.y + step * math.sin(self.heading)
                if min(self._wall_gaps(nx, ny)) <= c.radius_m:
                    event = self._start_turn(forced=True)
                else:
                    self.x, self.y = nx, ny
        self.frame += 1
        return event

    def pose(self) -> tuple[float, float, float]:
        return self.x, self.y, self.heading

    def advance(self, n: int) -> tuple[np.ndarray, list[TurnEvent]]:
        """Poses of the next ``n`` frames (the pose *during* each frame), and turns starting."""
        poses = np.empty((n, 3), dtype=np.float64)
        events: list[TurnEvent] = []
        for i in range(n):
            poses[i] = self.x, self.y, self.heading
            ev = self.step()
            if ev is not None:
                events.append(ev)
        return poses, events

"""Closed-loop collision mode: the simulated robot avoids walls with an on-board LGMD detector.

Per frame, as on the robot's processor: render the camera, run the collision detector and the
AVDM (the complexity profile of the same run), decide, move. An alert (spike rate ≥ threshold for
LGMD+, the firmware's consecutive-spike rule for the Colias port) starts an avoidance turn of
U(80°, 100°), left with ``turn_left_probability``; alerts are ignored during the turn and
``refractory_frames`` after it (lgmd_colias.md §4; the detectors' state is never reset, so an
offline recomputation on the recorded frames gives the logged outputs exactly). The light ring is
off. A step that would bring the body within ``crash_margin_m`` of a wall is a crash: logged, no
move, and the robot turns away from that wall and goes on.

Beyond the paper (``adaptive``): in this arena a drifting grating raises LGMD+'s feed-forward
inhibition F far above its threshold T_ffi (F ≈ 26 at TF 3 Hz vs ≈ 2 at TF 0), and the
inhibition β = F / T_ffi then blinds the detector to the approaching wall: the robot crashes
(it does not raise false alarms). The adaptive controller therefore lets T_ffi follow the
on-board AVDM's profile of the scene, ``T_ffi = max(T_ffi0, gain × ω̄)`` with ω̄ the mean ω̂ over the
last ``adaptive_window_s`` seconds (deg/s; ≈ 15 at TF 0, ≈ 35 at TF 3 Hz). The T_ffi in force is
logged under ``/model/controller/t_ffi``; the spike-rate alert threshold stays fixed.
"""

from __future__ import annotations

import json
import math
import sys
from typing import Any

import numpy as np

from avdm.registry import check_detector, make_model
from capture.config import CollisionConfig, SimConfig
from capture.device import Batch, Event
from capture.sim_robot import SimulatedRobot
from vdc.arena_geometry import distance_ahead
from vdc.errors import UserError

FORWARD, AVOIDING, CRASH_TURN = 0, 1, 2
CONTROLLER = "controller"  # on-board outputs of the decision itself
CONTROLLER_OUTPUTS = {
    "threshold": ("spikes/s", "alert threshold in force"),
    "t_ffi": ("levels/px", "LGMD+ FFI threshold in force"),
    "avdm_mean_dps": ("deg/s", "running mean of the on-board AVDM over the window"),
    "avdm_frac_over_100": ("1", "running fraction of AVDM > 100 deg/s over the window"),
}
_WALL_NAMES = ("+x", "-x", "+y", "-y")
_NORMALS = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))


class CollisionMotion:
    """The robot's body in collision mode: forward, avoidance turns, crash turns."""

    def __init__(self, config: SimConfig, rng: np.random.Generator) -> None:
        self.cfg = config.robot
        self.col: CollisionConfig = config.collision
        self.hx, self.hy = config.arena.half_extent
        self.dt = 1.0 / config.camera.fps
        self.rng = rng
        c = self.cfg
        margin = 0.15  # start away from the walls
        self.x = (
            c.start_x_m
            if not math.isnan(c.start_x_m)
            else rng.uniform(-self.hx + margin, self.hx - margin)
        )
        self.y = (
            c.start_y_m
            if not math.isnan(c.start_y_m)
            else rng.uniform(-self.hy + margin, self.hy - margin)
        )
        self.heading = (
            c.start_heading_rad
            if not math.isnan(c.start_heading_rad)
            else rng.uniform(-math.pi, math.pi)
        )
        self.state = FORWARD
        self.turn_left_rad = 0.0
        self.refractory = 0
        self.frame = 0

    def _gaps(self, x: float, y: float) -> tuple[float, float, float, float]:
        return self.hx - x, x + self.hx, self.hy - y, y + self.hy

    def _contact_wall(self, x: float, y: float) -> int | None:
        limit = self.cfg.radius_m + self.col.crash_margin_m
        gaps = self._gaps(x, y)
        best = min(range(4), key=lambda i: gaps[i])
        return best if gaps[best] <= limit else None

    def _heading_into(self, wall: int) -> bool:
        nx, ny = _NORMALS[wall]
        return math.cos(self.heading) * nx + math.sin(self.heading) * ny > 0.0

    def _random_angle(self) -> float:
        c = self.cfg
        return math.radians(self.rng.uniform(c.turn_min_deg, c.turn_max_deg))

    def _turn_away_from(self, wall: int) -> float:
        """A signed turn of U(min, max) whose sense brings the heading away from ``wall``."""
        angle = self._random_angle()
        nx, ny = _NORMALS[wall]
        left = math.cos(self.heading + angle) * nx + math.sin(self.heading + angle) * ny
        right = math.cos(self.heading - angle) * nx + math.sin(self.heading - angle) * ny
        return angle if left <= right else -angle

    def _event(self, kind: str, text: str) -> Event:
        return Event(kind, self.frame, self.x, self.y, self.heading, text)

    def step(self, alert: bool, detail: str) -> Event | None:
        """Advance one frame given the detector's decision; return an event that starts now."""
        c = self.cfg
        event = None
        if self.state != FORWARD:
            rate = math.radians(c.turn_speed_dps) * self.dt
            delta = max(-rate, min(rate, self.turn_left_rad))
            self.heading = math.remainder(self.heading + delta, math.tau)
            self.turn_left_rad -= delta
            if abs(self.turn_left_rad) < 1e-12:
                wall = self._contact_wall(self.x, self.y)
                if self.state == CRASH_TURN and wall is not None and self._heading_into(wall):
                    self.turn_left_rad = self._turn_away_from(wall)  # still facing the wall
                else:
                    self.state = FORWARD
                    self.refractory = self.col.refractory_frames
        elif alert and self.refractory == 0:
            angle = self._random_angle()
            if self.rng.random() >= self.col.turn_left_probability:
                angle = -angle
            dtc = distance_ahead(self.x, self.y, self.heading, self.hx, self.hy) - c.radius_m
            event = self._event(
                "avoidance",
                f"avoidance turn {math.degrees(angle):+.1f} deg at "
                f"x={self.x:.3f} m, y={self.y:.3f} m, distance to collision "
                f"{dtc:.3f} m ({detail})",
            )
            self.state = AVOIDING
            self.turn_left_rad = angle
        else:
            self.refractory = max(0, self.refractory - 1)
            step = c.speed_mps * self.dt
            nx = self.x + step * math.cos(self.heading)
            ny = self.y + step * math.sin(self.heading)
            wall = self._contact_wall(nx, ny)
            if wall is not None and self._heading_into(wall):
                event = self._event(
                    "crash",
                    f"crash into the {_WALL_NAMES[wall]} wall at "
                    f"x={self.x:.3f} m, y={self.y:.3f} m, heading "
                    f"{self.heading:.3f} rad ({detail})",
                )
                self.state = CRASH_TURN
                self.turn_left_rad = self._turn_away_from(wall)
            else:
                self.x, self.y = nx, ny
        self.frame += 1
        return event


class ClosedLoopRobot(SimulatedRobot):
    """A simulated Colias-IV whose on-board collision detector steers it (the capture device
    of ``vdc-capture sim --behaviour collision``). Batches carry the on-board outputs of the
    detector, the AVDM and the controller (threshold in force)."""

    nan_alert_frames = 0  # frames whose detector alert was NaN (read as no alert)

    def _nan_alert(self, frame: int) -> None:
        """A NaN alert reads as no alert; the first one is said in one line on stderr, and
        ``nan_alert_frames`` counts them all."""

        if self.nan_alert_frames == 0:
            print(
                f"note: detector {self.detector.name!r} gave alert = NaN at frame {frame}; "
                "a NaN alert is read as no alert (nan_alert_frames counts them)",
                file=sys.stderr,
            )
        self.nan_alert_frames += 1

    def __init__(self, config: SimConfig, batch_size: int = 1000) -> None:
        if config.behaviour != "collision":
            raise UserError("ClosedLoopRobot needs behaviour='collision'.")
        if config.arena.ring_enabled:
            raise UserError("the light ring must be off in collision mode (ring_enabled=False).")
        super().__init__(config, batch_size)
        ctx = config.camera.model_context()
        self._detector_spec = config.collision.detector_spec()
        # built and stepped once on the camera's raster: a bad spec or plug-in fails early
        cam = config.camera
        # (the checked one describes the run; connect() builds a fresh one to run)
        self.detector = check_detector(self._detector_spec, ctx, (cam.height_px, cam.width_px))
        make_model(config.model, **ctx)

    def properties(self) -> dict[str, dict[str, Any]]:
        """The simulated run's sections, with the detector's name, outputs and parameters."""
        d = self.detector
        return {
            **super().properties(),
            "detector": {
                "name": d.name,
                "outputs": json.dumps({o.name: o.unit for o in d.outputs}),
            },
            "detector_params": d.params.to_dict(),
        }

    def description(self) -> str:
        return (
            f"{super().description()}; closed loop with the collision detector {self.detector.name}"
        )

    def _make_motion(self) -> CollisionMotion:
        return CollisionMotion(self.config, self._motion_rng)

    def connect(self) -> None:
        super().connect()
        c = self.config
        ctx = c.camera.model_context()
        self.detector = make_model(self._detector_spec, **ctx)
        self.profiler = make_model(c.model, **ctx)
        p = self.detector.params
        self._base = float(getattr(p, "t_sr", getattr(p, "n_alert", getattr(p, "tau_alert_s", 0))))
        self._t_ffi0 = float(getattr(p, "t_ffi", 0.0))
        self._policy_param = getattr(getattr(self.detector, "policy", None), "param", None)
        window = max(1, round(c.collision.adaptive_window_s * c.camera.fps))
        self._omega_ring = np.zeros(window)  # AVDM ω̂ over the window (running mean)
        self._omega_sum = 0.0
        self._over_ring = np.zeros(window, dtype=np.int64)  # AVDM ω̂ > 100 over the window
        self._over_sum = 0

    def read(self) -> Batch | None:
        n = self._batch_length()
        if n == 0:
            return None
        c = self.config
        h, w = c.camera.height_px, c.camera.width_px
        images = np.empty((n, h, w), np.uint8)
        poses = np.empty((n, 3))
        tf = np.empty(n)
        det_out = {o.name: np.empty(n) for o in self.detector.outputs}
        prof_out = {o.name: np.empty(n) for o in self.profiler.outputs}
        ctrl = {name: np.empty(n) for name in CONTROLLER_OUTPUTS}
        events: list[Event] = []
        overhead = []
        ratio = c.overhead.fps / c.camera.fps
        spike_rate = c.collision.base_detector == "lgmd-plus"  # LGMD+ kinds decide on the rate
        window = len(self._over_ring)
        for i in range(n):
            f = self._next + i
            t = f / c.camera.fps
            tf[i] = c.wall.tf_at(t)
            m = self._motion
            poses[i] = m.x, m.y, m.heading
            frame = self._renderer.render(poses[i : i + 1], np.array([self._offset_m]))[0]
            if c.camera.noise_sd > 0:
                noisy = frame + self._noise_rng.normal(0.0, c.camera.noise_sd, size=frame.shape)
                frame = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
            images[i] = frame
            self._offset_m += tf[i] * c.wall.drift_period_m / c.camera.fps
            # the profile of the frames so far sets this frame's T_ffi (no look-ahead)
            seen = min(max(f, 1), window)
            frac = self._over_sum / seen
            mean_dps = self._omega_sum / seen
            t_ffi = self._t_ffi0
            if c.collision.adaptive:
                t_ffi = max(self._t_ffi0, c.collision.adaptive_gain * mean_dps)
                self.detector.set_t_ffi(t_ffi)  # type: ignore[attr-defined]
            d = self.detector.step(frame)
            if self._policy_param == "t_ffi":  # a learnt policy set it for this frame
                t_ffi = self.detector.value  # type: ignore[attr-defined]
            a = self.profiler.step(frame)
            omega = a.get("omega_dps", 0.0)
            slot = f % window
            self._over_sum += int(omega > 100.0) - int(self._over_ring[slot])
            self._over_ring[slot] = int(omega > 100.0)
            self._omega_sum += omega - self._omega_ring[slot]
            self._omega_ring[slot] = omega
            threshold = self._base
            if spike_rate:
                alert = d["spike_rate_hz"] >= threshold
                detail = (
                    f"spike rate {d['spike_rate_hz']:.0f}/s, threshold {threshold:.0f}/s, "
                    f"T_ffi {t_ffi:.1f}"
                )
            else:
                alert = d["alert"] > 0
                if d["alert"] != d["alert"]:  # NaN: no alert, but never silently
                    self._nan_alert(f)
                detail = (
                    f"{self._base:g} consecutive spikes"
                    if c.collision.base_detector == "lgmd-colias"
                    else f"time to contact {d['tau_s']:.2f} s < {self._base:g} s"
                    if c.collision.base_detector == "flow-ttc"
                    else f"{self.detector.name} alert"
                )
            for k, v in d.items():
                det_out[k][i] = v
            for k, v in a.items():
                prof_out[k][i] = v
            ctrl["threshold"][i] = threshold
            ctrl["t_ffi"][i] = t_ffi
            ctrl["avdm_mean_dps"][i] = mean_dps
            ctrl["avdm_frac_over_100"][i] = frac
            ev = m.step(bool(alert), detail)
            if ev is not None:
                events.append(ev)
            if self._overhead is not None and (f == 0 or int(f * ratio) != int((f - 1) * ratio)):
                overhead.append((f, self._overhead.render(poses[i])))
        frame_idx = np.arange(self._next, self._next + n, dtype=np.int64)
        self._next += n
        onboard = {self.detector.name: det_out, self.profiler.name: prof_out, CONTROLLER: ctrl}
        return Batch(
            frame_idx, frame_idx / c.camera.fps, images, poses, tf, events, overhead, onboard
        )

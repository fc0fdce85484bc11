"""The real Colias-IV as a capture device (:class:`ColiasRobotDevice`, ``record_robot``'s):
the serial link's packets joined to the overhead tracker's poses on the host's receive time,
the handshake that checks the model the robot announces, and the link's counts.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avdm.registry import canonical_name, make_model
from capture.config import (
    ArenaConfig,
    WallConfig,
    config_section,
    format_schedule,
)
from capture.device import Batch, DeviceContext, Event
from capture.robot_contract import accepted_model, announcement_change, frame_problem
from capture.serial_link import PORT_ERRORS, SerialLink
from capture.serial_protocol import TYPE_ANNOUNCE, TYPE_FRAME, Announcement, FramePacket
from capture.tracker import (
    MarkerLayout,
    calibrate_homography,
    load_calibration,
    open_camera,
    robot_pose,
)
from vdc.errors import UserError
from vdc.recording import camera_model_context

LINK_COUNTERS = (
    "packets",
    "bad_crc",
    "bad_length",
    "garbage_bytes",
    "lost_frames",
    "duplicate_frames",
    "disconnects",
)


@dataclasses.dataclass(frozen=True)
class RobotCaptureConfig:
    port: str
    camera: str  # device index ("0"), a video file, or an image-sequence pattern
    baud: int = 3_000_000
    calibration: str = ""  # homography file; empty = calibrate on the first overhead frame
    camera_fps: float = 10.0  # pace of video files / image sequences
    wall: WallConfig = dataclasses.field(
        default_factory=lambda: WallConfig(tf_schedule=((0.0, 48 * 3600.0),))
    )
    model: str = "avdm"  # the on-board model the host asks for (PARAMS) and expects
    wall_port: str = ""  # the LED wall controller's serial port ("": none), for the record
    # the camera assumed for a robot that does not announce its own (older firmware)
    fps: float = 33.0
    width_px: int = 99
    height_px: int = 72
    hfov_deg: float = 70.0
    # how long the host waits for the robot's ANNOUNCE after START (older firmware is found
    # out at once by a FRAME that comes first; this bounds a robot that sends nothing)
    announce_timeout_s: float = 5.0
    max_gap_s: float = 0.25
    batch_s: float = 0.5
    reconnect_timeout_s: float = 30.0
    layout: MarkerLayout = dataclasses.field(default_factory=MarkerLayout)


class ColiasRobotDevice(DeviceContext):
    """The real robot as a capture device (``connect`` / ``read`` / ``disconnect``)."""

    def __init__(
        self, config: RobotCaptureConfig, on_wall_tf: Callable[[float], None] | None = None
    ) -> None:
        self.cfg = config
        self.on_wall_tf = on_wall_tf  # e.g. a WallController driving the LED walls
        self._connected = False
        # until the robot announces its own: the host's model on the default camera
        self.model_context = camera_model_context(
            config.width_px, config.height_px, config.fps, config.hfov_deg
        )
        model = make_model(config.model, **self.model_context)  # a bad spec fails here
        self.model_name = model.name
        self.output_names = [o.name for o in model.outputs]
        self.output_units = [o.unit for o in model.outputs]
        self.announced: Announcement | None = None  # what the robot said it runs
        self.arena = ArenaConfig()  # the arena the robot runs in (the standard one)
        self.h = None if not config.calibration else load_calibration(Path(config.calibration))

    def properties(self) -> dict[str, dict[str, Any]]:
        """The recording's ``run`` (less its id), ``wall``, ``arena``, ``camera`` and ``link``
        property sections: what this robot is. Call it after :meth:`connect`: the camera is the
        one the robot announced (``announced`` true), else the host's defaults (false)."""
        cfg, context, announced = self.cfg, self.model_context, self.announced is not None
        return {
            "run": {
                "source": "robot",
                "port": cfg.port,
                "baud": cfg.baud,
                "camera": cfg.camera,
                "behaviour": "robot",
            },
            "wall": {
                "scene": cfg.wall.scene,
                "period_m": cfg.wall.period_m,
                "tf_schedule_text": format_schedule(cfg.wall.tf_schedule),
            },
            "arena": config_section(self.arena),
            "camera": {
                "fps": float(context["fps"]),
                "width_px": int(context["width_px"]),
                "height_px": int(context["height_px"]),
                "hfov_deg": float(context["deg_per_px"]) * int(context["width_px"]),
                "announced": announced,
            },
            "link": {
                "protocol": "vdc serial v1 (docs/guides/robot.md)",
                "stats": ",".join(LINK_COUNTERS),
                "announce": "received" if announced else "none (older firmware?)",
            },
        }

    def description(self) -> str:
        """What a recording of this robot holds, in a sentence (its ``/description``)."""
        cfg = self.cfg
        return (
            f"a Colias-IV robot on {cfg.port} ({cfg.wall_port or 'no'} wall controller), its "
            "camera frames and on-board model outputs over the serial link, poses from the "
            f"overhead camera {cfg.camera}; wall {cfg.wall.scene}, TF schedule "
            f"{format_schedule(cfg.wall.tf_schedule)}"
        )

    def connect(self) -> None:
        """Open the port (sends PARAMS and START), wait for the robot's ANNOUNCE and check it,
        open the camera; a second call does nothing. ValueError (before any file is written)
        when the port or camera cannot open, or the robot runs another model."""
        if self._connected:
            return
        cfg = self.cfg
        self.link = SerialLink(
            cfg.port, cfg.baud, cfg.reconnect_timeout_s, params=canonical_name(cfg.model)
        )
        try:
            self.link.open()
        except PORT_ERRORS as exc:
            raise UserError(
                f"cannot open the robot's serial port {cfg.port!r}: "
                f"{getattr(exc, 'strerror', None) or exc}"
            ) from None
        try:
            self.cam = open_camera(cfg.camera)
            announced = self.link.handshake(cfg.announce_timeout_s)
            if announced is not None:
                self._accept(announced)
            # the first frame must be what was announced (or, unannounced, assumed): a robot
            # that says 99x72 and sends 80x60 is refused here, before any file, as a wrong
            # model is; a robot that sends nothing yet is checked frame by frame as it runs
            first = self.link.first_frame(cfg.announce_timeout_s)
            problem = None if first is None else self._frame_problem(first)
            if problem is not None:
                said = "announced" if self.announced is not None else "assumed (no announcement)"
                raise UserError(
                    f"the robot's first frame does not match what was {said}: {problem}"
                )
        except BaseException:
            self.link.close(stop=True)  # the robot stops too
            if hasattr(self, "cam"):
                self.cam.release()
            raise
        self._video = not cfg.camera.isdigit()
        self.t0_ns = time.time_ns()
        self._cam_next = 0  # next video frame index (files are paced at camera_fps)
        self._cam_done = False
        self.samples: deque[tuple[int, tuple[float, float, float] | None]] = deque(maxlen=256)
        self.last_index = -1
        self.first_robot_us: int | None = None
        self.lost = 0
        self.duplicates = 0
        self.tracking = True
        self._reported = dict.fromkeys(LINK_COUNTERS, 0)
        self._disconnect_events: list[str] = []
        self.link_error: str | None = None  # why the run ended early: the robot broke its word
        self._connected = True

    @property
    def stop_reason(self) -> str | None:
        """``link error`` once the robot broke what it announced (the capture loop ends the
        run with it), else None."""
        return None if self.link_error is None else "link error"

    def _frame_problem(self, pkt: FramePacket) -> str | None:
        return frame_problem(pkt, self.model_context, self.model_name, self.output_names)

    def _announcement_change(self, a: Announcement) -> str | None:
        return announcement_change(
            a, self.announced, self.cfg.model, self.model_name, self.model_context
        )

    def _accept(self, a: Announcement) -> None:
        """Take the robot's word for its model, outputs and camera if it is the model the host
        was given (:func:`capture.robot_contract.accepted_model`); else ValueError."""
        host = accepted_model(a, self.cfg.model)
        self.announced = a
        self.model_context = a.model_context()
        self.model_name = host.name
        self.output_names = [n for n, _ in a.outputs]
        self.output_units = [u for _, u in a.outputs]

    def calibrate_tracker(self) -> np.ndarray | None:
        """Read the overhead frames due by now and return the tracker's homography (3, 3)
        from the corner markers, or None if no frame has shown them yet."""
        self._poll_camera()
        return self.h

    def _poll_camera(self) -> None:
        """Read the overhead frames due by now and track the robot in them."""
        now = time.time_ns()
        while not self._cam_done:
            if self._video:
                due = self.t0_ns + int(self._cam_next * 1e9 / self.cfg.camera_fps)
                if due > now:
                    return
            ok, img = self.cam.read()
            if not ok:
                self._cam_done = True
                return
            stamp = due if self._video else time.time_ns()
            self._cam_next += 1
            grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            if self.h is None:
                self.h = calibrate_homography(grey, self.cfg.layout)
            self.samples.append((stamp, robot_pose(grey, self.h)))
            if not self._video:
                return

    def _pose_at(self, t_ns: int) -> tuple[float, float, float] | None:
        best, best_dt = None, math.inf
        for stamp, pose in self.samples:
            dt = abs(stamp - t_ns)
            if dt < best_dt:
                best, best_dt = pose, dt
        if best is None or best_dt > self.cfg.max_gap_s * 1e9:
            return None
        return best

    def _end_on(self, why: str) -> None:
        """End the run after the frames read so far: a ``link_error`` event says why."""
        self.link_error = why
        self._disconnect_events.append(f"{why}; the capture ends here")

    def read(self) -> Batch | None:
        if self.link_error is not None:
            return None  # the run ended on the robot's fault (logged with the last batch)
        got: list[tuple[FramePacket, int]] = []
        start = time.monotonic()
        for ptype, obj in self.link.packets():
            self._poll_camera()
            if ptype == 0 and obj == "disconnect":
                self._disconnect_events.append("serial port lost; reconnecting")
            elif ptype == TYPE_ANNOUNCE:
                # after a reconnection (a power cycle?) the robot may say it runs something
                # else: its frames from here are not the recording's model or camera
                change = self._announcement_change(obj)  # type: ignore[arg-type]
                if change is not None:
                    self._end_on(change)
                    break
            elif ptype == TYPE_FRAME:
                pkt: FramePacket = obj  # type: ignore[assignment]
                if pkt.index <= self.last_index:
                    self.duplicates += 1
                    continue
                problem = self._frame_problem(pkt)
                if problem is not None:
                    self._end_on(f"the robot broke its announcement: {problem}")
                    break
                if self.last_index >= 0 and pkt.index > self.last_index + 1:
                    self.lost += pkt.index - self.last_index - 1
                self.last_index = pkt.index
                got.append((pkt, time.time_ns()))
            if time.monotonic() - start >= self.cfg.batch_s and (got or ptype != TYPE_FRAME):
                break
        if not got:
            if self.link_error is not None:
                return self._empty_batch(self._take_events(max(self.last_index, 0)))
            return None if self.link.ended else self._empty_batch()
        return self._batch(got)

    def _take_events(self, frame: int) -> list[Event]:
        """The pending link notes as ``link_error`` events at ``frame`` (then forgotten)."""
        events = [
            Event("link_error", frame, math.nan, math.nan, math.nan, text)
            for text in self._disconnect_events
        ]
        self._disconnect_events = []
        return events

    def _empty_batch(self, events: list[Event] | None = None) -> Batch:
        """No frame arrived this time: keep the loop alive (and log ``events``, if any)."""
        return Batch(
            np.empty(0, np.int64),
            np.empty(0),
            np.empty((0, 1, 1), np.uint8),
            np.empty((0, 3)),
            np.empty(0),
            events or [],
        )

    def _batch(self, got: list[tuple[FramePacket, int]]) -> Batch:
        if self.first_robot_us is None:
            self.first_robot_us = got[0][0].robot_time_us
        idx = np.array([p.index for p, _ in got], dtype=np.int64)
        t_s = np.array([(p.robot_time_us - self.first_robot_us) / 1e6 for p, _ in got])
        cap_ns = np.array([ns for _, ns in got], dtype=np.int64)
        with_img = [(p.index, p.image) for p, _ in got if p.image is not None]
        images = (
            np.stack([im for _, im in with_img])
            if with_img
            else np.empty((0, got[0][0].height, got[0][0].width), np.uint8)
        )
        poses = np.full((len(got), 3), np.nan)
        events: list[Event] = []
        for k, (pkt, ns) in enumerate(got):
            pose = self._pose_at(int(ns))
            if pose is None:
                if self.tracking:
                    events.append(
                        Event(
                            "tracker_lost",
                            pkt.index,
                            math.nan,
                            math.nan,
                            math.nan,
                            f"overhead tracker lost the robot at frame {pkt.index}",
                        )
                    )
                self.tracking = False
            else:
                poses[k] = pose
                self.tracking = True
        elapsed = (cap_ns - self.t0_ns) / 1e9
        tf = np.array([self.cfg.wall.tf_at(float(s)) for s in elapsed])
        if self.on_wall_tf is not None:
            self.on_wall_tf(float(tf[-1]))
        # every frame here has the announced outputs (read() ends the run on one that has not)
        outputs = {
            name: np.array([p.outputs[i] for p, _ in got])
            for i, name in enumerate(self.output_names)
        }
        stats = self.link_stats()
        changes = [
            f"{k} +{stats[k] - self._reported[k]}"
            for k in LINK_COUNTERS[1:]
            if stats[k] > self._reported[k]
        ]
        # a fault that ends the run is noted at the last frame kept, a reconnection at the first
        events += self._take_events(int(idx[-1] if self.link_error else idx[0]))
        if changes:
            events.append(
                Event(
                    "link_error",
                    int(idx[-1]),
                    math.nan,
                    math.nan,
                    math.nan,
                    "link: " + ", ".join(changes),
                )
            )
        self._reported = stats
        return Batch(
            idx,
            t_s,
            images,
            poses,
            tf,
            events,
            onboard={self.model_name: outputs},
            image_frame=np.array([i for i, _ in with_img], dtype=np.int64),
            capture_time_ns=cap_ns,
            link_stats=stats,
        )

    def link_stats(self) -> dict[str, int]:
        s = self.link.parser.stats
        return {
            "packets": s.packets,
            "bad_crc": s.bad_crc,
            "bad_length": s.bad_length,
            "garbage_bytes": s.garbage_bytes,
            "lost_frames": self.lost,
            "duplicate_frames": self.duplicates,
            "disconnects": self.link.disconnects,
        }

    def disconnect(self) -> None:
        if self._connected:
            self.link.close(stop=True)
            self.cam.release()
            self._connected = False

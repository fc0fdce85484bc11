"""Configuration of a simulated run: one frozen dataclass per part, every value recorded.

Paper defaults (docs/architecture.md); values the sources leave open are PROPOSED and say so. Every
``__post_init__`` raises ``ValueError`` naming the field and the accepted range.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
from typing import Any

from avdm.registry import VARIANTS, add_overrides, is_plugin
from avdm.version import __version__
from vdc.cli_support import SIM_CAMERA_FPS
from vdc.errors import UserError
from vdc.recording import camera_model_context

SCENES = ("grating", "natural")
BEHAVIOURS = ("profile", "collision")
DETECTORS = ("lgmd-plus", "lgmd-colias", "flow-ttc")


def _check(cond: bool, name: str, value: Any, why: str) -> None:
    if not cond:
        raise UserError(f"{name}={value!r}: {why}")


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _in_range(name: str, v: Any, lo: float, hi: float, unit: str = "") -> None:
    _check(_finite(v) and lo <= v <= hi, name, v, f"must be between {lo:g} and {hi:g}{unit}")


def _int_in_range(name: str, v: Any, lo: int, hi: int) -> None:
    _check(isinstance(v, int) and lo <= v <= hi, name, v, f"must be an integer from {lo} to {hi}")


def _plain(v: Any, declared: str, name: str = "") -> Any:
    """A config value as a recording property: tuples as JSON, NaN as its meaning."""
    if isinstance(v, tuple):
        return json.dumps(v)
    if isinstance(v, float) and math.isnan(v):
        return "random" if name.startswith("start_") else "default"
    if declared == "float" and isinstance(v, int) and not isinstance(v, bool):
        return float(v)  # one Arrow type per property, whatever the caller passed
    return v


def config_section(obj: Any) -> dict[str, Any]:
    """One config dataclass (``ArenaConfig``, ``CameraConfig``, ...) as a property section."""
    return {f.name: _plain(getattr(obj, f.name), str(f.type)) for f in dataclasses.fields(obj)}


@dataclasses.dataclass(frozen=True)
class ArenaConfig:
    """Rectangular arena centred on the origin; x along the long side (docs/architecture.md)."""

    length_m: float = 1.4
    width_m: float = 0.8
    wall_height_m: float = 0.15
    ring_width_m: float = 0.05  # white light ring on the floor
    ring_inset_m: float = 0.04  # gap between the walls and the ring's outer edge
    floor_level: float = 0.1  # intensities on [0, 1]; PROPOSED: dark floor, white ring,
    ring_level: float = 1.0  # dim room above the walls
    room_level: float = 0.05
    ring_enabled: bool = True  # drawn on the floor and sensed by the robot

    def __post_init__(self) -> None:
        _in_range("arena length_m", self.length_m, 0.2, 20.0, " m")
        _in_range("arena width_m", self.width_m, 0.2, 20.0, " m")
        _in_range("wall_height_m", self.wall_height_m, 0.01, 5.0, " m")
        _in_range("ring_width_m", self.ring_width_m, 0.0, 1.0, " m")
        _in_range("ring_inset_m", self.ring_inset_m, 0.0, 1.0, " m")
        inner = self.ring_inset_m + self.ring_width_m
        _check(
            2 * inner < min(self.length_m, self.width_m) - 0.1,
            "ring_inset_m + ring_width_m",
            inner,
            "leaves no room inside the ring",
        )
        for name in ("floor_level", "ring_level", "room_level"):
            _in_range(name, getattr(self, name), 0.0, 1.0)

    @property
    def half_extent(self) -> tuple[float, float]:
        return self.length_m / 2, self.width_m / 2

    @property
    def perimeter_m(self) -> float:
        return 2 * (self.length_m + self.width_m)

    @property
    def ring_inner_m(self) -> float:
        """Distance from the walls to the ring's inner edge."""
        return self.ring_inset_m + self.ring_width_m


@dataclasses.dataclass(frozen=True)
class WallConfig:
    """What the LED walls show. The pattern runs along the unrolled wall coordinate s (m),
    starting at the (−x, −y) corner and going counter-clockwise."""

    scene: str = "grating"
    period_m: float = 0.1  # grating period along the wall; PROPOSED default
    contrast: float = 1.0  # Michelson; peak-normalised (brightest LED = 1)
    tf_schedule: tuple[tuple[float, float], ...] = ((0.0, 1800.0),)  # (TF Hz, seconds)
    nominal_period_m: float = 0.1  # a natural scene drifts at tf_hz · nominal_period_m m/s
    image_path: str = ""  # natural scene from a file instead of seeded 1/f clutter
    texture_px: tuple[int, int] = (120, 3520)  # (H, W) of the LED wall panorama

    def __post_init__(self) -> None:
        _check(self.scene in SCENES, "scene", self.scene, f"must be one of {', '.join(SCENES)}")
        _in_range("period_m", self.period_m, 0.002, 10.0, " m")
        _in_range("wall contrast", self.contrast, 0.0, 1.0)
        _in_range("nominal_period_m", self.nominal_period_m, 0.002, 10.0, " m")
        _check(len(self.tf_schedule) > 0, "tf_schedule", self.tf_schedule, "is empty")
        for tf, dur in self.tf_schedule:
            _in_range("wall TF", tf, 0.0, 100.0, " Hz")
            _check(_finite(dur) and dur > 0, "schedule segment duration", dur, "must be > 0 s")
        h, w = self.texture_px
        _check(1 <= h <= 4096 and 8 <= w <= 65536, "texture_px", self.texture_px, "out of range")

    def tf_at(self, t_s: float) -> float:
        """The TF in force at ``t_s`` seconds (the last segment holds after the schedule)."""
        end = 0.0
        for tf, dur in self.tf_schedule:
            end += dur
            if t_s < end:
                return tf
        return self.tf_schedule[-1][0]

    @property
    def drift_period_m(self) -> float:
        """Metres of drift per cycle of TF: the grating period, or the scene's nominal period."""
        return self.period_m if self.scene == "grating" else self.nominal_period_m


@dataclasses.dataclass(frozen=True)
class RobotConfig:
    """Colias-IV: a disc driving forward, turning in place at the light ring."""

    radius_m: float = 0.021
    speed_mps: float = 0.08
    turn_min_deg: float = 80.0
    turn_max_deg: float = 100.0
    turn_speed_dps: float = 120.0  # PROPOSED: in-place turn rate (a 90° turn takes 0.75 s)
    # No refractory needed: a turn only triggers while heading toward the wall whose ring a
    # sensor sees, so a robot leaving the ring never re-triggers; a refractory time instead
    # let robots that turned ±90° parallel to a wall drive on into it (found by the tests).
    refractory_s: float = 0.0
    sensor_forward_m: float = 0.012  # two floor light sensors, PROPOSED placement
    sensor_lateral_m: float = 0.012
    start_x_m: float = float("nan")  # NaN = random start inside the ring (from the seed)
    start_y_m: float = float("nan")
    start_heading_rad: float = float("nan")

    def __post_init__(self) -> None:
        _in_range("robot radius_m", self.radius_m, 0.001, 0.5, " m")
        _in_range("speed_mps", self.speed_mps, 0.0, 2.0, " m/s")
        _in_range("turn_min_deg", self.turn_min_deg, 0.0, 360.0, " deg")
        _in_range("turn_max_deg", self.turn_max_deg, self.turn_min_deg, 360.0, " deg")
        _in_range("turn_speed_dps", self.turn_speed_dps, 1.0, 3600.0, " deg/s")
        _in_range("refractory_s", self.refractory_s, 0.0, 60.0, " s")
        _in_range("sensor_forward_m", self.sensor_forward_m, 0.0, 0.5, " m")
        _in_range("sensor_lateral_m", self.sensor_lateral_m, 0.0, 0.5, " m")


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """The on-board camera: pinhole, horizontal, looking forward, area-averaged pixels."""

    width_px: int = 99
    height_px: int = 72
    fps: float = SIM_CAMERA_FPS
    hfov_deg: float = 70.0
    height_m: float = 0.03
    supersample: int = 8  # sub-columns per pixel (area averaging across the stripes)
    noise_sd: float = 0.0  # Gaussian sensor noise, 8-bit levels (0 = off)

    def __post_init__(self) -> None:
        _int_in_range("camera width_px", self.width_px, 8, 2048)
        _int_in_range("camera height_px", self.height_px, 3, 2048)
        _in_range("camera fps", self.fps, 1.0, 1000.0, " Hz")
        _in_range("hfov_deg", self.hfov_deg, 5.0, 170.0, " deg")
        _in_range("camera height_m", self.height_m, 0.001, 5.0, " m")
        _int_in_range("supersample", self.supersample, 1, 64)
        _in_range("noise_sd", self.noise_sd, 0.0, 100.0, " levels")

    @property
    def focal_px(self) -> float:
        return (self.width_px / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def deg_per_px(self) -> float:
        """Angular pitch at the image centre (what the AVDM calibration is keyed on)."""
        return self.hfov_deg / self.width_px

    def model_context(self) -> dict[str, float | int]:
        """What a model needs to know about this camera: frame rate, angular pitch, and the
        AVDM's texture row. The released code counts transitions on row 2, which on this
        camera sees the dark room above the wall until the robot is 25 cm from it; the horizon
        row (camera height) always shows the wall."""
        return camera_model_context(self.width_px, self.height_px, self.fps, self.hfov_deg)


@dataclasses.dataclass(frozen=True)
class OverheadConfig:
    """Optional top-down camera: a render of the arena with a marker on the robot."""

    enabled: bool = False
    fps: float = 5.0
    px_per_m: float = 200.0

    def __post_init__(self) -> None:
        _in_range("overhead fps", self.fps, 0.1, 100.0, " Hz")
        _in_range("overhead px_per_m", self.px_per_m, 10.0, 2000.0)


@dataclasses.dataclass(frozen=True)
class CollisionConfig:
    """Closed-loop collision mode: the robot avoids walls with an on-board collision detector.

    The light ring is switched off in this mode (neither drawn nor sensed): only the detector
    turns the robot away from walls, and touching a wall is a crash."""

    detector: str = "lgmd-plus"
    # alert threshold: spike rate (spikes/s) for lgmd-plus, consecutive spike count for
    # lgmd-colias, time to contact (s) for flow-ttc; NaN = the detector's own default
    # (56 spikes/s, 4 spikes, 1 s)
    threshold: float = float("nan")
    # beyond the paper (lgmd-plus only): the FFI threshold follows the on-board AVDM,
    # T_ffi = max(T_ffi0, adaptive_gain × mean ω̂ over the last adaptive_window_s seconds),
    # so a visually busy scene no longer blinds the detector by inhibition
    adaptive: bool = False
    adaptive_gain: float = 1.0  # (levels/px of FFI) per (deg/s of mean ω̂)
    adaptive_window_s: float = 60.0
    refractory_frames: int = 10  # alerts ignored this long after an avoidance turn (§4)
    turn_left_probability: float = 0.5
    crash_margin_m: float = 0.005  # body within this of a wall = contact
    phase: str = ""  # a label for the study's tables, e.g. "TF 3 Hz, adjusted threshold"

    def __post_init__(self) -> None:
        plugin = is_plugin(self.detector)  # a bad spec fails here, in one line
        _check(
            plugin or self.base_detector in DETECTORS,
            "detector",
            self.detector,
            f"must be a collision detector: {', '.join(DETECTORS)}, lgmd-plus-arena (optionally "
            "with :key=value overrides), or a plug-in with an 'alert' output",
        )
        if not math.isnan(self.threshold):
            _check(
                not plugin,
                "threshold",
                self.threshold,
                "applies to the LGMD detectors; set a plug-in's own parameter in its spec",
            )
            if self.base_detector == "flow-ttc":
                _in_range("collision threshold (time to contact)", self.threshold, 0.05, 10.0, " s")
            else:
                hi = 2000.0 if self.base_detector == "lgmd-plus" else 100.0
                _in_range("collision threshold", self.threshold, 1.0, hi)
        _check(
            not (self.adaptive and (plugin or self.base_detector != "lgmd-plus")),
            "adaptive",
            self.adaptive,
            "the adaptive threshold needs a spike-rate detector (lgmd-plus)",
        )
        _check(
            not (self.adaptive and ":policy=" in self.detector.replace(" ", "")),
            "adaptive",
            self.adaptive,
            "a detector with a learnt policy adapts already: drop --adaptive",
        )
        _in_range("adaptive_gain", self.adaptive_gain, 0.0, 100.0)
        _in_range("adaptive_window_s", self.adaptive_window_s, 0.1, 600.0, " s")
        _int_in_range("refractory_frames", self.refractory_frames, 0, 1000)
        _in_range("turn_left_probability", self.turn_left_probability, 0.0, 1.0)
        _in_range("crash_margin_m", self.crash_margin_m, 0.0, 0.1, " m")

    @property
    def base_detector(self) -> str:
        """The detector's model kind (``lgmd-plus`` for ``lgmd-plus-arena:t_sr=80``)."""

        name = self.detector.split(":", 1)[0].strip()
        return VARIANTS[name].kind if name in VARIANTS else name

    def detector_spec(self) -> str:
        """The registry spec of the detector with its threshold applied."""
        if math.isnan(self.threshold):
            return self.detector

        if self.base_detector == "lgmd-plus":  # a spike-rate threshold
            return add_overrides(self.detector, f"t_sr={self.threshold:g}")
        if self.base_detector == "flow-ttc":  # a time to contact, s
            return add_overrides(self.detector, f"tau_alert_s={self.threshold:g}")
        return add_overrides(self.detector, f"n_alert={round(self.threshold)}")


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """A whole simulated run."""

    arena: ArenaConfig = ArenaConfig()
    wall: WallConfig = WallConfig()
    robot: RobotConfig = RobotConfig()
    camera: CameraConfig = CameraConfig()
    overhead: OverheadConfig = OverheadConfig()
    duration_s: float = 1800.0
    seed: int = 0
    model: str = "avdm"  # the online model (in collision mode: the profile model on board)
    behaviour: str = "profile"
    collision: CollisionConfig = CollisionConfig()

    def __post_init__(self) -> None:
        _check(
            self.behaviour in BEHAVIOURS,
            "behaviour",
            self.behaviour,
            f"must be one of {', '.join(BEHAVIOURS)}",
        )
        _check(
            _finite(self.duration_s) and 0 < self.duration_s <= 48 * 3600,
            "duration",
            self.duration_s,
            "must be between 0 and 48 hours",
        )
        _check(
            isinstance(self.seed, int) and 0 <= self.seed < 2**63,
            "seed",
            self.seed,
            "must be a non-negative integer",
        )
        hx, hy = self.arena.half_extent
        for name, v, lim in (
            ("start_x_m", self.robot.start_x_m, hx),
            ("start_y_m", self.robot.start_y_m, hy),
        ):
            if not math.isnan(v):
                _check(abs(v) < lim - self.robot.radius_m, name, v, "is outside the arena")

    @property
    def n_frames(self) -> int:
        return round(self.duration_s * self.camera.fps)

    def to_sections(self) -> dict[str, dict[str, Any]]:
        """``{section: {field: value}}`` with JSON-friendly values (for recording properties)."""
        out: dict[str, dict[str, Any]] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if dataclasses.is_dataclass(v):
                out[f.name] = config_section(v)
            else:
                out.setdefault("run", {})[f.name] = _plain(v, str(f.type))
        out["wall"]["tf_schedule_text"] = format_schedule(self.wall.tf_schedule)
        return out

    def digest(self) -> str:
        """8 hex digits identifying this exact configuration (same config → same run)."""

        text = json.dumps({**self.to_sections(), "vdc": __version__}, sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()[:8]

    def run_id(self) -> str:
        """A readable recording id, e.g. ``grating-tf3-s1-1a2b3c4d``."""
        tfs = []
        for tf, _ in self.wall.tf_schedule:
            label = f"{tf:g}".replace(".", "p")
            if not tfs or tfs[-1] != label:
                tfs.append(label)
        kind = self.wall.scene if self.behaviour == "profile" else f"collision-{self.wall.scene}"
        return f"{kind}-tf{'-'.join(tfs)}-s{self.seed}-{self.digest()}"


_SEGMENT = re.compile(r"^\s*([0-9.eE+-]+)\s*:\s*([0-9.eE+-]+)\s*([smh]?)\s*$")
_UNIT_S = {"": 1.0, "s": 1.0, "m": 60.0, "h": 3600.0}


def parse_schedule(text: str) -> tuple[tuple[float, float], ...]:
    """``"0:30m,3:30m"`` → ``((0.0, 1800.0), (3.0, 1800.0))``: TF Hz and duration (s|m|h,
    seconds without a unit) per segment. Raises ValueError naming the bad segment."""
    if not text or not text.strip():
        raise UserError("empty TF schedule: expected e.g. 0:30m,3:30m (TF Hz : duration).")
    out = []
    for part in text.split(","):
        m = _SEGMENT.match(part)
        if m is None:
            raise UserError(
                f"TF schedule segment {part.strip()!r} is not TF:DURATION (e.g. 3:30m, 0:90s)."
            )
        try:
            tf = float(m.group(1))
            dur = float(m.group(2)) * _UNIT_S[m.group(3)]
        except ValueError:
            raise UserError(
                f"TF schedule segment {part.strip()!r} has a non-numeric value."
            ) from None
        if not (math.isfinite(tf) and 0 <= tf <= 100):
            raise UserError(f"TF {tf:g} Hz in schedule segment {part.strip()!r}: must be 0–100 Hz.")
        if not (math.isfinite(dur) and dur > 0):
            raise UserError(f"duration in schedule segment {part.strip()!r} must be > 0.")
        out.append((tf, dur))
    return tuple(out)


def format_schedule(schedule: tuple[tuple[float, float], ...]) -> str:
    """The inverse of ``parse_schedule`` (durations in seconds)."""
    return ",".join(f"{tf:g}:{dur:g}s" for tf, dur in schedule)

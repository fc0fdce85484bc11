"""The recording contract (docs/architecture.md): what capture writes and analysis reads.

| entity                      | archetype                         | meaning                        |
|-----------------------------|-----------------------------------|--------------------------------|
| ``/arena`` (static)         | LineStrips3D (ViewCoordinates: /) | walls, light ring              |
| ``/arena/wall/tf_hz``       | Scalars                           | wall temporal frequency        |
| ``/arena/robot_path``       | Points3D                          | the robot's position (trail)   |
| ``/robot/pose``             | Scalars [x_m, y_m, heading_rad]   | tracked or simulated pose      |
| ``/robot``                  | Transform3D                       | the same pose, for the 3D view |
| ``/robot/camera/image``     | Image (L, U8)                     | raw on-board frame, lossless   |
| ``/robot/camera/timing``    | Scalars [repeat, dropped, dt_s]   | video: repeated/dropped frames |
| ``/model/<name>/<output>``  | Scalars                           | online model outputs           |
| ``/events/<kind>``          | TextLog + Points3D                | ring_turn, avoidance, crash... |
| ``/overhead/image``         | Image                             | optional overhead frames       |
| ``/link/stats``             | Scalars (hardware runs)           | serial link counts             |
| ``/description`` (static)   | TextDocument (markdown)           | what, model, camera, analyse   |
| ``/dataset/<cam>/video``    | VideoStream (AV1, H.264, HEVC)    | a dataset episode's packets    |
| ``/dataset/<cam>/measures/*``| Scalars                          | its per-frame measures         |

Timelines: ``frame`` (camera frame index) and ``time`` (duration since the run started);
hardware runs add ``capture_time``. Recording properties are sections of flat key-value pairs
(``PROPERTY_SECTIONS``). The recorder modules (``capture.recorder``, ``capture.live_view``)
write this and ``analysis.recordings.reader`` reads it; both import the names from here.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

# Rerun's own log lines that vdc replaces with one line of its own, one setting for every
# process (set before the SDK starts its logger, at import; a RUST_LOG the user set wins, and a
# process that sets it passes it to the processes it starts): a viewer that went away or a file
# it could not write (the recorder says so once) and a catalog server that failed under a
# query (analysis.catalog.query says so, naming the URL).
RERUN_LOG = "warn," + ",".join(
    f"{target}=off"
    for target in ("re_sdk::recording_stream", "re_grpc_client", "re_redap_client", "re_datafusion")
)


APP_ID = "vdc"
FRAME_TIMELINE = "frame"
TIME_TIMELINE = "time"
CAPTURE_TIME_TIMELINE = "capture_time"

ARENA = "/arena"
ARENA_WALLS = "/arena/walls"
ARENA_RING = "/arena/ring"
WALL_TF = "/arena/wall/tf_hz"
ROBOT_PATH = "/arena/robot_path"
ROBOT = "/robot"
ROBOT_BODY = "/robot/body"
ROBOT_HEADING = "/robot/heading"
POSE = "/robot/pose"
CAMERA = "/robot/camera/image"
# per camera frame: repeats the previous frame (0/1), frames missing just before it (from the
# timestamps), seconds since the previous frame; video recordings only
FRAME_TIMING = "/robot/camera/timing"
FRAME_TIMING_NAMES = ("repeat", "dropped_before", "dt_s")
# per frame of a source with native frames (video files, image sequences, cameras): the
# standard metrics on its native luma (vdc.frame_metrics), one series per name
NATIVE_METRICS_PATH = "/robot/camera/native_metrics"
NATIVE_METRICS = (
    "si_p910",
    "ti_p910",
    "si_legacy",
    "ti_legacy",
    "mafd",
    "edge_density",
    "jpeg_bpp",
    "codec_bpp",
)
OVERHEAD = "/overhead/image"
EVENTS = "/events"
MODEL_ROOT = "/model"
MODEL_VARIANTS_ROOT = "/model_variants"
COMPLEXITY_ROOT = "/complexity"  # baselines written by `vdc-analyse complexity` (same id)
# the unit of each metric `vdc-analyse complexity` writes, as docs/guides/video.md's table of
# columns gives it: its figure's axes, its recording's series and the viewer's panes, by unit
COMPLEXITY_UNITS = {
    "omega_dps": "deg/s",
    "flow_dps": "deg/s",
    "si_p910": "P.910 (×255)",
    "ti_p910": "P.910 (×255)",
    "si_legacy": "8-bit levels",
    "ti_legacy": "8-bit levels",
    "mafd": "8-bit levels",
    "edge_density": "share of pixels",
    "zlib_ratio": "compressed / raw",
    "jpeg_bpp": "bits/pixel",
    "codec_bpp": "bits/pixel",
}
LINK_STATS = "/link/stats"
# every capture's description of itself: what was recorded, with which model and camera, and
# the vdc-analyse commands that read it (markdown, static)
DESCRIPTION = "/description"
POSE_NAMES = ("x_m", "y_m", "heading_rad")

EVENT_KINDS = (
    "ring_turn",
    "avoidance",
    "crash",
    "link_error",
    "tracker_lost",
    "dropped_frames",
    "decode_error",
    "dataset_flag",
)

# Recording property sections (rr.send_property): each a flat dict of scalars and strings.
PROPERTY_SECTIONS = {
    "run": "recording id, source (simulation | robot), seed, behaviour, versions",
    "arena": "geometry of the arena (ArenaConfig)",
    "wall": "scene, period_m, contrast, tf_schedule_text, image_path",
    "robot": "the robot body and motion (RobotConfig)",
    "camera": "width_px, height_px, fps, hfov_deg, height_m, noise_sd; robot runs: announced "
    "(the robot's own camera, from its ANNOUNCE, else the host's defaults)",
    "overhead": "the optional overhead camera",
    "collision": "collision mode: detector spec, threshold, adaptive rule, phase",
    "model": "name and output units of the online model; robot runs: verified (the robot "
    "announced it) and on_board",
    "model_params": "the online model's parameters",
    "detector": "collision mode: name and output units of the detector",
    "detector_params": "collision mode: the detector's parameters",
    "link": "hardware runs: serial protocol and its counters",
    "provenance": "package versions, CPU model and Numba's compile target",
    "video": "video sources: path, codec, nominal fps, source size, rotation, FOV, bit depth "
    "and colour range; the header's duration, the frames the container states "
    "(container_frames) and the first frame's time after the stream's start (first_frame_s)",
    "calibration": "the AVDM decoding fit in use: a, b, r2, rms_rel_error, source",
    "model_context": "what every model of this recording is built with: fps, deg_per_px, "
    "texture_row (capture, recomputation and complexity read this one section)",
    "run_end": "written last: frames, stop_reason, complete",
    "episode": "a dataset episode (vdc-analyse dataset): episode_index, cameras, flags, "
    "flag_count, flagged_frame",
}


def entity_name(model_name: str) -> str:
    """A model spec as one entity-path part: ``avdm:beta=0.5`` → ``avdm_beta_0.5``."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", model_name)


def model_path(model_name: str, output: str) -> str:
    return f"{MODEL_ROOT}/{entity_name(model_name)}/{output}"


def variant_path(model_name: str, output: str) -> str:
    return f"{MODEL_VARIANTS_ROOT}/{entity_name(model_name)}/{output}"


# a robot-learning dataset's episode (``vdc-analyse dataset``): per camera (its feature key,
# e.g. ``observation.images.front``), the video's packets and the per-frame measures
DATASET_ROOT = "/dataset"


def dataset_video_path(camera: str) -> str:
    return f"{DATASET_ROOT}/{entity_name(camera)}/video"


def dataset_measure_path(camera: str, measure: str) -> str:
    return f"{DATASET_ROOT}/{entity_name(camera)}/measures/{measure}"


def event_path(kind: str) -> str:
    return f"{EVENTS}/{kind}"


# The AVDM variant for real footage (valid 1-300 deg/s at 25-30 fps): the default model of
# `vdc-capture video` and `vdc-analyse complexity`. The faithful `avdm` reads low and differs
# by direction above about 1-2 px of motion per frame on natural texture.
FOOTAGE_MODEL = "avdm-natural"

# The angular pitch the models were designed and calibrated for: the robot camera's 70° over
# 99 px. Video is resized to it (``working_size``) unless a width is given.
ROBOT_DEG_PER_PX = 70.0 / 99.0


def working_size(
    src_h: int, src_w: int, fov_deg: float, width: int | None = None
) -> tuple[int, int]:
    """(H, W) of the frames the models see for a source of ``src_h`` x ``src_w`` px whose
    horizontal field of view is ``fov_deg``: ``width`` if given, else the robot camera's
    angular pitch; the height keeps the aspect ratio (at least 4 rows)."""
    w = width or max(8, round(fov_deg / ROBOT_DEG_PER_PX))
    return max(4, round(w * src_h / src_w)), w


def camera_model_context(
    width_px: int, height_px: int, fps: float, hfov_deg: float
) -> dict[str, float | int]:
    """What a model needs to know about a camera: frame rate, angular pitch (deg/px at the
    image centre) and the AVDM's texture row (the horizon row, H/2: the released code's row 2
    sees the dark room above the arena wall on the robot camera). The capture builds its
    online model from this, and analysis rebuilds the same model from the recorded camera
    properties, so online and offline outputs agree bit for bit. The raster (``width_px``,
    ``height_px``) is part of it: the multi-scale AVDM's scales, hence its calibration, depend
    on the frame size."""
    return {
        "fps": fps,
        "deg_per_px": hfov_deg / width_px,
        "texture_row": height_px // 2,
        "width_px": width_px,
        "height_px": height_px,
    }


# A capture writes <stem>.partial.rrd beside its output while it runs and holds an flock on
# .<name>.lock (which names its pid); capture.output writes these, the reader checks them.
PARTIAL_SUFFIX = ".partial.rrd"


def partial_path(path: Path) -> Path:
    """Where a capture to ``path`` writes until it ends: ``<stem>.partial.rrd`` beside it."""
    return path.with_name(path.name.removesuffix(".rrd") + PARTIAL_SUFFIX)


def lock_path(path: Path) -> Path:
    """The claim of the capture writing ``path`` (or its partial file)."""
    name = path.name
    if name.endswith(PARTIAL_SUFFIX):
        name = name.removesuffix(PARTIAL_SUFFIX) + ".rrd"
    return path.with_name(f".{name}.lock")


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid runs (one of another user's counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def capture_writing(path: Path) -> int | None:
    """The pid of a live capture writing ``path`` (a final or partial name), else None."""
    try:
        text = lock_path(path).read_text().split()
    except OSError:
        return None
    if not text or not text[0].isdigit():
        return None
    pid = int(text[0])
    return pid if pid_alive(pid) else None  # a dead pid: a claim left by a killed capture

"""Loading a recording for analysis: its properties, its ``frames`` table (poses, wall TF,
frame timing, wall gap, the robot's own yaw rate and turns), every model output the capture
logged online and the native-frame metrics, as one ``LoadedRecording``; the tables, summaries
and recomputation built on it are in ``analysis.recordings.recompute``.

``frames`` columns: recording_id, frame, t_s, x_m, y_m, heading_rad, wall_tf_hz, wall_gap_m
(distance from the robot's centre to the nearest wall), repeat, dropped_before (video frame
timing), robot_omega_dps (the robot's own yaw rate) and turning (see ``ego_motion``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import polars as pl

from analysis.recordings.ego_motion import turning_flags, yaw_rate_dps
from analysis.recordings.reader import Recording, RecordingError
from vdc.recording import (
    FRAME_TIMING,
    MODEL_ROOT,
    NATIVE_METRICS,
    NATIVE_METRICS_PATH,
    POSE,
    WALL_TF,
    camera_model_context,
    entity_name,
)

# what counts as the robot turning (analysis/recordings/ego_motion.py), unless the settings say otherwise
TURN_THRESHOLD_DPS = 30.0
TURN_HOLD_FRAMES = 10  # the AVDM remembers a turn for its 10-frame window


class TurnRule(Protocol):
    """What counts as a turn: ``analysis.recordings.recompute.SummarySettings`` is one."""

    @property
    def turn_threshold_dps(self) -> float: ...

    @property
    def turn_hold_frames(self) -> int: ...


@dataclasses.dataclass(frozen=True)
class DefaultTurns:
    """The default ``TurnRule``."""

    turn_threshold_dps: float = TURN_THRESHOLD_DPS
    turn_hold_frames: int = TURN_HOLD_FRAMES


FRAMES_COLUMNS = (
    "recording_id",
    "frame",
    "t_s",
    "x_m",
    "y_m",
    "heading_rad",
    "wall_tf_hz",
    "wall_gap_m",
    "repeat",
    "dropped_before",
    "robot_omega_dps",
    "turning",
)


@dataclasses.dataclass
class LoadedRecording:
    """What analysis needs from one recording (frames are streamed separately)."""

    rec: Recording
    props: dict[str, dict[str, Any]]
    frames: pl.DataFrame
    logged: dict[str, pl.DataFrame]  # online model name → its logged outputs
    # the standard metrics the capture measured on the source's native frames (frame, then
    # one column per vdc.recording.NATIVE_METRICS name); None: a source without native frames
    native: pl.DataFrame | None = None

    @property
    def recording_id(self) -> str:
        return self.rec.recording_id

    @property
    def online_model(self) -> str | None:
        return self.props.get("model", {}).get("name")

    def camera_context(self) -> dict[str, float | int]:
        """The camera facts a model needs (fps, deg/px, texture row): the recording's own
        ``model_context`` section, which the capture built its online model with, else (older
        recordings) derived from its camera properties as the capture derived them. Nothing
        is assumed: a recording with neither raises RecordingError naming what it lacks."""
        recorded = self.props.get("model_context", {})
        if "fps" in recorded and "deg_per_px" in recorded:
            ctx: dict[str, float | int] = {
                "fps": float(recorded["fps"]),
                "deg_per_px": float(recorded["deg_per_px"]),
            }
            for key in ("texture_row", "width_px", "height_px"):
                if key in recorded:
                    ctx[key] = int(recorded[key])
            return ctx
        cam = self.props.get("camera", {})
        _require(self.rec.path, "camera", cam, ("fps", "width_px", "height_px", "hfov_deg"))
        return camera_model_context(
            int(cam["width_px"]), int(cam["height_px"]), float(cam["fps"]), float(cam["hfov_deg"])
        )

    def arena_half_extent(self) -> tuple[float, float]:
        """Half the arena's length and width, m; NaN for a recording without poses (a video),
        RecordingError for one with poses that does not record its arena."""
        has_poses = self.frames["x_m"].drop_nulls().len() > 0
        return _arena_half_extent(self.props, has_poses, self.rec.path)


def _require(path: str | Path, section: str, values: dict[str, Any], keys: Sequence[str]) -> None:
    """RecordingError in one line unless the property ``section`` holds every key of ``keys``:
    analysis assumes no camera and no arena."""
    missing = [k for k in keys if k not in values]
    if missing:
        raise RecordingError(
            f"{str(path)!r} is an old or foreign recording: it lacks "
            + ("a model_context section and " if section == "camera" else "")
            + f"the {section} propert{'ies' if len(missing) > 1 else 'y'} "
            f"{', '.join(missing)}, and analysis assumes none; record it again with this vdc"
        )


def _arena_half_extent(
    props: dict[str, dict[str, Any]], has_poses: bool, path: str | Path
) -> tuple[float, float]:
    if not has_poses:
        return math.nan, math.nan  # no position, no wall gap: the arena does not matter
    arena = props.get("arena", {})
    _require(path, "arena", arena, ("length_m", "width_m"))
    return float(arena["length_m"]) / 2, float(arena["width_m"]) / 2


class Notices(list):
    """Notes about repaired recordings: kept (for a command's result) and passed on to
    ``sink`` as they come (the CLI prints them)."""

    def __init__(self, sink: Callable[[str], None] | None = None) -> None:
        super().__init__()
        self.sink = sink

    def __call__(self, msg: str) -> None:
        self.append(msg)
        if self.sink is not None:
            self.sink(msg)

    def of(self, loaded: LoadedRecording) -> None:
        """The recording's own note (footer missing, file repaired), if it has one."""
        if loaded.rec.notice:
            self(loaded.rec.notice)


def load_recording(path: str | Path, settings: TurnRule = DefaultTurns()) -> LoadedRecording:
    """Open a recording and read its properties, poses, wall TF, frame timing and logged model
    outputs. A recording without poses (a video) has null poses, wall TF, wall gap, yaw rate
    and turning flag; one without frame timing (simulated or robot runs) has null ``repeat``
    and ``dropped_before``. ``settings`` says what counts as a turn."""
    rec = Recording(path)
    props = rec.properties()
    frames, logged, native = from_signals(rec.signals(), props, rec.recording_id, settings, path)
    return LoadedRecording(rec, props, frames, logged, native)


def from_signals(
    sig: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
    props: dict[str, dict[str, Any]],
    recording_id: str,
    settings: TurnRule = DefaultTurns(),
    path: str | Path = "",
) -> tuple[pl.DataFrame, dict[str, pl.DataFrame], pl.DataFrame | None]:
    """A recording's ``frames`` table, its online model's logged outputs and its native
    metrics, from its scalar signals ``{entity: (frame (N,), t_s (N,), values (N, K))}`` and
    its properties: the one construction behind ``tables`` and the catalog's queries."""
    if POSE in sig:
        f, t, pose = sig[POSE]
        frames = pl.DataFrame(
            {
                "frame": f.astype(np.int64),
                "t_s": t,
                "x_m": pose[:, 0],
                "y_m": pose[:, 1],
                "heading_rad": pose[:, 2],
            }
        )
        if _has_frame_index(sig):
            # a real robot's overhead tracker can miss frames (its first ones, on a busy
            # host): those frames still have images and outputs, and keep their rows, posed
            # with nulls; the poses alone would silently drop them from every table
            fi, ti = _frame_index(sig, path)
            every = pl.concat(
                [pl.DataFrame({"frame": fi, "t_s": ti}), frames.select("frame", "t_s")]
            ).unique("frame", keep="first", maintain_order=True)
            frames = every.join(frames.drop("t_s"), on="frame", how="left").sort("frame")
    else:
        f, t = _frame_index(sig, path)
        nan = np.full(len(f), np.nan)
        frames = pl.DataFrame(
            {"frame": f, "t_s": t, "x_m": nan, "y_m": nan, "heading_rad": nan}
        ).with_columns(pl.col("x_m", "y_m", "heading_rad").fill_nan(None))
    if WALL_TF in sig:
        tf_f, _, tf = sig[WALL_TF]
        tf_df = pl.DataFrame({"frame": tf_f.astype(np.int64), "wall_tf_hz": tf[:, 0]})
        frames = frames.join(tf_df, on="frame", how="left")
    else:
        frames = frames.with_columns(wall_tf_hz=pl.lit(None, pl.Float64))
    if FRAME_TIMING in sig:
        tm_f, _, tm = sig[FRAME_TIMING]
        timing = pl.DataFrame(
            {
                "frame": tm_f.astype(np.int64),
                "repeat": tm[:, 0] > 0.5,
                "dropped_before": tm[:, 1].astype(np.int64),
            }
        )
        frames = frames.join(timing, on="frame", how="left")
    else:
        frames = frames.with_columns(
            repeat=pl.lit(None, pl.Boolean), dropped_before=pl.lit(None, pl.Int64)
        )
    omega = yaw_rate_dps(
        frames["t_s"].to_numpy(), frames["heading_rad"].fill_null(np.nan).to_numpy()
    )
    turning = turning_flags(omega, settings.turn_threshold_dps, settings.turn_hold_frames)
    frames = frames.with_columns(
        pl.Series("robot_omega_dps", omega).fill_nan(None),
        pl.Series("turning", turning).fill_nan(None).cast(pl.Boolean),
    )
    native = None
    if NATIVE_METRICS_PATH in sig:
        nf, _, nv = sig[NATIVE_METRICS_PATH]
        cols = {name: nv[:, k] for k, name in enumerate(NATIVE_METRICS) if k < nv.shape[1]}
        native = pl.DataFrame({"frame": nf.astype(np.int64), **cols}).with_columns(
            pl.col(*cols).fill_nan(None)
        )
    hx, hy = _arena_half_extent(props, POSE in sig, path)
    frames = frames.with_columns(
        pl.lit(recording_id).alias("recording_id"),
        pl.min_horizontal(hx - pl.col("x_m").abs(), hy - pl.col("y_m").abs()).alias("wall_gap_m"),
    ).select(*FRAMES_COLUMNS)
    return frames, logged_outputs(sig, props), native


def logged_outputs(
    sig: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], props: dict[str, dict[str, Any]]
) -> dict[str, pl.DataFrame]:
    """Every model the capture logged online, ``{name: frame, t_s, outputs...}``: the online
    model, a collision run's detector and its controller, each under ``/model/<name>/``. A name
    is the spec the properties give for that entity (``model``, ``detector``), else the entity's
    own name (``controller``)."""
    specs = {
        entity_name(name): name
        for section in ("model", "detector")
        if (name := props.get(section, {}).get("name"))
    }
    roots = {e[len(MODEL_ROOT) + 1 :].split("/")[0] for e in sig if e.startswith(MODEL_ROOT + "/")}
    logged: dict[str, pl.DataFrame] = {}
    for root in sorted(roots, key=lambda r: (r not in specs, r)):  # the online model first
        out = signals_table(sig, f"{MODEL_ROOT}/{root}/")
        if out is not None:
            logged[specs.get(root, root)] = out
    return logged


def logged_params(props: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """``{name: params}`` of the models a capture logged (the online model, the detector)."""
    return {
        name: dict(props.get(f"{section}_params", {}))
        for section in ("model", "detector")
        if (name := props.get(section, {}).get("name"))
    }


def signals_table(
    sig: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], prefix: str
) -> pl.DataFrame | None:
    """The scalar entities under ``prefix`` (one model's outputs) as one table: frame, t_s,
    then a column per output. A capture killed mid-write may have logged some outputs of its
    last frames and not others: every frame any output reached is kept, missing values null."""
    cols = {e[len(prefix) :]: v for e, v in sig.items() if e.startswith(prefix)}
    if not cols:
        return None
    parts = [
        pl.DataFrame({"frame": v[0].astype(np.int64), "t_s": v[1], name: v[2][:, 0]})
        for name, v in cols.items()
    ]
    index = pl.concat([p.select("frame", "t_s") for p in parts]).unique("frame")
    table = index.sort("frame")
    for p in parts:
        table = table.join(p.drop("t_s"), on="frame", how="left")
    return table


def _has_frame_index(sig: dict) -> bool:
    return FRAME_TIMING in sig or any(e.startswith(MODEL_ROOT + "/") for e in sig)


def _frame_index(sig: dict, path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices and times of a recording without poses: from its frame timing, else
    from its first logged model output."""
    for entity in (FRAME_TIMING, *sorted(e for e in sig if e.startswith(MODEL_ROOT + "/"))):
        if entity in sig:
            f, t, _ = sig[entity]
            return f.astype(np.int64), t
    raise RecordingError(f"{str(path)!r} holds neither poses nor frame timing nor model outputs")

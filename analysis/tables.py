"""Recordings → polars tables → Parquet, and model recomputation (the table contract is in
docs/architecture.md).

* ``frames``: recording_id, frame, t_s, x_m, y_m, heading_rad, wall_tf_hz, wall_gap_m
  (distance from the robot's centre to the nearest wall), repeat, dropped_before (video frame
  timing), robot_omega_dps (the robot's own yaw rate) and turning (see ``ego_motion``);
* ``model_outputs``: recording_id, model, frame, t_s, one column per output (long over models);
* ``events``: recording_id, frame, t_s, kind, x_m, y_m, heading_rad, dtc_m (distance to
  collision: from the robot's body along its heading to the wall, D_ray − r), text;
* ``summary``: recording_id, model, condition columns (scene, wall_tf_hz, period_m, seed,
  source), motion ("all" frames, or "straight" driving only), output, n_frames, mean, p50,
  p95, max, frac_over_100, frac_over_threshold, near_wall_mean, centre_mean,
  near_wall_centre_ratio, threshold_dps.

Every table is a pure function of its recordings, the model params and the settings: re-running
writes identical rows. Frames are streamed chunk by chunk through all requested models at once.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.ego_motion import turning_flags, yaw_rate_dps
from analysis.rrd_reader import Recording, RecordingError
from avdm.base import Model, primary_output_name
from avdm.registry import canonical_name, make_model, parse_model_spec
from avdm.true_time import TrueTimeModel
from vdc.arena_geometry import distance_to_wall_along
from vdc.cli_support import API_ONLY, non_negative_int, option, positive_float
from vdc.parquet_io import WroteFiles, table_set, write_parquet
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


@dataclasses.dataclass(frozen=True)
class SummarySettings:
    """How summaries are computed (stored in the Parquet metadata as ``settings``)."""

    threshold_dps: float = option(
        100.0,
        "response threshold, deg/s (default: {default}, the paper's)",
        "--threshold",
        type=positive_float,
    )
    near_wall_m: float = option(  # PROPOSED: the paper does not define "near the wall"
        0.15, "'near the wall' = robot centre within this of a wall, m", type=positive_float
    )
    centre_m: float = option(
        0.25, "'centre' = farther than this from every wall, m", type=positive_float
    )
    # the models' first 2·Tw frames are left out of statistics
    warmup_frames: int = dataclasses.field(default=20, metadata=API_ONLY)
    # the robot's own turns (analysis/ego_motion.py): flagged in the frames table, and left
    # out of the summaries with exclude_turns
    turn_threshold_dps: float = option(
        30.0, "the robot turns when its own yaw rate exceeds this, deg/s", type=positive_float
    )
    turn_hold_frames: int = option(
        10,
        "frames after a turn still counted as turning: the AVDM remembers a turn for its "
        "10-frame window",
        type=non_negative_int,
    )
    exclude_turns: bool = option(
        False,
        "summarise straight driving only: leave out frames where the robot turns (or turned "
        "within --turn-hold-frames), so its own rotation is not counted as the scene's "
        "complexity",
    )

    def __post_init__(self) -> None:
        for name in ("threshold_dps", "near_wall_m", "centre_m", "turn_threshold_dps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}={v!r} must be a number >= 0")
        for name in ("warmup_frames", "turn_hold_frames"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)} must be >= 0")

    @property
    def motion(self) -> str:
        """Which frames the summaries use: "all", or "straight" driving only."""
        return "straight" if self.exclude_turns else "all"

    def summary_settings(self) -> SummarySettings:
        """Just the summary fields (what the tables' metadata records as ``settings``)."""
        return SummarySettings(
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(SummarySettings)}
        )


@dataclasses.dataclass(frozen=True)
class TablesSettings(SummarySettings):
    """``vdc-analyse tables``: the summary settings plus the models to recompute (none = the
    online model's logged outputs)."""

    models: tuple[str, ...] = option(
        (), "recompute this variant (repeatable)", flag="--model", metavar="MODEL"
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "models", tuple(self.models or ()))
        for spec in self.models:
            parse_model_spec(spec)  # an unknown model fails before any file is read


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


def load_recording(
    path: str | Path, settings: SummarySettings = SummarySettings()
) -> LoadedRecording:
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
    settings: SummarySettings = SummarySettings(),
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


def recompute(
    loaded: LoadedRecording,
    specs: Sequence[str],
    progress: Callable[[int], None] | None = None,
) -> dict[str, pl.DataFrame]:
    """Run every model in ``specs`` over the recorded raw frames, streaming chunk by chunk.

    Returns ``{canonical model name: DataFrame(frame, t_s, outputs...)}``. Models are built
    with the recording's camera (fps, deg/px), so the online model recomputes to the exact
    floats it logged."""
    ctx = loaded.camera_context()
    models: list[Model] = [make_model(s, **ctx) for s in specs]
    # a real camera's recording (frame timing logged): new frames only, over true time, as
    # the capture ran its online model (avdm.true_time)
    timing = loaded.frames.select("frame", "t_s", "repeat").drop_nulls()
    true_time = timing.height > 0
    runners = [TrueTimeModel(m) for m in models] if true_time else models
    by_frame = timing.sort("frame") if true_time else None
    outs: dict[str, list[dict[str, np.ndarray]]] = {m.name: [] for m in models}
    frames: list[np.ndarray] = []
    for chunk in loaded.rec.iter_frames():
        frames.append(chunk.frame)
        if by_frame is not None:
            sel = pl.DataFrame({"frame": chunk.frame.astype(np.int64)}).join(
                by_frame, on="frame", how="left", maintain_order="left"
            )
            t_c = sel["t_s"].to_numpy()
            rep = sel["repeat"].fill_null(False).to_numpy()
        for m in runners:
            if isinstance(m, TrueTimeModel):
                outs[m.name].append(m.run(chunk.images, t_c, rep))
            else:
                outs[m.name].append(m.run(chunk.images))
        if progress is not None:
            progress(len(chunk.frame))
    frame = np.concatenate(frames)
    t = loaded.frames.select("frame", "t_s")
    result = {}
    for m in models:
        cols = {o.name: np.concatenate([p[o.name] for p in outs[m.name]]) for o in m.outputs}
        df = pl.DataFrame({"frame": frame.astype(np.int64), **cols})
        # a snapshot of a recording still being written may hold a batch's images before the
        # same batch's poses: the tables keep the frames the frames table has, and no others
        result[m.name] = df.join(t, on="frame", how="inner").select("frame", "t_s", *cols)
    return result


def model_params(loaded: LoadedRecording, specs: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``{model name: params dict}`` as the models are built for this recording."""
    ctx = loaded.camera_context()
    return {canonical_name(s): make_model(s, **ctx).params.to_dict() for s in specs}


def model_outputs_table(loaded: LoadedRecording, outputs: dict[str, pl.DataFrame]) -> pl.DataFrame:
    """Long table over models: recording_id, model, frame, t_s, output columns."""
    parts = [
        df.with_columns(
            pl.lit(loaded.recording_id).alias("recording_id"), pl.lit(name).alias("model")
        ).select("recording_id", "model", pl.all().exclude("recording_id", "model"))
        for name, df in outputs.items()
    ]
    return pl.concat(parts, how="diagonal_relaxed") if parts else pl.DataFrame()


def events_table(loaded: LoadedRecording) -> pl.DataFrame:
    ev = loaded.rec.events()
    pose = loaded.frames.select("frame", "x_m", "y_m", "heading_rad")
    ev = ev.join(pose, on="frame", how="left", suffix="_pose")
    # the event's own logged position wins; the pose fills in for events without one
    ev = ev.with_columns(
        pl.when(pl.col("x_m").is_nan())
        .then(pl.col("x_m_pose"))
        .otherwise(pl.col("x_m"))
        .alias("x_m"),
        pl.when(pl.col("y_m").is_nan())
        .then(pl.col("y_m_pose"))
        .otherwise(pl.col("y_m"))
        .alias("y_m"),
    )
    hx, hy = loaded.arena_half_extent()
    radius = float(loaded.props.get("robot", {}).get("radius_m", 0.0))
    dtc = distance_to_wall_along(
        ev["x_m"].to_numpy(),
        ev["y_m"].to_numpy(),
        ev["heading_rad"].fill_null(np.nan).to_numpy(),
        hx,
        hy,
    )
    return ev.with_columns(
        pl.lit(loaded.recording_id).alias("recording_id"), pl.Series("dtc_m", dtc - radius)
    ).select("recording_id", "frame", "t_s", "kind", "x_m", "y_m", "heading_rad", "dtc_m", "text")


NON_OUTPUT_COLUMNS = (
    "recording_id",
    "model",
    "frame",
    "t_s",
    "wall_tf_hz",
    "wall_gap_m",
    "turning",
)
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


def _frame_index(sig: dict, path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices and times of a recording without poses: from its frame timing, else
    from its first logged model output."""
    for entity in (FRAME_TIMING, *sorted(e for e in sig if e.startswith(MODEL_ROOT + "/"))):
        if entity in sig:
            f, t, _ = sig[entity]
            return f.astype(np.int64), t
    raise RecordingError(f"{str(path)!r} holds neither poses nor frame timing nor model outputs")


def primary_output(outputs_df: pl.DataFrame) -> str:
    """The output summaries are about: ``omega_dps`` when a model has it, else its first
    output (the column order of a model's ``outputs``); all-null columns belong to other
    models of a long table."""
    cols = [
        c
        for c in outputs_df.columns
        if c not in NON_OUTPUT_COLUMNS and outputs_df[c].null_count() < outputs_df.height
    ]
    if not cols:
        raise ValueError("no model output columns")
    return primary_output_name(cols)


def condition_columns(loaded: LoadedRecording) -> dict[str, Any]:
    wall = loaded.props.get("wall", {})
    run = loaded.props.get("run", {})
    return {
        "scene": wall.get("scene"),
        "period_m": wall.get("period_m"),
        "seed": run.get("seed"),
        "source": run.get("source"),
    }


def summarise(values: np.ndarray, gap: np.ndarray, s: SummarySettings) -> dict[str, float]:
    """Statistics of one response series (N,) given the wall gap (N,) of each frame."""
    if len(values) == 0:
        nan = float("nan")
        return dict.fromkeys(
            (
                "mean",
                "p50",
                "p95",
                "max",
                "frac_over_100",
                "frac_over_threshold",
                "near_wall_mean",
                "centre_mean",
                "near_wall_centre_ratio",
            ),
            nan,
        )
    near = values[gap <= s.near_wall_m]
    centre = values[gap > s.centre_m]
    near_mean = float(near.mean()) if len(near) else float("nan")
    centre_mean = float(centre.mean()) if len(centre) else float("nan")
    ratio = near_mean / centre_mean if centre_mean > 0 else float("nan")
    return {
        "mean": float(values.mean()),
        "p50": float(np.percentile(values, 50)),
        "p95": float(np.percentile(values, 95)),
        "max": float(values.max()),
        "frac_over_100": float((values > 100.0).mean()),
        "frac_over_threshold": float((values > s.threshold_dps).mean()),
        "near_wall_mean": near_mean,
        "centre_mean": centre_mean,
        "near_wall_centre_ratio": ratio,
    }


def summary_table(
    loaded: LoadedRecording, outputs: pl.DataFrame, s: SummarySettings
) -> pl.DataFrame:
    """One row per (model, wall TF in force) of a recording."""
    return summary_rows(loaded.recording_id, condition_columns(loaded), loaded.frames, outputs, s)


MOTIONS = ("all", "straight", "turning")


def frames_in_statistics(
    df: pl.DataFrame, s: SummarySettings, recording_id: str, motion: str | None = None
) -> pl.DataFrame:
    """The rows of ``df`` (one recording's; columns ``frame`` and ``turning``) that statistics
    use: after the warm-up, and with ``s.exclude_turns`` only frames known to be straight.
    ``motion`` overrides the settings: "all", "straight" or "turning" frames."""
    motion = motion or s.motion
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}")
    df = df.filter(pl.col("frame") >= s.warmup_frames)
    if motion == "all":
        return df
    if df.height and df["turning"].null_count() == df.height:
        raise RecordingError(
            f"{recording_id} has no poses, so its turns are unknown: exclude_turns "
            "(--exclude-turns) needs a simulated or tracked run"
        )
    if motion == "turning":
        return df.filter(pl.col("turning"))
    return df.filter(pl.col("turning").not_())  # unknown (null) is not known to be straight


def summary_rows(
    recording_id: str,
    cond: dict[str, Any],
    frames: pl.DataFrame,
    outputs: pl.DataFrame,
    s: SummarySettings,
    motion: str | None = None,
) -> pl.DataFrame:
    """The summary of one recording's ``frames`` and ``outputs`` (both for that recording
    only); with ``s.exclude_turns`` only frames known to be straight driving count, and
    ``motion`` ("all", "straight", "turning") overrides that."""
    joined = outputs.join(
        frames.select("frame", "wall_tf_hz", "wall_gap_m", "turning"), on="frame", how="left"
    )
    motion = motion or s.motion
    joined = frames_in_statistics(joined, s, recording_id, motion)
    rows = []
    for (model, tf), g in joined.group_by("model", "wall_tf_hz", maintain_order=True):
        out = primary_output(g)
        vals = g[out].to_numpy()
        finite = np.isfinite(vals)
        rows.append(
            {
                "recording_id": recording_id,
                "model": model,
                **cond,
                "wall_tf_hz": tf,
                "motion": motion,
                "output": out,
                "n_frames": int(finite.sum()),
                **summarise(vals[finite], g["wall_gap_m"].to_numpy()[finite], s),
                "threshold_dps": s.threshold_dps,
            }
        )
    if not rows:
        n = frames.height
        why = (
            f"it has {n} frames and the summary skips the models' warm-up of "
            f"{s.warmup_frames}: record at least {s.warmup_frames + 1} frames"
            if n <= s.warmup_frames
            else f"no frame after the warm-up is {motion} driving"
        )
        raise RecordingError(f"{recording_id}: nothing to summarise: {why}")
    # a video has no walls: its wall TF is a null Float64 column, not an untyped one
    return (
        pl.DataFrame(rows)
        .with_columns(pl.col("wall_tf_hz").cast(pl.Float64))
        .sort("recording_id", "model", "wall_tf_hz")
    )


class DistinctRecordings:
    """Refuses a second recording with an id already seen in one analysis: the same file
    given twice, a copy, or a run recorded twice would give every table duplicate
    ``(recording_id, frame)`` keys."""

    def __init__(self) -> None:
        self.seen: dict[str, str] = {}

    def add(self, recording_id: str, path: str | Path) -> None:
        first = self.seen.get(recording_id)
        if first is None:
            self.seen[recording_id] = str(path)
            return
        what = (
            "is given twice"
            if Path(first).resolve() == Path(path).resolve()
            else f"and {first!r} are the same recording (id {recording_id})"
        )
        raise RecordingError(f"{str(path)!r} {what}: give each recording once")


def check_models(loaded: LoadedRecording, specs: Sequence[str]) -> None:
    """Each model in ``specs`` built with ``loaded``'s camera and stepped on one frame of its
    raster (:func:`avdm.registry.check_detector` without the alert), before any long run: a
    plug-in that cannot run is a ValueError in one line."""
    from avdm.registry import check_detector

    ctx = loaded.camera_context()
    cam = loaded.props.get("camera", {})
    h = int(ctx.get("height_px", cam.get("height_px", 0)))
    w = int(ctx.get("width_px", cam.get("width_px", 0)))
    if h <= 0 or w <= 0:
        first = next(loaded.rec.iter_frames(), None)
        if first is None:
            return
        h, w = first.images.shape[1:3]
    for spec in dict.fromkeys(specs):
        check_detector(spec, ctx, (h, w), alert=False)


def build_tables(
    paths: Sequence[str | Path],
    specs: Sequence[str] | None,
    settings: SummarySettings = SummarySettings(),
    progress: Callable[[int], None] | None = None,
    notices: Callable[[str], None] | None = None,
) -> tuple[dict[str, pl.DataFrame], dict[str, Any]]:
    """All four tables for ``paths``; ``specs`` None = the online model's logged outputs.

    Returns the tables and the metadata to store with them."""
    frames, outputs, events, summary = [], [], [], []
    params: dict[str, dict[str, dict[str, Any]]] = {}
    arenas: dict[str, tuple[float, float]] = {}
    distinct = DistinctRecordings()
    left: list[tuple[str, Exception]] = []  # said once the others are read (or raised)
    checked = False
    for path in sorted(paths, key=str):
        try:
            loaded = load_recording(path, settings)
        except (RecordingError, OSError) as exc:  # one bad file leaves the others be
            left.append((str(path), exc))
            continue
        distinct.add(loaded.recording_id, path)
        if specs and not checked:  # each model stepped once on this raster before any run
            check_models(loaded, specs)
            checked = True
        if loaded.rec.notice and notices is not None:
            notices(loaded.rec.notice)
        if specs:
            outs = recompute(loaded, specs, progress)
            params[loaded.recording_id] = model_params(loaded, specs)
        else:
            if not loaded.logged:
                raise RecordingError(
                    f"{str(path)!r} has no logged model outputs: pass --model to recompute one"
                )
            outs = loaded.logged
            params[loaded.recording_id] = logged_params(loaded.props)
            if progress is not None:
                progress(loaded.frames.height)
        arenas[loaded.recording_id] = loaded.arena_half_extent()
        mo = model_outputs_table(loaded, outs)
        frames.append(loaded.frames)
        outputs.append(mo)
        events.append(events_table(loaded))
        summary.append(summary_table(loaded, mo, settings))
    if not frames:  # nothing to tabulate: the first file's own reason
        raise left[0][1] if left else RecordingError("no recordings given")
    for path, exc in left:
        if notices is not None:
            notices(f"left out {path!r}: {str(exc).splitlines()[0]}")
    tables = {
        "frames": pl.concat(frames).sort("recording_id", "frame"),
        "model_outputs": pl.concat(outputs, how="diagonal_relaxed").sort(
            "recording_id", "model", "frame"
        ),
        "events": pl.concat(events).sort("recording_id", "frame", "kind"),
        "summary": pl.concat(summary, how="diagonal_relaxed").sort(
            "recording_id", "model", "wall_tf_hz"
        ),
    }
    meta = {
        "arena_half_extent_m": arenas,
        "params": params,
        "settings": dataclasses.asdict(settings.summary_settings()),
        "recordings": sorted(params),
    }
    return tables, meta


def write_tables(
    tables: dict[str, pl.DataFrame], out_dir: Path, meta: dict[str, Any]
) -> list[Path]:
    """Write each table to ``out_dir/<name>.parquet`` with ``meta`` in its metadata, as one set
    (``vdc.parquet_io.table_set``): a reader never sees new tables beside old ones."""
    with table_set(out_dir) as stage:
        for name, df in tables.items():
            write_parquet(df, stage / f"{name}.parquet", meta)
    return [out_dir / f"{name}.parquet" for name in tables]


@dataclasses.dataclass
class TablesResult(WroteFiles):
    """The four tables (polars DataFrames), their metadata, and the files written (if any)."""

    tables: dict[str, pl.DataFrame]
    meta: dict[str, Any]
    paths: list[Path]
    notices: list[str]

    def report(self) -> list[str]:
        """What the command line prints: each table's rows and file, then the summary."""
        lines = [
            f"{name:<14} {df.height:>8} rows -> {path}"
            for path, (name, df) in zip(self.paths, self.tables.items(), strict=True)
        ]
        lines.append("summary (primary output after warm-up):")
        for r in self.summary.iter_rows(named=True):
            tf = "no walls" if r["wall_tf_hz"] is None else f"TF {r['wall_tf_hz']:g} Hz"
            lines.append(
                f"  {r['recording_id']}  {r['model']:<16} {tf}: mean {r['mean']:.1f}, p95 "
                f"{r['p95']:.1f}, > 100: {100 * r['frac_over_100']:.1f} %, near wall / centre "
                f"{r['near_wall_centre_ratio']:.2f}"
            )
        return lines

    @property
    def frames(self) -> pl.DataFrame:
        return self.tables["frames"]

    @property
    def model_outputs(self) -> pl.DataFrame:
        return self.tables["model_outputs"]

    @property
    def events(self) -> pl.DataFrame:
        return self.tables["events"]

    @property
    def summary(self) -> pl.DataFrame:
        return self.tables["summary"]


def tables(
    recordings: Sequence[str | Path],
    settings: TablesSettings = TablesSettings(),
    out: str | Path | None = None,
    *,
    progress: Callable[[int], None] | None = None,
    notice: Callable[[str], None] | None = None,
) -> TablesResult:
    """``vdc-analyse tables``: the frames, model_outputs, events and summary tables of
    ``recordings``; written to ``out/<name>.parquet`` unless ``out`` is None.

    ``progress`` is called with the number of frames done; ``notice`` with each note about a
    repaired recording (they are also in the result)."""
    from vdc.folders import expand_recordings

    notes = Notices(notice)
    recordings = expand_recordings(recordings, notes)
    built, meta = build_tables(recordings, settings.models or None, settings, progress, notes)
    paths = write_tables(built, Path(out), meta) if out is not None else []
    return TablesResult(built, meta, paths, list(notes))

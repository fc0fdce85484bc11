"""Recordings → polars tables → Parquet, and model recomputation (the table contract is in
docs/architecture.md).

* ``frames``: one row per frame, as ``analysis.recordings.loading`` reads it from a recording (its columns
  are listed there);
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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.recordings.loading import (
    TURN_HOLD_FRAMES,
    TURN_THRESHOLD_DPS,
    LoadedRecording,
    Notices,
    load_recording,
    logged_params,
)
from analysis.recordings.reader import RecordingError
from avdm.base import Model, primary_output_name
from avdm.errors import PluginError
from avdm.registry import canonical_name, check_detector, make_model, parse_model_spec
from avdm.true_time import TrueTimeModel
from vdc.arena_geometry import distance_to_wall_along
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import TasksFailed
from vdc.folders import expand_recordings, path_list
from vdc.parquet_io import WroteFiles, table_set, write_parquet
from vdc.settings import API_ONLY, AT_LEAST_0, POSITIVE, RANGE, Settings


@dataclasses.dataclass(frozen=True)
class SummarySettings(Settings):
    """How summaries are computed (stored in the Parquet metadata as ``settings``)."""

    threshold_dps: float = option(
        100.0,
        "response threshold, deg/s (default: {default}, the paper's)",
        "--threshold",
        range=POSITIVE,
    )
    near_wall_m: float = option(  # PROPOSED: the paper does not define "near the wall"
        0.15, "'near the wall' = robot centre within this of a wall, m", range=POSITIVE
    )
    centre_m: float = option(
        0.25, "'centre' = farther than this from every wall, m", range=POSITIVE
    )
    # the models' first 2·Tw frames are left out of statistics
    warmup_frames: int = dataclasses.field(default=20, metadata={**API_ONLY, RANGE: AT_LEAST_0})
    # the robot's own turns (analysis/recordings/ego_motion.py): flagged in the frames table, and left
    # out of the summaries with exclude_turns
    turn_threshold_dps: float = option(
        TURN_THRESHOLD_DPS,
        "the robot turns when its own yaw rate exceeds this, deg/s",
        range=POSITIVE,
    )
    turn_hold_frames: int = option(
        TURN_HOLD_FRAMES,
        "frames after a turn still counted as turning: the AVDM remembers a turn for its "
        "10-frame window",
        range=AT_LEAST_0,
    )
    exclude_turns: bool = option(
        False,
        "summarise straight driving only: leave out frames where the robot turns (or turned "
        "within --turn-hold-frames), so its own rotation is not counted as the scene's "
        "complexity",
    )

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
    # a regular cadence's new frames are timed in whole model intervals, as the capture ran
    cadence = loaded.props.get("video", {}).get("model_fps_reason") == "regular cadence"
    runners = [TrueTimeModel(m, cadence) for m in models] if true_time else models
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
            try:
                if isinstance(m, TrueTimeModel):
                    outs[m.name].append(m.run(chunk.images, t_c, rep))
                else:
                    outs[m.name].append(m.run(chunk.images))
            except PluginError as exc:  # the user's model: the line names the frame
                raise exc.at(chunk.frame).on(str(loaded.rec.path)) from None
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
        raise UserError("no model output columns.")
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


def summary_statistics(values: np.ndarray, gap: np.ndarray, s: SummarySettings) -> dict[str, float]:
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
        raise UserError(f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}.")
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
                **summary_statistics(vals[finite], g["wall_gap_m"].to_numpy()[finite], s),
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
    paths: str | Path | Sequence[str | Path],
    specs: Sequence[str] | None,
    settings: SummarySettings = SummarySettings(),
    progress: Callable[[int], None] | None = None,
    notices: Callable[[str], None] | None = None,
    plugin_failures: list[PluginError] | None = None,
) -> tuple[dict[str, pl.DataFrame], dict[str, Any]]:
    """All four tables for ``paths``; ``specs`` None = the online model's logged outputs.

    Returns the tables and the metadata to store with them. A model plug-in that raises on a
    recording raises, or, given a ``plugin_failures`` list, goes into it and leaves that
    recording out (the others are tabulated)."""
    frames, outputs, events, summary = [], [], [], []
    params: dict[str, dict[str, dict[str, Any]]] = {}
    arenas: dict[str, tuple[float, float]] = {}
    distinct = DistinctRecordings()
    left: list[tuple[str, Exception]] = []  # said once the others are read (or raised)
    checked = False
    for path in sorted(path_list(paths)):  # a single path given as a str: a list of one
        try:
            loaded = load_recording(path, settings)
        except (RecordingError, OSError) as exc:  # one bad file leaves the others be
            left.append((str(path), exc))
            continue
        distinct.add(loaded.recording_id, path)
        if specs and not checked:  # each model stepped once on this raster before any run
            try:
                check_models(loaded, specs)
            except PluginError as exc:
                raise exc.on(str(path)) from None
            checked = True
        if loaded.rec.notice and notices is not None:
            notices(loaded.rec.notice)
        if specs:
            try:
                outs = recompute(loaded, specs, progress)
            except PluginError as exc:
                if plugin_failures is None:
                    raise
                plugin_failures.append(exc)
                continue
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
        if plugin_failures:
            raise plugin_failures[0]
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


def publish_tables(
    tables: dict[str, pl.DataFrame], out_dir: Path, meta: dict[str, Any]
) -> list[Path]:
    """Write each table to ``out_dir/<name>.parquet`` with ``meta`` in its metadata, as one set
    (``vdc.parquet_io.table_set``): a crash never leaves new tables beside old ones."""
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

    # each table by its name: ``result.frames`` is ``result.tables["frames"]``
    frames = property(lambda self: self.tables["frames"])
    model_outputs = property(lambda self: self.tables["model_outputs"])
    events = property(lambda self: self.tables["events"])
    summary = property(lambda self: self.tables["summary"])


def tables(
    recordings: str | Path | Sequence[str | Path],
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

    notes = Notices(notice)
    recordings = expand_recordings(recordings, notes)
    failed: list[PluginError] = []
    built, meta = build_tables(
        recordings, settings.models or None, settings, progress, notes, failed
    )
    paths = publish_tables(built, Path(out), meta) if out is not None else []
    if failed:  # the others' tables are kept (written when out is given); the run failed
        more = f" (and {len(failed) - 1} more recording(s))" if len(failed) > 1 else ""
        kept = f"; the tables of the other {len(meta['recordings'])} recording(s) were "
        kept += f"written to {out}" if out is not None else "built"
        raise TasksFailed(f"{failed[0]}{more}{kept}")
    return TablesResult(built, meta, paths, list(notes))

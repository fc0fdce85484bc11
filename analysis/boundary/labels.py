"""A footage boundary's labels table (``vdc-analyse boundary --labels``): one row per clip,
``clip`` (relative to the table's folder), ``label``, ``collision_frame`` (empty where nothing
collides), optionally ``hazard_onset_frame`` and ``scene`` (what clips share: the unit of the
predictors' intervals). Read and checked here, before any clip runs; every fault is one line."""

from __future__ import annotations

import math
from pathlib import Path

import polars as pl

from analysis.boundary.footage_predictors import scene_column
from vdc.errors import UserError
from vdc.sources import open_reader

LABEL_COLUMNS = ("clip", "label", "collision_frame")


def read_labels(path: str | Path) -> pl.DataFrame:
    """The labels table with ``clip`` resolved against its folder (``source`` column).

    UserError, in one line, for a table that cannot be read, missing columns, a bad collision
    or onset frame (negative, fractional, or beyond its clip's frames), or clips that are not
    there."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"labels table {str(path)!r} not found.")
    try:
        df = (
            pl.read_parquet(path)
            if path.suffix.lower() == ".parquet"
            else pl.read_csv(path, infer_schema_length=None)
        )
    except Exception as exc:  # polars' many parse errors: one line for the user
        raise UserError(f"labels table {str(path)!r} cannot be read: {exc}") from None
    missing = [c for c in LABEL_COLUMNS if c not in df.columns]
    if missing:
        raise UserError(
            f"labels table {str(path)!r} has no column {', '.join(missing)} (it needs "
            f"{', '.join(LABEL_COLUMNS)}; collision_frame empty where nothing collides)."
        )
    if df.height == 0:
        raise UserError(f"labels table {str(path)!r} lists no clips.")
    df = df.with_columns(
        pl.col("clip").cast(pl.Utf8),
        pl.col("label").cast(pl.Utf8),
        _frame_numbers(df, "collision_frame", path),
    )
    if "hazard_onset_frame" in df.columns:  # optional: where the hazard enters the scene
        df = df.with_columns(_frame_numbers(df, "hazard_onset_frame", path))
    df = scene_column(df, f"labels table {str(path)!r}")  # optional: what clips share
    if df["clip"].n_unique() != df.height:
        dup = df.filter(pl.col("clip").is_duplicated())["clip"][0]
        raise UserError(f"labels table {str(path)!r} lists clip {dup!r} twice.")
    sources = [
        str((path.parent / c).resolve()) if not Path(c).is_absolute() else c for c in df["clip"]
    ]
    unknown = [c for c, s in zip(df["clip"], sources, strict=True) if not Path(s).exists()]
    if unknown:
        more = f" (and {len(unknown) - 3} more)" if len(unknown) > 3 else ""
        raise UserError(
            f"labels table {str(path)!r} names clips that are not there: "
            f"{', '.join(unknown[:3])}{more} (clips are relative to the table's folder)."
        )
    df = df.with_columns(pl.Series("source", sources))
    _check_frames_inside_clips(df, path)
    return df


# the largest frame number a labels table may give: every integer up to it is exact as a
# float64 (CSV cells are read as numbers), and no clip comes near it
MAX_FRAME_NUMBER = 2**53


def _frame_numbers(df: pl.DataFrame, col: str, path: Path) -> pl.Series:
    """Column ``col`` of a labels table as Int64 frame numbers (null: empty). UserError, in one
    line naming the table, the row (1-based, after the header) and the field, for a value that
    is not a whole number from 0 to :data:`MAX_FRAME_NUMBER` (text, a fraction, negative, or
    a number of 23 digits, which no integer column holds)."""
    try:
        values = df[col].cast(pl.Float64)
    except pl.exceptions.PolarsError:
        values = df[col].cast(pl.Utf8).cast(pl.Float64, strict=False)
    given = df[col].cast(pl.Utf8, strict=False)
    for i, (v, text) in enumerate(zip(values, given, strict=True)):
        if text is None or text.strip() == "":
            continue
        if v is None or not (math.isfinite(v) and v % 1 == 0 and 0 <= v <= MAX_FRAME_NUMBER):
            raise UserError(
                f"labels table {str(path)!r}, row {i + 1}: {col} must be a frame number >= 0 "
                f"or empty, got {text.strip()!r}."
            )
    return values.cast(pl.Int64).alias(col)


def clip_length(source: str) -> int | None:
    """The frames a clip holds: as its source states them (``vdc.sources``: a container's
    count, or its duration at a constant rate; an image sequence's numbers), else counted by
    reading it (an MPEG-TS states neither). None where it cannot be opened: its run says why."""
    try:
        reader = open_reader(source)
    except UserError:
        return None
    try:
        n = reader.info.get("container_frames")
        if n is None:
            n = reader.lost_before_first + sum(1 + f.lost_before for f in reader.frames())
        return int(n)
    finally:
        reader.close()


def _check_frames_inside_clips(labels: pl.DataFrame, path: Path) -> None:
    """UserError, in one line, for a ``collision_frame`` or ``hazard_onset_frame`` at or past
    its clip's last frame: a collision no frame shows would turn a hit into a false alarm (an
    alert long before it) with no note, and a scene that never ends."""
    cols = [c for c in ("collision_frame", "hazard_onset_frame") if c in labels.columns]
    for i, row in enumerate(labels.iter_rows(named=True)):
        given = {c: row[c] for c in cols if row[c] is not None}
        if not given:
            continue
        n = clip_length(row["source"])
        if n is None:
            continue
        for col, frame in given.items():
            if frame >= n:
                raise UserError(
                    f"labels table {str(path)!r}, row {i + 1}: clip {row['clip']!r} has "
                    f"{col} {frame}, beyond its {n} frames (0 to {n - 1})."
                )

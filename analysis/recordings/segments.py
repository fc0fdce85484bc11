"""Profile segments, the data of a profile: its settings, one segment per recording and
condition (positions, times and the response), the histogram over the threshold, the mean
response per arena cell and a segment's summary. ``analysis.profile`` draws and writes them,
``analysis.recordings.analysis_rrd`` logs them; both import them from here.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import polars as pl

from analysis.recordings.recompute import SummarySettings, TablesSettings, summary_statistics
from analysis.stats import Estimate, mean_ci
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.settings import API_ONLY, AT_LEAST_1, POSITIVE, RANGE, between


@dataclasses.dataclass(frozen=True)
class ProfileSettings(TablesSettings):
    """``vdc-analyse profile``: the tables' settings plus how profiles are drawn."""

    by: str = option(
        "recording",
        "one profile per recording segment, or pooled per scene/TF/model",
        choices=("recording", "condition"),
    )
    bin_dps: float = option(20.0, "histogram bin width above the threshold, deg/s", range=POSITIVE)
    cell_m: float = option(0.05, "heat-map cell size, m", range=between(0.005, 0.5))
    # circles drawn in a PNG 3D profile (all go to the .rrd)
    max_points: int = dataclasses.field(default=4000, metadata={**API_ONLY, RANGE: AT_LEAST_1})

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.by not in ("recording", "condition"):
            raise UserError(f"--by must be recording or condition, got {self.by!r}.")


@dataclasses.dataclass
class ProfileSegment:
    """Responses of one model over one recording segment or pooled condition."""

    key: str  # a file- and entity-safe name
    label: str  # for titles
    model: str
    scene: str | None
    wall_tf_hz: float
    recording_ids: list[str]
    t_s: np.ndarray  # (N,) seconds since the segment's recording started
    x_m: np.ndarray
    y_m: np.ndarray
    gap_m: np.ndarray  # distance to the nearest wall
    response: np.ndarray  # (N,) the primary output, deg/s for the AVDM
    output: str
    half_extent: tuple[float, float]
    # (N,) which of ``recording_ids`` each frame came from (the units a pooled condition's
    # intervals resample: its seeds); None = every frame from the one recording
    recording_index: np.ndarray | None = None

    def per_recording(self, values: np.ndarray) -> list[np.ndarray]:
        """``values`` (N,) split by recording, in ``recording_ids`` order."""
        if self.recording_index is None:
            return [values]
        return [values[self.recording_index == k] for k in range(len(self.recording_ids))]


def safe_key(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.\-]+", "_", text).strip("_")


def segments_from_tables(
    frames: pl.DataFrame,
    outputs: pl.DataFrame,
    summary: pl.DataFrame,
    half_extents: dict[str, tuple[float, float]],
    by: str,
    warmup_frames: int,
    exclude_turns: bool = False,
) -> list[ProfileSegment]:
    """Split the long tables into segments (``by="recording"``) or conditions; with
    ``exclude_turns`` only frames known to be straight driving (``turning`` false) are kept."""
    # a video has no wall TF (null): NaN keys join with each other, nulls do not
    no_tf = pl.col("wall_tf_hz").fill_null(float("nan"))
    cond = (
        summary.select("recording_id", "model", "wall_tf_hz", "scene", "output")
        .unique()
        .with_columns(no_tf)
    )
    joined = (
        outputs.join(frames, on=["recording_id", "frame"], how="inner", suffix="_f")
        .filter(pl.col("frame") >= warmup_frames)
        .with_columns(no_tf)
    )
    if exclude_turns:
        joined = joined.filter(pl.col("turning").not_())
    straight = ", straight driving" if exclude_turns else ""
    joined = joined.join(cond, on=["recording_id", "model", "wall_tf_hz"], how="left")
    keys = (
        ["model", "scene", "wall_tf_hz"]
        if by == "condition"
        else ["recording_id", "model", "wall_tf_hz"]
    )
    segs = []
    for _, g in joined.sort("recording_id", "frame").group_by(keys, maintain_order=True):
        out = g["output"][0]
        rec_ids = g["recording_id"].unique(maintain_order=True).to_list()
        model, scene, tf = g["model"][0], g["scene"][0], float(g["wall_tf_hz"][0])
        walls = f"TF {tf:g} Hz" if math.isfinite(tf) else "no walls"
        tf_key = f"tf{tf:g}" if math.isfinite(tf) else "video"
        if by == "condition":
            label = f"{scene or 'video'} {walls}, {model}{straight} ({len(rec_ids)} recording(s))"
            key = safe_key(f"{scene or 'video'}_{tf_key}_{model}")
        else:
            label = f"{rec_ids[0]}: {walls}, {model}{straight}"
            key = safe_key(f"{rec_ids[0]}_{tf_key}_{model}")
        segs.append(
            ProfileSegment(
                key=key,
                label=label,
                model=model,
                scene=scene,
                wall_tf_hz=tf,
                recording_ids=rec_ids,
                t_s=g["t_s"].to_numpy(),
                x_m=g["x_m"].to_numpy(),
                y_m=g["y_m"].to_numpy(),
                gap_m=g["wall_gap_m"].to_numpy(),
                response=g[out].to_numpy().astype(float),
                output=out,
                half_extent=half_extents[rec_ids[0]],
                recording_index=np.searchsorted(np.asarray(rec_ids), g["recording_id"].to_numpy()),
            )
        )
    return segs


def histogram_over(values: np.ndarray, s: ProfileSettings) -> tuple[np.ndarray, np.ndarray]:
    """Counts of responses above the threshold in ``bin_dps`` bins: (edges (B+1,), counts (B,))."""
    over = values[values > s.threshold_dps]
    top = max(float(over.max()) if len(over) else s.threshold_dps, s.threshold_dps + s.bin_dps)
    n_bins = max(1, min(200, math.ceil((top - s.threshold_dps) / s.bin_dps)))
    edges = s.threshold_dps + s.bin_dps * np.arange(n_bins + 1)
    counts, _ = np.histogram(over, bins=edges)
    return edges, counts


def heat_map(seg: ProfileSegment, s: ProfileSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean response per arena cell: (x edges, y edges, mean (ny, nx), NaN where unvisited)."""
    hx, hy = seg.half_extent
    xe = np.linspace(-hx, hx, max(1, round(2 * hx / s.cell_m)) + 1)
    ye = np.linspace(-hy, hy, max(1, round(2 * hy / s.cell_m)) + 1)
    total, _, _ = np.histogram2d(seg.y_m, seg.x_m, bins=(ye, xe), weights=seg.response)
    count, _, _ = np.histogram2d(seg.y_m, seg.x_m, bins=(ye, xe))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    return xe, ye, mean


def segment_summary(seg: ProfileSegment, s: ProfileSettings, t: SummarySettings) -> dict:
    stats = summary_statistics(
        seg.response, seg.gap_m, dataclasses.replace(t, threshold_dps=s.threshold_dps)
    )
    share = over_share_by_recording(seg, s.threshold_dps)
    return {
        "segment": seg.key,
        "model": seg.model,
        "scene": seg.scene,
        "wall_tf_hz": seg.wall_tf_hz,
        "recordings": len(seg.recording_ids),
        "motion": t.motion,
        "output": seg.output,
        "n_frames": len(seg.response),
        "threshold_dps": s.threshold_dps,
        **stats,
        # the share over the threshold as an estimate over recordings (seeds): their mean and
        # a 95 % t-interval over them (NaN with one recording: frames are not independent)
        "frac_over_threshold_by_recording": share.mean,
        "frac_over_threshold_ci_low": share.low,
        "frac_over_threshold_ci_high": share.high,
    }


def over_share_by_recording(seg: ProfileSegment, threshold_dps: float) -> Estimate:
    """The share of frames over ``threshold_dps``: the mean over the segment's recordings of
    each one's share, with a 95 % t-interval over recordings (``n`` = recordings; no interval
    below 2, as a run's frames are not independent samples)."""
    shares = [float((r > threshold_dps).mean()) for r in seg.per_recording(seg.response) if len(r)]
    return mean_ci(shares, bounds=(0.0, 1.0))

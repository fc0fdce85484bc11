"""Analysis recordings (application id ``vdc``): profiles and variant comparisons as ``.rrd``.

This module knows the analysis recordings' entity paths and blueprints (the capture
recordings' contract lives in ``vdc.recording``):

* ``/profile/<segment>/circles``: Points3D (x_m, y_m, time up), radius ∝ response;
* ``/profile/<segment>/arena``: LineStrips3D, the arena outline at the start time;
* ``/profile/<segment>/histogram``: BarChart of responses over the threshold;
* ``/profile/<segment>/heatmap``: Image (RGB), mean response per arena cell, north up;
* ``/model_variants/<name>/<output>``: Scalars on ``frame`` and ``time``, in a recording
  with the *same* recording id as the source, so ``rerun REC OUT.rrd`` shows them together.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import polars as pl
import rerun as rr
import rerun.blueprint as rrb

from analysis.recordings.segments import ProfileSegment, ProfileSettings, heat_map, histogram_over
from avdm.base import primary_output_name
from vdc.recording import (
    APP_ID,
    CAMERA,
    FRAME_TIMELINE,
    MODEL_ROOT,
    TIME_TIMELINE,
    entity_name,
    variant_path,
)

PROFILE_ROOT = "/profile"
TIME_SCALE_M = 1.0  # the profile's time axis spans this height in the 3D view


def log_arena_outline(rec: rr.RecordingStream, entity: str, hx: float, hy: float) -> None:
    """The arena's rectangle at floor level (static), for the analysis recordings' 3D views."""
    corners = [[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0], [-hx, -hy, 0]]
    rec.log(entity, rr.LineStrips3D([corners], colors=[(150, 150, 150)]), static=True)


def _colours(values: np.ndarray, vmax: float, cmap: str = "viridis") -> np.ndarray:
    norm = np.clip(values / vmax, 0, 1) if vmax > 0 else np.zeros_like(values)
    return (matplotlib.colormaps[cmap](norm)[:, :3] * 255).astype(np.uint8)


def view_3d(name: str, base: str, *children: str) -> rrb.Spatial3DView:
    """A 3D view named ``name`` of the entities ``children`` under ``base``."""
    return rrb.Spatial3DView(name=name, origin=base, contents=[f"{base}/{c}" for c in children])


def open_tabbed_rrd(path: Path, recording_id: str, tabs: list[Any]) -> rr.RecordingStream:
    """An analysis recording of ``recording_id`` written to ``path``, z up, whose blueprint
    shows ``tabs`` (blueprint containers, one a tab). Flush and disconnect it when done."""
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(path), default_blueprint=rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=True))
    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


def write_profile_rrd(
    segs: Sequence[ProfileSegment], s: ProfileSettings, path: Path, recording_id: str
) -> Path:
    """One analysis recording holding every segment's profile, with a tabbed blueprint."""
    tabs = []
    for seg in segs:
        base = f"{PROFILE_ROOT}/{seg.key}"
        tabs.append(
            rrb.Horizontal(
                view_3d(f"{seg.key}: x, y against time (up)", base, "circles", "arena"),
                rrb.Vertical(
                    rrb.BarChartView(
                        name=f"responses > {s.threshold_dps:g}", origin=f"{base}/histogram"
                    ),
                    rrb.Spatial2DView(name="mean response per cell", origin=f"{base}/heatmap"),
                ),
                column_shares=[1.4, 1],
                name=seg.label[:60],
            )
        )
    rec = open_tabbed_rrd(path, recording_id, tabs)
    for seg in segs:
        base = f"{PROFILE_ROOT}/{seg.key}"
        span = float(seg.t_s.max() - seg.t_s.min()) if len(seg.t_s) else 1.0
        z = (seg.t_s - seg.t_s.min()) / max(span, 1e-9) * TIME_SCALE_M
        ref = max(
            float(np.percentile(seg.response, 99)) if len(seg.response) else 1.0,
            s.threshold_dps,
            1e-9,
        )
        radii = (0.002 + 0.02 * np.clip(seg.response / ref, 0, 1)).astype(np.float32)
        rec.log(
            f"{base}/circles",
            rr.Points3D(
                np.column_stack([seg.x_m, seg.y_m, z]),
                radii=radii,
                colors=_colours(seg.response, ref),
            ),
            static=True,
        )
        hx, hy = seg.half_extent
        edges, counts = histogram_over(seg.response, s)
        rec.log(
            f"{base}/histogram",
            rr.BarChart(counts.astype(np.float64), abscissa=edges[:-1].astype(np.float64)),
            static=True,
        )
        if not (np.isfinite(seg.x_m).any() and math.isfinite(hx) and math.isfinite(hy)):
            continue  # a video: no poses and no arena, so no outline and no map of cells
        log_arena_outline(rec, f"{base}/arena", hx, hy)
        _, _, mean = heat_map(seg, s)
        vmax = float(np.nanmax(mean)) if np.isfinite(mean).any() else 1.0
        rgb = _colours(np.nan_to_num(mean, nan=0.0).ravel(), vmax, "magma").reshape(*mean.shape, 3)
        rgb[~np.isfinite(mean)] = 40
        rec.log(f"{base}/heatmap", rr.Image(np.ascontiguousarray(rgb[::-1])), static=True)
    rec.flush()
    rec.disconnect()
    return path


def write_variants_rrd(
    recording_id: str,
    outputs: Mapping[str, pl.DataFrame],
    units: Mapping[str, Mapping[str, str]],
    path: Path,
    original_model: str | None,
) -> Path:
    """Variant traces under ``/model_variants/<name>/<output>`` with the source's recording id.

    The blueprint overlays every variant's primary output (and the online model's, from the
    source recording) so that ``rerun SOURCE.rrd OUT.rrd`` compares them on one time axis."""
    names = list(outputs)
    first = outputs[names[0]]
    out_names = [c for c in first.columns if c not in ("frame", "t_s")]
    main = primary_output_name(out_names)
    main_contents = [variant_path(n, main) for n in names]
    if original_model:
        main_contents.append(f"{MODEL_ROOT}/{entity_name(original_model)}/{main}")
    others = [o for o in out_names if o != main]
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(name="robot camera", origin=CAMERA),
            rrb.Vertical(
                rrb.TimeSeriesView(name=f"{main}: variants", origin="/", contents=main_contents),
                *[
                    rrb.TimeSeriesView(
                        name=o, origin="/", contents=[variant_path(n, o) for n in names]
                    )
                    for o in others[:3]
                ],
            ),
            column_shares=[1, 2],
        ),
        rrb.TimePanel(timeline=FRAME_TIMELINE),
    )
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(path))
    # active, not just default: opened after the source recording, this layout must win
    rec.send_blueprint(blueprint, make_active=True, make_default=True)
    # which model each /model_variants/<part> is (the catalog names its variants from this)
    rec.send_property("model_variants", rr.AnyValues(**{entity_name(n): n for n in names}))
    batch = 20_000  # bounded send_columns batches (rerun.md §8)
    for name, df in outputs.items():
        frame = df["frame"].to_numpy()
        t_ns = np.rint(df["t_s"].to_numpy() * 1e9).astype("timedelta64[ns]")
        for o in [c for c in df.columns if c not in ("frame", "t_s")]:
            unit = units.get(name, {}).get(o, "")
            rec.log(
                variant_path(name, o), rr.SeriesLines(names=[f"{name} {o} [{unit}]"]), static=True
            )
            values = df[o].to_numpy().astype(np.float64)
            for a in range(0, len(values), batch):
                idx = [
                    rr.TimeColumn(FRAME_TIMELINE, sequence=frame[a : a + batch]),
                    rr.TimeColumn(TIME_TIMELINE, duration=t_ns[a : a + batch]),
                ]
                rec.send_columns(
                    variant_path(name, o),
                    indexes=idx,
                    columns=rr.Scalars.columns(scalars=values[a : a + batch]),
                )
    rec.flush()
    rec.disconnect()
    return path

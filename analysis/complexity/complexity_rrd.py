"""``vdc-analyse complexity``'s analysis recording: each metric of a source over time, in its
own unit (``vdc.recording.COMPLEXITY_UNITS``), under ``/complexity/<metric>``, with the
source's recording id, so it merges with the source in the viewer (whose video blueprint gives
each unit its pane). The command that writes it owns it (the other analysis recordings are
``analysis.recordings.analysis_rrd``'s, which imports nothing of the commands)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import rerun as rr

from analysis.complexity.source_metrics import metrics_present
from vdc.recording import APP_ID, COMPLEXITY_ROOT, COMPLEXITY_UNITS, FRAME_TIMELINE, TIME_TIMELINE

OUTPUT_MARKER = "vdc_output"  # the property that marks a recording vdc derived from another


def write_complexity_rrd(df: pl.DataFrame, recording_id: str, path: Path) -> Path:
    """Each metric as measured, named with its unit (``omega_dps (deg/s)``), under
    ``/complexity/<metric>`` with the source's recording id, on its ``frame`` and ``time``
    timelines (so it merges with the source in the viewer)."""

    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(path))
    # an output, not a source: a folder scan that meets it skips it (plan_sources)
    rec.send_property(OUTPUT_MARKER, rr.AnyValues(command="complexity", of=recording_id))

    idx = [
        rr.TimeColumn(FRAME_TIMELINE, sequence=df["frame"].to_numpy()),
        rr.TimeColumn(
            TIME_TIMELINE,
            duration=np.rint(df["t_s"].to_numpy() * 1e9).astype("timedelta64[ns]"),
        ),
    ]
    for m in metrics_present(df):
        entity = f"{COMPLEXITY_ROOT}/{m}"
        unit = COMPLEXITY_UNITS.get(m)
        rec.log(entity, rr.SeriesLines(names=[f"{m} ({unit})" if unit else m]), static=True)
        values = df[m].cast(pl.Float64).fill_null(np.nan).to_numpy()
        rec.send_columns(entity, indexes=idx, columns=rr.Scalars.columns(scalars=values))
    rec.flush()
    rec.disconnect()
    return path

"""Every complexity measure of an arena grid's conditions, for
:mod:`analysis.predictors.statistics`.

Each profiling run of ``vdc-analyse boundary`` (ring turns, no detector: the scene alone) is
measured on the camera's raster (99 × 72 px, 8-bit full range) over its straight-driving frames
after the warm-up, as ``profile_dps`` is:

* ``avdm``: the paper's AVDM, the on-board model the run logged (``profile_dps``'s own frames);
* ``avdm_natural``: ``avdm-natural`` run on every frame (over true time);
* on every :data:`EVERY`-th frame and the one before it (a pair of consecutive frames, so the
  temporal measures keep their definitions): P.910 and legacy SI/TI, MAFD, edge density and
  JPEG bits per pixel (``vdc.frame_metrics``), DIS optic flow (mean |horizontal|, deg/s, the
  ``complexity`` command's preset) and the zlib ratio (level 6);
* ``codec_bpp``: the bits per pixel of the whole run encoded as H.264 (libx264, ``ultrafast``,
  CRF 23, every frame), the packets' mean.

``vdc-analyse boundary`` measures each profiling run in the worker that has just recorded it
(``boundary_campaign.record_and_measure``: no second pool to start and warm up);
:func:`arena_measures` measures a finished grid's runs afterwards, with the same function.
The numbers are cached beside the recording (``seedN.measures.json``, with its recording id
and :data:`MEASURE_VERSION`): a grid recorded before the predictors existed gains them without
recording anything, and a re-run measures nothing again.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import polars as pl

from analysis.boundary.settings import BoundarySettings
from analysis.boundary.statistics import WARMUP_FRAMES
from analysis.complexity.meter import DIS_PRESETS
from analysis.experiments.captures import profiling_items
from analysis.predictors.arena import arena_predictors
from analysis.predictors.report import PredictorResult, settings_meta, write_predictors
from analysis.predictors.statistics import MEASURES
from analysis.predictors.verdicts import table_note
from analysis.recordings.loading import load_recording
from avdm.registry import make_model
from avdm.true_time import TrueTimeModel
from vdc.errors import UserError
from vdc.executors import Feedback, run_tasks_or_raise
from vdc.frame_metrics import NativeMeter
from vdc.parquet_io import table_set
from vdc.recording import NATIVE_METRICS

MEASURE_VERSION = 2  # 1 lost codec_bpp (NaN)
# the SI/TI family, flow and zlib on every 8th frame pair (their cost; see module): the default
# of boundary's --measure-every, named once there
EVERY: int = BoundarySettings.measure_every
CODEC_CRF = 23


# full-range grey -> limited-range luma (16-235), exactly what FFmpeg's gray -> yuv420p
# conversion computes (checked against it pixel for pixel in
# tests/analysis/predictors/test_predictors.py)
_LIMITED_LUMA = np.rint(16 + np.arange(256) * 219 / 255).astype(np.uint8)


def yuv420_planes(frames: np.ndarray) -> np.ndarray:
    """Frames (T, H, W) uint8 full-range grey as FFmpeg's ``yuv420p`` layout, (T, 3 H' / 2, W')
    uint8 with H', W' the sizes padded to even (edge rows/columns repeated): the limited-range
    luma plane then the neutral (128) chroma planes. The same bytes as
    ``VideoFrame.from_ndarray(grey, format="gray").reformat(format="yuv420p")``, without a
    per-frame conversion (which cost most of the predictors' time on the arena's small frames)."""
    t, h, w = frames.shape
    luma = _LIMITED_LUMA[np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2)), mode="edge")]
    hh, ww = luma.shape[1:]
    chroma = np.full((t, hh // 2, ww), 128, np.uint8)  # U then V, each (H'/2, W'/2), row-packed
    return np.ascontiguousarray(np.concatenate([luma, chroma], axis=1))


def _codec_sizes(frames: np.ndarray, fps: float, state: dict[str, Any]) -> None:
    """Encode ``frames`` (T, H, W) uint8 into the H.264 stream kept in ``state`` and add the
    packets' bytes to ``state["bytes"]``."""
    import av  # lazy: start-up

    h, w = frames.shape[1:]
    if "stream" not in state:
        state["buf"] = io.BytesIO()
        state["out"] = av.open(state["buf"], "w", format="h264")
        st = state["out"].add_stream("libx264", rate=round(fps))
        st.width, st.height = w + w % 2, h + h % 2  # 4:2:0 wants even sizes
        st.pix_fmt = "yuv420p"
        # one encoder thread: the same bytes (ultrafast has no lookahead; checked on a whole
        # grid run), twice as fast on frames this small, and the executor's workers fill the cores
        st.options = {"preset": "ultrafast", "crf": str(CODEC_CRF), "threads": "1"}
        state |= {"stream": st, "bytes": 0, "frames": 0, "pixels": st.width * st.height}
    st = state["stream"]
    for planes in yuv420_planes(frames):
        for p in st.encode(av.VideoFrame.from_ndarray(planes, format="yuv420p")):
            state["bytes"] += p.size
        state["frames"] += 1


def measure_run(path: str | Path, every: int = EVERY, warmup: int | None = None) -> dict[str, Any]:
    """Every measure of one profiling run (see the module): their means over the straight-
    driving frames after the warm-up, with ``frames`` (straight frames after the warm-up) and
    ``sampled_frames`` (of those, measured by the sampled measures)."""

    warmup = WARMUP_FRAMES if warmup is None else warmup
    loaded = load_recording(path)
    ctx = loaded.camera_context()
    if not ctx:
        raise UserError(f"{str(path)!r} does not record its camera.")
    fps, deg_per_px = float(ctx["fps"]), float(ctx["deg_per_px"])
    timing = loaded.frames.select("frame", "t_s", "repeat", "turning")
    natural = TrueTimeModel(make_model("avdm-natural", **ctx))
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS["medium"])
    meter = NativeMeter(8, "full")
    codec: dict[str, Any] = {}
    parts = []
    prev: np.ndarray | None = None
    for chunk in loaded.rec.iter_frames():
        sel = pl.DataFrame({"frame": chunk.frame.astype(np.int64)}).join(
            timing, on="frame", how="left", maintain_order="left"
        )
        t = sel["t_s"].fill_null(strategy="forward").to_numpy()
        rep = sel["repeat"].fill_null(False).to_numpy()
        imgs = chunk.images
        cols: dict[str, Any] = {"frame": chunk.frame.astype(np.int64)}
        cols["avdm_natural"] = natural.run(imgs, t, rep)["omega_dps"]
        _codec_sizes(imgs, fps, codec)
        sampled = {
            m: np.full(len(imgs), np.nan) for m in (*NATIVE_METRICS, "flow_dps", "zlib_ratio")
        }
        # only the frames the means are over (straight driving after the warm-up): the others'
        # numbers were computed and dropped (a fifth of the run's flow, the dearest measure)
        used = (chunk.frame >= warmup) & ~sel["turning"].fill_null(True).to_numpy()
        for i in np.flatnonzero((chunk.frame % every == 0) & used):
            before = imgs[i - 1] if i > 0 else prev
            if before is None:
                continue
            meter._prev = before  # the pair's first frame: the temporal measures need it
            row = meter.row(imgs[i])
            for k, name in enumerate(NATIVE_METRICS):
                sampled[name][i] = row[k]
            flow = dis.calc(before, imgs[i], None)
            sampled["flow_dps"][i] = float(np.abs(flow[..., 0]).mean()) * deg_per_px * fps
            raw = imgs[i].tobytes()
            sampled["zlib_ratio"][i] = len(zlib.compress(raw, 6)) / len(raw)
        prev = imgs[-1]
        parts.append(pl.DataFrame(cols | sampled))
    for p in codec["stream"].encode():
        codec["bytes"] += p.size
    codec["out"].close()  # (a closed stream reads width 0: the size was kept before)
    size = float(codec["frames"]) * codec["pixels"]
    df = pl.concat(parts).join(timing, on="frame", how="left")
    profiler = loaded.online_model or "avdm"
    if profiler in loaded.logged:
        paper = loaded.logged[profiler].select("frame", pl.col("omega_dps").alias("avdm"))
        df = df.join(paper, on="frame", how="left")
    straight = df.filter((pl.col("frame") >= warmup) & pl.col("turning").not_())

    row: dict[str, Any] = {
        "recording_id": loaded.recording_id,
        "measure_version": MEASURE_VERSION,
        "every": every,
        "frames": straight.height,
        "sampled_frames": int(straight["si_p910"].is_not_nan().sum()),
        "profiler": profiler,
        "codec_bpp": 8.0 * codec["bytes"] / size if size else math.nan,
    }
    for m in MEASURES:
        if m in straight.columns and m not in row:  # codec_bpp: the whole run's, above
            v = straight[m].cast(pl.Float64).fill_nan(None).mean()
            row[m] = float(v) if v is not None else math.nan
    return row


def read_cached_measures(path: str | Path, every: int = EVERY) -> dict[str, Any] | None:
    """The cached :func:`measure_run` row of a recording (``"reused": True``), or None when
    there is none measured from this recording with this version and stride."""
    path = Path(path)
    cache = path.with_suffix(".measures.json")
    if not (cache.exists() and path.exists()):
        return None
    st = path.stat()
    stamp = [st.st_size, st.st_mtime_ns]  # the recording measured (a re-recorded run differs)
    row = json.loads(cache.read_text())
    same = row.get("measure_version") == MEASURE_VERSION and row.get("every") == every
    return row | {"reused": True} if same and row.get("rrd_stamp") == stamp else None


def cached_measures(path: str | Path, every: int = EVERY) -> dict[str, Any]:
    """An executor task: :func:`measure_run` of a recording, read from its cache
    (``seedN.measures.json``) when that was measured from this recording with this version and
    stride, else measured and cached."""
    path = Path(path)
    cache = path.with_suffix(".measures.json")
    row = read_cached_measures(path, every)
    if row is not None:
        return row
    st = path.stat()
    row = measure_run(path, every) | {"rrd_stamp": [st.st_size, st.st_mtime_ns]}
    tmp = cache.with_suffix(".partial")
    tmp.write_text(json.dumps(row))
    tmp.replace(cache)
    return row | {"reused": False}


def arena_measures(
    items: Sequence[tuple[Path, dict[str, Any]]],
    executor: Any,
    log: Callable[[str], None],
    every: int = EVERY,
) -> pl.DataFrame:
    """:func:`cached_measures` of every profiling run ``(path, columns)`` on ``executor`` (an
    ``ExecutorSettings``): one row per run, ``columns`` (condition, scene, tf_hz, seed) first."""

    tasks = [(str(p), (str(p), every)) for p, _ in items]
    got = run_tasks_or_raise(
        cached_measures, tasks, executor.executor_settings(), "measurement", Feedback(log)
    )
    return measures_table([(str(p), cols) for p, cols in items], got)


def measures_table(
    items: Sequence[tuple[str, dict[str, Any]]], got: dict[str, dict[str, Any]]
) -> pl.DataFrame:
    """The measures table of the profiling runs ``(key, columns)`` from their
    :func:`cached_measures` rows ``got`` (by key): one row per run, ``columns`` (condition,
    scene, tf_hz, seed) first. The same table whether the runs were measured by the workers
    that recorded them (``vdc-analyse boundary``) or afterwards (:func:`arena_measures`)."""
    rows = [{**cols, **got[key]} for key, cols in items if key in got]
    return pl.DataFrame(rows).sort("condition", "seed")


def predictors_for_folder(
    folder: str | Path,
    log: Callable[[str], None] | None = None,
    executor: Any = None,
) -> Any:
    """The predictors of a finished arena boundary (``vdc-analyse boundary --out folder``):
    measures its profiling runs (cached beside them), computes the tables and writes
    ``predictors.parquet``, ``predictor_measures.parquet``, ``predictors.png`` and the
    section of ``boundary.md`` into ``folder``. Returns
    :class:`analysis.predictors.report.PredictorResult`."""

    folder = Path(folder)
    meta = settings_meta(folder)
    if meta.get("labels"):
        raise UserError(
            f"{str(folder)!r} is a footage boundary: its predictors are written by the run."
        )
    fields = {f.name for f in dataclasses.fields(BoundarySettings)}
    s = BoundarySettings(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in meta.items() if k in fields}
    )
    if executor is not None:
        s = dataclasses.replace(s, **executor)
    runs = pl.read_parquet(folder / "boundary_runs.parquet")
    items = [(it.path, it.columns) for it in profiling_items(s, folder / "recordings")]
    missing = [str(p) for p, _ in items if not p.exists()]
    if missing:
        raise UserError(
            f"{len(missing)} profiling run(s) are missing (e.g. {missing[0]}): the predictors "
            "need the grid's profiling runs (--complexity profile)."
        )
    measures = arena_measures(items, s, log or (lambda _m: None), s.measure_every)
    md_path = folder / "boundary.md"
    md = md_path.read_text(encoding="utf-8") if md_path.exists() else ""
    cut = md.find("## Which measure predicts")
    md = md[:cut] if cut >= 0 else md
    with table_set(folder) as stage:
        table, paths, section = arena_predictor_tables(s, runs, measures, stage)
        note = table_note(table)
        if note and log is not None:
            log(note)
        (stage / "boundary.md").write_text(md + "\n" + section, encoding="utf-8")
    paths = [folder / p.name for p in paths]
    return PredictorResult(table, measures, paths, section)


def arena_predictor_tables(
    s: Any, runs: pl.DataFrame, measures: pl.DataFrame, stage: Path
) -> tuple[pl.DataFrame, list[Path], str]:
    """The predictor table of a grid written into ``stage``: (table, paths, report section)."""

    table = arena_predictors(runs, measures, s.param, s.target)
    meta = {"settings": dataclasses.asdict(s), "every": int(measures["every"][0])}
    paths, section = write_predictors(
        table,
        measures,
        stage,
        meta,
        s.param,
        "arena",
        f"{s.detector}: which measure predicts failure (arena, {measures.height} profiling runs)",
    )
    note = (
        f"Measures: each condition's profiling runs on the camera's raster, straight driving; "
        f"the SI/TI family, MAFD, edge density, JPEG, flow and zlib on every "
        f"{int(measures['every'][0])}th frame pair (`predictor_measures.parquet`).\n\n"
    )
    return table, paths, section.replace("\n\n", "\n\n" + note, 1)


def predictors(source: str | Path | Any) -> Any:
    """The predictor tables of a boundary's output: its folder (``vdc-analyse boundary
    --out``) or the :class:`analysis.boundary.command.BoundaryResult` it returned. Reads
    ``predictors.parquet`` and the measures table it was computed from; if the folder has
    none yet (a grid measured by an older vdc, or ``--no-predictors``), computes them from the
    recordings there (arena; the measurements are cached beside the runs)."""
    if hasattr(source, "paths"):
        folder = Path(next(iter(source.paths)).parent)
    else:
        folder = Path(source)
    if not folder.is_dir():
        raise UserError(f"{str(folder)!r} is not a boundary output folder.")
    pred = folder / "predictors.parquet"
    if not pred.exists():
        return predictors_for_folder(folder)
    measures = next(
        (
            folder / n
            for n in ("predictor_measures.parquet", "predictor_frames.parquet")
            if (folder / n).exists()
        ),
        None,
    )
    md_path = folder / "boundary.md"
    md = md_path.read_text() if md_path.exists() else ""
    cut = md.find("## Which measure predicts")
    paths = [pred] + ([measures] if measures else []) + [folder / "predictors.png"]

    return PredictorResult(
        pl.read_parquet(pred),
        pl.read_parquet(measures) if measures else pl.DataFrame(),
        [p for p in paths if p.exists()],
        md[cut:] if cut >= 0 else "",
    )

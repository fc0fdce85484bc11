"""Many recordings as one Rerun dataset (``vdc-analyse catalog``): what is registered. With
:mod:`analysis.catalog.server` (a server onto the folders, the web viewer) and
:mod:`analysis.catalog.query` (queries, by folder or by a running catalog's URL), the only
modules that know Rerun's catalog API (``rr.server``, ``rr.catalog``), pinned with the SDK to
0.41.

* Every recording found under the folders is a **segment** of one dataset (its recording id is
  the segment id), in the layer ``base``.
* A small **summary layer** per segment (``summary``) adds the properties researchers filter
  on as segment-table columns (``property:Summary:*``): source, scene, wall TF schedule, seed,
  model, duration, frames, complete or repaired, and the headline numbers (mean ω̂, the share
  over the threshold, a collision run's success rate). It is computed once per recording and
  kept in the cache (``$VDC_CACHE_DIR/catalog``), keyed by the file's size and time.
* The outputs of ``compare`` (``variants.rrd``), ``complexity`` (``complexity_<id>.rrd``) and
  ``batch`` (its parts, written as ``.rrd`` layers into the cache) are **layers** of their
  source's segment, each under its own entity paths. Two layers that log the same entity path
  would merge silently (the newest row wins), so a second one is left out and listed.
* A recording without a footer (a capture cut short) would be loaded whole into the server's
  memory: it is rewritten first (``rerun rrd route --continue-on-error``, into the cache) and
  marked ``repaired`` (with a note). A file of another application, whose ``frame`` timeline
  is of another kind, or that cannot be served (each is checked before it is registered), is
  listed as unregistered with a one-line reason naming the user's file; of two files with one
  recording id the complete one is registered, whatever the names.

Nothing persists in the server: the folders are the truth, and a restart registers them again.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import re
import subprocess
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from vdc.recording import RERUN_LOG

# a server that dies or cannot read a recording mid-query is said in one line (query.py); the
# client's own log lines about it would come first. Set before the SDK starts its logger
# (at import); a RUST_LOG the user set wins.
os.environ.setdefault("RUST_LOG", RERUN_LOG)
import rerun as rr

from analysis.recordings.analysis_rrd import write_variants_rrd
from analysis.recordings.loading import load_recording
from analysis.recordings.reader import Recording, RecordingError, complete_prefix
from analysis.recordings.recompute import SummarySettings, events_table, primary_output
from avdm.calibration_store import cache_dir
from avdm.registry import make_model
from vdc.blueprints import dataset_blueprint, default_blueprint, video_blueprint
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.folders import path_list
from vdc.recording import (
    APP_ID,
    FRAME_TIMELINE,
    PARTIAL_SUFFIX,
    capture_writing,
)
from vdc.settings import Settings

# the summary layer's property section: capitalised, so that the viewer's segment table (which
# orders sections by name, RecordingInfo first) shows it before the recordings' own sections
BASE, SUMMARY_LAYER, SUMMARY = "base", "summary", "Summary"
LOOPBACK = "127.0.0.1"
CATALOG_EXTRA = "pip install 'visual-dynamic-complexity[catalog]'"
MAX_PORT = 65535  # a TCP port is 16 bits; 0 asks the system for a free one


def port_number(text: str) -> int:
    """argparse type: a TCP port, 1 to 65535, or 0 (a free one)."""
    try:
        v = int(text)
    except ValueError:
        v = -1
    if not 0 <= v <= MAX_PORT:
        raise argparse.ArgumentTypeError(
            f"expected a port from 1 to {MAX_PORT} (0: a free one), got {text!r}"
        )
    return v


@dataclasses.dataclass(frozen=True)
class CatalogSettings(Settings):
    """``vdc-analyse catalog serve``: the dataset's name and where the server listens."""

    dataset: str | None = option(
        None,
        "the dataset's name (default: the first folder's name; querying a catalog URL: which of "
        "its datasets, needed when it serves several)",
    )
    host: str = option(
        LOOPBACK,
        "the address the server and the web viewer listen on (default: {default}, this "
        "machine only)",
    )
    port: int = option(0, "the catalog server's port (0: a free one)", type=port_number)
    web: bool = option(False, "also serve the web viewer, on the same host")
    web_port: int = option(0, "the web viewer's port (0: a free one)", type=port_number)
    where: tuple[str, ...] = option(
        (),
        "query: only segments whose summary property KEY equals VALUE (repeatable)",
        metavar="KEY=VALUE",
    )
    layers: tuple[str, ...] = option(
        (),
        "query: the layers whose variants to include (repeatable; default: all)",
        flag="--layer",
        metavar="LAYER",
    )

    def __post_init__(self) -> None:
        for name in ("port", "web_port"):
            value = getattr(self, name)
            if not 0 <= value <= MAX_PORT:
                raise UserError(
                    f"CatalogSettings.{name}: a port is 1 to {MAX_PORT} (0: a free one), "
                    f"got {value}."
                )

    def where_dict(self) -> dict[str, str]:
        """``--where`` as ``{key: value}``; a malformed item raises UserError."""
        out = {}
        for item in self.where:
            key, sep, value = item.partition("=")
            if not sep or not key:
                raise UserError(f"--where {item!r}: expected KEY=VALUE, e.g. seed=1.")
            out[key.strip()] = value.strip()
        return out


@dataclasses.dataclass
class CatalogSegment:
    """One recording registered in the catalog (a segment of its dataset)."""

    recording_id: str
    path: Path  # the file registered (a repaired copy for a recording without footer)
    source: Path  # the file found
    summary: dict[str, Any]  # the summary layer's properties


@dataclasses.dataclass
class Found:
    """What a scan of the folders found: segments, layers ``{name: [(recording id, file)]}``
    and files left out ``[(file, one-line reason)]``."""

    segments: list[CatalogSegment]
    layers: dict[str, list[tuple[str, Path]]]
    unregistered: list[tuple[str, str]]
    entities: dict[str, set[str]] = dataclasses.field(default_factory=dict)  # per layer


def _cache(folder: Path) -> Path:
    key = hashlib.sha1(str(folder.resolve()).encode()).hexdigest()[:12]
    return cache_dir() / "catalog" / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', folder.name)}-{key}"


def _stamp(path: Path) -> str:
    st = path.stat()
    return hashlib.sha1(
        repr((str(path.resolve()), st.st_size, st.st_mtime_ns)).encode()
    ).hexdigest()[:12]


def _rerun_binary() -> str:
    """The ``rerun`` executable itself (the console script is a Python shim whose child
    survives a signal to the shim)."""
    import rerun_cli  # lazy: optional extra

    return str(Path(rerun_cli.__file__).parent / "rerun")


def repair(path: Path, out: Path) -> Path:
    """A copy of a recording without footer (a capture cut short), with one: its complete
    messages (``analysis.recordings.reader.complete_prefix``), rewritten by ``rerun rrd optimize``,
    which writes the footer. ValueError if it fails."""

    out.parent.mkdir(parents=True, exist_ok=True)
    good, count = complete_prefix(path)
    if count == 0:
        raise UserError("could not be repaired: no complete message.")
    prefix = out.with_name(out.name + f".prefix-{os.getpid()}")
    tmp = out.with_name(out.name + f".tmp-{os.getpid()}")
    try:
        with path.open("rb") as src, prefix.open("wb") as dst:
            dst.write(src.read(good))
        proc = subprocess.run(
            [_rerun_binary(), "rrd", "optimize", str(prefix), "-o", str(tmp)],
            capture_output=True,
            text=True,
            timeout=600,
        )
        if proc.returncode != 0 or not tmp.exists():
            why = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            raise UserError(f"could not be repaired: {why[0]}")
        tmp.replace(out)
    finally:
        prefix.unlink(missing_ok=True)
        tmp.unlink(missing_ok=True)
    return out


def headline(path: Path, repaired: bool = False) -> dict[str, Any]:
    """The summary layer's properties of one recording: what it is, and the numbers of the
    ``summary`` table (mean ω̂ and the share over 100 deg/s after the warm-up; success rate
    of a collision run)."""

    loaded = load_recording(path)
    props = loaded.props
    run, wall, end = props.get("run", {}), props.get("wall", {}), props.get("run_end", {})
    video = props.get("video", {})
    s = SummarySettings()
    out: dict[str, Any] = {
        "source": run.get("source") or ("video" if video else "unknown"),
        "behaviour": run.get("behaviour"),
        # a dataset episode is no scene of vdc's (its episode section says what it is)
        "scene": wall.get("scene")
        or ("video" if video and run.get("source") != "dataset" else None),
        "tf_schedule": wall.get("tf_schedule_text"),
        "seed": run.get("seed"),
        "model": loaded.online_model,
        # collision runs only: a profiling run records the (unused) detector's defaults too
        **(
            {k: props.get("collision", {}).get(k) for k in ("detector", "phase")}
            if run.get("behaviour") == "collision"
            else {}
        ),
        "video": video.get("path"),
        "frames": int(loaded.frames.height),
        "duration_s": float(loaded.frames["t_s"].max() or 0.0),
        "complete": bool(end.get("complete", False)),
        "repaired": repaired or loaded.rec.notice is not None,
    }
    episode = props.get("episode", {})  # a dataset episode (vdc-analyse dataset)
    for key in ("episode_index", "flags", "flag_count"):
        if key in episode:
            out[key] = episode[key]
    online = loaded.online_model
    if online and online in loaded.logged:
        df = loaded.logged[online]
        main = primary_output(df)
        v = df[main].cast(pl.Float64).to_numpy()[s.warmup_frames :]
        v = v[np.isfinite(v)]
        out["mean_" + main] = float(v.mean()) if len(v) else None
        out["frac_over_100"] = float((v > 100.0).mean()) if len(v) else None
    ev = events_table(loaded)
    if out["behaviour"] == "collision":
        a = int((ev["kind"] == "avoidance").sum())
        c = int((ev["kind"] == "crash").sum())
        out |= {"avoidances": a, "crashes": c, "success_rate": a / (a + c) if a + c else None}
    return {k: v for k, v in out.items() if v is not None}


def _write_summary_layer(recording_id: str, props: dict[str, Any], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}")
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(tmp))
    rec.send_property(SUMMARY, rr.AnyValues(**props))
    rec.flush()
    rec.disconnect()
    tmp.replace(path)


def _read_summary(path: Path) -> dict[str, Any] | None:
    try:
        return Recording(path).properties().get(SUMMARY)
    except Exception:  # an older or damaged cache file: computed again
        return None


def _frame_kind(rec: Any) -> str | None:
    """The arrow type of the ``frame`` timeline in a recording's first chunk that has one."""
    for _entity, rb in rec._batches("/**"):
        if FRAME_TIMELINE in rb.schema.names:
            return str(rb.schema.field(FRAME_TIMELINE).type)
    return None


def _batch_layers(
    folder: Path, cache: Path, segments: set[str], left: list[tuple[str, str]]
) -> Iterator[tuple[str, str, Path]]:
    """``batch`` outputs as layers: each (recording, variant) part written once as an ``.rrd``
    of its outputs under ``/model_variants/<variant>/...`` → (layer, recording id, file); a
    part that cannot be read is added to ``left``."""

    for part in sorted(folder.glob("parts/recording_id=*/model=*/model_outputs.parquet")):
        try:
            df = pl.read_parquet(part)
        except Exception as exc:  # a damaged part leaves the others be
            left.append((str(part), _without_path(exc, part)))
            continue
        if df.height == 0:
            continue
        rid, model = df["recording_id"][0], df["model"][0]
        if rid not in segments:
            continue
        slug = part.parent.name.removeprefix("model=")
        dest = cache / "batch" / _stamp(part) / f"{slug}.rrd"
        if not dest.exists():
            outs = df.drop("recording_id", "model").sort("frame")
            dest.parent.mkdir(parents=True, exist_ok=True)
            write_variants_rrd(rid, {model: outs}, {}, dest, None)
        yield f"batch-{slug}", rid, dest


def _without_path(exc: Exception, *paths: Path) -> str:
    """An error about one file as a note's reason: without the file's name in front (the note
    names it), and naming the user's file where it named a repaired copy."""
    msg = str(exc) if isinstance(exc, ValueError | OSError) else f"{type(exc).__name__}: {exc}"
    msg = msg.splitlines()[0] if msg else type(exc).__name__
    for path in paths:
        if msg.startswith(f"{str(path)!r} "):
            msg = msg[len(f"{str(path)!r} ") :]
    return msg.replace(str(paths[0]), str(paths[-1])) if len(paths) > 1 else msg


def _preference(item: tuple[Path, Any, dict[str, Any]]) -> tuple[bool, bool, int]:
    """Between files of one recording id, the complete one first: with a footer, then a run
    that ended, then the larger file."""
    path, rec, props = item
    finished = bool(props.get("run_end", {}).get("complete", False))
    return (rec.notice is not None, not finished, -path.stat().st_size)


def _register(path: Path, rec: Any, cache: Path, say: Callable[[str], None]) -> CatalogSegment:
    """One recording checked and made ready to register: repaired into the cache if it has no
    footer (with a note), its summary computed (or read from the cache). ValueError (or the
    reader's error) if it cannot be served."""
    rid = rec.recording_id
    registered = path
    if rec.notice is not None:  # no footer: the server would load it whole
        registered = repair(path, cache / "repaired" / f"{_stamp(path)}.rrd")
    dest = cache / SUMMARY_LAYER / f"{_stamp(path)}.rrd"
    summary = _read_summary(dest) if dest.exists() else None
    if summary is None:
        summary = headline(registered, repaired=registered != path)
        _write_summary_layer(rid, summary, dest)
    if registered != path:
        say(
            f"{path} has no footer (the capture was cut short): registered a repaired copy of "
            "its complete messages (marked repaired)."
        )
    return CatalogSegment(rid, registered, path, summary)


def scan(
    folders: str | Path | Sequence[str | Path], notice: Callable[[str], None] | None = None
) -> Found:
    """Find the recordings and the analysis outputs under ``folders`` (see the module). A file
    that cannot be served is left out with a one-line reason, never taking the others down;
    between files of one recording id the complete one is registered, whatever their names."""

    say = notice or (lambda _m: None)
    segments: dict[str, CatalogSegment] = {}
    runs: dict[str, list[tuple[Path, Any, dict[str, Any]]]] = {}  # recording id → files
    layers: dict[str, list[tuple[str, Path]]] = {}
    left: list[tuple[str, str]] = []
    outputs: list[tuple[str, Path]] = []
    folders = path_list(folders)  # one folder given as a str is a list of one, not of letters
    batch_folders: list[Path] = []
    cache = _cache(Path(folders[0]))
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise UserError(f"{str(folder)!r} is not a folder.")
        for path in sorted(folder.rglob("*.rrd")):
            if cache in path.parents:
                continue
            if path.is_symlink() and not path.exists():  # as vdc.folders.scan_folder says it
                left.append((str(path), "a dangling link (its target is gone)"))
                continue
            if path.name.endswith(PARTIAL_SUFFIX) and capture_writing(path) is not None:
                left.append((str(path), "still being written by a capture"))
                continue
            try:
                rec = Recording(path)
                if rec.application_id != APP_ID:
                    left.append(
                        (str(path), f"a recording of another application ({rec.application_id})")
                    )
                    continue
                props = rec.properties()
                kind = _frame_kind(rec)
                if kind is not None and kind != "int64":
                    left.append((str(path), f"its frame timeline is {kind}, not a frame count"))
                    continue
            except (RecordingError, OSError) as exc:
                left.append((str(path), _without_path(exc, path)))
                continue
            if "run" in props:
                runs.setdefault(rec.recording_id, []).append((path, rec, props))
            elif path.name == "variants.rrd":
                outputs.append((f"compare-{path.parent.name}", path))
            elif path.name.startswith("complexity_"):
                outputs.append((f"complexity-{path.parent.name}", path))
            else:  # never left out silently: a run cut before it described itself, most often
                why = "holds no description of its run (no 'run' properties)"
                if rec.notice is not None:
                    why += " (it has no footer: the capture was cut short)"
                left.append((str(path), why))
        if (folder / "parts").is_dir():
            batch_folders.append(folder)
        batch_folders += [
            p.parent for p in folder.rglob("parts") if p.is_dir() and p.parent != folder
        ]
    # each recording id: its most complete file that can be served (summary layers from the
    # cache where the file has not changed)
    for rid, files in runs.items():
        for path, rec, _props in sorted(files, key=_preference):
            if rid in segments:
                first = segments[rid].source
                left.append((str(path), f"the same recording as {str(first)!r} (id {rid})"))
                continue
            repaired = cache / "repaired" / f"{_stamp(path)}.rrd"
            try:
                segments[rid] = _register(path, rec, cache, say)
            except Exception as exc:  # one file that cannot be served leaves the others be
                reason = _without_path(exc, repaired, path)
                if rec.notice is not None:
                    reason += " (it has no footer: the capture was cut short)"
                left.append((str(path), reason))
    for seg in segments.values():
        dest = cache / SUMMARY_LAYER / f"{_stamp(seg.source)}.rrd"
        layers.setdefault(SUMMARY_LAYER, []).append((seg.recording_id, dest))
    for name, path in outputs:
        try:
            rid = Recording(path).recording_id
        except (RecordingError, OSError) as exc:
            left.append((str(path), _without_path(exc, path)))
            continue
        if rid not in segments:
            left.append((str(path), f"its recording ({rid}) is not in these folders"))
            continue
        layers.setdefault(name, []).append((rid, path))
    for folder in dict.fromkeys(batch_folders):
        for name, rid, path in _batch_layers(folder, cache, set(segments), left):
            layers.setdefault(name, []).append((rid, path))
    entities = _drop_colliding(layers, left)
    for path, why in left:
        say(f"not registered: {path}: {why}")
    return Found(list(segments.values()), layers, left, entities)


def _entities(path: Path) -> set[str]:
    return set(Recording(path).signals())


def _drop_colliding(
    layers: dict[str, list[tuple[str, Path]]], left: list[tuple[str, str]]
) -> dict[str, set[str]]:
    """Keep, per segment, only layers whose entity paths no earlier layer logs (two layers
    that log one path are merged by the server, the newest row winning); returns each
    layer's entity paths."""
    seen: dict[str, dict[str, str]] = {}  # segment → entity → layer
    by_layer: dict[str, set[str]] = {}
    for name in sorted(layers):
        if name == SUMMARY_LAYER:
            continue
        kept = []
        for rid, path in layers[name]:
            try:
                ents = _entities(path)
            except ValueError as exc:  # a damaged layer leaves the others be
                left.append((str(path), _without_path(exc, path)))
                continue
            mine = seen.setdefault(rid, {})
            clash = sorted(e for e in ents if e in mine)
            if clash:
                left.append((str(path), f"logs {clash[0]} like layer {mine[clash[0]]}"))
                continue
            mine.update(dict.fromkeys(ents, name))
            by_layer.setdefault(name, set()).update(ents)
            kept.append((rid, path))
        layers[name] = kept
    return by_layer


def _blueprint_file(found: Found) -> Path:
    """vdc's blueprint for the dataset's segments (the first segment's model: a video's for
    video recordings, the arena's otherwise), as an ``.rbl`` in the cache."""

    first = found.segments[0]
    if first.summary.get("source") == "dataset":  # episodes: their own cameras' layout
        cams = str(Recording(first.path).properties().get("episode", {}).get("cameras", ""))
        path = _cache(first.source.parent) / "dataset.rbl"
        path.parent.mkdir(parents=True, exist_ok=True)
        dataset_blueprint([c for c in cams.split(",") if c] or ["camera"]).save(APP_ID, str(path))
        return path
    model = make_model(first.summary.get("model") or "avdm")
    video = first.summary.get("source") == "video"
    bp = (video_blueprint if video else default_blueprint)(model.name, model.outputs)
    path = _cache(first.source.parent) / f"{'video' if video else 'arena'}-{model.name}.rbl"
    path.parent.mkdir(parents=True, exist_ok=True)
    bp.save(APP_ID, str(path))
    return path


def is_catalog_url(text: str | Path) -> bool:
    """``text`` names a running catalog (``rerun+http://host:port``), not a folder."""
    return str(text).startswith(("rerun+http://", "rerun+https://"))

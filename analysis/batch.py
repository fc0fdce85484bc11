"""Many recordings × many model variants: one task per (recording, variant), on any executor.

Each task opens its recording itself, recomputes one variant from the raw frames and writes its
own Parquet parts, atomically (temporary file, then rename), in a hive layout::

    OUT/parts/recording_id=<id>/frames.parquet, events.parquet        (shared by its tasks)
    OUT/parts/recording_id=<id>/model=<slug>/model_outputs.parquet
    OUT/parts/recording_id=<id>/model=<slug>/summary.parquet           (written last: "done")

The ids are columns inside every file too, and a variant's slug never contains ``=`` (a spec
such as ``avdm:beta=0.5`` would break the hive partition). A re-run skips finished parts
(resume after a crash or a killed worker); ``force`` recomputes them. ``shard = (i, n)`` runs
only every n-th task from the i-th (SLURM job arrays, workstations sharing a filesystem).
:func:`summarise_batch` concatenates the parts into the same ``frames``, ``model_outputs``,
``events`` and ``summary`` tables that ``vdc-analyse tables`` writes for the same inputs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from analysis.recordings.loading import load_recording
from analysis.recordings.reader import Recording, RecordingError
from analysis.recordings.recompute import (
    DistinctRecordings,
    SummarySettings,
    check_models,
    events_table,
    model_outputs_table,
    model_params,
    publish_tables,
    recompute,
    summary_table,
)
from analysis.recordings.segments import safe_key
from avdm.registry import canonical_name, parse_model_spec
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import ExecutorSettings, TaskOutcome, executor_field, run_tasks
from vdc.folders import expand_recordings, remove_output
from vdc.parquet_io import WroteFiles, read_metadata, table_set, write_parquet
from vdc.scratch import no_files_without_out

PARTS = "parts"


def model_slug(spec: str) -> str:
    """A directory-safe name for a variant: its canonical name with ``:``, ``=`` and ``,``
    replaced, plus a short hash when anything was replaced (so two specs never share one)."""
    name = canonical_name(spec)
    slug = safe_key(name.replace("=", "-"))
    if slug == name:
        return slug
    return f"{slug}-{hashlib.sha1(name.encode()).hexdigest()[:6]}"


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"I/N"`` (0 ≤ I < N) → (I, N); None → the SLURM array's own, if this is one."""
    if text is None:
        i, n = os.environ.get("SLURM_ARRAY_TASK_ID"), os.environ.get("SLURM_ARRAY_TASK_COUNT")
        if i is None or n is None:
            return None
        text = f"{int(i) - int(os.environ.get('SLURM_ARRAY_TASK_MIN', '0'))}/{n}"
    try:
        i_s, n_s = text.split("/")
        i, n = int(i_s), int(n_s)
    except ValueError:
        raise UserError(f"--shard {text!r}: expected I/N, e.g. 0/4.") from None
    if not (n >= 1 and 0 <= i < n):
        raise UserError(f"--shard {text!r}: need 0 <= I < N.")
    return i, n


@dataclasses.dataclass(frozen=True)
class BatchSettings(SummarySettings):
    """``vdc-analyse batch``: the summary settings, the variants, where tasks run, and which."""

    models: tuple[str, ...] = option(
        ("avdm",), "recompute this variant (repeatable)", flag="--model", metavar="MODEL"
    )
    executor: str = executor_field("executor")
    jobs: int = executor_field("jobs")
    scheduler: str | None = executor_field("scheduler")
    shard: str | None = option(
        None,
        "I/N: run only tasks I, I+N, ... (0-based; default in a SLURM array: its own); then "
        "`vdc-analyse summarise OUT`",
    )
    force: bool = option(False, "recompute finished parts")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "models", tuple(self.models or ()))
        if not self.models:
            raise UserError("give at least one --model.")
        for spec in self.models:
            parse_model_spec(spec)
        self.executor_settings()
        parse_shard(self.shard)

    def executor_settings(self) -> ExecutorSettings:
        return ExecutorSettings(self.executor, self.jobs, self.scheduler)


def part_dir(out: Path, recording_id: str, spec: str | None = None) -> Path:
    d = Path(out) / PARTS / f"recording_id={safe_key(recording_id)}"
    return d if spec is None else d / f"model={model_slug(spec)}"


def readable_part(path: Path) -> bool:
    """A part file that exists and whose Parquet footer reads (parts are written atomically,
    so a damaged one was damaged afterwards: a disk error, a copy cut short)."""
    try:
        pq.read_metadata(path)
    except (OSError, pa.ArrowException):
        return False
    return True


def part_is_done(out: Path, recording_id: str, spec: str) -> bool:
    """A task is done when its parts, and the recording's shared ones, all read."""
    d, shared = part_dir(out, recording_id, spec), part_dir(out, recording_id)
    return all(
        readable_part(p)
        for p in (
            d / "summary.parquet",
            d / "model_outputs.parquet",
            shared / "frames.parquet",
            shared / "events.parquet",
        )
    )


def analyse_task(path: str, spec: str, out: str, settings: dict[str, Any], force: bool) -> dict:
    """One task: recompute ``spec`` on the recording at ``path`` and write its parts under
    ``out``. Returns a small dict (the recording id, frames, seconds, skipped)."""
    t0 = time.perf_counter()
    s = SummarySettings(**settings)
    loaded = load_recording(path, s)
    rid = loaded.recording_id
    name = canonical_name(spec)
    if not force and part_is_done(Path(out), rid, spec):  # second line of defence after the plan
        return {"recording_id": rid, "model": name, "skipped": True}
    meta = {
        "arena_half_extent_m": {rid: loaded.arena_half_extent()},
        "params": {rid: model_params(loaded, [spec])},
        "settings": dataclasses.asdict(s),
        "recordings": [rid],
        "source": str(path),
    }
    shared = part_dir(Path(out), rid)
    for table, df in (("frames", loaded.frames), ("events", events_table(loaded))):
        if force or not readable_part(shared / f"{table}.parquet"):
            write_parquet(df, shared / f"{table}.parquet", meta)
    outputs = recompute(loaded, [spec])
    mo = model_outputs_table(loaded, outputs)
    d = part_dir(Path(out), rid, spec)
    write_parquet(mo, d / "model_outputs.parquet", meta)
    write_parquet(summary_table(loaded, mo, s), d / "summary.parquet", meta)  # last: done
    return {
        "recording_id": rid,
        "model": name,
        "frames": mo.height,
        "seconds": time.perf_counter() - t0,
        "skipped": False,
    }


@dataclasses.dataclass
class BatchResult(WroteFiles):
    """What a batch did: tasks run, skipped and failed (with their errors), and the tables."""

    planned: int  # tasks in this shard
    skipped: int  # already finished before the run
    outcomes: list[TaskOutcome]
    failures: list[tuple[str, str]]  # (task, error)
    tables: dict[str, pl.DataFrame] | None  # summarised tables (None when a shard ran)
    paths: list[Path]
    elapsed_s: float


def plan_tasks(
    recordings: Sequence[str | Path], models: Sequence[str]
) -> tuple[list[tuple[str, str, str | None]], list[tuple[str, str]]]:
    """Every (path, spec, recording id) in a fixed order, and recordings that do not open
    (path, error): a corrupt recording fails its own tasks only."""
    tasks, bad = [], []
    distinct = DistinctRecordings()  # two files of one id would share (and mix) their parts
    for path in sorted({str(p) for p in recordings}):
        try:
            rid = Recording(path).recording_id
        except (RecordingError, OSError, ValueError) as exc:
            bad.append((path, str(exc)))
            rid = None
        if rid is not None:
            distinct.add(rid, path)
        tasks += [(path, spec, rid) for spec in models]
    return tasks, bad


@no_files_without_out
def batch(
    recordings: str | Path | Sequence[str | Path],
    settings: BatchSettings,
    out: str | Path | None,
    *,
    progress: Callable[[int], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> BatchResult:
    """``vdc-analyse batch``: run every (recording, variant) task not finished yet on the
    chosen executor, then (unless this is one shard of several) :func:`summarise_batch`."""
    t0 = time.perf_counter()
    out = Path(out)
    say = log or (lambda _m: None)
    recordings = expand_recordings(recordings, say)  # folders walked as complexity walks them
    tasks, bad = plan_tasks(recordings, settings.models)
    shard = parse_shard(settings.shard)
    if shard is not None:
        tasks = tasks[shard[0] :: shard[1]]
    unreadable = dict(bad)
    failures = [(f"{p} {spec}", unreadable[p]) for p, spec, rid in tasks if rid is None]
    runnable = [t for t in tasks if t[2] is not None]
    todo = [t for t in runnable if settings.force or not part_is_done(out, t[2], t[1])]
    skipped = len(runnable) - len(todo)
    for path in dict.fromkeys(p for p, _, _ in todo):  # each model stepped once on the
        try:  # first readable recording's raster, before any task: a misfit fails here
            loaded = load_recording(path)
        except (RecordingError, OSError):
            continue  # its own tasks fail, with their reason
        check_models(loaded, settings.models)
        break
    say(
        f"{len(tasks)} tasks{f' (shard {shard[0]}/{shard[1]})' if shard else ''}: "
        f"{skipped} already done, {len(todo)} to run on {settings.executor_settings().where()}."
    )
    s = dataclasses.asdict(settings.summary_settings())

    def done(outcome: TaskOutcome) -> None:
        if outcome.error is not None:
            say(f"FAILED {outcome.key}: {outcome.error}")
        if progress is not None:
            progress(1)

    out.mkdir(parents=True, exist_ok=True)
    outcomes = run_tasks(
        analyse_task,
        [(f"{p} {spec}", (p, spec, str(out), s, settings.force)) for p, spec, _ in todo],
        settings.executor_settings(),
        done,
        say,
        shared_paths=[todo[0][0], out] if todo else [],
    )
    failures += [(o.key, o.error) for o in outcomes if o.error is not None]
    tables, paths = None, []
    if shard is None and any((out / PARTS).glob("recording_id=*/model=*/summary.parquet")):
        tables, paths = summarise_batch(out)
    if failures:  # published like every set: in the manifest, never over a user's file
        with table_set(out) as stage:
            write_parquet(
                pl.DataFrame(failures, schema=["task", "error"], orient="row"),
                stage / "failures.parquet",
                {},
            )
    else:
        remove_output(out, "failures.parquet")  # only vdc's own, from an earlier run
    return BatchResult(
        len(tasks), skipped, outcomes, failures, tables, paths, time.perf_counter() - t0
    )


def summarise_batch(out: str | Path) -> tuple[dict[str, pl.DataFrame], list[Path]]:
    """``vdc-analyse summarise`` (``vdc.summarise``): concatenate the finished parts under
    ``out/parts`` into ``out/{frames,model_outputs,events,summary}.parquet``, as ``tables``
    writes them."""
    if out is None:  # its input is that folder: None names nothing to summarise
        raise UserError("summarise reads the folder a batch wrote: give it as out.")
    out = Path(out)
    done = sorted((out / PARTS).glob("recording_id=*/model=*/summary.parquet"))
    if not done:
        raise UserError(f"{str(out)!r} has no finished batch parts (run vdc-analyse batch).")
    for p in done:
        for part in (p, p.parent / "model_outputs.parquet", *p.parent.parent.glob("*.parquet")):
            if not readable_part(part):
                raise UserError(
                    f"the batch part {str(part)!r} is damaged or missing: run the same "
                    "vdc-analyse batch again to recompute it."
                )
    recs = sorted({p.parent.parent for p in done})
    meta: dict[str, Any] = {"arena_half_extent_m": {}, "params": {}, "recordings": []}
    for p in done:
        m = read_metadata(p)
        for rid, ext in m["arena_half_extent_m"].items():
            meta["arena_half_extent_m"][rid] = tuple(ext)
        for rid, params in m["params"].items():
            meta["params"].setdefault(rid, {}).update(params)
        meta["settings"] = m["settings"]
    meta["params"] = {rid: dict(sorted(v.items())) for rid, v in meta["params"].items()}
    meta["recordings"] = sorted(meta["params"])
    read = pl.read_parquet
    tables = {
        "frames": pl.concat([read(r / "frames.parquet") for r in recs]).sort(
            "recording_id", "frame"
        ),
        "model_outputs": pl.concat(
            [read(p.parent / "model_outputs.parquet") for p in done], how="diagonal_relaxed"
        ).sort("recording_id", "model", "frame"),
        "events": pl.concat([read(r / "events.parquet") for r in recs]).sort(
            "recording_id", "frame", "kind"
        ),
        "summary": pl.concat([read(p) for p in done], how="diagonal_relaxed").sort(
            "recording_id", "model", "wall_tf_hz"
        ),
    }
    return tables, publish_tables(tables, out, meta)

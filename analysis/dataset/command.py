"""The command ``vdc-analyse dataset``: the function and its result (its settings: ``settings``; the
package's face, ``analysis.dataset``, names them)."""

from __future__ import annotations

import dataclasses
import errno
from pathlib import Path
from typing import Any

import polars as pl

from analysis.complexity.meter import (
    ANGULAR_METRICS,
    parse_metrics,
)
from analysis.dataset.episode_rrd import EPISODE_RECORDINGS, write_episode
from analysis.dataset.flags import finish, first_flags, severity
from analysis.dataset.layout import EpisodeVideo, Problem, open_dataset
from analysis.dataset.page import write_page
from analysis.dataset.resume import (
    DISK_FULL,
    OutputError,
    clear_partials,
    drop_stale,
    errno_of,
    measured,
    output_error,
    read_result,
    result_path,
)
from analysis.dataset.settings import DatasetSettings
from vdc.errors import UserError
from vdc.executors import Feedback, run_tasks
from vdc.parquet_io import WroteFiles, table_set, write_tables


@dataclasses.dataclass(frozen=True)
class DatasetResult(WroteFiles):
    """What ``dataset`` wrote (``paths``: episodes.parquet, frames.parquet, problems.parquet,
    dataset.html, then the episodes' recordings), the episodes table (polars; worst first),
    the problems as lines, the episodes flagged by ``fail_on``, the notes (e.g. no field of
    view) and ``reused``: the camera streams read back from an earlier run's results instead
    of measured (``analysis.dataset.resume``)."""

    paths: list[Path]
    episodes: Any
    problems: list[str]
    failed: list[int]
    notes: list[str]
    reused: int = 0
    dataset_problems: list[str] = dataclasses.field(default_factory=list)

    def report(self) -> list[str]:
        """Lines for people: what was profiled, what was flagged, what was written."""
        eps = self.episodes
        lines: list[str] = []  # the notes were said as the run started
        if eps is not None:
            flagged = eps.filter(pl.col("flag_count") > 0)
            lines.append(
                f"{eps['episode_index'].n_unique()} episode(s), {eps.height} camera stream(s) "
                f"profiled; {flagged.height} flagged"
            )
            for r in flagged.head(10).iter_rows(named=True):
                lines.append(f"  episode {r['episode_index']} {r['camera']}: {r['flags']}")
            if flagged.height > 10:
                lines.append(f"  ... and {flagged.height - 10} more (dataset.html)")
        if self.failed:
            lines.append(f"--fail-on: episode(s) {', '.join(map(str, self.failed))} flagged")
        # the dataset's own problems (its metadata disagreeing): they bear on every episode
        lines += [f"dataset problem: {p}" for p in self.dataset_problems]
        if self.problems:
            lines.append(f"{len(self.problems)} problem(s): exit 2 (problems.parquet)")
        rrds = [p for p in self.paths if p.suffix == ".rrd"]
        tables = [str(p) for p in self.paths if p.suffix != ".rrd"]
        if rrds:  # one folder of recordings, not a name per episode
            tables.append(f"{rrds[0].parent}/ ({len(rrds)} episode recording(s))")
        lines.append("wrote " + ", ".join(tables))
        return lines

    @property
    def exit_status(self) -> int:
        """2 where input was unreadable, else 1 where ``fail_on`` flagged an episode, else 0."""
        return 2 if self.problems else 1 if self.failed else 0


def dataset(
    path: str | Path,
    settings: DatasetSettings | None = None,
    out: str | Path = "results/dataset",
    feedback: Feedback | None = None,
) -> DatasetResult:
    """Profile the LeRobot dataset at ``path`` episode by episode into ``out`` (see the
    module). Needs the ``__main__`` guard in a script (it starts a process pool). A dataset
    that cannot be read at all (no meta/info.json, an unknown codebase_version) raises
    UserError; an unreadable episode is listed in ``problems``."""
    return _run(Path(path), settings or DatasetSettings(), Path(out), feedback or Feedback())


def no_fov_note(settings: DatasetSettings) -> str | None:
    """One note where the angular measures are left out for want of a field of view."""
    left = [m for m in parse_metrics(settings.metrics) if m in ANGULAR_METRICS]
    if settings.fov_deg is not None or not left:
        return None
    return (
        f"no --fov-deg: {', '.join(left)} and the shifts in degrees left out (they need the "
        "cameras' horizontal field of view); the other measures are taken"
    )


def _run(root: Path, settings: DatasetSettings, out: Path, feedback: Feedback) -> DatasetResult:
    ds = open_dataset(root)
    problems: list[Problem] = list(ds.problems)
    for p in problems:  # each unreadable file said as it is met: one line, file and episode
        feedback.log(f"error: {p.line()}")
    wanted = settings.episode_list()
    if wanted is not None:  # a gate that checks nothing must not pass
        absent = [e for e in wanted if e not in set(ds.listed)]
        if absent or not wanted:
            listed = f"{ds.listed[0]}-{ds.listed[-1]}" if ds.listed else "none"
            raise UserError(
                f"--episodes: {', '.join(map(str, absent)) or 'none given'}: not an episode of "
                f"{root} (its episodes: {len(ds.listed)}, indices {listed})"
            )
    videos = [v for v in ds.videos if wanted is None or v.episode in wanted]
    notes = [n for n in [no_fov_note(settings)] if n]
    for n in notes:
        feedback.log(n)
    feedback.log(
        f"{root}: LeRobot {ds.version}, {len(set(v.episode for v in videos))} episode(s), "
        f"{len(ds.cameras)} camera(s), {_rates_said(ds)}"
    )
    if out.exists() and not out.is_dir():  # as vdc.parquet_io.table_set says it
        raise UserError(f"--out {str(out)!r} is a file, not a folder; give a folder")
    out.mkdir(parents=True, exist_ok=True)  # each episode's result is kept there as it ends
    clear_partials(out)
    by_key = {f"{v.episode}:{v.camera}": v for v in videos}
    results: dict[str, dict[str, Any]] = {}
    # what an earlier (killed) run measured is read back here, without a worker
    for key, v in by_key.items():
        kept = read_result(result_path(out, v, settings, ds.rate(v.camera)))
        if kept is not None:
            results[key] = kept
    if results:
        feedback.log(f"{len(results)} camera stream(s) read back from an earlier run's results")
    tasks = [
        (k, (v, settings, ds.rate(v.camera), out)) for k, v in by_key.items() if k not in results
    ]

    feedback.expect(len(tasks))

    def done(outcome: Any) -> None:
        feedback.progress(1)
        if outcome.error is None:
            results[outcome.key] = outcome.result
            return
        if outcome.error.startswith(f"{OutputError.__name__}: "):  # the run's, not the video's
            raise UserError(outcome.error.split(": ", 1)[1])
        problem = _problem_of(by_key[outcome.key], outcome.error)
        if problem not in problems:  # a data file's problem: once, not once per camera
            problems.append(problem)
            feedback.log(f"error: {problem.line()}")

    if tasks:  # the task lives in resume: a worker imports the measuring, not this command
        run_tasks(measured, tasks, settings.executor_settings(), done,
                  feedback.log, shared_paths=(root, out))  # fmt: skip
    drop_stale(out, [result_path(out, v, settings, ds.rate(v.camera)) for v in videos])
    for k in sorted(results, key=_order):  # what the measuring found wrong with the data
        v = by_key[k]
        for msg in results[k].get("problems", ()):
            problem = Problem(v.data_path, v.episode, msg)
            if problem not in problems:  # the data's: once, not once per camera
                problems.append(problem)
                feedback.log(f"error: {problem.line()}")
    rows = [results[k]["row"] for k in sorted(results, key=_order)]
    frames = [
        results[k]["frames"].with_columns(
            pl.lit(results[k]["row"]["episode_index"]).alias("episode_index"),
            pl.lit(results[k]["row"]["camera"]).alias("camera"),
        )
        for k in sorted(results, key=_order)
    ]
    views = {(r["row"]["episode_index"], r["row"]["camera"]): r["views"] for r in results.values()}
    widths = {cam: _width(ds.info, cam) for cam in ds.cameras}
    meta = {"command": "dataset", "dataset": str(root), "version": ds.version,
            "settings": dataclasses.asdict(settings)}  # fmt: skip
    problem_table = pl.DataFrame(
        {"file": [p.file for p in problems], "episode_index": [p.episode for p in problems],
         "message": [p.message for p in problems]},
        schema={"file": pl.String, "episode_index": pl.Int64, "message": pl.String},
    )  # fmt: skip
    eps = None
    if rows:
        eps, frame_table = finish(rows, pl.concat(frames, how="diagonal_relaxed"), views,
                                  widths, settings.fov_deg)  # fmt: skip
        eps = severity(eps)
    try:
        with table_set(out) as stage:
            tables = {"episodes": eps, "frames": frame_table if rows else None,
                      "problems": problem_table}  # fmt: skip
            paths = write_tables(stage, tables, meta)
            if settings.page and eps is not None:
                paths.append(write_page(stage / "dataset.html", ds, eps, frame_table, problems))
            if settings.recordings and eps is not None:
                paths += _recordings(stage, ds, eps, frame_table, feedback)
    except OSError as exc:  # the output's fault (a full disk): the run's error
        if errno_of(exc) not in (*DISK_FULL, errno.EFBIG):
            raise
        raise UserError(output_error(out, exc)) from None
    paths = [out / p.relative_to(stage) for p in paths]
    fail = set(settings.fail_names())
    failed = []
    if eps is not None and fail:
        for r in eps.iter_rows(named=True):
            if fail & set(filter(None, r["flags"].split(","))):
                failed.append(int(r["episode_index"]))
    reused = sum(bool(r.get("reused")) for r in results.values())
    return DatasetResult(
        paths, eps, [p.line() for p in problems], sorted(set(failed)), notes, reused,
        [p.line() for p in problems if p.episode is None],
    )  # fmt: skip


def _rates_said(ds: Any) -> str:
    """The rate(s) the cameras are measured at, said once where they are the same."""
    rates = sorted({ds.rate(c) for c in ds.cameras})
    return ", ".join(f"{r:.4g}" for r in rates) + " fps"


def _recordings(
    stage: Path, ds: Any, eps: pl.DataFrame, frames: pl.DataFrame, feedback: Feedback
) -> list[Path]:
    """Each episode's recording under ``stage/recordings`` (``analysis.dataset.episode_rrd``),
    its cameras in the dataset's order; opened at its worst camera's first flag."""
    flagged = first_flags(eps, frames)
    order = {c: i for i, c in enumerate(ds.cameras)}
    paths = []
    episodes = sorted(eps["episode_index"].unique().to_list())
    feedback.log(f"writing {len(episodes)} episode recording(s) into {EPISODE_RECORDINGS}/")
    # the frames split once by episode and camera: a filter per episode reads the whole
    # table each time (a dataset's hundreds of episodes: quadratic)
    parts = frames.partition_by("episode_index", "camera", as_dict=True)
    for e in episodes:
        rows = sorted(eps.filter(pl.col("episode_index") == e).iter_rows(named=True),
                      key=lambda r: order.get(r["camera"], len(order)))  # fmt: skip
        per_cam = {r["camera"]: parts[(e, r["camera"])].sort("frame") for r in rows}
        worst = next((r for r in eps.iter_rows(named=True)
                      if r["episode_index"] == e and r["flag_count"] > 0), None)  # fmt: skip
        first = None
        if worst is not None:
            flag, frame = flagged[(e, worst["camera"])]
            first = (flag, worst["camera"], frame)
        path = stage / EPISODE_RECORDINGS / f"episode_{e:06d}.rrd"
        paths.append(write_episode(path, ds.root, ds.version, e, rows, per_cam, first))
    return paths


def _problem_of(v: EpisodeVideo, error: str) -> Problem:
    """The problem a failed task names: the file its message starts with (the episode's data
    or its video; the camera said for a video), else the video and the whole message (an
    unexpected error keeps its type)."""
    # the worker says "Type: message"; a UserError is the file's own problem, said as is
    msg = error.removeprefix("UserError: ")
    if msg.startswith(v.data_path + ": "):
        return Problem(v.data_path, v.episode, msg[len(v.data_path) + 2 :])
    if msg.startswith(v.path + ": "):
        msg = msg[len(v.path) + 2 :]
    return Problem(v.path, v.episode, f"{v.camera}: {msg}")


def _order(key: str) -> tuple[int, str]:
    e, cam = key.split(":", 1)
    return int(e), cam


def _width(info: dict, cam: str) -> int:
    feat = info.get("features", {}).get(cam, {})
    shape = feat.get("shape") or [0, 0]
    names = feat.get("names") or []
    if "width" in names:
        return int(shape[names.index("width")])
    return int(shape[1]) if len(shape) > 1 else 0

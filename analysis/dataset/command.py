"""The command ``vdc-analyse dataset``: the function and its result (its settings: ``settings``; the
package's face, ``analysis.dataset``, names them)."""

from __future__ import annotations

import dataclasses
import errno
import json
import shlex
import tempfile
import time
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

LIST_MAX = 25  # the terminal lists at most this many flagged episodes (all are in the files)
FLAGGED_FILE = "flagged_episodes.json"  # the flagged episodes and the command deleting them
PROGRESS_EVERY_S = 3.0  # a count of the camera streams measured, at least this often


def delete_command(root: Path, episodes: list[int]) -> str:
    """``lerobot-edit-dataset``'s command deleting ``episodes`` from the dataset at ``root``
    into a new dataset beside it (the original kept: a wrong index once deleted a whole
    dataset's folder, lerobot issue 2712). The repo id is the folder's last two names, as
    LeRobot keeps a local dataset under ``$HF_LEROBOT_HOME/{owner}/{name}``."""
    root = root.resolve()
    repo = f"{root.parent.name}/{root.name}"
    indices = "[" + ", ".join(map(str, episodes)) + "]"
    return " ".join(
        [
            "lerobot-edit-dataset",
            "--repo_id",
            shlex.quote(repo),
            "--root",
            shlex.quote(str(root)),
            "--new_repo_id",
            shlex.quote(f"{repo}_clean"),
            "--new_root",
            shlex.quote(str(root.with_name(f"{root.name}_clean"))),
            "--operation.type",
            "delete_episodes",
            "--operation.episode_indices",
            shlex.quote(indices),
        ]
    )


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
    # per camera: which kind it was taken for (fixed, or moving with the robot) and why
    cameras: list[str] = dataclasses.field(default_factory=list)
    # the flagged episodes (those of ``fail_on``'s flags when it names any) and the
    # lerobot-edit-dataset command that deletes them (None: none flagged)
    flagged: list[int] = dataclasses.field(default_factory=list)
    delete_command: str | None = None

    def report(self) -> list[str]:
        """Lines for people: what was profiled, what was flagged, what was written."""
        eps = self.episodes
        lines: list[str] = [f"camera {c}." for c in self.cameras]
        if eps is not None:
            n_eps = eps["episode_index"].n_unique()
            flagged = eps.filter(pl.col("flag_count") > 0)
            by_ep: dict[int, list[str]] = {}
            for r in flagged.iter_rows(named=True):  # worst first, one line an episode
                by_ep.setdefault(r["episode_index"], []).append(f"{r['camera']}: {r['flags']}")
            lines.append(
                f"{n_eps} episode(s), {eps.height} camera stream(s) profiled; "
                f"{len(by_ep)} episode(s) flagged" + (":" if by_ep else ".")  # the list follows
            )
            shown = list(by_ep.items())
            if len(shown) > LIST_MAX:  # a long list: the worst, the rest in the files
                shown = shown[: LIST_MAX - 1]
            for e, what in shown:
                lines.append(f"  episode {e}: {'; '.join(what)}")
            if len(shown) < len(by_ep):
                lines.append(
                    f"  ... and {len(by_ep) - len(shown)} more episode(s) flagged "
                    f"({FLAGGED_FILE}, dataset.html)."
                )
            lines.append(f"  {n_eps - len(by_ep)} episode(s) clean.")
        if self.failed:
            lines.append(f"--fail-on: episode(s) {', '.join(map(str, self.failed))} flagged.")
        # the dataset's own problems (its metadata disagreeing): they bear on every episode
        lines += [f"dataset problem: {p}" for p in self.dataset_problems]
        if self.problems:
            lines.append(f"{len(self.problems)} problem(s): exit 2 (problems.parquet).")
        rrds = [p for p in self.paths if p.suffix == ".rrd"]
        tables = [str(p) for p in self.paths if p.suffix != ".rrd"]
        if rrds:  # one folder of recordings, not a name per episode
            tables.append(f"{rrds[0].parent}/ ({len(rrds)} episode recording(s))")
        lines.append("wrote " + ", ".join(tables))
        if self.delete_command:
            lines.append(
                f"to delete the {len(self.flagged)} flagged episode(s) with LeRobot's own tool "
                f"(into a new dataset; vdc does not run it): {self.delete_command}"
            )
        return lines

    @property
    def exit_status(self) -> int:
        """2 where input was unreadable, else 1 where ``fail_on`` flagged an episode, else 0."""
        return 2 if self.problems else 1 if self.failed else 0


def dataset(
    path: str | Path,
    settings: DatasetSettings | None = None,
    out: str | Path | None = "results/dataset",
    feedback: Feedback | None = None,
) -> DatasetResult:
    """Profile the LeRobot dataset at ``path`` episode by episode into ``out`` (see the
    module). Needs the ``__main__`` guard in a script (it starts a process pool). A dataset
    that cannot be read at all (no meta/info.json, an unknown codebase_version) raises
    UserError; an unreadable episode is listed in ``problems``. ``out=None`` writes nothing
    (the work is done in a folder removed before this returns) and returns the tables."""
    if out is None:
        with tempfile.TemporaryDirectory(prefix="vdc-dataset-") as tmp:
            res = dataset(path, settings, tmp, feedback)
        return dataclasses.replace(res, paths=[])  # nothing written remains
    return _run(Path(path), settings or DatasetSettings(), Path(out), feedback or Feedback())


def no_fov_note(settings: DatasetSettings) -> str | None:
    """One note where the angular measures are left out for want of a field of view."""
    left = [m for m in parse_metrics(settings.metrics) if m in ANGULAR_METRICS]
    if settings.fov_deg is not None or not left:
        return None
    return (
        f"no --fov-deg: {', '.join(left)} and the shifts in degrees left out (they need the "
        "cameras' horizontal field of view); the other measures are taken."
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
                f"{root} (its episodes: {len(ds.listed)}, indices {listed})."
            )
    unknown = [c for c in settings.moving_camera_list() if c not in ds.cameras]
    if unknown:
        raise UserError(
            f"--moving-cameras: {unknown[0]!r} is not a camera of {root} (its "
            f"cameras: {', '.join(ds.cameras)})."
        )
    videos = [v for v in ds.videos if wanted is None or v.episode in wanted]
    notes = [n for n in [no_fov_note(settings)] if n]
    for n in notes:
        feedback.log(n)
    feedback.log(
        f"{root}: LeRobot {ds.version}, {len(set(v.episode for v in videos))} episode(s), "
        f"{len(ds.cameras)} camera(s), {_rates_said(ds)}."
    )
    if out.exists() and not out.is_dir():  # as vdc.parquet_io.table_set says it
        raise UserError(f"--out {str(out)!r} is a file, not a folder; give a folder.")
    out.mkdir(parents=True, exist_ok=True)  # each episode's result is kept there as it ends
    clear_partials(out)
    by_key = {f"{v.episode}:{v.camera}": v for v in videos}

    def rates(v: EpisodeVideo) -> tuple[float, float]:  # the camera's, the data's beside it
        return ds.rate(v.camera), ds.data_rate(v.camera)

    results: dict[str, dict[str, Any]] = {}
    # what an earlier (killed) run measured is read back here, without a worker
    for key, v in by_key.items():
        kept = read_result(result_path(out, v, settings, *rates(v)))
        if kept is not None:
            results[key] = kept
    if results:
        feedback.log(f"{len(results)} camera stream(s) read back from an earlier run's results.")
    tasks = [
        (k, (v, settings, ds.rate(v.camera), out, ds.data_rate(v.camera)))
        for k, v in by_key.items()
        if k not in results
    ]

    feedback.expect(len(tasks))
    n_done = [0, time.monotonic()]  # streams measured, when the count was last said

    def done(outcome: Any) -> None:
        feedback.progress(1)
        n_done[0] += 1
        now = time.monotonic()
        if now - n_done[1] >= PROGRESS_EVERY_S or n_done[0] == len(tasks):
            feedback.log(f"{n_done[0]} of {len(tasks)} camera stream(s) measured.")
            n_done[1] = now
        if outcome.error is None:
            results[outcome.key] = outcome.result
            return
        if outcome.error.startswith(f"{OutputError.__name__}: "):  # the run's, not the video's
            raise UserError(outcome.error.split(": ", 1)[1])
        problem = _problem_of(by_key[outcome.key], outcome.error)
        if problem not in problems:  # a data file's problem: once, not once per camera
            problems.append(problem)
            feedback.log(f"error: {problem.line()}")

    if tasks:
        feedback.log(
            f"measuring {len(tasks)} camera stream(s) of "
            f"{len({by_key[k].episode for k, _ in tasks})} episode(s); a count every "
            f"{PROGRESS_EVERY_S:g} s."
        )
    if tasks:  # the task lives in resume: a worker imports the measuring, not this command
        run_tasks(
            measured,
            tasks,
            settings.executor_settings(),
            done,
            feedback.log,
            shared_paths=(root, out),
        )
    drop_stale(out, [result_path(out, v, settings, *rates(v)) for v in videos])
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
    pose_deltas = {
        (r["row"]["episode_index"], r["row"]["camera"]): r.get("pose_delta")
        for r in results.values()
    }
    widths = {cam: _width(ds.info, cam) for cam in ds.cameras}
    meta = {
        "command": "dataset",
        "dataset": str(root),
        "version": ds.version,
        "settings": dataclasses.asdict(settings),
    }
    problem_table = pl.DataFrame(
        {
            "file": [p.file for p in problems],
            "episode_index": [p.episode for p in problems],
            "message": [p.message for p in problems],
        },
        schema={"file": pl.String, "episode_index": pl.Int64, "message": pl.String},
    )
    eps = None
    motions: dict[str, dict[str, Any]] = {}
    if rows:
        eps, frame_table, motions = finish(
            rows,
            pl.concat(frames, how="diagonal_relaxed"),
            views,
            widths,
            settings.fov_deg,
            pose_deltas,
            settings.moving_camera_list(),
            settings.flag_thresholds(),
            tuple(ds.cameras),
        )
        eps = severity(eps, settings.flag_thresholds())
    try:
        with table_set(out) as stage:
            tables = {
                "episodes": eps,
                "frames": frame_table if rows else None,
                "problems": problem_table,
            }
            paths = write_tables(stage, tables, meta)
            if eps is not None:
                flagged, command = _flagged(root, eps, settings)
                listing = {
                    "dataset": str(root),
                    "episode_indices": flagged,
                    "flags": {
                        str(r["episode_index"]): r["flags"]
                        for r in eps.iter_rows(named=True)
                        if r["flags"]
                    },
                    "lerobot_edit_dataset": command,
                }
                (stage / FLAGGED_FILE).write_text(json.dumps(listing, indent=2) + "\n")
                paths.append(stage / FLAGGED_FILE)
            if settings.page and eps is not None:
                paths.append(
                    write_page(
                        stage / "dataset.html",
                        ds,
                        eps,
                        frame_table,
                        problems,
                        tuple(m["evidence"] for m in motions.values()),
                    )
                )
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
        paths,
        eps,
        [p.line() for p in problems],
        sorted(set(failed)),
        notes,
        reused,
        [p.line() for p in problems if p.episode is None],
        [m["evidence"] for m in motions.values()],
        *(_flagged(root, eps, settings) if eps is not None else ([], None)),
    )


def _flagged(root: Path, eps: pl.DataFrame, settings: DatasetSettings) -> tuple:
    """(the flagged episodes: those with a flag of ``fail_on`` where it names any, else with
    any flag; the command deleting them, or None)."""
    fail = set(settings.fail_names())
    out = sorted(
        {
            int(r["episode_index"])
            for r in eps.iter_rows(named=True)
            if (fail & set(filter(None, r["flags"].split(","))) if fail else r["flags"])
        }
    )
    return out, delete_command(root, out) if out else None


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
    feedback.log(f"writing {len(episodes)} episode recording(s) into {EPISODE_RECORDINGS}/.")
    # the frames split once by episode and camera: a filter per episode reads the whole
    # table each time (a dataset's hundreds of episodes: quadratic)
    parts = frames.partition_by("episode_index", "camera", as_dict=True)
    for e in episodes:
        rows = sorted(
            eps.filter(pl.col("episode_index") == e).iter_rows(named=True),
            key=lambda r: order.get(r["camera"], len(order)),
        )
        per_cam = {r["camera"]: parts[(e, r["camera"])].sort("frame") for r in rows}
        worst = next(
            (
                r
                for r in eps.iter_rows(named=True)
                if r["episode_index"] == e and r["flag_count"] > 0
            ),
            None,
        )
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

"""Per-episode resumability of ``vdc-analyse dataset``: each camera of each episode, once
measured, is kept in ``out/episode_results/`` (written to ``<name>.partial-<pid>`` and renamed
when whole, so a killed run leaves whole results or none), keyed by what it was measured from
(the settings that change a measure, the episode's window and the stats of its video and data
files). A run that finds its key's result reads it back instead of decoding the episode again;
a changed setting or file is measured afresh, and its older result removed."""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import os
import pickle
import re
from pathlib import Path
from typing import Any

from analysis.dataset.layout import EpisodeVideo
from analysis.dataset.measure import measure_episode
from vdc.errors import UserError
from vdc.recording import pid_alive

RESULTS = "episode_results"  # the folder of ``out`` holding the measured episodes
# bumped when a measure's computation changes: results of an older version are measured again
RESULT_VERSION = 4  # 2: the rate measured at (fps) and the data's problems kept; 3: idle
# runs and the lag's "cannot tell"; 4: the view's motion and the pose's change per frame
# settings that decide where or what is reported, never what is measured
_NOT_MEASURED = {
    "fail_on",
    "episodes",
    "page",
    "recordings",
    "executor",
    "jobs",
    "scheduler",
    "thresholds",
    "moving_cameras",
}


def _stat(path: str) -> list[int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_size, st.st_mtime_ns]


def result_path(
    out: Path, video: EpisodeVideo, settings: Any, fps: float, data_fps: float | None = None
) -> Path:
    """Where ``video``'s result is kept under ``out``: its episode and camera, and a hash of
    what it is measured from (``data_fps``: the data's rate, where not the camera's)."""
    measured = {k: v for k, v in dataclasses.asdict(settings).items() if k not in _NOT_MEASURED}
    data_stat = _stat(video.data_path)
    video_stat = _stat(video.path) if video.kind == "video" else None
    key = json.dumps(
        [RESULT_VERSION, measured, dataclasses.asdict(video), fps, data_stat, video_stat]
        + ([data_fps] if data_fps not in (None, fps) else []),
        sort_keys=True,
        default=str,
    )
    digest = hashlib.sha1(key.encode()).hexdigest()[:16]
    cam = re.sub(r"[^A-Za-z0-9_.-]", "_", video.camera)
    return out / RESULTS / f"episode_{video.episode:06d}.{cam}.{digest}.pkl"


def measured(
    video: EpisodeVideo, settings: Any, fps: float, out: Path, data_fps: float | None = None
) -> dict[str, Any]:
    """An executor task: :func:`measure_episode`'s result for ``video``, read back from
    ``out/episode_results/`` when a run measured it from the same input with the same settings,
    else measured and kept there. The result's ``reused`` says which."""
    path = result_path(out, video, settings, fps, data_fps)
    kept = read_result(path)
    if kept is not None:
        return kept
    result = measure_episode(video, settings, fps, data_fps)
    tmp = path.with_name(f"{path.name}.partial-{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tmp.open("wb") as f:
            pickle.dump(result, f, protocol=pickle.HIGHEST_PROTOCOL)
        tmp.replace(path)
    except OSError as exc:  # the output's fault (a full disk), not the episode's
        tmp.unlink(missing_ok=True)
        raise OutputError(output_error(path.parent, exc)) from None
    return result | {"reused": False}


class OutputError(UserError):
    """The run's output cannot be written (a full disk, no permission): the run's error,
    never an episode's (``analysis.dataset.command`` stops the run on it)."""


# what a full disk or a quota raises, as errno
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def errno_of(exc: OSError) -> int | None:
    """``exc``'s errno; Arrow's own OSErrors carry it only in their message ("[errno 28]")."""
    if exc.errno is not None:
        return exc.errno
    found = re.search(r"\[errno (\d+)\]", str(exc))
    return int(found.group(1)) if found else None


def output_error(where: Path, exc: OSError) -> str:
    """One line: ``where`` could not be written, and why (a full disk said as such)."""
    full = errno_of(exc) in DISK_FULL
    why = "the disk is full" if full else "it cannot be written"
    return f"{where}: {why} ({exc.strerror or exc}); the episodes measured before are kept"


def read_result(path: Path) -> dict[str, Any] | None:
    """The result kept at ``path`` (``reused`` set), or None where there is none or it cannot
    be read (then removed, to be measured again)."""
    if not path.exists():
        return None
    try:
        # our own file, written whole by :func:`measured` (never a user's): pickle keeps the
        # polars table and the float32 views exactly
        with path.open("rb") as f:
            return pickle.load(f) | {"reused": True}
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError):
        path.unlink(missing_ok=True)  # unreadable (a disk fault): measured again
        return None


def clear_partials(out: Path) -> None:
    """Results a killed run left half-written (``*.partial-<pid>``, the pid gone): removed."""
    for p in (out / RESULTS).glob("*.partial-*"):
        pid = p.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not pid_alive(int(pid)):
            p.unlink(missing_ok=True)


def drop_stale(out: Path, current: list[Path]) -> None:
    """Results of the episodes and cameras of ``current`` measured with other settings or from
    files since changed: removed, so the folder keeps one result per camera of an episode
    (the others', e.g. episodes left out with ``--episodes``, stay)."""
    keep = set(current)
    for path in current:
        stem = path.name.rsplit(".", 2)[0]  # episode_NNNNNN.<camera>
        for old in path.parent.glob(f"{stem}.*.pkl"):
            if old not in keep and old.name.rsplit(".", 2)[0] == stem:
                old.unlink(missing_ok=True)

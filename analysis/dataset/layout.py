"""Reading a LeRobot dataset's layout without LeRobot: ``meta/info.json``, the episode index
and the frame data, with pyarrow (``v3.0`` and ``v2.1``).

* ``v3.0``: episodes are rows of ``meta/episodes/chunk-*/file-*.parquet``; an episode's
  video is the window ``videos/{key}/from_timestamp`` .. ``to_timestamp`` (s) of the file its
  ``videos/{key}/chunk_index``/``file_index`` name through ``info["video_path"]``; its frames
  are the rows of ``data/chunk-*/file-*.parquet`` with its ``episode_index``;
* ``v2.1`` (and ``v2.0``): episodes are lines of ``meta/episodes.jsonl``; each has its own
  video (``info["video_path"]`` with ``episode_chunk``, ``video_key``, ``episode_index``),
  whole, and its own data file.

Image features stored as PNG frames (``images/{key}/episode-{e:06d}/frame-{i:06d}.png``) are
read as image sequences. What cannot be read is a :class:`Problem` naming the file and the
episode; the other episodes are still listed. The metadata is a claim: a field of info.json
that cannot be used raises UserError naming it; an episode listed twice, or whose length or
window is not one, is a problem; and info.json's ``fps`` is held against each camera's own
frame times and the data's timestamps (``analysis.dataset.rates``), a disagreement being a problem
of the dataset.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from analysis.dataset.rates import agreed_rate, data_rate, own_rate, stream_rate
from vdc.errors import UserError

VERSIONS = ("v3.0", "v2.1", "v2.0")
CHUNKS_SIZE = 1000  # LeRobot's default when info.json states none


@dataclasses.dataclass(frozen=True)
class Problem:
    """Something unreadable: the file, the episode (None: several or all) and why."""

    file: str
    episode: int | None
    message: str

    def line(self) -> str:
        ep = "" if self.episode is None else f" (episode {self.episode})"
        return f"{self.file}{ep}: {self.message}"


@dataclasses.dataclass(frozen=True)
class EpisodeVideo:
    """One camera of one episode: ``path`` (a video file, or a PNG pattern ``%06d``), the
    window ``from_s`` .. ``to_s`` inside it (s; ``to_s`` None: to the file's end), the stated
    ``length`` (frames) and the data file holding its rows."""

    episode: int
    camera: str
    path: str
    from_s: float
    to_s: float | None
    length: int
    data_path: str
    kind: str = "video"  # or "images"


@dataclasses.dataclass
class Dataset:
    """A dataset's layout: ``root``, ``info`` (meta/info.json), ``version``, ``fps`` (as
    info.json states it), ``cameras`` (video and image features), the episodes' camera videos,
    the problems met, ``listed`` (every episode index the index lists, readable or not) and
    ``rates``: each camera's rate (frames/s) as the evidence agrees (:func:`agreed_rate`);
    ``data_rates``: the data's rate beside a camera recording at a rate of its own (its
    ``video.fps`` in info.json's features, borne out by its video), elsewhere the camera's."""

    root: Path
    info: dict[str, Any]
    version: str
    fps: float
    cameras: list[str]
    videos: list[EpisodeVideo]
    problems: list[Problem]
    listed: list[int] = dataclasses.field(default_factory=list)
    rates: dict[str, float] = dataclasses.field(default_factory=dict)
    data_rates: dict[str, float] = dataclasses.field(default_factory=dict)

    @property
    def episodes(self) -> list[int]:
        return sorted({v.episode for v in self.videos})

    def rate(self, camera: str) -> float:
        """The rate ``camera`` is measured at (frames/s)."""
        return self.rates.get(camera, self.fps)

    def data_rate(self, camera: str) -> float:
        """The rate of the data's rows beside ``camera`` (frames/s)."""
        return self.data_rates.get(camera, self.rate(camera))


def read_info(root: Path) -> dict[str, Any]:
    """``meta/info.json`` checked: a missing or unreadable file, or an unknown
    ``codebase_version``, raises UserError naming it."""
    path = root / "meta" / "info.json"
    if root.exists() and not root.is_dir():
        raise UserError(
            f"{root} is a file, not a folder: give the LeRobot dataset's folder (the "
            "one holding meta/info.json)."
        )
    if not root.is_dir():
        raise UserError(f"{root}: no such folder (give a LeRobot dataset folder).")
    if not path.is_file():
        raise UserError(f"{path}: no such file: {root} is not a LeRobot dataset.")
    try:
        info = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not readable JSON ({exc}).") from None
    version = info.get("codebase_version") if isinstance(info, dict) else None
    if version not in VERSIONS:
        raise UserError(
            f"{path}: codebase_version {version!r} is not one vdc reads ({', '.join(VERSIONS)})."
        )
    fps = info.get("fps")
    # a bool is an int to Python, and JSON's NaN and Infinity parse as floats: none is a rate
    if (
        not isinstance(fps, (int, float))
        or isinstance(fps, bool)
        or not math.isfinite(fps)
        or fps <= 0
    ):
        raise UserError(
            f"{path}: fps {json.dumps(fps)} is not a rate (a positive, finite number of frames "
            "per second)."
        )
    feats = info.get("features", {})
    if not isinstance(feats, dict):
        raise UserError(
            f"{path}: features is a {type(feats).__name__}, not an object of features by name."
        )
    size = info.get("chunks_size", CHUNKS_SIZE)
    if size is not None and (not isinstance(size, int) or isinstance(size, bool) or size <= 0):
        raise UserError(f"{path}: chunks_size {json.dumps(size)} is not a positive integer.")
    for field, keys in _TEMPLATE_KEYS[version == "v3.0"].items():
        _check_template(path, field, info.get(field), keys)
    return info


# the fields each path template of info.json may name (v3.0, v2.x)
_TEMPLATE_KEYS = {
    True: {
        "data_path": ("chunk_index", "file_index"),
        "video_path": ("video_key", "chunk_index", "file_index"),
    },
    False: {
        "data_path": ("episode_chunk", "episode_index"),
        "video_path": ("episode_chunk", "video_key", "episode_index"),
    },
}


def _check_template(path: Path, field: str, tpl: Any, keys: tuple[str, ...]) -> None:
    """``info[field]`` (None: the default) formats with ``keys``, else UserError naming it."""
    if tpl is None:
        return
    if not isinstance(tpl, str):
        raise UserError(f"{path}: {field} is a {type(tpl).__name__}, not a path template.")
    try:
        tpl.format(**{k: 0 for k in keys})
    except KeyError as exc:
        raise UserError(
            f"{path}: {field} {tpl!r} names {{{exc.args[0]}}}, which vdc cannot fill (it "
            f"knows {', '.join(keys)})."
        ) from None
    except (IndexError, ValueError) as exc:
        raise UserError(f"{path}: {field} {tpl!r} is not a path template ({exc}).") from None


def _cameras(info: dict[str, Any]) -> list[str]:
    feats = info.get("features") or {}  # an object: read_info checked it
    return [
        k for k, v in feats.items() if isinstance(v, dict) and v.get("dtype") in ("video", "image")
    ]


def _read_table(path: Path, problems: list[Problem], episode: int | None = None) -> pa.Table | None:
    try:
        return pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        why = "no such file" if not path.exists() else f"not a readable Parquet file ({exc})"
        problems.append(Problem(str(path), episode, why))
        return None


def open_dataset(root: str | Path) -> Dataset:
    """The layout of the dataset at ``root`` (see the module). Raises UserError where the
    dataset itself is unreadable (no meta/info.json, an unknown version, no episode index,
    a malformed field of info.json); an unreadable or inconsistent episode is a Problem."""
    root = Path(root)
    info = read_info(root)
    version = info["codebase_version"]
    cams = _cameras(info)
    problems: list[Problem] = []
    listing = (
        _v3_videos(root, info, cams, problems)
        if version == "v3.0"
        else _v2_videos(root, info, cams, problems)
    )
    videos, listed = _no_duplicates(listing, problems)
    if not videos and not problems:
        raise UserError(f"{root}: the dataset lists no episodes with a camera.")
    if not listed and problems:  # not one episode could be listed: nothing to profile
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UserError(f"{problems[0].line()}{more}: no episode can be read.")
    ds = Dataset(root, info, version, float(info["fps"]), cams, videos, problems, listed)
    ds.rates = _rates(ds)
    return ds


def _image_pattern(root: Path, cam: str, e: int) -> str:
    return str(root / "images" / cam / f"episode-{e:06d}" / "frame-%06d.png")


def _count(v: Any) -> int | None:
    """``v`` as a count (an integer, or a float with an integral value; not a bool), or None."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    if isinstance(v, float) and not (math.isfinite(v) and v.is_integer()):
        return None
    return int(v)


def _window(r: dict, cam: str) -> tuple[float, float] | str:
    """A v3.0 row's window of ``cam`` (from_s, to_s), or why it is not one."""
    keys = [f"videos/{cam}/from_timestamp", f"videos/{cam}/to_timestamp"]
    ends = []
    for k in keys:
        v = r.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return f"{k} {v!r} is not a time"
        ends.append(float(v))
    if ends[0] < 0:
        return f"{keys[0]} {ends[0]:g} s is before the file's start"
    if ends[1] <= ends[0]:
        return f"the window {keys[0]} {ends[0]:g} s .. {keys[1]} {ends[1]:g} s runs backwards"
    return ends[0], ends[1]


# (episode, its index file, where in it, [its camera videos] or why they cannot be listed)
_Listing = tuple[int, str, str, "list[EpisodeVideo] | str"]


def _v3_videos(root: Path, info: dict, cams: list[str], problems: list[Problem]) -> list:
    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise UserError(f"{root / 'meta' / 'episodes'}: no episode index (chunk-*/file-*.parquet).")
    data_tpl = info.get("data_path") or (
        "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    )
    video_tpl = info.get("video_path") or (
        "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    )
    feats = info.get("features", {})
    out: list[_Listing] = []
    for f in files:
        table = _read_table(f, problems)
        if table is None:
            continue
        missing = [c for c in ("episode_index", "length") if c not in table.column_names]
        if missing:  # no row can be read: the file's problem, not each episode's
            problems.append(Problem(str(f), None, f"no column {missing[0]}"))
            continue
        for k, r in enumerate(table.to_pylist()):
            e = _count(r.get("episode_index"))
            where = f"row {k}"
            if e is None or e < 0:
                problems.append(
                    Problem(
                        str(f),
                        None,
                        f"row {k}: episode_index {r.get('episode_index')!r} is not "
                        "an episode index",
                    )
                )
                continue
            n = _count(r.get("length"))
            if n is None or n < 0:
                out.append((e, str(f), where, f"length {r.get('length')!r} is not a frame count"))
                continue
            chunk, file = _count(r.get("data/chunk_index")), _count(r.get("data/file_index"))
            if chunk is None or file is None:
                bad = "data/chunk_index" if chunk is None else "data/file_index"
                out.append((e, str(f), where, f"{bad} {r.get(bad)!r} is not an index"))
                continue
            data = root / data_tpl.format(chunk_index=chunk, file_index=file)
            videos: list[EpisodeVideo] = []
            for cam in cams:
                if feats[cam].get("dtype") == "image":
                    videos.append(
                        EpisodeVideo(
                            e, cam, _image_pattern(root, cam, e), 0.0, None, n, str(data), "images"
                        )
                    )
                    continue
                idx = [_count(r.get(f"videos/{cam}/{k}")) for k in ("chunk_index", "file_index")]
                window = _window(r, cam)
                if None in idx or isinstance(window, str):
                    bad = "chunk_index" if idx[0] is None else "file_index"
                    why = window if isinstance(window, str) else f"no videos/{cam}/{bad}"
                    problems.append(Problem(str(f), e, f"{cam}: {why}"))
                    continue
                path = root / video_tpl.format(video_key=cam, chunk_index=idx[0], file_index=idx[1])
                videos.append(EpisodeVideo(e, cam, str(path), *window, n, str(data)))
            out.append((e, str(f), where, videos))
    return out


def _v2_videos(root: Path, info: dict, cams: list[str], problems: list[Problem]) -> list:
    path = root / "meta" / "episodes.jsonl"
    if not path.is_file():
        raise UserError(f"{path}: no such file (the episode index of a v2 dataset).")
    size = int(info.get("chunks_size") or CHUNKS_SIZE)
    data_tpl = info.get("data_path") or (
        "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
    )
    video_tpl = info.get("video_path") or (
        "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
    )
    try:
        lines = path.read_bytes().splitlines()
    except OSError as exc:
        raise UserError(f"{path}: not readable ({exc.strerror}).") from None
    out: list[_Listing] = []
    for k, raw in enumerate(lines):
        if not raw.strip():
            continue
        try:
            r = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            problems.append(Problem(str(path), None, f"line {k + 1} is not a JSON record"))
            continue
        e = _count(r.get("episode_index")) if isinstance(r, dict) else None
        if e is None or e < 0:
            got = r.get("episode_index") if isinstance(r, dict) else r
            problems.append(
                Problem(
                    str(path), None, f"line {k + 1}: episode_index {got!r} is not an episode index"
                )
            )
            continue
        n = _count(r.get("length"))
        if n is None or n < 0:
            out.append(
                (e, str(path), f"line {k + 1}", f"length {r.get('length')!r} is not a frame count")
            )
            continue
        data = root / data_tpl.format(episode_chunk=e // size, episode_index=e)
        videos = []
        for cam in cams:
            if info["features"][cam].get("dtype") == "image":
                videos.append(
                    EpisodeVideo(
                        e, cam, _image_pattern(root, cam, e), 0.0, None, n, str(data), "images"
                    )
                )
                continue
            video = root / video_tpl.format(episode_chunk=e // size, video_key=cam, episode_index=e)
            videos.append(EpisodeVideo(e, cam, str(video), 0.0, None, n, str(data)))
        out.append((e, str(path), f"line {k + 1}", videos))
    return out


def _no_duplicates(
    listing: list[_Listing], problems: list[Problem]
) -> tuple[list[EpisodeVideo], list[int]]:
    """(the videos of each episode listed once, every episode index listed). An episode listed
    more than once is a problem naming where: measured once when its listings agree, else not
    at all (which of them is the episode's is not known); a listing that is itself a problem
    (its message) is said here, once per episode."""
    by_episode: dict[int, list[tuple[str, str, Any]]] = {}
    for e, file, where, got in listing:
        by_episode.setdefault(e, []).append((file, where, got))
    videos: list[EpisodeVideo] = []
    for e in sorted(by_episode):
        entries = by_episode[e]
        for file, where, got in entries:
            if isinstance(got, str):
                problems.append(Problem(file, e, f"{where}: {got}"))
        if len(entries) > 1:
            files = {f for f, _, _ in entries}
            wheres = ", ".join(
                w if len(files) == 1 else f"{Path(f).name} {w}" for f, w, _ in entries
            )
            same = all(got == entries[0][2] for _, _, got in entries)
            problems.append(
                Problem(
                    entries[0][0],
                    e,
                    f"listed {len(entries)} times ({wheres}): "
                    + (
                        "the same each time, measured once"
                        if same
                        else "the listings differ, so the episode is not measured"
                    ),
                )
            )
            if not same:
                continue
        if isinstance(entries[0][2], list):
            videos.extend(entries[0][2])
    return videos, sorted(by_episode)


def _rates(ds: Dataset) -> dict[str, float]:
    """Each camera's rate from info.json's fps, its video's own rate (its first episode's
    file) and the data's timestamps (:func:`agreed_rate`); where they disagree, a problem of
    the dataset naming each and the rate measured at. A camera whose own ``video.fps``
    differs from the fps the data's timestamps bear out records at a rate of its own (LeRobot
    allows it): its rate is its ``video.fps`` against its video's, the data's stays the fps
    (``ds.data_rates``)."""
    info_path = str(ds.root / "meta" / "info.json")
    data = data_rate(list(dict.fromkeys(v.data_path for v in ds.videos))[:3])
    data_said = data is None or agreed_rate([("", ds.fps), ("", data)])[1]
    rates = {}
    for cam in ds.cameras:
        first = next((v for v in ds.videos if v.camera == cam), None)
        if first is None:
            continue
        stream = stream_rate(first.path) if first.kind == "video" else None
        own = own_rate(ds.info, cam)
        stream_said = (
            f"the video's frames {stream:.4g} fps (their median interval in "
            f"{Path(first.path).name})"
            if stream
            else "",
            stream,
        )
        if own is not None and data_said and not agreed_rate([("", ds.fps), ("", own)])[1]:
            evidence = [(f"info.json's {cam} video.fps {own:g}", own), stream_said]
            ds.data_rates[cam] = ds.fps
        else:
            evidence = [
                (f"info.json's fps {ds.fps:g}", ds.fps),
                stream_said,
                (
                    f"the data's timestamp {data:.4g} fps (its median interval in "
                    f"{Path(first.data_path).name})"
                    if data
                    else "",
                    data,
                ),
            ]
        rates[cam], agreed = agreed_rate(evidence)
        if not agreed:
            said = "; ".join(name for name, r in evidence if r is not None)
            why = f"{cam}: the rates disagree: {said}: measured at {rates[cam]:.4g} fps"
            ds.problems.append(Problem(info_path, None, why))
    return rates


@dataclasses.dataclass(frozen=True)
class EpisodeData:
    """An episode's rows of the data: ``timestamp`` (N,) float64 s; ``state`` and
    ``action`` (N, D) float64 (None where the dataset has no such feature)."""

    timestamp: np.ndarray
    state: np.ndarray | None
    action: np.ndarray | None


def _vectors(col: pa.ChunkedArray) -> np.ndarray:
    values = col.combine_chunks()
    if pa.types.is_list(values.type) or pa.types.is_fixed_size_list(values.type):
        flat = values.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
        return flat.reshape(len(values), -1)
    return values.to_numpy(zero_copy_only=False).astype(np.float64).reshape(len(values), -1)


def read_episode_data(path: str, episode: int) -> EpisodeData:
    """The rows of ``episode`` in the data file ``path``, in frame order. An unreadable file
    or one without the episode's rows raises UserError naming it."""
    cols = ["timestamp", "frame_index", "episode_index"]
    try:
        schema = pq.read_schema(path)
        want = cols + [c for c in ("observation.state", "action") if c in schema.names]
        table = pq.read_table(path, columns=want, filters=[("episode_index", "=", episode)])
    except FileNotFoundError:
        raise UserError(f"{path}: no such file.") from None
    except (OSError, pa.ArrowException) as exc:
        raise UserError(f"{path}: not a readable Parquet file ({exc}).") from None
    if table.num_rows == 0:
        raise UserError(f"{path}: no rows of episode {episode}.")
    order = np.argsort(table["frame_index"].to_numpy())
    ts = table["timestamp"].to_numpy().astype(np.float64)[order]
    state = _vectors(table["observation.state"])[order] if "observation.state" in want else None
    action = _vectors(table["action"])[order] if "action" in want else None
    return EpisodeData(ts, state, action)

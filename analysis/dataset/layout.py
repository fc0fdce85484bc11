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
episode; the other episodes are still listed.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

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
    """A dataset's layout: ``root``, ``info`` (meta/info.json), ``version``, ``fps``,
    ``cameras`` (video and image features), the episodes' camera videos and the problems met."""

    root: Path
    info: dict[str, Any]
    version: str
    fps: float
    cameras: list[str]
    videos: list[EpisodeVideo]
    problems: list[Problem]

    @property
    def episodes(self) -> list[int]:
        return sorted({v.episode for v in self.videos})


def read_info(root: Path) -> dict[str, Any]:
    """``meta/info.json`` checked: a missing or unreadable file, or an unknown
    ``codebase_version``, raises UserError naming it."""
    path = root / "meta" / "info.json"
    if not root.is_dir():
        raise UserError(f"{root}: no such folder (give a LeRobot dataset folder)")
    if not path.is_file():
        raise UserError(f"{path}: no such file: {root} is not a LeRobot dataset")
    try:
        info = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not readable JSON ({exc})") from None
    version = info.get("codebase_version") if isinstance(info, dict) else None
    if version not in VERSIONS:
        raise UserError(
            f"{path}: codebase_version {version!r} is not one vdc reads ({', '.join(VERSIONS)})"
        )
    if not isinstance(info.get("fps"), (int, float)) or info["fps"] <= 0:
        raise UserError(f"{path}: no positive fps")
    return info


def _cameras(info: dict[str, Any]) -> list[str]:
    feats = info.get("features") or {}
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
    dataset itself is unreadable (no meta/info.json, an unknown version, no episode index)."""
    root = Path(root)
    info = read_info(root)
    version = info["codebase_version"]
    cams = _cameras(info)
    problems: list[Problem] = []
    videos = (
        _v3_videos(root, info, cams, problems)
        if version == "v3.0"
        else _v2_videos(root, info, cams, problems)
    )
    if not videos and not problems:
        raise UserError(f"{root}: the dataset lists no episodes with a camera")
    return Dataset(root, info, version, float(info["fps"]), cams, videos, problems)


def _image_pattern(root: Path, cam: str, e: int) -> str:
    return str(root / "images" / cam / f"episode-{e:06d}" / "frame-%06d.png")


def _v3_videos(root: Path, info: dict, cams: list[str], problems: list[Problem]) -> list:
    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise UserError(f"{root / 'meta' / 'episodes'}: no episode index (chunk-*/file-*.parquet)")
    data_tpl = info.get("data_path", "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet")
    video_tpl = info.get(
        "video_path", "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    )
    feats = info.get("features", {})
    out: list[EpisodeVideo] = []
    for f in files:
        table = _read_table(f, problems)
        if table is None:
            continue
        rows = table.to_pylist()
        for r in rows:
            e = int(r["episode_index"])
            try:
                data = root / data_tpl.format(
                    chunk_index=r["data/chunk_index"], file_index=r["data/file_index"]
                )
            except KeyError as exc:
                problems.append(Problem(str(f), e, f"no column data/{exc.args[0]}"))
                continue
            for cam in cams:
                if feats[cam].get("dtype") == "image":
                    out.append(EpisodeVideo(e, cam, _image_pattern(root, cam, e), 0.0, None,
                                            int(r["length"]), str(data), "images"))  # fmt: skip
                    continue
                ends = ("chunk_index", "file_index", "from_timestamp", "to_timestamp")
                keys = [f"videos/{cam}/{k}" for k in ends]
                missing = [k for k in keys if r.get(k) is None]
                if missing:
                    problems.append(Problem(str(f), e, f"no {missing[0]}"))
                    continue
                path = root / video_tpl.format(
                    video_key=cam, chunk_index=r[keys[0]], file_index=r[keys[1]]
                )
                out.append(EpisodeVideo(e, cam, str(path), float(r[keys[2]]), float(r[keys[3]]),
                                        int(r["length"]), str(data)))  # fmt: skip
    return out


def _v2_videos(root: Path, info: dict, cams: list[str], problems: list[Problem]) -> list:
    path = root / "meta" / "episodes.jsonl"
    if not path.is_file():
        raise UserError(f"{path}: no such file (the episode index of a v2 dataset)")
    size = int(info.get("chunks_size") or CHUNKS_SIZE)
    data_tpl = info.get(
        "data_path", "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
    )
    video_tpl = info.get(
        "video_path", "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
    )
    out: list[EpisodeVideo] = []
    for k, line in enumerate(path.read_text().splitlines()):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
            e, n = int(r["episode_index"]), int(r["length"])
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            problems.append(Problem(str(path), None, f"line {k + 1} is not an episode record"))
            continue
        data = root / data_tpl.format(episode_chunk=e // size, episode_index=e)
        for cam in cams:
            if info["features"][cam].get("dtype") == "image":
                out.append(EpisodeVideo(e, cam, _image_pattern(root, cam, e), 0.0, None, n,
                                        str(data), "images"))  # fmt: skip
                continue
            video = root / video_tpl.format(episode_chunk=e // size, video_key=cam,
                                            episode_index=e)  # fmt: skip
            out.append(EpisodeVideo(e, cam, str(video), 0.0, None, n, str(data)))
    return out


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
        raise UserError(f"{path}: no such file") from None
    except (OSError, pa.ArrowException) as exc:
        raise UserError(f"{path}: not a readable Parquet file ({exc})") from None
    if table.num_rows == 0:
        raise UserError(f"{path}: no rows of episode {episode}")
    order = np.argsort(table["frame_index"].to_numpy())
    ts = table["timestamp"].to_numpy().astype(np.float64)[order]
    state = _vectors(table["observation.state"])[order] if "observation.state" in want else None
    action = _vectors(table["action"])[order] if "action" in want else None
    return EpisodeData(ts, state, action)

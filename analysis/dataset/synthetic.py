"""Small LeRobot datasets written in the exact on-disk layout, with faults injected at known
places: the truth the dataset command is tested against, and the worked example of
docs/guides/dataset.md (``python -m analysis.dataset.synthetic OUT``).

The scene is a real photograph (matplotlib's sample ``grace_hopper.jpg``, installed with
matplotlib: no optional extra) seen by a fixed third-person camera (or one on the arm that
pans with it), with an object (matplotlib's gift box on a dark table) that the robot moves
across it: the object's image position is a fixed linear function of
``observation.state`` at the time the camera saw it. Each episode starts and ends at the home
pose (state 0) and moves as ``sin²`` in between, so every episode's first frame is the camera's
reference view.

Layouts (LeRobot's ``codebase_version``):

* ``v3.0``: ``meta/info.json``; ``meta/episodes/chunk-000/file-000.parquet`` (one row per
  episode, with its window ``videos/{key}/from_timestamp`` .. ``to_timestamp``);
  ``meta/tasks.parquet``; ``data/chunk-000/file-000.parquet`` (all episodes' frames:
  ``timestamp`` (per episode, s), ``frame_index``, ``episode_index``, ``index``,
  ``task_index``, ``observation.state``, ``action``); ``videos/{key}/chunk-000/file-000.mp4``
  (all episodes one after another in one shared file);
* ``v2.1``: ``meta/info.json``, ``meta/episodes.jsonl``, ``meta/tasks.jsonl``,
  ``data/chunk-000/episode_{e:06d}.parquet`` and ``videos/chunk-000/{key}/episode_{e:06d}.mp4``
  (one video per episode, its time from 0).

Codecs: ``libsvtav1`` (LeRobot's default: a key frame every 2 frames, CRF 30), ``libx264``
(the same GOP, no B-frames) and ``libx264-bframes`` (two B-frames, a key frame every 12),
yuv420p.

Faults (:class:`Faults`), each on the first camera of one episode and measured against the
data's own timeline (``timestamp = frame_index / fps``):

* ``frozen``: episode → (first frame, k): frames first..first+k-1 repeat the image of the
  frame before them while the state moves;
* ``dropped``: episode → (first frame, n): n frames missing from the video (a gap in its
  times); the data keeps their rows;
* ``drift_ms``: episode → d: the video's clock runs fast, its frames spaced so that the last
  one comes d ms later than the data's last timestamp (the start is exact);
* ``bump``: (episode e, p): the camera moved p px to the right from episode e on;
* ``knock``: (episode e, frame f, p): the camera knocked p px to the right at frame f of
  episode e, and left there (the episodes after e too);
* ``lag_ms``: episode → L: each frame shows the scene as it was L ms before its timestamp;
* ``idle_head_s``: episode → s: nothing moves for the first s seconds;
* ``blurred``: episodes filmed out of focus (a Gaussian blur, sigma 2.5 px);
* ``overexposed``: episodes with the gain too high (luma × 2.2 + 70, clipped).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from matplotlib import cbook

from analysis.dataset.synthetic_video import encode_file
from vdc.errors import UserError

# (libx264-bframes: H.264 with two B-frames between references and a key frame every 12, a
# stream whose decoding order is not its presentation order)
CODECS = {"libsvtav1": "av1", "libx264": "h264", "libx264-bframes": "h264"}
STATE_DIM = 6
MARGIN_PX = 24  # the canvas around the view that a bumped camera can move into


@dataclasses.dataclass(frozen=True)
class Faults:
    """Where each fault goes (see the module): episode indices into the dataset."""

    frozen: dict[int, tuple[int, int]] = dataclasses.field(default_factory=dict)
    dropped: dict[int, tuple[int, int]] = dataclasses.field(default_factory=dict)
    drift_ms: dict[int, float] = dataclasses.field(default_factory=dict)
    bump: tuple[int, int] | None = None
    knock: tuple[int, int, int] | None = None
    lag_ms: dict[int, float] = dataclasses.field(default_factory=dict)
    idle_head_s: dict[int, float] = dataclasses.field(default_factory=dict)
    blurred: frozenset[int] = frozenset()
    overexposed: frozenset[int] = frozenset()

    def clean(self, episode: int) -> bool:
        """Whether ``episode`` has no fault (a bumped camera's episodes are faulty)."""
        bumped = self.bump is not None and episode >= self.bump[0]
        knocked = self.knock is not None and episode >= self.knock[0]
        return (
            not bumped
            and not knocked
            and not any(
                episode in getattr(self, f.name)
                for f in dataclasses.fields(self)
                if f.name not in ("bump", "knock")
            )
        )


# the test datasets' faults: one per episode, clean episodes between (0, 8 and 9 before the bump)
STANDARD_FAULTS = Faults(
    frozen={1: (15, 12)},  # while the arm moves out fast (not at its turn)
    dropped={2: (45, 5)},
    drift_ms={3: 80.0},
    lag_ms={4: 100.0},
    idle_head_s={5: 1.0},
    blurred=frozenset({6}),
    overexposed=frozenset({7}),
    bump=(10, 6),
)


def _photo(name: str) -> np.ndarray:
    """A photograph from matplotlib's sample data (installed with matplotlib, a dependency of
    vdc: nothing downloaded), (H, W, 3) RGB uint8 or (H, W, 4) RGBA."""
    with cbook.get_sample_data(name) as f:
        buf = np.frombuffer(f.read(), np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise UserError(f"matplotlib's sample photograph {name} cannot be read.")
    return cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)


def _scene(height: int, width: int, pan_px: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(canvas RGB uint8 of the view plus a margin, ``pan_px`` more either side, object RGB
    uint8): real photographs that come with matplotlib (a portrait; a blue gift box on a
    dark table, the object the robot moves)."""
    bg = cv2.resize(
        _photo("grace_hopper.jpg"),
        (width + 2 * (MARGIN_PX + pan_px), height + 2 * MARGIN_PX),
        interpolation=cv2.INTER_AREA,
    )
    side = max(8, height // 4)
    box = _photo("Minduka_Present_Blue_Pack.png").astype(np.float32)
    alpha = box[..., 3:] / 255.0
    table = np.float32([40, 32, 28])  # dark brown: the box stands out of the portrait
    obj = box[..., :3] * alpha + table * (1 - alpha)
    obj = cv2.resize(
        np.clip(obj, 0, 255).astype(np.uint8), (side, side), interpolation=cv2.INTER_AREA
    )
    return bg, obj


def trajectory(
    n: int, fps: float, idle_s: float, amplitude: float, seed: int, strokes: int = 1
) -> np.ndarray:
    """(n, STATE_DIM) float64 joint positions at t = i / fps: still for ``idle_s``, then out
    and back to the home pose (0) as sin², ``strokes`` times; joint 0 moves the object across
    the view, joint 1 up and down (a third of it), the others follow slowly."""
    t = np.arange(n) / fps
    dur = n / fps
    u = np.clip((t - idle_s) / max(dur - idle_s - 1 / fps, 1e-9), 0, 1)
    base = np.sin(np.pi * strokes * u) ** 2
    rng = np.random.default_rng(seed)
    gains = np.concatenate(([1.0, 0.33], rng.uniform(0.05, 0.2, STATE_DIM - 2)))
    return amplitude * base[:, None] * gains[None, :]


def state_at(state: np.ndarray, fps: float, t: float) -> np.ndarray:
    """The state at time ``t`` (s), linearly interpolated (before 0: the first)."""
    x = t * fps
    i = int(np.clip(math.floor(x), 0, len(state) - 1))
    j = min(i + 1, len(state) - 1)
    a = float(np.clip(x - i, 0, 1))
    return state[i] * (1 - a) + state[j] * a


def render(
    bg: np.ndarray, obj: np.ndarray, s: np.ndarray, shape: tuple[int, int], shift_px: float = 0
) -> np.ndarray:
    """The camera's (H, W, 3) uint8 view of the scene with the object at state ``s`` (px:
    joint 0 horizontal from the left quarter, joint 1 vertical), the camera moved right by
    ``shift_px`` (a camera that pans: a fraction of a px too). Sub-pixel positions are
    rendered by a warp (bilinear)."""
    h, w = shape
    mx = (bg.shape[1] - w) // 2  # the canvas's margins: MARGIN_PX, wider for a pan
    my = (bg.shape[0] - h) // 2
    canvas = bg.astype(np.float32)
    side = obj.shape[0]
    x = mx + w * 0.2 + float(s[0])
    y = my + h * 0.4 + float(s[1])
    m = np.float32([[1, 0, x], [0, 1, y]])
    size = (canvas.shape[1], canvas.shape[0])
    placed = cv2.warpAffine(obj.astype(np.float32), m, size, flags=cv2.INTER_LINEAR)
    mask = cv2.warpAffine(np.ones((side, side), np.float32), m, size, flags=cv2.INTER_LINEAR)
    canvas = canvas * (1 - mask[..., None]) + placed
    if float(shift_px).is_integer():
        ox = mx + int(shift_px)
        return np.clip(canvas[my : my + h, ox : ox + w], 0, 255).astype(np.uint8)
    crop = np.float32([[1, 0, -(mx + shift_px)], [0, 1, -my]])
    view = cv2.warpAffine(canvas, crop, (w, h), flags=cv2.INTER_LINEAR)
    return np.clip(view, 0, 255).astype(np.uint8)


def _episode_frames(
    e: int,
    n: int,
    fps: float,
    shape: tuple[int, int],
    faults: Faults,
    scene: tuple,
    seed: int,
    pan_px_per_unit: float = 0.0,
    strokes: int = 1,
    state_width: int | None = None,
    cam_fps: float | None = None,
) -> tuple[np.ndarray, list[tuple[float, np.ndarray]]]:
    """(state (n, STATE_DIM), [(video time since the episode's start s, RGB frame)]); the
    camera pans right by ``pan_px_per_unit`` × joint 0 (a camera on the arm). The state's
    scale: ``state_width`` (the dataset's first camera's width; default this one's). A camera
    at ``cam_fps`` (default ``fps``) films n / fps s in its own frames (the faults' too)."""
    bg, obj = scene
    # px: the object crosses the view
    amplitude = (state_width or shape[1]) * (0.45 + 0.1 * ((e * 7) % 3))
    state = trajectory(n, fps, faults.idle_head_s.get(e, 0.0), amplitude, seed + e, strokes)
    lag = faults.lag_ms.get(e, 0.0) / 1000
    shift = faults.bump[1] if faults.bump is not None and e >= faults.bump[0] else 0
    drift = faults.drift_ms.get(e, 0.0) / 1000
    m = math.ceil(n * (cf := cam_fps or fps) / fps - 1e-6)  # the camera's frames
    f0, k = faults.frozen.get(e, (m, 0))
    d0, dn = faults.dropped.get(e, (m, 0))
    frames: list[tuple[float, np.ndarray]] = []
    img = None
    for i in range(m):
        if d0 <= i < d0 + dn:
            continue  # lost: a gap in the video's times
        if not (f0 <= i < f0 + k) or img is None:
            seen = state_at(state, fps, i / cf - lag)
            knocked = faults.knock is not None and (
                e > faults.knock[0] or (e == faults.knock[0] and i >= faults.knock[1])
            )
            at = shift + pan_px_per_unit * float(seen[0]) + (faults.knock[2] if knocked else 0)
            img = render(bg, obj, seen, shape, at)
            if e in faults.blurred:
                img = cv2.GaussianBlur(img, (0, 0), 2.5)
            if e in faults.overexposed:
                img = np.clip(img.astype(np.float32) * 2.2 + 70, 0, 255).astype(np.uint8)
        t = i / cf + drift * i / max(m - 1, 1)
        frames.append((t, img))
    return state, frames


def _features(
    cameras: tuple[str, ...],
    shapes: dict[str, tuple],
    codec: str,
    rates: dict[str, float],
    images: tuple = (),
) -> dict:
    def video_info(shape: tuple, fps: float) -> dict:
        return {
            "video.height": shape[0],
            "video.width": shape[1],
            "video.codec": CODECS[codec],
            "video.pix_fmt": "yuv420p",
            "video.is_depth_map": False,
            "video.fps": fps,
            "video.channels": 3,
            "has_audio": False,
        }

    names = [f"joint_{j}" for j in range(STATE_DIM)]
    feats: dict[str, Any] = {
        cam: {
            "dtype": "image" if cam in images else "video",
            "shape": [shapes[cam][0], shapes[cam][1], 3],
            "names": ["height", "width", "channels"],
        }
        | ({} if cam in images else {"info": video_info(shapes[cam], rates[cam])})
        for cam in cameras
    }
    feats |= {
        "observation.state": {"dtype": "float32", "shape": [STATE_DIM], "names": names},
        "action": {"dtype": "float32", "shape": [STATE_DIM], "names": names},
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
        "frame_index": {"dtype": "int64", "shape": [1], "names": None},
        "episode_index": {"dtype": "int64", "shape": [1], "names": None},
        "index": {"dtype": "int64", "shape": [1], "names": None},
        "task_index": {"dtype": "int64", "shape": [1], "names": None},
    }
    return feats


def _data_table(e: int, state: np.ndarray, fps: float, first_index: int) -> pa.Table:
    n = len(state)
    action = np.vstack([state[1:], state[-1:]])  # the next pose: the action leads the state
    vec = pa.list_(pa.float32(), STATE_DIM)
    return pa.table(
        {
            "observation.state": pa.array(list(state.astype(np.float32)), type=vec),
            "action": pa.array(list(action.astype(np.float32)), type=vec),
            "timestamp": pa.array((np.arange(n) / fps).astype(np.float32)),
            "frame_index": pa.array(np.arange(n, dtype=np.int64)),
            "episode_index": pa.array(np.full(n, e, dtype=np.int64)),
            "index": pa.array(np.arange(first_index, first_index + n, dtype=np.int64)),
            "task_index": pa.array(np.zeros(n, dtype=np.int64)),
        }
    )


def write_dataset(
    root: str | Path,
    episodes: int = 12,
    version: str = "v3.0",
    codec: str = "libsvtav1",
    fps: float = 30.0,
    shape: tuple[int, int] = (96, 128),
    seconds: tuple[float, float] = (3.0, 4.0),
    faults: Faults = STANDARD_FAULTS,
    cameras: tuple[str, ...] = ("observation.images.front",),
    seed: int = 0,
    image_cameras: tuple[str, ...] = (),
    pan_px_per_unit: float = 0.0,
    strokes: int = 1,
    camera_shapes: dict[str, tuple[int, int]] | None = None,
    camera_fps: dict[str, float] | None = None,
) -> dict[str, Any]:
    """Write a LeRobot dataset at ``root`` (see the module) and return its truth: ``lengths``
    (frames per episode), ``faults``, ``fps``, ``cameras``. Episode lengths are spread evenly
    over ``seconds``; the first camera carries the faults, the others see the clean scene
    (their own, shifted a little). Faults name episodes below ``episodes``. The cameras in
    ``image_cameras`` are stored as LeRobot image features instead of video: one PNG per frame,
    ``images/{key}/episode-{e:06d}/frame-{i:06d}.png``. With ``pan_px_per_unit`` the first
    camera is on the arm: its view pans right by that many px per unit of joint 0 (the object
    crosses up to 0.65 × the width in joint 0's units). ``strokes``: out-and-back motions per
    episode (more strokes: more evidence of a lag). ``camera_shapes``, ``camera_fps``: a
    camera's own (height, width) and rate (its video's and ``video.fps``), where not given."""
    if version not in ("v3.0", "v2.1"):
        raise UserError(f"version must be v3.0 or v2.1, got {version!r}.")
    if codec not in CODECS:
        raise UserError(f"codec must be one of {', '.join(CODECS)}, got {codec!r}.")
    root = Path(root)
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise UserError(f"{root} exists and is not an empty folder: give a new folder.")
    # written into a hidden folder beside it, renamed when whole: a failed or killed write
    # leaves no half dataset under the name (a leftover hidden folder is removed on failure)
    part = root.with_name(f".{root.name}.partial-{os.getpid()}")
    shutil.rmtree(part, ignore_errors=True)
    try:
        truth = _write(
            part,
            episodes,
            version,
            codec,
            fps,
            shape,
            seconds,
            faults,
            cameras,
            seed,
            image_cameras,
            pan_px_per_unit,
            strokes,
            camera_fps or {},
            camera_shapes,
        )
        if root.exists():
            root.rmdir()  # empty: checked above
        part.rename(root)
    except BaseException:
        shutil.rmtree(part, ignore_errors=True)
        raise
    return truth


def _write(
    root: Path,
    episodes: int,
    version: str,
    codec: str,
    fps: float,
    shape: tuple[int, int],
    seconds: tuple[float, float],
    faults: Faults,
    cameras: tuple[str, ...],
    seed: int,
    image_cameras: tuple[str, ...],
    pan_px_per_unit: float,
    strokes: int,
    camera_fps: dict[str, float],
    camera_shapes: dict[str, tuple[int, int]] | None,
) -> dict[str, Any]:
    """:func:`write_dataset` into ``root`` (a new folder)."""
    (root / "meta").mkdir(parents=True, exist_ok=True)
    knock_px = faults.knock[2] if faults.knock is not None else 0
    pan_px = math.ceil(abs(pan_px_per_unit) * 0.66 * shape[1]) + abs(knock_px)
    shapes = {cam: tuple((camera_shapes or {}).get(cam, shape)) for cam in cameras}
    rates = {cam: float(camera_fps.get(cam, fps)) for cam in cameras}
    scenes = {cam: _scene(*shapes[cam], pan_px if c == 0 else 0) for c, cam in enumerate(cameras)}
    span = np.linspace(seconds[0], seconds[1], episodes) if episodes > 1 else [seconds[0]]
    lengths = [round(float(s) * fps) for s in span]
    per_cam: dict[str, list] = {cam: [] for cam in cameras}  # [(state, frames)] per episode
    states = []
    for e, n in enumerate(lengths):
        for c, cam in enumerate(cameras):
            f = faults if c == 0 else Faults()
            sc = scenes[cam]
            sc = sc if c == 0 else (np.roll(sc[0], 5 * c, axis=1), sc[1])
            pan = pan_px_per_unit if c == 0 else 0.0
            state, frames = _episode_frames(
                e, n, fps, shapes[cam], f, sc, seed, pan, strokes, shape[1], rates[cam]
            )
            per_cam[cam].append(frames)
        states.append(state)
    info: dict[str, Any] = {
        "codebase_version": version,
        "robot_type": "synthetic_arm",
        "total_episodes": episodes,
        "total_frames": int(sum(lengths)),
        "total_tasks": 1,
        "chunks_size": 1000,
        "fps": fps,
        "splits": {"train": f"0:{episodes}"},
        "features": _features(cameras, shapes, codec, rates, image_cameras),
    }
    for cam in image_cameras:
        if cam not in per_cam:
            raise UserError(f"image camera {cam!r} is not one of the cameras {cameras}.")
        for e, frames in enumerate(per_cam.pop(cam)):
            folder = root / "images" / cam / f"episode-{e:06d}"
            folder.mkdir(parents=True, exist_ok=True)
            for i, (_, rgb) in enumerate(frames):  # a PNG carries no time: frame i is row i
                cv2.imwrite(str(folder / f"frame-{i:06d}.png"), rgb[..., ::-1])
    if version == "v3.0":
        _write_v3(root, info, lengths, states, per_cam, codec, fps, shapes, rates)
    else:
        _write_v21(root, info, lengths, states, per_cam, codec, fps, shapes, rates)
    return {
        "lengths": lengths,
        "faults": faults,
        "fps": fps,
        "cameras": cameras,
        "version": version,
        "codec": codec,
        "shape": shape,
        "image_cameras": image_cameras,
    }


def _write_v3(root, info, lengths, states, per_cam, codec, fps, shapes, rates) -> None:
    info |= {
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200,
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
    }
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=2))
    tasks = pa.table({"task_index": [0], "__index_level_0__": ["move the cup"]})
    pq.write_table(tasks, root / "meta" / "tasks.parquet")
    data, start = [], 0
    for e, state in enumerate(states):
        data.append(_data_table(e, state, fps, start))
        start += len(state)
    (root / "data" / "chunk-000").mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.concat_tables(data), root / "data" / "chunk-000" / "file-000.parquet")
    windows: dict[str, list[tuple[float, float]]] = {}
    for cam, eps in per_cam.items():
        t0, win, timed = 0.0, [], []
        for frames in eps:
            timed += [(t0 + t, img) for t, img in frames]
            end = t0 + frames[-1][0] + 1 / rates[cam]  # one interval after its last frame
            win.append((t0, end))
            t0 = end
        path = root / "videos" / cam / "chunk-000" / "file-000.mp4"
        encode_file(path, codec, rates[cam], shapes[cam], timed)
        windows[cam] = win
    cols: dict[str, list] = {
        "episode_index": list(range(len(lengths))),
        "tasks": [["move the cup"]] * len(lengths),
        "length": lengths,
        "data/chunk_index": [0] * len(lengths),
        "data/file_index": [0] * len(lengths),
        "dataset_from_index": list(np.cumsum([0, *lengths[:-1]]).tolist()),
        "dataset_to_index": list(np.cumsum(lengths).tolist()),
    }
    for cam, win in windows.items():
        cols[f"videos/{cam}/chunk_index"] = [0] * len(lengths)
        cols[f"videos/{cam}/file_index"] = [0] * len(lengths)
        cols[f"videos/{cam}/from_timestamp"] = [a for a, _ in win]
        cols[f"videos/{cam}/to_timestamp"] = [b for _, b in win]
    cols["meta/episodes/chunk_index"] = [0] * len(lengths)
    cols["meta/episodes/file_index"] = [0] * len(lengths)
    out = root / "meta" / "episodes" / "chunk-000"
    out.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table(cols), out / "file-000.parquet")


def _write_v21(root, info, lengths, states, per_cam, codec, fps, shapes, rates) -> None:
    info |= {
        "total_chunks": 1,
        "total_videos": len(lengths) * len(per_cam),
        "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
        "video_path": "videos/chunk-{episode_chunk:03d}/{video_key}/"
        "episode_{episode_index:06d}.mp4",
    }
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=2))
    lines = [
        json.dumps({"episode_index": e, "tasks": ["move the cup"], "length": n})
        for e, n in enumerate(lengths)
    ]
    (root / "meta" / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    (root / "meta" / "tasks.jsonl").write_text('{"task_index": 0, "task": "move the cup"}\n')
    (root / "data" / "chunk-000").mkdir(parents=True, exist_ok=True)
    start = 0
    for e, state in enumerate(states):
        path = root / "data" / "chunk-000" / f"episode_{e:06d}.parquet"
        pq.write_table(_data_table(e, state, fps, start), path)
        start += len(state)
    for cam, eps in per_cam.items():
        for e, frames in enumerate(eps):
            path = root / "videos" / "chunk-000" / cam / f"episode_{e:06d}.mp4"
            encode_file(path, codec, rates[cam], shapes[cam], frames)


if __name__ == "__main__":  # python -m analysis.dataset.synthetic OUT [v3.0|v2.1] [codec]
    args = sys.argv[1:]
    if not args:
        sys.exit("usage: python -m analysis.dataset.synthetic OUT [v3.0|v2.1] [libsvtav1|libx264]")
    try:
        truth = write_dataset(
            args[0],
            version=args[1] if len(args) > 1 else "v3.0",
            codec=args[2] if len(args) > 2 else "libsvtav1",
        )
    except UserError as exc:  # one line, exit 2, as vdc's commands say it
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    print(
        f"wrote {len(truth['lengths'])} episodes ({truth['version']}, {truth['codec']}) "
        f"to {args[0]}"
    )


def lag_signals(
    rng: np.random.Generator, fps: float, seconds: float, lag_s: float, noise: float
) -> tuple[np.ndarray, np.ndarray]:
    """A robot arm's speed and its camera's motion, the camera ``lag_s`` late: the known truth
    the lag's interval is checked against (``benchmarks/bench_lag_interval.py``). Strokes of
    0.5-1.5 s (``sin²`` bumps of random height, random pauses) on a 1 kHz clock, sampled at
    ``fps`` from a random phase; the camera's motion is the same speed ``lag_s`` later, plus
    Gaussian noise and a frame-to-frame alternation (a key frame every 2 frames), each
    ``noise`` × the peak speed. Returns (state speed, camera motion), each (N,) float64."""
    clock = np.arange(0.0, seconds + 1.0, 1e-3)
    speed = np.zeros_like(clock)
    start = 0.0
    while start < seconds + 1.0:
        length = rng.uniform(0.5, 1.5)
        on = (clock >= start) & (clock < start + length)
        speed[on] += rng.uniform(0.3, 1.0) * np.sin(np.pi * (clock[on] - start) / length) ** 2
        start += length + rng.uniform(0.0, 0.5)
    t = np.arange(0.0, seconds, 1.0 / fps) + rng.uniform(0.0, 1.0 / fps)
    peak = speed.max()
    camera = np.interp(t - lag_s, clock, speed)
    camera += rng.normal(0.0, noise * peak, len(t)) + 0.5 * noise * peak * np.resize(
        [1, -1], len(t)
    )
    return np.interp(t, clock, speed), camera

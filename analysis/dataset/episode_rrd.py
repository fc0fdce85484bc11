"""Each episode of a profiled dataset as a vdc recording (``recordings/episode_NNNNNN.rrd``):
its cameras' video referenced as compressed samples, the measures on its own timelines, its
flags as events, and a blueprint that opens it at its flagged frame.

* **Video.** Each camera's packets of the episode's window, copied from the dataset's file
  without decoding (``rr.VideoStream``: AV1 as stored, H.264/HEVC rewritten from MP4's
  length prefixes to Annex B by FFmpeg's own bitstream filter). A v3.0 window inside a shared
  file is cut at its presentation times; the packets from the key frame before it, which the
  window's first frames need to decode, sit before frame 0 (negative frames and times). A
  recording is thus about the size of its share of the video, never of decoded frames. A
  stream with B-frames (presentation order unlike decoding order) cannot be a ``VideoStream``
  (a sample has one time, its presentation's): its window's whole groups of pictures are
  copied, still undecoded, into an MP4 of their own, logged as ``rr.AssetVideo`` with a
  ``rr.VideoFrameReference`` per frame. PNG image features are left out with a note in the
  recording's description (a frame sequence is not a video).
* **Measures.** Every numeric column of the per-frame table under
  ``/dataset/<camera>/measures/<column>`` (booleans as 0/1) on ``frame`` (the camera's decoded
  frame index, as in ``frames.parquet``) and ``time`` (s from the episode's start). The first
  camera's repeats and drops are also the recording's frame timing (``/robot/camera/timing``),
  so ``catalog query`` builds its ``frames`` table as for any video recording.
* **Properties.** ``run`` (source ``dataset``, the dataset, its version, the episode), ``video``
  (the first camera's file and window) and ``episode`` (flags, flag count, flagged frame).
"""

from __future__ import annotations

import dataclasses
import io
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import av
import numpy as np
import polars as pl
import rerun as rr

from analysis.dataset.window import EDGE_S
from vdc.blueprints import dataset_blueprint
from vdc.recording import (
    APP_ID,
    DESCRIPTION,
    FRAME_TIMELINE,
    FRAME_TIMING,
    TIME_TIMELINE,
    dataset_measure_path,
    dataset_video_path,
    event_path,
)

# the codecs a VideoStream carries, by PyAV's decoder name; H.264/HEVC need Annex B
_CODECS = {
    "h264": (rr.components.VideoCodec.H264, "h264_mp4toannexb"),
    "hevc": (rr.components.VideoCodec.H265, "hevc_mp4toannexb"),
    "av1": (rr.components.VideoCodec.AV1, None),
    "libdav1d": (rr.components.VideoCodec.AV1, None),
    "libaom-av1": (rr.components.VideoCodec.AV1, None),
}
EPISODE_RECORDINGS = "recordings"  # the folder of ``out`` holding the episodes' recordings


@dataclasses.dataclass(frozen=True)
class VideoSamples:
    """A camera's packets over an episode's window: ``samples`` (bytes each), ``t_s`` (N,)
    float64 s from the window's start (negative: the lead-in from the key frame before it),
    ``key`` (N,) bool, ``codec`` (a ``rr.components.VideoCodec``)."""

    samples: list[bytes]
    t_s: np.ndarray
    key: np.ndarray
    codec: Any


def episode_recording_id(root: Path, episode: int) -> str:
    """The episode's recording id (the catalog's segment id): the dataset folder's name and
    the episode, e.g. ``pick_place-episode_000003``."""
    return f"{re.sub(r'[^A-Za-z0-9_.-]', '_', root.resolve().name)}-episode_{episode:06d}"


def video_samples(path: str, from_s: float, to_s: float | None) -> VideoSamples:
    """The packets of ``path``'s video stream presented in [from_s, to_s), with those from the
    key frame before from_s, in decoding order, undecoded. ValueError for a codec a
    ``VideoStream`` cannot carry or a stream with B-frames."""
    with av.open(path) as container:
        stream = container.streams.video[0]
        name = stream.codec_context.name
        if name not in _CODECS:
            raise ValueError(f"codec {name} cannot be referenced (AV1, H.264 and HEVC can)")
        codec, bsf_name = _CODECS[name]
        bsf = av.bitstream.BitStreamFilterContext(bsf_name, stream) if bsf_name else None
        tb = float(stream.time_base)
        if from_s > 0:  # the key frame at or before the window
            container.seek(int(from_s / tb), stream=stream, backward=True)
        samples, times, keys = [], [], []
        last = -np.inf
        for packet in container.demux(stream):
            if packet.pts is None or not packet.size:
                continue
            t = packet.pts * tb
            if to_s is not None and t >= to_s - EDGE_S:
                break
            if t <= last:
                raise ReorderedFrames("the stream has B-frames (a VideoStream cannot carry them)")
            last = t
            out = bsf.filter(packet) if bsf is not None else [packet]
            for p in out:
                samples.append(bytes(p))
                times.append(t - from_s)
                keys.append(bool(packet.is_keyframe))
    # the lead-in starts at the key frame the seek found: anything before one is useless
    t_arr, key = np.asarray(times, dtype=np.float64), np.asarray(keys, dtype=bool)
    first_key = int(np.argmax(key)) if key.any() else 0
    return VideoSamples(samples[first_key:], t_arr[first_key:], key[first_key:], codec)


class ReorderedFrames(ValueError):
    """A stream with B-frames: its decoding order is not its presentation order."""


def window_asset(
    path: str, from_s: float, to_s: float | None, t_frames: np.ndarray
) -> tuple[bytes, np.ndarray]:
    """The window of ``path`` as an MP4 of its own, its packets copied undecoded from the key
    frame at or before ``from_s`` to the first key frame at or after ``to_s`` (whole groups of
    pictures: a B-frame needs the frames after it), and the timestamp (ns, as Rerun reads the
    MP4: ``AssetVideo.read_frame_timestamps_nanos``) of each frame at ``t_frames`` (N,) s from
    the window's start, int64. ValueError where the two readings disagree."""
    buf = io.BytesIO()
    pts: list[int] = []
    with av.open(path) as src:
        stream = src.streams.video[0]
        tb = float(stream.time_base)
        if from_s > 0:
            src.seek(int(from_s / tb), stream=stream, backward=True)
        with av.open(buf, "w", format="mp4") as out:
            copy = out.add_stream_from_template(stream)
            for packet in src.demux(stream):
                if packet.pts is None or not packet.size or not (pts or packet.is_keyframe):
                    continue
                if packet.is_keyframe and to_s is not None and packet.pts * tb >= to_s - EDGE_S:
                    break
                pts.append(packet.pts)
                packet.stream = copy
                out.mux(packet)
    data = buf.getvalue()
    ns = rr.AssetVideo(contents=data, media_type="video/mp4").read_frame_timestamps_nanos()
    shown = np.sort(np.asarray(pts, dtype=np.int64)) * tb - from_s  # presentation order
    if len(ns) != len(shown):
        raise ValueError(f"the window's MP4 holds {len(ns)} frames for {len(shown)} packets")
    k = np.clip(np.searchsorted(shown, np.asarray(t_frames) - EDGE_S), 0, len(ns) - 1)
    return data, np.asarray(ns, dtype=np.int64)[k]


def _frames_of(t_video: np.ndarray, t_frames: np.ndarray) -> np.ndarray:
    """Each sample's frame index: the decoded frame at its time (the measures' ``frame``),
    counted back from frame 0 for the lead-in before the window."""
    idx = np.searchsorted(t_frames, t_video - EDGE_S)
    lead = t_video < -EDGE_S
    idx[lead] = np.arange(-int(lead.sum()), 0)
    return idx.astype(np.int64)


def _index(frame: np.ndarray, t_s: np.ndarray) -> list[rr.TimeColumn]:
    return [
        rr.TimeColumn(FRAME_TIMELINE, sequence=frame),
        rr.TimeColumn(TIME_TIMELINE, duration=(np.round(t_s * 1e9)).astype("timedelta64[ns]")),
    ]


def measure_columns(frames: pl.DataFrame) -> list[str]:
    """The per-frame table's columns logged as measures: every numeric or boolean one but the
    index (frame, t_s) and the keys (episode_index, camera)."""
    skip = {"frame", "t_s", "episode_index", "camera"}
    return [
        c
        for c, dt in frames.schema.items()
        if c not in skip and (dt.is_numeric() or dt == pl.Boolean)
    ]


def write_episode(
    path: Path,
    root: Path,
    version: str,
    episode: int,
    rows: Sequence[dict[str, Any]],
    frames: dict[str, pl.DataFrame],
    flagged: tuple[str, str, int] | None,
) -> Path:
    """Write episode ``episode``'s recording to ``path`` (via ``<name>.partial``, renamed when
    whole). ``rows``: the episode's rows of the episodes table, one per camera (the first is
    the recording's main camera); ``frames``: each camera's per-frame table (sorted by frame);
    ``flagged``: (flag, camera, frame) that the blueprint opens at, or None."""
    rid = episode_recording_id(root, episode)
    cameras = [r["camera"] for r in rows]
    measures = measure_columns(next(iter(frames.values())))
    bp = dataset_blueprint(cameras, flagged[1:] if flagged else None)
    tmp = path.with_name(path.name + f".partial-{os.getpid()}")
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APP_ID, recording_id=rid)
    rec.save(str(tmp), default_blueprint=bp)
    notes = []
    try:
        main = rows[0]
        flags = ",".join(sorted({f for r in rows for f in r["flags"].split(",") if f}))
        rec.send_property(
            "run",
            rr.AnyValues(
                source="dataset",
                dataset=str(root),
                version=version,
                episode_index=episode,
                recording_id=rid,
            ),
        )
        rec.send_property(
            "video",
            rr.AnyValues(
                path=main["video_path"],
                camera=main["camera"],
                from_s=main["from_s"],
                to_s=main["to_s"] if main["to_s"] is not None else float("nan"),
            ),
        )
        rec.send_property(
            "episode",
            rr.AnyValues(
                episode_index=episode,
                cameras=",".join(cameras),
                flags=flags,
                flag_count=len([f for f in flags.split(",") if f]),
                flagged_frame=flagged[2] if flagged else -1,
            ),
        )
        for k, r in enumerate(rows):
            cam, fr = r["camera"], frames[r["camera"]]
            frame, t = fr["frame"].to_numpy(), fr["t_s"].to_numpy()
            try:
                _log_video(rec, dataset_video_path(cam), r, frame, t)
            except (ValueError, av.FFmpegError, OSError) as exc:
                notes.append(f"{cam}: video not referenced: {exc}")
            for m in measures:
                if m not in fr.columns:
                    continue
                vals = fr[m].cast(pl.Float64).fill_null(float("nan")).to_numpy()
                rec.send_columns(
                    dataset_measure_path(cam, m),
                    indexes=_index(frame, t),
                    columns=rr.Scalars.columns(scalars=vals),
                )
            if k == 0:  # the main camera's timing: the recording's frames for catalog query
                timing = np.c_[
                    fr["repeat"].cast(pl.Float64).to_numpy(),
                    fr["dropped_before"].cast(pl.Float64).to_numpy(),
                    fr["dt_s"].cast(pl.Float64).fill_null(float("nan")).to_numpy(),
                ]
                rec.send_columns(
                    FRAME_TIMING,
                    indexes=_index(frame, t),
                    columns=rr.Scalars.columns(scalars=timing),
                )
        if flagged:
            flag, cam, f = flagged
            fr = frames[cam]
            t_f = float(fr["t_s"][min(f, len(fr) - 1)])
            at = _index(np.array([f]), np.array([t_f]))
            text = rr.TextLog.columns(text=[f"{flag} ({cam})"], level=["WARN"])
            rec.send_columns(event_path("dataset_flag"), indexes=at, columns=text)
        rec.log(
            DESCRIPTION,
            rr.TextDocument(
                _description(rid, root, episode, rows, flagged, notes), media_type="text/markdown"
            ),
            static=True,
        )
        rec.flush()
        rec.disconnect()
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _log_video(rec: Any, vpath: str, r: dict, frame: np.ndarray, t: np.ndarray) -> None:
    """One camera's video of the episode (``r``: its row) at ``vpath``: its packets as a
    ``VideoStream``, or with B-frames its window's MP4 and a frame reference per frame."""
    try:
        v = video_samples(r["video_path"], r["from_s"], r["to_s"])
    except ReorderedFrames:
        data, ns = window_asset(r["video_path"], r["from_s"], r["to_s"], t)
        rec.log(vpath, rr.AssetVideo(contents=data, media_type="video/mp4"), static=True)
        rec.send_columns(
            vpath, indexes=_index(frame, t), columns=rr.VideoFrameReference.columns_nanos(ns)
        )
        return
    rec.log(vpath, rr.VideoStream(codec=v.codec), static=True)
    columns = rr.VideoStream.columns(sample=v.samples, is_keyframe=v.key)
    rec.send_columns(vpath, indexes=_index(_frames_of(v.t_s, t), v.t_s), columns=columns)


def _description(rid, root, episode, rows, flagged, notes) -> str:
    lines = [
        f"# {rid}",
        "",
        f"Episode {episode} of the LeRobot dataset `{root}`, profiled by `vdc-analyse dataset`.",
        "",
    ]
    for r in rows:
        lines.append(
            f"* **{r['camera']}**: {r['frames_decoded']} frames decoded of "
            f"{r['length']} stated; flags: {r['flags'] or 'none'}"
        )
    if flagged:
        lines += ["", f"Opened at frame {flagged[2]}, where `{flagged[0]}` shows best."]
    lines += [f"* {n}" for n in notes]
    return "\n".join(lines)

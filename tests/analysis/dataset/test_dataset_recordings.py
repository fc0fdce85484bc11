"""``vdc-analyse dataset``'s Rerun dataset out and its resumability: each episode of a LeRobot
v3.0 AV1 dataset (episodes as windows of one shared MP4) becomes a vdc recording whose video is
the file's own packets (the same bytes Rerun's own ``LeRobotReader`` cuts for that episode, and
decodable into exactly the frames measured), whose measures are those of ``frames.parquet`` on
the episode's timeline, which opens at its flagged frame, and which ``catalog query`` reads like
any recording; a run killed with SIGKILL resumes without measuring its finished episodes
again and ends with the tables of a run never interrupted."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import polars as pl
import pytest
import rerun as rr
from polars.testing import assert_frame_equal

from analysis.dataset import DatasetSettings, dataset
from analysis.dataset.episode_rrd import episode_recording_id
from analysis.dataset.flags import first_flags
from analysis.dataset.resume import RESULTS
from analysis.dataset.synthetic import Faults, write_dataset
from analysis.recordings.reader import Recording
from tests.helpers import ROOT, flags, write_h264_dataset
from vdc.blueprints import FLAG_CONTEXT_FRAMES
from vdc.recording import dataset_measure_path, dataset_video_path, event_path

CAM = "observation.images.front"
FROZEN_EPISODE = 1


@pytest.fixture(scope="module")
def profiled(tmp_path_factory):
    d = tmp_path_factory.mktemp("dsout")
    root = d / "arm_v3"
    frozen = Faults(frozen={FROZEN_EPISODE: (12, 10)})
    truth = write_dataset(
        root, episodes=3, version="v3.0", codec="libsvtav1", seconds=(2.0, 2.4), faults=frozen
    )
    res = dataset(root, DatasetSettings(jobs=2, page=False), d / "out")
    return {"root": root, "out": d / "out", "res": res, "truth": truth, "tmp": d}


def _samples(path: Path, entity: str, timeline: str) -> dict[int, bytes]:
    """A VideoStream's samples by their index on ``timeline``, read back from the file.
    (``Recording._batches``: the reader's own walk over a file's record batches.)"""
    out: dict[int, bytes] = {}
    for ent, rb in Recording(path)._batches("/**"):
        col = "VideoStream:sample"
        if ent != entity or col not in rb.schema.names:
            continue
        index, blobs = rb.column(timeline).to_pylist(), rb.column(col).to_pylist()
        for i, blob in zip(index, blobs, strict=True):
            if blob:
                out[int(i)] = bytes(blob[0])
    return out


def test_each_episode_is_a_recording_with_its_video_referenced(profiled) -> None:
    out, res, root = profiled["out"], profiled["res"], profiled["root"]
    eps = res.episodes
    rrds = sorted((out / "recordings").glob("*.rrd"))
    assert [p.name for p in rrds] == [f"episode_{e:06d}.rrd" for e in range(3)]
    assert all(p in res.paths for p in rrds)
    shape = profiled["truth"]["shape"]
    for e, path in enumerate(rrds):
        row = eps.filter(pl.col("episode_index") == e).row(0, named=True)
        rec = Recording(path)
        assert rec.recording_id == episode_recording_id(root, e)
        mine = _samples(path, dataset_video_path(CAM), "frame")
        window = {f: s for f, s in mine.items() if f >= 0}
        assert sorted(window) == list(range(row["frames_decoded"]))
        # the truth: Rerun's own LeRobot importer cuts the same packets for this episode
        from rerun.experimental import LeRobotReader

        ref_file = profiled["tmp"] / f"lerobot_{e}.rrd"
        LeRobotReader(str(root)).stream(e).write_rrd(
            str(ref_file), application_id="ref", recording_id=f"episode_{e}"
        )
        ref = _samples(ref_file, f"/{CAM}", "frame_index")
        assert window == ref
        # the samples decode, from the lead-in's key frame on, into every frame measured
        dec = av.CodecContext.create("libdav1d", "r")
        frames = [f for _, s in sorted(mine.items()) for f in dec.decode(av.Packet(s))]
        frames += dec.decode(None)
        assert len(frames) == len(mine) and (frames[0].height, frames[0].width) == shape
        # referenced, not decoded: the recording is far smaller than the frames it shows
        # (8-bit RGB; measured 8x smaller on these 2 s episodes, where the measures'
        # fixed cost of about 80 kB weighs most; 5x leaves room for the encoder's variation)
        decoded_bytes = row["frames_decoded"] * shape[0] * shape[1] * 3
        assert path.stat().st_size * 5 < decoded_bytes
        assert sum(map(len, mine.values())) <= path.stat().st_size


def test_h264_episodes_of_two_cameras_are_self_contained_streams(tmp_path: Path) -> None:
    """v2.1, H.264 (MP4's length-prefixed samples rewritten to Annex B), two cameras: each
    camera's samples decode on their own, with no container's extradata, into exactly the
    frames the file gives, pixel for pixel."""
    root = tmp_path / "v21"
    wrist = "observation.images.wrist"
    write_h264_dataset(root, 2, (1.0, 1.0), version="v2.1", cameras=(CAM, wrist))
    res = dataset(root, DatasetSettings(jobs=1, page=False), tmp_path / "out")
    for e in range(2):
        path = tmp_path / "out" / "recordings" / f"episode_{e:06d}.rrd"
        assert Recording(path).properties()["episode"]["cameras"] == f"{CAM},{wrist}"
        for cam in (CAM, wrist):
            row = res.episodes.filter((pl.col("episode_index") == e) & (pl.col("camera") == cam))
            samples = _samples(path, dataset_video_path(cam), "frame")
            assert sorted(samples) == list(range(row["frames_decoded"][0]))  # no lead-in
            dec = av.CodecContext.create("h264", "r")  # no extradata: Annex B carries it
            got = [f for _, s in sorted(samples.items()) for f in dec.decode(av.Packet(s))]
            got += dec.decode(None)
            with av.open(row["video_path"][0]) as c:
                want = list(c.decode(video=0))
            assert len(got) == len(want) == row["frames_decoded"][0]
            for a, b in zip(got, want, strict=True):
                assert np.array_equal(a.to_ndarray(format="gray"), b.to_ndarray(format="gray"))


def _asset(path: Path, entity: str) -> tuple[bytes, dict[int, int]]:
    """An AssetVideo's MP4 and its frame references (frame index -> timestamp, ns)."""
    blob, refs = b"", {}
    for ent, rb in Recording(path)._batches("/**"):
        if ent != entity:
            continue
        if "AssetVideo:blob" in rb.schema.names:
            blob = bytes(rb.column("AssetVideo:blob").to_pylist()[0][0])
        if "VideoFrameReference:timestamp" in rb.schema.names:
            ts = rb.column("VideoFrameReference:timestamp").to_pylist()
            frame = rb.column("frame").to_pylist()
            refs |= {int(i): int(t[0]) for i, t in zip(frame, ts, strict=True)}
    return blob, refs


def test_b_frame_episodes_reference_their_window_as_an_mp4(tmp_path: Path) -> None:
    """H.264 with B-frames in a shared v3.0 file (decoding order unlike presentation order: no
    VideoStream): each episode's recording holds its window's packets as an MP4 of its own,
    undecoded and smaller than the file, and each decoded frame's reference shows that very
    frame, pixel for pixel as decoded from the dataset's file."""
    root = tmp_path / "bf"
    write_dataset(
        root,
        episodes=3,
        version="v3.0",
        codec="libx264-bframes",
        seconds=(1.0, 1.4),
        faults=Faults(),
    )
    res = dataset(root, DatasetSettings(jobs=1, page=False), tmp_path / "out")
    video = root / "videos" / CAM / "chunk-000" / "file-000.mp4"
    with av.open(str(video)) as c:  # the truth: the file decoded, by presentation time
        pts = [p.pts for p in c.demux(video=0) if p.pts is not None]
    with av.open(str(video)) as c:
        truth = {round(f.time * 1000): f.to_ndarray(format="gray") for f in c.decode(video=0)}
    assert pts != sorted(pts)  # the file's packets are out of presentation order: B-frames
    for r in res.episodes.iter_rows(named=True):
        path = tmp_path / "out" / "recordings" / f"episode_{r['episode_index']:06d}.rrd"
        blob, refs = _asset(path, dataset_video_path(CAM))
        assert 0 < len(blob) < video.stat().st_size
        assert sorted(refs) == list(range(r["frames_decoded"]))
        shown = rr.AssetVideo(contents=blob, media_type="video/mp4").read_frame_timestamps_nanos()
        with av.open(io.BytesIO(blob)) as c:  # the MP4's frames, in presentation order
            frames = sorted(c.decode(video=0), key=lambda f: f.pts)
        assert len(frames) == len(shown)
        at = {int(t): f.to_ndarray(format="gray") for t, f in zip(shown, frames, strict=True)}
        for i, t_ns in refs.items():
            want = truth[round((r["from_s"] + i / 30.0) * 1000)]
            assert np.array_equal(at[t_ns], want), (r["episode_index"], i)


def test_the_measures_are_on_the_episode_timeline_and_it_opens_at_its_flag(profiled) -> None:
    out, res = profiled["out"], profiled["res"]
    frames = pl.read_parquet(out / "frames.parquet")
    for e in range(3):
        fr = frames.filter(pl.col("episode_index") == e).sort("frame")
        sig = Recording(out / "recordings" / f"episode_{e:06d}.rrd").signals()
        for m in ("mafd", "si_p910", "ti_p910", "sharpness", "change_max", "frozen"):
            f, t, v = sig[dataset_measure_path(CAM, m)]
            assert np.array_equal(f, fr["frame"].to_numpy())
            # times: nanoseconds on the recording's duration timeline (exact to 1 ns)
            np.testing.assert_allclose(t, fr["t_s"].to_numpy(), rtol=0, atol=1e-9)
            want = fr[m].cast(pl.Float64).to_numpy()
            assert np.array_equal(v[:, 0], want, equal_nan=True), m
    # the flagged episode opens where its flag shows: the property and the event agree
    eps = res.episodes
    flag, frame = first_flags(eps, frames)[(FROZEN_EPISODE, CAM)]
    assert flag == "frozen"
    path = out / "recordings" / f"episode_{FROZEN_EPISODE:06d}.rrd"
    props = Recording(path).properties()
    assert props["episode"]["flags"] == "frozen" and props["episode"]["flagged_frame"] == frame
    assert props["run"]["source"] == "dataset"
    # the injected freeze starts at frame 12: the flagged frame is at it (within a frame: the
    # run's first frozen frame passes only the one-interval test, counted back in)
    assert abs(frame - 12) <= 1
    events = {e: rb for e, rb in Recording(path)._batches("/**") if e == event_path("dataset_flag")}
    assert events and events[event_path("dataset_flag")].column("frame").to_pylist() == [frame]
    clean = Recording(out / "recordings" / "episode_000000.rrd").properties()["episode"]
    assert clean["flag_count"] == 0 and clean["flagged_frame"] == -1
    # its blueprint (stored in the file beside the recording) loops over the flagged frame
    panel = _time_panel(path)
    assert panel["TimePanelBlueprint:timeline"] == ["frame"]
    sel = panel["TimePanelBlueprint:time_selection"][0]
    assert sel["min"] < frame < sel["max"]
    assert (sel["min"], sel["max"]) == (
        max(0, frame - FLAG_CONTEXT_FRAMES),
        frame + FLAG_CONTEXT_FRAMES,
    )
    assert "TimePanelBlueprint:time_selection" not in _time_panel(
        out / "recordings" / "episode_000000.rrd"
    )


def _time_panel(path: Path) -> dict:
    """The time panel's fields in the blueprint an ``.rrd`` carries."""
    import rerun as rr

    reader = rr.chunk.RrdReader(str(path))
    fields: dict = {}
    for ch in reader.stream(store=reader.blueprints()[0]).filter(content="/time_panel"):
        fields |= {k: v for k, v in ch.to_record_batch().to_pylist()[0].items() if ":" in k}
    return fields


def test_catalog_query_reads_the_episodes(profiled) -> None:
    from vdc.catalog import query

    out, root = profiled["out"], profiled["root"]
    frames = pl.read_parquet(out / "frames.parquet")
    res = query(out)
    ids = sorted(res["frames"]["recording_id"].unique().to_list())
    assert ids == [episode_recording_id(root, e) for e in range(3)]
    for e in range(3):
        fr = frames.filter(pl.col("episode_index") == e).sort("frame")
        got = res["frames"].filter(pl.col("recording_id") == episode_recording_id(root, e))
        assert got["frame"].to_list() == fr["frame"].to_list()
        assert got["repeat"].to_list() == fr["repeat"].to_list()
        m = res["measures"].filter(pl.col("recording_id") == episode_recording_id(root, e))
        assert m["camera"].unique().to_list() == [CAM]
        assert np.array_equal(m["mafd"].to_numpy(), fr["mafd"].to_numpy(), equal_nan=True)
    flagged = query(out, where={"flags": "frozen"})
    assert flagged["frames"]["recording_id"].unique().to_list() == [
        episode_recording_id(root, FROZEN_EPISODE)
    ]


def test_a_killed_run_resumes_without_measuring_finished_episodes(tmp_path: Path) -> None:
    # 20 episodes: the kill must come while some are left, whatever the machine's load (with
    # 6, a test process descheduled for a second once found all of them finished), and the
    # run is frozen the moment 2 are seen, so none finishes between the count and the kill
    n = 20
    root = tmp_path / "arm"
    write_dataset(
        root, episodes=n, version="v3.0", codec="libx264", seconds=(1.5, 1.5), faults=Faults()
    )
    out = tmp_path / "out"
    results = out / RESULTS
    cmd = [
        sys.executable,
        "-m",
        "analysis",
        "dataset",
        str(root),
        *flags("--jobs 1 --no-page", out=out),
    ]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        while proc.poll() is None and len(list(results.glob("*.pkl"))) < 2:
            try:
                proc.wait(timeout=0.02)
            except subprocess.TimeoutExpired:
                pass
        os.killpg(proc.pid, signal.SIGSTOP)  # frozen: no episode finishes after the count
        os.killpg(proc.pid, signal.SIGKILL)  # the command and its pool's workers
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read() if proc.stderr else ""
    kept = {p: p.stat().st_mtime_ns for p in results.glob("*.pkl")}
    assert 2 <= len(kept) < n, f"{len(kept)} of {n} episodes written before the kill"
    assert not (out / "episodes.parquet").exists()  # nothing published half
    resumed = dataset(root, DatasetSettings(jobs=2, page=False), out)
    assert resumed.reused == len(kept)  # every finished episode read back, none measured again
    assert all(p.stat().st_mtime_ns == t for p, t in kept.items())
    assert len(list(results.glob("*.pkl"))) == n and not list(results.glob("*.partial*"))
    fresh = dataset(root, DatasetSettings(jobs=2, page=False), tmp_path / "fresh")
    assert fresh.reused == 0
    for name in ("episodes", "frames"):
        a = pl.read_parquet(out / f"{name}.parquet")
        b = pl.read_parquet(tmp_path / "fresh" / f"{name}.parquet")
        assert_frame_equal(a, b)
    # a changed setting is measured afresh, not read back
    again = dataset(
        root,
        DatasetSettings(jobs=1, page=False, recordings=False, episodes="0", repeat_tol=0.25),
        out,
    )
    assert again.reused == 0 and again.episodes.height == 1
    # one result per episode kept: episode 0's older one removed, the others' left as they were
    assert len(list(results.glob("episode_000000.*.pkl"))) == 1
    assert len(list(results.glob("*.pkl"))) == n

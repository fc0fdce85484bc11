"""``vdc-analyse dataset`` on the other layouts and on bad input: a LeRobot v2.1 dataset (a video
per episode, H.264, two cameras), a v3.0 one with H.264, and copies of them broken one way each.
Every unreadable file is one line naming it and its episode (exit 2), and every other episode
is still profiled."""

from __future__ import annotations

import json
import shutil

import av
import numpy as np
import pyarrow.parquet as pq
import pytest

from analysis.dataset import DatasetSettings, dataset
from analysis.dataset.synthetic import Faults, write_dataset
from analysis.dataset.window import WindowReader
from tests.helpers import assert_one_line_error, write_h264_dataset
from tests.in_process import run_in_process
from vdc.frame_batches import FrameBatcher

FRONT, WRIST = "observation.images.front", "observation.images.wrist"
FAULTS = Faults(frozen={1: (12, 10)}, dropped={2: (30, 4)})


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("layouts")
    v21 = d / "v21"
    write_h264_dataset(v21, 4, (3.0, 3.3), version="v2.1", faults=FAULTS, cameras=(FRONT, WRIST))
    v3 = d / "v3"
    write_dataset(
        v3, episodes=3, version="v3.0", codec="libx264", seconds=(2.0, 2.0), faults=Faults()
    )
    return {"v21": v21, "v3": v3, "tmp": d}


def _copy(made, name: str, to: str):
    dst = made["tmp"] / to
    shutil.copytree(made[name], dst)
    return dst


def _run(root, out):
    return dataset(root, DatasetSettings(jobs=2, page=False), out)


def test_v21_h264_two_cameras(made) -> None:
    res = _run(made["v21"], made["tmp"] / "out_v21")
    assert res.problems == [] and res.exit_status == 0
    flags = {
        (r["episode_index"], r["camera"]): r["flags"] for r in res.episodes.iter_rows(named=True)
    }
    assert len(flags) == 8  # 4 episodes x 2 cameras
    expected = {(1, FRONT): "frozen", (2, FRONT): "dropped"}
    assert {k: v for k, v in flags.items() if v} == expected
    row = res.episodes.filter(
        (res.episodes["episode_index"] == 2) & (res.episodes["camera"] == FRONT)
    )
    assert row["dropped"][0] == 4 and row["frames_decoded"][0] + 4 == row["length"][0]


def test_no_info_json_and_unknown_version_are_one_line(made) -> None:
    bad = _copy(made, "v3", "no_info")
    (bad / "meta" / "info.json").unlink()
    proc = run_in_process("analysis", "dataset", str(bad), "--out", str(made["tmp"] / "o1"))
    assert_one_line_error(proc, "meta/info.json", "not a LeRobot dataset")
    bad = _copy(made, "v3", "v9")
    info = json.loads((bad / "meta" / "info.json").read_text())
    (bad / "meta" / "info.json").write_text(json.dumps(info | {"codebase_version": "v9.9"}))
    proc = run_in_process("analysis", "dataset", str(bad), "--out", str(made["tmp"] / "o2"))
    assert_one_line_error(proc, "info.json", "'v9.9'", "v3.0")


def test_a_window_past_its_file_is_named_and_the_others_profiled(made) -> None:
    bad = _copy(made, "v3", "past")
    index = bad / "meta" / "episodes" / "chunk-000" / "file-000.parquet"
    t = pq.read_table(index).to_pydict()
    t[f"videos/{FRONT}/to_timestamp"][2] += 5.0  # five seconds past the shared file's end
    import pyarrow as pa

    pq.write_table(pa.table(t), index)
    out = made["tmp"] / "o3"
    proc = run_in_process("analysis", "dataset", str(bad), "--out", str(out))
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "file-000.mp4 (episode 2)" in errors[0], proc.stderr
    assert "past the file's end" in errors[0]
    assert "Traceback" not in proc.stderr
    eps = pq.read_table(out / "episodes.parquet").to_pydict()
    assert sorted(eps["episode_index"]) == [0, 1]


def test_missing_corrupt_and_cut_videos_and_a_corrupt_parquet(made) -> None:
    bad = _copy(made, "v21", "broken")
    videos = bad / "videos" / "chunk-000"
    (videos / FRONT / "episode_000001.mp4").unlink()  # missing
    (videos / WRIST / "episode_000002.mp4").write_bytes(b"\x00not a video" * 100)  # corrupt
    cut = videos / FRONT / "episode_000003.mp4"
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 3])  # cut short
    (bad / "data" / "chunk-000" / "episode_000000.parquet").write_bytes(b"PAR1 garbage")
    res = _run(bad, made["tmp"] / "o4")
    assert res.exit_status == 2
    lines = res.problems
    assert len(lines) == 4, lines  # one per unreadable file and episode
    assert any("episode_000000.parquet (episode 0)" in ln and "Parquet" in ln for ln in lines)
    assert any("episode_000001.mp4 (episode 1)" in ln and "no such file" in ln for ln in lines)
    assert any("episode_000002.mp4 (episode 2)" in ln for ln in lines)
    assert any("episode_000003.mp4 (episode 3)" in ln for ln in lines)
    done = {(r["episode_index"], r["camera"]) for r in res.episodes.iter_rows(named=True)}
    # the others are profiled: episode 1's wrist camera, 2's front, 3's wrist
    assert done == {(1, WRIST), (2, FRONT), (3, WRIST)}
    assert pq.read_table(res.files.problems).num_rows == 4


def test_an_untagged_window_reopened_gives_the_values_of_both_ranges_at_once(tmp_path) -> None:
    """An H.264 window whose colour range is not tagged and whose luma leaves the limited
    range only in its second batch: measured with a reader that can reopen the window (the
    frames before are read again in full range) it gives the same SI/TI, bit for bit, as the
    meter that keeps a full-range alternative on every frame, including the corrections of
    the earlier batch."""
    path = tmp_path / "untagged.mp4"
    rng = np.random.default_rng(0)
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30, options={"bf": "0", "g": "2"})
        s.width, s.height, s.pix_fmt = 64, 64, "yuv420p"
        for i in range(200):
            y = rng.integers(60, 180, (64, 64), dtype=np.uint8)
            if i >= 165:  # white: past the limited range's 235, in the window's second batch
                y[20:40, 20:40] = 255
            frame = av.VideoFrame.from_ndarray(np.dstack([y, y, y]), format="rgb24")
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode():
            c.mux(p)

    def window() -> WindowReader:
        return WindowReader(str(path), 1.0, 6.5, 30.0)  # frames 30..194

    def measured(reopen) -> tuple[np.ndarray, np.ndarray, bool]:
        reader = window()
        assert reader.info.get("color_range_tag") is None  # untagged: the range is detected
        b = FrameBatcher(reader, None, 30.0, metrics=("si_p910", "ti_p910"), reopen=reopen)
        rows = []
        while (batch := b.next_batch()) is not None:
            rows.append(batch.native_metrics)
        late, left = b.p910_late_corrections(), b.meter.left_limited_at
        reader.close()
        return np.concatenate(rows), late, left

    got, got_late, left = measured(window)
    want, want_late, _ = measured(None)
    assert left >= 128  # the luma left the limited range in the second batch
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(got_late, want_late, equal_nan=True) and len(got_late) == left


def test_a_deadlocked_encoder_is_abandoned_and_the_file_encoded_again(
    tmp_path, monkeypatch, capsys
):
    """SVT-AV1 once deadlocked in the suite (every thread waiting, no CPU, for ever) while the
    test dataset was written. The encoder's first attempt is made to hang here: the file is
    encoded again and holds every frame; three hangs end in one clear error."""
    import threading

    from analysis.dataset import synthetic_video
    from vdc.errors import UserError

    real_add, hangs, release = synthetic_video._Encoder.add, [1], threading.Event()

    def add(self, t_s, rgb):
        if hangs[0] > 0 and str(self.container.name).endswith("attempt0.mp4"):
            release.wait()  # blocks as the deadlocked encoder did
        real_add(self, t_s, rgb)

    monkeypatch.setattr(synthetic_video._Encoder, "add", add)
    frames = [(k / 30, np.full((48, 64, 3), 8 * k, np.uint8)) for k in range(12)]
    path = tmp_path / "v.mp4"
    try:
        synthetic_video.encode_file(path, "libx264", 30.0, (48, 64), frames, stall_s=1.0)
        assert "no progress for 1 s on v.mp4" in capsys.readouterr().err
        with av.open(str(path)) as c:
            assert sum(1 for _ in c.decode(video=0)) == len(frames)
        hangs[0] = 3
        monkeypatch.setattr(synthetic_video._Encoder, "add", lambda self, t, rgb: release.wait())
        with pytest.raises(UserError, match="deadlocked three times"):
            synthetic_video.encode_file(
                tmp_path / "w.mp4", "libx264", 30.0, (48, 64), frames, stall_s=0.5
            )
    finally:
        release.set()  # the abandoned threads finish and close their files


@pytest.mark.parametrize("version", ["v3.0", "v2.1"])
def test_image_features_stored_as_png_frames_are_measured(tmp_path, version: str) -> None:
    """LeRobot's image features (one PNG per frame, images/{key}/episode-*/frame-*.png, no
    video) are read as image sequences at the dataset's fps: every frame of every episode
    measured, and a frozen run in the PNGs flagged as in a video."""
    root = tmp_path / "png"
    truth = write_h264_dataset(
        root,
        3,
        (2.0, 2.2),
        version=version,
        faults=Faults(frozen={1: (12, 10)}),
        cameras=(FRONT, WRIST),
        image_cameras=(FRONT,),
    )
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["features"][FRONT]["dtype"] == "image" and not (root / "videos" / FRONT).exists()
    assert (
        len(list((root / "images" / FRONT / "episode-000001").glob("frame-*.png")))
        == (truth["lengths"][1])
    )
    res = _run(root, tmp_path / "out")
    assert res.problems == [] and res.exit_status == 0
    rows = {(r["episode_index"], r["camera"]): r for r in res.episodes.iter_rows(named=True)}
    assert len(rows) == 6  # 3 episodes x 2 cameras, the PNG one among them
    for e, n in enumerate(truth["lengths"]):
        assert rows[(e, FRONT)]["frames_decoded"] == n  # every PNG, once
    flagged = {k: r["flags"] for k, r in rows.items() if r["flags"]}
    assert flagged == {(1, FRONT): "frozen"}

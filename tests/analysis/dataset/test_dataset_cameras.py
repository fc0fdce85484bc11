"""``vdc-analyse dataset`` on cameras that move with the robot, flags on evidence, and the
v2.1 / H.264 example's idle head and lag: datasets written by
``analysis.dataset.synthetic`` in the exact layout, with known truths."""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys

import pytest

from analysis.dataset import DatasetSettings, dataset
from analysis.dataset.flags import FLAGS
from analysis.dataset.page import number
from analysis.dataset.synthetic import Faults, write_dataset
from tests.helpers import assert_one_line_error, write_h264_dataset
from tests.in_process import run_in_process
from vdc.errors import UserError
from vdc.executors import Feedback

KNOCK = (5, 60, 25)  # episode 5's camera knocked 25 px at its frame 60


@pytest.fixture(scope="module")
def panning(tmp_path_factory):
    """Six episodes whose camera is on the arm: its view pans 1 px per unit of joint 0 (up to
    80 px over an episode), and a knock of 25 px at frame 60 of the last."""
    root = tmp_path_factory.mktemp("arm") / "ds"
    write_dataset(
        root, episodes=6, codec="libx264", pan_px_per_unit=1.0, faults=Faults(knock=KNOCK)
    )
    out = root.parent / "out"
    said: list[str] = []
    res = dataset(
        root,
        DatasetSettings(jobs=2, page=False, recordings=False),
        out,
        feedback=Feedback(log=said.append),
    )
    return root, out, res, said


def _rows(res) -> dict[int, dict]:
    return {r["episode_index"]: r for r in res.episodes.iter_rows(named=True)}


def test_a_camera_on_the_arm_flags_no_clean_episode_and_finds_the_knock_at_its_frame(
    panning,
) -> None:
    _, _, res, _ = panning
    rows = _rows(res)
    e, frame, px = KNOCK
    for i, r in rows.items():
        if i != e:  # clean: the pan is the state's, not a fault (every one flagged before)
            assert r["flags"] == "", (i, r["flags"], r["shift_within_px"], r["shift_px"])
        assert r["camera_motion"] == "moves with the robot"
    r = rows[e]
    assert r["flags"] == "moved_within"
    # the knock's size: phase correlation of the views, less the state's pan (the map learnt
    # from the dataset's own frames: R² 0.95): measured 24.85 px for 25, within 1.5 px
    assert r["shift_within_px"] == pytest.approx(px, abs=1.5)
    assert r["shift_within_low_px"] >= FLAGS["moved_within"].threshold
    assert r["shift_frame"] == pytest.approx(frame, abs=1)  # the strip shows the knock
    # the terminal says which kind the camera was taken for, and from what
    report = "\n".join(res.report())
    assert "moves with the robot (learnt: the state's change explains R²" in report
    assert r["camera_motion_r2"] > 0.5


def test_the_user_can_name_the_moving_camera_and_turn_a_flag_off(panning, tmp_path) -> None:
    root, first, _, _ = panning
    out = tmp_path / "out"
    shutil.copytree(first, out)  # the measures kept, the first run's files left as they were
    # the second run reads the measures back (no setting here changes what is measured)
    s = DatasetSettings(
        jobs=1,
        page=False,
        recordings=False,
        moving_cameras="observation.images.front",
        thresholds="moved_within=off,lag=80",
    )
    res = dataset(root, s, out)
    assert res.reused == 6
    rows = _rows(res)
    assert all(r["flags"] == "" for r in rows.values())
    assert any("as --moving-cameras says" in line for line in res.report())
    with pytest.raises(UserError, match="--moving-cameras: 'wrist' is not a camera"):
        dataset(root, DatasetSettings(moving_cameras="wrist", page=False), out)


def test_the_flagged_episodes_are_listed_for_lerobots_own_tool(panning) -> None:
    root, out, res, said = panning
    listing = json.loads((out / "flagged_episodes.json").read_text())
    assert listing["episode_indices"] == [KNOCK[0]] == res.flagged
    cmd = shlex.split(listing["lerobot_edit_dataset"])
    # lerobot-edit-dataset's flags (LeRobot's dataset-tools guide): the list as one argument
    assert cmd[0] == "lerobot-edit-dataset"
    assert cmd[cmd.index("--operation.type") + 1] == "delete_episodes"
    assert cmd[cmd.index("--operation.episode_indices") + 1] == f"[{KNOCK[0]}]"
    assert cmd[cmd.index("--root") + 1] == str(root.resolve())
    assert "--new_root" in cmd  # into a new dataset: the original is kept
    lines = res.report()
    assert any(listing["lerobot_edit_dataset"] in line for line in lines)
    # the episodes' list ends with the clean count; the run counted the streams as it went
    assert "  5 episode(s) clean." in lines
    assert "6 of 6 camera stream(s) measured." in said


def test_a_file_given_as_the_dataset_is_said_to_be_a_file(panning) -> None:
    root, out, _, _ = panning
    with pytest.raises(UserError, match=r"info\.json is a file, not a folder"):
        dataset(root / "meta" / "info.json", DatasetSettings(page=False), out)


def test_thresholds_are_parsed_and_bad_ones_refused() -> None:
    s = DatasetSettings(thresholds="lag=80, idle=off")
    assert s.flag_thresholds() == {"lag": 80.0, "idle": None}
    for bad in ("lag", "nope=3", "lag=-1", "lag=many"):
        with pytest.raises(UserError, match="--thresholds"):
            DatasetSettings(thresholds=bad)


@pytest.fixture(scope="module")
def example_v21(tmp_path_factory):
    """The v2.1 / H.264 example's idle head (1 s) and blurred episode, in five episodes."""
    root = tmp_path_factory.mktemp("v21") / "ds"
    faults = Faults(idle_head_s={1: 1.0}, blurred=frozenset({2}))
    write_dataset(root, episodes=5, version="v2.1", codec="libx264", faults=faults)
    res = dataset(root, DatasetSettings(jobs=2, page=False, recordings=False), root.parent / "out")
    return res


def test_the_v21_h264_idle_head_is_found(example_v21) -> None:
    rows = _rows(example_v21)
    # H.264 at CRF 30 codes every second frame again as a key frame, which changed a still
    # view's block by 12 levels (it read 0.033 s): the first frame is within 3 of 1 s
    assert rows[1]["idle_head_s"] == pytest.approx(1.0, abs=3 / 30)
    assert "idle" in rows[1]["flags"]
    for e in (0, 3, 4):
        assert rows[e]["idle_head_s"] < 0.1, e


def test_the_blurred_episode_gets_no_lag_and_no_lag_is_flagged_on_a_point(example_v21) -> None:
    rows = _rows(example_v21)
    assert rows[2]["flags"] == "blurred"  # it was flagged lag too, on a 169-ms point
    for e, r in rows.items():
        assert "lag" not in r["flags"], e
        if r["lag_ms"] is None and r["lag_low_ms"] is not None:  # an interval without a lag
            assert r["lag_note"].startswith("cannot tell"), (e, r["lag_note"])
            assert r["lag_high_ms"] - r["lag_low_ms"] >= 0.9 * 800


def test_two_cameras_are_checked_against_each_other_for_lag(tmp_path) -> None:
    """Episode 1's front camera shows the scene 150 ms late (its wrist camera on time), three
    strokes in 6 s: the front is late against the state and against the wrist camera, and
    the flag lands on the front camera, the one behind. The cameras' sizes differ (96 × 128
    and 120 × 160)."""
    root = tmp_path / "ds"
    write_h264_dataset(
        root,
        3,
        (6.0, 6.0),
        version="v2.1",
        strokes=3,
        faults=Faults(lag_ms={1: 150.0}),
        cameras=("observation.images.front", "observation.images.wrist"),
        camera_shapes={"observation.images.wrist": (120, 160)},
    )
    res = dataset(root, DatasetSettings(jobs=2, page=False, recordings=False), tmp_path / "o")
    rows = {(r["episode_index"], r["camera"]): r for r in res.episodes.iter_rows(named=True)}
    wrist = rows[(1, "observation.images.wrist")]
    # the wrist's motion against the front's (the first camera): the front 150 ms late reads
    # as the wrist 150 ms early; measured -137 ms (a 33-ms frame grid): within 30 ms
    assert wrist["lag_camera_ref"] == "observation.images.front"
    assert wrist["lag_camera_ms"] == pytest.approx(-150, abs=30)
    assert wrist["lag_camera_high_ms"] < -FLAGS["lag"].threshold
    assert "lag" in rows[(1, "observation.images.front")]["flags"]
    assert "lag" not in wrist["flags"]
    for e in (0, 2):  # on time: the two cameras agree within 10 ms, nothing flagged
        r = rows[(e, "observation.images.wrist")]
        assert (
            abs(r["lag_camera_ms"]) < 10 and r["lag_camera_low_ms"] <= 0 <= r["lag_camera_high_ms"]
        )
        assert not any(
            rows[(e, c)]["flags"] for c in ("observation.images.front", "observation.images.wrist")
        )


def test_the_example_is_written_without_scikit_image_and_a_failed_write_leaves_nothing(
    tmp_path,
) -> None:
    # a plain install has no scikit-image: the scene's photographs come with matplotlib
    code = (
        "import sys; sys.modules['skimage'] = None\n"
        "from analysis.dataset.synthetic import write_dataset, Faults\n"
        f"write_dataset({str(tmp_path / 'ok')!r}, episodes=2, codec='libx264', "
        "seconds=(1.0, 1.0), faults=Faults())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "ok" / "meta" / "info.json").is_file()
    # a write that fails midway (after the frames are drawn) leaves no folder, hidden or not
    bad = tmp_path / "bad"
    with pytest.raises(UserError, match="image camera 'nope'"):
        write_h264_dataset(bad, 2, (1.0, 1.0), image_cameras=("nope",))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok"]
    with pytest.raises(UserError, match="not an empty folder"):
        write_dataset(tmp_path / "ok", episodes=1)


def test_the_page_rounds_its_numbers() -> None:
    # it printed -0, 1.78e-08 and -0.000112
    assert number(-0.000112, 1) == "0.0" and number(1.78e-08, 2) == "0.00"
    assert number(-0.04, 1) == "0.0" and number(12.345, 1) == "12.3"
    assert number(None, 1) == "-" and number(float("nan"), 2) == "-"


def test_a_fixed_cameras_knock_is_found_at_its_frame_and_after_it(tmp_path) -> None:
    """A fixed camera knocked 8 px at frame 45 of episode 2 (and left there): episode 2 moved
    within, at frame 45; episode 3 moved against the reference view; the others clean."""
    root = tmp_path / "ds"
    write_dataset(root, episodes=4, codec="libx264", faults=Faults(knock=(2, 45, 8)))
    res = dataset(root, DatasetSettings(jobs=2, page=False, recordings=False), tmp_path / "o")
    rows = _rows(res)
    assert all(r["camera_motion"] == "fixed" for r in rows.values())
    assert rows[0]["flags"] == rows[1]["flags"] == ""
    assert rows[2]["flags"] == "moved_within" and rows[3]["flags"] == "moved"
    # whole px shifts: phase correlation reads them within 0.3 px (H.264 at CRF 30)
    assert rows[2]["shift_within_px"] == pytest.approx(8, abs=0.3)
    assert rows[2]["shift_frame"] == pytest.approx(45, abs=1)
    assert rows[3]["shift_px"] == pytest.approx(8, abs=0.3)


def test_the_command_line_refuses_a_bad_threshold_and_a_file_in_one_line(panning) -> None:
    root, out, _, _ = panning
    proc = run_in_process(
        "analysis", "dataset", str(root), "--out", str(out), "--thresholds", "lag=soon"
    )
    assert_one_line_error(proc, "--thresholds", "lag", "'soon'")
    info = root / "meta" / "info.json"
    proc = run_in_process("analysis", "dataset", str(info), "--out", str(out))
    assert_one_line_error(proc, str(info), "is a file, not a folder")


def test_a_camera_at_half_the_rate_is_measured_in_its_own_frames(tmp_path) -> None:
    """The wrist camera films at 15 fps (its video's frames, its ``video.fps``) beside a top
    camera and data at 30 fps: measured at 15 with no rate problem; a clean episode flags
    nothing; 5 of its own frames dropped count 5, and a 100-ms lag reads 100 ms (before: 30 of
    its 60 frames counted missing and flagged short, its end 33 ms off flagged drift, a lag on
    the data's rows read at its rate: doubled)."""
    slow, fast = "observation.images.wrist", "observation.images.top"
    root = tmp_path / "ds"
    write_h264_dataset(
        root,
        3,
        (6.0, 6.0),
        strokes=3,
        faults=Faults(dropped={1: (20, 5)}, lag_ms={2: 100.0}),
        cameras=(slow, fast),
        camera_fps={slow: 15.0},
    )
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["fps"] == 30 and info["features"][slow]["info"]["video.fps"] == 15
    res = dataset(root, DatasetSettings(jobs=2, page=False, recordings=False), tmp_path / "o")
    assert res.dataset_problems == []  # its own video.fps borne out by its video
    rows = {(r["episode_index"], r["camera"]): r for r in res.episodes.iter_rows(named=True)}
    for e in range(3):
        r = rows[(e, slow)]
        # 6 s at 15 fps: 90 frames, its own (the data has 180 rows)
        assert r["fps"] == 15 and r["length"] == 90 and r["data_timestamps"] == 180
        assert r["frames_decoded"] == 90 - (5 if e == 1 else 0)
        assert r["frames_missing"] == 0
        assert not {"frozen", "drift", "short"} & set(r["flags"].split(","))
        # its last frame is the one holding the data's last row: the clocks agree within the
        # MP4's and float32's rounding (DRIFT_RESOLUTION_MS)
        assert r["drift_abs_ms"] < 1.0, (e, r["drift_start_ms"], r["drift_end_ms"])
        assert rows[(e, fast)]["flags"] == "" and rows[(e, fast)]["fps"] == 30
    assert rows[(0, slow)]["flags"] == ""
    assert rows[(1, slow)]["flags"] == "dropped" and rows[(1, slow)]["dropped"] == 5
    for e in (0, 1):  # on time: the intervals against the state and between cameras hold 0
        r = rows[(e, slow)]
        assert r["lag_low_ms"] <= 0 <= r["lag_high_ms"], (e, r["lag_ms"])
        r = rows[(e, fast)]
        assert r["lag_camera_low_ms"] <= 0 <= r["lag_camera_high_ms"], (e, r["lag_camera_ms"])
    late = rows[(2, slow)]
    assert late["flags"] == "lag"
    # measured 102 ms [76, 129] (it read 120 with the wrist's clock stretched to the data's
    # last row, 33 ms after its last frame): the interval holds 100, the point within 30 ms
    assert late["lag_low_ms"] <= 100 <= late["lag_high_ms"]
    assert late["lag_ms"] == pytest.approx(100, abs=30)
    # the top camera against the late wrist (the first camera): 100 ms early
    assert rows[(2, fast)]["lag_camera_ms"] == pytest.approx(-100, abs=30)

"""The overhead ArUco tracker on frames rendered with known ground truth."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from capture import tracker
from capture.config import ArenaConfig, SimConfig, WallConfig
from capture.render import OverheadRenderer
from capture.sim_robot import SimulatedRobot


@pytest.fixture(scope="module")
def overhead() -> OverheadRenderer:
    return OverheadRenderer(ArenaConfig(), 0.021, 1200.0, markers=True)


def test_pose_error_below_5_mm_and_3_degrees_over_a_run(overhead: OverheadRenderer) -> None:
    cfg = SimConfig(wall=WallConfig(tf_schedule=((0.0, 40.0),)), duration_s=40.0, seed=5)
    with SimulatedRobot(cfg, batch_size=100_000) as dev:
        poses = dev.read().poses[::11]  # 3 Hz over a 40-s run: driving and ring turns
    h = tracker.calibrate_homography(overhead.render(poses[0]), overhead.layout)
    pos_err, head_err = [], []
    for x, y, hd in poses:
        pose = tracker.robot_pose(overhead.render(np.array([x, y, hd])), h)
        assert pose is not None
        pos_err.append(math.hypot(pose[0] - x, pose[1] - y))
        head_err.append(abs(math.degrees(math.remainder(pose[2] - hd, math.tau))))
    assert len(pos_err) == 120
    assert max(pos_err) < 0.005
    assert max(head_err) < 3.0


def test_lost_track_gives_no_pose_and_calibration_round_trips(overhead, tmp_path: Path) -> None:
    frame = overhead.render(np.array([0.2, 0.1, 1.0]))
    h = tracker.calibrate_homography(frame, overhead.layout)
    blank = frame.copy()
    px, py = overhead._to_px_f(0.2, 0.1)
    r = 40
    blank[int(py) - r : int(py) + r, int(px) - r : int(px) + r] = 25  # the robot is hidden
    assert tracker.robot_pose(blank, h) is None
    tracker.save_calibration(h, tmp_path / "cal.json")
    assert np.allclose(tracker.load_calibration(tmp_path / "cal.json"), h)
    with pytest.raises(ValueError, match="cannot read"):
        tracker.load_calibration(tmp_path / "missing.json")


def test_calibration_names_the_missing_corner(overhead: OverheadRenderer) -> None:
    frame = overhead.render(np.array([0.0, 0.0, 0.0]))
    cx, cy = overhead._to_px_f(*overhead.layout.corner_centres()[2])
    frame[int(cy) - 40 : int(cy) + 40, int(cx) - 40 : int(cx) + 40] = 30
    with pytest.raises(ValueError, match=r"\[2\] not visible"):
        tracker.calibrate_homography(frame, overhead.layout)

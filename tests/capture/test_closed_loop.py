"""Closed-loop collision mode: the body's rules, the on-board models, the command line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from analysis.recordings.reader import Recording
from avdm import make_model
from capture.closed_loop import ClosedLoopRobot, CollisionMotion
from capture.config import (
    ArenaConfig,
    CameraConfig,
    CollisionConfig,
    RobotConfig,
    SimConfig,
    WallConfig,
)
from tests.helpers import assert_one_line_error, flags, run_cli
from tests.in_process import run_in_process


def config(**kw) -> SimConfig:
    robot = kw.pop("robot", RobotConfig())
    col = kw.pop("collision", CollisionConfig(detector="lgmd-plus-arena"))
    tf = kw.pop("tf", 0.0)
    minutes = kw.pop("minutes", 0.5)
    return SimConfig(
        arena=ArenaConfig(ring_enabled=False),
        wall=WallConfig(tf_schedule=((tf, minutes * 60),)),
        duration_s=minutes * 60,
        behaviour="collision",
        collision=col,
        robot=robot,
        seed=4,
        **kw,
    )


def test_without_alerts_the_robot_crashes_turns_away_and_never_leaves() -> None:
    cfg = config(robot=RobotConfig(start_x_m=0.5, start_y_m=0.0, start_heading_rad=0.0))
    m = CollisionMotion(cfg, np.random.default_rng(0))
    events, xs, ys = [], [], []
    for _ in range(33 * 120):
        ev = m.step(False, "test")
        xs.append(m.x)
        ys.append(m.y)
        if ev is not None:
            events.append(ev)
    assert events and all(e.kind == "crash" for e in events)
    first = events[0]
    assert first.x_m == pytest.approx(0.7 - 0.021 - 0.005, abs=0.003)  # at the +x wall
    gap = np.minimum(0.7 - np.abs(xs), 0.4 - np.abs(ys))
    assert gap.min() > 0.021  # the body never passes a wall
    assert len(events) < 120  # it turns away and drives on, rather than crashing in place


def test_an_alert_starts_an_80_to_100_degree_turn_and_alerts_wait_for_the_refractory() -> None:
    cfg = config(
        robot=RobotConfig(start_x_m=0.0, start_y_m=0.0, start_heading_rad=0.0),
        collision=CollisionConfig(detector="lgmd-plus", refractory_frames=10),
    )
    m = CollisionMotion(cfg, np.random.default_rng(1))
    ev = m.step(True, "alert")
    assert ev is not None and ev.kind == "avoidance"
    h0 = ev.heading_rad
    n = 0
    while m.state != 0:  # turning
        assert m.step(True, "ignored") is None
        n += 1
    turned = abs(math.degrees(math.remainder(m.heading - h0, math.tau)))
    assert 80 <= turned <= 100
    assert n == math.ceil(turned / (120 / 33)) or n == math.ceil(turned / (120 / 33)) + 1
    for _ in range(10):  # refractory frames: alerts ignored, the robot drives on
        assert m.step(True, "ignored") is None
    assert m.step(True, "alert again").kind == "avoidance"


def test_onboard_detector_outputs_recompute_exactly_offline() -> None:
    cfg = config(tf=3.0, minutes=0.4)
    with ClosedLoopRobot(cfg) as dev:
        batch = dev.read()
        name = dev.detector.name
    assert set(batch.onboard) == {name, "avdm", "controller"}
    offline = make_model(name, fps=33.0).run(batch.images)
    for key, values in batch.onboard[name].items():
        assert np.array_equal(values, offline[key]), key
    avdm = make_model("avdm", **CameraConfig().model_context()).run(batch.images)
    assert np.array_equal(batch.onboard["avdm"]["omega_dps"], avdm["omega_dps"])
    assert (batch.onboard["controller"]["t_ffi"] == 12.0).all()


def test_adaptive_mode_lets_t_ffi_follow_the_avdm_mean() -> None:
    col = CollisionConfig(
        detector="lgmd-plus-arena", adaptive=True, adaptive_gain=1.0, adaptive_window_s=5.0
    )
    with ClosedLoopRobot(config(tf=3.0, minutes=0.4, collision=col)) as dev:
        batch = dev.read()
    ctrl = batch.onboard["controller"]
    np.testing.assert_allclose(ctrl["t_ffi"], np.maximum(12.0, 1.0 * ctrl["avdm_mean_dps"]))
    # the running mean is over the frames before each frame (no look-ahead)
    omega = batch.onboard["avdm"]["omega_dps"]
    window = round(5.0 * 33)
    k = 300
    assert ctrl["avdm_mean_dps"][k] == pytest.approx(omega[k - window : k].mean())
    assert ctrl["t_ffi"].max() > 12.0


def test_collision_recording_has_events_detector_and_controller(tmp_path: Path) -> None:
    out = tmp_path / "col.rrd"
    proc = run_in_process(
        "capture",
        "sim",
        *flags(
            "--behaviour collision --model lgmd-plus-arena --tf-hz 3 --minutes 0.5 --seed 2 "
            "--quiet",
            out=out,
        ),
    )
    assert proc.returncode == 0, proc.stderr
    rec = Recording(out)
    props = rec.properties()
    assert props["run"]["behaviour"] == "collision"
    assert props["arena"]["ring_enabled"] is False
    assert props["detector"]["name"] == "lgmd-plus-arena"
    assert props["detector_params"]["t_de"] == 5.0
    sig = rec.signals()
    for entity in (
        "/model/lgmd-plus-arena/spike_rate_hz",
        "/model/avdm/omega_dps",
        "/model/controller/t_ffi",
    ):
        assert len(sig[entity][0]) == 990, entity
    kinds = set(rec.events()["kind"])
    assert kinds <= {"avoidance", "crash"} and kinds


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--behaviour", "collision", "--model", "avdm"], "must be a collision detector"),
        (["--threshold", "80"], "belongs to --behaviour collision"),
        (["--adaptive"], "belongs to --behaviour collision"),
        (["--behaviour", "collision", "--model", "lgmd-colias", "--adaptive"], "spike-rate"),
        (["--behaviour", "collision", "--threshold", "5000"], "collision threshold"),
        (["--behaviour", "collision", "--model", "lgmd-plus:t_sr=x"], "expected a number"),
    ],
)
def test_bad_collision_options(tmp_path: Path, args: list[str], needle: str) -> None:
    out = tmp_path / "x.rrd"
    assert_one_line_error(  # in this process (tests.in_process): refused before any run
        run_in_process("capture", "sim", "--minutes", "0.05", *args, "--out", str(out)), needle
    )
    assert not out.exists()


NAN_LATER = '''
import math


class NanLater:
    """A detector whose alert is NaN from its third frame on (finite before: it passes the
    check of one frame before the run)."""

    outputs = (("alert", "1"),)

    def __init__(self, **camera: float) -> None:
        self.i = 0

    def step(self, frame):
        self.i += 1
        return {"alert": 0.0 if self.i < 3 else math.nan}
'''


def test_a_nan_alert_in_the_closed_loop_is_said_not_read_silently(tmp_path: Path) -> None:
    (tmp_path / "nan_later_det.py").write_text(NAN_LATER)
    out = tmp_path / "col.rrd"
    proc = run_cli(
        "capture",
        "sim",
        *flags(
            "--behaviour collision --model nan_later_det:NanLater --minutes 0.03 --quiet", out=out
        ),
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    notes = [ln for ln in proc.stderr.splitlines() if "alert = NaN" in ln]
    assert len(notes) == 1 and "frame 2" in notes[0], proc.stderr  # once, at the first

"""The simulated arena: the robot's motion and what its camera sees."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capture.config import (
    ArenaConfig,
    CameraConfig,
    OverheadConfig,
    RobotConfig,
    SimConfig,
    WallConfig,
)
from capture.render import CameraRenderer
from capture.robot import RobotMotion
from capture.sim_robot import SimulatedRobot

ARENA = ArenaConfig()
CAMERA = CameraConfig()


def motion(seed: int, **robot) -> RobotMotion:
    return RobotMotion(ARENA, RobotConfig(**robot), CAMERA.fps, np.random.default_rng(seed))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_robot_stays_inside_and_turns_80_to_100_degrees(seed: int) -> None:
    m = motion(seed)
    poses, turns = m.advance(round(20 * 60 * CAMERA.fps))  # 20 minutes
    hx, hy = ARENA.half_extent
    r = m.cfg.radius_m
    assert (np.abs(poses[:, 0]) < hx - r).all() and (np.abs(poses[:, 1]) < hy - r).all()
    # it explores: turns happen all around the arena, and it crosses the middle
    assert len(turns) > 100
    angles = np.array([t.angle_deg for t in turns])
    assert ((np.abs(angles) >= 80) & (np.abs(angles) <= 100)).all()
    assert 0.35 < (angles > 0).mean() < 0.65  # left or right at random
    assert not any(t.forced for t in turns)  # the ring always catches it before the wall
    assert poses[:, 0].min() < -0.4 and poses[:, 0].max() > 0.4


def test_turns_happen_at_the_ring_and_at_the_stated_rate() -> None:
    m = motion(5)
    poses, turns = m.advance(round(5 * 60 * CAMERA.fps))
    hx, hy = ARENA.half_extent
    for t in turns:
        gap = min(hx - abs(t.x_m), hy - abs(t.y_m))
        assert gap <= ARENA.ring_inner_m + m.cfg.sensor_forward_m + m.cfg.radius_m
    # during a turn the heading changes by turn_speed_dps / fps per frame, position is fixed
    t0 = turns[0].frame
    dh = np.degrees(np.abs(np.diff(np.unwrap(poses[t0 : t0 + 10, 2]))))
    # float64 headings differenced after unwrap: a few ulps (~1e-15) of rounding, on any CPU
    assert dh[1:] == pytest.approx(m.cfg.turn_speed_dps / CAMERA.fps, rel=1e-9)
    assert np.ptp(poses[t0 + 1 : t0 + 10, :2], axis=0).max() == 0.0


def test_forward_speed_is_8_cm_per_second() -> None:
    m = motion(0, start_x_m=-0.3, start_y_m=0.0, start_heading_rad=0.0)
    poses, turns = m.advance(33)
    assert not turns
    # 32 float64 steps accumulate at most ~32 ulps (~1e-14 relative); 1e-9 leaves room
    assert poses[-1, 0] - poses[0, 0] == pytest.approx(0.08 * 32 / 33, rel=1e-9)


def analytic_row(distance_m: float, period_m: float, x0: float, width: int) -> np.ndarray:
    """What the horizon row of a camera at (x0, wall − distance) facing the +y wall shows:
    the grating averaged over each pixel (64 samples), written independently of the renderer."""
    f = (width / 2) / math.tan(math.radians(35))
    hx, hy = ARENA.half_extent
    mean, amp = 0.5, 0.5  # contrast 1, peak-normalised
    out = np.empty(width)
    for j in range(width):
        u = j + (np.arange(64) + 0.5) / 64 - width / 2
        x_hit = x0 + distance_m * u / f  # image right = −left = +x when facing +y
        s = 2 * hx + 2 * hy + (hx - x_hit)  # top wall runs from +x to −x
        out[j] = np.mean(mean + amp * np.sin(2 * np.pi * s / period_m))
    return out


@pytest.mark.parametrize(("distance_m", "period_m"), [(0.4, 0.1), (0.25, 0.05), (0.6, 0.2)])
def test_stripes_facing_a_wall_have_the_analytic_angular_period(distance_m, period_m) -> None:
    _, hy = ARENA.half_extent
    wall = WallConfig(period_m=period_m)
    r = CameraRenderer(ARENA, wall, CAMERA)
    pose = np.array([[0.05, hy - distance_m, math.pi / 2]])
    frame = r.render(pose, np.zeros(1))[0]
    h = CAMERA.height_px
    row = frame[h // 2].astype(float) / 255  # the horizon row (camera height) is on the wall
    expected = analytic_row(distance_m, period_m, 0.05, CAMERA.width_px)
    assert np.abs(row - expected).max() <= 1.0 / 255 + 1e-9
    # the stripes' angular period at the centre is period/distance radians
    f = CAMERA.focal_px
    crossings = np.flatnonzero(np.diff(np.sign(row - 0.5)) != 0)
    mid = crossings[np.abs(crossings - CAMERA.width_px / 2) < 25]
    if len(mid) >= 2:
        half_period_px = np.median(np.diff(mid))
        assert half_period_px == pytest.approx(f * period_m / distance_m / 2, abs=1.0)


def test_wall_top_edge_room_and_floor_are_where_the_geometry_puts_them() -> None:
    _, hy = ARENA.half_extent
    d = 0.4
    r = CameraRenderer(ARENA, WallConfig(), CAMERA)
    frame = r.render(np.array([[0.0, hy - d, math.pi / 2]]), np.zeros(1))[0].astype(int)
    f = CAMERA.focal_px
    h = CAMERA.height_px
    top = h / 2 - (ARENA.wall_height_m - CAMERA.height_m) * f / d  # image row of the top edge
    bottom = h / 2 + CAMERA.height_m * f / d
    room = round(ARENA.room_level * 255)
    floor = round(ARENA.floor_level * 255)
    assert (frame[: math.floor(top)] == room).all()
    assert (frame[math.ceil(bottom) + 1 :] == floor).all()  # ring is behind the camera here
    wall_rows = frame[math.ceil(top) : math.floor(bottom)]
    assert wall_rows.max() > 240 and wall_rows.min() < 15  # full-contrast stripes


def test_ring_is_visible_on_the_floor_when_facing_it() -> None:
    _, hy = ARENA.half_extent
    r = CameraRenderer(ARENA, WallConfig(), CAMERA)
    frame = r.render(np.array([[0.0, hy - 0.15, math.pi / 2]]), np.zeros(1))[0]
    # the ring band 0.04–0.09 m from the wall lies 0.06–0.11 m ahead: a white band below the wall
    f, h = CAMERA.focal_px, CAMERA.height_px
    row_near = round(h / 2 + CAMERA.height_m * f / 0.07)
    assert frame[row_near, CAMERA.width_px // 2] == 255


def still_config(tf: float) -> SimConfig:
    return SimConfig(
        wall=WallConfig(tf_schedule=((tf, 2.0),)),
        duration_s=2.0,
        robot=RobotConfig(speed_mps=0.0, start_x_m=0.1, start_y_m=0.0, start_heading_rad=1.0),
    )


def test_a_static_wall_seen_from_a_still_robot_gives_identical_frames() -> None:
    with SimulatedRobot(still_config(0.0)) as dev:
        images = dev.read().images
    assert (images == images[0]).all()
    with SimulatedRobot(still_config(3.0)) as dev:
        moving = dev.read().images
    assert (np.diff(moving.astype(int), axis=0) != 0).any(axis=(1, 2)).all()


def test_same_seed_same_frames_and_poses() -> None:
    cfg = SimConfig(wall=WallConfig(tf_schedule=((3.0, 20.0),)), duration_s=20.0, seed=7)
    with SimulatedRobot(cfg, batch_size=256) as a, SimulatedRobot(cfg, batch_size=700) as b:
        xa = [a.read() for _ in range(3)]
        xb = [b.read()]
    ia = np.concatenate([x.images for x in xa])[:700]
    assert np.array_equal(ia, xb[0].images)
    assert np.array_equal(np.concatenate([x.poses for x in xa])[:700], xb[0].poses)
    other = SimConfig(wall=WallConfig(tf_schedule=((3.0, 20.0),)), duration_s=20.0, seed=8)
    with SimulatedRobot(other, batch_size=700) as c:
        assert not np.array_equal(c.read().poses, xb[0].poses)


def test_natural_scene_and_noise_and_overhead() -> None:
    cfg = SimConfig(
        wall=WallConfig(scene="natural", tf_schedule=((3.0, 1.0),)),
        duration_s=1.0,
        camera=CameraConfig(noise_sd=3.0),
        overhead=OverheadConfig(enabled=True, fps=5.0),
    )
    with SimulatedRobot(cfg) as dev:
        batch = dev.read()
    assert batch.images.shape == (33, 72, 99)
    assert len(batch.overhead) == 5  # 1 s at 5 Hz
    frame_idx, img = batch.overhead[0]
    assert frame_idx == 0 and img.ndim == 2 and img.dtype == np.uint8
    with SimulatedRobot(cfg) as again:
        assert np.array_equal(again.read().images, batch.images)  # noise is seeded too

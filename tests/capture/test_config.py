"""Simulation config: schedules, validation, run ids."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from capture.config import (
    ArenaConfig,
    CameraConfig,
    RobotConfig,
    SimConfig,
    WallConfig,
    format_schedule,
    parse_schedule,
)


def test_schedule_parses_units_and_round_trips() -> None:
    s = parse_schedule("0:30m, 3:90s,1.5:1h,2:10")
    assert s == ((0.0, 1800.0), (3.0, 90.0), (1.5, 3600.0), (2.0, 10.0))
    assert parse_schedule(format_schedule(s)) == s


@given(st.lists(st.tuples(st.floats(0, 100), st.floats(0.01, 1e5)), min_size=1, max_size=6))
def test_any_valid_schedule_round_trips(segments: list[tuple[float, float]]) -> None:
    text = ",".join(f"{tf!r}:{dur!r}s" for tf, dur in segments)
    assert parse_schedule(text) == tuple(segments)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("3", "not TF:DURATION"),
        ("3:30x", "not TF:DURATION"),
        ("a:30m", "not TF:DURATION"),
        ("3:0m", "must be > 0"),
        ("300:1m", "0–100 Hz"),
        ("3:30m,,", "not TF:DURATION"),
    ],
)
def test_bad_schedules_name_the_segment(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_schedule(text)


def test_tf_in_force_follows_the_schedule() -> None:
    wall = WallConfig(tf_schedule=((0.0, 10.0), (3.0, 5.0)))
    assert [wall.tf_at(t) for t in (0, 9.99, 10, 14.9, 15, 100)] == [0, 0, 3, 3, 3, 3]


@pytest.mark.parametrize(
    ("factory", "message"),
    [
        (lambda: ArenaConfig(length_m=-1), "length_m"),
        (lambda: ArenaConfig(ring_inset_m=0.3, ring_width_m=0.2), "no room"),
        (lambda: WallConfig(scene="stars"), "scene"),
        (lambda: WallConfig(period_m=0), "period_m"),
        (lambda: WallConfig(tf_schedule=((3.0, -1.0),)), "duration"),
        (lambda: RobotConfig(turn_min_deg=100, turn_max_deg=80), "turn_max_deg"),
        (lambda: CameraConfig(fps=float("nan")), "fps"),
        (lambda: SimConfig(duration_s=0), "duration"),
        (lambda: SimConfig(seed=-1), "seed"),
        (lambda: SimConfig(robot=RobotConfig(start_x_m=5.0)), "outside the arena"),
    ],
)
def test_absurd_values_are_refused(factory, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        factory()


def test_run_id_is_readable_and_a_function_of_the_config() -> None:
    a = SimConfig(wall=WallConfig(tf_schedule=((3.0, 60.0),)), seed=1, duration_s=60)
    b = SimConfig(wall=WallConfig(tf_schedule=((3.0, 60.0),)), seed=1, duration_s=60)
    c = SimConfig(wall=WallConfig(tf_schedule=((3.0, 60.0),)), seed=2, duration_s=60)
    assert a.run_id() == b.run_id()
    assert a.run_id().startswith("grating-tf3-s1-") and len(a.run_id().split("-")[-1]) == 8
    assert a.run_id() != c.run_id()
    two = SimConfig(wall=WallConfig(tf_schedule=((0.0, 5.0), (1.5, 5.0))), duration_s=10)
    assert two.run_id().startswith("grating-tf0-1p5-s0-")
    sections = a.to_sections()
    assert sections["wall"]["tf_schedule_text"] == "3:60s"
    assert sections["run"]["seed"] == 1 and sections["camera"]["width_px"] == 99

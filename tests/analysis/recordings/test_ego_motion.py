"""The robot's own rotation: yaw rate and turning flag from poses, and ``--exclude-turns``."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.recordings.ego_motion import YAW_WINDOW_S, turning_flags, yaw_rate_dps
from analysis.recordings.recompute import SummarySettings, TablesSettings, tables
from tests.in_process import run_in_process

FPS = 33.0  # the arena robot's camera
TURN_DPS = 120.0  # its in-place turn rate (capture/config.py)
HOLD = SummarySettings().turn_hold_frames
K = round(FPS * YAW_WINDOW_S / 2)  # half-window of the yaw-rate difference, frames


def test_turning_flag_matches_the_simulators_known_turns(recordings) -> None:
    """Every ring turn the simulator logged (frame, signed angle) is flagged, at 120 °/s with
    its sign, and nothing else is: straight driving reads exactly 0 °/s (exact poses)."""
    t = tables(
        [recordings["tf3_a"]], TablesSettings(models=("avdm",)), None
    )  # 24 s with several turns
    frames, events = t.frames, t.events
    turns = []
    for r in events.filter(pl.col("kind") == "ring_turn").iter_rows(named=True):
        angle = float(re.search(r"ring turn ([+-][\d.]+) deg", r["text"]).group(1))
        steps = math.ceil(abs(angle) / (TURN_DPS / FPS) - 1e-9)
        # the turn starts in frame f; the poses of frames f+1 .. f+steps+1 show the rotation
        turns.append((r["frame"], r["frame"] + steps + 1, math.copysign(1.0, angle)))
    last = frames["frame"].max()
    complete = [tr for tr in turns if tr[1] + K < last]  # a turn cut by the end of the run
    assert len(complete) >= 2
    omega = frames["robot_omega_dps"].to_numpy()
    turning = frames["turning"].to_numpy()
    frame = frames["frame"].to_numpy()
    for start, end, sign in complete:
        # windows that see only full turn steps (the last step is the remainder of the angle)
        inside = (frame >= start + 1 + K) & (frame <= end - K - 1)
        assert inside.sum() > 10
        # headings and times go through the recording as float32/ns: ~1e-8 relative
        np.testing.assert_allclose(omega[inside], sign * TURN_DPS, rtol=1e-6)
        assert turning[(frame >= start + 1) & (frame <= end - 1)].all()
    near_a_turn = np.zeros(len(frame), bool)
    for start, end, _ in turns:
        near_a_turn |= (frame >= start - K) & (frame <= end + K + HOLD)
    assert not turning[~near_a_turn].any()
    far = np.ones(len(frame), bool)
    for start, end, _ in turns:
        far &= (frame < start - K) | (frame > end + K)
    assert np.abs(omega[far]).max() < 1e-6


@settings(max_examples=40, deadline=None)
@given(
    noise_deg=st.floats(0.0, 1.5),
    angle_deg=st.floats(60.0, 180.0),
    start_s=st.floats(1.0, 3.0),
    seed=st.integers(0, 2**16),
)
def test_tracked_headings_with_jitter_flag_the_turn_and_only_the_turn(
    noise_deg: float, angle_deg: float, start_s: float, seed: int
) -> None:
    """A tracker's heading jitters (up to 1.5° here, several times a well-lit marker's); the
    0.3 s slope keeps straight driving well under the 30 °/s threshold and the 120 °/s turn
    well over it."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 8.0, 1 / FPS)
    dur = angle_deg / TURN_DPS
    true = np.radians(np.clip((t - start_s) * TURN_DPS, 0, angle_deg)) + 0.3
    heading = np.angle(np.exp(1j * (true + np.radians(rng.normal(0, noise_deg, len(t))))))
    heading[rng.random(len(t)) < 0.02] = np.nan  # the marker is missed now and then
    omega = yaw_rate_dps(t, heading)
    flags = turning_flags(omega, 30.0, HOLD)
    margin = 2 * K / FPS
    mid = (t > start_s + margin) & (t < start_s + dur - margin) & np.isfinite(omega)
    # the recording's first and last K frames have a one-sided (half) window, whose slope has
    # 2.5x the noise: at 1.5 deg of jitter it can cross 30 deg/s (hypothesis found one), so
    # the claim is for frames with their whole window (and past the hold of an edge frame)
    whole = (np.arange(len(t)) >= K + HOLD) & (np.arange(len(t)) < len(t) - K)  # + its hold
    straight = (
        ((t < start_s - margin) | (t > start_s + dur + margin + HOLD / FPS))
        & np.isfinite(omega)
        & whole
    )
    # σ of an 11-point slope of 1.5° jitter over 0.3 s is ~5 °/s: 30 is 6σ from 0 and from 120
    assert (flags[mid] == 1.0).all()
    assert (flags[straight] == 0.0).all()
    # too few poses in the window: unknown, not straight
    assert np.isnan(flags[np.isnan(omega) & (flags != 1.0)]).all()


def test_the_flag_holds_for_the_models_memory_after_a_turn() -> None:
    omega = np.zeros(40)
    omega[5:10] = 120.0
    omega[30] = np.nan
    flags = turning_flags(omega, 30.0, hold_frames=4)
    assert flags[:5].tolist() == [0.0] * 5
    assert flags[5:14].tolist() == [1.0] * 9  # the turn and 4 frames after it
    assert flags[14] == 0.0 and np.isnan(flags[30])
    with pytest.raises(ValueError, match="turn_threshold_dps"):
        turning_flags(omega, 0.0)
    # a marker lost for a second: no yaw rate and no flag there, known again after it
    t = np.arange(100) / FPS
    heading = np.full(100, 0.5)
    heading[40:73] = np.nan
    omega = yaw_rate_dps(t, heading)
    assert np.isnan(omega[45:68]).all() and (omega[:35] == 0).all() and (omega[78:] == 0).all()
    assert np.isnan(turning_flags(omega)[45:68]).all()


def test_exclude_turns_summarises_straight_driving_only(recordings, tmp_path: Path) -> None:
    rec = recordings["tf3_a"]
    proc = run_in_process(
        "analysis", "tables", str(rec), "--out", str(tmp_path / "s"), "--exclude-turns"
    )
    assert proc.returncode == 0, proc.stderr
    straight = pl.read_parquet(tmp_path / "s" / "summary.parquet").row(0, named=True)
    frames = pl.read_parquet(tmp_path / "s" / "frames.parquet")
    outputs = pl.read_parquet(tmp_path / "s" / "model_outputs.parquet")
    kept = outputs.join(frames, on=["recording_id", "frame"]).filter(
        (pl.col("frame") >= 20) & ~pl.col("turning")
    )
    assert straight["motion"] == "straight" and straight["n_frames"] == kept.height
    assert 0 < kept.height < frames.height - 20
    # numpy's and polars' float64 means sum in different orders: ~1e-15 apart (approx: 1e-6)
    assert straight["mean"] == pytest.approx(kept["omega_dps"].mean())
    everything = tables([rec], TablesSettings()).summary.row(0, named=True)
    assert everything["motion"] == "all"
    # the robot's 120 °/s turns are most of what the decoder reads over 100 deg/s
    assert straight["frac_over_100"] < everything["frac_over_100"]
    # the profile labels say which frames it shows
    proc = run_in_process(
        "analysis", "profile", str(rec), "--out", str(tmp_path / "p"), "--exclude-turns"
    )
    assert proc.returncode == 0, proc.stderr
    prof = pl.read_parquet(tmp_path / "p" / "profile_summary.parquet").row(0, named=True)
    assert prof["motion"] == "straight" and prof["n_frames"] == kept.height


def test_an_alert_that_starts_a_turn_is_not_counted_as_while_turning() -> None:
    """A constructed run at 33 Hz: straight, an alert at frame 100 that starts a 90 deg/s turn;
    straight again, a turn from frame 190 and an alert at 200 in the middle of it. Only the
    second alert happened while the robot was already turning; the per-frame turning flag
    (a centred slope and a hold) marks both, because it sees the turn the first one starts."""
    from analysis.recordings.ego_motion import turning_before, turning_flags, yaw_rate_dps

    fps = 33.0
    t = np.arange(300) / fps
    rate = np.zeros(300)
    rate[100:130] = 90.0  # the turn the first alert triggers
    rate[190:230] = 90.0  # a turn under way before the second alert
    heading = np.radians(np.cumsum(rate) / fps)
    alerts = np.array([100, 200])
    before = turning_before(t, heading, alerts, threshold_dps=30.0)
    assert before.tolist() == [False, True]
    flags = turning_flags(yaw_rate_dps(t, heading), 30.0, 10)
    assert flags[alerts].tolist() == [1.0, 1.0]  # the old count: both

"""Inputs checked at the door: a range the camera bounds is refused before any run, in one
line naming the input (the arena's simulated camera runs at 33 Hz: TFs stay below 16.5 Hz)."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis.boundary.command import BoundarySettings
from capture.config import CameraConfig
from capture.sim import SimSettings
from tests.helpers import assert_one_line_error, run_cli

NYQUIST_HZ = CameraConfig().fps / 2  # 16.5 Hz: a grating drifting faster aliases


def test_analysis_checks_against_the_arena_cameras_own_rate() -> None:
    from vdc.cli_support import SIM_CAMERA_FPS  # what analysis holds TFs to, not importing capture

    assert CameraConfig().fps == SIM_CAMERA_FPS == 33.0


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda: BoundarySettings(design="adaptive", tf_range="0:40"), "--tf-range 0:40"),
        (lambda: BoundarySettings(tf=(0.0, 3.0, 20.0)), "--tf reaches 20 Hz"),
        (lambda: SimSettings(tf_hz=NYQUIST_HZ), "--tf-hz reaches 16.5 Hz"),
    ],
)
def test_a_tf_the_camera_cannot_show_is_refused_when_set(make, needle: str) -> None:
    with pytest.raises(ValueError) as err:
        make()
    message = str(err.value)
    assert needle in message and "Nyquist frequency 16.5 Hz" in message, message
    assert "\n" not in message


def test_tfs_below_nyquist_are_taken() -> None:  # the control: the bound is not too tight
    assert BoundarySettings(design="adaptive", tf_range="0:16").tf_bounds() == (0.0, 16.0)
    assert SimSettings(tf_hz=16.4).tf_hz == 16.4


def test_the_command_line_refuses_it_before_any_run(tmp_path: Path) -> None:
    out = tmp_path / "b"
    # the timeout bounds the old behaviour: a whole campaign through aliased TFs
    args = ["boundary", "--design", "adaptive", "--tf-range", "0:40", "--out", str(out)]
    res = run_cli("analysis", *args, timeout=120)
    assert_one_line_error(res, "--tf-range 0:40", "Nyquist")
    assert not out.exists()
    res = run_cli("capture", "sim", "--tf-hz", "20", "--out", str(tmp_path / "s.rrd"), timeout=120)
    assert_one_line_error(res, "--tf-hz reaches 20 Hz")
    assert not list(tmp_path.iterdir())

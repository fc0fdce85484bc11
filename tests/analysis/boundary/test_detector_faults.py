"""Detectors that cannot be one, and runs that hold no evidence: a plug-in is checked once,
before any run takes it (built with the first value, stepped on one frame of the raster it will
get), in one line with exit status 2, wherever a detector is taken; a grid too short for any
avoidance, crash or complexity says so in one line (with how long runs need to be) instead of
a verdict; a resumed grid says how many runs it reused."""

from __future__ import annotations

import dataclasses
import math
import os
import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from analysis.boundary.fit_text import describe_boundary
from analysis.boundary.report_tables import interval
from analysis.boundary.settings import BoundarySettings
from analysis.experiments.captures import run_captures
from analysis.experiments.collision.boundary_campaign import boundary
from avdm.registry import check_detector
from capture.sim import SimSettings
from tests.helpers import ROOT, assert_one_line_error, flags, module_on_path, run_cli, write_video
from vdc.errors import UserError
from vdc.executors import ExecutorSettings, Feedback

# a user's module of detectors that do not fit, written into a temporary folder
PLUGINS = """
import numpy as np


class NoAlert:  # declares no alert output
    outputs = (("brightness", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain

    def step(self, frame):
        return {"brightness": self.gain * float(frame.mean())}


class NoStep:  # nothing to step
    outputs = (("alert", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain


class OtherKeys:  # declares alert, returns other keys
    outputs = (("alert", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain

    def step(self, frame):
        return {"danger": self.gain}


class NanAlert:
    outputs = (("alert", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain

    def step(self, frame):
        return {"alert": float("nan")}


class Raises:
    outputs = (("alert", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain

    def step(self, frame):
        return {"alert": frame[0, 500]}  # written for a wider camera
"""

KINDS = {
    "NoAlert": "has no 'alert' output",
    "NoStep": "has no step(frame)",
    "OtherKeys": "step() returned no alert",
}
CAMERA = {"fps": 33.0, "deg_per_px": 70 / 99, "width_px": 99, "height_px": 72}


@pytest.fixture(scope="module")
def plugins(tmp_path_factory) -> Iterator[Path]:
    yield from module_on_path(tmp_path_factory.mktemp("plugins"), "unfit_detectors", PLUGINS)


def _cli(plugins: Path, *args: str) -> subprocess.CompletedProcess:
    """``python -m <args>`` with the user's plug-in folder on PYTHONPATH."""
    return run_cli(*args, env={**os.environ, "PYTHONPATH": f"{plugins}{os.pathsep}{ROOT}"})


@pytest.mark.parametrize(
    ("kind", "needle"),
    [
        *KINDS.items(),
        ("NanAlert", "returned alert=nan on a 99x72 frame"),
        ("Raises", "IndexError"),
    ],
)
def test_check_detector_builds_and_steps_once(plugins, kind: str, needle: str) -> None:
    with pytest.raises(ValueError, match=re.escape(needle)) as err:
        check_detector(f"unfit_detectors:{kind}:gain=2", CAMERA, (72, 99))
    assert "\n" not in str(err.value) and len(str(err.value)) < 300
    # a detector that fits passes, a built-in one and a plug-in
    check_detector("lgmd-plus-arena:t_ffi=12", CAMERA, (72, 99))
    check_detector("examples.looming:Looming:threshold=0.2", CAMERA, (72, 99))


@pytest.mark.parametrize("kind", list(KINDS))
def test_an_unfit_plugin_stops_the_arena_grid_before_any_run(plugins, kind, tmp_path) -> None:
    out, log = tmp_path / "grid", []
    s = BoundarySettings(
        detector=f"unfit_detectors:{kind}",
        param="gain",
        values="1,2",
        tf="0,3",
        scenes="grating",
        seeds=2,
        minutes=0.02,
    )
    with pytest.raises(ValueError, match=re.escape(KINDS[kind])):
        boundary(s, out, Feedback(log=log.append))
    assert log == [] and not out.exists()  # said before a word, nothing ran or was written
    if kind == "OtherKeys":  # from the command line: one line, exit status 2
        proc = _cli(
            plugins,
            "analysis",
            "boundary",
            *flags(
                "--param gain --values 1,2 --tf 0,3 --scenes grating --seeds 2 --minutes 0.02",
                detector=f"unfit_detectors:{kind}",
                out=out,
            ),
        )
        assert_one_line_error(proc, f"unfit_detectors:{kind}", KINDS[kind])
        assert not out.exists()


def test_an_unfit_plugin_stops_footage_mode_and_the_closed_loop(plugins, tmp_path) -> None:
    write_video(tmp_path / "clip.mp4", np.full((5, 48, 64), 128, np.uint8), 25.0)
    labels = tmp_path / "labels.csv"
    labels.write_text("clip,label,collision_frame\nclip.mp4,background,\n")
    proc = _cli(
        plugins,
        "analysis",
        "boundary",
        *flags(
            "--detector unfit_detectors:OtherKeys --param gain --values 1 --fov-deg 60",
            labels=labels,
            out=tmp_path / "footage",
        ),
    )
    # stepped on the clips' own working raster
    assert_one_line_error(proc, "step() returned no alert", "frame (WxH)")
    proc = _cli(
        plugins,
        "capture",
        "sim",
        *flags(
            "--behaviour collision --model unfit_detectors:NoStep --minutes 0.02",
            out=tmp_path / "run.rrd",
        ),
    )
    assert_one_line_error(proc, "has no step(frame)")
    assert not (tmp_path / "run.rrd").exists()
    # the campaigns' runner (collision-study, reproduce) checks before any process starts
    bad = SimSettings(behaviour="collision", model="unfit_detectors:NanAlert", minutes=0.02)
    with pytest.raises(ValueError, match="returned alert=nan"):
        run_captures([("bad", bad, tmp_path / "c" / "bad.rrd")], ExecutorSettings(), print)
    assert not (tmp_path / "c" / "bad.rrd").exists()


# 2 runs of 0.02 min (40 frames, shorter than the 60-frame warm-up) at TF 0: no avoidance, no
# crash (seeds 1 and 2 start far from the walls)
TINY = BoundarySettings(
    tf="0",
    scenes="grating",
    values="12",
    seeds=2,
    minutes=0.02,
    complexity="online",
    no_fit=True,
    jobs=1,
)


def test_a_grid_without_evidence_says_so_and_a_resumed_one_counts_its_reuse(tmp_path) -> None:
    out = tmp_path / "tiny"
    log: list[str] = []
    with pytest.raises(UserError, match="no run had an avoidance or a crash") as err:
        boundary(TINY, out, Feedback(log=log.append))
    msg = str(err.value)
    assert "--minutes 0.2 at the very least" in msg and "nan" not in msg.lower()
    assert not (out / "boundary.md").exists() and not (out / "policy.csv").exists()
    assert not any("reused" in line for line in log)
    # the same grid again, from the command line: its runs are reused, and it says how many
    proc = run_cli(
        "analysis",
        "boundary",
        *flags(
            "--tf 0 --scenes grating --values 12 --seeds 2 --minutes 0.02 --complexity online "
            "--no-fit --jobs 1",
            out=out,
        ),
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "reused 2 of 2 collision run(s) that an earlier run finished" in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ": error: " in ln]
    assert len(errors) == 1 and "no run had an avoidance or a crash" in errors[0]
    assert "nan" not in proc.stderr.lower()


def test_runs_shorter_than_the_warm_up_give_no_complexity_and_no_verdict(tmp_path) -> None:
    # at TF 3 the drift alerts the detector at once (avoidances), but 40 frames end before
    # the warm-up: no condition's complexity is measured
    s = dataclasses.replace(TINY, tf="3", values="30", seeds=1)
    with pytest.raises(UserError, match="the complexity of grating-tf3 could not be measured"):
        boundary(s, tmp_path / "short")
    assert not (tmp_path / "short" / "boundary.md").exists()


def test_the_report_never_says_nan() -> None:
    nan = math.nan
    for row in (
        {
            "where": "beyond",
            "boundary_dps": nan,
            "boundary_low_dps": nan,
            "boundary_high_dps": math.inf,
        },
        {
            "where": "below",
            "boundary_dps": nan,
            "boundary_low_dps": -math.inf,
            "boundary_high_dps": nan,
        },
        {"where": "within", "boundary_dps": nan, "boundary_low_dps": 3.0, "boundary_high_dps": nan},
    ):
        phrase = describe_boundary(row)
        assert "nan" not in phrase and phrase.startswith("not placed")
    assert (
        describe_boundary(
            {
                "where": "beyond",
                "boundary_dps": nan,
                "boundary_low_dps": 4.3,
                "boundary_high_dps": math.inf,
            }
        )
        == "beyond the grid (> 4.3 deg/s)"
    )
    row = {"success_rate": nan, "success_low": nan, "success_high": nan}
    assert interval(row, "success", 100.0) == "—"

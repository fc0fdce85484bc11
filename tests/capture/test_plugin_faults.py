"""A user's plug-in that raises mid-run ends its clip with one line naming the plug-in, the clip
and the frame (no traceback), exit status 1; in a run over several recordings the others keep
their tables. A plug-in that blocks forever in its pool workers: Ctrl-C, sent to the whole
process group as a terminal sends it, ends the run, leaving no process behind (it was ignored:
the parent's main thread, waiting on the workers, never ran its handler). Run from the command
line, as a user runs it, on a plug-in file in the folder the command runs from."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq
import pytest

from analysis.recordings.reader import Recording
from tests.footage_clips import write_collection
from tests.helpers import flags, make_sim_recording, run_cli, spawn, wait_until, write_video

# raises at the 6th frame (index 5) it is given, from its 3rd build on: in `tables` the 1st
# build is the check before any run (one step), the 2nd the first recording's, the 3rd the
# second recording's, so only the second recording fails
RAISER = """
BUILT = []


class Raiser:
    outputs = (("mean_level", "1"),)

    def __init__(self, after: int = 5, from_build: int = 1) -> None:
        BUILT.append(self)
        self.after, self.n = after, 0
        self.armed = len(BUILT) >= from_build

    def step(self, frame):
        if self.armed and self.n == self.after:
            raise RuntimeError("my detector broke\\nsecond line of its message")
        self.n += 1
        return {"mean_level": float(frame.mean())}
"""


@pytest.fixture()
def plugin_folder(tmp_path: Path) -> Path:
    (tmp_path / "raiser.py").write_text(RAISER)
    return tmp_path


def _one_error_line(stderr: str) -> str:
    assert "Traceback" not in stderr, stderr
    errors = [ln for ln in stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1, stderr
    return errors[0]


def test_video_capture_ends_its_clip_in_one_line_naming_plugin_clip_and_frame(
    plugin_folder: Path,
) -> None:
    # distinct frames (no repeats): the model's 6th frame is the clip's frame 5
    frames = (np.random.default_rng(0).random((30, 48, 64)) * 255).astype(np.uint8)
    write_video(plugin_folder / "clip.mp4", frames, 25.0)
    proc = run_cli(
        "capture",
        "video",
        "clip.mp4",
        *flags("--fov-deg 60 --model raiser:Raiser --out clip.rrd --quiet"),
        cwd=plugin_folder,
    )
    assert proc.returncode == 1, (proc.stdout, proc.stderr)
    line = _one_error_line(proc.stderr)
    for needle in ("'raiser:Raiser'", "clip.mp4", "at frame 5", "RuntimeError: my detector broke"):
        assert needle in line, (needle, line)
    assert "second line" not in proc.stderr
    # the recording is published, readable, with the frames read and the run's end said
    assert not (plugin_folder / "clip.partial.rrd").exists()
    props = Recording(plugin_folder / "clip.rrd").properties()
    assert props["run_end"]["stop_reason"] == "plug-in error", props["run_end"]


def test_tables_keeps_the_other_recordings_and_names_the_failed_one(
    plugin_folder: Path,
) -> None:
    a = make_sim_recording(plugin_folder / "a.rrd", seed=1)
    b = make_sim_recording(plugin_folder / "b.rrd", seed=2)
    out = plugin_folder / "tables"
    proc = run_cli(
        "analysis.cli",
        "tables",
        str(a),
        str(b),
        *flags("--model raiser:Raiser:from_build=3", out=out),
        cwd=plugin_folder,
    )
    assert proc.returncode == 1, (proc.stdout, proc.stderr)
    line = _one_error_line(proc.stderr)
    for needle in ("'raiser:Raiser'", "b.rrd", "at frame 5", "my detector broke"):
        assert needle in line, (needle, line)
    kept = pl.read_parquet(out / "model_outputs.parquet")
    assert kept["recording_id"].n_unique() == 1  # a's tables, written; b's left out
    assert kept.height > 0 and kept["mean_level"].is_not_null().all()


# steps once (the detector's check before any run, in the parent), then blocks forever in the
# pool workers, saying so in a file of its own first
SLEEPER = """
import os
import time


class Sleeper:
    outputs = (("alert", "1"),)

    def __init__(self, gain: float = 1.0, **camera) -> None:
        self.gain, self.n = gain, 0

    def step(self, frame):
        self.n += 1
        if self.n > 1:
            open(f"blocked-{os.getpid()}", "w").close()
            while True:
                time.sleep(3600)
        return {"alert": 0.0}
"""


def _group(pgid: int) -> list[int]:
    """The live processes of process group ``pgid`` (zombies are not running: left out)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, pgrp, ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            found.append(int(entry))
    return found


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_ends_a_footage_boundary_whose_plugin_blocks(tmp_path: Path) -> None:
    (tmp_path / "sleeper.py").write_text(SLEEPER)
    labels = write_collection(tmp_path / "clips", drifts=(0.0,), seeds=(1,))
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = spawn(
        [
            sys.executable,
            "-m",
            "analysis",
            "boundary",
            *flags(
                "--detector sleeper:Sleeper --param gain --values 1 --fov-deg 60 --jobs 2",
                labels=labels,
                out=out,
            ),
        ],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    # the workers block in the plug-in: a hang guard, not a timing
    blocked = wait_until(lambda: list(tmp_path.glob("blocked-*")) or proc.poll() is not None, 240)
    assert blocked and proc.poll() is None, "the plug-in never blocked"
    assert len(_group(proc.pid)) > 1  # the command and its workers (and the fork server)
    for _ in range(3):  # Ctrl-C, repeated, to the whole group, as a terminal sends it
        os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout=60)  # a hang guard: it ends within seconds
    except subprocess.TimeoutExpired:
        pytest.fail("Ctrl-C did not end the run")
    stderr = proc.stderr.read()
    assert proc.returncode in (130, -signal.SIGINT), (proc.returncode, stderr)
    assert "interrupted" in stderr and "Traceback" not in stderr, stderr
    assert wait_until(lambda: not _group(proc.pid), 60), _group(proc.pid)  # no process left
    for table in out.rglob("*.parquet"):  # what was written is whole
        pq.read_metadata(table)


RUNNER = """
class Runner:
    outputs = (("x", "1"),)

    def step(self, frame):
        return {"x": 0.0}

    def run(self, frames):
        raise ValueError("cannot run a batch")
"""


def test_the_failing_frame_is_named_through_true_time_and_a_batch_run(tmp_path: Path) -> None:
    """The frame named is the clip's: counted through the repeats the true-time model skips;
    a plug-in whose own ``run`` raises is named with the batch's frames."""
    from avdm.errors import PluginError
    from avdm.registry import make_model
    from avdm.true_time import TrueTimeModel

    (tmp_path / "raiser_mod.py").write_text(RAISER)
    (tmp_path / "runner_mod.py").write_text(RUNNER)
    sys.path.insert(0, str(tmp_path))
    try:
        frames = np.zeros((10, 8, 8), np.uint8)
        model = TrueTimeModel(make_model("raiser_mod:Raiser:after=2", fps=25.0))
        repeat = np.array([0, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)  # new: 0, 3, 5, 6, ...
        with pytest.raises(PluginError) as err:
            model.run(frames, np.arange(10) / 25.0, repeat)
        numbers = np.arange(100, 110)  # the clip's frame numbers of this batch
        assert "at frame 105" in str(err.value.at(numbers).on("c.mp4"))  # its 3rd new frame
        with pytest.raises(PluginError) as err:
            make_model("runner_mod:Runner").run(frames)
        line = str(err.value.at(numbers))
        assert "in frames 100-109" in line and "ValueError: cannot run a batch" in line
    finally:
        sys.path.remove(str(tmp_path))

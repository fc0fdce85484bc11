"""A user's model runs everywhere a built-in one does: online in ``vdc-capture sim`` and
``vdc-capture video``, as the detector that steers the robot in the closed loop, and
recomputed from the frames by ``tables``, ``compare`` and ``batch`` (on a process pool whose
workers import it), all from the command line as a user runs them, in the folder that holds
the plug-in (here: the guides' OpenCV example, ``examples/looming.py``)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from analysis.recordings.reader import Recording
from tests.helpers import ROOT, assert_one_line_error, flags, run_cli, write_video

LOOMING = "examples.looming:Looming"


def _outputs(folder: Path, model: str) -> pl.DataFrame:
    df = pl.read_parquet(folder / "model_outputs.parquet")
    return df.filter(pl.col("model") == model).sort("frame")


@pytest.fixture(scope="module")
def online(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plugin") / "online.rrd"
    proc = run_cli(
        "capture",
        "sim",
        *flags("--tf-hz 3 --minutes 0.1 --quiet", model=LOOMING, out=out),
    )
    assert proc.returncode == 0, proc.stderr
    return out


def test_online_in_sim_and_recomputed_by_tables_alike(online: Path, tmp_path: Path) -> None:
    props = Recording(online).properties()
    assert props["model"]["name"] == LOOMING
    assert json.loads(props["model"]["outputs"]) == {"excitation": "1", "alert": "1"}
    logged, again = tmp_path / "logged", tmp_path / "again"
    assert run_cli("analysis.cli", "tables", str(online), "--out", str(logged)).returncode == 0
    proc = run_cli("analysis.cli", "tables", str(online), "--model", LOOMING, "--out", str(again))
    assert proc.returncode == 0, proc.stderr
    a, b = _outputs(logged, LOOMING), _outputs(again, LOOMING)
    assert a.height == 198 and a["excitation"].max() > 0.1
    np.testing.assert_array_equal(a["excitation"].to_numpy(), b["excitation"].to_numpy())
    np.testing.assert_array_equal(a["alert"].to_numpy(), b["alert"].to_numpy())


def test_compare_and_batch_recompute_a_plugin(online: Path, tmp_path: Path) -> None:
    spec = f"{LOOMING}:threshold=0.3"
    proc = run_cli(
        "analysis.cli",
        "compare",
        str(online),
        *flags(model=["avdm", spec], out=tmp_path / "cmp"),
    )
    assert proc.returncode == 0, proc.stderr
    stats = pl.read_parquet(tmp_path / "cmp" / "compare_summary.parquet")
    assert set(stats["model"]) == {"avdm", spec}
    proc = run_cli(
        "analysis.cli",
        "batch",
        str(online),
        *flags("--jobs 2", model=[spec, "avdm"], out=tmp_path / "batch"),
    )
    assert proc.returncode == 0, proc.stderr
    batch = _outputs(tmp_path / "batch", spec)
    assert batch.height == 198
    alone = run_cli(
        "analysis.cli", "tables", str(online), "--model", spec, "--out", str(tmp_path / "alone")
    )
    assert alone.returncode == 0
    np.testing.assert_array_equal(
        batch["alert"].to_numpy(), _outputs(tmp_path / "alone", spec)["alert"].to_numpy()
    )


def test_a_plugin_detector_steers_the_robot_in_the_closed_loop(tmp_path: Path) -> None:
    out = tmp_path / "loop.rrd"
    spec = f"{LOOMING}:threshold=0.05"
    proc = run_cli(
        "capture",
        "sim",
        *flags("--behaviour collision --minutes 1 --seed 2 --quiet", model=spec, out=out),
    )
    assert proc.returncode == 0, proc.stderr
    rec = Recording(out)
    assert rec.properties()["detector"]["name"] == spec
    avoid = rec.events().filter(pl.col("kind") == "avoidance")
    assert avoid.height > 3  # its alerts turned the robot
    assert all(f"({spec} alert)" in t for t in avoid["text"])


def test_online_in_video_capture(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    frames = np.clip(rng.normal(128, 40, (30, 72, 96)), 0, 255).astype(np.uint8)
    clip = write_video(tmp_path / "noise.mp4", frames, 25.0)
    out = tmp_path / "clip.rrd"
    proc = run_cli(
        "capture",
        "video",
        str(clip),
        *flags("--fov-deg 60 --quiet", model=LOOMING, out=out),
    )
    assert proc.returncode == 0, proc.stderr
    assert Recording(out).properties()["model"]["name"] == LOOMING


@pytest.mark.parametrize(
    ("cmd", "needle"),
    [
        (["capture", "sim", "--model", "nosuch_pkg.mod:make"], "no module named 'nosuch_pkg.mod'"),
        (["capture", "sim", "--model", "tests.toy_detector:broken"], "failed to build"),
        (
            ["capture", "sim", "--behaviour", "collision", "--model", "tests.toy_detector:NoAlert"],
            "has no 'alert' output",
        ),
        (["analysis.cli", "tables", "x.rrd", "--model", "examples.looming:Nope"], "has no 'Nope'"),
    ],
)
def test_a_bad_plugin_is_one_line_and_exit_2(tmp_path: Path, cmd: list[str], needle: str) -> None:
    extra = ["--out", str(tmp_path / "o.rrd")] if cmd[1] == "sim" else []
    proc = run_cli(*cmd, *extra, cwd=ROOT)
    assert_one_line_error(proc, needle)


def test_online_on_the_robot_over_its_serial_link(tmp_path: Path) -> None:
    """The emulated Colias-IV runs the plug-in on board and sends its outputs over the pty;
    ``vdc-capture robot --model`` records them; recomputing on the recorded frames gives the
    same floats, to the link's float32 (online = offline through the serial link)."""
    from tests.capture.test_serial_link import render_overhead, start_emulator

    seconds = 4.0
    render_overhead(tmp_path / "overhead", seconds, seed=5)
    link, out = tmp_path / "robot", tmp_path / "robot.rrd"
    emu = start_emulator(
        link,
        tmp_path / "report.json",
        *flags("--tf-hz 3 --seed 5", minutes=seconds / 60, model=LOOMING),
    )
    proc = run_cli(
        "capture",
        "robot",
        *flags(
            "--quiet", port=link, camera=tmp_path / "overhead" / "%05d.png", model=LOOMING, out=out
        ),
        timeout=120,
    )
    emu.wait(timeout=60)
    robot_said = emu.stdout.read() + emu.stderr.read()
    assert proc.returncode == 0, proc.stderr + "\nemulator: " + robot_said
    again = tmp_path / "again"
    assert run_cli("analysis.cli", "tables", str(out), "--out", str(tmp_path / "t")).returncode == 0
    proc = run_cli("analysis.cli", "tables", str(out), "--model", LOOMING, "--out", str(again))
    assert proc.returncode == 0, proc.stderr
    onboard, host = _outputs(tmp_path / "t", LOOMING), _outputs(again, LOOMING)
    assert onboard.height > 100 and onboard["excitation"].max() > 0.05
    # the link carries float32: the robot's values are the host's rounded to float32, exactly
    np.testing.assert_array_equal(
        onboard["excitation"].to_numpy().astype(np.float32),
        host["excitation"].to_numpy().astype(np.float32),
    )


def _console(script: str, *args: str) -> list[str]:
    """``script`` as the user runs it: the console script installed beside this Python (the
    current folder is not on its ``sys.path``), else ``python -P -m`` (the same for that)."""
    exe = Path(sys.executable).parent / script
    module = {"vdc-capture": "capture", "vdc-analyse": "analysis.cli"}[script]
    return [str(exe), *args] if exe.exists() else [sys.executable, "-P", "-m", module, *args]


def test_a_plain_folder_of_plugins_works_from_the_current_folder(tmp_path: Path) -> None:
    """The guides' ``--model examples.looming:Looming`` as a user types it in a clone: the
    package installed, the current folder *not* on the path, the plug-in a module in a plain
    folder (no ``__init__.py``). Here a copy of ``examples/`` under a name found nowhere on
    ``PYTHONPATH``, so only the current-folder lookup can find it: online in ``vdc-capture
    sim``, and in ``vdc-analyse boundary``'s worker processes."""
    shutil.copytree(ROOT / "examples", tmp_path / "my_detectors")
    assert not (tmp_path / "my_detectors" / "__init__.py").exists()
    spec = "my_detectors.looming:Looming"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    assert str(tmp_path) not in env["PYTHONPATH"]

    def run(script: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            _console(script, *args),
            cwd=tmp_path,
            env=env,
            text=True,
            capture_output=True,
            timeout=600,
        )

    proc = run(
        "vdc-capture",
        "sim",
        *flags(
            "--behaviour collision --minutes 0.05 --out loop.rrd --quiet",
            model=f"{spec}:threshold=0.05",
        ),
    )
    assert proc.returncode == 0, proc.stderr
    assert Recording(tmp_path / "loop.rrd").properties()["detector"]["name"] == (
        f"{spec}:threshold=0.05"
    )
    proc = run(
        "vdc-analyse",
        "boundary",
        *flags(
            "--param threshold --values 0.05,0.1 --tf 0 --scenes grating --seeds 1 --minutes 0.2 "
            "--jobs 2 --no-predictors --out b",
            detector=spec,
        ),
    )
    assert proc.returncode == 0, proc.stderr
    conditions = pl.read_parquet(tmp_path / "b" / "boundary_conditions.parquet")
    assert sorted(conditions["threshold"].unique().to_list()) == [0.05, 0.1]
    # a folder of that name without the module asked for is still one line
    proc = run(
        "vdc-capture",
        "sim",
        *flags("--model my_detectors.nothere:Looming --minutes 0.05 --out x.rrd"),
    )
    assert_one_line_error(proc, "no module named 'my_detectors.nothere'")

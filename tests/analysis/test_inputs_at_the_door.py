"""Inputs checked at the door: a range the camera bounds is refused before any run, in one
line naming the input (the arena's simulated camera runs at 33 Hz: TFs stay below 16.5 Hz); a
labelled frame outside its clip; a video smaller than the metrics need; a plug-in's parameter
or output named like one of vdc's own columns."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
import pytest

from analysis.boundary.labels import clip_length, read_labels
from analysis.boundary.settings import OWN_COLUMNS, BoundarySettings
from analysis.complexity.command import ComplexitySettings, complexity
from analysis.experiments.collision.boundary_campaign import boundary
from analysis.recordings.recompute import TablesSettings, tables
from avdm.base import FRAME_TABLE_COLUMNS
from capture.config import CameraConfig
from capture.sim import SimSettings
from tests.footage_clips import looming_boundary_settings, write_collection
from tests.helpers import (
    assert_one_line_error,
    flags,
    make_sim_recording,
    module_on_path,
    run_cli,
    write_video,
)
from tests.in_process import run_in_process
from vdc.errors import UserError
from vdc.sources import open_reader

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


# -- a labelled collection: its frames inside its clips ------------------------------------

CLIP_FRAMES = 30  # the tiny clip's length: frames 0 to 29


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory) -> Path:
    """A real 30-frame H.264 clip (a random texture panning right), 48x64 px at 25 fps."""
    folder = tmp_path_factory.mktemp("tiny")
    scene = np.random.default_rng(3).integers(40, 200, size=(48, 124), dtype=np.uint8)
    pan = np.stack([np.roll(scene, 2 * t, 1)[:, :64] for t in range(CLIP_FRAMES)])
    return write_video(folder / "tiny.mp4", pan, 25.0)


@pytest.mark.parametrize(
    ("columns", "row", "needle"),
    [
        ("collision_frame", "5000", "collision_frame 5000, beyond its 30 frames (0 to 29)"),
        ("collision_frame", "30", "collision_frame 30, beyond its 30 frames"),  # one past
        ("collision_frame,hazard_onset_frame", "29,31", "hazard_onset_frame 31, beyond its 30"),
        ("collision_frame", "-1", "collision_frame must be a frame number >= 0"),
        ("collision_frame,hazard_onset_frame", "29,-4", "hazard_onset_frame must be"),
        # no integer column holds 23 digits: it was a traceback from the cast to Int64
        ("collision_frame", "12345678901234567890123", "row 1: collision_frame must be a frame"),
        ("collision_frame,hazard_onset_frame", "29,1e30", "row 1: hazard_onset_frame must be"),
        ("collision_frame", "2.5", "row 1: collision_frame must be a frame number >= 0"),
    ],
)
def test_a_labelled_frame_outside_its_clip_is_refused(
    tiny_clip: Path, tmp_path: Path, columns: str, row: str, needle: str
) -> None:
    table = tmp_path / "labels.csv"
    table.write_text(f"clip,label,{columns}\n{tiny_clip},collision,{row}\n")
    with pytest.raises(UserError) as err:
        read_labels(table)
    assert needle in str(err.value) and "\n" not in str(err.value), err.value
    assert "tiny.mp4" in str(err.value) or "must be" in str(err.value)  # names the clip


def test_frames_inside_the_clip_are_taken(tiny_clip: Path, tmp_path: Path) -> None:
    """The control: the last frame (29) and an onset before it pass, a clip without a
    collision needs no frame, and the clip's length is the container's."""
    assert clip_length(str(tiny_clip)) == CLIP_FRAMES
    table = tmp_path / "labels.csv"
    table.write_text(
        f"clip,label,collision_frame,hazard_onset_frame\n{tiny_clip},collision,29,10\n"
        f"{tiny_clip.name},background,,\n"
    )
    shutil.copy(tiny_clip, tmp_path / tiny_clip.name)
    labels = read_labels(table)
    assert labels["collision_frame"].to_list() == [29, None]


def test_a_clip_whose_container_states_no_length_is_counted(
    tiny_clip: Path, tmp_path: Path
) -> None:
    """MPEG-TS states neither a frame count nor a trustworthy duration: the clip is counted,
    so a collision past its end is refused there too."""
    frames = np.stack([f.luma for f in open_reader(str(tiny_clip)).frames()])
    ts = write_video(tmp_path / "tiny.ts", frames, 25.0, container="mpegts")
    reader = open_reader(str(ts))
    assert reader.info["container_frames"] is None  # the case: nothing stated
    reader.close()
    assert clip_length(str(ts)) == CLIP_FRAMES
    table = tmp_path / "labels.csv"
    table.write_text(f"clip,label,collision_frame\ntiny.ts,collision,{CLIP_FRAMES}\n")
    with pytest.raises(UserError, match="collision_frame 30, beyond its 30 frames"):
        read_labels(table)


def test_boundary_refuses_a_collision_beyond_the_clip_before_any_run(
    tiny_clip: Path, tmp_path: Path
) -> None:
    res, out = footage_boundary(
        run_cli,
        tiny_clip,
        tmp_path,
        5000,
        "examples.looming:Looming",
        "threshold",
        "0.1",
        timeout=300,  # bounds the old behaviour: the whole run
    )
    assert_one_line_error(res, "collision_frame 5000", "beyond its 30 frames", "tiny.mp4")
    assert not out.exists()


def test_boundary_refuses_a_frame_number_no_integer_holds_in_one_line(
    tiny_clip: Path, tmp_path: Path
) -> None:
    res, out = footage_boundary(
        run_in_process,
        tiny_clip,
        tmp_path,
        "12345678901234567890123",
        "examples.looming:Looming",
        "threshold",
        "0.1",
    )
    assert_one_line_error(res, "labels.csv", "row 1", "collision_frame", "12345678901234567890123")
    assert not out.exists()


def footage_boundary(
    run,
    clip: Path,
    tmp_path: Path,
    collision_frame: int | str,
    detector: str,
    param: str,
    values: str,
    **kw,
):
    """``vdc-analyse boundary`` in footage mode on one labelled clip: (result, out folder)."""
    table = tmp_path / "labels.csv"
    table.write_text(f"clip,label,collision_frame\n{clip},collision,{collision_frame}\n")
    out = tmp_path / "b"
    res = run(
        "analysis",
        "boundary",
        *flags(
            "--fov-deg 60", labels=table, detector=detector, param=param, values=values, out=out
        ),
        **kw,
    )
    return res, out


# -- a video smaller than the metrics need ----------------------------------------------------


def _tiny_video(path: Path, width: int, height: int, n: int = 10) -> Path:
    """A real FFV1 (lossless) grey video of ``n`` frames of random texture, any size (H.264's
    4:2:0 needs even sides; FFV1's grey plane takes 1x1)."""
    rng = np.random.default_rng(width * 100 + height)
    with av.open(str(path), "w") as out:
        st = out.add_stream("ffv1", rate=25)
        st.width, st.height, st.pix_fmt = width, height, "gray"
        for _ in range(n):
            img = rng.integers(0, 256, (height, width), dtype=np.uint8)
            out.mux(st.encode(av.VideoFrame.from_ndarray(img, format="gray")))
        out.mux(st.encode())
    return path


@pytest.mark.parametrize(("width", "height"), [(1, 1), (2, 2), (64, 2)])
@pytest.mark.parametrize("command", ["capture video", "analysis complexity"])
def test_a_video_too_small_for_the_metrics_is_one_line(
    tmp_path: Path, width: int, height: int, command: str
) -> None:
    video = _tiny_video(tmp_path / "tiny.mkv", width, height)
    module, sub = command.split()
    out = tmp_path / ("o.rrd" if module == "capture" else "o")
    res = run_in_process(module, sub, str(video), "--fov-deg", "60", "--out", str(out))
    assert_one_line_error(res, "tiny.mkv", f"is {width}x{height} px", "at least 3x3 px")
    assert not out.exists()


def test_a_3x3_video_is_measured(tmp_path: Path) -> None:
    """The control: the smallest size taken is measured (SI's Sobel has one interior pixel;
    random frames differ, so TI is far from 0)."""
    video = _tiny_video(tmp_path / "three.mkv", 3, 3)
    res = complexity(
        [str(video)], ComplexitySettings(metrics="si_p910,ti_p910", jobs=1), tmp_path / "c"
    )
    assert res.table.height == 10 and not res.failures
    assert res.table["ti_p910"].drop_nans().drop_nulls().min() > 10  # 8-bit levels


# -- a plug-in's names against vdc's own columns ------------------------------------------------

PLUGINS = '''
import numpy as np


class Dark:
    """Alerts while the view is darker than ``frame`` (a share of white): a parameter with
    the name of vdc's frame column; ``level`` and ``alert`` are its outputs."""

    outputs = (("level", "1"), ("alert", "1"))

    def __init__(self, frame: float = 0.3, value: float = 0.0, level_gain: float = 1.0):
        self.frame, self.value, self.level_gain = frame, value, level_gain

    def step(self, img):
        level = float(np.mean(img)) / 255 * self.level_gain
        return {"level": level, "alert": float(level < self.frame)}


class FrameOut:  # an output with the name of the per-frame tables' frame column
    outputs = (("frame", "1"), ("alert", "1"))

    def step(self, img):
        return {"frame": 0.0, "alert": 0.0}


class TimeOut:  # an output with the name of their time column
    outputs = {"t_s": "s", "alert": "1"}

    def step(self, img):
        return {"t_s": 1.0, "alert": 0.0}
'''


@pytest.fixture(scope="module")
def plugins(tmp_path_factory) -> Iterator[Path]:
    yield from module_on_path(tmp_path_factory.mktemp("plugins"), "door_plugins", PLUGINS)


@pytest.mark.parametrize("name", ["frame", "t_s", "value", "frames", "hit", "collision_frame"])
def test_a_swept_parameter_named_as_a_column_is_refused_when_set(plugins, name: str) -> None:
    with pytest.raises(UserError) as err:
        BoundarySettings(
            labels="labels.csv",
            fov_deg=60.0,
            detector="door_plugins:Dark",
            param=name,
            values="0.3",
        )
    message = str(err.value)
    assert f"--param {name}" in message and f"column {name!r}" in message, message
    assert "\n" not in message


def test_boundary_refuses_a_parameter_named_frame_before_any_run(
    plugins, tiny_clip: Path, tmp_path: Path
) -> None:
    """The fault: a detector parameter ``frame`` swept in footage mode crashed at the end with
    polars' DuplicateError. Now one line, before any clip runs."""
    res, out = footage_boundary(
        run_in_process, tiny_clip, tmp_path, 29, "door_plugins:Dark", "frame", "0.3,0.6"
    )
    assert_one_line_error(res, "--param frame", "column 'frame'", "rename it")
    assert not out.exists()


@pytest.mark.parametrize(("factory", "name"), [("FrameOut", "frame"), ("TimeOut", "t_s")])
def test_an_output_named_as_a_column_is_refused_before_any_frame(
    plugins, tiny_clip: Path, tmp_path: Path, factory: str, name: str
) -> None:
    out = tmp_path / "c.rrd"
    res = run_in_process(
        "capture",
        "video",
        str(tiny_clip),
        *flags("--fov-deg 60", model=f"door_plugins:{factory}", out=out),
    )
    assert_one_line_error(res, f"output {name!r}", f"column {name!r}", "rename the output")
    assert not list(tmp_path.iterdir())


def test_the_per_frame_tables_hold_no_other_column_of_their_own(plugins, tmp_path: Path) -> None:
    """What the output check keeps free is what the tables take: a plug-in's outputs are
    written beside FRAME_TABLE_COLUMNS and nothing else (a new column there must join them)."""
    rec = make_sim_recording(tmp_path / "run.rrd", tf_hz=1.0, seed=1)
    res = tables([rec], TablesSettings(models=("door_plugins:Dark",)))
    cols = res.tables["model_outputs"].columns
    assert set(cols) - {"level", "alert"} == set(FRAME_TABLE_COLUMNS), cols
    assert res.tables["model_outputs"]["level"].drop_nans().len() > 0  # the outputs are there


def test_footage_tables_hold_no_column_outside_the_reserved_set(tmp_path: Path) -> None:
    """What the --param check keeps free is every column footage mode writes (arena mode's
    are checked in test_boundary.py): a parameter of any other name cannot collide."""
    labels = write_collection(tmp_path / "clips", drifts=(0.0,), seeds=(1,))
    s = looming_boundary_settings(labels)
    res = boundary(s, tmp_path / "b")
    written = [p for p in res.paths if p.suffix == ".parquet"]
    assert {p.name for p in written} >= {"boundary_clips.parquet", "predictor_frames.parquet"}
    for path in written:
        extra = set(pq.read_schema(path).names) - OWN_COLUMNS - {"threshold"}
        assert not extra, (path.name, extra)


@pytest.mark.parametrize("command", ["tables", "batch", "complexity"])
def test_a_missing_recording_beside_its_partial_file_names_the_partial_file(
    tmp_path: Path, command: str
) -> None:
    """A killed capture left ``run.partial.rrd`` and no ``run.rrd``: the line names the
    partial recording and what to do, not just 'no such file'."""
    (tmp_path / "run.partial.rrd").write_bytes(b"RRF2" + bytes(60))
    extra = ["--model", "avdm"] if command == "batch" else []
    proc = run_in_process(
        "analysis", command, str(tmp_path / "run.rrd"), *extra, "--out", str(tmp_path / "o")
    )
    assert_one_line_error(proc, "run.partial.rrd", "analyse that file by name")
    assert not (tmp_path / "o").exists()

"""The recording contract checks itself: the recorder refuses what the contract does not know,
every capture writes its model description and a description of itself, and analysis names
what an old or foreign recording lacks instead of assuming it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from analysis.recordings.loading import load_recording
from analysis.recordings.reader import Recording, RecordingError
from analysis.recordings.recompute import build_tables
from avdm.stimuli import grating
from capture.closed_loop import ClosedLoopRobot
from capture.config import CameraConfig
from capture.recorder import Recorder
from capture.sim import SimSettings, record_sim
from capture.sim_robot import SimulatedRobot
from capture.video import VideoSettings, record_video
from tests.helpers import assert_one_line_error, make_sim_recording, write_video
from tests.in_process import run_in_process
from vdc.recording import EVENT_KINDS, PROPERTY_SECTIONS

MODEL_DESCRIPTION = ("model", "model_params", "model_context")


def test_the_recorder_refuses_unknown_sections_and_event_kinds(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "r.rrd", "contract")
    try:
        with pytest.raises(ValueError, match=r"'wal'.*allowed: run, arena, wall") as err:
            rec.send_properties({"run": {"recording_id": "contract"}, "wal": {"tf_hz": 1.0}})
        assert all(name in str(err.value) for name in PROPERTY_SECTIONS)
        one = (np.array([0]), np.array([0.0]), np.full((1, 2), np.nan), ["x"])
        with pytest.raises(ValueError, match=r"'bump'.*allowed: ring_turn") as err:
            rec.log_events("bump", *one)
        assert all(kind in str(err.value) for kind in EVENT_KINDS)
        rec.send_properties({"run": {"recording_id": "contract"}})  # what it knows passes
        rec.log_events("crash", *one)
    finally:
        rec.close(frames=0, stop_reason="test")
    props = Recording(tmp_path / "r.rrd").properties()
    assert "wal" not in props and props["run"]["recording_id"] == "contract"  # nothing of it


def test_a_simulated_run_describes_its_model_and_itself(tmp_path: Path) -> None:
    out = tmp_path / "sim.rrd"
    make_sim_recording(out, 0.02, tf_hz=3.0, model="avdm:beta=0.5")
    rec = Recording(out)
    props = rec.properties()
    assert set(MODEL_DESCRIPTION) <= set(props)
    assert props["model"]["name"] == "avdm:beta=0.5" and props["model_params"]["beta"] == 0.5
    assert props["model_context"] == CameraConfig().model_context()
    text = rec.description()
    assert text is not None and text.startswith(f"# vdc recording `{rec.recording_id}`")
    for needle in (
        "simulated Colias-IV",
        "`avdm:beta=0.5`",
        "`omega_dps` [deg/s]",
        "99 x 72 px at 33 Hz",
        "texture row 36",
        "vdc-analyse tables REC",
    ):
        assert needle in text, needle


@pytest.mark.parametrize("behaviour", ["profile", "collision"])
def test_the_simulated_device_describes_itself_in_its_recording(
    tmp_path: Path, behaviour: str
) -> None:
    """What the user sees in the viewer: the simulated device's properties and description,
    from the settings it was given (1.2 s at 33 Hz: 40 frames)."""
    settings = SimSettings(minutes=0.02, tf_hz=3.0, seed=7, behaviour=behaviour)
    device = (ClosedLoopRobot if behaviour == "collision" else SimulatedRobot)(settings.to_config())
    out = tmp_path / "sim.rrd"
    record_sim(settings, out)
    rec = Recording(out)
    props = rec.properties()
    # every section and value, as stored (None and "" are left out, lists and NaNs encoded)
    for name, section in device.properties().items():
        stored = {k: v for k, v in section.items() if v not in (None, "")}
        assert set(props[name]) == set(stored), name
        plain = {k: v for k, v in stored.items() if isinstance(v, str | int | float) and v == v}
        assert {k: props[name][k] for k in plain} == plain, name
    assert props["run"]["recording_id"] == rec.recording_id and props["run"]["seed"] == 7
    assert props["run"]["source"] == "simulation" and props["wall"]["tf_schedule_text"] == "3:1.2s"
    assert len(rec.read_frames().frame) == 40
    text = rec.description() or ""
    what = (
        f"a simulated Colias-IV in the 1.4 x 0.8 m arena ({behaviour}), grating walls, TF "
        "schedule 3:1.2s, 0.02 min (40 frames), seed 7"
    )
    if behaviour == "collision":
        detector = settings.to_config().collision.detector_spec()
        what += f"; closed loop with the collision detector {detector}"
        assert props["detector"]["name"] == detector
    assert f"**What**: {what}\n" in text, text


def test_a_video_recording_describes_its_model_and_itself(tmp_path: Path) -> None:
    # 33 fps over 70 deg on 99 px: the AVDM's shipped calibration (no fit in the test)
    frames = grating(size=(72, 100), fps=33.0, tf_hz=2.0, period_px=12, n_frames=30)
    clip = write_video(tmp_path / "g.mp4", frames, 33.0)
    out = tmp_path / "v.rrd"
    record_video(VideoSettings(str(clip), 70.0, model="avdm"), out)
    rec = Recording(out)
    props = rec.properties()
    assert set(MODEL_DESCRIPTION) <= set(props)
    assert props["model"]["true_time"] is True
    assert props["model_context"]["fps"] == 33.0 and props["model_context"]["width_px"] == 99
    text = rec.description()
    assert text is not None
    for needle in ("g.mp4", "`avdm`", "99 x 71 px at 33 Hz", "vdc-analyse complexity REC"):
        assert needle in text, needle
    # a recording without poses needs no arena: its tables build, the arena is not made up
    _, meta = build_tables([out], None)
    assert all(math.isnan(v) for v in meta["arena_half_extent_m"][rec.recording_id])


def foreign_recording(path: Path, sections: dict) -> Path:
    """A recording written without the capture's properties (as an older vdc or another tool
    would): frames, poses and one model's outputs."""
    rec = Recorder(path, path.stem)
    n = 30
    f, t = np.arange(n), np.arange(n) / 33.0
    rec.send_properties({"run": {"recording_id": path.stem}, "model": {"name": "avdm"}, **sections})
    rec.log_frames(f, t, np.zeros((n, 72, 99), np.uint8))
    rec.log_poses(f, t, np.column_stack([np.zeros(n), np.zeros(n), np.zeros(n)]))
    rec.log_model_outputs("avdm", f, t, {"omega_dps": np.ones(n)})
    rec.close(frames=n, stop_reason="finished")
    return path


def test_analysis_names_what_an_old_or_foreign_recording_lacks(tmp_path: Path) -> None:
    no_arena = foreign_recording(tmp_path / "no_arena.rrd", {})
    proc = run_in_process("analysis", "tables", str(no_arena), "--out", str(tmp_path / "t"))
    assert_one_line_error(proc, "old or foreign recording", "arena", "length_m, width_m")
    assert not (tmp_path / "t" / "frames.parquet").exists()
    # with its arena it tabulates its logged outputs; recomputing needs the camera it lacks
    arena = {"arena": {"length_m": 2.0, "width_m": 1.0}}
    path = foreign_recording(tmp_path / "no_camera.rrd", {**arena, "camera": {"fps": 33.0}})
    loaded = load_recording(path)
    assert loaded.arena_half_extent() == (1.0, 0.5)  # its own, not 1.4 x 0.8
    with pytest.raises(RecordingError, match=r"model_context.*width_px, height_px, hfov_deg"):
        loaded.camera_context()
    with pytest.raises(RecordingError, match="old or foreign"):
        build_tables([path], ["avdm"])
    tables, _ = build_tables([path], None)
    assert tables["frames"]["wall_gap_m"].to_list() == [0.5] * 30  # 1.0 m wide: 0.5 m to a wall


def test_an_empty_property_is_left_out_whatever_was_recorded_before(tmp_path: Path) -> None:
    """The same run's properties, whatever this process recorded before: Rerun keeps an empty
    string once the process has sent that field name with text (a natural scene's
    image_path), and drops it before, so a grating's wall section held image_path "" only
    after a natural scene (a suite-order failure of the test above)."""
    wall = {"scene": "grating", "image_path": ""}
    first = foreign_recording(tmp_path / "first.rrd", {"wall": wall})
    natural = foreign_recording(tmp_path / "natural.rrd", {"wall": wall | {"image_path": "a.png"}})
    after = foreign_recording(tmp_path / "after.rrd", {"wall": wall})
    assert Recording(natural).properties()["wall"]["image_path"] == "a.png"
    for path in (first, after):
        assert Recording(path).properties()["wall"] == {"scene": "grating"}, path.name


def test_a_section_without_values_is_no_property_and_no_warning(tmp_path: Path) -> None:
    """A plug-in without parameters has an empty model_params: sent as it was, the SDK warned
    "AnyValues: No valid component batches" on every robot capture and dropped it."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path = foreign_recording(tmp_path / "r.rrd", {"model_params": {}, "wall": {"scene": "x"}})
    assert not [w for w in caught if "component batches" in str(w.message)], caught
    props = Recording(path).properties()
    assert "model_params" not in props and props["wall"] == {"scene": "x"}

"""The bigger arena's parts: wall scenes by name (gratings of several periods and contrasts,
scikit-image's photographs) and wall TFs drawn from a continuous range."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from analysis.boundary.scenes import scene_fields
from analysis.boundary.settings import BoundarySettings
from analysis.experiments.captures import collision_run_item

SCENES = "grating,grating-p0.05,grating-p0.2-c0.3,natural-c0.5,photo-astronaut,photo-grass"


def test_scene_names_stand_for_their_sim_settings() -> None:
    assert scene_fields("grating") == {
        "scene": "grating",
        "period_m": 0.1,
        "contrast": 1.0,
        "image": None,
    }
    g = scene_fields("grating-p0.05-c0.3")
    assert (g["period_m"], g["contrast"]) == (0.05, 0.3)
    photo = scene_fields("photo-astronaut")
    assert photo["scene"] == "natural"
    # the file is scikit-image's own photograph: it reads as the astronaut
    from skimage import data

    img = cv2.imread(str(photo["image"]), cv2.IMREAD_GRAYSCALE)
    ref = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)
    assert img.shape == ref.shape and np.abs(img.astype(int) - ref).mean() < 2


# a scene name refused -> what its one line says
BAD_SCENES = {
    "photo-nope": "unknown photograph",
    "grating-p0": "period 0 m",
    "natural-p0.1": "only a grating",
    "walls": "unknown arena scene",
    "grating-c1.5": "contrast 1.5",
}


@pytest.mark.parametrize(("name", "needle"), BAD_SCENES.items())
def test_bad_scene_names_are_one_line(name: str, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        BoundarySettings(scenes=name)


def test_tfs_are_drawn_per_scene_from_the_range_one_per_stratum() -> None:
    s = BoundarySettings(scenes=SCENES, tf_draws=5, tf_range="0:4", seed=3)
    conds = s.conditions()
    assert len(conds) == 6 * 5  # 30 conditions over 6 scenes
    for scene in s.scene_list():
        tfs = np.array([tf for sc, tf in conds if sc == scene])
        # one TF in each fifth of 0-4 Hz (rounded to 0.01 Hz)
        assert np.array_equal(np.floor(np.minimum(tfs, 3.999) / 0.8), np.arange(5)), tfs
        assert tfs.tolist() == s.scene_tfs(scene)  # the same draw every time
    first = {tf for sc, tf in conds if sc == "grating"}
    assert first != {tf for sc, tf in conds if sc == "grating-p0.05"}  # scenes differ
    fewer = BoundarySettings(scenes="photo-grass,grating", tf_draws=5, tf_range="0:4", seed=3)
    assert {tf for sc, tf in fewer.conditions() if sc == "grating"} == first  # nor its place


def test_a_run_of_a_scene_is_configured_with_its_wall(tmp_path: Path) -> None:
    s = BoundarySettings(
        scenes=SCENES,
        tf_draws=2,
        tf_range="0:4",
        detector="flow-ttc",
        param="tau_alert_s",
        values="0.5",
        seeds=1,
        minutes=0.1,
    )
    run = collision_run_item(
        s, "grating-p0.2-c0.3", 1.5, 0.5, 1, tmp_path, {"scene": "grating-p0.2-c0.3"}
    )
    wall = run.settings.to_config().wall
    assert (wall.scene, wall.period_m, wall.contrast) == ("grating", 0.2, 0.3)
    assert run.columns["condition"] == "grating-p0.2-c0.3-tf1.5"
    photo = collision_run_item(s, "photo-grass", 1.5, 0.5, 1, tmp_path, {}).settings
    assert photo.to_config().wall.image_path.endswith("grass.png")
    assert photo.to_config().collision.detector == "flow-ttc:tau_alert_s=0.5"


def test_the_flow_detector_drives_the_robot_with_its_threshold_in_seconds() -> None:
    from capture.config import CollisionConfig

    assert CollisionConfig("flow-ttc", threshold=0.5).detector_spec() == (
        "flow-ttc:tau_alert_s=0.5"
    )
    with pytest.raises(ValueError, match="time to contact"):
        CollisionConfig("flow-ttc", threshold=20.0)  # 20 s: a spike rate, not a time

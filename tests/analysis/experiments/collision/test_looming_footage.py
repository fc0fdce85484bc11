"""The looming-footage generator: clips over real photographs through a real codec, labels by
construction (the hazard onset checked against the geometry recomputed here), a resumable
re-run, and the flow detector on its clips."""

from __future__ import annotations

import math
from pathlib import Path

import av
import numpy as np
import pytest

from analysis.boundary.labels import read_labels
from analysis.experiments.collision.looming_footage import (
    LoomingFootageSettings,
    draw_conditions,
    looming_footage,
)
from avdm.registry import make_model

SETTINGS = LoomingFootageSettings(clips=4, seconds=4.0, near_miss_share=0.5, seed=7)


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("looming")
    return out, looming_footage(SETTINGS, out)


def decode(path: Path) -> np.ndarray:
    with av.open(str(path)) as c:
        return np.stack([f.to_ndarray(format="gray") for f in c.decode(video=0)])


def test_labels_hold_impact_and_hazard_onset_by_construction(collection) -> None:
    out, _ = collection
    n = SETTINGS.n_frames
    labels = read_labels(out / "labels.csv")  # the boundary's own reader accepts the table
    assert labels.height == SETTINGS.clips
    assert set(labels["label"]) == {"collision", "near-miss"}  # seed 7 draws both
    f = (SETTINGS.width_px / 2) / math.tan(math.radians(SETTINGS.hfov_deg) / 2)
    for row in labels.iter_rows(named=True):
        collision = row["label"] == "collision"
        assert row["collision_frame"] == (n - 1 if collision else None)
        onset = row["hazard_onset_frame"]
        # the geometry, recomputed: image radius f * (R/v) / tau >= 1 px, centre in view, and
        # not before the object enters the scene
        enter = n - 1 - round(row["enter_s"] * SETTINGS.fps)

        def visible(t: int, row=row, enter=enter) -> bool:
            tau = (n - 1 - t) / SETTINGS.fps
            ang = math.atan(row["miss_radii"] * row["rv_s"] / tau) + math.radians(
                row["rotation_dps"] * tau
            )
            off = abs(f * math.tan(ang)) if abs(ang) < math.radians(89) else math.inf
            return t >= enter and f * row["rv_s"] / tau >= 1 and off < SETTINGS.width_px / 2

        if onset is None:  # a near miss may pass without coming into view: nothing drawn
            assert not collision and not any(visible(t) for t in range(n - 1)), row
            continue
        assert visible(onset) and not visible(onset - 1), row
        assert 0 < onset < n - 1
        assert row == row | draw_conditions(SETTINGS, int(row["clip"][4:8]))


def test_clips_are_h264_at_the_stated_rate_and_the_object_appears_at_onset(collection) -> None:
    out, res = collection
    row = res.labels.row(0, named=True)
    path = out / row["clip"]
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        assert stream.codec_context.name == "h264"
        assert float(stream.average_rate) == SETTINGS.fps
    frames = decode(path).astype(np.float64)
    assert frames.shape == (SETTINGS.n_frames, SETTINGS.height_px, SETTINGS.width_px)
    onset = row["hazard_onset_frame"]
    # before the onset only the panned scene changes; the object adds change from its onset
    # on, and by the last frame it covers a large part of a collision's view
    assert not (out / (path.stem + ".partial.mp4")).exists()
    if row["label"] == "collision":
        last, before = frames[-1], frames[onset - 1]
        assert np.abs(last - before).mean() > 5  # grey levels: the object is there


def test_a_rerun_reuses_every_clip(collection) -> None:
    out, res = collection
    again = looming_footage(SETTINGS, out)
    assert again.reused == SETTINGS.clips
    assert again.labels.equals(res.labels)


def test_the_flow_detector_alerts_on_collisions_in_the_encoded_clips(collection) -> None:
    """Through the codec, on the brightest, least noisy collision clip of a larger draw: the
    flow detector's first alert comes before contact."""
    out, res = collection
    rows = res.labels.filter(res.labels["label"] == "collision").sort("light", descending=True)
    row = rows.row(0, named=True)
    frames = decode(out / row["clip"])
    model = make_model("flow-ttc", fps=SETTINGS.fps)
    alert = model.run(frames)["alert"]
    assert not alert[: row["hazard_onset_frame"]].any()  # nothing approaches yet
    assert alert.any() and int(np.argmax(alert > 0)) < row["collision_frame"]


def test_bad_settings_are_one_line() -> None:
    for kw, needle in (
        ({"clips": 0}, "LoomingFootageSettings.clips"),
        ({"seconds": 2.0}, "too short"),
        ({"near_miss_share": 1.5}, "near_miss_share"),
    ):
        with pytest.raises(ValueError, match=needle):
            LoomingFootageSettings(**kw)


def test_the_amended_collection_has_21_photographs_none_its_own_object() -> None:
    """The 2026-12 collection (docs/findings/power_plan_amendment.md): clip k over photograph
    k mod 21, each a package's own photograph file; the looming object is never the clip's
    background; the other draws are the 2026-11 collection's (same generator, same order)."""
    from analysis.experiments.collision.looming_footage import (
        PHOTOS_2026_12,
        LoomingFootageSettings,
        _photo,
        draw_conditions,
    )

    s = LoomingFootageSettings(collection="2026-12", clips=42)
    old = LoomingFootageSettings(clips=42)
    drawn = [draw_conditions(s, k) for k in range(42)]
    assert len(PHOTOS_2026_12) == 21
    counts: dict[str, int] = {}
    for k, c in enumerate(drawn):
        counts[str(c["background"])] = counts.get(str(c["background"]), 0) + 1
        assert c["object"] != c["background"]
        assert c["rotation_dps"] == draw_conditions(old, k)["rotation_dps"]
    assert counts == {name: 2 for name in PHOTOS_2026_12}
    for name in PHOTOS_2026_12:  # every one loads from the installed packages
        img = _photo(name)
        assert min(img.shape[:2]) >= 100 and img.std() > 5, (
            name
        )  # a picture, not a blank (the retina crop: 9.9)

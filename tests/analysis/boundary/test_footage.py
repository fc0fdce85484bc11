"""Footage mode of ``vdc-analyse boundary`` on labelled clips the tests render and encode
themselves: a dark object looming over textured backgrounds drifting at known speeds, and the
same backgrounds with nothing colliding."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq
import pytest

from analysis.boundary.settings import BoundarySettings
from analysis.experiments.collision.boundary_campaign import boundary
from tests.figures import assert_figure, recording_figures
from tests.footage_clips import COLLISION_FRAME, FPS, write_collection
from tests.helpers import assert_one_line_error, flags
from tests.in_process import run_in_process
from vdc.executors import Feedback

DRIFTS = (0.0, 0.5, 1.0, 2.0, 4.0)  # px per frame: five groups of clips, ever busier
WINDOW_S = 1.0


@pytest.fixture(scope="module")
def labels(tmp_path_factory) -> Path:
    return write_collection(tmp_path_factory.mktemp("clips"), DRIFTS)


def settings(
    labels: Path, detector: str, param: str, values: str, min_ttc_s: float = 0.5
) -> BoundarySettings:
    return BoundarySettings(
        labels=str(labels),
        fov_deg=60.0,
        detector=detector,
        param=param,
        values=values,
        alert_window_s=WINDOW_S,
        min_ttc_s=min_ttc_s,
        jobs=2,
    )


def test_the_toy_detectors_constructed_boundary_is_found(labels: Path, tmp_path: Path) -> None:
    """The toy is blind once the AVDM's running mean exceeds ``blind_above_dps``: the boundary
    found for each value brackets that value (the grid's spacing is the interval)."""
    with recording_figures() as figures:
        res = boundary(
            settings(labels, "tests.toy_detector:BlindAbove", "blind_above_dps", "6.5,12.5"),
            tmp_path,
        )
    groups = res.conditions.filter(pl.col("blind_above_dps") == 6.5).sort("complexity_dps")
    assert groups.height == len(DRIFTS)  # clips of one drift speed make one group
    assert (groups["complexity_dps"].diff().drop_nulls() > 2).all()  # busier, group by group
    for row in res.boundaries.iter_rows(named=True):
        truth = row["blind_above_dps"]
        assert row["where"] == "within"
        assert row["boundary_low_dps"] < truth <= row["boundary_high_dps"]
        # the curve fitted over the clips themselves: its 95 % interval covers the truth
        assert row["fit_state"] == "within", row
        assert row["boundary_dps_low"] <= truth <= row["boundary_dps_high"], row
    clips = res.runs
    seen = clips.filter(pl.col("collision") & pl.col("hit"))
    assert seen.height > 0 and (seen["ttc_first_alert_s"] > 0).all()
    assert (seen["ttc_first_alert_s"] <= WINDOW_S).all()
    assert not clips.filter(~pl.col("collision"))["false_alarm"].any()  # it never cries wolf
    md = (tmp_path / "boundary.md").read_text()
    assert "## Per clip" in md and "hit rate" in md
    assert_figure(tmp_path / "boundary.png", figures, title="success", labels=("success (%)",))


def test_the_readme_looming_detector_breaks_on_busy_backgrounds(
    labels: Path, tmp_path: Path
) -> None:
    # scored with --min-ttc-s 0 (any alert inside the window is a hit): this test is about
    # where the drift breaks it, not how early it alerts (0.5 s made its still hits misses)
    cfg = settings(labels, "examples.looming:Looming", "threshold", "0.05", min_ttc_s=0.0)
    said: list[str] = []
    res = boundary(cfg, tmp_path, Feedback(said.append))
    # the labels name no scene: the run says, in one line, that its clips are independent
    assert sum(line.startswith("Clips taken as independent") for line in said) == 1, said
    assert "Clips taken as independent" in (tmp_path / "boundary.md").read_text()
    kv = pq.read_schema(tmp_path / "predictors.parquet").metadata  # and in the table itself
    assert json.loads(kv[b"vdc.units_note"]).startswith("Clips taken as independent")
    clips = res.runs
    still = clips.filter(pl.col("clip").str.contains("drift0-"))
    assert still.filter(pl.col("collision"))["hit"].all()  # on a still background it works
    assert not still["false_alarm"].any()
    busy = clips.filter(pl.col("clip").str.contains("drift4-"))
    assert busy.filter(~pl.col("collision"))["false_alarm"].all()  # the drift excites it
    assert not busy["hit"].any()  # and its alerts come long before the object does
    summary = pl.read_parquet(tmp_path / "boundary_summary.parquet").row(0, named=True)
    assert summary["hit_rate_low"] < summary["hit_rate"] < summary["hit_rate_high"]
    assert summary["clips"] == 4 * len(DRIFTS)
    b = res.boundaries.row(0, named=True)
    assert b["where"] == "within"
    hits = clips.filter(pl.col("hit"))
    assert (hits["collision_frame"] == COLLISION_FRAME).all()
    frames_ahead = hits["ttc_first_alert_s"].to_numpy() * FPS  # whole frames before the hit
    assert np.allclose(frames_ahead, np.round(frames_ahead)) and (frames_ahead >= 0).all()
    assert (frames_ahead <= WINDOW_S * FPS).all()


def test_the_flow_detector_is_not_fooled_by_the_drift(labels: Path, tmp_path: Path) -> None:
    """flow-ttc (registered, not a plug-in) in footage mode: the drift translates the image
    without expanding it, so where the frame-difference example breaks (above) the flow
    detector neither cries wolf nor misses at any drift; the small uniform disc expands only
    at its rim, so its alerts come late (under 0.5 s before the collision, inside the window)."""
    # its alerts come under 0.5 s before impact (asserted below): with the default
    # --min-ttc-s 0.5 they are too late to turn away, so it is judged on alerting at all
    res = boundary(settings(labels, "flow-ttc", "tau_alert_s", "1", min_ttc_s=0.0), tmp_path)
    clips = res.runs
    assert not clips["false_alarm"].any()
    collisions = clips.filter(pl.col("collision"))
    assert collisions["hit"].all() and collisions.height == 2 * len(DRIFTS)
    assert (collisions["ttc_first_alert_s"] > 0).all()
    assert (collisions["ttc_first_alert_s"] < 0.5).all()
    assert res.boundaries.row(0, named=True)["where"] == "beyond"  # it never breaks here


@pytest.mark.parametrize(
    ("table", "needles"),
    [
        ("clip,label\nx.mp4,looming\n", ["has no column collision_frame"]),
        ("clip,label,collision_frame\nnothere.mp4,looming,10\n", ["not there: nothere.mp4"]),
        ("clip,label,collision_frame\n{clip},looming,-3\n", ["collision_frame must be"]),
        (
            "clip,label,collision_frame,hazard_onset_frame\n{clip},looming,30,x\n",
            ["hazard_onset_frame must be"],
        ),
        (  # a scene for some clips and not others: which clips share what is unknown
            "clip,label,collision_frame,scene\n{clip},looming,30,\n",
            ["has no scene", "every clip's scene"],
        ),
    ],
)
def test_a_bad_labels_table_is_one_line(labels: Path, tmp_path: Path, table: str, needles) -> None:
    clip = labels.parent / "bg-drift0-s1.mp4"
    path = tmp_path / "labels.csv"
    path.write_text(table.replace("{clip}", str(clip)))
    proc = run_in_process(
        "analysis.cli",
        "boundary",
        *flags(
            "--fov-deg 60 --detector examples.looming:Looming --param threshold --values 0.1",
            labels=path,
            out=tmp_path / "o",
        ),
    )
    assert_one_line_error(proc, *needles)


@pytest.mark.parametrize(
    ("first_alert", "collision", "failure"),
    [
        (None, 100, "miss"),  # never alerted
        (95, 100, "miss"),  # 5 frames = 0.2 s before impact: under 0.5 s, too late to turn
        (100, 100, "miss"),  # at the moment of impact: no longer a hit
        (80, 100, "hit"),  # 0.8 s before: inside the 2 s window, above the 0.5 s minimum
        (20, 100, "early"),  # 3.2 s before: earlier than the window
        (40, None, "false_alarm"),  # an alert where nothing collides
        (None, None, "quiet"),
    ],
)
def test_failures_are_scored_apart(first_alert, collision, failure) -> None:
    """A miss, an early alert and a false alarm are different failures (their signs oppose
    on real footage), scored apart; an alert later than the minimum time to contact is a
    miss. 25 fps: a frame is 0.04 s."""
    from analysis.boundary.footage import judge_clip

    frames = np.arange(120)
    alert = np.zeros(120)
    if first_alert is not None:
        alert[first_alert:] = 1.0
    row = judge_clip(frames, alert, 25.0, collision, 2.0, min_ttc_s=0.5)
    assert row["failure"] == failure
    assert row["hit"] == (failure == "hit")
    assert row["correct"] == (failure in ("hit", "quiet"))


@pytest.mark.parametrize(
    ("first_alert", "collision", "failure"),
    [
        (20, 100, "hit"),  # 3.2 s before contact but after the object entered: seen in time
        (9, 100, "early"),  # before the object was in view: the scene set it off
        (90, 100, "miss"),  # 0.4 s before contact: too late, onset or not
        (None, 100, "miss"),
        (9, None, "early"),  # a near miss: an alert before its object enters
        (40, None, "false_alarm"),  # after it entered
        (None, None, "quiet"),
    ],
)
def test_with_the_hazards_onset_early_means_before_it(first_alert, collision, failure) -> None:
    """Where the labels give the onset (frame 10 here), the object's own entry divides the
    scene from the hazard, not the fixed alert window (2 s): an object in view 3.6 s before
    contact and seen at once is a hit (issue 45: the plan's rule, footage mode's too)."""
    from analysis.boundary.footage import judge_clip

    frames = np.arange(120)
    alert = np.zeros(120)
    if first_alert is not None:
        alert[first_alert:] = 1.0
    row = judge_clip(frames, alert, 25.0, collision, 2.0, 0.5, hazard_onset_frame=10)
    assert row["failure"] == failure
    assert row["hit"] == (failure == "hit")
    assert row["false_alarm"] == (failure in ("early", "false_alarm"))

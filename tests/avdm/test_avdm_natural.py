"""The AVDM on real footage: real photographs (scikit-image's own files) panned at known speeds,
through H.264; the multi-scale variant against its plain reference; calibration for any
dynamics."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.complexity.avdm_truth import Cell, cell_frames, measure_truth_cell
from avdm import make_model
from avdm.avdm_multiscale import MULTISCALE_OUTPUT_NAMES
from avdm.calibration_store import calibration_for, lookup_calibration
from avdm.reference_multiscale import AvdmMultiScaleReference
from avdm.stimuli import grating

ROBOT = {"fps": 30.0, "deg_per_px": 70 / 99}


@pytest.fixture(scope="module")
def panned() -> np.ndarray:
    """A real photograph panned at 40 deg/s through H.264, at the robot camera's raster."""
    return cell_frames(Cell("astronaut", 40.0, 1, 30.0, "robot", "h264"), 45)


def test_run_equals_step_and_chunks_bit_for_bit(panned) -> None:
    whole = make_model("avdm-natural", **ROBOT).run(panned)
    stepper = make_model("avdm-natural", **ROBOT)
    steps = [stepper.step(f) for f in panned]
    chunked = make_model("avdm-natural", **ROBOT)
    parts = [chunked.run(panned[i : i + 7]) for i in range(0, len(panned), 7)]
    for key in MULTISCALE_OUTPUT_NAMES:
        assert np.array_equal(whole[key], [s[key] for s in steps]), key
        assert np.array_equal(whole[key], np.concatenate([p[key] for p in parts])), key


@pytest.mark.parametrize("size", [(72, 99), (232, 320)])
def test_fast_kernel_matches_the_plain_reference(size) -> None:
    cell = Cell("coffee", 80.0, -1, 25.0, "robot" if size == (72, 99) else "video", "none")
    frames = cell_frames(cell, 30)
    fps, dpp = 25.0, 70.0 / size[1]
    # the decoding's gain and exponent given (the shipped ones, rounded): the kernel and the
    # reference share them, and a new camera's calibration fit (10 s) is not what is compared
    model = make_model(
        "avdm-natural", fps=fps, deg_per_px=dpp, width_px=size[1], height_px=size[0], a=1.1, b=1.0
    )
    fast = model.run(frames)
    ref = AvdmMultiScaleReference(model.params).run(frames)
    for key in MULTISCALE_OUTPUT_NAMES:
        # the kernel keeps images in float32 (the reference in float64) and sums in another
        # order: ~1e-6 relative apart; 1e-4 is ample on any CPU and far below any effect
        np.testing.assert_allclose(fast[key], ref[key], rtol=1e-4, atol=1e-9, err_msg=key)


# the band docs/guides/video.md gives for avdm-natural: 80 % of the protocol's cell readings lie
# within 0.79-1.12x the truth (up to 80 deg/s; the two cells here read 0.86-0.92x, 300 deg/s
# included)
NATURAL_BAND = (0.79, 1.12)


@pytest.mark.parametrize(
    ("image", "speed", "fps"), [("astronaut", 80.0, 30.0), ("gravel", 300.0, 25.0)]
)
def test_avdm_natural_reads_true_speed_in_both_directions(image, speed, fps) -> None:
    """Held to the bounds docs/guides/video.md states for single cells of avdm-natural (its "Tests
    hold" paragraph): each direction's reading inside the 0.79-1.12x band, and the two
    directions within 10 % of each other, through H.264 at the robot camera's pitch. The
    per-speed median error (<= 10 %) is over 64 cells a speed: the benchmark's, not this
    test's."""
    read = {}
    for d in (1, -1):
        rows = measure_truth_cell(Cell(image, speed, d, fps, "robot", "h264"), ["avdm-natural"])
        read[d] = rows[0]["omega_dps"]
        low, high = NATURAL_BAND
        assert low < read[d] / speed < high, (d, read[d])
        assert rows[0]["valid_share"] == 1.0  # inside the valid regime on every frame
    assert abs(read[1] - read[-1]) / ((read[1] + read[-1]) / 2) < 0.10


def test_faithful_avdm_holds_in_its_stated_range_and_fails_beyond_it() -> None:
    """docs/guides/video.md states the faithful avdm's behaviour on natural footage at 25-30 fps: at
    10 deg/s on the robot raster (0.47 px/frame) 80 % of cell readings lie within 0.25-2x the
    truth; beyond about 1 px per frame the reading falls relative to the truth (median over
    the protocol's cells 0.40x at 40 deg/s, 0.13x at 160 deg/s) although the speed rises: the
    reason avdm-natural exists. One image's cells are held to what one cell can show: inside
    the band at 10 deg/s; at 160 deg/s below the protocol's 90th percentile there (0.42x on
    the robot raster at 30 fps through H.264; this cell reads 0.20x) and below its own
    reading at 40 deg/s relative to the truth; and flagged on some frames."""
    for d in (1, -1):
        row = measure_truth_cell(Cell("astronaut", 10.0, d, 30.0, "robot", "h264"), ["avdm"])[0]
        assert 0.25 < row["omega_dps"] / 10.0 < 2.0, (d, row["omega_dps"])
    fast = measure_truth_cell(Cell("astronaut", 160.0, 1, 30.0, "robot", "h264"), ["avdm"])[0]
    mid = measure_truth_cell(Cell("astronaut", 40.0, 1, 30.0, "robot", "h264"), ["avdm"])[0]
    assert fast["omega_dps"] / 160.0 < 0.42  # far below the truth at 7.5 px/frame
    assert fast["omega_dps"] / 160.0 < mid["omega_dps"] / 40.0
    assert fast["valid_share"] < 1.0  # and its flag says so on some frames


def test_omega_valid_marks_warm_up_and_textureless_frames(panned) -> None:
    out = make_model("avdm-natural", **ROBOT).run(panned)
    assert (out["omega_valid"][:9] == 0).all() and (out["omega_valid"][10:] == 1).all()
    flat = np.full((20, 72, 99), 128, np.uint8)
    still = make_model("avdm-natural", **ROBOT).run(flat)
    assert (still["omega_valid"] == 0).all() and (still["omega_dps"] == 0).all()
    faithful = make_model("avdm", **ROBOT).run(panned)
    assert (faithful["omega_valid"][:9] == 0).all()
    assert set(np.unique(faithful["omega_valid"])) <= {0.0, 1.0}


def test_a_variant_with_other_dynamics_gets_its_own_calibration() -> None:
    """avdm:beta=0.5 used to keep the default calibration and read ~14 % low; now it is fitted
    for its own dynamics and reads deg/s within the fit's own stated error."""
    ctx = {"fps": 33.0, "deg_per_px": 70 / 99}
    default = make_model("avdm", **ctx)
    changed = make_model("avdm:beta=0.5", **ctx)
    assert default.params.a == lookup_calibration(33.0, 70 / 99)["a"]  # shipped, unchanged
    cal = calibration_for(33.0, 70 / 99, params=changed.params)
    assert cal["source"] in ("fitted", "cache") and cal["key"]["dynamics"]["beta"] == 0.5
    assert changed.params.a == cal["a"] != default.params.a
    # a grating inside the valid band: 12 px period, 2 Hz → 16.97 deg/s
    frames = grating(size=(72, 99), fps=33.0, tf_hz=2.0, period_px=12.0, n_frames=120)
    truth = 2.0 * 12.0 * 70 / 99
    honest = changed.run(frames)["omega_dps"][40:].mean()
    assert abs(honest - truth) / truth < cal["max_rel_error"]
    # the texture row is no part of the dynamics: the robot camera's H/2 row keeps the fit
    assert make_model("avdm", texture_row=36, **ctx).params.a == default.params.a

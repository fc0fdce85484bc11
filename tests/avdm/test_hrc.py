"""The Hassenstein–Reichardt correlator (``hrc``): a registered model like the others, signed by
the direction of a real panned photograph, and tuned to temporal frequency, not velocity."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.complexity.avdm_truth import Cell, cell_frames
from avdm import canonical_name, make_model, make_params, parse_model_spec
from avdm.hrc import HRC_OUTPUT_NAMES, Hrc, HrcParams
from avdm.registry import check_detector, require_angular_velocity
from avdm.stimuli import grating
from vdc.recording import camera_model_context

ROBOT = camera_model_context(99, 72, 30.0, 70.0)  # the robot camera's raster, 30 fps
WARM = 20  # the protocol's warm-up (2·tw)


@pytest.fixture(scope="module")
def panned() -> np.ndarray:
    """A real photograph panned at 10 deg/s through H.264 at the robot camera's raster."""
    return cell_frames(Cell("grass", 10.0, 1, 30.0, "robot", "h264"), 40)


def test_hrc_conforms_to_the_registry(panned) -> None:
    """What every registered model gives: built from the camera context, a step on one frame
    returns every declared output, run = step = chunks bit for bit, reset forgets, overrides
    parse and round-trip, bad ones name the problem, and it counts as an angular-velocity
    model."""
    check_detector("hrc", ROBOT, (72, 99), alert=False)
    require_angular_velocity("hrc", "complexity")
    whole = make_model("hrc", **ROBOT).run(panned)
    stepper = make_model("hrc", **ROBOT)
    steps = [stepper.step(f) for f in panned]
    chunked = make_model("hrc", **ROBOT)
    parts = [chunked.run(panned[i : i + 7]) for i in range(0, len(panned), 7)]
    chunked.reset()
    again = chunked.run(panned)
    assert set(whole) == set(HRC_OUTPUT_NAMES)
    for key in HRC_OUTPUT_NAMES:
        assert np.array_equal(whole[key], [s[key] for s in steps]), key
        assert np.array_equal(whole[key], np.concatenate([p[key] for p in parts])), key
        assert np.array_equal(whole[key], again[key]), key
    p = make_params("hrc", **ROBOT)  # the response curve measured for this camera, filled in
    assert p.fps == 30.0 and None not in (p.r_peak, p.v_peak_dps, p.knee, p.change_max)
    assert type(p)(**p.to_dict()) == p
    # constants given by the user win (and spare a calibration of these dynamics)
    fixed = "hrc:tau_ms=50,tw=6,r_peak=0.5,v_peak_dps=30,knee=1,change_max=1"
    q = make_params(fixed, **ROBOT)
    assert (q.tau_ms, q.tw, q.r_peak, q.v_peak_dps) == (50.0, 6, 0.5, 30.0)
    assert make_model(fixed).name.startswith("hrc:change_max=1.0,knee=1.0,r_peak=0.5,tau_ms")
    assert parse_model_spec(canonical_name("hrc:knee=1.5")) == ("hrc", {"knee": 1.5})
    for spec, message in [("hrc:tw=0", "tw=0"), ("hrc:gain=1", "unknown parameter 'gain'")]:
        with pytest.raises(ValueError, match=message):
            make_params(spec)


def test_sign_follows_the_direction_of_a_panned_photograph(panned) -> None:
    """A view turning toward +x moves the image toward −x: R̄ and the signed reading are
    negative on every frame after the warm-up; the other way, positive. At 10 deg/s (inside
    the valid range, below v_peak ≈ 23-25 deg/s) the speed is read within 25 % (this cell
    reads 0.99×; the calibration is on 1/f clutter, not on this photograph) and the two
    directions within 10 % of each other."""
    minus = make_model("hrc", **ROBOT).run(panned)
    back = cell_frames(Cell("grass", 10.0, -1, 30.0, "robot", "h264"), 40)
    plus = make_model("hrc", **ROBOT).run(back)
    assert (minus["response"][WARM:] < 0).all() and (minus["omega_signed_dps"][WARM:] < 0).all()
    assert (plus["response"][WARM:] > 0).all() and (plus["omega_signed_dps"][WARM:] > 0).all()
    speeds = [minus["omega_dps"][WARM:].mean(), plus["omega_dps"][WARM:].mean()]
    assert all(0.75 < s / 10.0 < 1.25 for s in speeds), speeds
    assert abs(speeds[0] - speeds[1]) / np.mean(speeds) < 0.10
    assert (minus["omega_valid"][WARM:] == 1).all() and (minus["omega_valid"][:9] == 0).all()


def test_past_its_peak_it_reads_slow_and_says_so() -> None:
    """80 deg/s is past the correlator's peak: it reads a fraction of the truth (the HRC
    cannot tell), and the non-directional change pathway flags every frame invalid."""
    fast = make_model("hrc", **ROBOT).run(
        cell_frames(Cell("grass", 80.0, 1, 30.0, "robot", "h264"))
    )
    assert fast["omega_dps"][WARM:].mean() < 0.5 * 80.0
    assert (fast["omega_valid"][WARM:] == 0).all()


def test_response_to_drifting_gratings_peaks_at_a_temporal_frequency() -> None:
    """The HRC signature: for two spatial periods (12 and 24 px, 8.5 and 17°) the response
    peaks at the same temporal frequency, so at velocities a factor 2 apart. The first-order
    delay filter held over frames predicts the peak at cos(2πf/fps) = 2β/(1+β²), β =
    e^(−1/(fps·τ)): 4.0 Hz at 30 fps and τ = 35 ms; the grid's 3-5 Hz brackets it. Raw
    response only: the decoding constants play no part (set to 1)."""
    p = HrcParams(
        fps=30.0, deg_per_px=70 / 99, r_peak=1.0, v_peak_dps=1.0, knee=1.0, change_max=1.0
    )
    tfs = np.array([0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0])
    peaks = {}
    for period in (12.0, 24.0):
        resp = []
        for tf in tfs:
            frames = grating(size=(72, 99), fps=30.0, tf_hz=tf, period_px=period, n_frames=40)
            resp.append(Hrc(p).run(frames)["response"][WARM:].mean())
        resp = np.abs(resp)  # the sign is the drift's direction; tuning is about size
        i = int(np.argmax(resp))
        assert 3.0 <= tfs[i] <= 5.0, (period, resp)
        # an interior peak: well above both ends of the range
        assert resp[i] > 1.5 * resp[0] and resp[i] > 1.5 * resp[-1], (period, resp)
        peaks[period] = tfs[i]
    assert peaks[12.0] == peaks[24.0]  # the same TF: 2x apart in velocity (TF·period)

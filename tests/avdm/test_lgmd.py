"""LGMD+ and the Colias firmware port: fast ≡ reference, run ≡ step, the §2.4 behaviours."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from avdm import make_model, make_params
from avdm.lgmd_params import LGMD_OUTPUT_NAMES, bias_matrix
from avdm.lgmd_reference import LgmdColiasReference, LgmdPlusReference
from avdm.stimuli import grating

REFERENCES = {"lgmd-plus": LgmdPlusReference, "lgmd-colias": LgmdColiasReference}


def looming_square(n: int = 60, h: int = 72, w: int = 99, dark: int = 30) -> np.ndarray:
    """A dark square on a bright background growing ever faster until it fills the view."""
    frames = np.full((n, h, w), 200, np.uint8)
    for i in range(n):
        half = int(2 + (i / n) ** 3 * 60)
        frames[i, max(0, h // 2 - half) : h // 2 + half, max(0, w // 2 - half) : w // 2 + half] = (
            dark
        )
    return frames


def fills_view_at(frames: np.ndarray) -> int:
    return int(np.flatnonzero((frames < 100).all(axis=(1, 2)))[0])


@pytest.mark.parametrize(
    "spec",
    ["lgmd-plus", "lgmd-colias", "lgmd-plus:blur_truncate=false", "lgmd-colias:border=1,n_alert=2"],
)
def test_fast_path_matches_the_reference(spec: str) -> None:
    model = make_model(spec)
    ref = REFERENCES[spec.split(":")[0]](model.params)
    rng = np.random.default_rng(3)
    for frames in (looming_square(), rng.integers(0, 256, (20, 40, 50), dtype=np.uint8)):
        model.reset()
        ref.reset()
        a, b = model.run(frames), ref.run(frames)
        for key in LGMD_OUTPUT_NAMES:
            # both in float64 and without fast-math, so they differ only by summation order
            # (~1e-13 relative over 7,128 px); a spike decision could flip only for a value
            # within that of its threshold, which uint8 inputs do not produce in practice
            np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-9, err_msg=key)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    frames=hnp.arrays(
        np.uint8, st.tuples(st.integers(1, 6), st.integers(33, 40), st.integers(33, 45))
    ),
    spec=st.sampled_from(["lgmd-plus", "lgmd-colias"]),
)
def test_any_frames_match_the_reference(frames: np.ndarray, spec: str) -> None:
    model = make_model(spec)
    a = model.run(frames)
    b = REFERENCES[spec](model.params).run(frames)
    for key in LGMD_OUTPUT_NAMES:
        assert np.isfinite(a[key]).all()
        # float64 both ways: summation order only (see test_fast_path_matches_the_reference)
        np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-9, err_msg=key)


@pytest.mark.parametrize("spec", ["lgmd-plus", "lgmd-colias"])
def test_run_equals_step_bit_for_bit(spec: str) -> None:
    frames = looming_square()
    whole = make_model(spec).run(frames)
    stepper = make_model(spec)
    steps = [stepper.step(f) for f in frames]
    chunked = make_model(spec)
    parts = [chunked.run(frames[i : i + 7]) for i in range(0, len(frames), 7)]
    for key in LGMD_OUTPUT_NAMES:
        assert np.array_equal(whole[key], [s[key] for s in steps]), key
        assert np.array_equal(whole[key], np.concatenate([p[key] for p in parts])), key


@pytest.mark.parametrize("spec", ["lgmd-plus", "lgmd-colias"])
def test_static_frame_gives_no_spikes(spec: str) -> None:
    frames = np.repeat(looming_square()[30:31], 40, axis=0)
    out = make_model(spec).run(frames)
    assert out["spikes"].sum() == 0 and out["alert"].sum() == 0
    if spec == "lgmd-plus":
        assert out["smp"][-1] == pytest.approx(0.5) and out["sfa"][-1] == pytest.approx(0.5)


@pytest.mark.parametrize("spec", ["lgmd-plus", "lgmd-colias"])
def test_looming_dark_square_alerts_before_it_fills_the_view(spec: str) -> None:
    frames = looming_square()
    out = make_model(spec).run(frames)
    alerts = np.flatnonzero(out["alert"])
    assert len(alerts) > 0
    assert alerts[0] < fills_view_at(frames) - 3


def test_full_view_drifting_grating_is_suppressed_by_feed_forward_inhibition() -> None:
    frames = grating(size=(72, 99), fps=33.0, tf_hz=6.0, period_px=15.0, n_frames=60)
    out = make_model("lgmd-plus").run(frames)
    assert out["ffi"][10:].min() > make_params("lgmd-plus").t_ffi  # β = F / T_ffi ≫ W_base
    assert out["alert"].sum() == 0


def test_bias_matrix_inhibits_less_in_the_centre() -> None:
    p = make_params("lgmd-plus")
    wloc = bias_matrix(72, 99, p.std_w, p.w_min)
    assert wloc[36, 49] == pytest.approx(0.223, abs=0.002)
    assert wloc[36, 0] == pytest.approx(0.991, abs=0.002)
    assert wloc.min() >= p.w_min


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("lgmd-plus:t_sr=-1", "t_sr"),
        ("lgmd-plus:n_ts=0", "n_ts"),
        ("lgmd-plus:fps=2000", "fps"),
        ("lgmd-colias:border=x", "integer"),
        ("lgmd-plus:dc=1.5", "dc"),
    ],
)
def test_bad_parameters_are_refused(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_model(spec)


def test_frames_inside_the_border_are_required() -> None:
    with pytest.raises(ValueError, match="border"):
        make_model("lgmd-colias").run(np.zeros((3, 20, 20), np.uint8))

"""The AVDM: the behaviours the authors describe, under our defaults, and fast ≡ reference."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from avdm import make_model, make_params
from avdm.avdm_model import OUTPUT_NAMES, Avdm
from avdm.reference import AvdmReference
from avdm.stimuli import grating

FPS = 300.0
SIZE = (100, 100)  # (H, W): 3.6 deg/px
WARM = 20  # 2·Tw frames


def mean_after_warmup(out: dict[str, np.ndarray], key: str = "omega_dps") -> float:
    return float(out[key][WARM:].mean())


def respond(
    period_px: float, tf_hz: float, *, spec: str = "avdm", n: int | None = None, **kw
) -> dict:
    """Outputs of a fresh model on a grating lasting at least one full temporal cycle."""
    if n is None:
        n = max(320, WARM + int(np.ceil(FPS / tf_hz))) if tf_hz > 0 else 320
    frames = grating(size=SIZE, fps=FPS, tf_hz=tf_hz, period_px=period_px, n_frames=n, **kw)
    return make_model(spec).run(frames)


def assert_matches_reference(model: Avdm, frames: np.ndarray) -> None:
    fast = model.run(frames)
    ref = AvdmReference(model.params).run(frames)
    for key in ref:  # the six layer outputs; omega_valid is derived from them
        # the fast path multiplies in float32: agree to float32 rounding
        np.testing.assert_allclose(fast[key], ref[key], rtol=2e-5, atol=1e-9, err_msg=key)
    np.testing.assert_array_equal(fast["lambda_px"], ref["lambda_px"])
    np.testing.assert_array_equal(fast["contrast"], ref["contrast"])


@pytest.mark.parametrize(
    "spec",
    [
        "avdm",
        "avdm-on",
        "avdm-off",
        "avdm-unity",
        "avdm-allmean",
        "avdm:direction=-1,sd=2,delay=3,tw=6,texture_row=0",
        "avdm:contrast_term=false,beta=0.6",
    ],
)
def test_fast_path_matches_plain_reference(spec: str) -> None:
    rng = np.random.default_rng(1)
    noise = rng.integers(0, 256, size=(40, 12, 17), dtype=np.uint8)
    assert_matches_reference(make_model(spec), noise)
    g = grating(size=(8, 40), fps=FPS, tf_hz=7.0, period_px=9.0, n_frames=50, contrast=0.6)
    assert_matches_reference(make_model(spec), g)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    frames=st.one_of(
        hnp.arrays(np.uint8, hnp.array_shapes(min_dims=3, max_dims=3, min_side=3, max_side=14)),
        # Float frames are multiples of 1/256: then every detector value E is exact in both
        # float32 (fast path) and float64 (reference), so both make the same θ_E decisions.
        # Arbitrary floats can put one E within a float32 ulp of θ_E, where the two paths
        # legitimately disagree on whether that detector counts (a discrete, not a rounding,
        # difference). uint8 frames are safe as they are: their smallest non-zero |E| is
        # β/255² ≈ 3.8e-6, four times θ_E = 1e-6.
        hnp.arrays(
            st.sampled_from([np.float32, np.float64]),
            hnp.array_shapes(min_dims=3, max_dims=3, min_side=3, max_side=14),
            elements=st.integers(0, 256).map(lambda k: k / 256),
        ),
    )
)
def test_any_valid_frames_give_finite_outputs_equal_to_reference(frames: np.ndarray) -> None:
    model = make_model("avdm")
    out = model.run(frames)
    for key in OUTPUT_NAMES:
        assert out[key].shape == (frames.shape[0],)
        assert np.isfinite(out[key]).all()
        assert (out[key] >= 0).all()
    ref = AvdmReference(model.params).run(frames)
    for key in ref:  # the six layer outputs; omega_valid is derived from them
        # float32 sums over tiny frames with few active detectors: a looser 1e-4 than the
        # 2e-5 on real stimuli, since one rounding is a larger share of a small pooled mean
        np.testing.assert_allclose(out[key], ref[key], rtol=1e-4, atol=1e-7, err_msg=key)


def test_run_equals_repeated_step_bit_for_bit_and_chunks_continue() -> None:
    frames = grating(size=(72, 99), fps=33.0, tf_hz=3.0, period_px=12.0, n_frames=90)
    frames = frames ^ np.random.default_rng(2).integers(0, 4, frames.shape, dtype=np.uint8)
    whole = make_model("avdm").run(frames)
    stepper = make_model("avdm")
    steps = [stepper.step(f) for f in frames]
    chunked = make_model("avdm")
    parts = [chunked.run(frames[i : i + 13]) for i in range(0, len(frames), 13)]
    for key in OUTPUT_NAMES:
        stepped = np.array([s[key] for s in steps])
        assert np.array_equal(whole[key], stepped), key  # exact, not approximate
        assert np.array_equal(whole[key], np.concatenate([p[key] for p in parts])), key
    assert stepper.frames_seen == len(frames)


def test_reset_forgets_history() -> None:
    frames = grating(size=(20, 50), fps=FPS, tf_hz=5.0, period_px=10.0, n_frames=30)
    model = make_model("avdm")
    first = model.run(frames)
    model.reset()
    again = model.run(frames)
    for key in OUTPUT_NAMES:
        assert np.array_equal(first[key], again[key])


@pytest.mark.parametrize("period_px", [5.0, 8.0, 12.5, 20.0, 25.0, 33.3, 50.0])
@pytest.mark.parametrize("waveform", ["sine", "square"])
def test_texture_pathway_tracks_the_grating_period(period_px: float, waveform: str) -> None:
    for tf in (2.0, 20.0):
        out = respond(period_px, tf, waveform=waveform, contrast=0.7)
        lam = out["lambda_px"][WARM:]
        assert abs(lam.mean() / period_px - 1) < 0.05, (tf, lam.mean())


def test_static_and_uniform_input_give_zero() -> None:
    static = respond(10.0, 0.0)
    assert (static["omega_dps"] == 0).all() and (static["motion"] == 0).all()
    # λ̂ is still defined: 19 transitions of a static 10 px grating across 100 px → 10.5 px
    assert abs(static["lambda_px"][WARM:].mean() / 10.0 - 1) < 0.06
    uniform = make_model("avdm").run(np.full((30, 20, 40), 128, dtype=np.uint8))
    assert (uniform["omega_dps"] == 0).all()
    assert (uniform["lambda_px"] == (2 * 40) // 10).all()  # the released code's fallback
    assert (uniform["contrast"] == 0).all()


def test_response_rises_with_tf_below_aliasing() -> None:
    tfs = [1, 2, 3, 5, 8, 13, 20, 35, 50, 75]
    for period in (5.0, 10.0, 25.0):
        means = [mean_after_warmup(respond(period, tf)) for tf in tfs]
        assert all(b > a for a, b in pairwise(means)), (period, means)
        motion = [mean_after_warmup(respond(period, tf), "motion") for tf in tfs]
        assert all(b > a for a, b in pairwise(motion))


@pytest.mark.parametrize("omega_dps", [90.0, 360.0, 900.0])
def test_decoded_omega_is_sf_invariant_where_the_raw_motion_signal_is_not(omega_dps: float) -> None:
    # the valid band of the calibration: 4–50 px periods, TF from fps/300 = 1 Hz to fps/4 = 75 Hz
    periods = [
        p for p in (4.0, 5.0, 8.0, 12.5, 20.0, 25.0, 50.0) if 1 <= omega_dps / (p * 3.6) <= 75
    ]
    est, motion = [], []
    for p in periods:
        out = respond(p, omega_dps / (p * 3.6))
        est.append(mean_after_warmup(out))
        motion.append(mean_after_warmup(out, "motion"))
    est_arr = np.array(est)
    assert len(periods) >= 4
    assert (np.abs(est_arr / omega_dps - 1) < 0.25).all(), est
    assert max(motion) / min(motion) > 3.0, motion


def test_contrast_invariance_with_peak_normalised_gratings() -> None:
    contrasts = [0.3, 0.5, 0.7, 1.0]
    for period, tf in ((8.0, 10.0), (20.0, 4.0)):
        est = [mean_after_warmup(respond(period, tf, contrast=c)) for c in contrasts]
        motion = [mean_after_warmup(respond(period, tf, contrast=c), "motion") for c in contrasts]
        assert max(est) / min(est) < 1.10, est
        assert max(motion) / min(motion) > 2.0, motion  # the raw signal scales with contrast
    # without the (1+C)/(2C) term the decoded value follows contrast
    raw = [
        mean_after_warmup(respond(8.0, 10.0, contrast=c, spec="avdm:contrast_term=false"))
        for c in contrasts
    ]
    assert raw[-1] / raw[0] > 2.0


def test_no_dead_zone_at_1hz_in_the_paper_sweep_but_the_released_threshold_has_one() -> None:
    for sf_upc in (1.0, 5.0, 10.0, 25.0):
        frames = grating(size=SIZE, fps=FPS, tf_hz=1.0, sf_upc=sf_upc, n_frames=300)
        out = make_model("avdm").run(frames)
        assert (out["omega_dps"][WARM:] > 0).all(), sf_upc
        released = make_model("avdm:theta_e=0.001").run(frames)
        assert (released["omega_dps"][WARM:] == 0).all(), sf_upc


def test_direction_selectivity_is_weak_and_output_non_negative() -> None:
    pref = mean_after_warmup(respond(12.5, 10.0, direction=1), "motion")
    null = mean_after_warmup(respond(12.5, 10.0, direction=-1), "motion")
    assert 0.5 < null / pref < 0.98
    # a model preferring −x sees the mirrored stimulus as the default model sees the original
    frames = grating(size=SIZE, fps=FPS, tf_hz=10.0, period_px=12.5, n_frames=320)
    original = make_model("avdm").run(frames)
    mirrored = make_model("avdm:direction=-1").run(np.ascontiguousarray(frames[:, :, ::-1]))
    for key in ("motion", "omega_dps"):
        # the same float32 sums in mirrored order: ~1e-7 apart; 1e-5 is ample on any CPU
        np.testing.assert_allclose(mirrored[key], original[key], rtol=1e-5)


def test_unity_variant_uses_the_nine_frame_lag() -> None:
    p = make_params("avdm-unity")
    assert (p.photoreceptor_lag, p.photoreceptor_sign, p.theta_e) == (9, -1, 0.001)
    fast = respond(10.0, 5.0, spec="avdm-unity", n=60)
    ref = AvdmReference(p).run(grating(size=SIZE, fps=FPS, tf_hz=5.0, period_px=10.0, n_frames=60))
    np.testing.assert_allclose(fast["motion"], ref["motion"], rtol=2e-5)


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        (np.zeros((5, 10)), "shape (T, H, W)"),
        (np.zeros((0, 10, 10)), "must not be empty"),
        (np.zeros((3, 10, 10), dtype=np.int16), "dtype int16"),
        (np.full((3, 10, 10), np.nan), "NaN"),
        (np.zeros((3, 10, 10), dtype=np.complex64), "numeric images"),
        (np.zeros((3, 2, 10), dtype=np.uint8), "texture_row=2"),
    ],
)
def test_bad_frames_raise_value_error_naming_the_problem(frames: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        make_model("avdm").run(frames)


def test_shape_change_mid_stream_is_refused() -> None:
    model = make_model("avdm")
    model.step(np.zeros((10, 10), dtype=np.uint8))
    with pytest.raises(ValueError, match="frame shape changed"):
        model.step(np.zeros((10, 11), dtype=np.uint8))
    with pytest.raises(ValueError, match=r"shape \(H, W\)"):
        model.step(np.zeros((1, 10, 10), dtype=np.uint8))
    with pytest.raises(ValueError, match="dtype changed"):
        model.step(np.zeros((10, 10), dtype=np.float32))

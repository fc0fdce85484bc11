"""Gratings and natural scenes: geometry, levels, drift and determinism."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from avdm.stimuli import (
    clutter_image,
    drifting_image,
    grating,
    natural_scene,
    omega_true_dps,
    period_px_from_sf,
    resize_image,
)


def dominant_cycles(row: np.ndarray) -> int:
    spectrum = np.abs(np.fft.rfft(row - row.mean()))
    return int(np.argmax(spectrum))


def test_units_per_circle_convention() -> None:
    assert period_px_from_sf(10, 100) == 10.0
    assert omega_true_dps(10, 3) == pytest.approx(108.0)  # 3 Hz · 36° per cycle
    g = grating(sf_upc=7, tf_hz=0, n_frames=1, dtype=np.float64)
    assert g.shape == (1, 100, 100)
    assert dominant_cycles(g[0, 0]) == 7


@given(sf=st.integers(1, 40), tf=st.floats(0.5, 60), direction=st.sampled_from([1, -1]))
@settings(max_examples=30, deadline=None)
def test_grating_drifts_at_tf_in_the_given_direction(sf: int, tf: float, direction: int) -> None:
    fps = 300.0
    g = grating(
        sf_upc=sf,
        tf_hz=tf,
        fps=fps,
        n_frames=2,
        direction=direction,
        dtype=np.float64,
        size=(3, 100),
    )
    # the phase of the dominant Fourier component moves by 2π·TF/fps per frame
    c0 = np.fft.rfft(g[0, 0])[sf]
    c1 = np.fft.rfft(g[1, 0])[sf]
    dphi = np.angle(c1 / c0)
    expected = -direction * 2 * np.pi * tf / fps
    assert np.angle(np.exp(1j * (dphi - expected))) == pytest.approx(0, abs=1e-6)


def test_peak_and_mean_normalisation_levels() -> None:
    # phase π/2 puts a peak and a trough on pixel centres
    at_peak = {"period_px": 10, "n_frames": 1, "phase_rad": np.pi / 2}
    peak = grating(contrast=0.5, dtype=np.float64, **at_peak)
    assert peak.max() == pytest.approx(1.0, abs=1e-9)
    assert peak.min() == pytest.approx((1 - 0.5) / (1 + 0.5), abs=1e-9)
    mean = grating(contrast=0.5, normalisation="mean", dtype=np.float64, **at_peak)
    assert mean.mean() == pytest.approx(0.5, abs=1e-9)
    assert mean.max() == pytest.approx(0.75, abs=1e-9)
    u8 = grating(contrast=1.0, **at_peak)
    assert u8.dtype == np.uint8 and u8.max() == 255 and u8.min() == 0


def test_square_wave_has_two_levels_and_rows_are_identical() -> None:
    sq = grating(period_px=10, waveform="square", contrast=0.6, n_frames=3, dtype=np.float64)
    assert len(np.unique(sq)) == 2
    assert (sq == sq[:, :1, :]).all()


def test_duration_sets_frame_count() -> None:
    assert grating(period_px=10, fps=300, duration_s=0.5).shape[0] == 150


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"period_px": 10, "sf_upc": 3}, "exactly one"),
        ({}, "exactly one"),
        ({"sf_upc": 0}, "> 0 upc"),
        ({"period_px": 10, "tf_hz": -1}, ">= 0 Hz"),
        ({"period_px": 10, "contrast": 1.5}, "between 0 and 1"),
        ({"period_px": 10, "waveform": "saw"}, "waveform"),
        ({"period_px": 10, "normalisation": "max"}, "normalisation"),
        ({"period_px": 10, "fps": 0}, "fps"),
        ({"period_px": 10, "duration_s": 0}, "duration"),
        ({"period_px": 10, "size": (0, 10)}, "at least"),
        ({"period_px": 10, "dtype": np.int32}, "dtype"),
        ({"period_px": 10, "direction": 2}, "direction"),
    ],
)
def test_bad_grating_arguments_raise(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        grating(**kwargs)


def test_clutter_is_seeded_periodic_and_close_to_one_over_f() -> None:
    a = clutter_image((128, 128), seed=3)
    assert np.array_equal(a, clutter_image((128, 128), seed=3))
    assert not np.array_equal(a, clutter_image((128, 128), seed=4))
    assert a.min() == pytest.approx(-1) and a.max() == pytest.approx(1)
    # radially averaged amplitude spectrum falls as 1/f: log-log slope ≈ −1
    amp = np.abs(np.fft.fft2(a))
    fy, fx = np.meshgrid(np.fft.fftfreq(128), np.fft.fftfreq(128), indexing="ij")
    r = np.hypot(fx, fy)
    bins = np.geomspace(2 / 128, 0.4, 12)
    idx = np.digitize(r, bins)
    f = [r[idx == i].mean() for i in range(1, len(bins))]
    s = [amp[idx == i].mean() for i in range(1, len(bins))]
    slope = np.polyfit(np.log(f), np.log(s), 1)[0]
    assert -1.15 < slope < -0.85


def test_natural_scene_drifts_at_tf_times_nominal_period() -> None:
    # 2 Hz · 10 px = 20 px/s = 1 px per frame at 20 fps: frame k is frame 0 rolled by k px
    scene = {"size": (30, 60), "fps": 20.0, "tf_hz": 2.0, "nominal_period_px": 10.0}
    frames = natural_scene(**scene, n_frames=4, seed=1, dtype=np.float64)
    for k in range(1, 4):
        np.testing.assert_allclose(frames[k], np.roll(frames[0], k, axis=1), atol=1e-9)
    assert np.array_equal(frames, natural_scene(**scene, n_frames=4, seed=1, dtype=np.float64))


def test_user_image_is_resized_and_drifted() -> None:
    img = np.zeros((40, 80))
    img[:, :40] = 1.0
    frames = drifting_image(
        img, size=(20, 40), fps=10.0, speed_px_s=10.0, n_frames=3, dtype=np.float64
    )
    assert frames.shape == (3, 20, 40)
    np.testing.assert_allclose(frames[2], np.roll(frames[0], 2, axis=1), atol=1e-9)
    assert resize_image(img, (20, 40))[:, :20].mean() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="NaN"):
        drifting_image(np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="2-D"):
        drifting_image(np.zeros((4, 4, 3)))


def test_a_size_too_small_is_said_width_by_height() -> None:
    """Sizes are written W x H everywhere: the stimulus's check said "1x2 px (HxW)"."""
    from avdm.errors import ParameterError
    from avdm.stimuli import grating

    with pytest.raises(ParameterError) as err:
        grating(size=(5, 1), period_px=4.0, n_frames=2)  # 5 high, 1 wide
    assert "at least 2x1 px (W x H), got 1x5 px" in str(err.value), err.value

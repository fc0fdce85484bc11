"""Named variants and ``name:key=value`` overrides."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from avdm import canonical_name, make_model, make_params, parse_model_spec
from avdm.calibration_store import lookup_calibration, shipped_calibrations
from avdm.registry import VARIANTS


def test_overrides_are_parsed_into_typed_values() -> None:
    name, over = parse_model_spec("avdm:beta=0.5, tw=6 ,channel=on,contrast_term=false")
    assert name == "avdm"
    assert over == {"beta": 0.5, "tw": 6, "channel": "on", "contrast_term": False}
    assert isinstance(over["tw"], int) and isinstance(over["beta"], float)


def test_variants_apply_their_overrides_and_user_overrides_win() -> None:
    assert make_params("avdm-on").channel == "on"
    assert make_params("avdm-on:channel=off").channel == "off"
    assert make_params("avdm-unity").photoreceptor_lag == 9
    assert make_params("avdm", fps=33.0, deg_per_px=70 / 99).fps == 33.0
    assert make_params("avdm:fps=33", fps=300.0, deg_per_px=70 / 99).fps == 33.0


def test_canonical_names_sort_keys() -> None:
    assert canonical_name("avdm") == "avdm"
    assert canonical_name("avdm:tw=6,beta=0.5") == "avdm:beta=0.5,tw=6"
    assert make_model("avdm:tw=6,beta=0.5").name == "avdm:beta=0.5,tw=6"


def test_shipped_calibrations_fill_in_a_and_b() -> None:
    offline = make_params("avdm")
    robot = make_params("avdm", fps=33.0, deg_per_px=70 / 99)
    assert offline.a == lookup_calibration(300.0, 3.6)["a"]
    assert robot.b == lookup_calibration(33.0, 70 / 99)["b"]
    assert make_params("avdm:a=100,b=1").a == 100.0
    names = {c["name"] for c in shipped_calibrations()}
    assert {"offline-stimuli", "robot-camera"} <= names


def test_params_round_trip_through_a_flat_dict() -> None:
    p = make_params("avdm:beta=0.4")
    d = p.to_dict()
    assert d["beta"] == 0.4 and set(d) >= {"fps", "deg_per_px", "a", "b", "tw"}
    assert type(p)(**d) == p


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("", "empty model spec"),
        ("nope", "unknown model 'nope'"),
        ("avdm:", "no key=value"),
        ("avdm:beta", "not key=value"),
        ("avdm:gamma=1", "unknown parameter 'gamma'"),
        ("avdm:beta=abc", "expected a number"),
        ("avdm:tw=2.5", "expected an integer"),
        ("avdm:tw=0", "tw=0"),
        ("avdm:beta=2", "between 0 and 1"),
        ("avdm:channel=left", "one of on, off, on_off_mean"),
        ("avdm:contrast_term=maybe", "true or false"),
        ("avdm:beta=", "has no value"),
        ("avdm:fps=-3", "positive"),
        ("a vdm", "malformed"),
    ],
)
def test_bad_specs_fail_with_a_message_naming_the_problem(spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        make_params(spec)


def test_a_camera_without_a_shipped_calibration_is_fitted_on_first_use() -> None:
    # (the tests' calibration cache is a temporary folder: see tests/conftest.py)
    p = make_params("avdm", fps=50.0, deg_per_px=1.0)
    assert p.a is not None and 0.9 < p.b < 1.1
    assert make_params("avdm", fps=50.0, deg_per_px=1.0) == p  # the cached fit, same numbers


AVDM_VARIANTS = sorted(n for n, v in VARIANTS.items() if v.kind == "avdm")
LGMD_VARIANTS = sorted(n for n, v in VARIANTS.items() if v.kind.startswith("lgmd"))


def _overrides_hold(name: str, values: dict[str, float | int]) -> None:
    """``name:k=v,...`` builds params with those values and its canonical name parses back."""
    spec = f"{name}:" + ",".join(f"{k}={v!r}" for k, v in values.items())
    p = make_params(spec)
    assert all(getattr(p, k) == v for k, v in values.items())
    assert parse_model_spec(canonical_name(spec)) == parse_model_spec(spec)


@given(st.sampled_from(LGMD_VARIANTS), st.floats(1.0, 500.0), st.integers(1, 50))
def test_any_lgmd_variant_accepts_valid_overrides(name: str, fps: float, n_ts: int) -> None:
    _overrides_hold(name, {"fps": fps, "n_ts": n_ts})


# a parse round trip: 30 drawn examples cover every variant several times; the decoding's
# gain and exponent are given, so no example fits a calibration for its new dynamics (each
# fit took 0.2-0.8 s: 11 s of the suite's CPU; the fit is tested in test_calibration*.py)
@settings(max_examples=30)
@given(st.sampled_from(AVDM_VARIANTS), st.floats(0.0, 1.0), st.integers(1, 50))
def test_any_variant_accepts_valid_overrides(name: str, beta: float, tw: int) -> None:
    _overrides_hold(name, {"beta": beta, "tw": tw, "a": 11.0, "b": 1.0})


def test_released_units_variant_decodes_as_the_released_code_on_a_grating() -> None:
    """``avdm-released-units`` is ω = 100 · λ̂ · √R̄ (avdm.md §6): no fitted gain, exponent 1,
    no (1+C)/(2C) term; the robot camera's context (33 Hz, 70°/99 px) as in the arena."""
    from avdm.stimuli import grating

    frames = grating(size=(72, 99), fps=33.0, tf_hz=3.0, period_px=14.0, duration_s=2.0)
    released = make_model("avdm-released-units", fps=33.0, deg_per_px=70 / 99).run(frames)
    calibrated = make_model("avdm", fps=33.0, deg_per_px=70 / 99).run(frames)
    settled = slice(30, None)  # after the 2·T_w warm-up
    lam, motion = released["lambda_px"][settled], released["motion"][settled]
    assert (motion > 0).all() and lam == pytest.approx(14.0, rel=0.05)
    # the same float64 arithmetic as the kernel's last step, in another order: ~1 ulp
    assert released["omega_dps"][settled] == pytest.approx(100.0 * lam * motion, rel=1e-12)
    # the motion pathway is shared: only the decoding differs from the calibrated model
    assert np.array_equal(released["motion"], calibrated["motion"])
    assert np.array_equal(released["lambda_px"], calibrated["lambda_px"])
    # and the two disagree by far more than rounding: the calibrated one reads deg/s (its fit
    # has a 7 % RMS error over the calibration grid; 25 % leaves room for this one cell)
    true_dps = 3.0 * 14.0 * 70 / 99
    assert calibrated["omega_dps"][settled].mean() == pytest.approx(true_dps, rel=0.25)
    assert released["omega_dps"][settled].mean() > 3 * true_dps

"""Learnt policies: the table file, and a parameter set from the profiled complexity online."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from avdm import make_model
from avdm.policy import Policy, load_policy
from avdm.stimuli import grating
from tests.helpers import ROOT

CAMERA = {"fps": 33.0, "deg_per_px": 70 / 99, "width_px": 99, "height_px": 72}


def drifting(tf_hz: float, n: int) -> np.ndarray:
    return grating(size=(72, 99), fps=33.0, tf_hz=tf_hz, period_px=12.0, n_frames=n)


def test_a_policy_file_round_trips_and_interpolates(tmp_path: Path) -> None:
    p = Policy("t_ffi", (10.0, 30.0), (12.0, 36.0), window_s=2.0)
    path = p.save(tmp_path / "policy.csv")
    text = path.read_text()
    assert text.startswith("# vdc policy\n# param: t_ffi\n")  # a person can read it
    q = load_policy(path)
    assert q == p
    assert q.value(0.0) == 12.0 and q.value(20.0) == 24.0 and q.value(99.0) == 36.0


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("complexity_dps,t_ffi\n1,2\n", "no '# param: NAME' line"),
        ("# param: t_ffi\ncomplexity_dps,other\n1,2\n", "no column t_ffi"),
        ("# param: t_ffi\ncomplexity_dps,t_ffi\n1,2\n1,3\n", "must increase"),
        ("# param: t_ffi\ncomplexity_dps,t_ffi\n1,nan\n", "finite"),
    ],
)
def test_a_bad_policy_file_is_one_line_naming_it(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        make_model(f"lgmd-plus-arena:policy={path}", **CAMERA)
    assert needle in str(err.value) and "bad.csv" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_constant_policy_is_the_fixed_parameter_bit_for_bit(tmp_path: Path) -> None:
    Policy("t_ffi", (0.0,), (30.0,), window_s=1.0).save(tmp_path / "p.csv")
    frames = drifting(3.0, 120)
    fixed = make_model("lgmd-plus-arena:t_ffi=30", **CAMERA).run(frames)
    learnt = make_model(f"lgmd-plus-arena:policy={tmp_path / 'p.csv'}", **CAMERA).run(frames)
    for name in ("spike_rate_hz", "alert", "ffi"):
        np.testing.assert_array_equal(learnt[name], fixed[name])
    assert (learnt["policy_value"] == 30.0).all()


def test_the_policy_follows_the_scenes_complexity_online_and_offline_alike(tmp_path: Path) -> None:
    """Static walls, then a 3 Hz drift: the running mean of the AVDM rises and the policy
    raises T_ffi with it; running the frames in chunks gives the floats of stepping them."""
    Policy("t_ffi", (2.0, 30.0), (12.0, 40.0), window_s=1.0).save(tmp_path / "p.csv")
    spec = f"lgmd-plus-arena:policy={tmp_path / 'p.csv'}"
    frames = np.concatenate([drifting(0.0, 66), drifting(3.0, 99)])
    stepped = make_model(spec, **CAMERA)
    rows = [stepped.step(f) for f in frames]
    chunked = make_model(spec, **CAMERA)
    parts = [chunked.run(frames[:50]), chunked.run(frames[50:])]
    value = np.concatenate([p["policy_value"] for p in parts])
    np.testing.assert_array_equal(value, [r["policy_value"] for r in rows])
    np.testing.assert_array_equal(
        np.concatenate([p["spike_rate_hz"] for p in parts]), [r["spike_rate_hz"] for r in rows]
    )
    assert value[60] == pytest.approx(12.0, abs=0.5)  # static walls: the least complex row
    assert value[-1] > 20.0  # a second into the drift, the running mean has risen


def test_a_parameter_that_cannot_change_while_running_is_refused(tmp_path: Path) -> None:
    Policy("w_base", (0.0,), (0.3,)).save(tmp_path / "p.csv")
    with pytest.raises(ValueError, match="cannot change while it runs"):
        make_model(f"lgmd-plus-arena:policy={tmp_path / 'p.csv'}", **CAMERA)


def test_a_capture_loads_polars_only_to_read_a_policy(tmp_path: Path) -> None:
    """Every capture imports the policy module (through the registry) and vdc.parquet_io (its
    result type); polars (0.3 s of CPU and a thread pool at import) loads only when a table is
    written or read."""
    path = tmp_path / "policy.csv"
    code = (
        "import sys, avdm.registry, avdm.policy, capture.cli, capture.sim, capture.robot_capture, "
        "capture.video\n"
        "avdm.registry.make_params('avdm')\n"
        "print('polars' in sys.modules)\n"
        f"avdm.policy.Policy('t_ffi', (10.0, 30.0), (12.0, 36.0)).save({str(path)!r})\n"
        f"print('polars' in sys.modules, avdm.policy.load_policy({str(path)!r}).value(20.0))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert proc.stdout.split() == ["False", "True", "24.0"], proc.stderr

"""Models from outside vdc: ``package.module:factory`` specs and the ``vdc.models`` entry-point
group, built, parsed and rejected as the registry's own are."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from avdm import make_model
from avdm.registry import canonical_name, describe_models, make_params, parse_model_spec
from avdm.stimuli import grating
from tests.helpers import ROOT

LOOMING = "examples.looming:Looming"


def frames(n: int = 40) -> np.ndarray:
    return grating(size=(72, 99), fps=33.0, tf_hz=3.0, period_px=12.0, n_frames=n)


def test_a_factory_spec_builds_the_plugin_with_typed_overrides_and_the_camera() -> None:
    name, over = parse_model_spec(f"{LOOMING}:threshold=0.2,frames=3")
    assert name == LOOMING and over == {"threshold": 0.2, "frames": 3}  # typed by the signature
    assert (
        canonical_name(f"{LOOMING}:frames=3,threshold=0.2") == f"{LOOMING}:frames=3,threshold=0.2"
    )
    model = make_model(f"{LOOMING}:threshold=0.2", fps=33.0, deg_per_px=0.7)
    assert model.name == f"{LOOMING}:threshold=0.2"
    assert model.params.to_dict() == {"threshold": 0.2}  # fps is not one of its parameters
    assert [(o.name, o.unit) for o in model.outputs] == [("excitation", "1"), ("alert", "1")]
    assert make_params(LOOMING).to_dict() == {}


def test_a_plugin_runs_in_chunks_as_it_steps_bit_for_bit() -> None:
    f = frames()
    stepped = make_model(LOOMING)
    rows = [stepped.step(x) for x in f]
    chunked = make_model(LOOMING)
    a, b = chunked.run(f[:17]), chunked.run(f[17:])
    for name in ("excitation", "alert"):
        np.testing.assert_array_equal(np.concatenate([a[name], b[name]]), [r[name] for r in rows])
    assert max(r["excitation"] for r in rows) > 0.1  # a 3 Hz grating excites it: it computes


def test_a_plugin_can_build_vdcs_own_models_with_the_camera_it_is_given() -> None:
    spec = "tests.toy_detector:BlindAbove:blind_above_dps=5,profile_model=avdm"
    toy = make_model(spec, fps=33.0, deg_per_px=70 / 99, width_px=99, height_px=72)
    out = toy.run(frames(60))
    blind = out["busy_dps"] > 5  # its AVDM saw the drift: blind from then on
    assert blind[-1] and out["alert"][blind].sum() == 0
    assert out["alert"][~blind].sum() > 0  # the grating's dark bars alert it before


@pytest.mark.parametrize(
    ("spec", "needle"),
    [
        ("nosuch_pkg.detectors:make", "no module named 'nosuch_pkg.detectors'"),
        ("examples.looming:Nothing", "has no 'Nothing'"),
        (f"{LOOMING}:colour=red", "unknown parameter 'colour'"),
        (f"{LOOMING}:frames=two", "expected an integer"),
        ("not-a-model", "unknown model 'not-a-model'"),
    ],
)
def test_bad_plugin_specs_fail_in_one_line(spec: str, needle: str) -> None:
    with pytest.raises(ValueError) as err:
        make_model(spec)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_a_factory_that_raises_or_builds_no_model_is_one_line() -> None:
    with pytest.raises(ValueError) as err:
        make_model("tests.toy_detector:broken")
    assert "failed to build" in str(err.value) and "RuntimeError: no camera" in str(err.value)
    with pytest.raises(ValueError, match="has no step"):
        make_model("builtins:dict")  # a callable, but what it builds is not a model


def test_an_installed_entry_point_is_a_model_name(tmp_path: Path) -> None:
    """A package that declares ``[project.entry-points."vdc.models"]`` (here: its installed
    metadata, as pip writes it) is named like a built-in model."""
    info = tmp_path / "vdc_demo_detectors-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: vdc-demo-detectors\nVersion: 0.1\n"
    )
    (info / "entry_points.txt").write_text(f"[vdc.models]\nlooming = {LOOMING}\n")
    code = (
        "from avdm.registry import make_model, describe_models\n"
        "m = make_model('looming:threshold=0.3')\n"
        "print(m.name, m.params.to_dict()['threshold'])\n"
        "print('looming' in describe_models())\n"
    )
    env = {"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin"}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["looming:threshold=0.3", "0.3", "True"]
    assert "module:factory" in describe_models()  # the help says how to bring your own


def test_a_plugin_in_the_current_folder_loads_without_changing_sys_path(tmp_path: Path) -> None:
    """As a console script runs (the current folder not on ``sys.path``: ``python -P``), a
    plug-in beside the user's data is found there, and the process's ``sys.path`` stays as it
    was: a module of the same name elsewhere cannot be shadowed for the rest of the run."""
    (tmp_path / "beside_data_det.py").write_text(
        "from examples.looming import Looming as make\n"  # a real detector under a new name
    )
    code = (
        "import os, sys; before = list(sys.path); "
        "assert os.getcwd() not in sys.path and '' not in sys.path; "
        "from avdm import make_model; m = make_model('beside_data_det:make'); "
        "assert sys.path == before, sys.path; print(m.name)"
    )
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    proc = subprocess.run(
        [sys.executable, "-P", "-c", code],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "beside_data_det:make"

"""The least-squares decoding calibration and the shipped defaults."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from avdm import make_params
from avdm.calibration import fit_decoding
from avdm.calibration_store import shipped_calibrations
from tests.helpers import run_behind_a_held_lock

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("entry", shipped_calibrations(), ids=lambda e: e["name"])
def test_shipped_calibration_is_reproduced_by_the_fit(entry: dict) -> None:
    params = make_params(f"avdm:a=1,b=1,fps={entry['fps']!r},deg_per_px={entry['deg_per_px']!r}")
    result = fit_decoding(
        params, size=(entry["height"], entry["width"]), contrasts=tuple(entry["grid"]["contrasts"])
    )
    # The AVDM kernel sums in float32 with reassociation (so LLVM vectorises it), and the
    # vector width is the host CPU's: AVX-512 and AVX2 machines round the pooled sums
    # differently, by a few float32 ulps (1.2e-7 each). Across machines the fit moved by
    # 3e-7 relative; 1e-5 relative (about 100 ulps) covers that with room, and is still far
    # below the 4 significant digits the docs quote and the 7 % RMS error of the fit.
    assert result.a == pytest.approx(entry["a"], rel=1e-5)
    assert result.b == pytest.approx(entry["b"], rel=1e-5)
    assert result.n_points == entry["n_points"]
    # avdm.md §9.12: b close to 1 and a good log-log fit
    assert 0.9 < result.b < 1.1
    assert result.r2 > 0.98
    assert result.rms_rel_error < 0.12


def test_fit_refuses_a_grid_with_no_valid_cells() -> None:
    params = make_params("avdm:a=1,b=1,theta_e=10")  # nothing ever passes the threshold
    with pytest.raises(ValueError, match="valid band"):
        fit_decoding(params, size=(20, 40), periods_px=[5.0, 10.0], tfs_hz=[5.0, 10.0])


PROBE = """
import json, sys
from avdm.avdm_model import AvdmParams
from avdm.calibration_store import cache_path, calibration_for, decoding_key
fps, dpp = 47.0, 0.7071  # a camera no calibration is shipped for
if sys.argv[1] == "path":  # where calibration_for caches this camera's fit
    params = AvdmParams(fps=fps, deg_per_px=dpp)
    print(cache_path(decoding_key(fps, dpp, params), "avdm-47Hz"))
else:
    cal = calibration_for(fps, dpp)
    print(json.dumps({"source": cal["source"], "a": cal["a"], "b": cal["b"]}))
"""


@pytest.mark.skipif(not os.path.exists("/proc/locks"), reason="needs Linux's /proc/locks")
def test_two_processes_needing_one_new_calibration_fit_it_once(tmp_path: Path) -> None:
    """A pool's workers on clips of one new camera: one fits, the other waits and reads."""
    env = {**os.environ, "VDC_CACHE_DIR": str(tmp_path / "cache")}
    path = subprocess.run(
        [sys.executable, "-c", PROBE, "path"], env=env, capture_output=True, text=True, cwd=ROOT
    )
    assert path.returncode == 0, path.stderr
    json_path = Path(path.stdout.strip())
    assert not json_path.exists()
    cmd = [sys.executable, "-c", PROBE, "fit"]
    runs = run_behind_a_held_lock(
        json_path.with_name(json_path.name + ".lock"), [cmd, cmd], env=env, cwd=ROOT
    )
    assert [code for code, _ in runs] == [0, 0]
    cals = [json.loads(out) for _, out in runs]
    assert sorted(c["source"] for c in cals) == ["cache", "fitted"]  # fitted once
    assert cals[0]["a"] == cals[1]["a"] and cals[0]["b"] == cals[1]["b"]  # the same file
    assert json_path.exists()

"""The project's layout contract: entry points, import rules, lint."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.helpers import ROOT, run_cli


@pytest.mark.parametrize("module", ["capture", "analysis"])
def test_packages_run_as_modules(module: str) -> None:
    proc = run_cli(module, "--help")
    assert proc.returncode == 0, proc.stderr
    assert "usage:" in proc.stdout


def test_avdm_imports_neither_capture_nor_analysis() -> None:
    code = (
        "import sys, avdm, avdm.stimuli, avdm.calibration, avdm.reference, avdm.registry; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('capture', 'analysis', 'rerun')]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_ruff_is_clean() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "ruff", "check", str(ROOT)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr

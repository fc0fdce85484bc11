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


def test_analysis_outside_experiments_does_not_import_capture() -> None:
    """Only analysis/experiments produce recordings; the rest only consumes them, and the
    recording contract comes from contract/, not from the recorder."""
    mods = sorted(
        f"analysis.{p.stem}"
        for p in (ROOT / "analysis").glob("*.py")
        if p.stem not in ("__main__", "cli")
    )
    code = (
        f"import sys, {', '.join(mods)}; "
        "bad = [m for m in sys.modules if m.split('.')[0] == 'capture']; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize(
    ("old", "new"),
    [
        (
            ["sweep", "--sf", "1,2", "--tf", "3", "--duration", "0.5"],
            ["sweep", "--sf-upc", "1,2", "--tf-hz", "3", "--duration-s", "0.5"],
        ),
        (["tables", "r.rrd", "--threshold", "80"], ["tables", "r.rrd", "--threshold-dps", "80"]),
        (["calibrate", "--contrast", "1"], ["calibrate", "--contrasts", "1"]),
        (["reproduce", "--repeats", "2"], ["reproduce", "--approach-repeats", "2"]),
    ],
)
def test_old_flag_names_are_aliases_of_the_field_names(old: list[str], new: list[str]) -> None:
    from analysis.cli import build_parser

    parser = build_parser()
    assert vars(parser.parse_args(old)) == vars(parser.parse_args(new))

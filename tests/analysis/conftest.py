"""Short simulated recordings shared by the analysis tests (made once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.in_process import run_in_process


def _capture(out: Path, *args: str) -> Path:
    # in this process (tests.in_process): the command as a user gives it, without a
    # subprocess's imports (each xdist worker makes these once)
    proc = run_in_process("capture", "sim", *args, "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.fixture(scope="session")
def recordings(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("recordings")
    return {
        "phases": _capture(d / "phases.rrd", "--tf-schedule", "0:20s,3:20s", "--seed", "1"),
        "tf3_a": _capture(d / "tf3_a.rrd", "--tf-hz", "3", "--minutes", "0.4", "--seed", "2"),
        "tf3_b": _capture(d / "tf3_b.rrd", "--tf-hz", "3", "--minutes", "0.4", "--seed", "3"),
    }

"""Helpers shared by the tests, imported as ``tests.helpers`` (the repo root is on the
pythonpath, so ``tests/avdm`` never shadows the ``avdm`` package)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_cli(
    *args: str, cwd: Path | None = None, timeout: float = 300
) -> subprocess.CompletedProcess:
    """Run ``python -m <args>`` as a user would, capturing text output."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [sys.executable, "-m", *args],
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        env=env,
        timeout=timeout,
    )


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    """Exit status 2, exactly one line on stderr, no traceback, mentioning every needle."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def start_long_capture(out: Path, *, min_bytes: int = 2_000_000) -> subprocess.Popen:
    """Start a 60-minute simulated capture writing ``out`` and wait until the file holds at
    least ``min_bytes`` (frames are being written); the caller stops it."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "capture",
            "sim",
            "--tf-hz",
            "3",
            "--minutes",
            "60",
            "--out",
            str(out),
            "--quiet",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    deadline = time.time() + 60
    while time.time() < deadline and (not out.exists() or out.stat().st_size < min_bytes):
        time.sleep(0.2)
    return proc

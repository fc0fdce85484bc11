"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import end_background_processes


@pytest.fixture
def out_dir(tmp_path: Path) -> Path:
    return tmp_path / "out"


@pytest.fixture(autouse=True)
def _end_background_processes():
    """No test leaves a process behind, even when it fails before its own clean-up."""
    yield
    end_background_processes()

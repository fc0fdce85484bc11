"""Every shell and Python block of docs/boundary.md runs as written from a clone's root, in
order (a block may read what an earlier one of the same guide wrote); tests/readme_blocks.py
says how, and which marks shorten or skip what."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.readme_blocks import Block, clone_root_fixture, guide_cases, run_block

clone_root = clone_root_fixture()


@pytest.mark.parametrize(("block", "skipped_line"), guide_cases(__file__))
def test_every_block_runs_as_written(block: Block, skipped_line, clone_root: Path) -> None:
    run_block(block, skipped_line, clone_root)

"""Every shell and Python block of docs/guides/video.md runs as written (tests/readme_blocks.py)."""

from tests.readme_blocks import guide_tests

clone_root, test_every_block_runs_as_written = guide_tests(__file__)

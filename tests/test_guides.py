"""Every shell and Python block of the other guides in docs/ runs as written (readme_blocks)."""

from tests.readme_blocks import guide_tests

clone_root, test_every_block_runs_as_written = guide_tests(__file__)

"""Every shell block of docs/guides/commands.md runs as written (tests/readme_blocks.py), from a
clone of its own: its commands read recordings/*.rrd, which another guide's runs would add to."""

from tests.readme_blocks import guide_tests

clone_root, test_every_block_runs_as_written = guide_tests(__file__)

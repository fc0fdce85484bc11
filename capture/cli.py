"""``vdc-capture``: produce recordings (simulated arena now; the real robot later)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from avdm.cli_support import OneLineParser

PROG = "vdc-capture"


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        description="Record runs of the arena as Rerun .rrd files.",
    )
    parser.add_subparsers(dest="command", parser_class=OneLineParser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    return 0

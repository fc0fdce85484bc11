"""The arguments of ``vdc-capture`` and ``vdc-analyse`` that are not settings (those are the
settings dataclasses' fields, ``vdc.cli_support``): what a sub-command reads (recordings, a
folder) and where it writes (``--out``), and the output flags every capture command shares.
Each builder here is a ``Command``'s ``inputs``: it adds its arguments to the sub-command's
parser."""

from __future__ import annotations

import argparse
from collections.abc import Callable

InputsAdder = Callable[[argparse.ArgumentParser], None]


def inputs(
    out: str,
    recordings: str | None = ".rrd recordings",
    one: bool = False,
    dest: str = "recordings",
) -> InputsAdder:
    """The recordings (``one``: a single one; ``recordings`` None: none), under ``dest`` with
    the help ``recordings``, and ``--out`` (default ``out``), for a ``vdc-analyse`` command."""

    def add(p: argparse.ArgumentParser) -> None:
        if recordings and one:
            p.add_argument("recording", metavar="REC", help=recordings)
        elif recordings:
            p.add_argument(dest, nargs="+", metavar="REC", help=recordings)
        p.add_argument("--out", default=out, help="output folder (default: %(default)s)")

    return add


def sweep_inputs(p: argparse.ArgumentParser) -> None:
    """``vdc-analyse sweep``: ``--out``, and ``--square``, the older spelling of
    ``--waveform square``."""
    inputs("results/sweep", None)(p)
    p.add_argument(
        "--square",
        dest="waveform",
        action="store_const",
        const="square",
        help="square-wave instead of sine gratings",
    )


def reproduce_inputs(p: argparse.ArgumentParser) -> None:
    """``vdc-analyse reproduce``: ``--quick`` and ``--out``."""
    p.add_argument("--quick", action="store_true", help="the quick preset: 3-min runs, 3 seeds")
    inputs("results/reproduce", None)(p)


def catalog_inputs(p: argparse.ArgumentParser) -> None:
    """``vdc-analyse catalog``: the action, the folders (or a catalog's URL) and ``--out``."""
    p.add_argument("action", choices=("serve", "query"), help="serve the folders, or query them")
    p.add_argument(
        "folders",
        nargs="+",
        metavar="FOLDER",
        help="folders of recordings and outputs; query also takes a catalog's URL, "
        "rerun+http://HOST:PORT",
    )
    p.add_argument(
        "--out", default="results/catalog-query", help="query: output folder (default: %(default)s)"
    )


def summarise_inputs(p: argparse.ArgumentParser) -> None:
    """``vdc-analyse summarise``: the batch's output folder."""
    p.add_argument("out", metavar="OUT", help="the batch's --out folder")


def add_output_options(p: argparse.ArgumentParser, default: str) -> None:
    """--out, --force, --spawn / --connect and --quiet: the same on every capture command."""
    p.add_argument("--out", help=f"output .rrd (default: {default})")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    live = p.add_mutually_exclusive_group()
    live.add_argument(
        "--spawn",
        action="store_true",
        help="also stream to a new Rerun viewer (listening on 127.0.0.1)",
    )
    live.add_argument(
        "--connect",
        metavar="URL",
        help="also stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines (no heartbeat)")


def output_options(default: str) -> InputsAdder:
    """:func:`add_output_options` with the output's ``default`` shown, as a ``Command``'s
    ``inputs``."""
    return lambda p: add_output_options(p, default)


def campaign_inputs(p: argparse.ArgumentParser) -> None:
    """``vdc-capture campaign``: its output folder and ``--quiet``."""
    p.add_argument("--out", default="results/campaign", help="output folder (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="no progress lines (no heartbeat)")

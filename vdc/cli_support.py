"""Small helpers shared by the ``vdc-capture`` and ``vdc-analyse`` command lines.

Bad input must end in one clear line and exit status 2, never a traceback
(docs/architecture.md); these helpers make argparse and the commands' own checks behave that
way.
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

EXIT_BAD_INPUT = 2


class UserError(Exception):
    """A problem with the user's input: printed as one line, exit status 2."""


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error as a single line (and exit status 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def fail(prog: str, message: str) -> NoReturn:
    """Print ``prog: error: message`` on stderr and exit with status 2."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(EXIT_BAD_INPUT)


def parse_float_list(text: str) -> list[float]:
    """``"1,2.5,10"`` → ``[1.0, 2.5, 10.0]`` (argparse type; rejects empty and non-numbers)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}"
        ) from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one number")
    return values


MAX_SIDE_PX = 4096


def parse_size(text: str) -> tuple[int, int]:
    """``"99x72"`` (W x H, as image sizes are usually written) → ``(H, W)``."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a size WIDTHxHEIGHT such as 99x72, got {text!r}"
        ) from None
    if w < 2 or h < 1:
        raise argparse.ArgumentTypeError(f"size {text!r} is too small")
    if w > MAX_SIDE_PX or h > MAX_SIDE_PX:  # stimuli are held in memory: 4096² is ~16 MB/frame
        raise argparse.ArgumentTypeError(
            f"size {text!r} is too large: at most {MAX_SIDE_PX} px a side"
        )
    return h, w


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def add_executor_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--executor``, ``--jobs`` and ``--scheduler``: where the command's independent
    ``what`` (e.g. "analysis tasks", "simulated runs") run; fields of the same names in the
    command's settings (``vdc.executors.ExecutorSettings``)."""
    p.add_argument(
        "--executor",
        choices=("local", "dask"),
        default="local",
        help=f"where the {what} are done: local = a process pool on this machine (default); "
        "dask = a Dask cluster (pip install -e '.[dask]')",
    )
    p.add_argument(
        "--jobs",
        type=int,
        help="worker processes of the local pool or of a local Dask cluster "
        "(default, and the local pool's cap: the cores this process may use; "
        "VDC_OVERSUBSCRIBE=1 lifts the cap)",
    )
    p.add_argument(
        "--scheduler",
        help="an existing Dask cluster: tcp://HOST:PORT, tls://HOST:PORT or a scheduler file "
        "(implies --executor dask); without it, --executor dask starts one on 127.0.0.1",
    )

"""The console scripts' entry: imports nothing heavy itself, so that Ctrl-C while the
command's modules load (NumPy, Numba, polars: the first half-second) is one line, not a
traceback."""

from __future__ import annotations

import contextlib
import importlib
import sys

from vdc import heartbeat  # standard library only: nothing heavy
from vdc.errors import UserError  # standard library only: nothing heavy
from vdc.no_pandas import arrow_without_pandas  # standard library only: nothing heavy
from vdc.shadow import shadowed  # standard library only: nothing heavy


def launch(prog: str, module: str) -> int:
    """Run ``module.main()`` for the console script ``prog``; Ctrl-C at any moment ends in
    one line and exit status 130. A folder named like one of vdc's packages that Python finds
    first (``vdc/`` in the current folder under ``python -m``, or on ``PYTHONPATH``) ends in one
    line naming it and exit status 2."""
    problem = shadowed()
    if problem is not None:
        print(f"{prog}: {problem}", file=sys.stderr)
        return 2
    arrow_without_pandas()  # pandas' import is 0.25 s of every command's CPU otherwise
    argv = sys.argv[1:]
    command = f"{prog} {argv[0]}" if argv and not argv[0].startswith("-") else prog
    # the heartbeat starts before the modules load (seconds on a busy machine): never silent
    # from the first second (vdc.cli_support.run_command_line keeps this one)
    try:
        beat = (
            heartbeat.Heartbeat(command)
            if heartbeat.wanted() and "--quiet" not in argv and not heartbeat.waits(argv)
            else contextlib.nullcontext()
        )
    except UserError as exc:  # a bad VDC_PROGRESS_EVERY_S
        print(f"{command}: error: {exc}", file=sys.stderr)
        return 2
    try:
        with beat:
            return int(importlib.import_module(module).main() or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


def capture() -> int:
    """``vdc-capture``."""
    return launch("vdc-capture", "capture.cli")


def analyse() -> int:
    """``vdc-analyse``."""
    return launch("vdc-analyse", "analysis.cli")

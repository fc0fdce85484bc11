"""Two kinds of ``vdc-analyse`` sub-command that need no printer of their own: a function run
over recordings with a progress bar over their frames (:func:`over_recordings`), and a campaign
run with a progress bar over its units (:func:`campaign_runner`). Each loads its function by
name (``module:function``) when it runs, so the command line starts without it."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable

from vdc.cli_support import load_settings_class, progress_bar, say, settings_from_args
from vdc.executors import Feedback

Runner = Callable[[argparse.Namespace], int]


def _function(entry: str) -> tuple[str, Callable]:
    module, name = entry.split(":")
    return name, getattr(importlib.import_module(module), name)


def over_recordings(
    entry: str, notice: Callable[[str], None], inputs: str = "recordings"
) -> Runner:
    """A sub-command that runs ``module:function(recordings, settings, out, progress=,
    notice=)`` (``inputs``: the argument that holds the recordings, or the one) with a progress
    bar over frames and prints the result's ``report()`` lines."""

    def run(args: argparse.Namespace) -> int:
        name, fn = _function(entry)
        settings = settings_from_args(load_settings_class(args.settings_target), args)
        with progress_bar(None, name, "frame") as bar:
            res = fn(getattr(args, inputs), settings, args.out, progress=bar.update, notice=notice)
        print("\n".join(res.report()))
        return 0

    return run


def campaign_runner(entry: str, unit: str, *inputs: str) -> Runner:
    """A sub-command that runs ``module:function(*inputs, settings, out, feedback)`` with a
    progress bar over its ``unit``s, prints ``report()`` and exits with ``exit_status``
    (default 0)."""

    def run(args: argparse.Namespace) -> int:
        name, fn = _function(entry)
        with progress_bar(None, name, unit) as bar:
            settings = settings_from_args(load_settings_class(args.settings_target), args)
            feedback = Feedback(say, bar.update, bar.expect)
            res = fn(*map(args.__getattribute__, inputs), settings, args.out, feedback)
        print("\n".join(res.report()))
        return getattr(res, "exit_status", 0)

    return run

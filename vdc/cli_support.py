"""Small helpers shared by the ``vdc-capture`` and ``vdc-analyse`` command lines.

Bad input must end in one clear line and exit status 2, never a traceback
(docs/architecture.md); these helpers make argparse and the commands' own checks behave that
way.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

EXIT_BAD_INPUT = 2

# dataclasses.field(metadata=API_ONLY): a settings field without a flag (set from Python only,
# or through another flag); the layout test holds every other field to a flag of its name
API_ONLY = {"api_only": True}


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


def field_default(field: dataclasses.Field) -> Any:
    """A dataclass field's default (calling its factory), or ``dataclasses.MISSING``."""
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def _shown(value: Any) -> str:
    if isinstance(value, tuple | list):
        return ",".join(map(str, value))
    return str(value)


def bind_settings(parser: argparse.ArgumentParser, cls: type) -> None:
    """Make the settings dataclass ``cls`` the one source of ``parser``'s defaults.

    A flag whose ``dest`` is a field of ``cls`` is left unset by default (None: the settings'
    own default applies, see :func:`settings_from_args`), and ``%(default)s`` in its help shows
    the field's default. Switches (``store_true``) keep False, which their fields default to."""
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    for act in parser._actions:
        f = fields.get(act.dest)
        if f is None or isinstance(act, argparse._StoreTrueAction | argparse._HelpAction):
            continue
        default = field_default(f)
        if default is dataclasses.MISSING:
            continue
        act.default = None
        if act.help and "%(default)s" in act.help:
            act.help = act.help.replace("%(default)s", _shown(default).replace("%", "%%"))


def settings_from_args(cls: type, args: argparse.Namespace, **extra: Any) -> Any:
    """The command's settings dataclass from the parsed flags (flag name = field name): flags
    left unset take the dataclass's default; repeatable flags and lists become tuples."""
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    values = {k: getattr(args, k) for k in names if hasattr(args, k)}
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    return cls(**{k: v for k, v in values.items() if v is not None}, **extra)


def load_settings_class(target: str) -> type:
    """``"package.module:ClassName"`` → the class (the command lines name their settings so)."""
    import importlib

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def bind_commands(
    subparsers: argparse._SubParsersAction, settings: dict[str, str], command: str | None
) -> None:
    """Bind each sub-command's settings class (``settings``: name -> ``"module:Class"``);
    ``command`` binds only that one (its modules alone load: a command line starts faster),
    None every one, "" none."""
    for name, target in settings.items():
        if command is None or name == command:
            bind_settings(subparsers.choices[name], load_settings_class(target))


def command_of(argv: Sequence[str] | None, settings: dict[str, str]) -> str:
    """The sub-command named in ``argv`` (default: ``sys.argv``) if it has settings to bind,
    else "": the first argument that is not an option (the parsers have no global options)."""
    given = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in given if not a.startswith("-")), "")
    return command if command in settings else ""

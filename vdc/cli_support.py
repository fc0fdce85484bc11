"""Small helpers shared by the ``vdc-capture`` and ``vdc-analyse`` command lines.

Bad input must end in one clear line and exit status 2, never a traceback
(docs/architecture.md); these helpers make argparse and the commands' own checks behave that
way.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import numbers
import sys
import textwrap
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

from vdc import heartbeat
from vdc.errors import UserError
from vdc.interrupt import ctrl_c_ends_the_run
from vdc.settings import (
    AT_LEAST_0,
    FINITE,
    MAX_SIDE_PX,
    POSITIVE,
    RANGE,
    Range,
    out_of_range,
)

EXIT_BAD_INPUT = 2

# the simulated arena camera's frame rate (capture.config.CameraConfig.fps): analysis checks
# the TFs it asks of the arena against it without importing capture
SIM_CAMERA_FPS = 33.0


def check_below_nyquist(tf_hz: float, flag: str, fps: float = SIM_CAMERA_FPS) -> None:
    """UserError in one line naming ``flag`` when the wall TF ``tf_hz`` is not below the
    Nyquist frequency of a camera at ``fps`` (default: the simulated arena's): a wall that
    drifts faster than half the frame rate aliases to a slower, even backward, drift, and a
    profile over it is not monotone."""
    if not tf_hz < fps / 2:
        raise UserError(
            f"{flag} reaches {tf_hz:g} Hz, not below the camera's Nyquist frequency "
            f"{fps / 2:g} Hz (a {fps:g} Hz camera): a faster wall aliases; keep TFs below "
            f"{fps / 2:g} Hz."
        )


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error as a single line (and exit status 2)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def say(message: str) -> None:
    """A line on stderr, at once (a command's log: progress notes beside its stdout results);
    through the command's heartbeat when it has one (:mod:`vdc.heartbeat`)."""
    heartbeat.emit(message)


def progress_bar(total: int | None, desc: str, unit: str = "cell", quiet: bool = False) -> Any:
    """The count of a long stage's units, shown by the command's heartbeat line (on terminals
    and with ``VDC_PROGRESS=1``; see :mod:`vdc.heartbeat`), or never with ``quiet``."""
    return heartbeat.Count(total, desc, unit, quiet)


def tasks_line(res: Any, units: str, ran: int, verb: str) -> str:
    """The line a command that runs tasks ends with (``res``: its ``planned``, ``skipped``,
    ``failures`` and ``elapsed_s``): ``12 runs: 3 already done, 8 recorded, 1 failed (4.2 s)``."""
    return (
        f"{res.planned} {units}: {res.skipped} already done, {ran} {verb}, "
        f"{len(res.failures)} failed ({res.elapsed_s:.1f} s)"
    )


class CalibrationNotes:
    """Shows the calibration fits a command starts (``avdm.calibration_store.fit_progress``):
    one line when a fit starts (what is fitted, for which camera), a bar on a terminal while
    it runs, one line when it is cached; with ``quiet``, the lines only."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.bar: Any = None

    def __call__(self, note: Any) -> None:
        if note.stage == "fitting":
            say(
                f"calibrating {note.model} for this camera ({note.camera()}): "
                f"{note.total} stimuli, once; the fit is then cached."
            )
            self.bar = progress_bar(note.total, "calibrating", "stimulus", quiet=self.quiet)
        elif note.stage == "step" and self.bar is not None:
            self.bar.update(1)
        elif note.stage == "cached":
            if self.bar is not None:
                self.bar.close()
                self.bar = None
            where = (
                f"cached in {note.cache_file}"
                if note.cache_file
                else "not cached (no cache folder)"
            )
            say(f"calibrated {note.model} for {note.camera()}: {where}")


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


def ranged(parse: Callable[[str], Any], rng: Range) -> Callable[[str], Any]:
    """argparse type: ``parse`` the text, then hold the number (or a list's each) to ``rng``,
    the field's own range (:mod:`vdc.settings`): the flag refuses what the settings would."""

    def parse_in_range(text: str) -> Any:
        try:
            value = parse(text)
        except ValueError:
            if parse is int:
                raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
            if parse is float:
                raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
            raise
        bad = out_of_range(value, rng)
        if bad is not None:
            wanted = rng.wanted(isinstance(bad, numbers.Integral))
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
        return value

    parse_in_range.__name__ = getattr(parse, "__name__", "value")
    return parse_in_range


# argparse types of the arguments that are not settings fields (a field states its range)
finite_float = ranged(float, FINITE)
non_negative_float = ranged(float, AT_LEAST_0)
non_negative_int = ranged(int, AT_LEAST_0)
positive_float = ranged(float, POSITIVE)


@dataclasses.dataclass(frozen=True)
class Flag:
    """How a settings field appears on the command line (``option(...)`` puts it in the
    field's metadata): the field is the flag, its name the flag's (``--near-wall-m`` for
    ``near_wall_m``), its default the flag's default, shown in the help."""

    help: str  # "{default}" is replaced by the field's default; else "(default: X)" is appended
    aliases: tuple[str, ...] = ()  # older or shorter spellings that stay accepted
    type: Callable[[str], Any] | None = None  # the parser type; default: from the annotation
    choices: tuple[str, ...] | None = None
    metavar: str | None = None
    required: bool = False
    exclusive: str | None = None  # flags of one group name exclude each other
    positional: bool = False  # an argument, not a flag (a tuple field takes one or more)
    flag: str | None = None  # the flag when it is not --field-name (e.g. --model for models)
    shown: str | None = None  # the default as the help states it, when not str(default)


def option(default: Any = dataclasses.MISSING, help: str = "", *aliases: str, **how: Any) -> Any:
    """A settings field that is also a command-line flag (see :class:`Flag`)::

        near_wall_m: float = option(0.15, "'near the wall' = within this of a wall, m")

    ``default=dataclasses.MISSING`` makes a required field (and flag); a callable
    ``factory=`` gives a default computed per object (shown only as the help words it);
    ``range=`` (:class:`vdc.settings.Range`) what its flag and the settings both allow."""
    factory = how.pop("factory", dataclasses.MISSING)
    rng = how.pop("range", None)
    meta: dict[str, Any] = {"flag": Flag(help, tuple(aliases), **how)}
    if rng is not None:
        meta[RANGE] = rng
    return dataclasses.field(default=default, default_factory=factory, metadata=meta)


def field_default(field: dataclasses.Field) -> Any:
    """A dataclass field's default (calling its factory), or ``dataclasses.MISSING``."""
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def stated_default(field: dataclasses.Field) -> str:
    """The default a field's help states ("" for none: None, False, empty, or computed per
    object by a factory, which the help describes in words)."""
    flag = field.metadata.get("flag")
    if flag is not None and flag.shown is not None:
        return flag.shown
    value = field.default
    if value is dataclasses.MISSING or value is None or value is False or value == ():
        return ""
    if flag is not None and flag.type is parse_size:
        return f"{value[1]}x{value[0]}"  # (H, W) fields are written WIDTHxHEIGHT
    if isinstance(value, tuple | list):
        return ",".join(map(str, value))
    return str(value)


def _parser_type(field: dataclasses.Field, flag: Flag) -> Callable[[str], Any] | None:
    """The parser type from the field's annotation (a string: modules use postponed
    annotations): numbers in the field's range (finite), lists of numbers comma-separated."""
    rng = field.metadata.get(RANGE)
    parse: Callable[[str], Any] | None = flag.type
    hint = str(field.type).replace(" ", "")
    if parse is None:
        if hint.startswith("tuple[float"):
            parse = parse_float_list
        elif hint in ("float", "float|None"):
            parse = float
            rng = rng or FINITE
        elif hint in ("int", "int|None"):
            parse = int
    if parse is None or rng is None:
        return parse
    return ranged(parse, rng)


def add_settings_flags(parser: argparse.ArgumentParser, cls: type) -> None:
    """Add a flag (or argument) for every field of the settings dataclass ``cls``, from the
    :class:`Flag` in its metadata; fields marked :data:`API_ONLY` get none. Flags have no
    default of their own: an unset flag is None and takes the field's default (see
    :func:`settings_from_args`), so the dataclass is the one source of every default."""
    groups: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("api_only"):
            continue
        flag: Flag | None = f.metadata.get("flag")
        if flag is None:
            raise TypeError(f"{cls.__name__}.{f.name}: give it option(...) or API_ONLY metadata")
        where: Any = parser
        if flag.exclusive:
            if flag.exclusive not in groups:
                groups[flag.exclusive] = parser.add_mutually_exclusive_group()
            where = groups[flag.exclusive]
        shown = stated_default(f)
        text = flag.help
        if "{default}" in text:
            text = text.replace("{default}", shown)
        elif shown:
            text += f" (default: {shown})"
        kw: dict[str, Any] = {"help": text.replace("%", "%%"), "metavar": flag.metavar}
        if flag.choices:
            kw["choices"] = flag.choices
        if flag.positional:
            many = str(f.type).startswith("tuple")
            where.add_argument(f.name, nargs="+" if many else None, **kw)
            continue
        names = [flag.flag or "--" + f.name.replace("_", "-"), *flag.aliases]
        if f.default is False:
            where.add_argument(*names, dest=f.name, action="store_true", help=kw["help"])
            continue
        if f.default is True:  # on unless told: --page / --no-page
            where.add_argument(
                *names,
                dest=f.name,
                action=argparse.BooleanOptionalAction,
                default=None,
                help=kw["help"],
            )
            continue
        if str(f.type).startswith("tuple[str"):
            kw["action"] = "append"  # repeatable: --model A --model B
        else:
            kw["type"] = _parser_type(f, flag)
        where.add_argument(*names, dest=f.name, default=None, required=flag.required, **kw)


def flag_values(cls: type, args: argparse.Namespace) -> dict[str, Any]:
    """The fields of settings dataclass ``cls`` that the parsed flags set (flag name = field
    name; an unset flag is None); repeatable flags and lists become tuples."""
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    values = {k: getattr(args, k) for k in names if getattr(args, k, None) is not None}
    return {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}


def settings_from_args(cls: type, args: argparse.Namespace, **extra: Any) -> Any:
    """The command's settings dataclass from the parsed flags: flags left unset take the
    dataclass's default."""
    return cls(**flag_values(cls, args), **extra)


def load_settings_class(target: str) -> type:
    """``"package.module:ClassName"`` → the class (the command lines name their settings so)."""

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


@dataclasses.dataclass(frozen=True)
class Command:
    """One sub-command: its settings dataclass (``"module:Class"``, whose fields are its
    flags), the function that runs it on the parsed arguments, and its texts. ``inputs`` adds
    what is not a setting (input paths, ``--out``, ...) before the settings' flags."""

    settings: str | None
    run: Callable[[argparse.Namespace], int]
    help: str
    description: str
    epilog: str = ""
    inputs: Callable[[argparse.ArgumentParser], None] | None = None
    models: bool = False  # list the models (--model NAME:key=value) after the epilog


def command_line(
    prog: str, description: str, commands: dict[str, Command], command: str | None
) -> OneLineParser:
    """The parser of a command line. The flags of sub-command ``command`` are generated from
    its settings (only its modules load, so a command line starts fast); None generates every
    sub-command's (the CLI reference), "" none (the top-level help)."""
    from avdm.registry import describe_models  # lazy: start-up

    parser = OneLineParser(
        prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    for name, cmd in commands.items():
        epilog = cmd.epilog
        if cmd.models and command in (None, name):
            epilog += ("\n\n" if epilog else "") + "models:\n" + describe_models()
        p = sub.add_parser(
            name,
            help=cmd.help,
            description=textwrap.fill(cmd.description, 88),
            epilog=epilog or None,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        if cmd.inputs is not None:
            cmd.inputs(p)
        if cmd.settings and command in (None, name):
            add_settings_flags(p, load_settings_class(cmd.settings))
        p.set_defaults(func=cmd.run, settings_target=cmd.settings)
    return parser


def command_of(argv: Sequence[str] | None, commands: dict[str, Command]) -> str:
    """The sub-command named in ``argv`` (default: ``sys.argv``), else "": the first argument
    that is not an option (the parsers have no global options)."""
    given = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in given if not a.startswith("-")), "")
    return command if command in commands else ""


def reference_page(
    prog: str, parser: argparse.ArgumentParser, commands: dict[str, Command]
) -> list[str]:
    """Markdown for every sub-command of ``parser``: its description, then a table of its
    arguments and flags with the default each states (a setting's from its field)."""
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    lines: list[str] = []
    for name, sub in subs.choices.items():
        target = commands[name].settings
        cls = load_settings_class(target) if target else None
        fields = {f.name: f for f in dataclasses.fields(cls)} if cls else {}
        lines += [f"## `{prog} {name}`", "", (sub.description or "").strip(), ""]
        lines += ["| flag | default | meaning |", "|---|---|---|"]
        for act in sub._actions:
            if isinstance(act, argparse._HelpAction):
                continue
            flag = ", ".join(f"`{o}`" for o in act.option_strings) or f"`{act.dest.upper()}`"
            text = (act.help or "").replace("%%", "%")
            f = fields.get(act.dest)
            if f is not None and "flag" in f.metadata:  # the default has a column of its own
                default = stated_default(f)
                text = f.metadata["flag"].help.replace("{default}", default)
            else:  # a flag that is not a setting (e.g. --out)
                default = "" if act.default in (None, False) else str(act.default)
            text = text.replace("|", "\\|").replace("\n", " ")
            lines.append(f"| {flag} | {f'`{default}`' if default else ''} | {text} |")
        lines.append("")
    return lines


def raised_on_purpose(exc: BaseException) -> bool:
    """Whether ``exc`` is an error vdc raises on purpose for bad input: a :class:`UserError` or
    the models' ``avdm.errors.ParameterError`` (looked up, not imported: if avdm is not loaded,
    no model raised one, and a command line's start stays light)."""
    models = sys.modules.get("avdm.errors")
    return isinstance(exc, UserError) or (
        models is not None and isinstance(exc, models.ParameterError)
    )


def run_command_line(
    prog: str,
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    stopped: dict[type[Exception], str] | None = None,
) -> int:
    """Parse ``argv`` and run the sub-command. Bad input (the errors vdc raises on purpose:
    :class:`UserError`, the models' :class:`ParameterError`; an OSError on a named file) is one
    line and exit status 2; an exception of a type in ``stopped`` (work stopped with what was
    done kept) is its message plus that text, exit 1; Ctrl-C is exit 130. Anything else (a
    ValueError from NumPy or polars included) is a bug: its traceback is kept, exit 1."""
    from avdm.calibration_store import fit_progress  # lazy: start-up

    args = parser.parse_args(argv)
    where = f"{prog} {args.command}"
    quiet = bool(getattr(args, "quiet", False))
    # never silent: on a terminal (or VDC_PROGRESS=1) a line at least every few seconds
    # (one the console script started, vdc.launch, is kept)
    words = [args.command, str(getattr(args, "action", ""))]
    fresh = (
        heartbeat.wanted()
        and not quiet
        and heartbeat.current() is None
        and not heartbeat.waits(words)
    )
    try:
        beat = heartbeat.Heartbeat(where) if fresh else contextlib.nullcontext()
        # a model built for a new camera fits its calibration first: say so, not a silent minute
        notes = CalibrationNotes(quiet=quiet)
        with beat, ctrl_c_ends_the_run(f"{prog}: interrupted"), fit_progress(notes):
            return int(args.func(args) or 0)
    except ValueError as exc:
        if not raised_on_purpose(exc):
            raise
        fail(where, str(exc))
    except OSError as exc:
        fail(where, f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": "))
    except KeyboardInterrupt:
        say(f"{prog}: interrupted.")
        return 130
    except tuple(stopped or ()) as exc:
        say(f"{where}: error: {exc}{next(t for k, t in stopped.items() if isinstance(exc, k))}.")
        return 1


def reference_markdown(clis: Sequence[Any]) -> str:
    """The CLI reference page of command-line modules (each with ``PROG``, ``COMMANDS`` and
    ``build_parser``), rendered from their settings dataclasses."""
    lines = [
        "# CLI reference",
        "",
        "Generated from the settings dataclasses by `analysis.cli.cli_reference()`; "
        "`tests/test_layout.py` keeps this page equal to it. Each flag is the field of the same "
        "name of the command's settings dataclass (see the README's table of functions).",
        "",
    ]
    for cli in clis:
        lines += reference_page(cli.PROG, cli.build_parser(), cli.COMMANDS)
    return "\n".join(lines).rstrip() + "\n"

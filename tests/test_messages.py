"""Messages end their sentences: every error vdc raises for people (UserError, the models'
ParameterError, OutputError) and every line a command logs (``say``, ``notice``, ``log``,
``emit``) ends with a full stop (or ``?``, ``!``), or with a colon before the list or value it
introduces. Checked on the source by its syntax tree, so a new message that stops mid-air
fails here, with its file and line.

``python tests/test_messages.py --fix`` adds the missing full stops (the literal's last
character) and lists the messages it cannot end itself (a value last, after no colon)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("vdc", "analysis", "capture", "avdm")
ERRORS = {"UserError", "ParameterError", "OutputError"}
LOG_LINES = {"say", "_notice", "notice", "log", "emit"}
ENDINGS = (".", ":", "?", "!")
COMMANDS = ("pip install ", "vdc-analyse ", "vdc-capture ", "python -m ", "rerun ", "lerobot-")
# Modules, then messages, left to a branch that moves or rewraps them as this check lands: once
# it is merged, drop the entry and run this file with --fix (none is left today)
PENDING: dict[str, str] = {}
# (module, the message's last words, each value a "{}")
PENDING_MESSAGES: set[tuple[str, str]] = set()


def _parts(node: ast.expr) -> list[tuple[str, object]]:
    """A message's pieces in order: ("text", str) or ("value", expression), through f-strings,
    implicit concatenation and ``+``."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [("text", node.value)]
    if isinstance(node, ast.JoinedStr):
        return [
            ("text", v.value) if isinstance(v, ast.Constant) else ("value", v) for v in node.values
        ]
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _parts(node.left) + _parts(node.right)
    return [("value", node)]


def ends_a_sentence(node: ast.expr) -> bool:
    """Whether the message ``node`` (a literal, an f-string, a sum) ends as a sentence: its last
    text ends with a full stop, ``?``, ``!`` or a colon, or a value comes last after a colon.
    A message with no text of its own (``str(exc)``) is another message's: not judged here."""
    parts = _parts(node)
    if not any(kind == "text" and str(piece).strip() for kind, piece in parts):
        return True
    kind, last = parts[-1]
    if kind == "text":
        text = str(last).rstrip()
        # a command to run, after a colon, is its value: a full stop would be copied with it
        return text.endswith(ENDINGS) or text.rsplit(": ", 1)[-1].startswith(COMMANDS)
    before = parts[-2] if len(parts) > 1 else None
    return before is not None and before[0] == "text" and str(before[1]).rstrip().endswith(":")


def messages(source: str) -> list[tuple[int, ast.expr]]:
    """Each message a module raises or logs: (line, its first argument)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call) or not node.args:
            continue
        f = node.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
        # a line for people is a log call's one argument; Rerun's ``rec.log(entity, archetype)``
        # names an entity path, not a sentence
        if name in ERRORS or (name in LOG_LINES and len(node.args) == 1 and not node.keywords):
            found.append((node.lineno, node.args[0]))
    return found


def _modules() -> list[Path]:
    return [
        p
        for package in PACKAGES
        for p in sorted((ROOT / package).rglob("*.py"))
        if not any(p.relative_to(ROOT).as_posix().startswith(k) for k in PENDING)
    ]


def _pending(rel: str, node: ast.expr) -> bool:
    # its text, each value a "{}"
    text = "".join(str(piece) if kind == "text" else "{}" for kind, piece in _parts(node)).rstrip()
    return any(rel == m and text.endswith(words) for m, words in PENDING_MESSAGES)


def unfinished() -> list[str]:
    """``file:line: …its last words`` of every message that does not end a sentence."""
    out = []
    for path in _modules():
        rel = path.relative_to(ROOT).as_posix()
        for line, node in messages(path.read_text(encoding="utf-8")):
            if not ends_a_sentence(node) and not _pending(rel, node):
                out.append(f"{rel}:{line}: …{ast.unparse(node)[-60:]}")
    return out


def test_every_message_ends_its_sentence() -> None:
    assert unfinished() == []


def test_a_message_that_stops_mid_air_is_found() -> None:
    def judged(code: str) -> list[bool]:
        return [ends_a_sentence(node) for _, node in messages(code)]

    assert judged(
        "raise UserError(f'--tf must be numbers, got {x!r}')\n"
        "say('measuring 4 camera streams')\n"
        "raise UserError('bad ' + 'input (see --help)')\n"
    ) == [False, False, False]
    assert judged(
        "raise UserError(f'--tf must be numbers, got {x!r}.')\n"
        "say(f'{n} file(s) left out:')\n"
        "raise UserError(f'cannot reach {url}: {why}')\n"  # a colon before the value
        "raise UserError(str(exc))\n"  # another message, passed on
        "raise UserError('the photographs need scikit-image: pip install scikit-image')\n"
        "log(f'is {x} too high?')\n"
    ) == [True, True, True, True, True, True]
    # an entity path logged to Rerun is not a message (its name would gain a full stop)
    assert judged("rec.log(f'{base}/heatmap', rr.Image(img), static=True)\n") == []


def test_the_pending_modules_and_messages_exist() -> None:
    """An entry of PENDING that names nothing (the move merged, the message ended) goes."""
    for rel in PENDING:
        assert (ROOT / rel).exists(), rel
    for rel, words in PENDING_MESSAGES:
        source = (ROOT / rel).read_text(encoding="utf-8")
        assert any(_pending(rel, node) for _, node in messages(source)), (rel, words)


def _fix() -> None:
    """Add a full stop inside the closing quote of each unfinished message's last literal."""
    left = []
    for path in _modules():
        rel = path.relative_to(ROOT).as_posix()
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines(keepends=True)
        edits = []
        for line, node in messages(source):
            if ends_a_sentence(node) or _pending(rel, node):
                continue
            last = node.right if isinstance(node, ast.BinOp) else node
            if not isinstance(last, ast.Constant | ast.JoinedStr) or last.end_lineno is None:
                left.append(f"{rel}:{line}")
                continue
            raw = lines[last.end_lineno - 1].encode()
            quote = (
                3 if raw[last.end_col_offset - 3 : last.end_col_offset] in (b'"""', b"'''") else 1
            )
            edits.append((last.end_lineno - 1, last.end_col_offset - quote))
        for row, col in sorted(edits, reverse=True):
            raw = lines[row].encode()
            lines[row] = (raw[:col] + b"." + raw[col:]).decode()
        if edits:
            path.write_text("".join(lines), encoding="utf-8")
    print("\n".join(f"ended by hand: {where}" for where in left) or "done")


if __name__ == "__main__" and "--fix" in sys.argv:
    _fix()

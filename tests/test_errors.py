"""Which errors are one line: only those vdc raises on purpose for bad input (vdc.errors'
UserError, avdm.errors' ParameterError, a recording that is not one); a bug's exception, a
ValueError from NumPy included, keeps its traceback and exit status 1."""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Callable

import numpy as np
import pytest

from vdc.cli_support import run_command_line
from vdc.errors import UserError


def _run(body: Callable[[], object]) -> int:
    parser = argparse.ArgumentParser(prog="vdc-test")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("go").set_defaults(func=lambda _args: body())
    return run_command_line("vdc-test", parser, ["go"])


def _user_error() -> None:
    raise UserError("no such clip: a.mp4")


def _bad_model() -> None:
    from avdm.registry import make_model

    make_model("avdm:beta=x")


def _not_a_recording() -> None:
    from analysis.recordings.reader import Recording

    Recording(__file__)


@pytest.mark.parametrize(
    ("body", "needle"),
    [(_user_error, "no such clip"), (_bad_model, "beta"), (_not_a_recording, "test_errors")],
)
def test_errors_raised_on_purpose_are_one_line_and_exit_2(
    body: Callable[[], None], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        _run(body)
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vdc-test go: error: ") and needle in lines[0]


def test_a_bugs_value_error_keeps_its_traceback() -> None:
    with pytest.raises(ValueError, match="reshape"):
        _run(lambda: np.zeros(3).reshape(2))


def test_a_bug_exits_1_with_its_traceback() -> None:
    """The whole way: a command line whose command hits a NumPy ValueError."""
    code = (
        "import argparse, numpy as np\n"
        "from vdc.cli_support import run_command_line\n"
        "p = argparse.ArgumentParser(prog='t'); s = p.add_subparsers(dest='command')\n"
        "s.add_parser('go').set_defaults(func=lambda a: np.zeros(3).reshape(2))\n"
        "run_command_line('t', p, ['go'])\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 1
    assert "Traceback" in proc.stderr and "reshape" in proc.stderr

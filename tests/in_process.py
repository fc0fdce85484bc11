"""``run_in_process``: a command line run inside the test's own process, for the tests that
check only what a command prints, writes and exits with.

A ``python -m analysis|capture`` subprocess (``tests.helpers.run_cli``) first spends about two
CPU seconds importing NumPy, Numba, polars, Rerun and matplotlib and loading the cached Numba
kernels; in the test's process that is paid once per xdist worker. The command runs through the
console scripts' own entry (``vdc.launch``) with ``sys.argv`` set, so it parses, fails and
exits exactly as a user's would. What a separate process would have kept apart is kept apart:

* stdout and stderr are captured at the file descriptors (so the output of the pool workers
  a command spawns is captured too, as a subprocess's pipes would), and ``sys.stdout`` /
  ``sys.stderr`` write to them;
* warnings are shown on stderr as a fresh interpreter shows them (not recorded by pytest), so a
  test of "one line on stderr" still sees a warning that would break it;
* an exception that escapes the command is printed as the interpreter would (a traceback,
  exit status 1); SystemExit gives the exit status; Ctrl-C, which the command takes as a user's
  (status 130), then stops the test run too;
* the environment, the working folder, ``sys.argv``, the signal handlers, the root logger's
  handlers and OpenCV's thread count are restored afterwards;
* ``timeout`` ends the command with :class:`subprocess.TimeoutExpired`, as ``subprocess.run``;
* under ``tests.figures.figure_env`` the figures the command saves are recorded as its probe
  records them in a subprocess (the processes it starts load the probe themselves).

Keep a real subprocess (``run_cli``) where the test is about the process: signals, kill, ptys,
timeouts, resource limits, interpreter-level tracebacks, "no process left", start-up time, or
a plug-in module loaded from the current folder (cached per process).
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import tempfile
import traceback
import warnings
from pathlib import Path

from tests import figures
from tests.helpers import ROOT

_ENTRIES = {
    "analysis": ("vdc-analyse", "analysis.cli"),
    "analysis.cli": ("vdc-analyse", "analysis.cli"),
    "capture": ("vdc-capture", "capture.cli"),
}
_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGPIPE, signal.SIGALRM)


class _Timeout(BaseException):
    """Raised in the command by the timer (a BaseException: the command's own ``except
    Exception`` cannot take it for an error of its own)."""


def _fresh_interpreter_warnings() -> None:
    """The warning filters of ``python -m`` without -W options, shown on sys.stderr."""
    warnings.resetwarnings()
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
    for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.filterwarnings("ignore", category=category)

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    warnings.showwarning = show


def _record_figures(record: str):
    """Append every Figure saved from now on to ``record`` (as ``figures.install_from_env``);
    returns the function that stops it."""
    import json

    from matplotlib.figure import Figure

    def append(info: dict) -> None:
        with open(record, "a", encoding="utf-8") as f:
            f.write(json.dumps(info) + "\n")

    original = figures._install(append)

    def stop() -> None:
        Figure.savefig = original

    return stop


def run_in_process(
    *args: str, cwd: Path | None = None, timeout: float = 300, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    """``run_cli(*args)`` (``args[0]`` is ``analysis`` or ``capture``) in this process: the
    same CompletedProcess (args, returncode, stdout, stderr as text)."""
    import logging

    from vdc.launch import launch

    prog, module = _ENTRIES[args[0]]
    argv = [str(a) for a in args[1:]]
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    saved_fds = (os.dup(1), os.dup(2))
    saved_streams = (sys.stdout, sys.stderr)
    saved = {
        "environ": dict(os.environ),
        "cwd": os.getcwd(),
        "argv": sys.argv,
        "signals": {s: signal.getsignal(s) for s in _SIGNALS},
        "log_handlers": list(logging.getLogger().handlers),
        "log_level": logging.getLogger().level,
        "cv2_threads": sys.modules["cv2"].getNumThreads() if "cv2" in sys.modules else None,
    }
    files = (tempfile.TemporaryFile(), tempfile.TemporaryFile())
    status = 0
    unrecord = None

    def expire(signum, frame) -> None:
        raise _Timeout

    try:
        if env is not None:
            os.environ.clear()
            os.environ.update(env)
        os.environ["PYTHONUNBUFFERED"] = "1"  # for the processes the command starts
        if os.environ.get(figures.ENV):  # what the probe's sitecustomize does in a subprocess
            unrecord = _record_figures(os.environ[figures.ENV])
        os.chdir(cwd or ROOT)
        sys.argv = [prog, *argv]
        os.dup2(files[0].fileno(), 1)
        os.dup2(files[1].fileno(), 2)
        sys.stdout, sys.stderr = (
            io.TextIOWrapper(open(os.dup(fd), "wb"), encoding="utf-8", line_buffering=True)
            for fd in (1, 2)
        )
        signal.signal(signal.SIGALRM, expire)
        signal.setitimer(signal.ITIMER_REAL, timeout)
        with warnings.catch_warnings():
            _fresh_interpreter_warnings()
            try:
                status = launch(prog, module)
            except SystemExit as exc:
                code = exc.code
                if code is None or isinstance(code, int):
                    status = code or 0
                else:  # SystemExit("message"): printed, status 1, as the interpreter does
                    print(code, file=sys.stderr)
                    status = 1
            except _Timeout:
                raise
            except BaseException:  # the interpreter prints it and exits 1
                traceback.print_exc()
                status = 1
    except _Timeout:
        status = None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        if unrecord is not None:
            unrecord()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
                stream.close()
            except Exception:  # a stream the command closed itself
                pass
        sys.stdout, sys.stderr = saved_streams
        os.dup2(saved_fds[0], 1)
        os.dup2(saved_fds[1], 2)
        for fd in saved_fds:
            os.close(fd)
        os.chdir(saved["cwd"])
        os.environ.clear()
        os.environ.update(saved["environ"])
        sys.argv = saved["argv"]
        for s, handler in saved["signals"].items():
            signal.signal(s, handler)
        root = logging.getLogger()
        root.handlers[:] = saved["log_handlers"]
        root.setLevel(saved["log_level"])
        if saved["cv2_threads"] is not None:
            sys.modules["cv2"].setNumThreads(saved["cv2_threads"])
    out, err = (_read(f) for f in files)
    cmd = [sys.executable, "-m", *args]
    if status is None:
        raise subprocess.TimeoutExpired(cmd, timeout, out, err)
    if status == 130:  # Ctrl-C (no test signals a command it runs in its own process)
        raise KeyboardInterrupt(err)
    return subprocess.CompletedProcess(cmd, status, out, err)


def _read(f) -> str:
    f.seek(0)
    text = f.read().decode("utf-8", "replace")
    f.close()
    return text

"""A long command is never silent: a heartbeat line at most every few seconds.

A :class:`Heartbeat` prints the lines a command logs and, whenever nothing was printed for
``every_s`` seconds, one more: how long the command has run, what it is doing (its last
line) and, when it counts units (runs, clips, episodes, frames), how many of how many are
done and about how long the rest takes. A background thread prints it, so a stage that
reports nothing (a worker's first run, a fit, a sweep in this process) still shows it is
alive.

The command line turns it on when stderr is a terminal, or when ``VDC_PROGRESS=1`` (a log
file, a test); pipes and CI logs otherwise keep the command's own lines only. A script
turns it on with ``with vdc.Feedback.printing() as feedback:``.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
from typing import Any, TextIO

from vdc.errors import UserError  # standard library only: nothing heavy

# A line at most 4 s after the last: the promise is one at least every 10 s, and the 6 s
# left is margin for a loaded machine (the ticker thread waits for a core and for the GIL,
# which Python hands between threads every 5 ms; at a load of 11 on 2 cores the lines of a
# quick reproduction came 4.0-4.6 s apart, the ticker looking every 0.5 s). Frequent enough
# that a person sees it move, rare enough that a 4-minute run prints about 60 lines.
EVERY_S = 4.0

ENV = "VDC_PROGRESS"  # "1": heartbeat lines on stderr even when it is not a terminal
# seconds of silence before a heartbeat line, instead of EVERY_S: the tests shorten it, so
# that a command of a few seconds shows its beats and counts whatever the machine's load
EVERY_ENV = "VDC_PROGRESS_EVERY_S"


def interval_s() -> float:
    """The silence before a heartbeat line: ``VDC_PROGRESS_EVERY_S`` (seconds, above 0) if
    set, else :data:`EVERY_S`."""
    text = os.environ.get(EVERY_ENV, "").strip()
    if not text:
        return EVERY_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise UserError(f"{EVERY_ENV}={text!r} is not a number of seconds above 0.")
    return value


def wanted(stream: TextIO | None = None) -> bool:
    """Whether the command line prints heartbeat lines: ``VDC_PROGRESS=1``, or stderr (or
    ``stream``) is a terminal; ``VDC_PROGRESS=0`` never."""
    env = os.environ.get(ENV)
    if env in ("0", "1"):
        return env == "1"
    stream = stream or sys.stderr
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


# commands that wait for the user (a server, a robot emulator): no heartbeat, however long
WAITING = (("catalog", "serve"), ("emulate-robot",))


def waits(words: list[str]) -> bool:
    """Whether a command line's words (after the program) start a command that waits."""
    return any(tuple(words[: len(w)]) == w for w in WAITING)


def duration(seconds: float) -> str:
    """``75`` → ``1 min 15 s``; ``3700`` → ``1 h 2 min``."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {s % 3600 // 60} min"


IRREGULAR = {"stimulus": "stimuli"}


def plural(noun: str, n: int) -> str:
    """``run`` → ``runs``, ``stimulus`` → ``stimuli``, unless there is one."""
    if n == 1:
        return noun
    if noun in IRREGULAR:
        return IRREGULAR[noun]
    return noun + ("es" if noun.endswith(("s", "sh", "ch")) else "s")


class Counter:
    """Units of one stage: how many are done, of how many (None: not known yet)."""

    def __init__(self, desc: str, unit: str, total: int | None) -> None:
        self.desc, self.unit, self.total = desc, unit, total
        self.done = 0
        self.t0 = time.monotonic()
        # when the first unit that took time ended: units read back from an earlier run
        # (a campaign's reused runs) finish at once and would make the estimate too short
        self.t_first: float | None = None
        self.done_first = 0

    def update(self, n: int = 1) -> None:
        now = time.monotonic()
        if self.t_first is None and now - self.t0 > 0.5:
            self.t_first, self.done_first = self.t0, self.done
        self.done += n

    def expect(self, n: int) -> None:
        """``n`` more units are planned."""
        self.total = (self.total or 0) + n

    def line(self) -> str:
        """``3 of 12 runs done, about 1 min 5 s left`` (or ``3 runs done`` with no total)."""
        unit = plural(self.unit, self.total if self.total is not None else self.done)
        if self.total is None:
            return f"{self.done} {unit} done"
        text = f"{self.done} of {self.total} {unit} done"
        left = self.total - self.done
        if left <= 0:
            return text
        timed = self.done - self.done_first
        start = self.t_first if self.t_first is not None else self.t0
        if timed <= 0:
            return f"{text}, no estimate before the first {self.unit} ends"
        rate = timed / max(time.monotonic() - start, 1e-9)
        return f"{text}, about {duration(math.ceil(left / rate))} left"


class Heartbeat:
    """The lines of one command on ``stream`` (default stderr), and a heartbeat line when
    nothing was printed for ``every_s`` seconds. Use it as a context manager (the ticker
    thread runs inside the block); :meth:`vdc.Feedback.printing` gives a Feedback that
    reports to one."""

    def __init__(
        self, what: str, every_s: float | None = None, stream: TextIO | None = None
    ) -> None:
        # (None: VDC_PROGRESS_EVERY_S or EVERY_S, read when the command starts)
        self.what, self.stream = what, stream
        self.every_s = every_s if every_s is not None else interval_s()
        self.t0 = time.monotonic()
        self.last_print = self.t0
        self.stage = "starting"
        self.counters: list[Counter] = []
        self.lock = threading.Lock()
        self.stopped = threading.Event()
        self.thread: threading.Thread | None = None

    # -- what the command reports
    def log(self, line: str) -> None:
        """Print ``line`` (a line of the command's log) and remember it as what it is doing."""
        with self.lock:
            self._print(line)
            # an indented line is a detail of the stage (a run finished), not a new stage
            if line.strip() and not line[:1].isspace():
                self.stage = line.strip()

    def counter(self, desc: str, unit: str, total: int | None = None) -> Counter:
        c = Counter(desc, unit, total)
        with self.lock:
            self.counters.append(c)
        return c

    def drop(self, c: Counter) -> None:
        with self.lock, contextlib.suppress(ValueError):
            self.counters.remove(c)

    # -- the ticker
    def tick_line(self) -> str:
        """``vdc-analyse boundary: 1 min 5 s in; stage 1/2: 12 closed-loop run(s): 3 of 12
        runs done, about 2 min left.``"""
        now = time.monotonic()
        # the newest stage still counting (a finished one's "12 of 12" says nothing now)
        busy = [c for c in self.counters if (c.done < c.total if c.total else c.done > 0)]
        counted = f": {busy[-1].line()}" if busy else ""
        # before its first line, a command is what it counts (measuring, the sweep, ...)
        stage = (busy[-1].desc if busy and self.stage == "starting" else self.stage).rstrip(".:;")
        if len(stage) > 100:  # a long log line, shortened: the count after it is the news
            stage = stage[:99].rstrip() + "…"
        return f"{self.what}: {duration(now - self.t0)} in; {stage}{counted}."

    def _print(self, line: str) -> None:
        stream = self.stream or sys.stderr
        try:
            print(line, file=stream, flush=True)
        except (OSError, ValueError):  # a closed pipe: the command goes on regardless
            pass
        self.last_print = time.monotonic()

    def _run(self) -> None:
        while not self.stopped.wait(min(0.5, self.every_s / 4)):
            with self.lock:
                if time.monotonic() - self.last_print >= self.every_s:
                    self._print("  ... " + self.tick_line())

    def __enter__(self) -> Heartbeat:
        global _current
        self.previous = _current
        _current = self
        self.thread = threading.Thread(target=self._run, name="vdc-heartbeat", daemon=True)
        self.thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        global _current
        self.stopped.set()
        if self.thread is not None:
            self.thread.join()
        _current = self.previous


# the heartbeat of the command running in this process (set inside a Heartbeat's block)
_current: Heartbeat | None = None


def _forget_in_child() -> None:
    """A forked worker has no ticker thread, and its copy of the lock may be held: its lines
    go straight to stderr."""
    global _current
    _current = None


os.register_at_fork(after_in_child=_forget_in_child)


def current() -> Heartbeat | None:
    return _current


def emit(line: str) -> None:
    """A line on stderr at once; through the running heartbeat when there is one (it then
    knows what the command is doing)."""
    hb = _current
    if hb is not None:
        hb.log(line)
    else:
        print(line, file=sys.stderr, flush=True)


class Count:
    """A stage's count of units (frames, clips, runs) on the running heartbeat: ``update``
    (n more done), ``expect`` (n more planned), ``close`` (the stage ended; also as a context
    manager). Nothing without a heartbeat (a pipe, a CI log, ``--quiet``) or with ``quiet``."""

    def __init__(
        self, total: int | None, desc: str, unit: str = "unit", quiet: bool = False
    ) -> None:
        hb = None if quiet else _current
        self.hb = hb
        self.counter = hb.counter(desc, unit, total) if hb is not None else None

    def update(self, n: int = 1) -> None:
        if self.counter is not None:
            self.counter.update(n)

    def expect(self, n: int) -> None:
        if self.counter is not None:
            self.counter.expect(n)

    def close(self) -> None:
        if self.hb is not None and self.counter is not None:
            self.hb.drop(self.counter)
        self.counter = None

    def __enter__(self) -> Count:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

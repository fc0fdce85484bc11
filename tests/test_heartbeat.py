"""Never silent (vdc.heartbeat): a command prints a line at least every 10 s, with what it is
doing, how many units of how many are done and about how long the rest takes; a script turns
the same lines on with ``vdc.Feedback.printing()``."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from tests.helpers import ROOT

# The promise: no stretch of more than 10 s without a line. The heartbeat prints one 4 s after
# the last (vdc.heartbeat.EVERY_S), so the 6 s between is margin for a loaded machine.
PROMISE_S = 10.0


def _timed_lines(args: list[str], cwd: Path) -> tuple[int, list[tuple[float, str]]]:
    """Run ``python -m <args>`` with the heartbeat forced on (VDC_PROGRESS=1: its stderr is a
    pipe here, not a terminal); each line of stdout and stderr with the wall-clock second it
    arrived at, from the process's start."""
    env = {**os.environ, "VDC_PROGRESS": "1", "PYTHONUNBUFFERED": "1"}
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        bufsize=1,
    )
    lines: list[tuple[float, str]] = []
    lock = threading.Lock()

    def read(stream) -> None:
        for line in stream:  # as each line arrives
            with lock:
                lines.append((time.monotonic() - t0, line.rstrip("\n")))

    readers = [threading.Thread(target=read, args=(s,)) for s in (proc.stdout, proc.stderr)]
    for r in readers:
        r.start()
    status = proc.wait(timeout=300)
    end = time.monotonic() - t0
    for r in readers:
        r.join()
    return status, [*sorted(lines), (end, "<exit>")]


def test_looming_footage_prints_a_line_at_least_every_10_s_with_its_count(tmp_path) -> None:
    """24 clips render for 15-30 s on a busy 2-core machine: before the heartbeat, the plan's
    line and the summary were all it printed, 15 s and more apart."""
    status, lines = _timed_lines(
        ["analysis", "looming-footage", "--clips", "24", "--out", str(tmp_path / "clips")],
        ROOT,
    )
    assert status == 0, lines
    times = [0.0] + [t for t, _ in lines]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) <= PROMISE_S, list(zip(gaps, lines, strict=True))
    beats = [text for _, text in lines if text.startswith("  ... vdc-analyse looming-footage")]
    assert beats, lines
    # the count of clips, of how many, and an estimate of what is left; a finished sentence
    assert any(" of 24 clips done, about " in b and b.endswith(" left.") for b in beats), beats


def test_a_library_call_prints_when_asked_and_is_quiet_by_default(tmp_path, capfd) -> None:
    import vdc
    from analysis.experiments.collision.looming_footage import (
        LoomingFootageSettings,
        looming_footage,
    )

    settings = LoomingFootageSettings(clips=4)
    looming_footage(settings, tmp_path / "quiet")
    assert capfd.readouterr().err == ""  # quiet by default
    # a beat every 0.05 s: rendering a clip takes longer, so a count shows between clips
    with vdc.Feedback.printing("looming", unit="clip", every_s=0.05) as feedback:
        looming_footage(settings, tmp_path / "loud", feedback)
    err = capfd.readouterr().err.splitlines()
    assert err[0].startswith("looming-footage: 4 clips"), err
    beats = [line for line in err if line.startswith("  ... looming: ")]
    assert any(" of 4 clips done" in b for b in beats), err


def test_a_count_reads_as_english() -> None:
    from vdc.heartbeat import Counter, duration, plural

    assert [plural("run", 2), plural("clip", 1), plural("stimulus", 60)] == [
        "runs",
        "clip",
        "stimuli",
    ]
    assert [duration(5), duration(75), duration(3700)] == ["5 s", "1 min 15 s", "1 h 1 min"]
    c = Counter("sweep", "cell", None)
    c.expect(10)
    assert c.line() == "0 of 10 cells done, no estimate before the first cell ends"


def test_a_command_that_waits_for_the_user_has_no_heartbeat() -> None:
    """A catalog server or a robot emulator waits for hours by design: a line every 4 s would
    bury the one that matters (its URL, its device)."""
    from vdc.heartbeat import waits

    assert waits(["catalog", "serve", "results"]) and waits(["emulate-robot", "--link", "x"])
    assert not waits(["catalog", "query", "results"]) and not waits(["boundary"])

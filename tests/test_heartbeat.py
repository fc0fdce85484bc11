"""Never silent (vdc.heartbeat): every first-hour command prints a line at least every 10 s, with
what it is doing, how many units of how many are done and about how long the rest takes; a
script turns the same lines on with ``vdc.Feedback.printing()``.

Each command runs as a real subprocess on a small input, its lines timestamped as they arrive.
The heartbeat's interval is shortened (``VDC_PROGRESS_EVERY_S``) so that a command of a few
seconds shows its beats and counts; the tests assert on what was sent (a beat before the
command's first line, a beat inside its longest silence, a count of how many of how many with
an estimate of what is left), never on wall-clock gaps, which a busy machine stretches."""

from __future__ import annotations

import itertools
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.helpers import ROOT, flags, write_pan

# The silence before a beat in these tests: short, so that the few seconds each command's
# counting stage lasts on these inputs hold several beats (the default is 4 s, for people).
EVERY_S = 0.05

BEAT = re.compile(r"^  \.\.\. (?P<what>[^:]+): (?P<elapsed>[^;]+) in; (?P<rest>.*)\.$")
DURATION = r"\d+ s|\d+ min \d+ s|\d+ h \d+ min"
ESTIMATE = re.compile(
    rf"(?P<done>\d+) of (?P<total>\d+) (?P<unit>\w+) done, about (?P<left>{DURATION}) left$"
)
COUNT = re.compile(r"(?P<done>\d+) of (?P<total>\d+) (?P<unit>\w+) done")


def _timed_lines(args: list[str], cwd: Path = ROOT) -> tuple[int, list[tuple[float, str]]]:
    """Run ``python <args>`` with the heartbeat forced on (VDC_PROGRESS=1: its stderr is a
    pipe here, not a terminal) every EVERY_S; each line of stdout and stderr with the second
    it arrived at, from the process's start."""
    env = {
        **os.environ,
        "VDC_PROGRESS": "1",
        "VDC_PROGRESS_EVERY_S": str(EVERY_S),
        "PYTHONUNBUFFERED": "1",
    }
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, *args],
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
    try:
        status = proc.wait(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        for r in readers:
            r.join(timeout=30)
    return status, sorted(lines)


def assert_never_silent(lines: list[tuple[float, str]], what: str, total: str, unit: str) -> None:
    """The heartbeat of the command ``what`` covered it from its start and through its longest
    silence, and counted ``unit``s of ``total`` (a regular expression: a stage's total may
    grow) with an estimate of what is left."""
    beats = [(t, m) for t, text in lines if (m := BEAT.match(text))]
    own = [t for t, text in lines if not BEAT.match(text)]
    assert beats and own, lines
    assert {m["what"] for _, m in beats} == {what}, {m["what"] for _, m in beats}
    # the start-up (the imports: seconds on a busy machine) is covered before the first line
    assert beats[0][0] < own[0], lines[:5]
    # the command's longest silence of its own (from the start to its last line) held a beat
    a, b = max(itertools.pairwise([0.0, *own]), key=lambda gap: gap[1] - gap[0])
    assert any(a < t < b for t, _ in beats), (a, b, lines)
    counts = [c for _, m in beats if (c := COUNT.search(m["rest"]))]
    assert all(int(c["done"]) <= int(c["total"]) for c in counts), counts
    estimates = [
        e
        for _, m in beats
        if (e := ESTIMATE.search(m["rest"]))
        and re.fullmatch(total, e["total"])
        and e["unit"] == unit
    ]
    assert estimates, [m["rest"] for _, m in beats]
    assert all(0 < int(e["done"]) < int(e["total"]) for e in estimates), estimates


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """500 frames of 490x360 px, 70 deg wide: the robot camera's raster once resized (99x73 px),
    whose calibration vdc ships (no fit to wait for); large enough frames that decoding them
    lasts a few beats."""
    return write_pan(tmp_path_factory.mktemp("clip") / "clip.mp4", 490, 360, 500)


def test_vdc_capture_video_counts_the_frames_it_decodes(clip, tmp_path) -> None:
    """It was silent 12.6 s before its first line: the read-ahead decodes the clip first."""
    status, lines = _timed_lines(
        ["-m", "capture", "video", str(clip), "--fov-deg", "70", "--out", str(tmp_path / "c.rrd")]
    )
    assert status == 0, lines
    assert_never_silent(lines, "vdc-capture video", "500", "frames")


def test_complexity_of_a_video_counts_its_frames_of_those_the_container_states(
    clip, tmp_path
) -> None:
    status, lines = _timed_lines(
        ["-m", "analysis", "complexity", str(clip), "--fov-deg", "70", "--out", str(tmp_path)]
    )
    assert status == 0, lines
    assert_never_silent(lines, "vdc-analyse complexity", "500", "frames")


def test_dataset_counts_its_camera_streams(tmp_path) -> None:
    from analysis.dataset.synthetic import write_dataset

    # frames of 240x320 px: the streams after the worker's first take a few beats each
    write_dataset(tmp_path / "ds", episodes=4, codec="libx264", shape=(240, 320))
    status, lines = _timed_lines(
        [
            "-m",
            "analysis",
            "dataset",
            str(tmp_path / "ds"),
            *flags("--jobs 1", out=tmp_path / "out"),
        ]
    )
    assert status == 0, lines
    assert_never_silent(lines, "vdc-analyse dataset", "4", "cameras")


# the smallest grid that decides something: 2 conditions x 2 seeds of 6 s (TF 3 Hz alerts the
# detector at once), then as many profiling runs
BOUNDARY = flags(
    "--tf 0,3 --scenes grating --values 12 --seeds 2 --minutes 0.1 --jobs 1 --no-predictors"
)


def test_boundary_counts_its_runs(tmp_path) -> None:
    """It was silent 14.8 s inside a stage."""
    status, lines = _timed_lines(["-m", "analysis", "boundary", *BOUNDARY, "--out", str(tmp_path)])
    assert status == 0, lines
    assert_never_silent(lines, "vdc-analyse boundary", "4|8", "runs")


def test_the_library_boundary_counts_its_runs_with_feedback_printing(tmp_path) -> None:
    """``vdc.boundary()`` from a script printed nothing for 21 s: quiet by default, its
    Feedback prints as the command line does (docs/guides/python.md)."""
    script = (
        "import sys, vdc\n"
        "s = vdc.BoundarySettings(tf='0,3', scenes='grating', values='12', seeds=1,\n"
        "                         minutes=0.1, jobs=1, no_predictors=True)\n"
        "with vdc.Feedback.printing('boundary') as feedback:\n"
        "    vdc.boundary(s, sys.argv[1], feedback)\n"
    )
    status, lines = _timed_lines(["-c", script, str(tmp_path)])
    assert status == 0, lines
    assert_never_silent(lines, "boundary", "2|4", "runs")


def test_a_quick_reproduction_counts_its_runs(tmp_path) -> None:
    """It was silent for 44.7 s before its first run reported, then for 20-30 s."""
    args = flags(
        "--quick --profile-minutes 0.3 --collision-minutes 0.1 --repeats 1 "
        "--sweep-duration-s 0.1 --seeds 1 --jobs 2"
    )
    status, lines = _timed_lines(["-m", "analysis", "reproduce", *args, "--out", str(tmp_path)])
    assert status == 0, lines
    assert_never_silent(lines, "vdc-analyse reproduce", "10", "runs")
    # the profiling tables count the planned frames (5 runs of 0.3 min at 33 Hz) and the
    # collision study its recordings (5 phases): each stage's beats say how far it is
    counted = {
        (c["total"], c["unit"])
        for _, text in lines
        if (m := BEAT.match(text)) and (c := COUNT.search(m["rest"]))
    }
    assert {("2970", "frames"), ("5", "recordings")} <= counted, counted


def test_looming_footage_counts_its_clips(tmp_path) -> None:
    """Before the heartbeat, the plan's line and the summary were all it printed, 15 s and
    more apart."""
    status, lines = _timed_lines(
        ["-m", "analysis", "looming-footage", "--clips", "6", "--out", str(tmp_path / "clips")]
    )
    assert status == 0, lines
    assert_never_silent(lines, "vdc-analyse looming-footage", "6", "clips")


def test_a_beat_names_its_count_and_ends_as_a_sentence() -> None:
    """What the assertions above parse, from the heartbeat itself."""
    from vdc.heartbeat import Heartbeat

    hb = Heartbeat("vdc-analyse boundary", every_s=60)
    hb.stage = "stage 1/3: 12 closed-loop run(s) of lgmd-plus-arena."
    c = hb.counter("boundary", "run", 12)
    c.t0 -= 10  # 3 runs in 10 s
    c.update(3)
    m = BEAT.match("  ... " + hb.tick_line())
    assert m and m["what"] == "vdc-analyse boundary"
    e = ESTIMATE.search(m["rest"])
    assert e and (e["done"], e["total"], e["unit"], e["left"]) == ("3", "12", "runs", "31 s")


def test_the_interval_is_read_from_the_environment(monkeypatch) -> None:
    from vdc.errors import UserError
    from vdc.heartbeat import EVERY_S, Heartbeat, interval_s

    monkeypatch.delenv("VDC_PROGRESS_EVERY_S", raising=False)
    assert interval_s() == EVERY_S == Heartbeat("x").every_s
    monkeypatch.setenv("VDC_PROGRESS_EVERY_S", "0.5")
    assert Heartbeat("x").every_s == 0.5 and Heartbeat("x", every_s=2.0).every_s == 2.0
    for bad in ("0", "-1", "soon", "nan", "inf"):
        monkeypatch.setenv("VDC_PROGRESS_EVERY_S", bad)
        with pytest.raises(UserError, match="VDC_PROGRESS_EVERY_S"):
            interval_s()


def test_a_bad_interval_is_one_line_and_exit_2() -> None:
    env = {**os.environ, "VDC_PROGRESS": "1", "VDC_PROGRESS_EVERY_S": "soon"}
    proc = subprocess.run(
        [sys.executable, "-m", "analysis", "boundary", "--help"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.splitlines() == [
        "vdc-analyse boundary: error: VDC_PROGRESS_EVERY_S='soon' is not a number of seconds "
        "above 0."
    ]


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

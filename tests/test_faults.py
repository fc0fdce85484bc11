"""Fault injection on real processes and real files: concurrent writers, a dead viewer, gaps
and bad packets in the input, signals to parents with live pools, an input given as the
output, a recording still growing, resource limits and duplicate recording ids.

Every test checks what is left afterwards (the files, the tables, the process list), not
only the exit status. The module runs in well under two minutes.
"""

from __future__ import annotations

import hashlib
import os
import resource
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import av
import cv2
import numpy as np
import polars as pl
import pytest

from analysis.recordings.reader import Recording
from tests.helpers import ROOT, assert_one_line_error, end_group, run_cli, spawn, wait_until
from tests.in_process import run_in_process
from vdc.executors import pool_size, usable_cpus
from vdc.recording import partial_path

PY = sys.executable


def _processes_mentioning(text: str) -> list[str]:
    """Command lines of live processes that mention ``text`` (a test's own folder)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in args and _alive(int(cmdline.parent.name)):
            found.append(args)
    return found


def assert_clean(folder: Path) -> None:
    """No capture, staging folder or claim left in ``folder``, and no process working on it."""
    left = [
        p.name
        for p in folder.rglob("*")
        if p.name.endswith((".partial.rrd", ".lock")) or ".staging-" in p.name
    ]
    assert not left, left
    assert not _processes_mentioning(str(folder)), _processes_mentioning(str(folder))


def sim(out: Path, *extra: str, minutes: float = 0.5, **kwargs) -> subprocess.Popen:
    cmd = [PY, "-m", "capture", "sim", "--minutes", str(minutes), "--out", str(out), "--quiet"]
    return spawn(
        [*cmd, *extra],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def n_frames(path: Path) -> int:
    return sum(len(c.frame) for c in Recording(path).iter_frames())


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- concurrent writers ------------------------------------------------------------------------
@pytest.mark.parametrize("force", [False, True])
def test_two_captures_to_one_path_one_wins_and_the_file_is_whole(tmp_path: Path, force) -> None:
    out = tmp_path / "race.rrd"
    extra = ("--force",) if force else ()
    for _ in range(2):
        out.unlink(missing_ok=True)
        procs = [sim(out, *extra), sim(out, *extra)]
        results = [(p.wait(timeout=120), *p.communicate()) for p in procs]
        codes = sorted(r[0] for r in results)
        # one wins; the other is refused in one line, whether it started during the winner's
        # run (the claim is held) or after it (the file exists; with --force it replaces a
        # complete file with another complete one, and both succeed)
        assert codes in ([0, 2], [0, 0] if force else [0, 2]), results
        for code, _, err in results:
            if code == 2:
                assert "another capture is writing" in err or "already exists" in err, err
                assert "Traceback" not in err
        assert n_frames(out) == 990  # 0.5 min at 33 Hz: whole, never two runs interleaved
        assert Recording(out).notice is None  # a footer: the file was closed, not cut
        assert_clean(tmp_path)


def test_an_output_in_an_unwritable_place_is_one_line(tmp_path: Path) -> None:
    assert_one_line_error(
        run_in_process("capture", "sim", "--minutes", "0.1", "--out", "/proc/vdc-x.rrd"), "/proc"
    )
    assert not Path("/proc/vdc-x.rrd").exists()


# two workers that would sleep a minute each: long enough to be killed mid-task
# each task marks, in the folder given as the script's argument, that it is running
SCRIPT = """
import sys
from tests.helpers import touch_then_sleep
from vdc.executors import ExecutorSettings, run_tasks
tasks = [(k, (f"{sys.argv[1]}/{k}.running", 60)) for k in "ab"]
run_tasks(touch_then_sleep, tasks, ExecutorSettings(jobs=2))
"""


def _children(pid: int) -> list[int]:
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            kids.append(int(stat.parent.name))
    return kids


def _descendants(pid: int) -> list[int]:
    """Children, their children, ...: the pool's workers are the fork server's children."""
    found, todo = [], [pid]
    while todo:
        kids = _children(todo.pop())
        found += kids
        todo += kids
    return found


def _processes_holding(folder: Path) -> list[str]:
    """Files inside ``folder`` that a live process holds open (pid: path), from /proc."""
    held = []
    for fd in Path("/proc").glob("[0-9]*/fd/*"):
        try:
            target = os.readlink(fd)
        except OSError:  # gone, or another user's process
            continue
        if target.startswith(str(folder)) and _alive(int(fd.parent.parent.name)):
            held.append(f"{fd.parent.parent.name}: {target}")
    return held


def _has_loaded(pid: int, package: str) -> bool:
    """Whether process ``pid`` has mapped a shared library from ``package`` (it imported it)."""
    try:
        return f"/{package}/" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has ended; only its exit status waits to be collected


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_pool_workers_end_when_their_parent_is_killed(sig, tmp_path: Path) -> None:
    env = {**os.environ, "VDC_OVERSUBSCRIBE": "1"}  # two workers even on a one-core runner
    parent = subprocess.Popen([sys.executable, "-c", SCRIPT, str(tmp_path)], cwd=ROOT, env=env)
    workers: list[int] = []
    try:
        running = [tmp_path / "a.running", tmp_path / "b.running"]
        # a wait, not a speed: the fork server imports first, slowly on a machine at load 100+
        assert wait_until(lambda: all(p.exists() for p in running), 300), "no task started"
        # the resource tracker, the fork server and, its children, the two pool workers
        workers = [p for p in _descendants(parent.pid) if _alive(p)]
        assert len(workers) >= 4, f"the pool did not start: descendants {workers}"
        parent.send_signal(sig)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        assert not [p for p in workers if _alive(p)], "workers outlived their parent"
    finally:
        for p in [parent.pid, *workers]:
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass
        parent.wait(timeout=10)


def test_local_pool_is_capped_at_the_usable_cores(monkeypatch) -> None:
    monkeypatch.delenv("VDC_OVERSUBSCRIBE", raising=False)
    assert pool_size(18, 100) == min(18, usable_cpus())
    assert pool_size(18, 1) == 1
    monkeypatch.setenv("VDC_OVERSUBSCRIBE", "1")
    assert pool_size(18, 100) == 18


# -- a dead viewer -----------------------------------------------------------------------------
def test_a_viewer_that_is_not_there_costs_only_the_live_view(tmp_path: Path) -> None:
    out = tmp_path / "a.rrd"
    url = f"rerun+http://127.0.0.1:{_free_port()}/proxy"  # nothing listens there
    proc = sim(out, "--connect", url)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "no Rerun viewer answers" in warnings[0], err
    assert "Traceback" not in err
    assert n_frames(out) == 990 and Recording(out).notice is None
    assert_one_line_error(
        run_cli(
            "capture", "sim", "--out", str(tmp_path / "b.rrd"), "--connect", "rerun+http://a b"
        ),
        "--connect",
    )
    assert not (tmp_path / "b.rrd").exists()
    assert_clean(tmp_path)


def test_a_viewer_that_dies_mid_run_costs_only_the_live_view(tmp_path: Path) -> None:
    import rerun_cli

    viewer_bin = Path(rerun_cli.__file__).parent / "rerun"  # the real server, headless
    port = _free_port()
    viewer = spawn(
        [str(viewer_bin), "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.1)
    out = tmp_path / "live.rrd"
    proc = sim(out, "--connect", f"rerun+http://127.0.0.1:{port}/proxy", minutes=20)
    part = partial_path(out)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not part.exists() or part.stat().st_size < 2e6):
        time.sleep(0.05)
    viewer.kill()  # the viewer is closed while the capture streams to it
    viewer.wait(timeout=10)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "went away" in err and err.count("warning:") == 1, err
    assert n_frames(out) == 39600 and Recording(out).notice is None
    assert_clean(tmp_path)


# -- gaps and bad packets in the input ---------------------------------------------------------
def test_a_gap_and_a_bad_image_in_a_sequence_are_flagged_not_a_cut(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    seq = tmp_path / "seq"
    seq.mkdir()
    for i in range(40):
        cv2.imwrite(str(seq / f"{i:04d}.png"), rng.integers(0, 255, (60, 80), dtype=np.uint8))
    (seq / "0010.png").unlink()  # a gap
    good = (seq / "0020.png").read_bytes()
    (seq / "0020.png").write_bytes(good[: len(good) // 3])  # a truncated image
    out = tmp_path / "seq.rrd"
    res = run_in_process(
        "capture",
        "video",
        str(seq / "%04d.png"),
        "--fps",
        "25",
        "--fov-deg",
        "60",
        "--out",
        str(out),
        "--quiet",
    )
    assert res.returncode == 0, res.stderr
    notes = [ln for ln in res.stderr.splitlines() if "lost inside the source" in ln]
    assert len(notes) == 1 and "0010.png missing" in notes[0], res.stderr
    assert n_frames(out) == 38  # every readable image, past the gap and the bad one
    tables = tmp_path / "t"
    assert run_in_process("analysis", "tables", str(out), "--out", str(tables)).returncode == 0
    events = pl.read_parquet(tables / "events.parquet")
    lost = events.filter(pl.col("kind") == "decode_error")
    assert lost["frame"].to_list() == [10, 19]  # the frames just after each loss
    assert "0020.png" in lost["text"][1]
    dropped = events.filter(pl.col("kind") == "dropped_frames")["frame"].to_list()
    assert dropped == [10, 19]  # and the time line shows the missing frame intervals
    assert_clean(tmp_path)


def test_a_bad_packet_costs_its_own_frames_only(tmp_path: Path) -> None:
    from tests.helpers import write_video

    rng = np.random.default_rng(0)
    clip = write_video(
        tmp_path / "clip.mp4", rng.integers(0, 255, (90, 72, 96), dtype=np.uint8), 30.0
    )
    data = bytearray(clip.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 5000] = bytes(5000)  # a run of zeroed bytes inside the stream
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(bytes(data))
    whole_stream = 0
    with av.open(str(bad)) as c:  # what a whole-stream decode keeps: it stops at the error
        try:
            for _ in c.decode(video=0):
                whole_stream += 1
        except av.FFmpegError:
            pass
    out = tmp_path / "bad.rrd"
    res = run_in_process(
        "capture", "video", str(bad), "--fov-deg", "60", "--out", str(out), "--quiet"
    )
    assert res.returncode == 0, res.stderr
    assert "lost inside the source" in res.stderr and "Traceback" not in res.stderr
    kept = n_frames(out)
    assert whole_stream < 80 <= kept < 90, (whole_stream, kept)  # decoding went on
    kinds = Recording(out).events()["kind"].to_list()
    assert "decode_error" in kinds


# -- input = output ----------------------------------------------------------------------------
def test_a_video_given_as_its_own_output_is_refused_and_unchanged(tmp_path: Path) -> None:
    from tests.helpers import write_video

    clip = write_video(
        tmp_path / "v.rrd", np.zeros((10, 48, 64), np.uint8), 30.0, container="matroska"
    )
    before = hashlib.sha256(clip.read_bytes()).hexdigest()
    res = run_in_process(
        "capture", "video", str(clip), "--fov-deg", "60", "--out", str(clip), "--force"
    )
    assert_one_line_error(res, "source")
    assert hashlib.sha256(clip.read_bytes()).hexdigest() == before
    assert_clean(tmp_path)


# -- a recording still growing -----------------------------------------------------------------
def test_a_growing_recording_is_read_as_one_snapshot(tmp_path: Path) -> None:
    out = tmp_path / "growing.rrd"
    proc = sim(out, "--tf-hz", "3", minutes=60)
    part = partial_path(out)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not part.exists() or part.stat().st_size < 3e6):
        time.sleep(0.05)
    res = run_in_process(
        "analysis", "tables", str(part), "--model", "avdm", "--out", str(tmp_path / "t")
    )
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert res.returncode == 0, res.stderr
    assert "still being written" in res.stderr and "snapshot" in res.stderr
    frames = pl.read_parquet(tmp_path / "t" / "frames.parquet")
    outputs = pl.read_parquet(tmp_path / "t" / "model_outputs.parquet")
    # the tables agree with each other: every frame has its output and nothing more
    assert frames["frame"].to_list() == outputs["frame"].to_list() == list(range(frames.height))
    assert 1000 < frames.height < n_frames(out)  # a snapshot, shorter than the finished run
    summary = pl.read_parquet(tmp_path / "t" / "summary.parquet")
    assert summary["wall_tf_hz"].null_count() == 0
    assert_clean(tmp_path)


# -- resource limits ---------------------------------------------------------------------------
def _limit_file_size(nbytes: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))

    return apply


def test_a_file_size_limit_stops_the_capture_at_once_with_a_readable_file(tmp_path) -> None:
    out = tmp_path / "limited.rrd"
    proc = sim(out, minutes=30, preexec_fn=_limit_file_size(20_000_000))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "no room left" in lines[0] and str(tmp_path) in lines[0], err
    assert "Traceback" not in err
    kept = int(lines[0].split("first ")[1].split()[0])
    rec = Recording(out)
    assert rec.notice is None  # stopped before the limit: the footer fitted
    assert n_frames(out) == kept and 1000 < kept < 59400
    assert rec.properties()["run_end"]["stop_reason"] == "write error"
    assert out.stat().st_size <= 20_000_000
    assert_clean(tmp_path)


def test_analysis_temporaries_never_outlive_a_full_disk(tmp_path: Path) -> None:
    src = tmp_path / "src.rrd"
    assert sim(src, minutes=1).wait(timeout=120) == 0
    data = src.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) * 2 // 3])
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp)}

    def tables(limit_bytes: int, *args: str) -> subprocess.CompletedProcess:
        """``vdc-analyse tables ARGS`` with its temporaries in ``tmp``, files capped."""
        return subprocess.run(
            [PY, "-m", "analysis", "tables", *args],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            preexec_fn=_limit_file_size(limit_bytes),
        )

    # the repair copy does not fit under the limit: one line naming the folder, nothing left
    res = tables(200_000, str(cut), "--out", str(tmp_path / "t"))
    assert_one_line_error(res, str(tmp), "TMPDIR")
    assert not list(tmp.iterdir()) and not (tmp_path / "t").exists()
    # a table set that does not fit leaves the old set whole and no staging folder
    old = tmp_path / "tables"
    assert run_in_process("analysis", "tables", str(src), "--out", str(old)).returncode == 0
    before = {p.name: p.read_bytes() for p in old.iterdir()}
    res = tables(60_000, str(src), "--model", "avdm", "--model", "avdm-on", "--out", str(old))
    assert res.returncode != 0 and "Traceback" not in res.stderr, res.stderr
    assert {p.name: p.read_bytes() for p in old.iterdir()} == before
    assert not list(tmp.iterdir())
    assert_clean(tmp_path)


# -- duplicate recording ids -------------------------------------------------------------------
def test_duplicate_recording_ids_are_refused(tmp_path: Path) -> None:
    a = tmp_path / "a.rrd"
    assert sim(a, minutes=0.2).wait(timeout=120) == 0
    copy = tmp_path / "copy.rrd"
    shutil.copy(a, copy)
    for cmd, args in (
        ("tables", [str(a), str(a)]),
        ("tables", [str(a), str(copy)]),
        ("complexity", [str(a), str(copy)]),
        ("batch", [str(a), str(copy), "--model", "avdm", "--jobs", "1"]),
    ):
        res = run_in_process("analysis", cmd, *args, "--out", str(tmp_path / cmd))
        assert_one_line_error(res, "give each recording once")
        assert not (tmp_path / cmd / "frames.parquet").exists()
    assert_clean(tmp_path)


def test_a_damaged_batch_part_is_recomputed_not_counted_as_done(tmp_path: Path) -> None:
    a = tmp_path / "a.rrd"
    assert sim(a, minutes=0.2).wait(timeout=120) == 0
    out = tmp_path / "b"
    assert (
        run_in_process(
            "analysis", "batch", str(a), "--model", "avdm", "--jobs", "1", "--out", str(out)
        ).returncode
        == 0
    )
    good = pl.read_parquet(out / "summary.parquet")
    part = next((out / "parts").rglob("model_outputs.parquet"))
    part.write_bytes(part.read_bytes()[:100])  # damaged after it was written
    res = run_in_process("analysis", "summarise", str(out))
    assert_one_line_error(res, "damaged", str(part))
    res = run_in_process(
        "analysis", "batch", str(a), "--model", "avdm", "--jobs", "1", "--out", str(out)
    )
    assert res.returncode == 0, res.stderr
    assert "0 already done, 1 to run" in res.stderr
    assert pl.read_parquet(out / "summary.parquet").equals(good)
    assert_clean(tmp_path)


# -- signals to a parent with a live pool of capture workers ----------------------------------
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_sweep_killed_mid_run_leaves_no_worker_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    env = {**os.environ, "VDC_OVERSUBSCRIBE": "1"}  # two workers even on a one-core runner
    cmd = [PY, "-m", "capture", "campaign", "minutes=10", "seed=1,2", "--jobs", "2"]
    cmd += ["--out", str(out), "--quiet"]
    parent = spawn(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    recs = out / "recordings"
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and len(list(recs.glob("*.partial.rrd"))) < 2:
        time.sleep(0.05)
    # the pool's workers: the fork server's children (not the fork server, nor multiprocessing's
    # resource tracker, which hold no file of the run and end when the parent's pipes close)
    direct = set(_children(parent.pid))
    workers = [p for p in _descendants(parent.pid) if _alive(p) and p not in direct]
    assert len(workers) >= 2, workers
    parent.send_signal(signal.SIGTERM)
    parent.wait(timeout=60)  # a bound on a hang, not a measurement
    # the event waited for is the parent's exit: by then its workers have ended and closed
    # their files (the parent collects them first), so nothing is polled for a while here
    assert parent.returncode == -signal.SIGTERM, parent.returncode
    assert not [w for w in workers if _alive(w)], "workers outlived their parent"
    assert not _processes_mentioning(str(tmp_path)), "workers outlived their parent"
    assert list(recs.glob("*.partial.rrd"))  # the killed runs' partial files...
    assert not _processes_holding(recs), "a process still holds a recording open"  # ...unwritten
    # the re-run records the two killed runs again (replacing their partial files)
    rerun = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert pl.read_parquet(out / "runs.parquet").height == 2
    assert all(n_frames(p) == 19800 for p in recs.glob("*.rrd"))
    assert_clean(tmp_path)


# -- smaller promises --------------------------------------------------------------------------
def test_the_emulator_never_replaces_a_file_at_its_link_path(tmp_path: Path) -> None:
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    res = run_in_process("capture", "emulate-robot", "--link", str(precious), "--minutes", "0.1")
    assert_one_line_error(res, "--link", "not a link")
    assert precious.read_text() == "keep me"
    assert_clean(tmp_path)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_while_the_command_loads_is_one_line(tmp_path: Path) -> None:
    # Interrupt it while it imports: NumPy is loaded, Numba and the SDK are still to come. The
    # test must see that moment, which a busy machine can hide from it (the test's own process
    # descheduled until the capture ran, or finished): a 30-min run cannot finish meanwhile,
    # the capture is frozen the moment NumPy is seen, and a try that saw it too late (the
    # capture had started) is ended and tried again; never a pass on a signal that missed
    for attempt in range(5):
        out = tmp_path / f"try{attempt}" / "early.rrd"
        out.parent.mkdir()
        proc = sim(out, minutes=30)
        seen = wait_until(
            lambda: _has_loaded(proc.pid, "numpy") or proc.poll() is not None,  # noqa: B023
            300,  # ends as soon as it is seen: a loaded machine only makes it later
            0.005,
        )
        assert seen and proc.poll() is None, "the capture neither loaded NumPy nor kept running"
        os.kill(proc.pid, signal.SIGSTOP)
        if not partial_path(out).exists():
            break  # still loading: interrupt it there
        os.kill(proc.pid, signal.SIGCONT)
        end_group(proc)  # too late: the capture had started
        shutil.rmtree(out.parent)
    else:
        pytest.fail("5 tries never saw the capture still loading: the machine starved this test")
    proc.send_signal(signal.SIGINT)
    os.kill(proc.pid, signal.SIGCONT)
    _, err = proc.communicate(timeout=60)
    # 130, or death by SIGINT (-2) when the signal lands before Python hands control to vdc;
    # a shell reports both as 130
    assert proc.returncode in (130, -signal.SIGINT), err
    assert "Traceback" not in err and "Error" not in err, err
    assert not err.strip() or err.strip().splitlines()[-1].endswith("interrupted"), err
    assert not out.exists()
    assert_clean(tmp_path)


def test_a_spawned_command_gets_sigint_at_its_default_whatever_the_test_ignores() -> None:
    """The harness, not vdc: a child inherits an ignored SIGINT and Python then installs no
    KeyboardInterrupt, so the test above once saw Ctrl-C ignored while the command loaded
    (exit 0 after a full run) because something earlier in its process had set SIGINT aside.
    ``spawn`` starts every command with SIGINT as a terminal gives it."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        probe = (
            "import signal; print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
        )
        proc = spawn([PY, "-c", probe], stdout=subprocess.PIPE, text=True)
        out, _ = proc.communicate(timeout=60)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert out.strip() == "True"


def test_a_recording_shorter_than_the_warm_up_is_one_line(tmp_path: Path) -> None:
    short = tmp_path / "short.rrd"
    assert sim(short, minutes=0.01).wait(timeout=120) == 0  # 20 frames
    for cmd in ("tables", "profile"):
        res = run_in_process("analysis", cmd, str(short), "--out", str(tmp_path / cmd))
        assert_one_line_error(res, "warm-up")
        assert not (tmp_path / cmd).exists()
    res = run_in_process("analysis", "complexity", str(short), "--out", str(tmp_path / "c"))
    assert res.returncode == 0, res.stderr  # per-frame metrics need no warm-up
    assert pl.read_parquet(tmp_path / "c" / "complexity.parquet").height == 20
    assert_clean(tmp_path)


def test_a_recording_given_as_the_tables_folder_is_refused_and_kept(tmp_path: Path) -> None:
    rec = tmp_path / "r.rrd"
    assert sim(rec, minutes=0.2).wait(timeout=120) == 0
    before = hashlib.sha256(rec.read_bytes()).hexdigest()
    assert_one_line_error(
        run_in_process("analysis", "tables", str(rec), "--out", str(rec)), "not a folder"
    )
    assert hashlib.sha256(rec.read_bytes()).hexdigest() == before
    assert_clean(tmp_path)

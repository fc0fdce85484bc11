"""Helpers shared by the tests, imported as ``tests.helpers`` (the repo root is on the
pythonpath, so ``tests/avdm`` never shadows the ``avdm`` package)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np
import polars as pl

from analysis.dataset.synthetic import Faults, write_dataset

ROOT = Path(__file__).resolve().parents[1]

# How close vdc's P.910 SI and TI must be to siti-tools': the precision siti-tools prints
# them to, half a unit of the third decimal. Its CSV output rounds each value to 3 decimals
# (``np.round(value, 3)``; its JSON gives the float unrounded, its own tests compare to ground
# truth within rel 0.005, abs 0.01). vdc computes P.910 in float32 (vdc.frame_metrics
# .p910_table), not siti-tools' float64: about 3e-8 relative apart on the tests' clips (1e-6
# absolute), so a value within this agrees with siti-tools' printed one but at a rounding edge.
SITI_TOOLS_PRINTED_ATOL = 5e-4

# Background processes started by the running test; the autouse fixture in tests/conftest.py
# ends them after every test, whether it passed, failed or was interrupted.
_BACKGROUND: list[subprocess.Popen] = []


def _sigint_as_a_terminal_gives_it() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def spawn(cmd: Sequence[str], **kwargs) -> subprocess.Popen:
    """Start a background process for a test, in its own process group so that it and any
    children it starts can be ended together by :func:`end_background_processes`. SIGINT
    starts at its default, as from a terminal: a child inherits an ignored SIGINT, and Python
    then installs no KeyboardInterrupt for it, so Ctrl-C while the command loaded was ignored
    whenever something earlier in the test's process had set SIGINT aside (a suite-order
    failure: exit 0 after a full run)."""
    kwargs.setdefault("preexec_fn", _sigint_as_a_terminal_gives_it)
    proc = subprocess.Popen(list(cmd), process_group=0, **kwargs)
    _BACKGROUND.append(proc)
    return proc


def end_group(proc: subprocess.Popen, grace_s: float = 5.0) -> bool:
    """Terminate (then kill) ``proc`` with its process group (it must lead one: ``spawn``, or
    ``start_new_session``) and close its pipes; True when it was still running."""
    running = proc.poll() is None
    if running:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                proc.wait(timeout=grace_s)
                break
            except subprocess.TimeoutExpired:
                continue
    else:  # the leader is gone; its group may not be
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    for pipe in (proc.stdin, proc.stdout, proc.stderr):
        if pipe is not None:
            pipe.close()
    return running


def end_background_processes(grace_s: float = 5.0) -> list[str]:
    """End every process :func:`spawn` started that still runs, with its process group
    (:func:`end_group`); returns the commands that were still running."""
    left = []
    while _BACKGROUND:
        proc = _BACKGROUND.pop()
        if end_group(proc, grace_s):
            left.append(" ".join(map(str, proc.args)))  # type: ignore[arg-type]
    return left


def run_cli(
    *args: str, cwd: Path | None = None, timeout: float = 300, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    """Run ``python -m <args>`` as a user would, capturing text output; ``env`` replaces the
    environment (e.g. ``tests.figures.figure_env()``)."""
    env = {**(os.environ if env is None else env), "PYTHONUNBUFFERED": "1"}
    return run_text([sys.executable, "-m", *args], cwd=cwd, timeout=timeout, env=env)


def run_text(
    cmd: Sequence[str | Path],
    *,
    cwd: Path | None = None,
    timeout: float = 300,
    env: dict[str, str] | None = None,
) -> subprocess.CompletedProcess:
    """Run ``cmd`` to its end (at most ``timeout`` s) in ``cwd`` (default: this checkout), its
    output captured as text; ``env`` replaces the environment (None: this one's)."""
    return subprocess.run(
        cmd, capture_output=True, text=True, cwd=cwd or ROOT, env=env, timeout=timeout
    )


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    """Exit status 2, exactly one line on stderr, no traceback, mentioning every needle."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def start_emulator(link: Path, report: Path, *extra: str) -> subprocess.Popen:
    """``vdc-capture emulate-robot`` behind the pseudo-terminal link ``link``, its report to
    ``report``; returns once the link is there (fails if the emulator ends first, or after
    30 s)."""
    proc = spawn(
        [
            sys.executable,
            "-m",
            "capture",
            "emulate-robot",
            "--link",
            str(link),
            "--report",
            str(report),
            *extra,
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    deadline = time.time() + 30
    while time.time() < deadline and not link.is_symlink() and proc.poll() is None:
        time.sleep(0.05)
    assert link.is_symlink(), proc.stderr.read() if proc.poll() is not None else "no port"
    return proc


def make_sim_recording(out: Path, minutes: float = 0.05, **settings) -> Path:
    """A short simulated run (``capture.sim.SimSettings`` fields as keywords: ``tf_hz``,
    ``seed``, ``behaviour``, ``model``...) recorded to ``out`` in this process; its path."""
    from capture.sim import SimSettings, record_sim

    return record_sim(SimSettings(minutes=minutes, **settings), out).path


def start_long_capture(out: Path, *, min_bytes: int = 2_000_000) -> subprocess.Popen:
    """Start a 60-minute simulated capture to ``out`` and wait until its partial file (where a
    capture writes until it ends) holds at least ``min_bytes`` (:func:`assert_file_grows`);
    the caller stops it."""
    from vdc.recording import partial_path

    argv = ["-m", "capture", "sim", "--tf-hz", "3", "--minutes", "60", "--out", str(out)]
    proc = spawn(
        [sys.executable, *argv, "--quiet"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    part = partial_path(out)
    assert_file_grows(proc, part, min_bytes)
    return proc


def wait_until(predicate: Callable[[], object], timeout_s: float, poll_s: float = 0.05) -> bool:
    """Poll ``predicate`` every ``poll_s`` seconds until it is true or ``timeout_s`` seconds
    have passed; returns whether it became true (the caller asserts, with its own message)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return bool(predicate())
        time.sleep(poll_s)


def touch_then_sleep(path: str, seconds: float) -> dict:
    """A pool task for tests: create ``path`` (the task is running), then sleep."""
    Path(path).touch()
    time.sleep(seconds)
    return {}


def file_size(path: Path) -> int:
    """Bytes in ``path``; 0 while it does not exist."""
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def assert_file_grows(
    proc: subprocess.Popen, path: Path, min_bytes: int, stall_s: float = 300
) -> None:
    """Wait until the background process ``proc`` has written at least ``min_bytes`` to
    ``path``. No deadline while it makes progress: a loaded machine only makes it slower
    (at load 18, a robot capture wrote 130-150 kB in its first 60 s). Fails, with its stderr,
    when it has ended, or when the file has not grown for ``stall_s`` seconds (a hang; its
    imports come first, so the first bytes may take a while)."""
    last, since = -1, time.monotonic()
    while (size := file_size(path)) < min_bytes and proc.poll() is None:
        if size != last:
            last, since = size, time.monotonic()
        elif time.monotonic() - since > stall_s:
            break
        time.sleep(0.1)
    if file_size(path) >= min_bytes:
        return
    ended = proc.poll() is not None
    why = (
        f"the process ended with status {proc.returncode}"
        if ended
        else f"it has not grown for {stall_s:g} s and the process still runs"
    )
    err = proc.stderr.read() if ended and proc.stderr else ""
    raise AssertionError(f"{path} holds {file_size(path)} bytes, not {min_bytes}: {why}: {err}")


def kill_a_worker_mid_batch(
    args: Sequence[str], out: Path, victim, total: int
) -> tuple[int, str, str, int]:
    """Run ``vdc-analyse batch ARGS --out OUT`` in the background and SIGKILL one worker as
    soon as a task has finished (fewer than ``total``, so the run is still going).
    ``victim(batch_pid)`` names the worker's pid (None: not known yet). Returns the batch's
    exit status, stdout, stderr and the killed pid."""
    proc = spawn(
        [sys.executable, "-m", "analysis", "batch", *args, "--out", str(out)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 120
    killed = None
    while time.time() < deadline and proc.poll() is None:
        finished = list(out.glob("parts/*/model=*/summary.parquet"))
        pid = victim(proc.pid) if finished else None
        if pid is not None:
            assert len(finished) < total, "the run ended before a worker could be killed"
            killed = pid
            os.kill(killed, signal.SIGKILL)
            break
        time.sleep(0.05)
    assert killed is not None, "no worker was seen with a finished part"
    stdout, stderr = proc.communicate(timeout=300)
    return proc.returncode, stdout, stderr, killed


def ffmpeg_siti(path: Path, force_range: str | None = None) -> np.ndarray:
    """FFmpeg's own siti filter over every frame of a video (PyAV's filter graph): its legacy
    (P.910) SI and TI per frame, (N, 2) float64, as FFmpeg prints them (2 decimals); with
    ``force_range`` ("full" or "limited") after ``setparams`` gives the frames that range (as
    ``--color-range`` does)."""
    import itertools

    import av.filter

    values = []
    with av.open(str(path)) as c:
        st = c.streams.video[0]
        graph = av.filter.Graph()
        chain = [graph.add_buffer(template=st)]
        if force_range:
            chain.append(graph.add("setparams", f"range={'pc' if force_range == 'full' else 'tv'}"))
        chain += [graph.add("siti"), graph.add("buffersink")]
        for a, b in itertools.pairwise(chain):
            a.link_to(b)
        graph.configure()
        for frame in c.decode(st):
            graph.push(frame)
            md = graph.pull().metadata
            values.append((float(md["lavfi.siti.si"]), float(md["lavfi.siti.ti"])))
    return np.array(values, dtype=np.float64).reshape(-1, 2)


def write_pan(
    path: Path,
    width: int,
    height: int,
    n_frames: int,
    *,
    step_px: int = 5,
    color_range: str = "limited",
    crf: int = 20,
) -> Path:
    """A real photograph (scikit-image's astronaut, grey) panned ``step_px`` px per frame,
    H.264 (x264 veryfast) at 25 fps; levels kept inside 30..220 so that decoded limited-range
    values stay in 16..235 (siti-tools refuses others). ``color_range`` full is yuvj420p."""
    import cv2
    from skimage import data

    img = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY).astype(np.float64)
    pano = cv2.resize(30 + img * (190 / 255), (width * 3, height), interpolation=cv2.INTER_CUBIC)
    pano = np.clip(np.rint(pano), 0, 255).astype(np.uint8)
    out = av.open(str(path), "w")
    st = out.add_stream("libx264", rate=25)
    st.width, st.height = width, height
    st.pix_fmt = "yuvj420p" if color_range == "full" else "yuv420p"
    st.options = {"preset": "veryfast", "crf": str(crf)}
    for i in range(n_frames):
        x = (i * step_px) % (2 * width)
        view = np.ascontiguousarray(pano[:, x : x + width])
        out.mux(st.encode(av.VideoFrame.from_ndarray(view, format="gray")))
    out.mux(st.encode())  # flush the encoder
    out.close()
    return path


def write_video(
    path: Path,
    frames: np.ndarray,
    fps: float,
    times_s: np.ndarray | None = None,
    container: str | None = None,
) -> Path:
    """Encode grey frames (T, H, W) as H.264 (yuv420p, near-lossless CRF 12); ``times_s``
    gives each frame's presentation time (variable frame rate)."""
    out = av.open(str(path), "w", format=container)
    stream = out.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
    stream.width, stream.height = frames.shape[2], frames.shape[1]
    stream.pix_fmt = "yuv420p"
    stream.options = {"crf": "12", "bf": "0"}
    if times_s is not None:
        stream.time_base = Fraction(1, 1000)
        stream.codec_context.time_base = Fraction(1, 1000)
    for i, f in enumerate(frames):
        frame = av.VideoFrame.from_ndarray(np.stack([f] * 3, axis=-1), format="rgb24")
        if times_s is not None:
            frame.pts = round(times_s[i] * 1000)
            frame.time_base = Fraction(1, 1000)
        out.mux(stream.encode(frame))
    out.mux(stream.encode())  # flush the encoder
    out.close()
    return path


def module_on_path(folder: Path, module: str, source: str) -> Iterator[Path]:
    """``source`` written as ``folder/<module>.py`` and importable (``folder`` first on
    ``sys.path``) until the generator ends: the body of a fixture of test plugins."""
    (folder / f"{module}.py").write_text(source)
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))


def flock_waiters(path: Path) -> int:
    """Processes blocked on a ``flock`` of ``path``, from the kernel's lock table (Linux)."""
    inode = os.stat(path).st_ino
    with open("/proc/locks") as f:
        return sum(1 for line in f if "->" in line and line.split()[6].endswith(f":{inode}"))


def run_behind_a_held_lock(
    lock_path: Path, cmds: Sequence[Sequence[str]], **popen: object
) -> list[tuple[int, str]]:
    """Start ``cmds`` while the test holds ``lock_path`` (a ``flock``), wait until every one
    of them waits for it (the kernel's lock table, not a time), release it, and return each
    one's exit status and standard output. Whatever the machine's load, all of them reach
    the lock before any gets it."""
    from avdm.file_lock import exclusive

    lock_path.parent.mkdir(parents=True, exist_ok=True)
    procs: list[subprocess.Popen] = []
    try:
        with exclusive(lock_path) as locked:
            assert locked, f"the test could not lock {lock_path}"
            for cmd in cmds:
                procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, **popen))
            deadline = time.monotonic() + 300  # imports on a loaded machine; a hang fails here
            while flock_waiters(lock_path) < len(cmds):
                assert all(p.poll() is None for p in procs), "a process ended without waiting"
                assert time.monotonic() < deadline, "the processes never waited for the lock"
                time.sleep(0.05)
    finally:  # the lock is released: collect them, whether or not they waited
        outs = [p.communicate(timeout=300)[0] for p in procs]
    return [(p.returncode, out) for p, out in zip(procs, outs, strict=True)]


def write_h264_dataset(
    root: Path, episodes: int, seconds: tuple[float, float], **kw: Any
) -> dict[str, Any]:
    """A LeRobot dataset in H.264 (the codec the tests decode fastest), with no fault unless
    ``faults`` says otherwise; the rest as :func:`analysis.dataset.synthetic.write_dataset`."""
    kw.setdefault("faults", Faults())
    return write_dataset(root, episodes=episodes, codec="libx264", seconds=seconds, **kw)


def flags(line: str = "", **values: object) -> list[str]:
    """A command line's flags: ``line`` split at white space (the flags whose values are plain
    words, as one would type them), then keyword arguments named as the settings' fields name
    the flags (``fov_deg=60`` → ``--fov-deg 60``; ``True`` → the flag alone, as ``--no-fit``; a
    list repeats its flag, in order) for the values computed by the test, such as paths."""
    out = line.split()
    for name, value in values.items():
        flag = "--" + name.replace("_", "-")
        if value is True:
            out.append(flag)
            continue
        for v in value if isinstance(value, list) else [value]:
            out += [flag, str(v)]
    return out


def no_frames(*measures: str) -> pl.DataFrame:
    """A footage study's per-frame table without a frame (the clips' statistics alone), with
    a Float64 column for each of ``measures``."""
    schema = {"clip": pl.String, "threshold": pl.Float64, "frame": pl.Int64}
    schema |= {"positive": pl.Boolean, "keep": pl.Boolean}
    return pl.DataFrame(schema=schema | dict.fromkeys(measures, pl.Float64))

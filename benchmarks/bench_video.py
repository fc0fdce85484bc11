"""Video complexity at the decoder's pace: ``vdc-analyse complexity`` end to end against real
time and against FFmpeg's ``siti`` filter and siti-tools, all measured in the same run.

Run: ``python benchmarks/bench_video.py`` (a few minutes; ``--seconds`` sets the clips'
length, ``--long`` adds the peak memory of a 10-minute 1080p clip). It writes H.264 clips of
a real photograph (scikit-image's astronaut, grey, levels 30-220 so that siti-tools accepts
every decoded frame) panning 7 px per frame at 25 fps to a temporary folder, then measures,
each from the file (decoding included):

1. ``complexity --metrics si_p910,ti_p910`` on one core (pinned), FFmpeg's ``siti`` filter
   through PyAV's filter graph (decode, filter) and siti-tools' ``SiTiCalculator.calculate()``
   on the same 720p25 file (the first ``--sititools-frames`` frames: it runs at a few frames
   per second), as frames per second, multiples of real time and ratios;
2. ``complexity`` with the default metrics on two cores (the pipeline of ``vdc.pipeline``) at
   720p25 and 1080p25;
3. a collection of 4 clips (720p25, ``--seconds`` each) on 1 pool worker on one core and on 2
   workers on two cores, the whole command each time, with the workers' CPU time beside;
4. ``--long``: the command on a 10-minute 1080p25 clip (a 20-s clip's packets 30 times over)
   in a child process, its peak resident memory.

Every figure is wall-clock time on whatever else the machine runs; the CPU time per frame
(all threads) is printed beside it, which load disturbs much less. Targets from issue #33.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import av
import cv2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# vdc's modules are imported where they are used, not here: the pool's workers (spawned) run
# this file's top again, and would pay for importing the whole command on the wall clock
DEFAULT = "omega_dps,si_p910,ti_p910,mafd,flow_dps,codec_bpp"  # DEFAULT_METRICS (checked)

FPS, FOV = 25, 70.0
SITI = "si_p910,ti_p910"


def write_clip(path: Path, width: int, height: int, seconds: float) -> Path:
    """A grey photograph panning 7 px per frame, ``seconds`` long (H.264, x264 veryfast,
    CRF 23, yuv420p, 25 fps)."""
    from tests.helpers import write_pan

    return write_pan(path, width, height, round(seconds * FPS), step_px=7, crf=23)


def timed(fn: Callable[[], int]) -> tuple[int, float, float]:
    """(frames, wall s, CPU s of the whole process) of ``fn()``, which returns its frames."""
    c0, t0 = time.process_time(), time.perf_counter()
    n = fn()
    return n, time.perf_counter() - t0, time.process_time() - c0


def line(label: str, n: int, wall: float, cpu: float) -> float:
    fps = n / wall
    print(
        f"  {label:<44} {fps:7.1f} frames/s = {fps / FPS:5.1f}x real time "
        f"({cpu / n * 1e3:5.2f} ms CPU per frame)"
    )
    return fps


def ours(path: Path, metrics: str) -> int:
    from analysis.complexity.command import ComplexitySettings
    from analysis.complexity.source_metrics import measure_video

    s = ComplexitySettings(fov_deg=FOV, metrics=metrics)
    return measure_video(str(path), s, "bench").table.height


def ffmpeg_siti_frames(path: Path) -> int:
    """FFmpeg's siti filter end to end: decode and filter every frame (PyAV's filter graph,
    ``tests.helpers.ffmpeg_siti``); the number of frames."""
    from tests.helpers import ffmpeg_siti

    return len(ffmpeg_siti(path))


def sititools(path: Path, frames: int) -> int:
    from siti_tools.siti import ColorRange, SiTiCalculator

    si, _, _ = SiTiCalculator(color_range=ColorRange.LIMITED).calculate(str(path), frames)
    return len(si)


def one_core(hd: Path, n_siti: int) -> None:
    print("720p25 SI/TI (P.910 2022) from the file, one core:")
    ours(hd, SITI)  # warm: compiled kernels loaded
    vdc = line(f"vdc complexity --metrics {SITI}", *timed(lambda: ours(hd, SITI)))
    ff = line("FFmpeg siti filter (PyAV, legacy SI/TI)", *timed(lambda: ffmpeg_siti_frames(hd)))
    st = line(f"siti-tools calculate() ({n_siti} frames)", *timed(lambda: sititools(hd, n_siti)))
    print(
        f"  vdc: {vdc / FPS:.1f}x real time (target >= 8x), {vdc / ff:.1f}x FFmpeg "
        f"(target >= 5x), {vdc / st:.0f}x siti-tools (target >= 20x)"
    )


def two_cores(path: Path, label: str, target: float) -> None:
    default = DEFAULT
    warm = path.with_name(f"warm-{path.name}")
    ours(warm, default)  # the AVDM's calibration for this raster, cached
    n, wall, cpu = timed(lambda: ours(path, default))
    fps = line(f"vdc complexity {label}, default metrics, 2 cores", n, wall, cpu)
    print(f"    {fps / FPS:.1f}x real time (target >= {target:g}x)")


def collection(folder: Path, out: Path, cores: list[int], seconds: float) -> None:
    """The scaling of one clip per worker: 1 worker on one core against 2 workers on two (a
    lone worker on two cores would run its clip's pipeline on both), the whole command each
    time. Beside it, the CPU time of the pool's workers: the measuring itself, which the
    second worker halves on the wall clock; the rest of the wall time (starting the workers,
    the tables, the figure) is paid once whatever the number of workers."""
    from analysis.complexity.command import ComplexitySettings, complexity

    clips = sorted(str(p) for p in folder.glob("*.mp4"))
    runs = {}
    for jobs in (1, 2):
        os.sched_setaffinity(0, set(cores[:jobs]))  # the pool's workers inherit it
        settings = ComplexitySettings(fov_deg=FOV, jobs=jobs, force=True)
        complexity(clips[:2], settings, out / f"warm{jobs}")  # workers' first compile
        t0, c0 = time.perf_counter(), os.times()
        complexity(clips, settings, out / f"jobs{jobs}")
        c1 = os.times()
        workers = c1.children_user + c1.children_system - c0.children_user - c0.children_system
        runs[jobs] = time.perf_counter() - t0, workers
    (wall1, cpu1), (wall2, cpu2) = runs[1], runs[2]
    print(
        f"collection of {len(clips)} clips of {seconds:g} s (720p25, default metrics): 1 worker on "
        f"1 core {wall1:.1f} s, 2 workers on 2 cores {wall2:.1f} s: {wall1 / wall2:.2f}x "
        f"(target >= 1.8x)\n    workers' CPU {cpu1:.1f} s and {cpu2:.1f} s; "
        f"wall time beyond the workers' CPU per worker {wall1 - cpu1:.1f} s and "
        f"{wall2 - cpu2 / 2:.1f} s (starting the pool, the tables, the figure)"
    )


def repeat_clip(short: Path, path: Path, times: int) -> Path:
    """``short``'s packets ``times`` over, timestamps shifted, as one file (remuxed, not
    encoded again: a 10-minute 1080p file in seconds instead of minutes of x264)."""
    with av.open(str(short)) as src:
        ist = src.streams.video[0]
        packets = [p for p in src.demux(ist) if p.size]
        span = max(p.pts for p in packets) - min(p.pts for p in packets) + packets[1].duration
        out = av.open(str(path), "w")
        ost = out.add_stream_from_template(ist)
        for k in range(times):
            for p in packets:
                q = av.Packet(bytes(p))
                q.pts, q.dts, q.time_base = p.pts + k * span, p.dts + k * span, p.time_base
                q.is_keyframe, q.stream = p.is_keyframe, ost
                out.mux(q)
        out.close()
    return path


def peak_memory(folder: Path) -> None:
    """The command on a 10-minute 1080p25 clip (a 20-s clip of :func:`write_clip` 30 times
    over) in a child process: its peak resident set."""
    short = write_clip(folder / "short1080.mp4", 1920, 1080, 20.0)
    clip = repeat_clip(short, folder / "long1080.mp4", 30)
    cmd = [sys.executable, "-m", "analysis", "complexity", str(clip), "--fov-deg", str(FOV)]
    t0 = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([*cmd, "--out", str(folder / "long")], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL)  # fmt: skip
    _, status, usage = os.wait4(proc.pid, 0)  # this child's own peak, not the pool workers'
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"the 10-minute run failed (status {os.waitstatus_to_exitcode(status)})")
    peak_mb = usage.ru_maxrss / 1024
    cpu_ms = (usage.ru_utime + usage.ru_stime) / (600 * FPS) * 1e3
    print(
        f"10-min 1080p25 clip, default metrics, 2 cores: {wall:.0f} s = {600 / wall:.1f}x real "
        f"time ({cpu_ms:.2f} ms CPU per frame); peak memory {peak_mb:.0f} MB (target <= 1024 MB)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="length of the clips (20-60)")
    ap.add_argument("--sititools-frames", type=int, default=50)
    ap.add_argument("--long", action="store_true", help="also the 10-min 1080p memory check")
    args = ap.parse_args()
    from analysis.complexity.source_metrics import DEFAULT_METRICS

    assert DEFAULT == ",".join(DEFAULT_METRICS), "bench_video: DEFAULT is not DEFAULT_METRICS"
    cv2.setNumThreads(1)
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        sys.exit("bench_video needs 2 cores")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        hd = write_clip(d / "720p.mp4", 1280, 720, args.seconds)
        fhd = write_clip(d / "1080p.mp4", 1920, 1080, args.seconds)
        for p, (w, h) in ((hd, (1280, 720)), (fhd, (1920, 1080))):
            write_clip(p.with_name(f"warm-{p.name}"), w, h, 2.0)
        (d / "set").mkdir()
        for i in range(4):
            write_clip(d / "set" / f"clip{i}.mp4", 1280, 720, args.seconds)
        print(f"{args.seconds:g}-s clips at {FPS} fps; cores {cores[:2]}")
        os.sched_setaffinity(0, {cores[0]})
        one_core(hd, args.sititools_frames)
        os.sched_setaffinity(0, set(cores[:2]))
        print(f"default metrics ({DEFAULT}), two cores:")
        two_cores(hd, "720p25", 8)
        two_cores(fhd, "1080p25", 3)
        collection(d / "set", d / "out", cores, args.seconds)
        if args.long:
            peak_memory(d)


if __name__ == "__main__":
    main()

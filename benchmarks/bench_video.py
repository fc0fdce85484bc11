"""Video complexity at native resolution: frames per second, each beside its reference.

Run: ``python benchmarks/bench_video.py`` (it pins itself to one core for the single-core
figures, then uses two for the collection). It writes H.264 clips of a real photograph
(scikit-image's astronaut, scaled up) panning at 25 fps to a temporary folder, then measures:

1. native SI/TI, both variants (``vdc.frame_metrics.frame_sums``), at 1280×720 and 1920×1080,
   beside siti-tools' own per-frame functions (its domain transform, ``si()`` and ``ti()``, for
   each variant) and FFmpeg's ``siti`` filter through PyAV's filter graph, on the same decoded
   frames (decoding excluded from all three);
2. ``vdc-analyse complexity`` end to end on a 720p25 and a 1080p25 clip, in process: decoding,
   the native metrics, the working raster, the AVDM, the flow and the compression, as
   multiples of real time, beside decoding alone;
3. a collection of 8 clips (720p25, 30 s each) on 1 and on 2 workers (the local process pool,
   one thread of computation per worker), the whole command each time: the pool's start,
   every clip, and the tables, figure and page at the end.
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from pathlib import Path

import av
import av.filter
import cv2
import numpy as np
from siti_tools.siti import ColorRange, SiTiCalculator
from skimage import data

from analysis.complexity import ComplexitySettings, complexity
from analysis.source_metrics import measure_video
from vdc.frame_metrics import NativeMeter, frame_sums, luma_plane

FPS, FOV = 25, 70.0


def write_clip(path: Path, width: int, height: int, seconds: float) -> Path:
    """A photograph panning 7 px per frame, H.264 (x264 veryfast, CRF 23, yuv420p)."""
    img = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2BGR)
    pano = cv2.resize(img, (width * 3, height), interpolation=cv2.INTER_CUBIC)
    out = av.open(str(path), "w")
    st = out.add_stream("libx264", rate=FPS)
    st.width, st.height, st.pix_fmt = width, height, "yuv420p"
    st.options = {"preset": "veryfast", "crf": "23"}
    for i in range(int(seconds * FPS)):
        x = (i * 7) % (2 * width)
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(pano[:, x : x + width]), "bgr24")
        for p in st.encode(frame):
            out.mux(p)
    for p in st.encode():
        out.mux(p)
    out.close()
    return path


def per_second(n: int, seconds: float) -> str:
    return f"{n / seconds:8.1f} frames/s"


def siti_figures(path: Path, label: str) -> None:
    """Native SI/TI on decoded frames: vdc's fused pass against the two references."""
    with av.open(str(path)) as c:
        frames = list(c.decode(video=0))
    planes = [luma_plane(f, 8).copy() for f in frames]
    meter = NativeMeter(8, "limited")
    frame_sums(planes[1], planes[0], meter._p910, meter._legacy, True)  # compiled
    t0 = time.perf_counter()
    for prev, cur in itertools.pairwise(planes):
        frame_sums(cur, prev, meter._p910, meter._legacy, True)
    ours = time.perf_counter() - t0
    n = len(planes) - 1
    # siti-tools, per frame, both variants: what its calculate() does, without the decoding
    p910 = SiTiCalculator(color_range=ColorRange.LIMITED)
    legacy = SiTiCalculator(color_range=ColorRange.LIMITED, legacy=True)
    # siti-tools refuses limited-range frames with codes outside 16..235 (x264 keeps a few)
    few = [np.clip(y, 16, 235) for y in planes[:11]]
    t0 = time.perf_counter()
    prev_v = prev_l = None
    for y in few:
        x = p910.normalize_between_0_1(y.astype(np.float64))
        x = SiTiCalculator.apply_display_model(
            x, eotf_function=p910.eotf_function, l_max=p910.l_max, l_min=p910.l_min,
            gamma=p910.gamma,
        )  # fmt: skip
        v = p910.oetf_function(x, **p910.oetf_function_kwargs)
        SiTiCalculator.si(v)
        SiTiCalculator.ti(v, prev_v)
        lv = legacy.normalize_between_0_1(y.astype(np.float64))
        SiTiCalculator.si(lv)
        SiTiCalculator.ti(lv, prev_l)
        prev_v, prev_l = v, lv
    sititools = time.perf_counter() - t0
    # FFmpeg's siti filter (legacy only: it has no 2022 variant), push/pull per frame
    with av.open(str(path)) as c:
        st = c.streams.video[0]
        graph = av.filter.Graph()
        src, siti, sink = graph.add_buffer(template=st), graph.add("siti"), graph.add("buffersink")
        src.link_to(siti)
        siti.link_to(sink)
        graph.configure()
        t0 = time.perf_counter()
        for f in frames:
            graph.push(f)
            graph.pull()
        ffmpeg = time.perf_counter() - t0
    ff_fps = len(frames) / ffmpeg
    print(f"native SI/TI {label}, both variants, decoding excluded:")
    print(f"  vdc fused pass (P.910 2022 + legacy)  {per_second(n, ours)}")
    print(f"  siti-tools per-frame functions (both) {per_second(len(few), sititools)}")
    print(f"  FFmpeg siti filter via PyAV (legacy)  {per_second(len(frames), ffmpeg)}")
    print(f"  vdc / FFmpeg: {n / ours / ff_fps:.1f}x (target >= 5x)")


def end_to_end(path: Path, label: str, seconds: float) -> None:
    settings = ComplexitySettings(fov_deg=FOV)
    measure_video(str(path), settings, "warm-up")  # compiled kernels, calibration cached
    t0 = time.perf_counter()
    with av.open(str(path)) as c:
        n = sum(1 for _ in c.decode(video=0))
    decode = time.perf_counter() - t0
    t0 = time.perf_counter()
    m = measure_video(str(path), settings, label)
    dt = time.perf_counter() - t0
    print(
        f"complexity end to end {label}: {per_second(m.table.height, dt)} = "
        f"{seconds / dt:.1f}x real time (decoding alone: {n / decode:.0f} frames/s = "
        f"{seconds / decode:.1f}x)"
    )


def collection(folder: Path, out: Path) -> None:
    clips = sorted(str(p) for p in folder.glob("*.mp4"))
    runs = {}
    for jobs in (1, 2):
        settings = ComplexitySettings(fov_deg=FOV, jobs=jobs, force=True)
        complexity(clips[:2], settings, out / f"warm{jobs}")  # workers' first compile
        t0 = time.perf_counter()
        complexity(clips, settings, out / f"jobs{jobs}")
        runs[jobs] = time.perf_counter() - t0
    print(
        f"collection of {len(clips)} clips (1280x720, 30 s each): 1 worker {runs[1]:.1f} s, "
        f"2 workers {runs[2]:.1f} s: {runs[1] / runs[2]:.2f}x (target >= 1.8x)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of the HD clips")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    cores = sorted(os.sched_getaffinity(0))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        hd = write_clip(d / "720p.mp4", 1280, 720, args.seconds)
        fhd = write_clip(d / "1080p.mp4", 1920, 1080, args.seconds)
        (d / "set").mkdir()
        for i in range(8):
            write_clip(d / "set" / f"clip{i}.mp4", 1280, 720, 30.0)
        os.sched_setaffinity(0, {cores[0]})  # the single-core figures
        print(f"one core ({cores[0]}), {args.seconds:g}-s clips at {FPS} fps")
        siti_figures(hd, "1280x720")
        siti_figures(fhd, "1920x1080")
        end_to_end(hd, "720p25", args.seconds)
        end_to_end(fhd, "1080p25", args.seconds)
        os.sched_setaffinity(0, set(cores[:2]))
        collection(d / "set", d / "out")


if __name__ == "__main__":
    main()

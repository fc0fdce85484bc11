"""Frames per second of each stage of video profiling on one core, as multiples of real time.

Run: ``taskset -c 0 python benchmarks/bench_video.py``. Writes a 640×360 H.264 clip (a 1/f
natural scene panning at 30 deg/s, 25 fps, 20 s) to a temporary folder, then times: decoding
with PyAV (luma), resizing to the working raster, repeated-frame detection, the AVDM over true
time, every baseline of ``vdc-analyse complexity``, and end to end ``vdc-capture video`` (decode
+ detection + AVDM + .rrd) and ``vdc-analyse complexity`` on its recording. The plain
reference is siti-tools' own ``SiTiCalculator.calculate`` on the same file (what a user of
siti-tools would run), beside vdc's per-frame use of its functions on the working raster.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from analysis.complexity import ComplexityMeter, ComplexitySettings, _SiTi, complexity
from avdm import make_model
from avdm.stimuli import clutter_image
from avdm.true_time import TrueTimeModel, repeat_flags
from capture.video import VideoSettings, record_video

FPS, W, H, FOV = 25.0, 640, 360, 60.0


def write_clip(path: Path, seconds: float) -> int:
    scene = clutter_image((H, 4 * W), seed=3)
    scene = np.clip(127.5 + 110 * scene, 0, 255).astype(np.uint8)
    px_per_frame = 30.0 / FPS * W / FOV  # a 30 deg/s pan
    out = av.open(str(path), "w")
    stream = out.add_stream("libx264", rate=Fraction(int(FPS)))
    stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
    n = int(seconds * FPS)
    for i in range(n):
        x = int(i * px_per_frame) % (3 * W)
        f = scene[:, x : x + W]
        frame = av.VideoFrame.from_ndarray(np.stack([f] * 3, -1), format="rgb24")
        for p in stream.encode(frame):
            out.mux(p)
    for p in stream.encode():
        out.mux(p)
    out.close()
    return n


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=20.0, help="clip length (default 20)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="vdc-bench-video-"))
    clip = tmp / "clip.mp4"
    n = write_clip(clip, args.seconds)
    real = n / FPS

    def line(name: str, secs: float, frames: int = n) -> None:
        print(
            f"{name:<34} {frames / secs:9.0f} frames/s  {real * frames / n / secs:7.1f}x real time"
        )

    print(f"clip: {W}x{H} H.264, {FPS:g} fps, {n} frames ({real:g} s), FOV {FOV:g} deg")
    lumas: list[np.ndarray] = []

    def decode() -> None:
        with av.open(str(clip)) as c:
            lumas.extend(f.to_ndarray(format="gray") for f in c.decode(video=0))

    line("decode (PyAV, luma)", timed(decode))
    settings = VideoSettings(str(clip), FOV)
    h, w = settings.working_size(H, W)
    small: list[np.ndarray] = []
    line(
        f"resize to {w}x{h} (area)",
        timed(
            lambda: small.extend(cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA) for x in lumas)
        ),
    )
    frames = np.stack(small)
    t = np.arange(n) / FPS
    rep: list[np.ndarray] = []
    line("repeated-frame detection", timed(lambda: rep.append(repeat_flags(frames))))
    model = TrueTimeModel(make_model("avdm", fps=FPS, deg_per_px=FOV / w))
    model.run(frames[:50], t[:50], rep[0][:50])  # compile and calibrate outside the timing
    model.reset()
    line("AVDM (true time)", timed(lambda: model.run(frames, t, rep[0])))

    meter = ComplexityMeter(FPS, FOV / w, ComplexitySettings())
    siti, legacy = _SiTi(False), _SiTi(True)
    line("SI/TI P.910 2022 (siti-tools fns)", timed(lambda: [siti(f) for f in frames]))
    line("SI/TI legacy (siti-tools fns)", timed(lambda: [legacy(f) for f in frames]))
    line("MAFD", timed(lambda: [np.abs(np.diff(frames.astype(np.int16), axis=0)).mean()]))
    line(
        "DIS flow (medium)",
        timed(lambda: [meter.dis.calc(frames[i - 1], frames[i], None) for i in range(1, n)]),
    )
    line("Canny edge density", timed(lambda: [cv2.Canny(f, 100, 200) for f in frames]))
    import zlib

    line("zlib ratio", timed(lambda: [zlib.compress(f.tobytes(), 6) for f in frames]))
    line("JPEG q75 bpp", timed(lambda: [cv2.imencode(".jpg", f) for f in frames]))

    from siti_tools.siti import ColorRange, SiTiCalculator

    ref = SiTiCalculator(color_range=ColorRange.LIMITED)
    line("reference: siti-tools calculate()", timed(lambda: ref.calculate(str(clip))))

    rec = tmp / "clip.rrd"
    secs = timed(lambda: record_video(settings, rec, force=True))
    line("end to end: vdc-capture video", secs)
    secs = timed(lambda: complexity([rec], ComplexitySettings(), tmp / "cx"))
    line("end to end: vdc-analyse complexity", secs)


if __name__ == "__main__":
    main()

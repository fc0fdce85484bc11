"""The synthetic datasets' videos: frames encoded into an MP4 at given times (:func:`encode_file`),
watched for the SVT-AV1 deadlock and encoded again when it strikes."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from vdc.errors import UserError

STALL_S = 60.0  # an encoder with no frame done for this long is taken as deadlocked
TIME_BASE = Fraction(1, 90000)  # the video stream's clock: fine enough for any drift or lag


class _Encoder:
    """One MP4 (one video stream) written frame by frame at given times."""

    def __init__(self, path: Path, codec: str, fps: float, shape: tuple[int, int]) -> None:
        # SVT-AV1 prints its configuration on stderr for every file unless told: errors only
        os.environ.setdefault("SVT_LOG", "1")

        path.parent.mkdir(parents=True, exist_ok=True)
        self.container = av.open(str(path), "w")
        opts = {"g": "2", "crf": "30"}
        if codec == "libx264":
            opts |= {"bf": "0", "preset": "veryfast"}
        elif codec == "libx264-bframes":
            opts |= {"bf": "2", "g": "12", "preset": "veryfast"}
        else:
            opts |= {"preset": "12"}  # libsvtav1's fastest: the tests' CPU
        s = self.container.add_stream(codec.removesuffix("-bframes"), rate=round(fps), options=opts)
        s.width, s.height, s.pix_fmt = shape[1], shape[0], "yuv420p"
        s.codec_context.time_base = TIME_BASE
        s.time_base = TIME_BASE
        self.stream = s
        self.last_pts = -1

    def add(self, t_s: float, rgb: np.ndarray) -> None:

        frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
        pts = max(round(t_s / TIME_BASE), self.last_pts + 1)
        frame.pts, frame.time_base = pts, TIME_BASE
        self.last_pts = pts
        for p in self.stream.encode(frame):
            self.container.mux(p)

    def close(self) -> None:
        for p in self.stream.encode(None):
            self.container.mux(p)
        self.container.close()


def encode_file(
    path: Path,
    codec: str,
    fps: float,
    shape: tuple[int, int],
    frames: Sequence[tuple[float, np.ndarray]],
    stall_s: float = STALL_S,
) -> None:
    """Encode ``frames`` ((t_s, (H, W, 3) uint8 RGB) pairs) into the MP4 at ``path``.

    SVT-AV1 (the library in PyAV's wheels) can deadlock inside ``svt_av1_enc_send_picture``:
    every thread waits and no CPU is used, for ever (seen once in the suite, in this function;
    a known SVT-AV1 fault). The file is therefore encoded in a thread watched for progress; one
    that finishes no frame for ``stall_s`` is abandoned (PyAV releases the GIL while it
    encodes) and the file is encoded again into a fresh file that then takes the name, so
    the abandoned writer can never touch it. Three stalls in a row end in UserError."""
    for attempt in range(3):
        fresh = path.with_name(f".{path.stem}.attempt{attempt}{path.suffix}")
        last_progress = [time.monotonic()]
        failed: list[BaseException] = []
        done = threading.Event()

        def work(
            out: Path = fresh,
            progress: list[float] = last_progress,
            errors: list[BaseException] = failed,
            finished: threading.Event = done,
        ) -> None:
            try:
                enc = _Encoder(out, codec, fps, shape)
                for t, img in frames:
                    enc.add(t, img)
                    progress[0] = time.monotonic()
                enc.close()
            except BaseException as exc:  # handed to the waiting thread
                errors.append(exc)
            finally:
                finished.set()

        threading.Thread(target=work, daemon=True, name=f"encode {path.name}").start()
        while not done.wait(0.5):
            if time.monotonic() - last_progress[0] > stall_s:
                break
        if done.is_set():
            if failed:
                fresh.unlink(missing_ok=True)
                raise failed[0]
            fresh.replace(path)
            return
        print(
            f"warning: the {codec} encoder made no progress for {stall_s:g} s on {path.name} "
            "(an SVT-AV1 deadlock); encoding it again",
            file=sys.stderr,
        )
    raise UserError(
        f"the {codec} encoder deadlocked three times on {path}; write it with libx264 instead."
    )

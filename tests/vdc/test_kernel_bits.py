"""The native metrics' kernel gives the same bits for the same frames however it was compiled
(``vdc.siti_kernel``): in a process that compiles it and in one that loads it from Numba's
cache, on a decoder's padded plane and on a contiguous copy (the arrays' path). With
fast-math sums the grouping was the compiler's choice and P.910 TI differed between these (1
end-to-end run in 4 saw the file's TI differ from the arrays')."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
from skimage import data

from tests.helpers import write_video

ROOT = Path(__file__).resolve().parents[2]

# run in a fresh process: the frames' sums as PyAV's planes (views of the decoder's buffers,
# rows padded to the line size) and as contiguous copies, padded first (the order that
# compiled the kernel's row sums apart from their copy inlined in it)
MEASURE = """
import json, sys
import av, numpy as np
from vdc.frame_metrics import NativeMeter, _every_code, legacy_lut, luma_plane, p910_table
from vdc.siti_kernel import chosen_sums
with av.open(sys.argv[1]) as c:
    planes = [luma_plane(f, 8) for f in c.decode(video=0)]
lut, legacy = p910_table(8, "limited"), _every_code(legacy_lut(8, "limited"))
out = {"padded": not planes[0].flags.c_contiguous}
for name, frames in (("plane", planes), ("copy", [p.copy() for p in planes])):
    pairs = zip(frames, frames[1:])
    sums = [chosen_sums(y, x, lut, legacy, True, True, True, True) for x, y in pairs]
    meter = NativeMeter(8, "limited", metrics=("si_p910", "ti_p910", "si_legacy", "ti_legacy"))
    rows = [meter.row(y) for y in frames]
    out[name] = [np.concatenate(sums).tobytes().hex(), np.stack(rows).tobytes().hex()]
print(json.dumps(out))
"""


def measure_in_a_process(clip: Path, cache: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-c", MEASURE, str(clip)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_a_frames_sums_are_the_same_bits_compiled_or_cached_padded_or_not(tmp_path) -> None:
    # a real photograph panned 3 px a frame, 198 px wide: FFmpeg pads its rows (to 256)
    img = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)
    pano = cv2.resize(img, (198 + 3 * 6, 120), interpolation=cv2.INTER_AREA)
    frames = np.stack([pano[:, 3 * i : 3 * i + 198] for i in range(6)])
    clip = write_video(tmp_path / "pan.mp4", frames, 25.0)
    cache = tmp_path / "numba"  # empty: the first process compiles every kernel it calls
    compiled = measure_in_a_process(clip, cache)
    cached = measure_in_a_process(clip, cache)  # loads them from that cache
    assert compiled["padded"]  # the decoder's plane is a strided view, not a copy
    assert compiled["plane"] == compiled["copy"]  # the file's path and the arrays' path
    assert cached == compiled

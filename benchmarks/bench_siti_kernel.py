"""The P.910 SI/TI kernel stage by stage, against decoding in the same run (issue 47).

Run: ``python benchmarks/bench_siti_kernel.py`` (about a minute; ``--sizes 720p,1080p``).
It writes the H.264 clip ``bench_video.py`` measures (scikit-image's astronaut panning 7 px
per frame, ``tests.helpers.write_pan``), decodes it, and on two consecutive decoded luma
planes times, in CPU time on one pinned core, the least of ``--rounds`` interleaved
rounds:

* **decoding alone**: every frame decoded and its luma plane taken, as ``bench_video.py``
  does; per frame, the marginal cost between a clip of 50 frames and one of 200;
* **the kernel** as ``complexity --metrics si_p910,ti_p910`` runs it on an untagged stream
  (``vdc.frame_metrics.chosen_sums``: P.910 SI, TI, the MAFD and the colour-range scan);
* its stages over a whole frame: the table lookup of one frame's codes, TI (the previous
  frame's codes looked up and the difference summed), the MAFD, the Sobel magnitude, and the
  Sobel without its square root (what the square root costs);
* how far the kernel's SI and TI (float32 since issue 62: the table, the Sobel, its square
  root and each row's sums; the frame's sums in float64) fall from siti-tools' own float64
  arithmetic on the same frames (its ``SiTiCalculator.si``/``ti`` on the looked-up values).

A share of 0.80 of the decoder's pace leaves the kernel a quarter of decoding's time; the
stages show where the rest goes. On two cores (``bench_video.py --cores 2``) the kernel runs
beside the decoder: a share of 1.0 needs it at no more than decoding's cost.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import av
import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from siti_tools.siti import SiTiCalculator  # noqa: E402

from tests.helpers import write_pan  # noqa: E402
from vdc import frame_metrics as fm  # noqa: E402
from vdc import siti_kernel as sk  # noqa: E402

SIZES = {"720p": (1280, 720), "1080p": (1920, 1080)}
FRAMES = 50  # the short clip; the long one 4 times as long
OPTS = {"fastmath": True, "error_model": "numpy", "nogil": True}
F32 = np.float32


@numba.njit(**OPTS)
def lookup_frame(y, lut, rows):  # pragma: no cover - compiled
    for i in range(y.shape[0]):
        sk._map_row(y[i], lut, rows[i % 3])


@numba.njit(**OPTS)
def ti_frame(y, prev, lut, rows, sums):  # pragma: no cover - compiled
    for i in range(y.shape[0]):
        sk._map_row(y[i], lut, rows[0])
    for i in range(y.shape[0]):
        sk._diff_row(rows[0], prev[i], lut, y.shape[1], sums, F32(0))


@numba.njit(**OPTS)
def mafd_frame(y, prev):  # pragma: no cover - compiled
    s = 0
    for i in range(y.shape[0]):
        s += sk._abs_diff_row(y[i], prev[i])
    return s


@numba.njit(**OPTS)
def _sobel_no_sqrt(r0, r1, r2, w, sums):  # pragma: no cover - compiled
    """:func:`vdc.frame_metrics._sobel_row32` summing m² in place of m (no square root)."""
    s = F32(0)
    ss = F32(0)
    two = F32(2)
    for j in range(1, w - 1):
        gx = (r0[j + 1] + two * r1[j + 1] + r2[j + 1]) - (r0[j - 1] + two * r1[j - 1] + r2[j - 1])
        gy = (r2[j - 1] + two * r2[j] + r2[j + 1]) - (r0[j - 1] + two * r0[j] + r0[j + 1])
        x = gx * gx + gy * gy
        s += x
        ss += x * x
    sums[0] += s
    sums[1] += ss


@numba.njit(**OPTS)
def sobel_frame(rows, h, sums, root):  # pragma: no cover - compiled
    """The Sobel pass over ``h`` rows (three looked-up rows in turn: the arithmetic and the
    square root without the lookups)."""
    w = rows.shape[1]
    for i in range(2, h):
        a, b, c = rows[(i - 2) % 3], rows[(i - 1) % 3], rows[i % 3]
        if root:
            sk._sobel_row32(a, b, c, w, sums)
        else:
            _sobel_no_sqrt(a, b, c, w, sums)


def planes(path: Path) -> list[np.ndarray]:
    """Every frame's luma plane (copies: two are kept for the kernel)."""
    with av.open(str(path)) as c:
        return [fm.luma_plane(f, 8).copy() for f in c.decode(video=0)]


def decode(path: Path) -> int:
    """Decoding alone, as ``bench_video.py`` times it: every frame decoded and its luma plane
    taken (no copy), FFmpeg's threads as vdc sets them; the number of frames."""
    n = 0
    with av.open(str(path)) as c:
        st = c.streams.video[0]
        st.thread_type = "NONE" if os.environ.get("VDC_WORKER_THREADS") == "1" else "AUTO"
        for frame in c.decode(st):
            n += fm.luma_plane(frame, 8).shape[0] > 0
    return n


def least(cases: dict[str, Callable[[], object]], rounds: int) -> dict[str, float]:
    """The least CPU seconds per call of each case over ``rounds`` interleaved rounds."""
    best = dict.fromkeys(cases, math.inf)
    for fn in cases.values():
        fn()  # compiled and warm
    for _ in range(rounds):
        for name, fn in cases.items():
            t0 = time.process_time()
            fn()
            best[name] = min(best[name], time.process_time() - t0)
    return best


def one_size(label: str, folder: Path, rounds: int) -> None:
    w, h = SIZES[label]
    short = write_pan(folder / f"{label}-short.mp4", w, h, FRAMES, step_px=7, crf=23)
    clip = write_pan(folder / f"{label}.mp4", w, h, 4 * FRAMES, step_px=7, crf=23)
    luma = planes(short)
    prev, y = luma[FRAMES // 2 - 1], luma[FRAMES // 2]
    lut, legacy = fm.p910_table(8, "limited"), fm._every_code(fm.legacy_lut(8, "limited"))
    rows = sk._aligned_rows32(3, w)
    rows[:, :w] = lut[y[:3]]
    sums = np.zeros(2)
    cases = {
        "decoding": lambda: decode(clip),
        "decoding_short": lambda: decode(short),
        "kernel": lambda: sk.chosen_sums(y, prev, lut, legacy, True, True, False, True),
        "lookup": lambda: lookup_frame(y, lut, rows),
        "ti": lambda: ti_frame(y, prev, lut, rows, sums),
        "mafd": lambda: mafd_frame(y, prev),
        "sobel": lambda: sobel_frame(rows, h, sums, True),
        "sobel_no_sqrt": lambda: sobel_frame(rows, h, sums, False),
    }
    t = {k: v * 1e3 for k, v in least(cases, rounds).items()}
    # marginal: what a frame costs beyond the first (a key frame) and opening the file
    dec = (t["decoding"] - t["decoding_short"]) / (3 * FRAMES)
    # the TI stage looks one frame up before it sums: its own part is the difference
    ti_own = t["ti"] - t["lookup"]
    a = sk.chosen_sums(y, prev, lut, legacy, True, True, False)
    n_int, n_all = (h - 2) * (w - 2), float(y.size)
    # siti-tools' own float64 arithmetic on the float64 table's values
    v, v_prev = fm.p910_lut(8, "limited")[y], fm.p910_lut(8, "limited")[prev]
    si_dev = fm._std(a[0], a[1], n_int) / SiTiCalculator.si(v) - 1
    ti_dev = fm._std(a[2], a[3], n_all) / SiTiCalculator.ti(v, v_prev) - 1
    print(
        f"{label}: decoding alone {dec:.2f} ms/frame (CPU); SI/TI kernel {t['kernel']:.2f} ms "
        f"= {t['kernel'] / dec:.2f}x decoding (share 0.80 on one core leaves {dec / 4:.2f} ms)"
    )
    print(
        f"  stages: lookup {t['lookup']:.2f}, TI {ti_own:.2f} (its lookup of the previous "
        f"frame included), MAFD {t['mafd']:.2f}, Sobel {t['sobel']:.2f} (square root "
        f"{t['sobel'] - t['sobel_no_sqrt']:.2f}) ms"
    )
    print(
        f"  against siti-tools' float64 on the same frames: SI {si_dev:+.1e}, TI {ti_dev:+.1e} "
        f"relative ({abs(si_dev) * SiTiCalculator.si(v):.1e}, "
        f"{abs(ti_dev) * SiTiCalculator.ti(v, v_prev):.1e} absolute; siti-tools prints 3 "
        "decimals)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="720p", help="720p, 1080p (comma-separated)")
    ap.add_argument("--rounds", type=int, default=30, help="interleaved rounds; least counts")
    args = ap.parse_args()
    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})  # one core, as bench_video.py measures
    print(f"one core ({core}), least of {args.rounds} rounds; load {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as d:
        for label in args.sizes.split(","):
            one_size(label, Path(d), args.rounds)
    print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()

"""How true is each speed reader on real footage? Real photographs panned at known speeds.

    python benchmarks/bench_avdm_truth.py          # the whole protocol (1,152 cells, ~20 min)
    python benchmarks/bench_avdm_truth.py --quick  # 3 images, no H.264 (216 cells, ~4 min)

(on a quiet machine; 15 min for --quick on one shared by six jobs)

Protocol (analysis/complexity/avdm_truth.py): 8 photographs shipped in scikit-image, a 70° camera
panning
at 1, 2, 5, 10, 20, 40, 80, 160 and 300 deg/s in both directions, at 25 and 30 fps, at the
robot camera's pitch (0.71 deg/px) and a video pitch (0.22 deg/px), raw and through H.264.
The readers: the registered models avdm, avdm-natural and hrc (a Hassenstein-Reichardt
correlator), and OpenCV's DIS, Farnebäck and pyramidal Lucas-Kanade optic flows (mean
|horizontal flow| in deg/s). Prints every cell, then per reader the median absolute relative
error per speed, the share of frames a model flagged valid per speed, the worst direction
asymmetry and Spearman's ρ, then the speed of every reader against DIS on the same frames,
one core. Writes the figure and tables to --out.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from itertools import pairwise
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
# one BLAS thread: the pans' small matrix products only lose to thread start-up and spinning
# (3-4x the CPU time on a busy machine)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2
import numpy as np
import polars as pl
from tqdm import tqdm

from analysis.complexity.avdm_truth import (
    FARNEBACK,
    FOV_DEG,
    IMAGES,
    TRUTH_VARIANTS,
    Cell,
    cell_frames,
    lk_grid,
    plot_truth,
    protocol_cells,
    run_protocol,
    summarise_truth,
)
from avdm.registry import make_model
from vdc.recording import camera_model_context


def speed(pitch: str) -> list[str]:
    """frames/s of each model and of DIS on the same 300 frames (one core)."""
    cv2.setNumThreads(1)
    cell = Cell("camera", 40.0, 1, 30.0, pitch, "none")
    frames = np.concatenate([cell_frames(cell, 100)] * 3)
    h, w = frames.shape[1:]
    ctx = camera_model_context(w, h, 30.0, FOV_DEG)
    lines, rates = [], {}
    for spec in TRUTH_VARIANTS:
        m = make_model(spec, **ctx)
        m.run(frames[:5])  # compile
        m.reset()
        t = time.perf_counter()
        m.run(frames)
        rates[spec] = len(frames) / (time.perf_counter() - t)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    pts = lk_grid(h, w)
    flows = {
        "dis (reference)": lambda a, b: dis.calc(a, b, None),
        "farneback": lambda a, b: cv2.calcOpticalFlowFarneback(a, b, None, **FARNEBACK),
        "lk": lambda a, b: cv2.calcOpticalFlowPyrLK(a, b, pts, None),
    }
    for name, flow in flows.items():
        t = time.perf_counter()
        for a, b in pairwise(frames):
            flow(a, b)
        rates[name] = (len(frames) - 1) / (time.perf_counter() - t)
    for k, v in rates.items():
        lines.append(
            f"  {pitch:5s} {w}x{h}  {k:18s} {v:10.0f} frames/s"
            f"  ({v / rates['dis (reference)']:.1f}x DIS)"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="3 images, no H.264")
    ap.add_argument("--out", default="results/avdm_truth", help="folder for figure and tables")
    args = ap.parse_args()
    if args.quick:
        cells = protocol_cells(images=IMAGES[:3], codecs=("none",))
    else:
        cells = protocol_cells()
    with tqdm(total=len(cells), desc="cells", unit="cell") as bar:
        table = run_protocol(cells, progress=bar.update)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table.write_parquet(out / "cells.parquet")
    wide = table.pivot(
        on="reader",
        index=["image", "fps", "pitch", "codec", "omega_true_dps", "direction"],
        values="omega_dps",
    ).sort("image", "fps", "pitch", "codec", "omega_true_dps", "direction")
    with pl.Config(tbl_rows=-1, tbl_cols=-1, float_precision=2, tbl_width_chars=200):
        print(wide)
        per_speed, per_reader = summarise_truth(table)
        print("\nmedian |reading − truth| / truth per speed (over images, directions, fps,")
        print("pitches and codecs):")
        print(per_speed.pivot(on="reader", index="omega_true_dps", values="median_abs_rel_error"))
        print("\nshare of frames flagged valid (omega_valid) per speed, after the warm-up:")
        flagged = per_speed.filter(pl.col("valid_share").is_not_nan())
        print(flagged.pivot(on="reader", index="omega_true_dps", values="valid_share"))
    with pl.Config(tbl_cols=-1, float_precision=3, tbl_width_chars=200):
        print("\nper reader (asymmetry and ρ over 2-300 deg/s):")
        print(per_reader)
    print("\nspeed on the same frames, one core:")
    for pitch in ("robot", "video"):
        print("\n".join(speed(pitch)))
    print("figure:", plot_truth(table, out / "avdm_truth.png"))


if __name__ == "__main__":
    main()

"""What measuring a profiling run on every Nth frame pair costs in accuracy (boundary's
``--measure-every N``, default 8): the sampled measures' run means on every Nth pair against
every pair, on real profiling runs, and what that does to the ranking of conditions the
predictors judge.

    python benchmarks/bench_measure_every.py RUNS [--seeds 1] [--every 2,4,8,16]

RUNS: a folder of arena profiling runs, ``<condition>/seedN.rrd`` (a boundary or power-study
output's ``recordings/profile``). For each run, DIS flow (``flow_dps``, the dearest measure) and
P.910 TI (``ti_p910``, the primary comparison's) are measured on every straight-driving pair
after the warm-up, exactly as the predictors measure them; then each N keeps the pairs whose
second frame is a multiple of N, as ``--measure-every N`` does. Printed per N and measure: the
median and largest |difference| of a run's mean from every pair's, in % of that mean and in
units of its own sampling sd (sd · √(1/n_N − 1/n_1)); and Spearman's ρ between the conditions'
means at N and at every pair (1.0: the predictors see the same order). Also the CPU seconds per
run of each N, from the measured cost of a pair.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import polars as pl
from scipy.stats import spearmanr

from analysis.boundary.statistics import WARMUP_FRAMES
from analysis.complexity.meter import DIS_PRESETS
from analysis.recordings.loading import load_recording
from vdc.frame_metrics import NativeMeter
from vdc.recording import NATIVE_METRICS

TI = NATIVE_METRICS.index("ti_p910")


def every_pair(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(second frame of each straight pair after the warm-up, flow_dps, ti_p910, CPU s/pair)."""
    loaded = load_recording(path)
    ctx = loaded.camera_context()
    fps, deg_per_px = float(ctx["fps"]), float(ctx["deg_per_px"])
    timing = loaded.frames.select("frame", "turning")
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS["medium"])
    meter = NativeMeter(8, "full")
    frames, flow, ti = [], [], []
    prev = None
    cpu = 0.0
    for chunk in loaded.rec.iter_frames():
        sel = pl.DataFrame({"frame": chunk.frame.astype(np.int64)}).join(
            timing, on="frame", how="left", maintain_order="left"
        )
        used = (chunk.frame >= WARMUP_FRAMES) & ~sel["turning"].fill_null(True).to_numpy()
        imgs = chunk.images
        for i in np.flatnonzero(used):
            before = imgs[i - 1] if i > 0 else prev
            if before is None:
                continue
            t0 = time.process_time()
            meter._prev = before  # as predictor_runs.measure_run: the pair's first frame
            ti.append(meter.row(imgs[i])[TI])
            f = dis.calc(before, imgs[i], None)
            flow.append(float(np.abs(f[..., 0]).mean()) * deg_per_px * fps)
            cpu += time.process_time() - t0
            frames.append(int(chunk.frame[i]))
        prev = imgs[-1]
    return np.array(frames), np.array(flow), np.array(ti), cpu / max(len(frames), 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", type=Path, help="folder of <condition>/seedN.rrd profiling runs")
    ap.add_argument("--seeds", type=int, default=1, help="runs per condition (the first N)")
    ap.add_argument("--every", default="2,4,8,16", help="the N to compare with every pair")
    args = ap.parse_args()
    ns = [int(n) for n in args.every.split(",")]
    paths = [
        p
        for c in sorted(args.runs.iterdir())
        if c.is_dir()
        for p in sorted(c.glob("seed*.rrd"))[: args.seeds]
    ]
    rows = []
    for k, path in enumerate(paths, 1):
        fr, flow, ti, per_pair = every_pair(path)
        row = {
            "condition": path.parent.name,
            "run": str(path),
            "pairs": len(fr),
            "cpu_per_pair_s": per_pair,
        }
        for name, v in (("flow_dps", flow), ("ti_p910", ti)):
            row[f"{name}@1"] = v.mean()
            sd = v.std(ddof=1)
            for n in ns:
                keep = fr % n == 0
                d = v[keep].mean() - v.mean()
                row[f"{name}@{n}"] = v[keep].mean()
                row[f"{name}@{n}_pct"] = 100 * abs(d) / abs(v.mean()) if v.mean() else np.nan
                row[f"{name}@{n}_z"] = abs(d) / (sd * np.sqrt(1 / keep.sum() - 1 / len(v)))
        rows.append(row)
        print(f"\r{k}/{len(paths)} runs measured", end="", flush=True)
    print()
    df = pl.DataFrame(rows)
    by = df.drop("run").group_by("condition").mean()
    pair_ms = df["cpu_per_pair_s"].mean() * 1e3
    print(
        f"{len(df)} runs of {by.height} conditions, {df['pairs'].median():.0f} straight pairs "
        f"a run (median); every pair costs {pair_ms:.2f} ms of CPU"
    )
    print(
        f"{'N':>3} {'measure':>9} | {'|diff| % of mean':>22} | {'|diff| in sampling sd':>22} "
        f"| {'rho of conditions':>17} | CPU s/run"
    )
    for n in ns:
        for name in ("flow_dps", "ti_p910"):
            pct, z = df[f"{name}@{n}_pct"], df[f"{name}@{n}_z"]
            rho = spearmanr(by[f"{name}@{n}"], by[f"{name}@1"]).statistic
            cpu = (df["pairs"] / n * df["cpu_per_pair_s"]).median()
            print(
                f"{n:3d} {name:>9} | median {pct.median():5.2f}, max {pct.max():6.2f} | "
                f"median {z.median():5.2f}, max {z.max():6.2f} | {rho:17.4f} "
                f"| {cpu:6.2f}"
            )
    print(
        f"  1 (every pair)                                                              "
        f"| {(df['pairs'] * df['cpu_per_pair_s']).median():6.2f}"
    )


if __name__ == "__main__":
    main()

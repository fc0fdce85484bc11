"""DIS flow (the predictors' ``flow_dps``) on every 8th against every 16th frame pair of real
profiling runs (grating, TF 0 and 3 Hz, seed 0, 2 min; recorded into ``--out`` if not there):
the difference of the means against the across-frame sd and its own sampling sd.

    python benchmarks/dis_stride.py --out /tmp/dis-stride
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2
import numpy as np
import polars as pl

from analysis.boundary.command import WARMUP_FRAMES
from analysis.complexity.meter import DIS_PRESETS
from analysis.recordings.loading import load_recording
from capture.run import REPLACE_OUTPUT
from capture.sim import SimSettings, record_sim

ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
ap.add_argument("--out", default="/tmp/dis-stride", help="folder of the two recordings")
out = Path(ap.parse_args().out)
out.mkdir(parents=True, exist_ok=True)
for tf in (0.0, 3.0):
    p = out / f"grating-tf{tf:g}.rrd"
    if not p.exists():
        record_sim(
            SimSettings(scene="grating", tf_hz=tf, minutes=2.0, seed=0, model="avdm"),
            p,
            REPLACE_OUTPUT,
        )
    loaded = load_recording(p)
    ctx = loaded.camera_context()
    fps, dpp = float(ctx["fps"]), float(ctx["deg_per_px"])
    timing = loaded.frames.select("frame", "turning")
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS["medium"])
    vals = {}
    prev = None
    for chunk in loaded.rec.iter_frames():
        sel = pl.DataFrame({"frame": chunk.frame.astype(np.int64)}).join(
            timing, on="frame", how="left", maintain_order="left"
        )
        used = (chunk.frame >= WARMUP_FRAMES) & ~sel["turning"].fill_null(True).to_numpy()
        imgs = chunk.images
        for i in np.flatnonzero((chunk.frame % 8 == 0) & used):
            before = imgs[i - 1] if i > 0 else prev
            if before is None:
                continue
            f = dis.calc(before, imgs[i], None)
            vals[int(chunk.frame[i])] = float(np.abs(f[..., 0]).mean()) * dpp * fps
        prev = imgs[-1]
    fr = np.array(sorted(vals))
    v = np.array([vals[k] for k in fr])
    v16 = v[fr % 16 == 0]
    sd = v.std(ddof=1)
    d = v16.mean() - v.mean()
    # the 16th pairs are a half of the 8th: the difference's sampling sd is sd*sqrt(1/n16 - 1/n8)
    se = sd * np.sqrt(1 / len(v16) - 1 / len(v))
    print(
        f"grating tf{tf:g}: every 8th n={len(v)} mean {v.mean():.4f} deg/s; "
        f"every 16th n={len(v16)} mean {v16.mean():.4f}; diff {d:+.4f} = "
        f"{d / sd:+.3f} across-frame sd ({sd:.4f}), "
        f"{d / se:+.2f} of its sampling sd ({se:.4f})"
    )

"""End-to-end simulated capture speed and memory: render + online AVDM + .rrd writing.

Run: ``taskset -c 0 python benchmarks/bench_capture.py`` (one core). Prints frames/s and wall
time of a 30-minute run (target ≤ 15 s), and the resident memory at 30, 60 and 90 minutes of a
90-minute run (target: flat), e.g. ``capture 30 min: 59400 frames in 7.4 s (8027 frames/s)``.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

from avdm.registry import make_model
from capture.config import SimConfig, WallConfig
from capture.recorder import Recorder
from capture.recording_start import model_sections
from capture.run import batch_bytes, log_batch
from capture.sim_robot import SimulatedRobot
from vdc.blueprints import default_blueprint


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * resource.getpagesize() / 1e6


def capture(minutes: float, out: Path, checkpoints_min: tuple[float, ...] = ()) -> dict:
    cfg = SimConfig(
        wall=WallConfig(tf_schedule=((3.0, minutes * 60),)), duration_s=minutes * 60, seed=1
    )
    model = make_model(cfg.model, **cfg.camera.model_context())
    t0 = time.perf_counter()
    rec = Recorder(out, cfg.run_id(), blueprint=default_blueprint(model.name, model.outputs))
    dev = SimulatedRobot(cfg)
    rec.send_properties({**dev.properties(), **model_sections(model, cfg.camera.model_context())})
    rec.log_arena(cfg.arena, cfg.robot.radius_m)
    rss_at: dict[float, float] = {}
    frames = 0
    marks = list(checkpoints_min)
    with dev:
        while (batch := dev.read()) is not None:
            # what run_capture does per batch: the disk check, the batch, the flush
            rec.reserve(batch_bytes(batch))
            log_batch(rec, model, batch)
            rec.end_batch()
            frames += len(batch)
            if marks and frames >= marks[0] * 60 * cfg.camera.fps:
                rss_at[marks.pop(0)] = rss_mb()
    rec.close(frames=frames, stop_reason="finished", complete=True)
    wall = time.perf_counter() - t0
    return {"frames": frames, "wall_s": wall, "rss_at": rss_at, "size_mb": out.stat().st_size / 1e6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--skip-90", action="store_true", help="only the 30-minute run")
    args = ap.parse_args()
    # compile the kernels outside the timing
    with tempfile.TemporaryDirectory() as tmp:
        capture(0.2, Path(tmp) / "warm.rrd")
    with tempfile.TemporaryDirectory() as tmp:
        r = capture(30, Path(tmp) / "run30.rrd")
        print(
            f"capture 30 min: {r['frames']} frames in {r['wall_s']:.1f} s "
            f"({r['frames'] / r['wall_s']:.0f} frames/s), file {r['size_mb']:.0f} MB"
        )
    if args.skip_90:
        return
    with tempfile.TemporaryDirectory() as tmp:
        r = capture(90, Path(tmp) / "run90.rrd", checkpoints_min=(30, 60, 90))
        at = r["rss_at"]
        print(
            f"capture 90 min: {r['frames']} frames in {r['wall_s']:.1f} s, file "
            f"{r['size_mb']:.0f} MB; resident memory at 30/60/90 min: "
            f"{at[30]:.0f} / {at[60]:.0f} / {at[90]:.0f} MB; peak "
            f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB"
        )


if __name__ == "__main__":
    main()

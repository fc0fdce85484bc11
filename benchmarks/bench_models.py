"""Frames per second of the vision models on one core, beside the plain NumPy reference.

Run: ``taskset -c 0 python benchmarks/bench_models.py`` (pin to one core; numba runs
single-threaded here anyway). Prints one line per figure, e.g.
``avdm run 99x72: 343000 frames/s``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from avdm import make_model
from avdm.lgmd_reference import LgmdColiasReference, LgmdPlusReference
from avdm.reference import AvdmReference


def frames_for(h: int, w: int, n: int, seed: int = 0) -> np.ndarray:
    """A drifting, noisy uint8 scene: representative work for every detector."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, size=(h, w + n), dtype=np.uint8)
    return np.stack([base[:, i : i + w] for i in range(n)])


def rate(fn, n_frames: int, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n_frames / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=30_000, help="frames per timed run")
    args = ap.parse_args()
    for h, w in ((72, 99), (100, 100)):
        frames = frames_for(h, w, args.frames)
        model = make_model("avdm")
        model.run(frames[:20])  # compile outside the timing

        def run_all(model=model, frames=frames) -> None:
            model.reset()
            model.run(frames)

        print(f"avdm run {w}x{h}: {rate(run_all, len(frames)):.0f} frames/s")
        n_step = min(len(frames), 10_000)

        def step_all(model=model, frames=frames[:n_step]) -> None:
            model.reset()
            for f in frames:
                model.step(f)

        print(f"avdm step {w}x{h}: {rate(step_all, n_step):.0f} frames/s")
        ref = AvdmReference(model.params)
        n_ref = 1_000

        def ref_all(ref=ref, frames=frames[:n_ref]) -> None:
            ref.reset()
            for f in frames:
                ref.step(f)

        print(
            f"avdm reference (plain NumPy) step {w}x{h}: "
            f"{rate(ref_all, n_ref, repeats=1):.0f} frames/s"
        )
    bench_lgmd(min(args.frames, 10_000))


def bench_lgmd(n_frames: int) -> None:
    frames = frames_for(72, 99, n_frames, seed=1)
    for spec, ref_cls in (("lgmd-plus", LgmdPlusReference), ("lgmd-colias", LgmdColiasReference)):
        model = make_model(spec)
        model.run(frames[:5])

        def step_all(model=model, frames=frames) -> None:
            model.reset()
            for f in frames:
                model.step(f)

        def run_all(model=model, frames=frames) -> None:
            model.reset()
            model.run(frames)

        print(f"{spec} run 99x72: {rate(run_all, len(frames)):.0f} frames/s")
        print(f"{spec} step 99x72: {rate(step_all, len(frames)):.0f} frames/s")
        ref = ref_cls(model.params)

        def ref_all(ref=ref, frames=frames[:300]) -> None:
            ref.reset()
            for f in frames:
                ref.step(f)

        print(f"{spec} reference (plain NumPy) step 99x72: {rate(ref_all, 300, 1):.0f} frames/s")


if __name__ == "__main__":
    main()

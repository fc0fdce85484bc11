"""Analysis speed and memory on long simulated recordings.

Run: ``taskset -c 0 python benchmarks/bench_analysis.py`` (one core). Makes a 30-minute and a
90-minute recording in a temporary folder, then prints: seconds to read every frame of the
30-minute one (target ≤ 2 s), frames/s of recomputing the AVDM over it, and the peak memory of
``vdc-analyse tables`` and ``vdc-analyse profile`` on the 90-minute one (target < 1 GB).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from analysis.recordings.loading import load_recording
from analysis.recordings.reader import Recording
from analysis.recordings.recompute import recompute


def capture(minutes: int, out: Path) -> Path:
    subprocess.run(
        [
            sys.executable,
            "-m",
            "capture",
            "sim",
            "--tf-hz",
            "3",
            "--minutes",
            str(minutes),
            "--seed",
            "1",
            "--out",
            str(out),
            "--quiet",
        ],
        check=True,
        capture_output=True,
    )
    return out


# runs the CLI in a fresh process and reports that process's own peak resident memory
_MEASURE = (
    "import resource, sys\n"
    "from analysis.cli import main\n"
    "rc = main(sys.argv[1:])\n"
    "print('PEAK_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
    "raise SystemExit(rc)\n"
)


def peak_child_mb(args: list[str]) -> tuple[float, float]:
    """(wall seconds, peak resident MB) of one ``vdc-analyse`` run in its own process."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _MEASURE, *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(proc.stderr)
    wall = time.perf_counter() - t0
    kb = next(int(ln.split()[1]) for ln in proc.stderr.splitlines() if ln.startswith("PEAK_KB"))
    return wall, kb / 1e3


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        rec30 = capture(30, d / "r30.rrd")
        t0 = time.perf_counter()
        n = sum(len(c.frame) for c in Recording(rec30).iter_frames())
        read_s = time.perf_counter() - t0
        print(f"read frames 30 min: {n} frames in {read_s:.2f} s")
        loaded = load_recording(rec30)
        recompute(loaded, ["avdm"])  # compile
        t0 = time.perf_counter()
        recompute(loaded, ["avdm"])
        dt = time.perf_counter() - t0
        print(f"recompute avdm over 30 min (read + model): {n / dt:.0f} frames/s ({dt:.2f} s)")
        rec90 = capture(90, d / "r90.rrd")
        wall, peak = peak_child_mb(["tables", str(rec90), "--out", str(d / "t")])
        print(f"tables 90 min: {wall:.1f} s, peak memory {peak:.0f} MB")
        wall, peak2 = peak_child_mb(
            ["tables", str(rec90), "--model", "avdm", "--model", "avdm-on", "--out", str(d / "t2")]
        )
        print(f"tables 90 min recomputing 2 models: {wall:.1f} s, peak memory {peak2:.0f} MB")
        wall, peak3 = peak_child_mb(["profile", str(rec90), "--out", str(d / "p")])
        print(f"profile 90 min: {wall:.1f} s, peak memory {peak3:.0f} MB")


if __name__ == "__main__":
    main()

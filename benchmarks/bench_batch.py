"""Batch analysis throughput: the local pool and Dask, 1 and 2 workers, against a plain loop.

Run: ``python benchmarks/bench_batch.py`` (needs the dask extra; use a machine with at least
2 free cores). Records 8 simulated recordings (3 minutes each, TF 0/1/3 Hz, several seeds) in
a temporary folder, then runs the same 8 x 4 = 32 (recording, variant) tasks of
``vdc-analyse batch`` five ways and prints wall time, tasks/s and the speed-up over one
worker:

* the plain reference: ``analysis.batch.analyse_task`` called in a loop in this process;
* the local process pool (``--executor local``) with 1 and 2 workers;
* a local Dask cluster (``--executor dask``, 127.0.0.1, processes of one thread) with 1 and 2.

Executor times include starting and stopping the workers, as a user sees them. Then the
scheduling overhead per task: 2,000 (pool) and 500 (Dask) no-op tasks on 2 workers, start-up
subtracted.

``--footage``: instead, a collection of 4 clips (720p25 H.264, ``--seconds`` each, a panned
photograph) through ``vdc-analyse complexity`` with the default metrics, 1 worker on one core
against 2 workers on two, on the local pool and on a local Dask cluster: the library call in
this process (its fork server already warm from a first collection), and the command line in
a fresh process each time (which starts its own fork server), as a user sees both.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

from analysis.batch import BatchSettings, analyse_task, plan_tasks
from capture.sim import SimSettings, record_sim
from vdc.executors import ExecutorSettings, open_executor, run_tasks

VARIANTS = ("avdm", "avdm:beta=0.5", "avdm:tw=6", "lgmd-plus")


def make_recordings(folder: Path, minutes: float) -> list[str]:
    paths = []
    for i in range(8):
        out = folder / f"rec{i}.rrd"
        record_sim(SimSettings(tf_hz=(0.0, 1.0, 3.0)[i % 3], minutes=minutes, seed=i + 1), out)
        paths.append(str(out))
    return paths


def task_list(recs: list[str], out: Path) -> list[tuple[str, tuple]]:
    summary = dataclasses.asdict(BatchSettings(models=VARIANTS).summary_settings())
    tasks, bad = plan_tasks(recs, VARIANTS)
    assert not bad, bad
    return [(f"{p} {spec}", (p, spec, str(out), summary, True)) for p, spec, _ in tasks]


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def run_on(settings: ExecutorSettings, tasks) -> float:
    def go() -> None:
        outcomes = run_tasks(analyse_task, tasks, settings)
        failed = [o for o in outcomes if o.error]
        assert not failed, failed[0]

    return timed(go)


def startup_s(settings: ExecutorSettings) -> float:
    """Start the workers, run one no-op on each, stop them."""

    def go() -> None:
        with open_executor(settings, settings.jobs) as (ex, _client):
            for f in [ex.submit(abs, 0) for _ in range(settings.jobs)]:
                f.result()

    return timed(go)


def overhead_ms(settings: ExecutorSettings, n: int) -> float:
    """Milliseconds of scheduling per task: n no-op tasks, start-up subtracted."""
    tasks = [(str(i), (0,)) for i in range(n)]
    wall = timed(lambda: run_tasks(abs, tasks, settings))
    return (wall - startup_s(settings)) / n * 1e3


def footage(seconds: float) -> None:
    """A collection of 4 clips on 1 and 2 workers (see the module)."""
    import os
    import subprocess
    import sys

    from analysis.complexity.command import ComplexitySettings, complexity
    from tests.helpers import write_pan

    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        sys.exit("bench_batch --footage needs 2 cores")
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root)}
    with tempfile.TemporaryDirectory(prefix="vdc-bench-footage-") as tmp:
        folder = Path(tmp)
        clips = [
            str(write_pan(folder / f"clip{i}.mp4", 1280, 720, round(seconds * 25), step_px=7))
            for i in range(4)
        ]
        print(
            f"4 clips of {seconds:g} s (720p25 H.264), default metrics; load "
            f"{os.getloadavg()[0]:.1f}",
            flush=True,
        )
        rows = []
        for executor in ("local", "dask"):
            walls = {}
            for jobs in (1, 2):
                os.sched_setaffinity(0, set(cores[:jobs]))  # the workers inherit it
                s = ComplexitySettings(fov_deg=70.0, executor=executor, jobs=jobs, force=True)
                complexity(clips[:2], s, folder / "warm")  # fork server, calibration cached
                lib = timed(lambda s=s: complexity(clips, s, folder / "lib"))
                cmd = [
                    sys.executable,
                    "-m",
                    "analysis",
                    "complexity",
                    *clips,
                    "--fov-deg",
                    "70",
                    "--executor",
                    executor,
                    "--jobs",
                    str(jobs),
                    "--force",
                    "--out",
                    str(folder / "cli"),
                ]
                cli = timed(
                    lambda cmd=cmd: subprocess.run(cmd, env=env, check=True, capture_output=True)
                )
                walls[jobs] = lib, cli
                rows.append((executor, jobs, lib, cli))
            os.sched_setaffinity(0, set(cores))
            (l1, c1), (l2, c2) = walls[1], walls[2]
            rows.append((executor, "2 vs 1", l1 / l2, c1 / c2))
        print(f"{'executor':<10}{'workers':>8}{'library s':>11}{'command s':>11}")
        for executor, jobs, lib, cli in rows:
            if jobs == "2 vs 1":
                print(f"{executor:<10}{jobs:>8}{lib:>10.2f}x{cli:>10.2f}x  (target >= 1.9x)")
            else:
                print(f"{executor:<10}{jobs:>8}{lib:>11.1f}{cli:>11.1f}")
        print(f"load at the end {os.getloadavg()[0]:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=3.0, help="length of each recording")
    ap.add_argument("--footage", action="store_true", help="a collection of 4 clips instead")
    ap.add_argument("--seconds", type=float, default=20.0, help="--footage: each clip's length")
    args = ap.parse_args()
    if args.footage:
        footage(args.seconds)
        return
    with tempfile.TemporaryDirectory(prefix="vdc-bench-batch-") as tmp:
        folder = Path(tmp)
        print(f"recording 8 x {args.minutes:g}-minute runs ...", flush=True)
        recs = make_recordings(folder, args.minutes)
        tasks = task_list(recs, folder / "out")
        n = len(tasks)
        # warm the Numba on-disk cache and the page cache, so every row starts alike
        analyse_task(*tasks[0][1])
        plain = timed(lambda: [analyse_task(*a) for _, a in tasks])
        rows = [("plain loop in this process", 1, plain)]
        for executor in ("local", "dask"):
            for jobs in (1, 2):
                wall = run_on(ExecutorSettings(executor, jobs), tasks)
                rows.append((f"{executor} executor", jobs, wall))
        print(f"\n{n} tasks (8 recordings x {len(VARIANTS)} variants: {', '.join(VARIANTS)})")
        print(f"{'how':<28}{'workers':>8}{'wall s':>9}{'tasks/s':>9}{'vs 1 worker':>13}")
        one = {}
        for how, jobs, wall in rows:
            one.setdefault(how, wall)
            print(f"{how:<28}{jobs:>8}{wall:>9.1f}{n / wall:>9.2f}{one[how] / wall:>12.2f}x")
        print("\nscheduling overhead per task (no-op tasks, 2 workers, start-up subtracted):")
        for executor, count in (("local", 2000), ("dask", 500)):
            s = ExecutorSettings(executor, 2)
            up = startup_s(s)
            print(
                f"  {executor:<6} start-up {up:5.2f} s, "
                f"{overhead_ms(s, count):6.2f} ms/task over {count} tasks"
            )


if __name__ == "__main__":
    main()

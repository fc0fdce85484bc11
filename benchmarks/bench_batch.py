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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=3.0, help="length of each recording")
    args = ap.parse_args()
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

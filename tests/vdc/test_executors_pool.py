"""The local pool's and a local Dask cluster's workers: forked warm (vdc's modules imported
and the metric kernels loaded before the first task), one BLAS and one OpenCV thread each
even when the script loaded NumPy first with the default threads; and a plain script that
starts workers from its top level without the ``__main__`` guard ends in one line.

Each case runs as a real script in a child process with the BLAS variables removed from its
environment (the suite sets OPENBLAS_NUM_THREADS=1 for itself, which would hide a missing
limit)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest
import threadpoolctl

import vdc.frame_metrics as fm
from tests.helpers import ROOT

BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "VDC_WORKER_THREADS")


def worker_state(_k: int) -> dict:
    """What a worker sees before it has done any work of its own (this module's imports: a
    warm worker had the kernels loaded before it imported them)."""
    return {
        "blas": [i["num_threads"] for i in threadpoolctl.threadpool_info()],
        "opencv": cv2.getNumThreads(),
        "warm": "vdc.warm" in sys.modules,
        # a kernel whose compiled code is loaded has signatures before its first call here
        "kernels": len(fm.chosen_sums.signatures),
        "ppid": os.getppid(),
    }


SCRIPT = """
import json, sys
import numpy as np  # loaded with the default BLAS threads, before any pool exists
import threadpoolctl
from tests.vdc.test_executors_pool import worker_state
from vdc.executors import ExecutorSettings, run_tasks

if __name__ == "__main__":
    here = [i["num_threads"] for i in threadpoolctl.threadpool_info()]
    out = run_tasks(worker_state, [(str(k), (k,)) for k in range(2)],
                    ExecutorSettings(sys.argv[1], 2))
    print(json.dumps({"here": here, "workers": [o.result for o in out],
                      "errors": [o.error for o in out if o.error]}))
"""


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in BLAS_VARS}
    env["PYTHONPATH"] = str(ROOT)
    env["VDC_OVERSUBSCRIBE"] = "1"  # two workers even on a one-core runner
    return env


def _run(tmp_path: Path, script: str, *args: str) -> subprocess.CompletedProcess:
    path = tmp_path / "script.py"
    path.write_text(script)
    return subprocess.run(
        [sys.executable, str(path), *args], cwd=tmp_path, env=_env(), capture_output=True,
        text=True, timeout=300,
    )  # fmt: skip


@pytest.mark.parametrize("executor", ["local", pytest.param("dask", marks=pytest.mark.dask)])
def test_workers_start_warm_with_one_blas_and_one_opencv_thread(tmp_path, executor) -> None:
    proc = _run(tmp_path, SCRIPT, executor)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not got["errors"]
    # the script's own NumPy keeps OpenBLAS's default (one thread per core): the limit is
    # the workers' alone
    assert max(got["here"]) > 1 or len(os.sched_getaffinity(0)) == 1
    assert len(got["workers"]) == 2
    for w in got["workers"]:
        assert w["blas"] and all(n == 1 for n in w["blas"]), w
        assert w["opencv"] == 1, w
        assert w["warm"] and w["kernels"] >= 1, w
    # both forked by one server, not spawned by the script
    assert len({w["ppid"] for w in got["workers"]}) == 1


def test_the_fork_server_holds_one_thread_when_it_forks(tmp_path) -> None:
    """Forking copies one thread: what the server imported must have started none (a lock
    held by a thread that the child lacks would hang the child)."""
    script = """
import multiprocessing.forkserver as fs
from vdc.executors import pool_context
from vdc.warm import threads_now

if __name__ == "__main__":
    child = pool_context().Process(target=threads_now)
    child.start()  # forked: the server has preloaded by now
    child.join()
    pid = fs._forkserver._forkserver_pid
    print(open(f"/proc/{pid}/status").read().split("Threads:")[1].split()[0])
"""
    proc = _run(tmp_path, script)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-1] == "1"


UNGUARDED = """
from vdc.executors import ExecutorSettings, run_tasks

def negate(x):
    return -x

out = run_tasks(abs, [("a", (-1,)), ("b", (-2,))], ExecutorSettings("{executor}", 2))
print("results", [o.result for o in out])
"""


@pytest.mark.parametrize("executor", ["local", pytest.param("dask", marks=pytest.mark.dask)])
def test_a_plain_script_without_the_main_guard_is_one_line(tmp_path, executor) -> None:
    proc = _run(tmp_path, UNGUARDED.format(executor=executor))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "script.py, line 7" in lines[0] and 'if __name__ == "__main__":' in lines[0]
    assert "results" not in proc.stdout and "failed" not in proc.stderr


def test_the_same_script_with_the_guard_runs(tmp_path) -> None:
    body = UNGUARDED.format(executor="local").split("\nout = ")[1]
    guarded = UNGUARDED.format(executor="local").split("\nout = ")[0]
    guarded += '\nif __name__ == "__main__":\n    out = ' + body.replace("\nprint", "\n    print")
    proc = _run(tmp_path, guarded)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "results [1, 2]"
    assert proc.stderr == ""


def test_a_worker_has_the_environment_of_the_call_not_of_the_fork_server(tmp_path) -> None:
    """The fork server starts with the first pool; a variable set after it (a cache folder, a
    test's setting) still reaches the next pool's workers, as it did with fresh processes."""
    script = """
import os
from vdc.executors import ExecutorSettings, run_tasks

if __name__ == "__main__":
    tasks = [("a", ("VDC_PACE_PROBE",))]
    first = run_tasks(os.getenv, tasks, ExecutorSettings("local", 1))[0].result
    os.environ["VDC_PACE_PROBE"] = "set later"
    second = run_tasks(os.getenv, tasks, ExecutorSettings("local", 1))[0].result
    print(repr(first), repr(second))
"""
    proc = _run(tmp_path, script)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "None 'set later'"


def test_a_commands_stages_share_one_pool_and_a_broken_one_is_replaced(tmp_path) -> None:
    """Inside ``one_pool`` a stage's workers serve the next stage (their imports paid once);
    a worker that dies breaks that pool, its task is retried on a fresh one, and the stage
    after it still runs; outside, every call has its own workers; a changed environment
    gets workers that have it. Each stage's two tasks wait for each other, so both workers
    of the pool take one (which worker takes a task is otherwise up to the machine)."""
    script = """
import json, os, time
from pathlib import Path
from vdc.executors import ExecutorSettings, one_pool, run_tasks

def meet(folder):
    os.makedirs(folder, exist_ok=True)
    Path(folder, str(os.getpid())).touch()
    deadline = time.monotonic() + 120
    while len(os.listdir(folder)) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    return {"pid": os.getpid(), "probe": os.getenv("VDC_PACE_PROBE")}

def die_once(folder):
    if not os.path.exists("died"):
        open("died", "w").close()
        os._exit(1)
    return meet(folder)

def stage(fn, name):
    out = run_tasks(fn, [(str(k), (name,)) for k in range(2)], ExecutorSettings("local", 2))
    assert not [o.error for o in out if o.error], out
    return sorted({o.result["pid"] for o in out}), sorted({o.result["probe"] for o in out})

if __name__ == "__main__":
    got = {}
    with one_pool():
        got["first"] = stage(meet, "first")[0]
        got["second"] = stage(meet, "second")[0]
        got["broken"] = stage(die_once, "broken")[0]
        got["after"] = stage(meet, "after")[0]
        os.environ["VDC_PACE_PROBE"] = "set later"
        got["env"] = stage(meet, "env")
    got["outside"] = [stage(meet, "outside1")[0], stage(meet, "outside2")[0]]
    print(json.dumps(got))
"""
    proc = _run(tmp_path, script)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(got["first"]) == 2 and got["second"] == got["first"]  # the same two workers
    assert not set(got["broken"]) & set(got["first"])  # a pool a worker died in is not kept
    # the fresh pool is kept in turn (its retry may have used one of its two workers)
    assert len(got["after"]) == 2 and set(got["broken"]) <= set(got["after"])
    env_pids, probes = got["env"]
    assert probes == ["set later"] and not set(env_pids) & set(got["after"])
    a, b = got["outside"]
    assert len(a) == 2 and not set(a) & set(b)


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two cores to narrow to one")
@pytest.mark.parametrize("executor", ["local", pytest.param("dask", marks=pytest.mark.dask)])
def test_workers_run_on_the_cores_of_the_call_not_of_the_fork_server(tmp_path, executor) -> None:
    """The fork server starts with the first pool and keeps that process's cores: a caller
    that widens them since (a benchmark on 1 then 2 cores, ``taskset``) still gets workers
    on all of them (measured: two workers on the old single core ran no faster than one)."""
    script = """
import json, os, sys
from vdc.executors import ExecutorSettings, run_tasks

def cores(_k):
    return sorted(os.sched_getaffinity(0))

if __name__ == "__main__":
    every = set(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {min(every)})
    narrow = run_tasks(cores, [("a", (0,))], ExecutorSettings(sys.argv[1], 1))
    os.sched_setaffinity(0, every)
    wide = run_tasks(cores, [("a", (0,)), ("b", (1,))], ExecutorSettings(sys.argv[1], 2))
    print(json.dumps({"every": sorted(every), "narrow": [o.result for o in narrow],
                      "wide": [o.result for o in wide]}))
"""
    proc = _run(tmp_path, script, executor)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["narrow"] == [[got["every"][0]]]
    assert got["wide"] == [got["every"], got["every"]]

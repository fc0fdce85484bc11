"""The local pool's and a local Dask cluster's workers: forked warm (vdc's modules imported
and the metric kernels loaded before the first task), one BLAS and one OpenCV thread each
even when the script loaded NumPy first with the default threads; and a plain script that
starts workers from its top level without the ``__main__`` guard gets one error, before any
worker starts.

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
        # the fork server's preload ran: the worker inherited what it imported
        "warm": "vdc.warm_fork_server" in sys.modules and "av" in sys.modules,
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
        [sys.executable, str(path), *args],
        cwd=tmp_path,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )


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
import os
from pathlib import Path
from vdc.executors import pool_context

def server_threads(path):  # the child's parent is the fork server
    status = Path(f"/proc/{os.getppid()}/status").read_text()
    Path(path).write_text(status.split("Threads:")[1].split()[0])

if __name__ == "__main__":
    child = pool_context().Process(target=server_threads, args=("threads.txt",))
    child.start()  # forked: the server has preloaded by now
    child.join()
    print(Path("threads.txt").read_text())
"""
    proc = _run(tmp_path, script)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-1] == "1"


def test_importing_warm_changes_nothing_and_walks_no_stack() -> None:
    """``vdc.warm`` warms a fork server only when asked (its preload module calls it): its
    import sets no environment variable and loads nothing heavy, and it does not look at the
    call stack to tell where it runs."""
    code = (
        "import os, sys; before = dict(os.environ); import vdc.warm; "
        "assert dict(os.environ) == before, set(os.environ) ^ set(before); "
        "heavy = [m for m in ('numpy', 'cv2', 'av', 'numba') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    env = {k: v for k, v in _env().items() if k not in BLAS_VARS}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    source = (ROOT / "vdc" / "warm.py").read_text()
    assert "_getframe" not in source and "f_back" not in source
    from vdc.pool_workers import WARM_PRELOAD

    assert WARM_PRELOAD == ["vdc.warm_fork_server"]  # a module whose import is the warm-up


UNGUARDED = """
from vdc.executors import ExecutorSettings, run_tasks

def negate(x):
    return -x

out = run_tasks(abs, [("a", (-1,)), ("b", (-2,))], ExecutorSettings("{executor}", 2))
print("results", [o.result for o in out])
"""


@pytest.mark.parametrize("executor", ["local", pytest.param("dask", marks=pytest.mark.dask)])
def test_a_plain_script_without_the_main_guard_gets_one_error_before_any_worker(
    tmp_path, executor
) -> None:
    """A library call raises (it does not end the interpreter): one traceback, the script's
    own, no worker's, ending in the one line that names the script's line and the guard."""
    proc = _run(tmp_path, UNGUARDED.format(executor=executor))
    assert proc.returncode == 1
    assert proc.stderr.count("Traceback") == 1, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("vdc.executors.MissingMainGuard: script.py, line 7: "), last
    assert 'if __name__ == "__main__":' in last
    assert "results" not in proc.stdout and "failed" not in proc.stderr


def test_a_library_caller_catches_the_missing_guard_as_a_user_error(tmp_path) -> None:
    script = (
        UNGUARDED.format(executor="local")
        .replace(
            "\nout = run_tasks", "\nfrom vdc.errors import UserError\ntry:\n    out = run_tasks"
        )
        .replace(
            '\nprint("results"',
            "\nexcept UserError as e:\n    print('caught', type(e).__name__, e)"
            '\n    raise SystemExit(0)\nprint("results"',
        )
    )
    proc = _run(tmp_path, script)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert proc.stdout.startswith("caught MissingMainGuard script.py, line 9: "), proc.stdout


def test_a_command_line_prints_the_missing_guard_as_one_line_exit_2(tmp_path) -> None:
    """A script that runs ``vdc-analyse``'s main from its top level: the command line prints
    the error as one line and exits 2 (the unreadable input leaves no task, the check comes
    first all the same)."""
    script = (
        "from analysis.cli import main\n"
        "open('x.rrd', 'wb').write(b'not a recording')\n"
        "raise SystemExit(main(['batch', 'x.rrd', '--out', 'o']))\n"
    )
    proc = _run(tmp_path, script)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert len(errors) == 1, proc.stderr  # the line before it is the command's plan
    assert errors[0].startswith("vdc-analyse batch: error: script.py, line 3: "), errors


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


def test_a_pool_knows_its_workers_and_when_one_has_died(tmp_path) -> None:
    """``WorkerPool`` finds its workers through the context it made them with (the standard
    pool keeps them private): a dead worker marks it broken, and ``end_workers`` kills and
    collects every one, as a SIGTERM to the caller does."""
    script = """
import json, os
from vdc.executors import ExecutorSettings, open_executor
from vdc.pool_workers import end_workers

if __name__ == "__main__":
    with open_executor(ExecutorSettings("local", 2), 2) as (pool, _):
        pids = sorted(pool.submit(os.getpid).result() for _ in range(4))
        seen = sorted(p.pid for p in pool.workers())
        healthy = pool.is_broken()
        try:
            pool.submit(os._exit, 1).result()
        except Exception as exc:
            died = type(exc).__name__
        broken = pool.is_broken()
    with open_executor(ExecutorSettings("local", 2), 2) as (pool, _):
        pool.submit(os.getpid).result()
        end_workers(pool)
        ended = [p.exitcode for p in pool.workers()]
    print(json.dumps({"pids": pids, "seen": seen, "healthy": healthy, "died": died,
                      "broken": broken, "ended": ended}))
"""
    proc = _run(tmp_path, script)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    # workers start on demand: the tasks ran on some of those the pool knows
    assert got["seen"] and set(got["pids"]) <= set(got["seen"]), (
        f"Python {sys.version.split()[0]}: ProcessPoolExecutor no longer starts its workers "
        f"through its mp_context's Process (vdc.pool_workers.WorkerPool cannot see them): {got}"
    )
    assert got["healthy"] is False and got["died"] == "BrokenProcessPool" and got["broken"]
    # killed and collected: -9, or 255 where the pool's own thread read the exit status first
    # (the standard library's forkserver process objects then report 255)
    assert got["ended"] and all(code in (-9, 255) for code in got["ended"]), got

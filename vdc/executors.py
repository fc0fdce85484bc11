"""Where tasks run: one ``concurrent.futures`` loop, several backends.

* ``local`` (default): a process pool over the usable cores. Its workers are forked from a
  fork server that has already imported what every worker needs and loaded the Numba kernels
  (``vdc.warm``), so a second worker duplicates no start-up; the server imports nothing that
  starts threads (polars', Rerun's), which each worker imports itself. Where there is no fork
  server (Windows), workers start fresh (``spawn``). If a worker dies the stdlib pool breaks
  and every pending task fails with it; :func:`run_tasks` then starts a new pool once for the
  tasks that had not finished (finished ones wrote their results already).
* ``dask``: an existing cluster (``scheduler`` = ``tcp://host:port``, ``tls://...`` or a
  scheduler file) or, without one, a local cluster on 127.0.0.1 (dashboard on 127.0.0.1 too);
  ``client.get_executor`` gives real ``concurrent.futures`` futures. Needs the optional extra
  ``pip install "visual-dynamic-complexity[dask]"``.

Every worker, local or Dask, runs one OpenCV thread and one BLAS thread
(:func:`one_thread_per_worker`). Starting workers runs a plain script again from the top in
each of them: a script that calls a command at its top level without the
``if __name__ == "__main__":`` guard ends with one line saying so (:func:`check_main_guard`).

Tasks are module-level functions with small, picklable arguments (paths, not arrays) that
write their own outputs and return a small dict. Both sides use
this module: ``vdc-analyse batch`` and the closed-loop campaigns (``collision-study``,
``reproduce``, ``vdc-capture campaign``).
"""

from __future__ import annotations

import ast
import concurrent.futures as cf
import contextlib
import ctypes
import dataclasses
import multiprocessing
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import forkserver
from pathlib import Path
from typing import Any

import cv2
from threadpoolctl import threadpool_limits

from vdc.cli_support import Settings, option
from vdc.errors import UserError

EXECUTORS = ("local", "dask")


def usable_cpus() -> int:
    """CPUs this process may use (inside SLURM or a cgroup, not the whole node)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def executor_field(name: str) -> Any:
    """The settings field (and flag) ``executor``, ``jobs`` or ``scheduler``: where a
    command's independent tasks run."""
    if name == "executor":
        return option(
            "local",
            "where the tasks run: local = a process pool on this machine; dask = a Dask "
            "cluster (pip install 'visual-dynamic-complexity[dask]')",
            choices=EXECUTORS,
        )
    if name == "jobs":
        return option(
            factory=usable_cpus,
            help="worker processes of the local pool or of a local Dask cluster (default, and "
            "the local pool's cap: the cores this process may use; VDC_OVERSUBSCRIBE=1 lifts "
            "the cap)",
        )
    return option(
        None,
        "an existing Dask cluster: tcp://HOST:PORT, tls://HOST:PORT or a scheduler file "
        "(implies --executor dask); without it, --executor dask starts one on 127.0.0.1",
    )


@dataclasses.dataclass(frozen=True)
class ExecutorSettings(Settings):
    """Where tasks run: ``executor`` local|dask, ``jobs`` workers (local pool, or a local Dask
    cluster), ``scheduler`` an existing Dask cluster's address or scheduler file."""

    executor: str = executor_field("executor")
    jobs: int = executor_field("jobs")
    scheduler: str | None = executor_field("scheduler")

    def __post_init__(self) -> None:
        if self.scheduler and self.executor == "local":
            object.__setattr__(self, "executor", "dask")  # a scheduler means Dask
        if self.executor not in EXECUTORS:
            raise UserError(f"--executor must be one of {', '.join(EXECUTORS)}")
        if self.jobs < 1:
            raise UserError(f"--jobs must be at least 1, got {self.jobs}")
        if self.scheduler and not self.scheduler.startswith(("tcp://", "tls://", "inproc://")):
            path = Path(self.scheduler).expanduser()
            # Client(scheduler_file=...) neither expands ~ nor times out on a missing file
            if not path.is_file():
                raise UserError(
                    f"--scheduler {self.scheduler!r} is neither tcp://HOST:PORT, tls://HOST:PORT "
                    "nor an existing scheduler file"
                )

    def executor_settings(self) -> ExecutorSettings:
        """Just where tasks run (a command's settings may carry more fields)."""
        return ExecutorSettings(self.executor, self.jobs, self.scheduler)

    def where(self) -> str:
        """Where tasks run, for people: "2 local processes", "Dask at tcp://...", ..."""
        if self.scheduler:
            return f"Dask at {self.scheduler}"
        if self.executor == "dask":
            return f"a local Dask cluster of up to {self.jobs} worker(s)"
        return f"up to {self.jobs} local process(es)"


class TasksFailed(Exception):
    """Some tasks of a campaign failed (the others finished and kept their outputs); the
    command ends with exit status 1 and this message."""


def _quiet(_what: Any) -> None:
    """Feedback nobody listens to."""


@dataclasses.dataclass(frozen=True)
class Feedback:
    """What a long command tells its caller as it goes: ``log`` takes a line for people
    (the command line prints it on stderr), ``progress`` takes how many more units (runs,
    clips, ...) are done (the command line moves its bar). Both do nothing by default."""

    log: Callable[[str], None] = _quiet
    progress: Callable[[int], None] = _quiet


QUIET = Feedback()


def _dask_client(settings: ExecutorSettings, n_tasks: int) -> tuple[Any, Any]:
    """The client, and the local cluster it runs on when vdc started one (else None)."""
    try:
        from distributed import Client, LocalCluster, WorkerPlugin  # lazy: optional extra
    except ImportError:
        raise UserError(
            '--executor dask needs the optional extra: pip install -e ".[dask]"'
        ) from None
    if settings.scheduler:
        s = settings.scheduler
        try:
            if s.startswith(("tcp://", "tls://", "inproc://")):
                client = Client(s, timeout="10s")
            else:
                client = Client(scheduler_file=str(Path(s).expanduser()), timeout="10s")
        except (OSError, TypeError, ValueError) as exc:
            # unreachable or refused (OSError); tls:// without a client certificate in Dask's
            # configuration (TypeError "TLS expects a ssl_context")
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise UserError(f"cannot reach the Dask scheduler {s}: {why}") from None
        try:
            # workers running another vdc, Python or pickle library would fail obscurely later
            client.get_versions(check=True)
        except Exception as exc:
            client.close()
            raise UserError(f"the Dask cluster at {s} does not match this client: {exc}") from None
        _one_thread_on_dask(client, WorkerPlugin)
        return client, None
    # our own cluster: loopback only (a Dask port runs pickled code as the user), processes
    # with one thread each (the models' Python loops hold the GIL)
    # workers forked from the local pool's warm fork server (vdc.warm preloaded), as the
    # local pool's are
    import dask  # lazy: optional extra

    method = pool_context().get_start_method()
    with dask.config.set({"distributed.worker.multiprocessing-method": method}):
        cluster = LocalCluster(
            n_workers=max(1, min(settings.jobs, n_tasks)),
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        )
    client = Client(cluster)
    _one_thread_on_dask(client, WorkerPlugin)
    return client, cluster


def _one_thread_on_dask(client: Any, plugin_base: type) -> None:
    """One OpenCV and one BLAS thread in every worker of the cluster, now and after a restart
    (a worker plugin: Dask's nanny sets the BLAS variables before a worker starts, but not
    OpenCV's threads, nor the BLAS of a cluster started without a nanny)."""

    # distributed.WorkerPlugin; a local class, pickled by value (cloudpickle)
    class OneThreadPerWorker(plugin_base):
        name = "vdc-one-thread-per-worker"

        def setup(self, worker: Any) -> None:
            one_thread_per_worker(1)

    client.register_plugin(OneThreadPerWorker())


def _die_with_parent(
    parent_pid: int,
    threads: int = 1,
    pool_pid: int | None = None,
    environ: dict[str, str] | None = None,
) -> None:
    """Pool worker start-up: end this worker when the pool's process ends, by any signal,
    SIGKILL included, and undo the signal handling it may have inherited. ``environ``: the
    pool's process's environment when it started the pool (a worker forked from the fork
    server would otherwise have the server's, from when the server started; what a library
    read when the server imported it stays as it was).

    ``parent_pid`` is this worker's parent: the pool's process (``spawn``) or the fork server
    (``pool_pid`` is then the pool's process). The fork server does not end before its
    workers (they hold its liveness pipe), so a worker watches the pool's process itself.

    * Linux: the kernel sends SIGKILL when the parent dies (``PR_SET_PDEATHSIG``); the parent
      may already be gone by then, so that is checked once after asking;
    * a daemon thread waits for the pool's process to end (a pidfd, Linux 5.3+: no polling),
      or checks every half second whether it still runs (elsewhere, or with ``spawn``:
      whether the worker has been handed to another parent);
    * SIGTERM is the default again (a capture's handler, or an ignored SIGTERM, must not keep
      a worker alive), and SIGINT is ignored: Ctrl-C reaches the whole process group, and the
      parent decides what ends (it shuts the pool down)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if environ is not None and environ != os.environ:
        os.environ.clear()
        os.environ.update(environ)
    if sys.platform.startswith("linux"):
        try:
            pr_set_pdeathsig = 1
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)
        except (OSError, AttributeError):  # another libc: the watch thread still works
            pass
    if os.getppid() != parent_pid:
        os._exit(1)
    pidfd = None
    if pool_pid is not None:
        try:
            pidfd = os.pidfd_open(pool_pid)
        except (AttributeError, OSError):  # not Linux 5.3+; or already gone: the loop sees it
            pidfd = None

    def alive() -> bool:
        if os.getppid() != parent_pid:
            return False
        if pool_pid is None:
            return True
        try:
            os.kill(pool_pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # pragma: no cover - another user's process: ours ended
            return False
        return True

    def watch() -> None:
        if pidfd is not None:
            select.select([pidfd], [], [])  # readable once the process has ended
            os._exit(1)
        while alive():
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="vdc-parent-watch", daemon=True).start()
    one_thread_per_worker(threads)


# set in pool workers: a worker is one core's worth of work (the pool has one per core), so its
# libraries must not start threads of their own on the other cores (OpenCV, FFmpeg's decoder)
SINGLE_THREAD_ENV = "VDC_WORKER_THREADS"


def one_thread_per_worker(threads: int = 1) -> None:
    """Keep this process to one thread of computation: the pool has a worker per core, and
    OpenCV's, FFmpeg's and the BLAS library's own threads would otherwise compete for the same
    cores (measured: 8 clips on 2 workers ran only 1.19x faster than on one worker that used
    both cores; a calibration fit took 11.3 s of CPU with OpenBLAS's default threads on a busy
    machine, 0.6 s with one). ``threads`` > 1: the cores the pool leaves this worker (fewer
    workers than cores), which vdc's own pipelines may use (``vdc.pipeline.usable_threads``).

    The BLAS limit is set at run time (threadpoolctl), so it holds whenever NumPy was loaded:
    in the fork server before (``vdc.warm`` sets the environment first), or in a worker that
    imported it with the script it re-ran; it also holds for a BLAS loaded later."""
    os.environ[SINGLE_THREAD_ENV] = str(max(1, threads))
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"  # for what loads later, and the worker's own child processes
    cv2.setNumThreads(1)
    threadpool_limits(1)  # BLAS and OpenMP runtimes already loaded


def pool_size(jobs: int, n_tasks: int) -> int:
    """Workers of a local pool: ``jobs``, but no more than the tasks and, unless
    ``VDC_OVERSUBSCRIBE=1``, no more than the usable cores (each worker holds a Numba and
    polars runtime of several hundred MB: 18 workers on 2 cores only cost memory)."""
    n = max(1, min(jobs, n_tasks))
    if os.environ.get("VDC_OVERSUBSCRIBE") != "1":
        n = min(n, usable_cpus())
    return n


def end_workers(pool: cf.ProcessPoolExecutor) -> None:
    """Kill the pool's workers and collect each: then none runs and their files are closed.
    SIGKILL, as PDEATHSIG sends: a capture's own SIGTERM handler would finish a truncated run
    and mark it done; killed, it leaves its partial file for a re-run."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            p.kill()
    for p in procs:
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            p.join()


@contextlib.contextmanager
def _workers_end_before_parent(pool: cf.ProcessPoolExecutor) -> Iterator[None]:
    """While the block runs, SIGTERM first ends and collects the pool's workers, then ends
    this process by SIGTERM as before: PDEATHSIG alone let a worker on a busy machine hold its
    partial recording and lock after the parent's exit had been reported."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers belong to the main thread; PDEATHSIG still ends the workers
        return

    previous = signal.getsignal(signal.SIGTERM)
    if previous == signal.SIG_IGN:
        yield  # the caller chose to outlive SIGTERM: so do the workers' tasks
        return

    def on_term(signum: int, frame: Any) -> None:
        end_workers(pool)
        if callable(previous):  # the caller's own handler decides what happens next
            previous(signum, frame)
            return
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


# what the fork server imports before it forks the first worker (the modules it lists)
WARM_PRELOAD = ["vdc.warm"]


def pool_context() -> multiprocessing.context.BaseContext:
    """The local pool's start method: a warm ``forkserver`` (``vdc.warm`` preloaded, started
    now so that it warms while the caller plans), or ``spawn`` where there is none.

    The fork server is one per process (the standard library's): vdc sets its preload list
    only if it is not running yet. Started by someone else without ``vdc.warm``, its workers
    start cold but still right (each imports what it needs)."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    server = forkserver._forkserver  # the stdlib's one server: is it running yet?
    if getattr(server, "_forkserver_pid", None) is None:
        # not the default "__main__": the server must not run the caller's script
        ctx.set_forkserver_preload(WARM_PRELOAD)
    forkserver.ensure_running()
    return ctx


def _worker_parent(ctx: multiprocessing.context.BaseContext) -> int:
    """The process a new worker's parent is: the fork server (which ends when this process
    does, however it ends: its pipe from this process closes), or this process."""
    if ctx.get_start_method() == "forkserver":
        pid = getattr(forkserver._forkserver, "_forkserver_pid", None)
        if pid is not None:
            return pid
    return os.getpid()


@contextlib.contextmanager
def open_executor(settings: ExecutorSettings, n_tasks: int) -> Iterator[tuple[cf.Executor, Any]]:
    """The executor (and the Dask client, or None) for ``n_tasks`` tasks; closed on exit.

    Local pool workers end with the process that started them, however it ends."""
    if settings.executor == "local":
        ctx = pool_context()
        workers = pool_size(settings.jobs, n_tasks)
        pool = cf.ProcessPoolExecutor(
            workers,
            mp_context=ctx,
            initializer=_die_with_parent,
            initargs=(
                _worker_parent(ctx),
                max(1, usable_cpus() // workers),
                os.getpid(),
                dict(os.environ),
            ),
        )
        try:
            with _workers_end_before_parent(pool):
                yield pool, None
        except BaseException:
            end_workers(pool)  # the parent abandons the work (Ctrl-C, an error): so do they
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        return
    client, cluster = _dask_client(settings, n_tasks)
    try:
        yield client.get_executor(pure=False), client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@dataclasses.dataclass
class TaskOutcome:
    key: str  # the task's name for people: "<recording> <model>"
    result: dict[str, Any] | None
    error: str | None


def check_shared_paths(client: Any, paths: Sequence[str | Path]) -> None:
    """Every Dask worker sees ``paths`` (tasks pass paths, not data: recordings and outputs
    must be on a filesystem every worker mounts at the same place)."""
    for path in paths:
        seen = client.run(os.path.exists, str(Path(path).resolve()))
        blind = sorted(w for w, ok in seen.items() if not ok)
        if blind:
            raise UserError(
                f"{len(blind)} of {len(seen)} Dask worker(s) cannot see {path} (e.g. {blind[0]}): "
                "recordings and --out must be on a filesystem shared by every worker"
            )


def _is_main_guard(node: ast.stmt) -> bool:
    """``if __name__ == "__main__":`` (either order of the comparison)."""
    if not isinstance(node, ast.If) or not isinstance(node.test, ast.Compare):
        return False
    t = node.test
    sides = [t.left, *t.comparators]
    names = [x.id for x in sides if isinstance(x, ast.Name)]
    consts = [x.value for x in sides if isinstance(x, ast.Constant)]
    return len(sides) == 2 and names == ["__name__"] and consts == ["__main__"]


def unguarded_main_line() -> tuple[str, int] | None:
    """(script, line) when this call comes from the top level of a script that worker
    processes would run again from the top (a plain ``python script.py``, or ``python -m
    pkg.mod``), outside ``if __name__ == "__main__":``; else None (a guarded script, a
    package's ``__main__``, ``python -c``, a notebook or a console command).

    Why: a local pool's and a local Dask cluster's workers import the script again to find
    what it defines; unguarded, that import starts workers of its own, which Python forbids,
    and every worker dies with a page of tracebacks."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    name = getattr(spec, "name", None)
    if name is not None and (name == "__main__" or name.endswith(".__main__")):
        return None  # multiprocessing does not import a package's __main__ again
    path = getattr(main, "__file__", None)
    if main is None or not path:
        return None
    frame = sys._getframe(1)
    lines = []
    while frame is not None:
        if frame.f_globals is main.__dict__ and frame.f_code.co_name == "<module>":
            lines.append(frame.f_lineno)
        frame = frame.f_back
    if not lines:
        return None
    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"), filename=path)
    except (OSError, SyntaxError, UnicodeDecodeError, ValueError):
        return None
    guarded = [n for n in tree.body if _is_main_guard(n)]
    for line in lines:
        if not any(g.lineno <= line <= (g.end_lineno or g.lineno) for g in guarded):
            return str(path), line
    return None


def check_main_guard(settings: ExecutorSettings) -> None:
    """End a plain script that starts local workers from its top level without
    ``if __name__ == "__main__":`` with one line saying what to add, exit status 2, before
    any worker starts (each would run the script again; see :func:`unguarded_main_line`).
    An existing Dask cluster's workers do not run the script: no check then."""
    if settings.scheduler:
        return
    where = unguarded_main_line()
    if where is None:
        return
    script, line = where
    print(
        f"{Path(script).name}, line {line}: vdc runs its work in worker processes, which "
        "import this script again: put the script's top-level code under if __name__ == "
        '"__main__": (see the examples in the docs)',
        file=sys.stderr,
        flush=True,
    )
    raise SystemExit(2)


def run_tasks(
    fn: Callable[..., dict[str, Any]],
    tasks: Sequence[tuple[str, tuple]],
    settings: ExecutorSettings,
    on_done: Callable[[TaskOutcome], None] | None = None,
    log: Callable[[str], None] | None = None,
    shared_paths: Sequence[str | Path] = (),
) -> list[TaskOutcome]:
    """Run ``fn(*args)`` for every ``(key, args)`` in ``tasks``; a task that raises is an
    outcome with its error and does not stop the others. Futures are dropped as they finish
    (a held Dask future is recomputed if its worker dies). On Dask, ``shared_paths`` (e.g.
    the first input and the output folder) are checked on every worker first."""
    check_main_guard(settings)
    outcomes: dict[str, TaskOutcome] = {}
    todo = list(tasks)
    restarted = False
    while todo:
        with open_executor(settings, len(todo)) as (ex, client):
            if client is not None:
                check_shared_paths(client, shared_paths)
                if log is not None and settings.scheduler is None:
                    log(f"local Dask cluster on 127.0.0.1, dashboard {client.dashboard_link}")
            pending = {ex.submit(fn, *args): key for key, args in todo}
            broken: list[str] = []
            for fut in cf.as_completed(list(pending)):
                key = pending.pop(fut)
                try:
                    res = fut.result()
                    out = TaskOutcome(key, res, None)
                except BrokenProcessPool:
                    broken.append(key)  # a worker died: this task may not have run at all
                    continue
                except Exception as exc:  # the task's own error, reported, not fatal
                    out = TaskOutcome(key, None, f"{type(exc).__name__}: {exc}")
                outcomes[key] = out
                if on_done is not None:
                    on_done(out)
        by_key = dict(todo)
        todo = [(k, by_key[k]) for k in broken] if broken and not restarted else []
        if todo and log is not None:
            log(f"a worker process died: {len(todo)} unfinished task(s) go to a fresh pool")
        if broken and restarted:
            for k in broken:
                outcomes[k] = TaskOutcome(k, None, "a worker process died twice running it")
                if on_done is not None:
                    on_done(outcomes[k])
        restarted = restarted or bool(broken)
    return [outcomes[k] for k, _ in tasks if k in outcomes]


def run_tasks_or_raise(
    fn: Callable[..., dict[str, Any]],
    tasks: Sequence[tuple[str, tuple]],
    settings: ExecutorSettings,
    what: str,
    feedback: Feedback = QUIET,
    shared_paths: Sequence[str | Path] = (),
) -> dict[str, dict[str, Any]]:
    """A campaign's loop: :func:`run_tasks` with one ``feedback.progress`` unit and, for a
    failure, one ``feedback.log`` line per finished task; the results by key in the order
    they finished. A failed task does not stop the others: when all have finished,
    :class:`TasksFailed` names the failed ones (``what``: a task's noun, e.g. "run")."""
    results: dict[str, dict[str, Any]] = {}

    def done(outcome: TaskOutcome) -> None:
        feedback.progress(1)
        if outcome.error is not None:
            feedback.log(f"  {outcome.key} FAILED: {outcome.error}")
        else:
            results[outcome.key] = outcome.result or {}

    outcomes = run_tasks(fn, tasks, settings, done, feedback.log, shared_paths)
    report = failure_report(outcomes, what)
    if report:
        raise TasksFailed(report)
    return results


def failure_report(outcomes: Sequence[TaskOutcome], what: str = "task") -> str | None:
    """One message naming every failed task, or None when all finished."""
    bad = [o for o in outcomes if o.error is not None]
    if not bad:
        return None
    listed = "; ".join(f"{o.key}: {o.error}" for o in bad[:5])
    more = f" (and {len(bad) - 5} more)" if len(bad) > 5 else ""
    return (
        f"{len(bad)} of {len(outcomes)} {what}(s) failed: {listed}{more}; the finished ones "
        "are kept and a re-run retries only the failed"
    )

"""How a local pool's workers start and end (:mod:`vdc.executors` runs the tasks).

* They fork from a warm ``forkserver`` (its preload, ``vdc.warm_fork_server``, warms it), or
  start fresh (``spawn``) where there is none (:func:`pool_context`), in a :class:`WorkerPool`,
  which knows its workers.
* Each is one core's worth of work: one OpenCV, BLAS and FFmpeg thread
  (:func:`one_thread_per_worker`), on the cores of the process that started the pool, with
  its environment, and no pandas for pyarrow's sake (:mod:`vdc.no_pandas`).
* They end with that process, however it ends (``PR_SET_PDEATHSIG``, a watch thread), and a
  SIGTERM to it ends and collects them first (:func:`end_workers`)."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import multiprocessing
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Iterator
from multiprocessing import forkserver
from typing import Any

import cv2
from threadpoolctl import threadpool_limits

from vdc.no_pandas import arrow_without_pandas


def _die_with_parent(
    parent_pid: int | None,
    threads: int = 1,
    pool_pid: int | None = None,
    environ: dict[str, str] | None = None,
    cpus: frozenset[int] | None = None,
) -> None:
    """Pool worker start-up: end this worker when the pool's process ends, by any signal,
    SIGKILL included, and undo the signal handling it may have inherited. ``environ``: the
    pool's process's environment when it started the pool (a worker forked from the fork
    server would otherwise have the server's, from when the server started; what a library
    read when the server imported it stays as it was). ``cpus``: the cores the pool's process
    may use when it started the pool (the fork server kept those of when it started: a
    caller that narrowed or widened its cores since, as ``taskset`` or a benchmark does, had
    every worker on the old ones).

    ``parent_pid`` is this worker's parent: the pool's process (``spawn``), or None for the
    fork server (``pool_pid`` is then the pool's process): the standard library names no
    public way to ask the server's process id, so the worker takes its parent as it finds it
    once PDEATHSIG is set; a server that ended before that is caught by the watch on the
    pool's process. The fork server does not end before its workers (they hold its liveness
    pipe), so a worker watches the pool's process itself.

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
    if cpus is not None and hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):  # a core taken away since: keep the server's
            os.sched_setaffinity(0, cpus)
    if sys.platform.startswith("linux"):
        try:
            pr_set_pdeathsig = 1
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)
        except (OSError, AttributeError):  # another libc: the watch thread still works
            pass
    if parent_pid is None:
        parent_pid = os.getppid()
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
    arrow_without_pandas()  # a worker is vdc's own process: no pandas import (0.25 s each)


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
    in the fork server before (``vdc.warm.warm_fork_server`` sets the environment first), or
    in a worker that imported it with the script it re-ran; it also holds for a BLAS loaded
    later."""
    os.environ[SINGLE_THREAD_ENV] = str(max(1, threads))
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"  # for what loads later, and the worker's own child processes
    cv2.setNumThreads(1)
    threadpool_limits(1)  # BLAS and OpenMP runtimes already loaded


class _Remembering:
    """A multiprocessing context that remembers every process made with it (the rest is the
    context's own): how a :class:`WorkerPool` knows its workers."""

    def __init__(self, ctx: multiprocessing.context.BaseContext) -> None:
        self.ctx = ctx
        self.processes: list[multiprocessing.process.BaseProcess] = []

    def Process(self, *args: Any, **kwargs: Any) -> multiprocessing.process.BaseProcess:
        process = self.ctx.Process(*args, **kwargs)
        self.processes.append(process)
        return process

    def __getattr__(self, name: str) -> Any:
        return getattr(self.ctx, name)


class WorkerPool(cf.ProcessPoolExecutor):
    """The standard process pool, made through a context that remembers its workers: the
    pool itself keeps them private (``_processes``), and a SIGTERM or an abandoned run must
    end them (:func:`end_workers`)."""

    def __init__(
        self, max_workers: int, mp_context: multiprocessing.context.BaseContext, **kwargs: Any
    ) -> None:
        self.made = _Remembering(mp_context)
        super().__init__(max_workers, mp_context=self.made, **kwargs)  # type: ignore[arg-type]

    def workers(self) -> list[multiprocessing.process.BaseProcess]:
        """Every worker this pool started (a finished one too)."""
        return list(self.made.processes)

    def is_broken(self) -> bool:
        """Whether a worker has ended: the pool is then broken for good (it ends its other
        workers and fails every pending task); vdc's pools never retire a worker."""
        for p in self.workers():
            with contextlib.suppress(ValueError):  # closed: it had ended
                if not p.is_alive():
                    return True
        return False


def end_workers(pool: WorkerPool) -> None:
    """Kill the pool's workers and collect each: then none runs and their files are closed.
    SIGKILL, as PDEATHSIG sends: a capture's own SIGTERM handler would finish a truncated run
    and mark it done; killed, it leaves its partial file for a re-run."""
    procs = pool.workers()
    for p in procs:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            p.kill()
    for p in procs:
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            p.join()


@contextlib.contextmanager
def _workers_end_before_parent(pool: WorkerPool) -> Iterator[None]:
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


# what the fork server imports before it forks the first worker: a module whose import warms
# it (vdc.warm.warm_fork_server); the stdlib's fork server can only import its preload list
WARM_PRELOAD = ["vdc.warm_fork_server"]


def pool_context() -> multiprocessing.context.BaseContext:
    """The local pool's start method: a warm ``forkserver`` (``vdc.warm_fork_server``
    preloaded, started now so that it warms while the caller plans), or ``spawn`` where there
    is none.

    The fork server is one per process (the standard library's): the preload list is set at
    every call, and counts only when the server starts (a running one keeps its own). Started
    by someone else without it, its workers start cold but still right (each imports what it
    needs). Not the default "__main__": the server must not run the caller's script."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(WARM_PRELOAD)
    forkserver.ensure_running()
    return ctx


def _worker_parent(ctx: multiprocessing.context.BaseContext) -> int | None:
    """The process a new worker's parent is, for :func:`_die_with_parent`: this process
    (``spawn``), or None: the fork server, which the worker finds itself (its pid is the
    server's private detail)."""
    return None if ctx.get_start_method() == "forkserver" else os.getpid()


def caller_cores() -> frozenset[int] | None:
    """The cores this process may use now (None where the platform cannot say): what a new
    worker takes as its own (:func:`_die_with_parent`)."""
    return frozenset(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None

"""Where tasks run: one ``concurrent.futures`` loop, several backends.

* ``local`` (default): a process pool over the usable cores, its workers forked warm from
  a fork server (:mod:`vdc.pool_workers`: how they start and end). If a worker dies the
  stdlib pool breaks and every pending task fails with it; :func:`run_tasks` then starts a
  new pool once for the tasks that had not finished (finished ones wrote their results
  already). Inside :func:`one_pool` (every ``vdc-analyse`` command, the campaigns' library
  calls) the stages share one pool, so the workers' start-up is paid once.
* ``dask``: an existing cluster (``scheduler`` = ``tcp://host:port``, ``tls://...`` or a
  scheduler file) or, without one, a local cluster on 127.0.0.1 (dashboard on 127.0.0.1 too);
  ``client.get_executor`` gives real ``concurrent.futures`` futures. Needs the optional extra
  ``pip install "visual-dynamic-complexity[dask]"``.

Every worker, local or Dask, runs one OpenCV thread and one BLAS thread
(:func:`one_thread_per_worker`). Starting workers runs a plain script again from the top in
each of them: a script that calls a command at its top level without the
``if __name__ == "__main__":`` guard gets one error saying so (:func:`check_main_guard`).

Tasks are module-level functions with small, picklable arguments (paths, not arrays) that
write their own outputs and return a small dict. Both sides use
this module: ``vdc-analyse batch`` and the closed-loop campaigns (``collision-study``,
``reproduce``, ``vdc-capture campaign``).
"""

from __future__ import annotations

import ast
import concurrent.futures as cf
import contextlib
import dataclasses
import os
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from vdc.cli_support import option
from vdc.errors import UserError
from vdc.heartbeat import Heartbeat
from vdc.pool_workers import (
    WorkerPool,
    _die_with_parent,
    _worker_parent,
    _workers_end_before_parent,
    caller_cores,
    end_workers,
    one_thread_per_worker,
    pool_context,
)
from vdc.settings import AT_LEAST_1, Settings

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
            range=AT_LEAST_1,
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
            raise UserError(f"--executor must be one of {', '.join(EXECUTORS)}.")
        if self.scheduler and not self.scheduler.startswith(("tcp://", "tls://", "inproc://")):
            path = Path(self.scheduler).expanduser()
            # Client(scheduler_file=...) neither expands ~ nor times out on a missing file
            if not path.is_file():
                raise UserError(
                    f"--scheduler {self.scheduler!r} is neither tcp://HOST:PORT, tls://HOST:PORT "
                    "nor an existing scheduler file."
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
    clips, ...) are done (the command line moves its count), ``expect`` how many more units
    are planned (the count's total, for an estimate of what is left). All do nothing by
    default; :meth:`printing` prints them, as the command line does."""

    log: Callable[[str], None] = _quiet
    progress: Callable[[int], None] = _quiet
    expect: Callable[[int], None] = _quiet

    @staticmethod
    @contextlib.contextmanager
    def printing(
        what: str = "vdc", unit: str = "run", every_s: float | None = None
    ) -> Iterator[Feedback]:
        """Inside the block, a Feedback that prints on stderr: each line logged, and when
        nothing was printed for ``every_s`` seconds (default: ``VDC_PROGRESS_EVERY_S`` if
        set, else 4) a line with the time so far, what is running
        and how many ``unit``s of how many are done, with an estimate of the time left
        (:class:`vdc.heartbeat.Heartbeat`)::

            with vdc.Feedback.printing("boundary") as feedback:
                vdc.boundary(settings, "results/boundary", feedback)
        """
        with Heartbeat(what, every_s) as hb:
            count = hb.counter(what, unit)
            yield Feedback(hb.log, count.update, count.expect)


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
    # workers forked from the local pool's warm fork server (vdc.warm_fork_server preloaded), as the
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
    _one_thread_on_dask(client, WorkerPlugin, caller_cores())
    return client, cluster


def _one_thread_on_dask(client: Any, plugin_base: type, cpus: frozenset[int] | None = None) -> None:
    """One OpenCV and one BLAS thread in every worker of the cluster, now and after a restart
    (a worker plugin: Dask's nanny sets the BLAS variables before a worker starts, but not
    OpenCV's threads, nor the BLAS of a cluster started without a nanny). ``cpus``: the
    cores of vdc's own local cluster (its workers fork from the fork server, which kept the
    cores of when it started; see :func:`_die_with_parent`)."""

    # distributed.WorkerPlugin; a local class, pickled by value (cloudpickle)
    class OneThreadPerWorker(plugin_base):
        name = "vdc-one-thread-per-worker"

        def setup(self, worker: Any) -> None:
            if cpus is not None:
                with contextlib.suppress(OSError):
                    os.sched_setaffinity(0, cpus)
            one_thread_per_worker(1)

    client.register_plugin(OneThreadPerWorker())


def pool_size(jobs: int, n_tasks: int) -> int:
    """Workers of a local pool: ``jobs``, but no more than the tasks and, unless
    ``VDC_OVERSUBSCRIBE=1``, no more than the usable cores (each worker holds a Numba and
    polars runtime of several hundred MB: 18 workers on 2 cores only cost memory)."""
    n = max(1, min(jobs, n_tasks))
    if os.environ.get("VDC_OVERSUBSCRIBE") != "1":
        n = min(n, usable_cpus())
    return n


class _KeptExecutor:
    """The executor a command's stages share (:func:`one_pool`): its key (what it was started
    with), the executor, the Dask client or None, and how to close it."""

    def __init__(self) -> None:
        self.key: Any = None
        self.executor: Any = None
        self.client: Any = None
        self.close: Callable[[], None] | None = None

    def take(self, key: Any) -> tuple[Any, Any] | None:
        """The kept executor if it was started with ``key``; else None, the other closed."""
        if self.executor is not None and self.key == key:
            return self.executor, self.client
        self.drop()
        return None

    def keep(self, key: Any, executor: Any, client: Any, close: Callable[[], None]) -> None:
        self.key, self.executor, self.client, self.close = key, executor, client, close

    def forget(self) -> None:
        """Hold nothing, closing nothing (the caller closes what was kept)."""
        self.key, self.executor, self.client, self.close = None, None, None, None

    def drop(self) -> None:
        close = self.close
        self.forget()
        if close is not None:
            close()


# set by one_pool() in the main thread: the stages of one command share their workers
_kept: _KeptExecutor | None = None


@contextlib.contextmanager
def one_pool() -> Iterator[None]:
    """Within the block, the workers of one stage serve the next: :func:`run_tasks` keeps its
    local pool (or local Dask cluster) open and the next call with the same settings and as
    many workers reuses it, so a worker imports vdc's modules, polars and Rerun and loads
    the kernels once per command, not once per stage (a campaign runs several stages, an
    adaptive design several rounds). Closed when the block ends, however it ends. Nested
    blocks share the outer one's; other threads keep one pool per call."""
    global _kept
    if _kept is not None or threading.current_thread() is not threading.main_thread():
        yield
        return
    _kept = kept = _KeptExecutor()
    try:
        yield
    finally:
        _kept = None
        kept.drop()


def _shut(pool: cf.ProcessPoolExecutor) -> None:
    pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def open_executor(settings: ExecutorSettings, n_tasks: int) -> Iterator[tuple[cf.Executor, Any]]:
    """The executor (and the Dask client, or None) for ``n_tasks`` tasks; closed on exit,
    or kept for the next stage inside :func:`one_pool`.

    Local pool workers end with the process that started them, however it ends."""
    kept = _kept if threading.current_thread() is threading.main_thread() else None
    if settings.executor == "local":
        ctx = pool_context()
        workers = pool_size(settings.jobs, n_tasks)
        initargs = (
            _worker_parent(ctx),
            max(1, usable_cpus() // workers),
            os.getpid(),
            dict(os.environ),
            caller_cores(),
        )
        key = ("local", workers, initargs)
        reused = kept.take(key) if kept is not None else None
        pool = reused[0] if reused is not None else None
        if pool is None:
            pool = WorkerPool(workers, ctx, initializer=_die_with_parent, initargs=initargs)
        ok = False
        try:
            with _workers_end_before_parent(pool):
                yield pool, None
            ok = True
        except BaseException:
            end_workers(pool)  # the parent abandons the work (Ctrl-C, an error): so do they
            raise
        finally:
            # a pool whose worker died is broken for good: never kept
            if ok and kept is not None and not pool.is_broken():
                kept.keep(key, pool, None, lambda p=pool: _shut(p))
            else:
                if kept is not None and kept.executor is pool:
                    kept.forget()  # closed here, not by the keeper
                _shut(pool)
        return
    n_workers = max(1, min(settings.jobs, n_tasks))
    key = ("dask", settings.executor_settings(), n_workers)
    reused = kept.take(key) if kept is not None else None
    if reused is not None:
        client = reused[1]
        yield client.get_executor(pure=False), client
        return
    client, cluster = _dask_client(settings, n_tasks)

    def close() -> None:
        client.close()
        if cluster is not None:
            cluster.close()

    ok = False
    try:
        yield client.get_executor(pure=False), client
        ok = True
    finally:
        if ok and kept is not None:
            kept.keep(key, client.get_executor(pure=False), client, close)
        else:
            close()


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
                "recordings and --out must be on a filesystem shared by every worker."
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


class MissingMainGuard(UserError):
    """A plain script starts local workers from its top level, outside
    ``if __name__ == "__main__":``; the message is one line naming the script and line."""


def check_main_guard(settings: ExecutorSettings) -> None:
    """Raise :class:`MissingMainGuard` when a plain script starts local workers from its top
    level without ``if __name__ == "__main__":``, before any worker starts (each would run the
    script again; see :func:`unguarded_main_line`): a command line prints it as one line, exit
    status 2. An existing Dask cluster's workers do not run the script: no check then."""
    if settings.scheduler:
        return
    where = unguarded_main_line()
    if where is None:
        return
    script, line = where
    raise MissingMainGuard(
        f"{Path(script).name}, line {line}: vdc runs its work in worker processes, which "
        "import this script again: put the script's top-level code under if __name__ == "
        '"__main__": (see the examples in the docs)'
    )


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
                    log(f"local Dask cluster on 127.0.0.1, dashboard {client.dashboard_link}.")
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
            log(f"a worker process died: {len(todo)} unfinished task(s) go to a fresh pool.")
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
    """A campaign's loop: :func:`run_tasks` with ``feedback.expect`` of every task, one
    ``feedback.progress`` unit per finished task and, for a
    failure, one ``feedback.log`` line per finished task; the results by key in the order
    they finished. A failed task does not stop the others: when all have finished,
    :class:`TasksFailed` names the failed ones (``what``: a task's noun, e.g. "run")."""
    results: dict[str, dict[str, Any]] = {}

    feedback.expect(len(tasks))

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

"""Work on a stream of items as a pipeline of threads: each stage in its own thread, the
items in order.

One clip's frames pass through decoding, the native metrics and the resize to the models'
raster; these are independent per frame but each carries state from frame to frame (the
previous frame, a decoder), so they cannot be split by frame. As stages of a pipeline each
keeps its order and its state, and the stages overlap on different frames: on two cores the
slowest stage, not the sum, sets the pace. The work inside the stages (FFmpeg, OpenCV, the
Numba kernels, which are compiled ``nogil``) releases the GIL, so threads suffice. Every stage
sees the same items in the same order as a plain loop would: the results are the same bits.
"""

from __future__ import annotations

import collections
import os
import queue
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent import futures
from typing import Any

_END = object()


class _Failed:
    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


def usable_threads() -> int:
    """Threads a pipeline in this process may use: the cores it may run on, or 1 in a pool
    worker that the pool keeps to one core (``VDC_WORKER_THREADS``, ``vdc.executors``), or
    what the pool leaves it there (a number above 1)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    told = os.environ.get("VDC_WORKER_THREADS")
    if told and told.isdigit() and int(told) >= 1:
        return min(int(told), cores)
    return max(1, cores)


def pipelined(
    items: Iterable[Any], stages: Sequence[Callable[[Any], Any]], depth: int = 4
) -> Iterator[Any]:
    """``items`` (drawn in a thread of its own) through ``stages`` (a thread each), in order:
    yields ``stages[-1](...stages[0](item))`` for each item. At most ``depth`` items wait
    between two stages (memory: a few frames). An exception in any stage or in ``items``
    is raised here; closing the generator early stops the threads."""
    stop = threading.Event()
    queues: list[queue.Queue] = [queue.Queue(depth) for _ in range(len(stages) + 1)]

    def put(q: queue.Queue, x: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(x, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def source() -> None:
        try:
            for x in items:
                if not put(queues[0], x):
                    return
            put(queues[0], _END)
        except BaseException as exc:  # handed to the consumer
            put(queues[0], _Failed(exc))

    def stage(k: int, fn: Callable[[Any], Any]) -> None:
        src, dst = queues[k], queues[k + 1]
        while not stop.is_set():
            try:
                x = src.get(timeout=0.1)
            except queue.Empty:
                continue
            if x is _END or isinstance(x, _Failed):
                put(dst, x)
                return
            try:
                y = fn(x)
            except BaseException as exc:  # handed to the consumer
                put(dst, _Failed(exc))
                return
            if not put(dst, y):
                return

    threads = [threading.Thread(target=source, name="vdc-pipeline-source", daemon=True)]
    threads += [
        threading.Thread(target=stage, args=(k, fn), name=f"vdc-pipeline-{k}", daemon=True)
        for k, fn in enumerate(stages)
    ]
    for t in threads:
        t.start()
    try:
        while True:
            x = queues[-1].get()
            if x is _END:
                return
            if isinstance(x, _Failed):
                raise x.exc
            yield x
    finally:
        stop.set()
        for t in threads:
            t.join()


def ordered_map(
    fn: Callable[[Any], Any], items: Iterable[Any], threads: int, depth: int | None = None
) -> Iterator[Any]:
    """``fn(item)`` for each of ``items`` on ``threads`` threads at once, yielded in the
    items' order: for work on a frame that depends on nothing but its inputs (one frame's
    metrics against the frame before it), so that it spreads over every core while another
    thread decodes. At most ``depth`` (default 2 × ``threads``) items are in flight. An
    exception in ``fn`` or in ``items`` is raised here, at its item; closing the generator
    early cancels what has not started and waits for what has."""
    depth = depth or 2 * threads
    pending: collections.deque[futures.Future] = collections.deque()
    ex = futures.ThreadPoolExecutor(threads, thread_name_prefix="vdc-measure")
    try:
        for x in items:
            pending.append(ex.submit(fn, x))
            while len(pending) >= depth or (pending and pending[0].done()):
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        for f in pending:
            f.cancel()
        ex.shutdown(wait=True)
        close = getattr(items, "close", None)
        if close is not None:
            close()

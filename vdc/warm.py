"""What every pool worker needs, loaded once in the local pool's fork server, whose workers
are forked from it already warm (:func:`warm_fork_server`).

A worker started fresh pays about a second before its first frame: importing NumPy, OpenCV,
PyAV, Numba and vdc, and loading the cached Numba kernels from disk. Two workers each paid
it, so the second worker could not halve a short collection's time. Imported once, in the
fork server, each worker inherits them by forking (copy on write).

Importing this module loads nothing heavy and changes nothing: the fork server's preload,
``vdc.warm_fork_server`` (``vdc.pool_workers.WARM_PRELOAD``), calls :func:`warm_fork_server`,
and nothing else does.

Only what starts no thread at import belongs in :data:`PRELOAD`: a fork copies one thread, so
a library whose threads hold locks (polars' and Rerun's runtimes) must be imported by each
worker itself. :func:`threads_now` checks it (``tests/vdc/test_executors_pool.py``).
"""

from __future__ import annotations

import ctypes
import importlib
import os
import signal
import sys

BLAS_THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

# What the fork server imports, in order. Not scipy: the boundary fit and the statistics
# load scipy.stats and scipy.special where they compute (analysis.stats), so most workers
# never need them, and preloading them cost every fork server 1.1 s of CPU (one per command
# that opens a pool). Not pyplot: vdc never imports it (test_layout).
PRELOAD = (
    "av",
    "cv2",
    "matplotlib",
    "matplotlib.figure",
    "numba",
    "numpy",
    "vdc.frame_metrics",
    "vdc.recording",
    "vdc.resize",
    "vdc.sources",
)


def _end_with_parent() -> None:
    """The fork server ends at once when the process that started it ends, however it ends
    (``PR_SET_PDEATHSIG``), and its workers with it (each asks the same of the server,
    ``vdc.pool_workers``): the kernel ends them all, where otherwise the server would wait for
    its workers and they would have to notice, which a machine at load 100 can delay for tens
    of seconds. (If that process is already gone, the server's liveness pipe is closed and it
    ends at its first look.)"""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # another libc: the workers' watch threads remain
        pass


def warm_fork_server() -> None:
    """Make this process the pool's warm fork server: it ends with its parent, holds one BLAS
    and one OpenCV thread, has :data:`PRELOAD` imported and the metric kernels loaded.

    The BLAS limit is set before NumPy loads OpenBLAS (or MKL, or an OpenMP runtime): it reads
    its thread count once, when it loads, and a worker is one core's worth of work (the pool
    has one worker per core); each worker gets the caller's own environment back when it
    starts (``vdc.pool_workers``)."""
    _end_with_parent()
    for var in BLAS_THREAD_ENV:
        os.environ[var] = "1"
    for name in PRELOAD:
        importlib.import_module(name)
    sys.modules["cv2"].setNumThreads(1)
    try:
        load_kernels()
    except Exception:  # a worker loads them itself then; the server must not die
        pass


def load_kernels() -> None:
    """Load the native metrics' compiled kernels (Numba's on-disk cache, or a compile the
    first time) for the frame types a source gives: 8-bit and 16-bit luma, with and without
    a previous frame. Tiny frames: the kernels are the same whatever the size."""
    # by name, not at the top: importing this module must not load NumPy (its BLAS limit
    # comes first, in warm_fork_server)
    np = importlib.import_module("numpy")
    frame_metrics = importlib.import_module("vdc.frame_metrics")
    for bits, dtype in ((8, np.uint8), (10, np.uint16)):
        meter = frame_metrics.NativeMeter(bit_depth=bits, metrics=("si_p910", "ti_p910"))
        y = np.full((8, 8), 64 << (bits - 8), dtype=dtype)
        meter.update(y)
        meter.update(y)
        legacy = frame_metrics.NativeMeter(bit_depth=bits, p910_range="detect")
        legacy.update(y)
        legacy.update(y)


def threads_now() -> int:
    """Threads of this process (Linux: /proc; elsewhere 1, unknown)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Threads:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 1

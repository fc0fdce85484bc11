"""What every pool worker needs, loaded once: imported by the local pool's fork server
(``vdc.executors``), whose workers are forked from it already warm.

A worker started fresh pays about a second before its first frame: importing NumPy, OpenCV,
PyAV, Numba and vdc, and loading the cached Numba kernels from disk. Two workers each paid
it, so the second worker could not halve a short collection's time. Imported here once, in
the fork server, each worker inherits them by forking (copy on write).

Only what starts no thread at import belongs here: a fork copies one thread, so a library
whose threads hold locks (polars' and Rerun's runtimes) must be imported by each worker
itself. :func:`threads_now` checks it (``tests/vdc/test_executors_pool.py``).

The BLAS limit is set before NumPy loads OpenBLAS: it reads its thread count once, when it
loads, and a worker is one core's worth of work (the pool has one worker per core).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys


def _in_fork_server() -> bool:
    """Whether this import is the fork server's preload (``multiprocessing.forkserver.main``
    on the stack), not an import elsewhere."""
    frame = sys._getframe(1)
    while frame is not None:
        g = frame.f_globals
        if frame.f_code.co_name == "main" and g.get("__name__") == "multiprocessing.forkserver":
            return True
        frame = frame.f_back
    return False


def _end_with_parent() -> None:
    """The fork server ends at once when the process that started it ends, however it ends
    (``PR_SET_PDEATHSIG``), and its workers with it (each asks the same of the server,
    ``vdc.executors``): the kernel ends them all, where otherwise the server would wait for
    its workers and they would have to notice, which a machine at load 100 can delay for tens
    of seconds. (If that process is already gone, the server's liveness pipe is closed and it
    ends at its first look.)"""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # another libc: the workers' watch threads remain
        pass


if _in_fork_server():
    _end_with_parent()

# before NumPy (and through it OpenBLAS, or MKL, or an OpenMP runtime) loads
BLAS_THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
for _var in BLAS_THREAD_ENV:
    os.environ[_var] = "1"

import av  # noqa: E402, F401  - after the thread limits above
import cv2  # noqa: E402
import matplotlib  # noqa: E402
import matplotlib.figure  # noqa: E402, F401  - not pyplot: vdc never imports it (test_layout)
import numba  # noqa: E402, F401
import numpy as np  # noqa: E402

# Not scipy: the boundary fit and the statistics load scipy.stats and scipy.special where
# they compute (analysis.stats), so most workers never need them, and preloading them cost
# every fork server 1.1 s of CPU (one per command that opens a pool).
import vdc.frame_metrics  # noqa: E402
import vdc.recording  # noqa: E402
import vdc.resize  # noqa: E402
import vdc.sources  # noqa: E402

cv2.setNumThreads(1)


def load_kernels() -> None:
    """Load the native metrics' compiled kernels (Numba's on-disk cache, or a compile the
    first time) for the frame types a source gives: 8-bit and 16-bit luma, with and without
    a previous frame. Tiny frames: the kernels are the same whatever the size."""
    for bits, dtype in ((8, np.uint8), (10, np.uint16)):
        meter = vdc.frame_metrics.NativeMeter(bit_depth=bits, metrics=("si_p910", "ti_p910"))
        y = np.full((8, 8), 64 << (bits - 8), dtype=dtype)
        meter.update(y)
        meter.update(y)
        legacy = vdc.frame_metrics.NativeMeter(bit_depth=bits, p910_range="detect")
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


try:
    load_kernels()
except Exception:  # a worker loads them itself then; the server must not die
    pass

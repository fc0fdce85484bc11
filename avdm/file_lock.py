"""One process does a slow, cached piece of work while the others that need it wait for it.

Numba's kernels (:mod:`avdm.jit`) and the decoding calibrations (:mod:`avdm.calibration_store`)
are computed once and cached on disk, but processes that start together each found the
cache empty and computed the same thing side by side: a pool's workers, or the test suite's
workers and the commands they start. :func:`exclusive` holds a lock file beside the cached
file for the computation; whoever waited for it then finds the cache filled and loads it.

The lock is advisory (``flock``): the kernel drops it when its process ends however it ends,
so a killed worker leaves nobody waiting. Where no lock can be had (not POSIX, a folder that
cannot be written, a filesystem without locks) the block runs unlocked, as it did before.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

try:
    import fcntl
except ImportError:  # not POSIX: every process works for itself
    fcntl = None  # type: ignore[assignment]

# lock files this process holds: a second flock on a new descriptor of the same file from the
# same process would wait for the first forever (a kernel's compile may come back to itself)
_HELD: set[str] = set()


@contextlib.contextmanager
def exclusive(path: str | os.PathLike[str]) -> Iterator[bool]:
    """Hold an exclusive lock on ``path`` (created if missing, never removed: removing it
    would let two processes lock two different files) for the block. Yields True when locked,
    False when no lock could be had or this process already holds it (the block then runs
    unlocked)."""
    path = os.fspath(path)
    if fcntl is None or path in _HELD:
        yield False
        return
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:  # a folder that cannot be written
        yield False
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a filesystem without locks (ENOLCK)
            locked = False
        else:
            locked = True
            _HELD.add(path)
        try:
            yield locked
        finally:
            _HELD.discard(path)
    finally:
        os.close(fd)  # releases the lock

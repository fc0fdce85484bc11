"""Numba kernels compiled once per machine, not once per process that starts at the same time.

Every kernel in vdc is ``numba.njit(cache=True)``: the first call compiles it (1-9 s of CPU)
and writes the machine code beside the source, and later processes load it in milliseconds.
Until one process has written it, though, every process that calls the kernel compiles it
too: a fresh install running a pool of workers, or the test suite's workers and the commands
they start, compiled the same kernels side by side (on a fresh clone the suite spent about
135 CPU-s more than with the kernels cached, on 2 cores).

:func:`kernel` is ``numba.njit(cache=True, ...)`` whose compile holds a lock file beside
Numba's cache index for that kernel: a second process that needs the kernel meanwhile waits
for the first, then loads what it wrote. Waiting costs no CPU, and the lock is the kernel's
own, so processes compiling different kernels do not wait on each other. A kernel calls
others, and their locks are taken in call order (callers before callees, never the other way
round), so two processes cannot each hold what the other waits for. Within one process
Numba's own compiler lock is taken first: its threads compile one at a time anyway, and a
thread holding a kernel's file lock never waits for that lock while another thread of the
same process holds the file lock it needs.

The lock is :func:`avdm.file_lock.exclusive`: the kernel drops it when its holder ends however
it ends, and where no lock can be had (or Numba's cache is laid out otherwise) the kernel
compiles as plain Numba would.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
from numba.core import sigutils
from numba.core.compiler_lock import global_compiler_lock

from avdm.file_lock import exclusive


def _lock_path(dispatcher: Any) -> str | None:
    """The kernel's lock file: its cache index's path plus ``.lock`` (None: no cache)."""
    try:
        return dispatcher._cache._cache_file._index_path + ".lock"
    except AttributeError:  # caching off, or Numba's internals changed: no lock
        return None


def _locked_compile(dispatcher: Any) -> Callable[[Any], Any]:
    compile_unlocked = dispatcher.compile

    def compile(sig: Any) -> Any:
        args, _ = sigutils.normalize_signature(sig)
        path = _lock_path(dispatcher)
        if tuple(args) in dispatcher.overloads or path is None:  # loaded already, or no cache
            return compile_unlocked(sig)
        with global_compiler_lock, exclusive(path):
            return compile_unlocked(sig)  # loads what a process we waited for wrote

    return compile


def kernel(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)`` whose first compile on a machine is done by one
    process while the others that need it wait and load it from the cache (module docstring).
    Returns Numba's dispatcher itself: kernels call kernels, and Numba types those calls by
    their dispatchers."""

    def decorate(func: Callable[..., Any]) -> Any:
        dispatcher = numba.njit(cache=True, **options)(func)
        dispatcher.compile = _locked_compile(dispatcher)
        return dispatcher

    return decorate

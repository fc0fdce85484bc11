"""Ctrl-C ends a command even while its main thread is blocked in someone else's code.

Python runs a signal's handler in the main thread only, between bytecodes; a signal the kernel
hands to another thread (polars', FFmpeg's, a pool's) only sets a flag, and a main thread
blocked in a call (a user's plug-in whose ``step`` sleeps or waits; a wait on a pool's
results) never looks at it: Ctrl-C, however often repeated, did nothing, where SIGTERM (whose
default action needs no handler) ended the run. :func:`ctrl_c_ends_the_run` relays the signal:
a thread that hears every signal (``signal.set_wakeup_fd``) sends SIGINT to the main thread
itself when the handler has not run within half a second, which interrupts the blocking call
(``EINTR``) so that KeyboardInterrupt is raised where the main thread is, and the command
cleans up as on any Ctrl-C (a pool's workers ended, nothing published half-written). Where even
that cannot reach it (code that retries its call whatever the signal), the process ends after
a grace period with exit status 130; its pool workers end with it (``vdc.pool_workers``).
A second Ctrl-C while the first is being handled is ignored, so cleanup is not cut short.
A handler someone installed later (a capture's, which finishes its file) is left to decide.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

RELAY_AFTER_S = 0.5  # the main thread runs a pending handler within this when not blocked
GRACE_S = 5.0  # after the relay: then the process ends (exit status 130)
EXIT_INTERRUPTED = 130


@contextlib.contextmanager
def ctrl_c_ends_the_run(message: str = "interrupted") -> Iterator[None]:
    """Within the block, SIGINT raises KeyboardInterrupt in the main thread even when it is
    blocked in a call, or ends the process (``message`` on stderr, exit status 130) when it
    cannot be reached. Does nothing outside the main thread, or where SIGINT is ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous_handler = signal.getsignal(signal.SIGINT)
    if previous_handler in (signal.SIG_IGN, None):
        yield  # the caller chose not to be interrupted
        return
    handled = threading.Event()

    def on_sigint(signum: int, frame: Any) -> None:
        if handled.is_set():
            return  # a repeated Ctrl-C while the first one's KeyboardInterrupt is handled
        handled.set()
        raise KeyboardInterrupt

    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)  # the C handler must never block on it
    try:
        previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    except ValueError:  # not the main thread of the main interpreter
        os.close(read_fd)
        os.close(write_fd)
        yield
        return
    signal.signal(signal.SIGINT, on_sigint)
    main_ident = threading.main_thread().ident
    assert main_ident is not None

    def relay() -> None:
        while True:
            try:
                got = os.read(read_fd, 64)
            except OSError:
                return
            if not got:
                return  # the block ended: the pipe was closed
            if previous_fd >= 0:  # whoever listened before still hears every signal
                with contextlib.suppress(OSError):
                    os.write(previous_fd, got)
            if signal.SIGINT not in got or handled.is_set():
                continue
            if signal.getsignal(signal.SIGINT) is not on_sigint:
                continue  # a handler installed since (a capture's) decides what SIGINT does
            if handled.wait(RELAY_AFTER_S):
                continue
            # blocked in a call: SIGINT to the main thread itself interrupts it (EINTR)
            with contextlib.suppress(OSError, ValueError):
                signal.pthread_kill(main_ident, signal.SIGINT)
            if handled.wait(GRACE_S):
                continue
            # a call no signal interrupts: end here (pool workers end with this process)
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.write(f"{message}\n")
                sys.stderr.flush()
            os._exit(EXIT_INTERRUPTED)

    thread = threading.Thread(target=relay, name="vdc-ctrl-c-relay", daemon=True)
    thread.start()
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        signal.set_wakeup_fd(previous_fd)
        os.close(write_fd)  # the relay reads end-of-file and returns
        thread.join(timeout=1.0)
        if not thread.is_alive():  # else it still reads: leave its end open, not reused
            os.close(read_fd)

"""The live view: a Rerun viewer started for a capture (``spawn_viewer``) or one already
running (``--connect URL``), fed by its own recording stream beside the file's so that the
viewer can cost only itself. ``capture.recorder`` logs through ``Tee`` to both; together they
are the recorder modules, the only ones that write with the Rerun SDK.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from vdc.recording import RERUN_LOG

# the SDK's own log lines for a viewer that went away would repeat every batch: see
# capture/recorder.py, which sets the same before the SDK starts its logger
os.environ.setdefault("RUST_LOG", RERUN_LOG)
import rerun as rr
import rerun.blueprint as rrb

from vdc.errors import UserError
from vdc.recording import APP_ID


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def warn_line(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


def _reachable(host: str, port: int, timeout_s: float = 1.0) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


def spawn_viewer(
    memory_limit: str = "25%", warn: Callable[[str], None] = warn_line, wait_s: float = 5.0
) -> str | None:
    """Start a Rerun viewer listening on 127.0.0.1 only; return its gRPC URL, or None (with
    one warning) when it cannot start, e.g. on a machine without a display or GPU driver: the
    recording never depends on the live view."""
    exe = shutil.which("rerun")
    cmd = [exe] if exe else [sys.executable, "-m", "rerun_cli"]
    port = _free_port()
    try:
        proc = subprocess.Popen(
            [*cmd, "--bind", "127.0.0.1", "--port", str(port), "--memory-limit", memory_limit],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    except OSError as exc:
        warn(f"could not start a Rerun viewer ({exc.strerror}); recording to the file only")
        return None
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:  # until it listens (or dies: no display, no driver)
        if _reachable("127.0.0.1", port, 0.2):
            return f"rerun+http://127.0.0.1:{port}/proxy"
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    if proc.poll() is None:
        proc.kill()
    warn(
        f"the Rerun viewer did not start (exit status {proc.wait()}; no display or GPU driver?); "
        "recording to the file only"
    )
    return None


def check_live_url(url: str) -> tuple[str, int]:
    """The host and port of a viewer URL such as ``rerun+http://127.0.0.1:9876/proxy``;
    ValueError with the expected form when it is malformed (before anything is written)."""
    form = "expected rerun+http://HOST:PORT/proxy"
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("rerun+http", "rerun+https", "rerun") or not parts.hostname or not port:
        raise UserError(f"--connect {url!r} is not a Rerun viewer address; {form}.")
    try:
        rr.GrpcSink(url)  # the SDK's own parse, so what passes here also connects
    except (RuntimeError, ValueError) as exc:
        raise UserError(f"--connect {url!r}: {exc}; {form}.") from None
    return parts.hostname, port


class LiveView:
    """The optional second sink: a viewer. It can cost only itself.

    A separate recording stream (same application and recording id) so that a flush of the
    file never waits on, or fails with, the network. The viewer's port is probed at start and
    every ``probe_s`` seconds; when it does not answer, one warning is printed and the stream is
    dropped (its shutdown runs in a daemon thread, so the capture does not wait)."""

    def __init__(
        self,
        url: str,
        recording_id: str,
        blueprint: rrb.Blueprint | None,
        warn: Callable[[str], None] = warn_line,
        probe_s: float = 2.0,
    ) -> None:
        self.url = url
        self.host, self.port = check_live_url(url)
        self.warn = warn
        self.probe_s = probe_s
        self._last_probe = time.monotonic()
        self.stream: rr.RecordingStream | None = None
        if not _reachable(self.host, self.port):
            warn(f"no Rerun viewer answers at {url}; recording to the file only")
            return
        self.stream = rr.RecordingStream(APP_ID, recording_id=recording_id)
        self.stream.set_sinks(rr.GrpcSink(url), default_blueprint=blueprint)

    def check(self) -> None:
        """Probe the viewer at most every ``probe_s``; drop the stream if it has gone."""
        if self.stream is None or time.monotonic() - self._last_probe < self.probe_s:
            return
        self._last_probe = time.monotonic()
        if not _reachable(self.host, self.port):
            self.drop(f"the Rerun viewer at {self.url} went away; recording to the file only")

    def drop(self, message: str | None = None) -> None:
        stream, self.stream = self.stream, None
        if stream is None:
            return
        if message:
            self.warn(message)
        # disconnecting a gRPC sink waits for its final connection attempt: not on our time
        threading.Thread(target=stream.disconnect, daemon=True).start()

    def close(self) -> None:
        """End of the run: give a live viewer what is buffered (bounded), then let go."""
        if self.stream is None:
            return
        self.check()
        if self.stream is not None:
            try:
                self.stream.flush(timeout_sec=2.0)
            except RuntimeError:
                pass  # a slow viewer misses the tail of the live view; the file has it
            self.drop()


class Tee:
    """What the recorder logs with: the file stream first, then the live view if it is up."""

    def __init__(self, file_stream: rr.RecordingStream, live: LiveView | None) -> None:
        self.file = file_stream
        self.live = live

    def _each(self, method: str, *args: Any, **kwargs: Any) -> None:
        getattr(self.file, method)(*args, **kwargs)
        live = self.live
        if live is not None and live.stream is not None:
            try:
                getattr(live.stream, method)(*args, **kwargs)
            except Exception as exc:
                live.drop(f"the live view failed ({exc}); recording to the file only")

    def log(self, *args: Any, **kwargs: Any) -> None:
        self._each("log", *args, **kwargs)

    def send_columns(self, *args: Any, **kwargs: Any) -> None:
        self._each("send_columns", *args, **kwargs)

    def send_property(self, *args: Any, **kwargs: Any) -> None:
        self._each("send_property", *args, **kwargs)

"""A catalog query whose server fails under it: killed mid-query (a real ``catalog serve``
process, killed once a counted share of its answer has passed), or serving a recording cut
while it is served. Either ends in one line and exit status 2, never a traceback or a hang;
the Python function raises one :class:`UserError` line."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from analysis.catalog.query import query
from tests.helpers import assert_one_line_error, make_sim_recording, run_cli, spawn
from vdc.errors import UserError

pytest.importorskip("datafusion")  # the catalog's extra


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("served")
    make_sim_recording(folder / "a.rrd", tf_hz=1.0, seed=1)
    make_sim_recording(folder / "b.rrd", tf_hz=3.0, seed=2)
    return folder


class CountingProxy:
    """A TCP relay on 127.0.0.1 in front of the server, counting the bytes the server sent;
    ``when(n)`` is called with the running count as each piece passes (before it is relayed),
    so a test can act at a share of an answer without timing anything."""

    def __init__(self, upstream_port: int) -> None:
        self.upstream = upstream_port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.sent = 0
        self.when = lambda n: None
        self._lock = threading.Lock()
        self._sockets: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._start(self._accept)

    def _start(self, target, *args) -> None:
        t = threading.Thread(target=target, args=args, daemon=True)
        self._threads.append(t)
        t.start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:  # closed: the test is over
                return
            try:
                server = socket.create_connection(("127.0.0.1", self.upstream))
            except OSError:  # the server is gone: the client sees its connection closed
                client.close()
                continue
            self._sockets += [client, server]
            self._start(self._pump, client, server, False)
            self._start(self._pump, server, client, True)

    def _pump(self, src: socket.socket, dst: socket.socket, from_server: bool) -> None:
        while True:
            try:
                data = src.recv(65536)
            except OSError:
                data = b""
            if not data:
                try:
                    dst.shutdown(socket.SHUT_WR)
                except OSError:
                    pass
                return
            if from_server:
                with self._lock:
                    self.sent += len(data)
                    n = self.sent
                self.when(n)
            try:
                dst.sendall(data)
            except OSError:
                return

    def close(self) -> None:
        # shut down, then closed: a shutdown wakes a thread blocked in accept() or recv()
        for s in (self.listener, *self._sockets):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:  # not connected (any more)
                pass
            s.close()
        for t in self._threads:
            t.join(timeout=10)
        assert not any(t.is_alive() for t in self._threads)


def _serve(folder: Path) -> tuple[subprocess.Popen, int]:
    """``vdc-analyse catalog serve FOLDER`` as a user starts it; (process, port) once it
    says it serves. Its process group is ended after the test (tests/conftest.py)."""
    proc = spawn(
        [sys.executable, "-m", "analysis", "catalog", "serve", str(folder)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    lines = []
    for line in proc.stdout:  # ends if the server dies before it serves
        lines.append(line)
        if "serving until Ctrl-C" in line:
            url = next(ln.split()[-1] for ln in lines if ln.startswith("open it: rerun"))
            return proc, int(url.split("/dataset/")[0].rsplit(":", 1)[1])
    raise AssertionError(f"the server never served: {lines}")


@pytest.fixture
def proxied(recordings: Path) -> Iterator[tuple[subprocess.Popen, CountingProxy]]:
    proc, port = _serve(recordings)
    proxy = CountingProxy(port)
    try:
        yield proc, proxy
    finally:
        proxy.close()


def _kill_after(proc: subprocess.Popen, proxy: CountingProxy, share: float) -> list[int]:
    """Measure a whole query's answer through ``proxy`` (bytes the server sent), then arm it:
    the server's process group is killed (SIGKILL: no goodbye) once ``share`` of that many
    bytes of the next answer have passed. Returns the list the count at the kill lands in."""
    url = f"rerun+http://127.0.0.1:{proxy.port}"
    whole = query(url)  # the control: through the relay, the query works
    assert whole["frames"]["recording_id"].n_unique() == 2
    total, start = proxy.sent, proxy.sent
    killed: list[int] = []

    def when(n: int) -> None:
        if not killed and n - start >= share * total:
            killed.append(n - start)
            os.killpg(proc.pid, signal.SIGKILL)

    proxy.when = when
    return killed


@pytest.mark.parametrize("share", [0.05, 0.5])
def test_a_server_killed_mid_query_is_one_line(proxied, tmp_path: Path, share: float) -> None:
    """At 5 % of its answer the server dies while it lists the segments, at 50 % while it
    sends their chunks: one line, exit 2, nothing written."""
    proc, proxy = proxied
    killed = _kill_after(proc, proxy, share)
    url = f"rerun+http://127.0.0.1:{proxy.port}"
    out = tmp_path / "q"
    # the timeout only bounds the test were it to hang (the fault this guards against)
    res = run_cli("analysis", "catalog", "query", url, "--out", str(out), timeout=180)
    assert killed, "the server was never killed: the query needed less than the share"
    assert proc.wait(timeout=30) == -signal.SIGKILL  # really killed, mid-answer
    assert_one_line_error(res, url, "failed mid-query")
    assert not out.exists()


def test_the_python_function_raises_one_line_when_the_server_dies(proxied) -> None:
    proc, proxy = proxied
    killed = _kill_after(proc, proxy, 0.5)
    url = f"rerun+http://127.0.0.1:{proxy.port}"
    with pytest.raises(UserError, match="failed mid-query") as err:
        query(url)
    assert killed and "\n" not in str(err.value)


def test_a_recording_cut_while_served_is_one_line(recordings: Path, tmp_path: Path) -> None:
    """The server registered two whole recordings; one is then cut to half (a disk that filled,
    a copy overwritten) while it serves them."""
    folder = tmp_path / "served"
    shutil.copytree(recordings, folder)
    proc, port = _serve(folder)
    url = f"rerun+http://127.0.0.1:{port}"
    cut = folder / "a.rrd"
    os.truncate(cut, cut.stat().st_size // 2)
    out = tmp_path / "q"
    res = run_cli("analysis", "catalog", "query", url, "--out", str(out), timeout=180)
    assert_one_line_error(res, url, "failed mid-query", "read past end of file")
    assert not out.exists()
    with pytest.raises(UserError, match="read past end of file") as err:
        query(url)
    assert "\n" not in str(err.value)
    assert proc.poll() is None  # the server itself survives a recording it cannot read

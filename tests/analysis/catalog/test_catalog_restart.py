"""``catalog serve`` restarts at once on its own port: a connection the last server left in
TIME_WAIT does not make the port "taken"; a process listening on it still does."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from analysis.catalog.server import _require_free_port
from vdc.errors import UserError


def _time_wait_states(port: int) -> int:
    """Sockets on ``port`` in TIME_WAIT (state 06 in /proc/net/tcp), as the kernel lists them."""
    n = 0
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        local, state = fields[1], fields[3]
        if int(local.split(":")[1], 16) == port and state == "06":
            n += 1
    return n


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads /proc/net/tcp")
def test_a_port_left_in_time_wait_is_free_and_a_listened_one_taken() -> None:
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a real server does
    server.bind(("127.0.0.1", 0))
    port = server.getsockname()[1]
    server.listen()
    client = socket.create_connection(("127.0.0.1", port))
    conn, _ = server.accept()
    with pytest.raises(UserError, match=f"--port {port}: the port is taken"):
        _require_free_port("127.0.0.1", port, "--port")  # someone listens: taken
    conn.close()  # the server closes first (as one that crashed): its side goes to TIME_WAIT
    server.close()
    client.recv(1)  # the FIN arrived
    client.close()
    assert _time_wait_states(port) >= 1  # the state the fault needs is really there
    _require_free_port("127.0.0.1", port, "--port")  # free: a restart is not refused

"""A real headless browser for the web viewer's tests: Debian's Chromium, driven over the
DevTools protocol (the plain ``--screenshot`` switch shoots before the viewer has loaded)."""

from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

from tests.helpers import end_group

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def screenshot(
    url: str,
    out: Path,
    ready: Callable[[bytes], bool] = lambda _png: True,
    wait_s: float = 45.0,
    size: str = "1400,900",
) -> Path:
    """Open ``url`` in headless Chromium (software WebGL; every host but 127.0.0.1 blocked)
    and save a PNG of the page to ``out``: the first screenshot, taken every 2 s, that
    ``ready`` accepts, else the last one after ``wait_s`` seconds."""
    from websocket import create_connection

    assert CHROMIUM, "Chromium is not installed (Debian package chromium)"
    port = _free_port()
    profile = tempfile.mkdtemp(prefix="vdc-chromium-")
    proc = subprocess.Popen(
        [
            CHROMIUM,
            "--headless=new",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={profile}",
            f"--window-size={size}",
            f"--remote-debugging-port={port}",
            f"--remote-allow-origins=http://127.0.0.1:{port}",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
            "about:blank",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json"))
                page = next(p for p in pages if p.get("type") == "page")
                break
            except (OSError, StopIteration):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)
        ws = create_connection(page["webSocketDebuggerUrl"], timeout=60)
        ws.send(json.dumps({"id": 1, "method": "Page.navigate", "params": {"url": url}}))
        end, n = time.monotonic() + wait_s, 2
        while True:
            time.sleep(2.0)
            n += 1
            ws.send(json.dumps({"id": n, "method": "Page.captureScreenshot", "params": {}}))
            while True:
                msg = json.loads(ws.recv())
                if msg.get("id") == n:
                    break
            png = base64.b64decode(msg["result"]["data"])
            if ready(png) or time.monotonic() > end:
                break
        ws.close()
        out.write_bytes(png)
        return out
    finally:
        end_group(proc, grace_s=10)  # Chromium's renderer and GPU processes too
        shutil.rmtree(profile, ignore_errors=True)

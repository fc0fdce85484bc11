"""A catalog server onto folders of recordings (``vdc-analyse catalog serve``), and the web
viewer beside it; what it registers is :func:`analysis.catalog.build.scan`'s."""

from __future__ import annotations

import contextlib
import dataclasses
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

from analysis.catalog.build import (
    BASE,
    CATALOG_EXTRA,
    CatalogSettings,
    Found,
    _blueprint_file,
    _rerun_binary,
    is_catalog_url,
    scan,
)
from vdc.errors import UserError


def dataset_name(folders: Sequence[str | Path], settings: CatalogSettings) -> str:
    name = settings.dataset or Path(folders[0]).resolve().name or "vdc"
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


@dataclasses.dataclass
class Catalog:
    """A running catalog: the server's URL, the dataset and what was found."""

    url: str
    dataset: Any  # rerun.catalog.DatasetEntry
    name: str
    found: Found
    client: Any


def _require_catalog() -> Any:
    try:
        import datafusion  # noqa: F401 - the catalog's query engine  # lazy: optional extra
        import rerun as rr  # lazy: optional extra
    except ImportError:
        raise UserError(f"the catalog needs its extra: {CATALOG_EXTRA}") from None
    return rr


@contextlib.contextmanager
def open_catalog(
    folders: Sequence[str | Path],
    settings: CatalogSettings = CatalogSettings(),
    notice: Callable[[str], None] | None = None,
) -> Iterator[Catalog]:
    """Start a catalog server on ``settings.host`` and register the folders (see the module);
    the server stops when the block ends."""
    rr = _require_catalog()
    if settings.port:
        _require_free_port(settings.host, settings.port, "--port")
    found = scan(folders, notice)
    if not found.segments:
        raise UserError(f"no vdc recording found under {', '.join(map(str, folders))}.")
    name = dataset_name(folders, settings)
    with rr.server.Server(host=settings.host, port=settings.port or None) as srv:
        client = srv.client()
        ds = client.create_dataset(name)
        ds.register([s.path.resolve().as_uri() for s in found.segments], layer_name=BASE).wait()
        for layer, files in found.layers.items():
            if files:
                ds.register([p.resolve().as_uri() for _, p in files], layer_name=layer).wait()
        ds.register_blueprint(_blueprint_file(found).resolve().as_uri())
        yield Catalog(srv.url(), ds, name, found, client)


def serve(
    folders: Sequence[str | Path],
    settings: CatalogSettings = CatalogSettings(),
    ready: Callable[[Catalog, str | None], None] | None = None,
    notice: Callable[[str], None] | None = None,
    stop: Callable[[], bool] | None = None,
) -> None:
    """``vdc-analyse catalog serve``: register the folders and serve them until Ctrl-C or
    SIGTERM (or ``stop()`` returns True); ``ready`` gets the catalog and the web viewer's
    address (None without ``settings.web``). Every process started is ended on the way out."""

    if any(is_catalog_url(f) for f in folders):
        raise UserError("serve registers folders; a catalog URL is served already (query it).")

    def end(signum: int, _frame: Any) -> None:
        raise KeyboardInterrupt

    if settings.web and settings.web_port:  # said before anything starts or is announced
        _require_free_port(settings.host, settings.web_port, "--web-port")
    previous = signal.signal(signal.SIGTERM, end)
    web = None
    try:
        with open_catalog(folders, settings, notice) as cat:
            web_url = None
            if settings.web:
                web, web_url = _web_viewer(dataset_url(cat), settings)
            if ready is not None:
                ready(cat, web_url)
            while stop is None or not stop():
                time.sleep(0.2)
                if web is not None and web.poll() is not None:
                    raise UserError("the web viewer ended unexpectedly.")
    except KeyboardInterrupt:
        pass
    finally:
        if web is not None:
            _end(web)
        signal.signal(signal.SIGTERM, previous)


def _require_free_port(host: str, port: int, flag: str) -> None:
    """UserError, in one line, if another process holds ``port`` on ``host`` (checked before
    anything is started or announced)."""

    with socket.socket() as s:
        # as the servers' own listeners do: a connection of a server that just ended, left in
        # TIME_WAIT, does not hold the port (without it a restart at once was refused); a
        # process listening on it still does
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            raise UserError(
                f"{flag} {port}: the port is taken on {host} ({exc.strerror or exc}); choose "
                "another, or 0 for a free one."
            ) from None


def _free_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _web_viewer(url: str, settings: CatalogSettings) -> tuple[subprocess.Popen, str]:
    """The web viewer (the ``rerun`` binary) onto the catalog, bound to ``settings.host``;
    returns the process and the address to open. It is ended with this process however this
    one ends: by :func:`serve` on the way out, and by the kernel (``setpriv --pdeathsig``,
    where util-linux has it) if this process is killed outright."""

    if settings.web_port:
        _require_free_port(settings.host, settings.web_port, "--web-port")
    port = settings.web_port or _free_port(settings.host)
    cmd = [
        _rerun_binary(),
        "--serve-web",
        "--bind",
        settings.host,
        "--web-viewer-port",
        str(port),
        url,
    ]
    if shutil.which("setpriv"):
        cmd = ["setpriv", "--pdeathsig", "SIGTERM", "--", *cmd]
    log = tempfile.TemporaryFile()  # its messages, read only if it fails to start
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            log.seek(0)
            raise UserError(f"the web viewer did not start: {log.read().decode()[-300:]}")
        with contextlib.suppress(OSError), socket.create_connection((settings.host, port), 0.5):
            break
        time.sleep(0.2)

    return proc, f"http://{settings.host}:{port}/?url={quote(url, safe='')}"


def dataset_url(cat: Catalog) -> str:
    """The dataset's page on the running server (its id is new at every start: links in
    reports name the dataset and segment instead)."""
    return f"{cat.url}/dataset/{cat.dataset.id}"


def _end(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()

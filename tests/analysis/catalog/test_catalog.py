"""Many recordings as one Rerun dataset: a real catalog server on 127.0.0.1, recordings as
segments, analysis outputs as layers, one reader() call that gives the tables `tables` writes,
files refused in one line, and a server that ends with its signal."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import polars as pl
import pytest
import rerun as rr

from analysis.batch import BatchSettings, batch
from analysis.catalog.build import CatalogSettings
from analysis.catalog.query import query, segment_table
from analysis.catalog.server import open_catalog
from analysis.compare import CompareSettings, compare
from analysis.complexity.command import ComplexitySettings, complexity
from analysis.recordings.reader import Recording, RecordingError
from analysis.recordings.recompute import TablesSettings, tables
from tests.browser import CHROMIUM
from tests.helpers import assert_one_line_error, make_sim_recording, run_cli, spawn
from tests.in_process import run_in_process
from vdc.errors import UserError


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> dict[str, Path]:
    """Two profiling runs, a collision run, a capture cut short, the outputs of compare,
    batch and complexity on them, and two files that must be refused."""
    root = tmp_path_factory.mktemp("campaign")
    rec = root / "recordings"
    paths = {
        "tf0": make_sim_recording(rec / "tf0.rrd", tf_hz=0.0, seed=1),
        "tf3": make_sim_recording(rec / "tf3.rrd", tf_hz=3.0, seed=2),
        "crash": make_sim_recording(rec / "col.rrd", 0.3, behaviour="collision", tf_hz=3.0, seed=3),
    }
    cut = make_sim_recording(root / "whole.rrd", tf_hz=1.0, seed=4)
    data = cut.read_bytes()
    (rec / "cut.rrd").write_bytes(data[: int(len(data) * 0.6)])  # a copy that stopped early
    cut.unlink()
    profile = [paths["tf0"], paths["tf3"]]
    compare(paths["tf3"], CompareSettings(models=("avdm", "avdm:beta=0.5")), root / "cmp")
    batch(profile, BatchSettings(models=("avdm-on",), jobs=1), root / "bt")
    complexity([paths["tf3"]], ComplexitySettings(), root / "cx")  # one source: its .rrd too
    other = rr.RecordingStream("another_app", recording_id="theirs")
    other.save(str(rec / "theirs.rrd"))
    other.send_columns(
        "/x",
        indexes=[rr.TimeColumn("frame", sequence=np.arange(5))],
        columns=rr.Scalars.columns(scalars=np.arange(5.0)),
    )
    other.flush()
    other.disconnect()
    stamped = rr.RecordingStream("vdc", recording_id="stamped")
    stamped.save(str(rec / "stamped.rrd"))
    stamped.send_columns(
        "/x",
        indexes=[rr.TimeColumn("frame", timestamp=np.arange(5) * 1e9)],
        columns=rr.Scalars.columns(scalars=np.arange(5.0)),
    )
    stamped.flush()
    stamped.disconnect()
    return {"root": root, **paths}


def test_segments_layers_and_what_is_refused(campaign) -> None:
    with open_catalog([campaign["root"]]) as cat:
        assert cat.url.startswith("rerun+http://127.0.0.1:")
        seg = segment_table(cat)
        names = rr.catalog.CatalogClient(cat.url).dataset_names()
    assert cat.name in names
    assert seg.height == 4  # three runs and the repaired copy
    by_id = {r["recording_id"]: r for r in seg.iter_rows(named=True)}
    cut = [r for r in by_id.values() if r["repaired"]]
    assert len(cut) == 1 and not cut[0]["complete"] and cut[0]["frames"] > 0
    col = next(r for r in by_id.values() if r["behaviour"] == "collision")
    assert col["success_rate"] == col["avoidances"] / (col["avoidances"] + col["crashes"])
    for r in by_id.values():
        assert r["source"] == "simulation" and r["scene"] == "grating" and r["model"]
    # the headline numbers are the `tables` summary's (one wall TF: one summary row)
    t = tables([campaign["tf3"]], TablesSettings()).summary.row(0, named=True)
    row = by_id[t["recording_id"]]
    assert row["mean_omega_dps"] == pytest.approx(t["mean"], rel=1e-12)
    assert row["frac_over_100"] == pytest.approx(t["frac_over_100"], abs=1e-12)
    assert row["tf_schedule"] == "3:3s" and row["seed"] == 2
    layers = set(row["layers"])
    assert {"base", "summary", "compare-cmp", "complexity-cx", "batch-avdm-on"} <= layers
    refused = dict(cat.found.unregistered)
    assert "another application" in refused[str(campaign["root"] / "recordings" / "theirs.rrd")]
    assert "not a frame count" in refused[str(campaign["root"] / "recordings" / "stamped.rrd")]


def test_one_query_gives_the_tables_that_tables_and_batch_write(campaign) -> None:
    q = query([campaign["root"]], where={"behaviour": "profile", "repaired": "false"})
    runs = [campaign["tf0"], campaign["tf3"]]
    ref = tables(runs, TablesSettings())
    assert q["frames"].equals(ref.frames)  # poses, wall TF, turning flags: bit for bit
    mo = q["model_outputs"]
    online = mo.filter(pl.col("model") == "avdm").select(ref.model_outputs.columns)
    assert online.equals(ref.model_outputs)
    # batch's variant, as batch wrote it
    bt = pl.read_parquet(campaign["root"] / "bt" / "model_outputs.parquet")
    on = mo.filter(pl.col("model") == "avdm-on").select(bt.columns)
    assert on.equals(bt.sort("recording_id", "model", "frame"))
    # compare's variant of one recording: the recomputation `tables --model` writes
    rec = tables([campaign["tf3"]], TablesSettings(models=("avdm:beta=0.5",)))
    beta = mo.filter(pl.col("model") == "avdm:beta=0.5").select(rec.model_outputs.columns)
    assert beta.equals(rec.model_outputs)
    only = query([campaign["root"]], where={"seed": "2"}, layers=[])
    assert set(only["frames"]["recording_id"]) == {ref.frames["recording_id"][-1]}
    assert set(only["model_outputs"]["model"]) == {"avdm"}  # no layer: the online model only


def _wait_for(proc, needle: str, timeout_s: float = 120.0) -> list[str]:
    lines: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.strip())
        if needle in line:
            return lines
    raise AssertionError(f"no {needle!r} in {lines}; stderr: {proc.stderr.read()[-2000:]}")


def _listening(host: str, port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex((host, port)) == 0


def _serve(campaign) -> tuple:
    """Start ``vdc-analyse catalog serve --web`` as a user would; (process, dataset URL parts,
    web viewer address) once it says it serves."""
    from urllib.parse import urlsplit

    proc = spawn(
        [sys.executable, "-m", "analysis", "catalog", "serve", str(campaign["root"]), "--web"],
        stdout=-1,
        stderr=-1,
        text=True,
    )
    lines = _wait_for(proc, "serving until Ctrl-C")
    url = urlsplit(next(ln.split()[-1] for ln in lines if ln.startswith("open it: rerun")))
    web = next(ln.split()[-1] for ln in lines if ln.startswith("web viewer:"))
    return proc, url, web


def test_serve_until_sigterm_on_loopback_only(campaign) -> None:
    """Both servers on 127.0.0.1 only, the dataset there, and nothing left after SIGTERM."""
    from urllib.parse import urlsplit

    proc, url, web = _serve(campaign)
    host, port, web_port = url.hostname, url.port, urlsplit(web).port
    assert url.path.startswith("/dataset/")  # opens on the dataset's segment table
    assert host == "127.0.0.1" and _listening(host, port) and _listening(host, web_port)
    other = socket.gethostbyname(socket.gethostname())  # the machine's other address
    if not other.startswith("127."):
        assert not _listening(other, port) and not _listening(other, web_port)
    client = rr.catalog.CatalogClient(f"rerun+http://{host}:{port}")
    assert len(client.get_dataset(client.dataset_names()[0]).segment_ids()) == 4
    os.kill(proc.pid, signal.SIGTERM)
    assert proc.wait(timeout=20) == 0
    assert not _listening(host, port) and not _listening(host, web_port)


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (.ci/run installs it)")
def test_the_web_viewer_shows_the_dataset_in_a_real_browser(campaign, tmp_path: Path) -> None:
    from tests.browser import screenshot

    def drawn(png: bytes) -> bool:
        """Not blank: the viewer drew its panels and the segment table (many distinct colours
        and strong contrast; a blank or loading page has a handful of greys)."""
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        return img.std() > 20 and len(np.unique(img.reshape(-1, 3), axis=0)) > 200

    proc, _url, web = _serve(campaign)
    shot = screenshot(web, tmp_path / "web.png", ready=drawn)
    assert drawn(shot.read_bytes()) and cv2.imread(str(shot)).shape[0] > 500
    # killed outright (no clean-up of its own): the kernel ends its web viewer with it
    from urllib.parse import urlsplit

    web_port = urlsplit(web).port
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=20)
    deadline = time.monotonic() + 15
    while _listening("127.0.0.1", web_port) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _listening("127.0.0.1", web_port)


def test_a_catalog_already_serving_is_queried_by_its_url(campaign, tmp_path: Path) -> None:
    """A lab's shared server: ``catalog serve`` in one process, ``catalog query URL`` (and
    ``vdc.catalog.query(URL)``) in another give the tables a query by folder gives."""
    import vdc.catalog

    where = {"behaviour": "profile", "repaired": "false"}
    by_folder = query([campaign["root"]], where=where)
    proc = spawn(
        [sys.executable, "-m", "analysis", "catalog", "serve", str(campaign["root"])],
        stdout=-1,
        stderr=-1,
        text=True,
    )
    try:
        lines = _wait_for(proc, "serving until Ctrl-C")
        dataset = next(ln.split()[-1] for ln in lines if ln.startswith("open it: rerun"))
        url = dataset.split("/dataset/")[0]
        by_url = vdc.catalog.query(url, where=where)
        assert by_url["frames"].equals(by_folder["frames"])
        cols = by_folder["model_outputs"].columns
        assert by_url["model_outputs"].select(cols).equals(by_folder["model_outputs"])
        out = tmp_path / "q"
        cli = run_cli("analysis", "catalog", "query", url, "--where", "seed=2", "--out", str(out))
        assert cli.returncode == 0, cli.stderr
        assert pl.read_parquet(out / "frames.parquet")["recording_id"].n_unique() >= 1
        bad = run_cli("analysis", "catalog", "query", url, "--layer", "bt", "--out", str(out))
        assert_one_line_error(bad, "--layer")
    finally:
        os.kill(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)
    gone = run_cli("analysis", "catalog", "query", url, "--out", str(tmp_path / "g"))
    assert_one_line_error(gone, "no catalog answers at")


def test_bad_catalog_input_is_one_line(tmp_path: Path) -> None:
    proc = run_cli("analysis", "catalog", "serve", str(tmp_path / "missing"))
    assert_one_line_error(proc, "is not a folder")
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = run_cli("analysis", "catalog", "query", str(empty))
    assert_one_line_error(proc, "no vdc recording found")


@pytest.mark.parametrize("flag, value", [("--port", "99999"), ("--web-port", "70000")])
def test_a_port_outside_the_tcp_range_is_refused_at_the_door(tmp_path, flag, value) -> None:
    """A port past 65535 reached the socket's bind() as a traceback; now the parser and the
    Python settings refuse it in one line."""
    proc = run_in_process("analysis", "catalog", "serve", str(tmp_path), "--web", flag, value)
    assert_one_line_error(proc, flag, value, "65535")
    field = flag.removeprefix("--").replace("-", "_")
    with pytest.raises(UserError, match=f"CatalogSettings.{field}: a port is 1 to 65535"):
        CatalogSettings(**{field: int(value)})


def test_a_where_that_names_no_property_is_one_line(campaign, tmp_path: Path) -> None:
    proc = run_cli(
        "analysis",
        "catalog",
        "query",
        str(campaign["root"]),
        "--where",
        "colour=blue",
        "--out",
        str(tmp_path / "q"),
    )
    # the notes on the refused files come first; the error is one line, no traceback
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ": error: " in ln]
    assert len(errors) == 1 and "--where colour: no such property" in errors[0]
    settings = CatalogSettings(where=("seed",))
    with pytest.raises(Exception, match="KEY=VALUE"):
        settings.where_dict()


@pytest.fixture(scope="module")
def intact_and_cut(tmp_path_factory) -> tuple[Path, bytes]:
    """A 30-s profiling run and its first 60 % (a copy that stopped early): the cut part holds
    no poses yet, so it cannot be served at all."""
    root = tmp_path_factory.mktemp("cutcopy")
    run = make_sim_recording(root / "run.rrd", 0.5, tf_hz=1.0, seed=4)
    data = run.read_bytes()
    return run, data[: int(len(data) * 0.6)]


@pytest.mark.parametrize("cut_name", ["a_cut.rrd", "z_cut.rrd"])  # sorts first, then last
def test_a_cut_copy_never_sinks_the_intact_recording(intact_and_cut, cut_name, tmp_path) -> None:
    run, cut_bytes = intact_and_cut
    folder = tmp_path / "runs"
    folder.mkdir()
    intact = folder / "run.rrd"
    intact.write_bytes(run.read_bytes())
    (folder / cut_name).write_bytes(cut_bytes)
    notes: list[str] = []
    q = query([folder], notice=notes.append)
    whole = tables([intact], TablesSettings())
    assert q["frames"].equals(whole.frames)  # the intact recording is served, all of it
    assert notes == [
        f"not registered: {folder / cut_name}: the same recording as {str(intact)!r} "
        f"(id {whole.frames['recording_id'][0]})"
    ]
    # the cut copy alone: left out in one note naming the user's file, not a cache copy
    intact.unlink()
    proc = run_cli("analysis", "catalog", "query", str(folder), "--out", str(tmp_path / "q"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 2 and "cache" not in proc.stderr, proc.stderr
    assert lines[0].endswith(
        f"not registered: {folder / cut_name}: holds neither poses nor frame timing nor model "
        "outputs (it has no footer: the capture was cut short)"
    )
    assert "no vdc recording found" in lines[1]


def test_a_query_names_each_recording_it_left_out_and_why(intact_and_cut, tmp_path) -> None:
    """A recording cut after its first properties but before it described its run (no
    ``run`` properties) was left out of a query without a word; now its result and its
    output name it."""
    run, _ = intact_and_cut
    folder = tmp_path / "runs"
    folder.mkdir()
    (folder / "run.rrd").write_bytes(run.read_bytes())
    other = make_sim_recording(tmp_path / "other.rrd", tf_hz=3.0, seed=5).read_bytes()
    early = folder / "early.rrd"
    for percent in range(5, 60, 2):  # the first cut that holds properties, but no run yet
        early.write_bytes(other[: len(other) * percent // 100])
        with contextlib.suppress(RecordingError):
            props = Recording(early).properties()
            if props and "run" not in props:
                break
    else:
        pytest.fail("no cut of the recording holds properties without its run")
    notes: list[str] = []
    q = query([folder], notice=notes.append)
    why = "holds no description of its run (no 'run' properties) (it has no footer: the "
    why += "capture was cut short)"
    assert q["left_out"].rows() == [(str(early), why)]
    assert notes == [f"not registered: {early}: {why}"]
    assert q["frames"]["recording_id"].n_unique() == 1  # the intact one, served
    out = tmp_path / "q"
    proc = run_cli("analysis", "catalog", "query", str(folder), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert f"not registered: {early}: {why}" in proc.stderr
    assert pl.read_parquet(out / "left_out.parquet").rows() == [(str(early), why)]
    assert "left_out" in proc.stdout


def test_query_says_it_repaired_a_recording_without_footer(campaign) -> None:
    notes: list[str] = []
    q = query([campaign["root"]], where={"repaired": "true"}, layers=[], notice=notes.append)
    assert q["frames"].height > 0
    repaired = [n for n in notes if "has no footer" in n]
    assert repaired == [
        f"{campaign['root'] / 'recordings' / 'cut.rrd'} has no footer (the capture was cut "
        "short): registered a repaired copy of its complete messages (marked repaired)."
    ]


def test_a_web_port_another_process_holds_is_said_before_anything_starts(campaign) -> None:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        proc = run_cli(
            "analysis",
            "catalog",
            "serve",
            str(campaign["root"]),
            "--web",
            "--web-port",
            str(port),
            timeout=120,
        )
    assert_one_line_error(proc, f"--web-port {port}: the port is taken on 127.0.0.1")
    assert "web viewer:" not in proc.stdout  # never announced

"""The Dask executor on a real ``distributed.LocalCluster`` (127.0.0.1, 2 worker processes of
one thread): batch analysis and campaigns on an existing cluster (by address and by scheduler
file), a cluster vdc starts itself, and a worker killed mid-run (the ``dask`` extra)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from urllib.parse import urlparse

import distributed  # the dask extra; the test extra brings it
import polars as pl
import pytest

from tests.helpers import ROOT, flags, kill_a_worker_mid_batch, run_cli
from vdc.executors import ExecutorSettings, open_executor

pytestmark = pytest.mark.dask  # the dask extra's test group: pytest -m dask

MODELS = ("avdm", "avdm:beta=0.5", "avdm:tw=6", "lgmd-plus")
TABLES = ("frames", "model_outputs", "events", "summary")


def _models(models=MODELS) -> list[str]:
    return [a for m in models for a in ("--model", m)]


@pytest.fixture(scope="module")
def cluster():
    """Two single-threaded worker processes on loopback, closed at the end of the module
    (even when a test fails)."""
    with (
        distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        ) as c,
        distributed.Client(c) as client,
    ):
        yield c, client


def _hosts(client) -> set[str]:
    info = client.scheduler_info()
    addrs = [info["address"], *info["workers"]]
    return {urlparse(a).hostname for a in addrs}


def test_batch_on_an_existing_cluster_by_address_and_by_scheduler_file(
    cluster, recordings, tmp_path: Path
) -> None:
    c, _client = cluster
    recs = [str(recordings[k]) for k in ("tf3_a", "tf3_b")]
    models = _models(MODELS[:2])
    out = tmp_path / "b"
    by_address = run_cli(
        "analysis",
        "batch",
        *recs,
        *models,
        *flags("--shard 0/2", out=out, scheduler=c.scheduler_address),
    )
    assert by_address.returncode == 0, by_address.stderr
    assert f"to run on Dask at {c.scheduler_address}" in by_address.stderr
    sfile = tmp_path / "scheduler.json"  # what `dask scheduler --scheduler-file` writes
    sfile.write_text(json.dumps({"address": c.scheduler_address}))
    by_file = run_cli(
        "analysis",
        "batch",
        *recs,
        *models,
        *flags("--shard 1/2", out=out, scheduler=sfile),
    )
    assert by_file.returncode == 0, by_file.stderr
    assert "2 tasks (shard 1/2): 0 already done" in by_file.stderr
    assert run_cli("analysis", "summarise", str(out)).returncode == 0
    ref = run_cli("analysis", "tables", *recs, *models, "--out", str(tmp_path / "t"))
    assert ref.returncode == 0, ref.stderr
    for name in TABLES:  # the same code on the same machine: the same rows as `tables`
        a = pl.read_parquet(out / f"{name}.parquet")
        assert a.equals(pl.read_parquet(tmp_path / "t" / f"{name}.parquet")), name


def test_a_cluster_vdc_starts_listens_on_loopback_only(recordings, tmp_path: Path) -> None:
    with open_executor(ExecutorSettings("dask", jobs=2), n_tasks=4) as (ex, client):
        assert _hosts(client) == {"127.0.0.1"}
        assert urlparse(client.dashboard_link).hostname == "127.0.0.1"
        assert len(client.scheduler_info()["workers"]) == 2
        assert ex.submit(os.getpid).result() != os.getpid()  # a worker process
        info = client.scheduler_info()
        assert all(w["nthreads"] == 1 for w in info["workers"].values())
    assert client.status == "closed"
    # and through the command line: the same tables as the local pool
    rec = str(recordings["tf3_a"])
    proc = run_cli(
        "analysis",
        "batch",
        rec,
        *_models(MODELS[:2]),
        *flags("--executor dask --jobs 2", out=tmp_path / "d"),
    )
    assert proc.returncode == 0, proc.stderr
    assert "local Dask cluster on 127.0.0.1, dashboard http://127.0.0.1:" in proc.stderr
    local = run_cli("analysis", "batch", rec, *_models(MODELS[:2]), "--out", str(tmp_path / "l"))
    assert local.returncode == 0, local.stderr
    for name in TABLES:
        a = pl.read_parquet(tmp_path / "d" / f"{name}.parquet")
        assert a.equals(pl.read_parquet(tmp_path / "l" / f"{name}.parquet")), name


def test_a_killed_dask_worker_loses_no_part_and_the_run_completes(
    cluster, recordings, tmp_path: Path
) -> None:
    """SIGKILL a worker process mid-run: its nanny starts a new one, the scheduler gives its
    tasks to the workers alive, every part is whole, and a re-run finds all done."""
    c, client = cluster
    pids = client.run(os.getpid)  # {worker address: pid}
    recs = [str(recordings[k]) for k in ("phases", "tf3_a", "tf3_b")]
    out = tmp_path / "b"
    rc, stdout, stderr, killed = kill_a_worker_mid_batch(
        [*recs, *_models(), "--scheduler", c.scheduler_address],
        out,
        lambda _batch_pid: next(iter(pids.values())),
        total=12,
    )
    assert rc == 0, stderr
    assert "12 tasks: 0 already done, 12 to run" in stderr
    assert "0 failed" in stdout
    for part in out.glob("parts/**/*.parquet"):
        pl.read_parquet(part)  # whole: written to a temporary name, then renamed
    # a temporary file left, if any, is the killed worker's own (SIGKILL mid-write), never
    # read as a part (the parts are *.parquet)
    left = [p.name for p in out.glob("parts/**/*.partial-*")]
    assert all(name.endswith(f".partial-{killed}") for name in left), left
    again = run_cli("analysis", "batch", *recs, *_models(), "--out", str(out))
    assert again.returncode == 0 and "12 already done, 0 ran" in again.stdout
    # the nanny replaced the worker: the cluster has two again, the killed pid is gone
    client.wait_for_workers(2, timeout=60)
    assert killed not in client.run(os.getpid).values()


def test_campaigns_run_on_the_cluster(cluster, tmp_path: Path) -> None:
    c, _client = cluster
    out = tmp_path / "sweep"
    proc = run_cli(
        "capture",
        "campaign",
        "behaviour=collision",
        "minutes=0.1",
        "tf_hz=0,3",
        *flags("--quiet", out=out, scheduler=c.scheduler_address),
    )
    assert proc.returncode == 0, proc.stderr
    assert "2 runs: 0 already done, 2 recorded, 0 failed" in proc.stdout
    runs = pl.read_parquet(out / "runs.parquet")
    assert runs["complete"].all() and runs["tf_hz"].to_list() == [0.0, 3.0]
    study = run_cli(
        "analysis",
        "collision-study",
        *flags("--minutes 0.1 --seeds 1", out=tmp_path / "cs", scheduler=c.scheduler_address),
    )
    assert study.returncode == 0, study.stderr
    assert "on Dask at" in study.stderr and "[5/5]" in study.stderr
    summary = pl.read_parquet(tmp_path / "cs" / "collision_summary.parquet")
    assert summary.height == 5


def test_a_collection_profiled_on_the_cluster_into_a_new_folder(cluster, tmp_path: Path) -> None:
    """``complexity`` on Dask into an --out that does not exist yet: the workers are asked
    whether they see it, so it is made first (it failed 'cannot see ...')."""
    from tests.helpers import write_pan  # lazy: PyAV's encoder, this test only

    c, _client = cluster
    clips = [str(write_pan(tmp_path / f"c{i}.mp4", 64, 48, 6, step_px=2 + i)) for i in range(2)]
    out = tmp_path / "new" / "profiles"
    proc = run_cli(
        "analysis", "complexity", *clips, "--metrics", "si_p910,ti_p910", "--out", str(out),
        "--scheduler", c.scheduler_address,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert pl.read_parquet(out / "clips.parquet").height == 2


def _tls_files(folder: Path) -> dict[str, Path]:
    """A CA of our own and one certificate it signed (for 127.0.0.1), as PEM files."""
    import datetime as dt
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = dt.datetime.now(dt.UTC)

    def cert(subject: str, key, issuer: str, issuer_key, ca: bool) -> x509.Certificate:
        b = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
            .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, issuer)]))
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
        )
        if not ca:
            san = [x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.DNSName("localhost")]
            b = b.add_extension(x509.SubjectAlternativeName(san), critical=False)
        return b.sign(issuer_key, hashes.SHA256())

    ca_key, node_key = (
        ec.generate_private_key(ec.SECP256R1()),
        ec.generate_private_key(ec.SECP256R1()),
    )
    files = {"ca": folder / "ca.pem", "cert": folder / "node.pem", "key": folder / "node.key"}
    pem = serialization.Encoding.PEM
    files["ca"].write_bytes(
        cert("vdc test CA", ca_key, "vdc test CA", ca_key, True).public_bytes(pem)
    )
    files["cert"].write_bytes(
        cert("node", node_key, "vdc test CA", ca_key, False).public_bytes(pem)
    )
    files["key"].write_bytes(
        node_key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    return files


def test_a_tls_cluster_takes_dasks_own_configuration(recordings, tmp_path: Path) -> None:
    """The TLS recipe of docs/guides/clusters.md: vdc passes no security object, so Dask's
    configuration (here its environment variables) gives the client its certificate; without
    it, one line."""
    from distributed.security import Security

    f = _tls_files(tmp_path)
    parties = ("scheduler", "worker", "client")
    sec = Security(
        tls_ca_file=str(f["ca"]),
        require_encryption=True,
        # the one certificate and key for the scheduler, the workers and the client
        **{f"tls_{who}_{part}": str(f[part]) for who in parties for part in ("cert", "key")},
    )
    rec = str(recordings["tf3_a"])
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
        protocol="tls",
        security=sec,
    ) as c:
        assert c.scheduler_address.startswith("tls://127.0.0.1:")
        args = ["batch", rec, "--model", "avdm", "--scheduler", c.scheduler_address]
        plain = run_cli("analysis", *args, "--out", str(tmp_path / "no"), timeout=120)
        # after the plan's line, one error line, no traceback
        assert plain.returncode == 2 and "Traceback" not in plain.stderr
        assert plain.stderr.splitlines()[-1].startswith(
            f"vdc-analyse batch: error: cannot reach the Dask scheduler {c.scheduler_address}: TLS"
        )
        env = {
            "DASK_DISTRIBUTED__COMM__TLS__CA_FILE": str(f["ca"]),
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT": str(f["cert"]),
            "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY": str(f["key"]),
            "DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION": "True",
        }
        proc = subprocess.run(
            [sys.executable, "-m", "analysis", *args, "--out", str(tmp_path / "tls")],
            capture_output=True,
            text=True,
            cwd=ROOT,
            env={**os.environ, **env},
            timeout=300,
        )
        assert proc.returncode == 0, proc.stderr
        assert "1 tasks: 0 already done, 1 ran, 0 failed" in proc.stdout

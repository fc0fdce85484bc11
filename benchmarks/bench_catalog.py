"""Registering many recordings in the catalog: seconds, not minutes.

Run: ``python benchmarks/bench_catalog.py [--n 500]``. Records ``n`` short simulated runs
(6 s each, as a campaign's grid would hold hundreds) into a temporary folder, then times
``vdc-analyse catalog``'s steps: the first scan (every recording opened, checked and
summarised into its summary layer, cached), a second scan (the cache used), and the catalog
server's registration of the segments and their summary layers; beside them, the plain
reference: registering the same files with Rerun's own server and nothing else.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import rerun as rr

from analysis.catalog.build import CatalogSettings, scan
from analysis.catalog.server import open_catalog
from capture.sim import SimSettings, record_sim


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500, help="recordings (default: %(default)s)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["VDC_CACHE_DIR"] = str(Path(tmp) / "cache")  # a cold cache of its own
        folder = Path(tmp) / "campaign"
        t0 = time.perf_counter()
        for i in range(args.n):
            settings = SimSettings(tf_hz=float(i % 4), minutes=0.1, seed=i)
            record_sim(settings, folder / f"run{i:04d}.rrd")
        print(f"recorded {args.n} runs in {time.perf_counter() - t0:.0f} s (setup, not timed)")
        t0 = time.perf_counter()
        scan([folder])
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        scan([folder])
        warm = time.perf_counter() - t0
        t0 = time.perf_counter()
        with open_catalog([folder], CatalogSettings()) as cat:
            served = time.perf_counter() - t0
            assert len(cat.dataset.segment_ids()) == args.n
        files = [p.resolve().as_uri() for p in sorted(folder.glob("*.rrd"))]
        t0 = time.perf_counter()
        with rr.server.Server(host="127.0.0.1", port=0) as srv:
            srv.client().create_dataset("plain").register(files).wait()
            plain = time.perf_counter() - t0
    print(f"first scan of {args.n} recordings (summaries computed): {cold:.1f} s")
    print(f"second scan (summaries cached):                  {warm:.1f} s")
    print(f"catalog up, {args.n} segments + summary layers:     {served:.1f} s")
    print(f"reference: Rerun's server registering the files: {plain:.1f} s")


if __name__ == "__main__":
    main()

"""vdc.show: a recording or a catalog segment in Rerun's notebook widget, its code served
from this machine (offline labs): never fetched from app.rerun.io."""

from __future__ import annotations

import urllib.request
from pathlib import Path

import vdc
from tests.helpers import make_sim_recording


def test_show_a_recording_and_a_segment_with_locally_served_assets(tmp_path: Path) -> None:
    rec = make_sim_recording(tmp_path / "run.rrd", seed=3)
    viewer = vdc.show(rec, height=400)
    import rerun_notebook

    assert rerun_notebook.ESM_MOD.startswith("http://localhost:")  # served here, not fetched
    with urllib.request.urlopen(rerun_notebook.ESM_MOD, timeout=30) as r:
        assert r.status == 200 and len(r.read()) > 100_000  # the widget's JavaScript
    assert type(viewer).__name__ == "Viewer"
    with vdc.catalog.open_catalog([tmp_path]) as cat:
        seg = cat.dataset.segment_ids()[0]
        assert type(vdc.show(cat, seg)).__name__ == "Viewer"

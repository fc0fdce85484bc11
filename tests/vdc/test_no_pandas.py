"""vdc's own processes (its commands, its pool workers) never import pandas for pyarrow's
sake (``vdc.no_pandas``): pyarrow imported it on its first list conversion, 0.25 s of CPU
each, where the extras install it. An explicit use (``to_pandas``) still works. The import
is seen from outside: ``python -X importtime`` lists every module a process loaded."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.helpers import ROOT

pytest.importorskip("pandas")  # the test extras install it (catalog, notebook): never skipped


def _imported(stderr: str) -> set[str]:
    """The modules ``-X importtime`` reports as loaded (a blocked import is listed too, with
    a few microseconds; pandas' package itself takes tens of milliseconds)."""
    out = set()
    for line in stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            _, cumulative, name = line.split("|")
            if cumulative.strip().isdigit() and int(cumulative) > 1000:
                out.add(name.strip())
    return out


def _run(tmp_path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-X", "importtime", *args],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_a_command_that_logs_to_rerun_loads_no_pandas(tmp_path) -> None:
    proc = _run(tmp_path, "-m", "capture", "sim", "--minutes", "0.02", "--out", "r.rrd")
    assert proc.returncode == 0, proc.stderr[-2000:]
    loaded = _imported(proc.stderr)
    assert "pyarrow" in loaded and "rerun" in loaded  # it did convert with pyarrow
    assert "pandas" not in loaded
    assert (tmp_path / "r.rrd").stat().st_size > 0


SCRIPT = """
import json, sys
from vdc.executors import ExecutorSettings, run_tasks

def convert(_k):
    import pyarrow as pa
    pa.array([1, 2, None])  # a list: pyarrow's first look for pandas
    before = "pandas" in sys.modules
    frame = pa.table({"a": [1.5, None]}).to_pandas()  # an explicit use still works
    return {"before": before, "frame": type(frame).__name__, "null": bool(frame["a"].isna()[1])}

if __name__ == "__main__":
    from vdc.no_pandas import arrow_without_pandas
    arrow_without_pandas()  # as vdc's console scripts do, before pyarrow loads
    import pyarrow as pa
    pa.array([1])
    here = "pandas" in sys.modules
    out = run_tasks(convert, [("a", (0,))], ExecutorSettings("local", 1))
    print(json.dumps({"here": here, "worker": out[0].result, "error": out[0].error}))
"""


def test_a_pool_worker_loads_pandas_only_when_asked(tmp_path) -> None:
    import json

    (tmp_path / "script.py").write_text(SCRIPT)
    proc = _run(tmp_path, "script.py")
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["error"] is None
    assert got["here"] is False
    assert got["worker"] == {"before": False, "frame": "DataFrame", "null": True}


def test_pyarrow_still_remembers_that_pandas_was_not_there(tmp_path) -> None:
    """The one detail ``vdc.no_pandas`` rests on (pyarrow's pandas shim tries the import once
    and remembers a failure, ``_PandasAPIShim._tried_importing_pandas``), checked through what
    it does: after the asking, further conversions load no pandas, and an explicit use still
    does. A new pyarrow that changes it fails here by name."""
    script = (
        "import sys, pyarrow as pa\n"
        "from vdc.no_pandas import arrow_without_pandas\n"
        "arrow_without_pandas()\n"
        "pa.array([1]); pa.array(['a', None]); pa.table({'a': [1.5]})\n"
        "after = 'pandas' in sys.modules\n"
        "kind = type(pa.table({'a': [1]}).to_pandas()).__name__\n"
        "print(pa.__version__, after, kind)\n"
    )
    proc = _run(tmp_path, "-c", script)
    assert proc.returncode == 0, proc.stderr[-2000:]
    version, after, kind = proc.stdout.split()
    assert after == "False", (
        f"pyarrow {version} imports pandas again after a failed look: its pandas shim no "
        "longer remembers (_PandasAPIShim._tried_importing_pandas); vdc.no_pandas saves "
        "nothing now (the plain path runs): drop it or follow the change"
    )
    assert kind == "DataFrame", (
        f"pyarrow {version} no longer retries pandas on an explicit use after a failed look: "
        "vdc.no_pandas would break to_pandas(); drop it"
    )

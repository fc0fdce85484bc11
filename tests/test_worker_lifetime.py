"""Pool workers end with the process that started them, whatever ends it (issue: orphaned
~450 MB workers kept recording after `batch`, `sweep` or `reproduce` was killed)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from contract.executors import pool_size, usable_cpus
from tests.helpers import ROOT

# two workers that would sleep a minute each: long enough to be killed mid-task
SCRIPT = """
import time
from contract.executors import ExecutorSettings, run_tasks
run_tasks(time.sleep, [("a", (60,)), ("b", (60,))], ExecutorSettings(jobs=2))
"""


def _children(pid: int) -> list[int]:
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            kids.append(int(stat.parent.name))
    return kids


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has ended; only its exit status waits to be collected


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_pool_workers_end_when_their_parent_is_killed(sig) -> None:
    env = {**os.environ, "VDC_OVERSUBSCRIBE": "1"}  # two workers even on a one-core runner
    parent = subprocess.Popen([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # wait for the spawned workers to run their tasks
            workers = [p for p in _children(parent.pid) if _alive(p)]
            # the resource tracker is a child too: two pool workers make three
            if len(workers) >= 3:
                break
            time.sleep(0.2)
        assert len(workers) >= 3, f"the pool did not start: children {workers}"
        time.sleep(1.0)  # the workers are inside their tasks now
        parent.send_signal(sig)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        assert not [p for p in workers if _alive(p)], "workers outlived their parent"
    finally:
        for p in [parent.pid, *workers]:
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass
        parent.wait(timeout=10)


def test_local_pool_is_capped_at_the_usable_cores(monkeypatch) -> None:
    monkeypatch.delenv("VDC_OVERSUBSCRIBE", raising=False)
    assert pool_size(18, 100) == min(18, usable_cpus())
    assert pool_size(18, 1) == 1
    monkeypatch.setenv("VDC_OVERSUBSCRIBE", "1")
    assert pool_size(18, 100) == 18

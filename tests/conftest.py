"""Shared fixtures."""

from __future__ import annotations

import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

# One OpenBLAS thread per process, set before NumPy loads here, in the xdist workers (which
# inherit the controller's environment) and in every command they start. The suite already
# runs a process per core, and OpenBLAS's own threads spin while they wait: on a busy 2-core
# machine a calibration's clutter pans (small matrix products, avdm.stimuli.panned_image)
# took 11.3 s CPU and 68 s with the default threads, 0.6 s CPU and 6 s with one. The numbers
# do not change (only the order of a sum could, far below any tolerance here).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import compileall

import pytest
from hypothesis import settings

from tests.helpers import ROOT, end_background_processes

# Property tests assert behaviour, never wall-clock time: a first example that compiles a
# kernel or fits a calibration on a loaded CI machine is not a failure (no deadline)
settings.register_profile("vdc", deadline=None)
settings.load_profile("vdc")


@pytest.fixture
def out_dir(tmp_path: Path) -> Path:
    return tmp_path / "out"


@pytest.fixture(autouse=True)
def _end_background_processes():
    """No test leaves a process behind, even when it fails before its own clean-up."""
    yield
    end_background_processes()


# The suite starts hundreds of Python processes (every command it runs as a user would, every
# pool worker), and each imports vdc's modules. An editable install compiles nothing, and
# with PYTHONDONTWRITEBYTECODE set (as on the CI machine) nothing is ever cached, so every
# process compiled the same sources again: 0.3-0.5 s of CPU each. The controller compiles
# them once, as pip does for an installed package; the workers and their commands only load.
if "PYTEST_XDIST_WORKER" not in os.environ:
    for _pkg in ("analysis", "avdm", "capture", "vdc"):
        compileall.compile_dir(ROOT / _pkg, quiet=1)


# Fitted calibrations are cached per user; the tests use a cache of their own (inherited by
# the commands they run), removed at the end of the session. One cache for the whole session:
# the xdist workers inherit the controller's, so a calibration one worker fits (atomically
# written) the others read instead of fitting it again.
_CACHE = os.environ.get("VDC_TEST_SESSION_CACHE") or tempfile.mkdtemp(prefix="vdc-test-cache-")
os.environ["VDC_TEST_SESSION_CACHE"] = _CACHE
os.environ["VDC_CACHE_DIR"] = _CACHE


@pytest.fixture(scope="session", autouse=True)
def _calibration_cache():
    yield Path(_CACHE)
    if "PYTEST_XDIST_WORKER" not in os.environ:  # the controller ends the session's cache
        shutil.rmtree(_CACHE, ignore_errors=True)


# Three workers per core for `-n auto` (`--maxprocesses 6` caps it). On a busy machine the
# suite's share of the cores is its share of the runnable processes, and a test often has one
# or none (it waits on the command, pool or server it started). Measured on 2 cores, fresh
# clone, 27 Nov 2026, with eight CPU-bound processes beside it (load 12-19): 2 workers took
# 46 min 20 s, 4 workers 29 min 42 s and 31 min 52 s (two passes), 6 workers (and Numba's
# kernels compiled once, avdm.jit) 29 min 56 s and 29 min 35 s, then (a capture without polars)
# 29 min 18 s and 26 min 11 s. Quiet: 4 workers 665 s from a fresh clone (1,322 CPU-s), 6
# workers with the kernel lock 586 s (1,167 CPU-s). The two changes were measured together:
# the gain under load is within the passes' spread. Under load the six workers end within two
# minutes of each other (VDC_TEST_CPU_LOG, below): the suite is bound by its CPU, not a tail.
def pytest_xdist_auto_num_workers(config) -> int:
    return 3 * len(os.sched_getaffinity(0))


# The longest test files first (measured on a fresh clone, 2 workers): the workers take whole
# files in collection order (`--dist loadfile --no-loadscope-reorder`), so starting the long
# ones first lets the two finish together instead of one waiting on a long file picked last.
LONGEST_FIRST = (
    "tests/test_guide_commands.py",  # the command tour that was the README's (4 min loaded)
    "tests/test_readme_python.py",
    "tests/test_guide_boundary.py",
    "tests/test_guide_video.py",
    "tests/analysis/catalog/test_catalog.py",
    "tests/analysis/test_dask.py",
    "tests/analysis/boundary/test_footage.py",
    "tests/analysis/boundary/test_boundary.py",
    "tests/capture/test_serial_link.py",
    "tests/test_faults.py",
    "tests/capture/test_plugin_everywhere.py",
    "tests/analysis/test_batch.py",
    "tests/capture/test_video.py",
)


def pytest_collection_modifyitems(config, items) -> None:
    rank = {path: k for k, path in enumerate(LONGEST_FIRST)}

    def key(item) -> int:
        path = Path(str(item.fspath)).resolve()
        rel = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
        return rank.get(rel, len(rank))

    items.sort(key=key)  # stable: within a file, and among the rest, the order stays


# `VDC_TEST_CPU_LOG=FILE pytest` appends one line per test: its CPU seconds (the worker's own
# and its finished child processes', setup to teardown), its wall seconds, when it ended (Unix
# time), the xdist worker and the test's id. The suite is CPU-bound on a 2-core machine, so
# this, not `--durations`, says where its time goes.
_CPU_LOG = os.environ.get("VDC_TEST_CPU_LOG")


def _cpu_s() -> float:
    both = (resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN))
    return sum(u.ru_utime + u.ru_stime for u in both)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not _CPU_LOG:
        yield
        return
    cpu0, wall0 = _cpu_s(), time.monotonic()
    yield
    cpu, wall = _cpu_s() - cpu0, time.monotonic() - wall0
    with open(_CPU_LOG, "a") as log:  # one short line per write: appends do not interleave
        worker = os.environ.get("PYTEST_XDIST_WORKER", "-")
        log.write(f"{cpu:.2f}\t{wall:.2f}\t{time.time():.1f}\t{worker}\t{item.nodeid}\n")

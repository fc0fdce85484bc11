"""avdm.jit: processes that need the same uncached kernel at once compile it once."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.helpers import flock_waiters, run_behind_a_held_lock, wait_until
from tests.test_layout import PACKAGES, module_sources

ROOT = Path(__file__).resolve().parents[2]

KERNELS = textwrap.dedent(
    """
    import json
    import sys

    import numpy as np

    from avdm.jit import kernel


    @kernel(nogil=True)
    def double(x):
        return 2.0 * x


    @kernel(nogil=True)
    def total(a):
        s = 0.0
        for v in a:
            s += double(v)
        return s


    if __name__ == "__main__":
        assert total(np.arange(4.0)) == 12.0
        stats = {name: f.stats for name, f in (("total", total), ("double", double))}
        print(json.dumps({
            name: {"hits": sum(s.cache_hits.values()), "misses": sum(s.cache_misses.values())}
            for name, s in stats.items()
        }))
    """
)


@pytest.mark.skipif(not os.path.exists("/proc/locks"), reason="needs Linux's /proc/locks")
def test_two_processes_needing_an_uncached_kernel_compile_it_once(tmp_path: Path) -> None:
    (tmp_path / "kernels.py").write_text(KERNELS)
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}
    env.pop("NUMBA_CACHE_DIR", None)  # Numba's cache beside kernels.py, empty: a cold start
    # the lock file the first compile takes (total's: the caller's, taken before its callee's)
    probe = "import kernels; from avdm.jit import _lock_path; print(_lock_path(kernels.total))"
    lock = subprocess.run(
        [sys.executable, "-c", probe], env=env, cwd=tmp_path, capture_output=True, text=True
    )
    assert lock.returncode == 0, lock.stderr
    lock_path = Path(lock.stdout.strip())
    assert lock_path.parent.parent == tmp_path  # beside the source, in its __pycache__
    # the test holds the kernel's lock, so both processes reach it before either compiles:
    # without the lock both would compile, whatever the machine's load
    cmd = [sys.executable, str(tmp_path / "kernels.py")]
    runs = run_behind_a_held_lock(lock_path, [cmd, cmd], env=env, cwd=tmp_path)
    assert [code for code, _ in runs] == [0, 0]
    stats = [json.loads(out) for _, out in runs]
    # one process compiled both kernels; the other loaded the caller, whose cached machine code
    # holds its callee's, so it never needed the callee at all
    assert sorted(s["total"]["misses"] for s in stats) == [0, 1], stats
    assert sorted(s["total"]["hits"] for s in stats) == [0, 1], stats
    assert sorted(s["double"]["misses"] for s in stats) == [0, 1], stats


def test_a_held_lock_is_released_when_its_holder_is_killed(tmp_path: Path) -> None:
    """A compile killed halfway leaves nobody waiting: a process blocked on the kernel's lock
    goes on, and compiles it, when the holder is killed (flock ends with its process)."""
    (tmp_path / "kernels.py").write_text(KERNELS)
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}
    env.pop("NUMBA_CACHE_DIR", None)
    hold = (
        "import os, sys, kernels; from avdm.file_lock import exclusive\n"
        "from avdm.jit import _lock_path\n"
        "p = _lock_path(kernels.total); os.makedirs(os.path.dirname(p), exist_ok=True)\n"
        "with exclusive(p) as locked:\n"
        "    print(p if locked else '', flush=True); sys.stdin.read()\n"
    )
    popen = {"env": env, "cwd": tmp_path, "stdout": subprocess.PIPE, "text": True}
    holder = subprocess.Popen([sys.executable, "-c", hold], stdin=subprocess.PIPE, **popen)
    run = None
    try:
        assert holder.stdout is not None
        lock_path = Path(holder.stdout.readline().strip())
        assert lock_path.is_file(), "the holder could not lock"
        run = subprocess.Popen([sys.executable, str(tmp_path / "kernels.py")], **popen)
        # the event, not a time: the kernel's lock table shows the run blocked on the lock
        assert wait_until(lambda: flock_waiters(lock_path) == 1 or run.poll() is not None, 300)
        assert run.poll() is None, "the run did not wait for the held lock"
    finally:
        holder.kill()
        holder.wait()
        out = run.communicate(timeout=300)[0] if run is not None else ""
    assert run.returncode == 0
    assert json.loads(out)["total"]["misses"] == 1  # it compiled the kernel itself


def test_every_kernel_in_the_packages_compiles_under_the_lock() -> None:
    """No plain ``numba.njit``/``numba.jit`` in the packages: each kernel is ``avdm.jit.kernel``."""
    plain = []
    for name, source in module_sources().items():
        if name == "avdm.jit" or name.split(".")[0] not in PACKAGES:
            continue
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.Attribute) and node.attr in ("njit", "jit"):
                if isinstance(node.value, ast.Name) and node.value.id == "numba":
                    plain.append(f"{name}:{node.lineno}")
            if isinstance(node, ast.ImportFrom) and node.module == "numba":
                if any(a.name in ("njit", "jit") for a in node.names):
                    plain.append(f"{name}:{node.lineno}")
    assert plain == []


def test_the_kernels_load_without_the_registry_polars_or_a_thread() -> None:
    """A pool's fork server imports the kernels (vdc.warm): ``avdm/__init__`` loads its names
    lazily, so ``avdm.jit`` brings neither the registry nor polars, whose threads a fork
    would not copy."""
    code = (
        "import sys, avdm.avdm_model, vdc.frame_metrics\n"
        "from vdc.warm import threads_now\n"
        "print(sorted(m for m in ('avdm.registry', 'polars') if m in sys.modules), threads_now())"
    )
    env = {**os.environ, **{v: "1" for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}}
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["[]", "1"]


def test_the_package_face_names_what_it_loads() -> None:
    import avdm

    assert avdm.__all__ == sorted(avdm._API)
    for name in avdm.__all__:
        assert getattr(avdm, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        avdm.nope  # noqa: B018

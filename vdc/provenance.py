"""Package versions and the machine that produced a result.

Numba compiles vdc's kernels for the host CPU (``cache=True`` keys the cache on it), and the
AVDM sums with reassociation so that LLVM vectorises them: an AVX-512 and an AVX2 machine round
those sums differently, by a few float32 ulps. Recordings and tables therefore carry the CPU
model and Numba's target beside the package versions.
"""

from __future__ import annotations

import functools
import platform
from importlib import metadata
from pathlib import Path

import llvmlite.binding as llvm

# vdc's own distribution on the package index ("vdc" there is an unrelated project); its
# version is reported under the key "vdc"
DISTRIBUTION = "visual-dynamic-complexity"

# the packages that determine a recording's or a table's contents
PACKAGES = (
    "vdc",
    "numpy",
    "numba",
    "llvmlite",
    "polars",
    "pyarrow",
    "rerun-sdk",
    "opencv-python-headless",
    "scipy",  # the claims' intervals and trend tests
)


def package_versions() -> dict[str, str]:
    """``{"python": "3.11.7", "numpy": "2.4.6", ...}``; ``"not installed"`` where absent."""
    return dict(_package_versions())


@functools.cache
def _package_versions() -> tuple[tuple[str, str], ...]:
    # once per process: each lookup scans every folder of sys.path for the distribution's
    # metadata (about 10 ms apiece), and every Parquet file and recording asks; the packages
    # a running process has imported do not change under it
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(DISTRIBUTION if name == "vdc" else name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return tuple(out.items())


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


@functools.cache
def machine_info() -> dict[str, str]:
    """The CPU model, Numba's compile target and the widest vector extension it may use."""
    info = {"cpu_model": _cpu_model(), "platform": platform.platform(terse=True)}
    try:
        info["numba_target_cpu"] = llvm.get_host_cpu_name()
        features = llvm.get_host_cpu_features()
        simd = [f for f in ("avx512f", "avx2", "avx", "sse4.2", "neon") if features.get(f)]
        info["simd"] = simd[0] if simd else "none"
    except Exception:  # llvmlite missing or too old: the rest still identifies the machine
        info["numba_target_cpu"] = "unknown"
        info["simd"] = "unknown"
    return info

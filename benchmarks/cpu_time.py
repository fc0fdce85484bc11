"""CPU time a benchmark's workers spent, where the wall clock of a shared machine cannot say.

A local pool's workers and a local Dask cluster's processes fork from the multiprocessing
fork server, a child of this process; their CPU reaches us only as the fork server's reaped
children (``cutime``/``cstime`` of its ``/proc/PID/stat``). The server is found as this
process's child whose command line runs ``multiprocessing.forkserver`` (public /proc, not the
module's private state)."""

from __future__ import annotations

import os
import resource
from pathlib import Path


def _fork_servers() -> list[int]:
    """This process's children that run multiprocessing's fork server (Linux /proc)."""
    me, found = os.getpid(), []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) != me:  # field 4, the parent's pid
                continue
            cmdline = (stat.parent / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue  # ended meanwhile, or no /proc
        if b"multiprocessing.forkserver" in cmdline:
            found.append(int(stat.parent.name))
    return found


def cpu_s(own: bool = True) -> float:
    """CPU seconds (user + system) of this process (``own``), its finished children and the
    fork server's finished children: a call's difference is the CPU spent in between."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = kids.ru_utime + kids.ru_stime
    if own:
        me = resource.getrusage(resource.RUSAGE_SELF)
        total += me.ru_utime + me.ru_stime
    for pid in _fork_servers():
        try:  # cutime, cstime: fields 16 and 17 of /proc/PID/stat, after the command's name
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[13]) + int(fields[14])) / os.sysconf("SC_CLK_TCK")
        except (OSError, IndexError, ValueError):
            pass
    return total

"""A regular install, as a user gets it: run with the Python of a fresh virtualenv into which
the wheel (not an editable install) was installed, from a folder outside the checkout.

Runs every command's and sub-command's ``--help``, then one short real run each of
``vdc-capture sim``, ``vdc-analyse tables`` and ``vdc-analyse sweep``. Exits non-zero (with
the command's output) at the first failure."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent


def run(*args: str) -> None:
    proc = subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"FAILED: {' '.join(args)} (exit {proc.returncode})\n{proc.stdout}{proc.stderr}")
    print(f"ok: {' '.join(args)}", flush=True)


def subcommands(module: str) -> list[str]:
    import importlib

    parser = importlib.import_module(module).build_parser()
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sorted(subs[0].choices) if subs else []


def main() -> None:
    here = Path.cwd().resolve()
    checkout = Path(__file__).resolve().parents[1]
    if here == checkout or checkout in here.parents:
        sys.exit("run this from a folder outside the checkout")
    for script, module in (("vdc-capture", "capture.cli"), ("vdc-analyse", "analysis.cli")):
        run(script, "--help")
        for sub in subcommands(module):
            run(script, sub, "--help")
    run("vdc-capture", "sim", "--minutes", "0.3", "--out", "smoke.rrd", "--quiet")
    run("vdc-analyse", "tables", "smoke.rrd", "--out", "tables")
    run(
        "vdc-analyse",
        "sweep",
        "--sf-upc",
        "1,2",
        "--tf-hz",
        "3",
        "--duration-s",
        "0.5",
        "--out",
        "sweep",
    )
    for f in ("smoke.rrd", "tables/summary.parquet", "sweep/sweep.parquet"):
        if not Path(f).exists():
            sys.exit(f"FAILED: {f} was not written")
    print("the wheel installs and runs outside the checkout")


if __name__ == "__main__":
    main()

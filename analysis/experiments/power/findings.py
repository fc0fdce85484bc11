"""The power study's answer published into the repository (``docs/findings/<study>/``) and the
docs' result section generated from it (docs/findings/power_plan_amendment.md).

* :func:`publish`: a finished study's answer tables and ``answer.md`` copied with
  ``made_by.json`` (the commit of the code that made them) by ``vdc-analyse power-study
  --publish-findings DIR``;
* :func:`result_section`: the README's and the findings index's section between
  :data:`BEGIN` and :data:`END`, rebuilt from the committed tables (:data:`PENDING` until they
  exist); :func:`update_section` writes it, and a test fails where a doc differs.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from importlib.metadata import version  # vdc.__version__ (the facade: not imported here)
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow.parquet as pq

from analysis.experiments.power.answer import _fmt, _p, first_paragraph, share_phrase

PUBLISHED = (
    "answer.md",
    "primary.parquet",
    "secondaries.parquet",
    "per_scene.parquet",
    "studies.parquet",
)
BEGIN, END = "<!-- power-study:begin (generated) -->", "<!-- power-study:end -->"
FINDINGS = Path("docs/findings/power-2026-12")  # where the amended plan's answer is committed
PENDING = (
    "The amended plan's run (docs/findings/power_plan_amendment.md) is pending: no result is "
    "committed yet, and none is quoted here."
)


def publish(out: Path, dest: Path, studies: pl.DataFrame, feedback: Any = None) -> list[Path]:
    """Copy a finished study's answer (:data:`PUBLISHED`) from ``out`` into ``dest`` with
    ``made_by.json``: the commit of the code that made it (and whether its tree had
    uncommitted changes), vdc's version, the plan and whether it was a quick run."""
    __version__ = version("visual-dynamic-complexity")

    dest.mkdir(parents=True, exist_ok=True)
    written = []
    for name in PUBLISHED:
        tmp = dest / f".{name}.partial"
        shutil.copyfile(out / name, tmp)
        tmp.replace(dest / name)
        written.append(dest / name)
    repo = Path(__file__).resolve().parents[3]

    def git(*args: str) -> str:
        try:
            run = subprocess.run(
                ["git", "-C", str(repo), *args],
                capture_output=True,
                text=True,
                timeout=30,
                check=False,
            )
        except (OSError, subprocess.SubprocessError):
            return ""
        return run.stdout.strip() if run.returncode == 0 else ""

    meta = {
        "commit": git("rev-parse", "HEAD") or "unknown",
        "uncommitted_changes": bool(git("status", "--porcelain", "--untracked-files=no")),
        "vdc": __version__,
        "quick": _quick(out),
        "studies": studies.height,
    }
    tmp = dest / ".made_by.json.partial"
    tmp.write_text(json.dumps(meta, indent=1) + "\n")
    tmp.replace(dest / "made_by.json")
    written.append(dest / "made_by.json")
    if feedback is not None:
        feedback.log(f"published the answer into {dest} (commit {meta['commit'][:12]}).")
    return written


def _quick(out: Path) -> bool:
    kv = pq.read_schema(out / "primary.parquet").metadata or {}
    return bool(json.loads(kv.get(b"vdc.quick", b"false")))


def result_section(folder: Path) -> str:
    """The docs' result section, generated from the committed tables in ``folder`` (the
    pending sentence where there are none): answer.md's first paragraph rebuilt from
    ``primary.parquet``, each study's line, and the commit that made them."""
    if not (folder / "primary.parquet").exists():
        return PENDING
    primary = pl.read_parquet(folder / "primary.parquet")
    made = json.loads((folder / "made_by.json").read_text())
    lines = [first_paragraph(primary), ""]
    lines += [
        "| source | detector | deviation | units | failing share | AVDM − TI | "
        "Holm p over the studies | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in primary.iter_rows(named=True):
        units = f"{r['n_units']} {r['unit']}s, n {r['n']}" if r.get("n_units") else "—"
        diff = _fmt(r.get("difference"), r.get("difference_low"), r.get("difference_high"), 3)
        across = r.get("p_holm_across")
        lines.append(
            f"| {r['source']} | {r['detector']} | {r.get('deviation') or 'none'} | {units} | "
            f"{share_phrase(r) or '—'} | {diff} | {_p(across) if across is not None else '—'} | "
            f"{(r.get('verdict') or '')[:100]} |"
        )
    quick = " (a QUICK run: not findings)" if made.get("quick") else ""
    lines += [
        "",
        f"Generated from `docs/findings/{folder.name}/`, made by commit "
        f"{made['commit'][:12]} (vdc {made['vdc']}){quick}.",
    ]
    return "\n".join(lines)


def section_in(text: str) -> str | None:
    """The generated section between :data:`BEGIN` and :data:`END` in a doc, or None."""
    if BEGIN not in text or END not in text:
        return None
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")


def update_section(doc: Path, folder: Path = FINDINGS) -> bool:
    """Rewrite ``doc``'s generated section from ``folder``; True when it changed."""
    text = doc.read_text(encoding="utf-8")
    old = section_in(text)
    if old is None:
        raise ValueError(f"{doc} has no generated section ({BEGIN} ... {END})")
    new = result_section(folder)
    if old == new:
        return False
    head, rest = text.split(BEGIN, 1)
    doc.write_text(head + BEGIN + "\n" + new + "\n" + END + rest.split(END, 1)[1], "utf-8")
    return True

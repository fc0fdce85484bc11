"""The power study's answer published into the repository (``docs/findings/<study>/``) and the
docs' result section generated from it (docs/findings/power_plan_amendment.md).

* :func:`publish`: a finished study's answer tables (:data:`PUBLISHED`), each study's run or
  clip table with its failure modes and measures (:data:`STUDY_TABLES`), and ``made_by.json``
  (the commit of the code that made them, and the run's code key) by ``vdc-analyse
  power-study --publish-findings DIR``;
* :func:`answer_text`: ``answer.md`` rebuilt from the published tables (a pure function of
  them: a test holds the committed ``answer.md`` to it);
* :func:`result_section`: the README's and the findings index's section between
  :data:`BEGIN` and :data:`END`, rebuilt from the committed tables (:data:`PENDING` until they
  exist); :func:`update_section` writes it, and a test fails where a doc differs.

``python -m analysis.experiments.power.findings`` rewrites the committed ``answer.md`` and the
docs' sections from the committed tables (after the answer's wording changed).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from importlib.metadata import version  # vdc.__version__ (the facade: not imported here)
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow.parquet as pq

from analysis.experiments.power.answer import (
    _fmt,
    _p,
    answer_markdown,
    first_paragraph,
    share_phrase,
)
from analysis.experiments.power.plans import plan_of
from analysis.experiments.power.units import plot_scene_table

PUBLISHED = (
    "answer.md",
    "primary.parquet",
    "secondaries.parquet",
    "per_scene.parquet",
    "per_scene.png",
    "studies.parquet",
)
# each study's own tables, under <source>/<study folder>/: the runs (arena) or clips (footage)
# with their outcome and failure mode, what each unit measured, and the study's statistics
STUDY_TABLES = {
    "arena": ("boundary_runs.parquet", "predictor_measures.parquet", "predictors.parquet"),
    "footage": ("boundary_clips.parquet", "predictors.parquet"),
}
LABELS_CSV = Path("footage/clips/labels.csv")  # each clip's scene (photograph) and truth
BEGIN, END = "<!-- power-study:begin (generated) -->", "<!-- power-study:end -->"
FINDINGS = Path("docs/findings/power-2026-12")  # where the amended plan's answer is committed
DOCS = (Path("README.md"), Path("docs/findings/index.md"))  # the docs with the section
PENDING = (
    "The amended plan's run (docs/findings/power_plan_amendment.md) is pending: no result is "
    "committed yet, and none is quoted here."
)


def _copy(src: Path, dst: Path) -> Path:
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.partial")
    shutil.copyfile(src, tmp)
    tmp.replace(dst)
    return dst


def _write_text(path: Path, text: str) -> Path:
    """``text`` into ``path`` whole or not at all (a partial file beside it, then renamed)."""
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path


def _git(*args: str) -> str:
    repo = Path(__file__).resolve().parents[3]
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


def publish(
    out: Path,
    dest: Path,
    studies: pl.DataFrame,
    plan: str = "2026-12",
    feedback: Any = None,
    *,
    commit: str | None = None,
) -> list[Path]:
    """Copy a finished study's answer (:data:`PUBLISHED`) from ``out`` into ``dest``, each
    study's tables (:data:`STUDY_TABLES`, under ``<source>/<folder>/``) and the clips' labels,
    with ``made_by.json``: the commit of the code that made them (``commit``, else this
    checkout's HEAD, and whether its tree had uncommitted changes), the run's code key
    (``out/code.json``), vdc's version, the plan's version and whether it was a quick run."""
    dest.mkdir(parents=True, exist_ok=True)
    written = [_copy(out / name, dest / name) for name in PUBLISHED]
    for st in studies.iter_rows(named=True):
        folder = Path(st["folder"])
        for name in STUDY_TABLES.get(st["source"], ()):
            if (folder / name).exists():  # a study that held no evidence wrote fewer
                written.append(_copy(folder / name, dest / st["source"] / folder.name / name))
    if (out / LABELS_CSV).exists():
        written.append(_copy(out / LABELS_CSV, dest / LABELS_CSV))
    code = out / "code.json"
    meta = {
        "commit": commit or _git("rev-parse", "HEAD") or "unknown",
        "uncommitted_changes": False
        if commit
        else bool(_git("status", "--porcelain", "--untracked-files=no")),
        "code_key": json.loads(code.read_text()) if code.exists() else None,
        "vdc": version("visual-dynamic-complexity"),
        "plan": plan,
        "quick": _quick(out),
        "studies": studies.height,
    }
    written.append(_write_text(dest / "made_by.json", json.dumps(meta, indent=1) + "\n"))
    if feedback is not None:
        feedback.log(f"published the answer into {dest} (commit {meta['commit'][:12]}).")
    return written


def answer_text(folder: Path) -> str:
    """``answer.md`` rebuilt from the published tables in ``folder`` by this code."""
    made = json.loads((folder / "made_by.json").read_text())
    return answer_markdown(
        pl.read_parquet(folder / "primary.parquet"),
        pl.read_parquet(folder / "secondaries.parquet"),
        pl.read_parquet(folder / "studies.parquet"),
        bool(made.get("quick")),
        plan_of(made.get("plan", "2026-11"), bool(made.get("quick"))),
        pl.read_parquet(folder / "per_scene.parquet"),
    )


def refresh(folder: Path = FINDINGS, docs: tuple[Path, ...] = DOCS) -> list[Path]:
    """Rewrite ``folder/answer.md``, ``folder/per_scene.png`` and the docs' generated sections
    from the tables committed in ``folder``; returns the text files that changed."""
    changed = []
    if (folder / "per_scene.parquet").exists():  # the figure drawn again by this code
        made = json.loads((folder / "made_by.json").read_text())
        plot_scene_table(
            pl.read_parquet(folder / "per_scene.parquet"),
            folder / "per_scene.png",
            bool(made.get("quick")),
        )
    if (folder / "primary.parquet").exists():
        text, md = answer_text(folder), folder / "answer.md"
        if md.read_text(encoding="utf-8") != text:
            changed.append(_write_text(md, text))
    changed += [doc for doc in docs if update_section(doc, folder)]
    return changed


def _quick(out: Path) -> bool:
    kv = pq.read_schema(out / "primary.parquet").metadata or {}
    return bool(json.loads(kv.get(b"vdc.quick", b"false")))


def short_verdict(verdict: str) -> str:
    """A verdict in a few words, for a table cell (answer.md keeps it whole)."""
    if verdict.startswith("cannot inform"):
        return "cannot inform (named before the runs)"
    if verdict.startswith("not shown"):
        return "neither beyond chance"
    if "too few to judge" in verdict:
        return "too few to judge"
    return verdict


def result_section(folder: Path, doc: Path | None = None) -> str:
    """The docs' result section, generated from the committed tables in ``folder`` (the
    pending sentence where there are none): answer.md's first paragraph rebuilt from
    ``primary.parquet``, a table of the studies, their deviations from the plan, and the
    commit that made them; links relative to ``doc`` (else to the repository's root)."""
    if not (folder / "primary.parquet").exists():
        return PENDING
    primary = pl.read_parquet(folder / "primary.parquet")
    made = json.loads((folder / "made_by.json").read_text())
    lines = [first_paragraph(primary), ""]
    lines += [
        "| study | units | failing | AVDM | TI | Holm p over the studies | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in primary.iter_rows(named=True):
        units = f"{r['n_units']} {r['unit']}s, {r['n']} in all" if r.get("n_units") else "—"
        across = r.get("p_holm_across")
        lines.append(
            f"| {r['source']}, {r['detector']} | {units} | {share_phrase(r) or '—'} | "
            f"{_fmt(r.get('avdm_estimate'), r.get('avdm_ci_low'), r.get('avdm_ci_high'))} | "
            f"{_fmt(r.get('ti_estimate'), r.get('ti_ci_low'), r.get('ti_ci_high'))} | "
            f"{_p(across) if across is not None else '—'} | "
            f"{short_verdict(r.get('verdict') or '')} |"
        )
    moved = [r for r in primary.iter_rows(named=True) if r.get("deviation")]
    answer_link = (
        Path(os.path.relpath(folder / "answer.md", doc.parent)).as_posix()
        if doc is not None
        else f"docs/findings/{folder.name}/answer.md"
    )
    quick = " (a QUICK run: not findings)" if made.get("quick") else ""
    lines += [
        "",
        "AVDM and TI: each one's Spearman ρ with a condition's failure rate (arena) or its "
        "clip AUROC (footage), 95 % intervals over scenes. Failing: the study's share against "
        "the plan's target; a detector's value was confirmed beforehand on a first seed or a "
        "pilot, and moved one step where 20-60 % did not fail there."
        + (
            " Deviations from the plan: "
            + "; ".join(f"{r['source']} {r['detector']}, {r['deviation']}" for r in moved)
            + "."
            if moved
            else " No deviation from the plan."
        )
        + f" Every number: [answer.md]({answer_link}), generated from "
        f"the tables in `docs/findings/{folder.name}/`, made by commit "
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
    new = result_section(folder, doc)
    if old == new:
        return False
    head, rest = text.split(BEGIN, 1)
    doc.write_text(head + BEGIN + "\n" + new + "\n" + END + rest.split(END, 1)[1], "utf-8")
    return True


if __name__ == "__main__":  # run from the repository's root
    for path in refresh():
        print(f"rewrote {path}")

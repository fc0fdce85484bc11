"""The reproduction report: ``report.md`` and a self-contained ``report.html`` rendered from
the claims and the tables, with the environment of the analysis and of the captures."""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import polars as pl

from analysis.collision import PAPER, PHASE_STATISTICS
from analysis.experiments.claims import RISE_TEST, Claim, claims_frame
from analysis.experiments.plan import ReproduceSettings
from vdc.parquet_io import read_metadata


def _cell(r: dict, digits: int = 4) -> str:
    """A row's estimate with its 95 % interval, to ``digits`` significant digits."""
    if r["ci_low"] is None:
        return _number(r["estimate"], digits)
    return f"{_number(r['estimate'], digits)} [{_number(r['ci_low'], digits)}, " + (
        f"{_number(r['ci_high'], digits)}]"
    )


def _header(*names: str) -> list[str]:
    """A markdown table's heading and rule."""
    return ["| " + " | ".join(names) + " |", "|---" * len(names) + "|"]


def _grid(
    rows: pl.DataFrame, by: str, across: str, columns: list[str]
) -> Iterator[tuple[Any, pl.DataFrame, str]]:
    """Per group of ``rows`` by ``by``: its value, the group, and its cells, one per value of
    ``across`` in ``columns`` (mean [95 % interval], "-" where the group has none)."""
    for (key,), g in rows.group_by(by, maintain_order=True):
        at = {r[across]: r for r in g.iter_rows(named=True)}
        yield key, g, " | ".join(_cell(at[c]) if c in at else "-" for c in columns)


def fig6_table_markdown(table: pl.DataFrame) -> str:
    """The Fig. 6 readings across seeds, rendered from claims.parquet's rows (``table``): the
    grating's rows decided or supported by a trend across wall TFs, one line per reading,
    one column per TF, cells mean [95 % interval], and the reading's trend test."""
    rows = table.filter(
        pl.col("test").str.starts_with(RISE_TEST) & pl.col("condition").str.starts_with("TF ")
    )
    if rows.height == 0:
        return "(no grating readings)"
    tfs = rows["condition"].unique(maintain_order=True).to_list()
    lines = _header("reading", *tfs, "trend test")
    for name, g, cells in _grid(rows, "quantity", "condition", tfs):
        first = g.row(0, named=True)
        method = first["test"].split(": ", 1)[-1]
        lines.append(f"| {name} | {cells} | p = {_number(first['p_value'], 3)} ({method}) |")
    n = int(rows["n_seeds"].max())
    return "\n".join(lines) + f"\n\nMean [95 % interval] over {n} seeds per condition."


def phases_markdown(table: pl.DataFrame) -> str:
    """The collision study per phase, rendered from claims.parquet's rows (``table``): mean
    [95 % interval] across seeds of each phase statistic, beside the paper's figures."""
    rows = table.filter(pl.col("quantity").is_in(PHASE_STATISTICS)).unique(
        ["condition", "quantity"], keep="first", maintain_order=True
    )
    if rows.height == 0:
        return "(no collision phases)"
    names = [q for q in PHASE_STATISTICS if q in set(rows["quantity"])]
    lines = _header("phase", "seeds", *names, "paper: avoidances", "paper: success")
    for phase, g, cells in _grid(rows, "condition", "quantity", names):
        paper = PAPER.get(phase, {})
        lines.append(
            f"| {phase} | {g['n_seeds'].max()} | {cells} | "
            f"{paper.get('paper_avoidances', '-')} | {paper.get('paper_success', '-')} |"
        )
    return "\n".join(lines) + "\n\nsuccess_rate is a share (0-1); the others are per 30 min."


def segments_markdown(out: Path) -> str:
    """Where to watch each condition: the catalog's dataset (named after the report's folder,
    ``vdc-analyse catalog serve OUT``) and, per condition, its segments (recording ids) and
    their frames. Names, not server URLs: a URL changes at every start of the server."""
    prof = pl.read_parquet(out / "profiling" / "summary.parquet")
    col = pl.read_parquet(out / "collision" / "collision_summary.parquet")
    frames = prof.group_by("recording_id").agg(pl.col("n_frames").max())
    rows = (
        prof.select("recording_id", "scene", "wall_tf_hz").unique()
        .join(frames, on="recording_id")
        .with_columns(
            condition=pl.col("scene") + " TF " + pl.col("wall_tf_hz").cast(pl.String) + " Hz"
        )
        .select("condition", "recording_id", "n_frames")
    )  # fmt: skip
    cols = rows.vstack(
        col.select(
            pl.lit("collision ").add(pl.col("phase")).alias("condition"),
            "recording_id",
            pl.lit(None, pl.Int64).alias("n_frames"),
        )
    )
    lines = [
        f"Dataset `{out.resolve().name}`: `vdc-analyse catalog serve {out}` serves every run "
        "below as a segment (open the printed URL with `rerun`, or add `--web`).",
        "",
        "| condition | segments (recording ids) |",
        "|---|---|",
    ]
    for (cond,), g in cols.sort("condition", "recording_id").group_by(
        "condition", maintain_order=True
    ):
        ids = ", ".join(f"`{r}`" for r in g["recording_id"])
        lines.append(f"| {cond} | {ids} |")
    return "\n".join(lines)


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">'


FIGURES = (
    ("SF–TF sweep (Fig. 3)", "sweep/sweep.png"),
    ("Open-loop approach (Fig. 4)", "approach/approach.png"),
    ("Fig. 6 across seeds: all frames and straight driving", "profiling/fig6_seeds.png"),
    ("Profiles per condition, every seed pooled (Figs. 6–7)", "profiling/profiles.png"),
    ("Collision study across seeds (Fig. 8)", "collision/collision_study.png"),
)


def _number(value: float | None, digits: int = 4) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}g}"


def numbers_markdown(table: pl.DataFrame) -> str:
    """The claims' numbers, rendered from claims.parquet's rows (and nothing else): one line per
    claim, condition and quantity with the mean across seeds and its 95 % interval (4
    significant digits), the seeds, the test and its p-value."""
    lines = [
        "| claim | condition | quantity | mean | 95 % interval | seeds | test | p |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in table.drop_nulls("quantity").iter_rows(named=True):
        interval = (
            f"[{_number(r['ci_low'])}, {_number(r['ci_high'])}]" if r["ci_low"] is not None else "-"
        )
        lines.append(
            f"| {r['claim_index'] + 1} | {r['condition']} | {r['quantity']} | "
            f"{_number(r['estimate'])} | {interval} | {r['n_seeds']} | {r['test'] or '-'} | "
            f"{_number(r['p_value'], 3)} |"
        )
    return "\n".join(lines)


# The report's symbols and terms, each with what it means and its unit. The key lists those
# the page uses (matched literally), so it explains everything there and nothing that is not.
NOTATION = (
    ("ω̂", "the AVDM's estimate of the angular velocity of the image, deg/s (ω, no hat: the true "
     "one)"),
    ("λ̂", "the AVDM's estimate of the texture's spatial period, px"),
    ("R̄", "the AVDM's mean correlator response, its motion energy; √R̄ is on the [0, 1] "
     "intensity scale"),
    ("upc", "units per circle: a grating's cycles across an image standing for 360° (SF 10 upc: "
     "a 36° period)"),
    ("SF", "a grating's spatial frequency, upc"),
    ("TF", "temporal frequency, Hz: the cycles passing a point each second (the walls' drift)"),
    ("ρ", "Spearman's rank correlation, from −1 (falls throughout) to +1 (rises throughout)"),
    ("Page's L", "Page's test for a trend rising across three or more ordered conditions, seeds "
     "as blocks; p is one-sided"),
    ("sign test", "the trend test for two conditions: how many seeds rise; p is one-sided"),
    ("95 % interval", "where the mean across seeds lies with 95 % confidence (Student's t, "
     "clipped to the quantity's range): mean [low, high]"),
    ("p", "the chance of a trend at least this strong if there were none; below 0.05 counts"),
)  # fmt: skip


def notation_markdown(text: str) -> list[str]:
    """The key to the notation ``text`` uses: a Markdown table of :data:`NOTATION`'s entries
    that occur in it (``p`` where a p-value is given: ``p =`` or a ``| p |`` column)."""
    used = [
        (symbol, meaning)
        for symbol, meaning in NOTATION
        if (symbol in text if symbol != "p" else ("p =" in text or "| p |" in text))
    ]
    if not used:
        return []
    return ["| symbol | meaning |", "|---|---|", *(f"| {s} | {m} |" for s, m in used)]


def write_report(
    out: Path, plan: ReproduceSettings, claims: list[Claim], elapsed_s: float
) -> list[Path]:
    """report.md and a self-contained report.html (figures embedded) in ``out``."""
    table = claims_frame(claims)
    mode = plan.plan_name
    head = (
        f"Mode: {mode} (profiling {plan.profile_minutes:g} min per condition, collision "
        f"phases {plan.collision_minutes:g} min, {plan.seeds} seeds per condition "
        f"({plan.seed}..{plan.seed + plan.seeds - 1}), approach {plan.approach_repeats} "
        f"repeats, sweep {plan.sweep_duration_s:g} s per cell); wall time {elapsed_s:.0f} s. "
        "A claim holds only if it holds across seeds at 95 % confidence: a trend test with "
        "p < 0.05 and rising means, or a 95 % interval wholly on the claimed side. Every "
        "number comes from the tables in this folder."
    )
    sections = [
        ("The numbers behind the claims", numbers_markdown(table).split("\n")),
        ("Fig. 6 across seeds (grating)", fig6_table_markdown(table).split("\n")),
        ("Collision study across seeds", phases_markdown(table).split("\n")),
        ("Browse the runs", segments_markdown(out).split("\n")),
        ("Environment", environment_markdown(out)),
    ]
    md = [
        '# vdc: reproducing "Profiling Visual Dynamic Complexity Using a Bio-Robotic Approach"',
        "",
        head,
        "",
        "## Claims",
        "",
        "| # | claim | paper | measured (numbers below) | verdict |",
        "|---|---|---|---|---|",
    ]
    md += [
        f"| {i} | {c.claim} | {c.paper} | {c.measured} | **{c.verdict}** |"
        for i, c in enumerate(claims, 1)
    ]
    key = notation_markdown("\n".join([*md, *(ln for _, lines in sections[:4] for ln in lines)]))
    md += ["", "## Notation", "", *key] if key else []
    for title, lines in sections[:4]:
        md += ["", f"## {title}", "", *lines]
    md += ["", "## Figures", ""]
    md += [f"### {title}\n\n![{title}]({rel})\n" for title, rel in FIGURES if (out / rel).exists()]
    md += ["## Environment", "", *sections[4][1], ""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")

    rows = "".join(
        f"<tr><td>{i}</td><td>{html.escape(c.claim)}</td><td>{html.escape(c.paper)}</td>"
        f"<td>{html.escape(c.measured)}</td><td class='{c.verdict.replace(' ', '-')}'>"
        f"{html.escape(c.verdict)}</td></tr>"
        for i, c in enumerate(claims, 1)
    )
    figs = "".join(
        f"<h3>{html.escape(t)}</h3>{_img(out / rel)}" for t, rel in FIGURES if (out / rel).exists()
    )
    tables = "".join(
        f"<h2>{html.escape(title)}</h2>{_md_html(lines)}" for title, lines in sections[:4]
    )
    key_html = f"<h2>Notation</h2>{_md_html(key)}" if key else ""
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>vdc reproduction</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top}}
.holds{{background:#d4f4d4}}.partly{{background:#fff3c4}}.does-not-hold{{background:#f8d0d0}}
</style></head><body><h1>vdc: reproducing the paper</h1><p>{html.escape(head)}</p>
<h2>Claims</h2><table><tr><th>#</th><th>claim</th><th>paper</th><th>measured</th><th>verdict</th></tr>
{rows}</table>{key_html}{tables}<h2>Figures</h2>{figs}
<h2>Environment</h2>{_md_html(sections[4][1])}</body></html>"""
    html_path = out / "report.html"
    html_path.write_text(page, encoding="utf-8")
    return [md_path, html_path]


def _md_html(lines: list[str]) -> str:
    """A Markdown section's table as an HTML table (its other lines as paragraphs)."""
    rows = [ln for ln in lines if ln.startswith("|") and not ln.startswith("|---")]
    text = [ln.strip() for ln in lines if ln.strip() and not ln.startswith("|")]
    cells = [[c.strip() for c in r.strip("|").split("|")] for r in rows]
    table = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in cells
    )
    return "".join(f"<p>{html.escape(t)}</p>" for t in text) + f"<table>{table}</table>"


def environment_markdown(out: Path) -> list[str]:
    """The versions and machines of the analysis and of the captures, from claims.parquet."""
    meta = read_metadata(out / "claims.parquet")
    lines = [
        "Two reports can be compared number for number only when these agree; Numba compiles "
        "for the host CPU, so floats may differ in the last digits between CPUs.",
        "",
        "| | "
        + " | ".join(
            ["analysis"]
            + [f"capture {i + 1}" for i, _ in enumerate(meta.get("capture_provenance", []))]
        )
        + " |",
    ]
    cols = [{**meta.get("versions", {}), **meta.get("machine", {})}]
    cols += [g["provenance"] for g in meta.get("capture_provenance", [])]
    lines.append("|---" * (len(cols) + 1) + "|")
    keys = list(dict.fromkeys(k for c in cols for k in c))
    lines += [f"| {k} | " + " | ".join(str(c.get(k, "-")) for c in cols) + " |" for k in keys]
    for i, g in enumerate(meta.get("capture_provenance", [])):
        lines.append(f"\ncapture {i + 1}: {', '.join(g['recordings'])}")
    return lines

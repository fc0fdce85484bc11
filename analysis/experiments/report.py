"""The reproduction report: ``report.md`` and a self-contained ``report.html`` rendered from
the claims and the tables, with the environment of the analysis and of the captures."""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

import polars as pl

from analysis.collision import phase_statistics, phase_table_markdown
from analysis.experiments.claims import (
    CALIBRATED,
    RELEASED,
    Claim,
    bounds_of,
    claims_frame,
    estimates,
    per_seed,
    tf_columns,
)
from analysis.experiments.plan import ReproduceSettings
from analysis.stats import (
    rising_trend,
)
from vdc.parquet_io import read_metadata


def fig6_table_markdown(summary: pl.DataFrame) -> str:
    """The Fig. 6 readings across seeds: rows are readings, columns the grating's wall TFs,
    cells mean [95 % interval], and the trend test's p-value."""
    readings = (
        (f"% over 100, {RELEASED}, all frames", RELEASED, "all", "frac_over_100", 100.0),
        ("% over 100 deg/s, calibrated, all frames", CALIBRATED, "all", "frac_over_100", 100.0),
        (
            "% over 100 deg/s, calibrated, straight driving",
            CALIBRATED,
            "straight",
            "frac_over_100",
            100.0,
        ),
        (
            "% over 100 deg/s, calibrated, while turning",
            CALIBRATED,
            "turning",
            "frac_over_100",
            100.0,
        ),
        ("mean ω̂ (deg/s), calibrated, all frames", CALIBRATED, "all", "mean", 1.0),
        ("mean ω̂ (deg/s), calibrated, straight driving", CALIBRATED, "straight", "mean", 1.0),
    )
    lines: list[str] = []
    for label, model, motion, metric, scale in readings:
        t = per_seed(summary, "grating", model, motion, metric)
        if t.height == 0:
            continue
        if not lines:
            tfs = tf_columns(t)
            lines = [
                "| reading | " + " | ".join(f"TF {tf:g} Hz" for tf in tfs) + " | trend test |",
                "|---" * (len(tfs) + 2) + "|",
            ]
        trend = rising_trend(t.select([c for c in t.columns if c != "seed"]).to_numpy())
        cells = " | ".join(e.text("{:.1f}", scale) for e in estimates(t, bounds_of(metric)))
        lines.append(f"| {label} | {cells} | p = {trend.p_value:.3g} ({trend.method}) |")
    n = int(summary["seed"].n_unique())
    return "\n".join(lines) + f"\n\nMean [95 % interval] over {n} seeds per condition."


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


def write_report(
    out: Path, plan: ReproduceSettings, claims: list[Claim], elapsed_s: float
) -> list[Path]:
    """report.md and a self-contained report.html (figures embedded) in ``out``."""
    col = pl.read_parquet(out / "collision" / "collision_summary.parquet")
    prof = pl.read_parquet(out / "profiling" / "summary.parquet")
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
        ("The numbers behind the claims", numbers_markdown(claims_frame(claims)).split("\n")),
        ("Fig. 6 across seeds (grating)", fig6_table_markdown(prof).split("\n")),
        (
            "Collision study across seeds",
            phase_table_markdown(phase_statistics(col)).split("\n"),
        ),
        ("Environment", environment_markdown(out)),
    ]
    md = [
        '# vdc: reproducing "Profiling Visual Dynamic Complexity Using a Bio-Robotic Approach"',
        "",
        head,
        "",
        "## Claims",
        "",
        "| claim | paper | measured | verdict |",
        "|---|---|---|---|",
    ]
    md += [f"| {c.claim} | {c.paper} | {c.measured} | **{c.verdict}** |" for c in claims]
    for title, lines in sections[:3]:
        md += ["", f"## {title}", "", *lines]
    md += ["", "## Figures", ""]
    md += [f"### {title}\n\n![{title}]({rel})\n" for title, rel in FIGURES if (out / rel).exists()]
    md += ["## Environment", "", *sections[3][1], ""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")

    rows = "".join(
        f"<tr><td>{html.escape(c.claim)}</td><td>{html.escape(c.paper)}</td>"
        f"<td>{html.escape(c.measured)}</td><td class='{c.verdict.replace(' ', '-')}'>"
        f"{html.escape(c.verdict)}</td></tr>"
        for c in claims
    )
    figs = "".join(
        f"<h3>{html.escape(t)}</h3>{_img(out / rel)}" for t, rel in FIGURES if (out / rel).exists()
    )
    tables = "".join(
        f"<h2>{html.escape(title)}</h2>{_md_html(lines)}" for title, lines in sections[:3]
    )
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>vdc reproduction</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top}}
.holds{{background:#d4f4d4}}.partly{{background:#fff3c4}}.does-not-hold{{background:#f8d0d0}}
</style></head><body><h1>vdc: reproducing the paper</h1><p>{html.escape(head)}</p>
<h2>Claims</h2><table><tr><th>claim</th><th>paper</th><th>measured</th><th>verdict</th></tr>
{rows}</table>{tables}<h2>Figures</h2>{figs}
<h2>Environment</h2>{_md_html(sections[3][1])}</body></html>"""
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

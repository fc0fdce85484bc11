"""The reproduction report: ``report.md`` and a self-contained ``report.html`` rendered from
the claims and the tables, with the environment of the analysis and of the captures."""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import polars as pl

from analysis.collision import PAPER, PHASE_STATISTICS
from analysis.experiments.paper.claims import EXCLUDED, RISE_TEST, Claim, Quantity, claims_frame
from analysis.experiments.paper.plan import ReproduceSettings
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
    return (
        "\n".join(lines)
        + "\n\nsuccess_rate is a share (0-1); the others are per 30 min.\n\n"
        + avoidance_note(rows)
    ).rstrip()


def avoidance_note(rows: pl.DataFrame) -> str:
    """Why our avoidances are not the paper's: the count at TF 0 against the paper's 229."""
    tf0 = rows.filter(
        (pl.col("condition") == "tf0") & (pl.col("quantity") == "avoidances_per_30min")
    )
    paper = PAPER.get("tf0", {}).get("paper_avoidances")
    if tf0.height == 0 or not paper or tf0["estimate"][0] is None:
        return ""
    ours = float(tf0["estimate"][0])
    return (
        f"Avoidances at TF 0: {_number(ours)} per 30 min against the paper's {paper} "
        f"({ours / float(paper):.1f} times as many). The simulated detector alerts more often "
        "than the paper's robot did: many of its alerts come 30-40 cm before the wall (the "
        "false_alarms column counts those with the wall 0.30 m or more ahead). The claims rest "
        "on the success rates, not on these counts; docs/guides/analysis.md compares the full "
        "run's."
    )


def segments_markdown(out: Path) -> str:
    """Where to watch each condition: the catalog's dataset (named after the report's folder,
    ``vdc-analyse catalog serve OUT``) and, per condition, its segments (recording ids) and
    their frames. Names, not server URLs: a URL changes at every start of the server."""
    prof = pl.read_parquet(out / "profiling" / "summary.parquet")
    col = pl.read_parquet(out / "collision" / "collision_summary.parquet")
    frames = prof.group_by("recording_id").agg(pl.col("n_frames").max())
    rows = (
        prof.select("recording_id", "scene", "wall_tf_hz")
        .unique()
        .join(frames, on="recording_id")
        .with_columns(
            condition=pl.col("scene") + " TF " + pl.col("wall_tf_hz").cast(pl.String) + " Hz"
        )
        .select("condition", "recording_id", "n_frames")
    )
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
    (
        "SF–TF sweep (Fig. 3); the SF 50 upc panel, at the Nyquist limit, is left out of claim 1",
        "sweep/sweep.png",
    ),
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
    (
        "ω̂",
        "the AVDM's estimate of the angular velocity of the image, deg/s (ω, no hat: the true one)",
    ),
    ("λ̂", "the AVDM's estimate of the texture's spatial period, px"),
    (
        "R̄",
        "the AVDM's mean correlator response, its motion energy; √R̄ is on the [0, 1] "
        "intensity scale",
    ),
    (
        "upc",
        "units per circle: a grating's cycles across an image standing for 360° (SF 10 upc: "
        "a 36° period)",
    ),
    ("SF", "a grating's spatial frequency, upc"),
    ("TF", "temporal frequency, Hz: the cycles passing a point each second (the walls' drift)"),
    ("ρ", "Spearman's rank correlation, from −1 (falls throughout) to +1 (rises throughout)"),
    (
        "Page's L",
        "Page's test for a trend rising across three or more ordered conditions, seeds "
        "as blocks; p is one-sided",
    ),
    ("sign test", "the trend test for two conditions: how many seeds rise; p is one-sided"),
    (
        "95 % interval",
        "where the mean across seeds lies with 95 % confidence (Student's t, "
        "clipped to the quantity's range): mean [low, high]",
    ),
    ("p", "the chance of a trend at least this strong if there were none; below 0.05 counts"),
)


def notation_markdown(text: str, known: str = "") -> list[str]:
    """The key to the notation ``text`` uses: a Markdown table of :data:`NOTATION`'s entries
    that occur in it (``p`` where a p-value is given: ``p =``, ``p <`` or a ``| p |``
    column), leaving out those ``known`` (text an earlier key explained) uses."""

    def uses(symbol: str, s: str) -> bool:
        if symbol == "p":
            return any(k in s for k in ("p =", "p <", "| p |"))
        return symbol in s

    used = [(s, m) for s, m in NOTATION if uses(s, text) and not uses(s, known)]
    if not used:
        return []
    return ["| symbol | meaning |", "|---|---|", *(f"| {s} | {m} |" for s, m in used)]


# a claim's quantities, named for its row of the first table (claims.parquet keeps the names)
SHORT_NAMES = {
    "spearman_rho_vs_tf": "ρ along TF",
    "spearman_rho_vs_sf": "ρ along SF",
    "omega_dps_far_over_40cm": "ω̂ over 40 cm away (deg/s)",
    "omega_dps_near_under_10cm": "ω̂ within 10 cm (deg/s)",
    "omega_dps_whole_approach": "ω̂ over the approach (deg/s)",
    "near_wall_centre_ratio": "near-wall / centre ω̂",
    "success_rate": "success (0-1)",
    "avoidances_per_30min": "avoidances per 30 min",
    "pct_over_100 · avdm-released-units · all": "% of frames over 100",
    "pct_over_100 · avdm · all": "% of frames over 100 deg/s",
    "mean · avdm · straight": "mean ω̂ driving straight (deg/s)",
    "mean · avdm · all": "mean ω̂ (deg/s)",
}


def _condition(text: str) -> str:
    """``sf_upc=10`` → ``SF 10 upc``; ``tf_hz=5`` → ``TF 5 Hz``; others as they are."""
    if text.startswith("sf_upc="):
        return f"SF {text.split('=', 1)[1]} upc"
    if text.startswith("tf_hz="):
        return f"TF {text.split('=', 1)[1]} Hz"
    return text


def _short(q: Quantity) -> str:
    """A quantity's value for the first table: 3 significant digits, its 95 % interval."""
    if q.test == EXCLUDED:
        return "excluded"
    e, lo, hi = (_number(v, 3) for v in (q.estimate, q.ci_low, q.ci_high))
    return e if lo == "-" else f"{e} [{lo}, {hi}]"


def claim_numbers(c: Claim) -> str:
    """The numbers that decide a claim, for its row of the first table: the quantities its
    tests read (all of them where none is tested; never the supporting readings), and the
    collision phases' avoidances (the paper's column gives its own); grouped by quantity."""
    deciding = [q for q in c.quantities if q.test and "(supporting)" not in q.test]
    shown = [
        q
        for q in c.quantities
        if q in deciding or not deciding or q.quantity == "avoidances_per_30min"
    ]
    groups: dict[str, list[str]] = {}
    for q in shown:
        name = SHORT_NAMES.get(q.quantity, q.quantity.split(" · ")[0].replace("_", " "))
        groups.setdefault(name, []).append(f"{_condition(q.condition)}: {_short(q)}")
    return "; ".join(f"{name}: {', '.join(v)}" for name, v in groups.items()) or "-"


def provisional_note(plan: ReproduceSettings) -> str:
    """What a quick or custom plan's verdicts are worth ("" for the full plan)."""
    mode = plan.plan_name
    if mode == "full":
        return ""
    return (
        f"Provisional: these verdicts come from a {mode} run ({plan.profile_minutes:g}-min "
        f"profiling runs, {plan.collision_minutes:g}-min collision phases, {plan.seeds} seeds), "
        "shorter and with fewer seeds than the paper's protocol; `vdc-analyse reproduce` "
        "without --quick (30-min runs, 5 seeds) decides them."
    )


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
    banner = provisional_note(plan)
    tag = " (provisional)" if banner else ""
    title = '# vdc: reproducing "Profiling Visual Dynamic Complexity Using a Bio-Robotic Approach"'
    numbers = [claim_numbers(c) for c in claims]
    claim_rows = [
        "| # | claim | paper | ours: mean [95 % interval] | verdict |",
        "|---|---|---|---|---|",
        *(
            f"| {i} | {c.claim} | {c.paper} | {n} | **{c.verdict}**{tag} |"
            for i, (c, n) in enumerate(zip(claims, numbers, strict=True), 1)
        ),
    ]
    measured = [f"{i}. {c.measured}" for i, c in enumerate(claims, 1)]
    # every symbol explained before its first use: the claims table's above it, the rest
    # (the methods and the tables below) above those
    first = "\n".join([banner, head, *claim_rows])
    key = notation_markdown(first)
    rest = "\n".join([*measured, *(ln for _, lines in sections[:4] for ln in lines)])
    more = notation_markdown(rest, known=first)
    md = [title, ""]
    md += [f"**{banner}**", ""] if banner else []
    md += [head, ""]
    md += ["## Notation", "", *key, ""] if key else []
    md += ["## Claims", "", *claim_rows, ""]
    md += ["## More notation", "", *more, ""] if more else []
    md += ["## How each claim was measured", "", *measured]
    for name, lines in sections[:4]:
        md += ["", f"## {name}", "", *lines]
    md += ["", "## Figures", ""]
    md += [f"### {t}\n\n![{t}]({rel})\n" for t, rel in FIGURES if (out / rel).exists()]
    md += ["## Environment", "", *sections[4][1], ""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")

    rows = "".join(
        f"<tr><td>{i}</td><td>{html.escape(c.claim)}</td><td>{html.escape(c.paper)}</td>"
        f"<td>{html.escape(n)}</td><td class='{c.verdict.replace(' ', '-')}'>"
        f"{html.escape(c.verdict + tag)}</td></tr>"
        for i, (c, n) in enumerate(zip(claims, numbers, strict=True), 1)
    )
    figs = "".join(
        f"<h3>{html.escape(t)}</h3>{_img(out / rel)}" for t, rel in FIGURES if (out / rel).exists()
    )
    tables = "".join(
        f"<h2>{html.escape(name)}</h2>{_md_html(lines)}" for name, lines in sections[:4]
    )
    method = "".join(f"<li>{html.escape(c.measured)}</li>" for c in claims)
    code = re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(banner))  # Markdown's code
    warn = f"<p class='provisional'>{code}</p>" if banner else ""
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>vdc reproduction</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top}}
.holds{{background:#d4f4d4}}.partly{{background:#fff3c4}}.does-not-hold{{background:#f8d0d0}}
.provisional{{background:#fff3c4;border:1px solid #e0c060;padding:6px 10px;font-weight:bold}}
.key{{font-size:90%;color:#333}}</style></head><body><h1>vdc: reproducing the paper</h1>
{warn}<p>{html.escape(head)}</p>{_key_html(key, "Notation")}
<h2>Claims</h2><table><tr><th>#</th><th>claim</th><th>paper</th>
<th>ours: mean [95 % interval]</th><th>verdict</th></tr>
{rows}</table>{_key_html(more, "More notation")}
<h2>How each claim was measured</h2><ol>{method}</ol>{tables}<h2>Figures</h2>{figs}
<h2>Environment</h2>{_md_html(sections[4][1])}</body></html>"""
    html_path = out / "report.html"
    html_path.write_text(page, encoding="utf-8")
    return [md_path, html_path]


def _key_html(key: list[str], name: str) -> str:
    """A notation key as one compact paragraph (the first screen is for the claims)."""
    if not key:
        return ""
    rows = [r.strip("|").split("|", 1) for r in key[2:]]
    items = "; ".join(
        f"<b>{html.escape(sym.strip())}</b>: {html.escape(text.strip())}" for sym, text in rows
    )
    return f"<p class='key'><b>{html.escape(name)}.</b> {items}.</p>"


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

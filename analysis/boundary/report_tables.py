"""Markdown tables and interval cells of the boundary and adaptation reports."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import polars as pl


def markdown_table(df: pl.DataFrame, columns: Sequence[str], digits: int = 2) -> str:
    """A Markdown table of ``columns`` (numbers rounded)."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "—" if math.isnan(v) else f"{v:.{digits}f}"
        return str(v)

    head = "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n"
    body = "".join(
        "| " + " | ".join(cell(r[c]) for c in columns) + " |\n" for r in df.iter_rows(named=True)
    )
    return head + body


def interval(row: dict[str, Any], name: str, scale: float = 1.0, digits: int = 1) -> str:
    """``mean [low, high]`` of ``name`` in a statistics row."""
    mean_key = {"success": "success_rate", "complexity": "complexity_dps"}.get(name, name)
    m, lo, hi = (row[mean_key], row[f"{name}_low"], row[f"{name}_high"])
    if not (isinstance(m, int | float) and math.isfinite(m)):
        return "—"  # not measured: never "nan" in a report
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{m * scale:.{digits}f}"
    return f"{m * scale:.{digits}f} [{lo * scale:.{digits}f}, {hi * scale:.{digits}f}]"

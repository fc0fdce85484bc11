"""Small statistics shared by the analysis commands and the experiments."""

from __future__ import annotations

import numpy as np
import polars as pl


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman rank correlation (average ranks for ties); NaN if either side is constant."""
    df = pl.DataFrame({"x": x, "y": y})
    if df["x"].n_unique() < 2 or df["y"].n_unique() < 2:
        return float("nan")
    return float(df.select(pl.corr("x", "y", method="spearman")).item())

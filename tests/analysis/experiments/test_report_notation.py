"""report.html keys its notation (issue 43, item 5): every symbol the page uses (ω̂, upc, λ̂,
Page's L ...) is explained, and nothing the page does not use."""

from __future__ import annotations

import html
import re
from pathlib import Path

import pytest

from analysis.experiments import report
from analysis.experiments.claims import Claim, profiling_claims
from analysis.experiments.plan import ReproduceSettings
from tests.analysis.experiments.test_claims import _summary


def _key(page: str) -> dict[str, str]:
    """The Notation section's rows of a report.html: symbol -> meaning."""
    section = page.split("<h2>Notation</h2>", 1)[1].split("<h2>", 1)[0]
    rows = re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td></tr>", section)
    return {html.unescape(s): html.unescape(m) for s, m in rows[1:]}  # rows[0]: the header


def test_report_html_has_a_key_to_its_notation(tmp_path: Path, monkeypatch) -> None:
    # the runs' segments and the machines are read from files a real run writes; neither has
    # notation, so they are left out here
    monkeypatch.setattr(report, "segments_markdown", lambda out: "")
    monkeypatch.setattr(report, "environment_markdown", lambda out: [])
    claims = profiling_claims(_summary(lambda *a: (0.1 * a[1] + 0.01 * a[4], 5.0 + a[1], 1.2)))
    sweep = Claim(
        "The AVDM response maps monotonically onto SF–TF (Fig. 3)",
        "monotonic",
        "Spearman ρ of ω̂ along each row; SF = 50 upc is excluded.",
        "holds",
    )
    report.write_report(tmp_path, ReproduceSettings(), [sweep, *claims], 1.0)
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    key = _key(page)
    for symbol in ("ω̂", "λ̂", "R̄", "upc", "SF", "TF", "ρ", "Page's L", "95 % interval", "p"):
        assert symbol in key, (symbol, sorted(key))
    assert "deg/s" in key["ω̂"] and "px" in key["λ̂"] and "360°" in key["upc"]
    # only what the page uses: every symbol keyed occurs outside the key
    before, after = page.split("<h2>Notation</h2>", 1)
    rest = html.unescape(before + after.split("<h2>", 1)[1])
    for symbol in key:
        assert symbol in rest or (symbol == "p" and "p =" in rest), symbol
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "## Notation" in md and "| Page's L |" in md


@pytest.mark.parametrize(
    ("text", "symbols"),
    [
        ("mean ω̂ (deg/s), sign test p = 0.03", ["ω̂", "sign test", "p"]),
        ("no symbols here", []),
    ],
)
def test_the_key_lists_exactly_what_the_text_uses(text: str, symbols: list[str]) -> None:
    rows = report.notation_markdown(text)
    assert [r.split(" | ")[0].lstrip("| ") for r in rows[2:]] == symbols

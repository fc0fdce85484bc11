"""report.html keys its notation (issue 43, item 5): every symbol the page uses (ω̂, upc, λ̂,
Page's L ...) is explained, and nothing the page does not use."""

from __future__ import annotations

import html
import re
from pathlib import Path

import pytest

from analysis.experiments.paper import report
from analysis.experiments.paper.claims import Claim, profiling_claims
from analysis.experiments.paper.plan import ReproduceSettings
from tests.analysis.experiments.paper.test_claims import _summary

KEY = re.compile(r"<p class='key'><b>(?:Notation|More notation)\.</b> (.*?)\.</p>", re.S)


def _key(page: str) -> dict[str, str]:
    """The notation keys of a report.html (a short one above the claims, the rest before the
    methods: the first screen is for the claims): symbol -> meaning."""
    rows = [
        row
        for k in KEY.findall(page)
        for row in re.findall(r"<b>(.*?)</b>: (.*?)(?:; (?=<b>)|$)", k)
    ]
    return {html.unescape(s): html.unescape(m) for s, m in rows}


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
    assert len(KEY.findall(page)) >= 1  # the first key is above the claims
    assert page.index("<b>Notation.</b>") < page.index("<h2>Claims</h2>")
    rest = html.unescape(KEY.sub("", page))
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

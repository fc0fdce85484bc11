"""The docs hold together: the API reference builds from the docstrings with every public name
and settings field described and no link leading nowhere; every dotted name the README and
docs/ give in backticks imports; every anchor of a link names a heading of its page; every
docs/ page the code names exists."""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import re
from functools import cache
from pathlib import Path
from types import ModuleType

import pytest

import vdc
from tests.helpers import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


@cache
def api_reference() -> ModuleType:
    """docs/api_reference.py, the reference's builder (a script, not a package module)."""
    spec = importlib.util.spec_from_file_location("api_reference", ROOT / "docs/api_reference.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# -- the API reference ----------------------------------------------------------------------


def html_ids_and_links(folder: Path) -> tuple[dict[str, set[str]], list[tuple[str, str]]]:
    """Per HTML file of ``folder``: its ids; and every (file, href) that is not a web address."""
    ids, links = {}, []
    for page in folder.glob("*.html"):
        text = page.read_text()
        ids[page.name] = set(re.findall(r'\bid="([^"]+)"', text))
        links += [
            (page.name, href)
            for href in re.findall(r'\bhref="([^"]*)"', text)
            if not re.match(r"[a-z]+:", href)
        ]
    return ids, links


def broken_links(folder: Path) -> list[str]:
    """Links of the HTML in ``folder`` to a file it does not hold or an id that file lacks."""
    ids, links = html_ids_and_links(folder)
    broken = []
    for page, href in links:
        target, _, anchor = href.partition("#")
        target = target or page
        if target not in ids and not (folder / target).exists():
            broken.append(f"{page}: {href}")
        elif anchor and anchor not in ids.get(target, set()):
            broken.append(f"{page}: {href}")
    return broken


def test_the_api_reference_describes_every_public_name_and_field(tmp_path: Path) -> None:
    api = api_reference()
    assert api.missing_texts() == []  # a docstring per name, a text per settings field
    api.build(tmp_path)
    page = (tmp_path / "vdc.html").read_text()
    ids = set(re.findall(r'\bid="([^"]+)"', page))
    assert set(vdc.__all__) <= ids, sorted(set(vdc.__all__) - ids)
    assert broken_links(tmp_path) == []
    # a settings field shows its unit, default and flag; a function its result's fields
    tf = page[page.index('id="SimSettings.tf_hz"') :][:3000]
    assert "wall drift temporal frequency, Hz (default: 0.0)" in tf and "--tf-hz" in tf
    tables = page[page.index('id="tables"') :]
    assert "<strong>Returns</strong> <code>TablesResult</code>" in tables[:20000]


@dataclasses.dataclass
class _Undescribed:
    width_px: int = 3


@dataclasses.dataclass
class _Described:
    """A box."""

    width_px: int = 3  # its width, px


def test_the_reference_check_finds_a_missing_docstring_and_field_text(tmp_path: Path) -> None:
    api = api_reference()
    assert api.missing_texts({"Undescribed": _Undescribed}) == [
        "vdc.Undescribed: no docstring",
        "vdc.Undescribed.width_px: no help, comment or mention",
    ]
    assert api.missing_texts({"Described": _Described}) == []
    assert api.field_text(_Described, dataclasses.fields(_Described)[0]) == "Its width, px."
    (tmp_path / "a.html").write_text('<p id="x"><a href="#x">x</a><a href="#gone">y</a></p>')
    (tmp_path / "b.html").write_text('<a href="a.html#x">x</a><a href="c.html">z</a>')
    assert sorted(broken_links(tmp_path)) == ["a.html: #gone", "b.html: c.html"]


def test_the_api_index_page_is_current() -> None:
    fix = "python docs/api_reference.py --markdown > docs/api.md"
    assert (ROOT / "docs/api.md").read_text() == api_reference().markdown_index(), (
        f"docs/api.md is stale: regenerate it with {fix}"
    )


# -- dotted names in the docs -----------------------------------------------------------------

_CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.S)
_DOTTED = re.compile(r"(?<![\w./-])((?:vdc|analysis|avdm|capture)(?:\.[A-Za-z_]\w*)+)")
# names in backticks that are not Python: Parquet metadata keys, an entry-point group, files
NOT_PYTHON = {"vdc.versions", "vdc.machine", "vdc.models"}
FILE_SUFFIXES = (".py", ".md", ".rrd", ".csv", ".json", ".parquet", ".png", ".pyi", ".html")


def dotted_names(text: str) -> set[str]:
    """The dotted names starting with vdc., analysis., avdm. or capture. in code spans
    (``...`` and `...`), outside fenced blocks (those run as tests)."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    names = set()
    for span in _CODE_SPAN.finditer(text):
        for name in _DOTTED.findall(span.group(2)):
            if name not in NOT_PYTHON and not name.endswith(FILE_SUFFIXES):
                names.add(name)
    return names


def resolves(name: str) -> bool:
    """Whether ``name`` is a module, or an attribute path from the longest module in it."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_every_dotted_name_in_the_docs_imports() -> None:
    names = {
        (page.relative_to(ROOT).as_posix(), n)
        for page in PAGES
        for n in dotted_names(page.read_text())
    }
    assert len(names) > 50  # the scan sees them
    assert not [f"{page}: `{name}`" for page, name in sorted(names) if not resolves(name)]


def test_the_dotted_name_check_finds_a_stale_name() -> None:
    text = (
        "the table named `analysis.catalog.build.serve` / `query`; ``vdc.catalog.query(x)``,\n"
        "`vdc.versions`, `analysis.py`, and\n```bash\npython -m analysis.gone\n```\n"
    )
    assert dotted_names(text) == {"analysis.catalog.build.serve", "vdc.catalog.query"}
    assert not resolves("analysis.catalog.build.serve")  # it lives in analysis.catalog.server
    assert resolves("vdc.catalog.query") and resolves("analysis.catalog.server.serve")


# -- links and anchors ------------------------------------------------------------------------


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation but - and _ dropped, spaces
    to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


@cache
def anchors(page: Path) -> set[str]:
    """The anchors of a Markdown page's headings (a repeated one gets -1, -2, ...)."""
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)
    found: set[str] = set()
    for heading in re.findall(r"^#+ (.+)$", text, re.M):
        base = slug(heading)
        name, k = base, 0
        while name in found:
            k += 1
            name = f"{base}-{k}"
        found.add(name)
    return found


def test_every_link_anchor_names_a_heading_of_its_page() -> None:
    """The link test (tests/test_layout.py) checks that a link's file exists; this one that
    the part after # is a heading there, in the README and every page of docs/."""
    broken = []
    for page in PAGES:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+://|mailto:", target) or "#" not in target:
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if file.suffix == ".md" and file.exists() and anchor not in anchors(file):
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, broken


def test_the_anchor_check_finds_a_missing_heading(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text(
        "# A page\n\n## Per scene: the scene as a factor (`--per-scene`)\n\n## A page\n"
    )
    assert anchors(page) == {"a-page", "per-scene-the-scene-as-a-factor---per-scene", "a-page-1"}
    assert "speed" not in anchors(page)


@pytest.mark.parametrize("package", ["vdc", "avdm", "capture", "analysis", "benchmarks", "tests"])
def test_every_docs_page_the_code_names_exists(package: str) -> None:
    """Help texts, comments and docstrings name docs/ pages (``docs/guides/boundary.md#scenes``):
    each exists, and so does its anchor."""
    missing = []
    for source in sorted((ROOT / package).rglob("*.py")):
        for path, anchor in re.findall(r"\b(docs/[\w/]+\.md)(?:#([\w-]+))?", source.read_text()):
            file = ROOT / path
            if not file.exists() or (anchor and anchor not in anchors(file)):
                missing.append(f"{source.relative_to(ROOT)}: {path}#{anchor}")
    assert not missing, missing

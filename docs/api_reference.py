"""The API reference: every public name of ``import vdc`` (``vdc.__all__``), built with pdoc.

    python docs/api_reference.py build/api      # HTML into build/api (open build/api/vdc.html)
    python docs/api_reference.py --markdown     # prints docs/api.md, the index of the names

pdoc renders the docstrings; this script adds what pdoc cannot read by itself: each settings
field's text (its flag's help, with its unit, its default and its flag, or the comment beside
the field where it has no flag) and, under each function, the fields of the result it returns.
``tests/test_docs.py`` builds it and fails on a name or a field without its text and on a link
that leads nowhere.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import re
import sys
import textwrap
import tokenize
import typing
from pathlib import Path
from typing import Any

PACKAGE = "vdc"


def public_objects() -> dict[str, Any]:
    """``vdc.__all__``: each public name and the object it gives."""
    import vdc

    return {name: getattr(vdc, name) for name in vdc.__all__}


def own_docstring(obj: Any) -> str:
    """The object's docstring as written (a dataclass's generated signature is none)."""
    doc = inspect.getdoc(obj) or ""
    if dataclasses.is_dataclass(obj) and doc.startswith(f"{obj.__name__}("):
        return ""
    return doc


def _field_comments(cls: type) -> dict[str, str]:
    """name -> the comment on a dataclass field's line(s), from the class that defines it
    (its bases first, so a subclass's own comment wins)."""
    comments: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        by_line: dict[int, str] = {}
        for tok in tokenize.generate_tokens(io.StringIO(source).readline):
            if tok.type == tokenize.COMMENT:
                by_line[tok.start[0]] = tok.string.lstrip("#").strip()
        source_lines = source.splitlines()
        (node,) = ast.parse(source).body
        for stmt in getattr(node, "body", []):
            if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
                above = stmt.lineno - 1  # a block of comment lines just above the field
                while above >= 1 and source_lines[above - 1].lstrip().startswith("#"):
                    above -= 1
                lines = range(above + 1, (stmt.end_lineno or stmt.lineno) + 1)
                text = " ".join(by_line[n] for n in lines if n in by_line)
                if text and not text.startswith(("fmt:", "noqa", "type:")):
                    comments[stmt.target.id] = text
    return comments


def field_text(cls: type, field: dataclasses.Field) -> str:
    """What a field means: its flag's help (units included), its default and its flag; or the
    comment beside it; or its mention in the class's docstring; "" where it has none."""
    from vdc.cli_support import stated_default

    flag = field.metadata.get("flag")
    if flag is not None and flag.help:
        default = stated_default(field)  # as the command line's help states it
        text = flag.help.rstrip(".")
        if "{default}" in text:
            text = text.replace("{default}", default)
        elif default:
            text += f" (default: {default})"
        name = flag.flag or f"--{field.name.replace('_', '-')}"
        return f"{text}. Flag `{name}`." if not flag.positional else f"{text}. Argument."
    comment = _field_comments(cls).get(field.name, "")
    if comment:
        return comment[0].upper() + comment[1:] + ("" if comment.endswith(".") else ".")
    if f"``{field.name}``" in own_docstring(cls):
        return f"See {cls.__name__}'s description above."
    return ""


def _type_name(tp: Any) -> str:
    text = tp if isinstance(tp, str) else getattr(tp, "__name__", None) or repr(tp)
    return str(text).replace("typing.", "")


def result_section(func: Any) -> str:
    """Markdown for a function's result: its class's description and fields ("" when the
    function returns no dataclass)."""
    try:
        result = typing.get_type_hints(func).get("return")
    except Exception:  # an annotation that does not resolve here: no section, the signature says
        return ""
    if not (inspect.isclass(result) and dataclasses.is_dataclass(result)):
        return ""
    lines = [f"**Returns** `{result.__name__}`: {own_docstring(result) or ''}".rstrip(), ""]
    for f in dataclasses.fields(result):
        if f.name.startswith("_"):
            continue
        text = field_text(result, f)
        lines.append(f"- `{f.name}` (`{_type_name(f.type)}`)" + (f": {text}" if text else ""))
    props = [
        name
        for name, value in inspect.getmembers(result)
        if isinstance(value, property) and not name.startswith("_")
    ]
    if props:
        lines.append(f"- and {', '.join(f'`{p}`' for p in props)}")
    return "\n".join(lines)


def missing_texts(objects: dict[str, Any] | None = None) -> list[str]:
    """Every public name (of ``objects``, by default ``vdc.__all__``'s) without a docstring, and
    every field of a public dataclass without a text (``field_text``)."""
    missing = []
    for name, obj in (public_objects() if objects is None else objects).items():
        if inspect.ismodule(obj):
            continue
        if not own_docstring(obj):
            missing.append(f"vdc.{name}: no docstring")
        if inspect.isclass(obj) and dataclasses.is_dataclass(obj):
            for f in dataclasses.fields(obj):
                if f.init and not field_text(obj, f):
                    missing.append(f"vdc.{name}.{f.name}: no help, comment or mention")
    return missing


def reference_module() -> Any:
    """pdoc's view of ``vdc`` with the field texts and result sections filled in."""
    import pdoc.doc  # lazy: optional extra (test)

    public_objects()  # pdoc reads the module's __dict__: load the lazy names into it first
    module = pdoc.doc.Module.from_name(PACKAGE)
    for member in module.members.values():
        obj = member.obj
        if isinstance(member, pdoc.doc.Class) and dataclasses.is_dataclass(obj):
            fields = {f.name: f for f in dataclasses.fields(obj)}
            for var in member.members.values():
                if var.name in fields and isinstance(var, pdoc.doc.Variable):
                    var.docstring = field_text(obj, fields[var.name])  # cached_property: set
        elif isinstance(member, pdoc.doc.Function):
            extra = result_section(obj)
            if extra:
                member.docstring = f"{member.docstring}\n\n{extra}"
    return module


def build(out: Path) -> list[Path]:
    """Write the HTML reference into ``out``; the files written."""
    import pdoc.render  # lazy: optional extra (test)

    module = reference_module()
    modules = {PACKAGE: module}
    out.mkdir(parents=True, exist_ok=True)
    page = out / f"{PACKAGE}.html"
    page.write_text(_inherited_links(pdoc.render.html_module(module, modules)))
    index = out / "index.html"
    index.write_text(pdoc.render.html_index(modules))
    search = out / "search.js"
    search.write_text(pdoc.render.search_index(modules))
    return [page, index, search]


def _inherited_links(html: str) -> str:
    """pdoc links ``name`` in a docstring to ``#Class.name`` even where ``name`` is inherited
    from a base (``CampaignSettings.executor``), whose section is the base's: point each such
    link at the public base that has it."""
    ids = set(re.findall(r'\bid="([^"]+)"', html))
    objects = public_objects()
    public = {obj: name for name, obj in objects.items() if inspect.isclass(obj)}

    def fix(match: re.Match[str]) -> str:
        cls_name, _, member = match.group(1).partition(".")
        if match.group(1) in ids or not member or cls_name not in objects:
            return match.group(0)
        for base in inspect.getmro(objects[cls_name])[1:]:
            if base in public and f"{public[base]}.{member}" in ids:
                return f'href="#{public[base]}.{member}"'
        return match.group(0)

    return re.sub(r'href="#([\w.]+)"', fix, html)


def markdown_index() -> str:
    """The text of docs/api.md: how to build the reference, and each public name with the
    first line of its docstring."""
    rows = []
    for name, obj in public_objects().items():
        first = own_docstring(obj).split("\n\n")[0].replace("\n", " ").replace("|", "\\|")
        kind = "class" if inspect.isclass(obj) else "function"
        rows.append(f"| `vdc.{name}` | {kind} | {first} |")
    return (
        "# API reference\n\n"
        "[← README](../README.md) · [in Python](guides/python.md) · [CLI reference](cli.md)\n\n"
        "Every public name of `import vdc`, with the first line of its docstring. The full "
        "reference (each settings field with its unit, default and flag; each function's "
        "result and its fields) is built from the docstrings with "
        "[pdoc](https://pdoc.dev) (the test extra):\n\n"
        "    python docs/api_reference.py build/api    # then open build/api/vdc.html\n\n"
        "This page is generated: "
        "`python docs/api_reference.py --markdown > docs/api.md`.\n\n"
        "| name | kind | what it is |\n|---|---|---|\n" + "\n".join(rows) + "\n"
    )


def main(argv: list[str]) -> int:
    if argv == ["--markdown"]:
        sys.stdout.write(markdown_index())
        return 0
    if len(argv) != 1:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    for path in build(Path(argv[0])):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Parameter tables of the docs, generated from the code's config dataclasses.

A docs page asks for a table with a pair of marker lines::

    <!-- params: darces_matcher.config.MatchConfig -->
    <!-- /params -->

and this script fills the lines between them with one row per dataclass field: its name,
its default and the first sentence of its entry in the class docstring's ``Attributes:``
section. ``--check`` (what the docs test runs) exits 1 naming every table that differs from
the code; ``--write`` rewrites the tables in place.

Usage: ``python scripts/param_tables.py --check|--write [PAGE.md ...]`` (default: docs/*.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"^<!-- params: (?P<target>[\w.]+) -->$")
END = "<!-- /params -->"


def attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> its description in the Google-style ``Attributes:`` section."""
    doc = cls.__doc__ or ""
    lines = doc.expandtabs().splitlines()
    out: dict[str, str] = {}
    inside, indent, name = False, None, None
    for line in lines:
        stripped = line.strip()
        if stripped == "Attributes:":
            inside, indent, name = True, None, None
            continue
        if not inside:
            continue
        if not stripped:
            continue
        lead = len(line) - len(line.lstrip())
        if indent is None:
            indent = lead
        if lead < indent:  # the section ended (e.g. "Raises:")
            break
        m = re.match(r"^(\w+)(?: \([^)]*\))?:\s*(.*)$", stripped)
        if lead == indent and m:
            name = m.group(1)
            out[name] = m.group(2)
        elif name is not None:
            out[name] = (out[name] + " " + stripped).strip()
    return out


def comment_docs(cls: type) -> dict[str, str]:
    """Field name -> its ``#:`` comment (on the field's line or the lines above it)."""
    try:
        lines = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):
        return {}
    out: dict[str, str] = {}
    above: list[str] = []
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#:"):
            above.append(stripped[2:].strip())
            continue
        m = re.match(r"^(\w+)\s*:[^=#]*(?:=[^#]*)?(?:#:\s*(.*))?$", stripped)
        if m and not stripped.startswith(("def ", "class ", "return")):
            text = " ".join(above + ([m.group(2)] if m.group(2) else []))
            if text:
                out[m.group(1)] = text
        above = []
    return out


def first_sentence(text: str) -> str:
    """The description up to its first full stop followed by a space (or all of it)."""
    m = re.search(r"\.(\s|$)", text)
    sentence = text[: m.start() + 1] if m else text
    return sentence.replace("|", "\\|").strip()


def default_of(field: dataclasses.Field) -> str:
    if field.default is not dataclasses.MISSING:
        value = field.default
    elif field.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        value = field.default_factory()  # type: ignore[misc]
        if dataclasses.is_dataclass(value):
            return f"see `{type(value).__name__}`"
    else:
        return "required"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, tuple):
        value = list(value)
    return f"`{value!r}`"


def resolve(target: str) -> type:
    module, _, name = target.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise LookupError(f"{target}: no such class ({exc})") from exc
    if not dataclasses.is_dataclass(cls):
        raise LookupError(f"{target}: not a dataclass")
    return cls


def table(target: str) -> list[str]:
    """The markdown rows of ``target``'s parameter table."""
    cls = resolve(target)
    docs = {**comment_docs(cls), **attribute_docs(cls)}
    rows = ["| parameter | default | what it does |", "|---|---|---|"]
    for field in dataclasses.fields(cls):
        if field.name.startswith("_"):
            continue
        text = first_sentence(docs.get(field.name, ""))
        if not text:
            raise LookupError(f"{target}.{field.name}: no entry in the class's Attributes: section")
        rows.append(f"| `{field.name}` | {default_of(field)} | {text} |")
    return rows


def render(page: Path) -> tuple[str, list[str]]:
    """The page with its tables regenerated, and the targets it holds."""
    lines = page.read_text().splitlines()
    out: list[str] = []
    targets: list[str] = []
    i = 0
    while i < len(lines):
        m = MARKER.match(lines[i].strip())
        out.append(lines[i])
        i += 1
        if not m:
            continue
        targets.append(m.group("target"))
        j = i
        while j < len(lines) and lines[j].strip() != END:
            if MARKER.match(lines[j].strip()):
                break
            j += 1
        if j >= len(lines) or lines[j].strip() != END:
            raise LookupError(f"{page}: table {m.group('target')} has no closing '{END}' line")
        out.extend(table(m.group("target")))
        i = j  # the END line is appended by the loop
    return "\n".join(out) + "\n", targets


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="exit 1 when a table differs")
    mode.add_argument("--write", action="store_true", help="rewrite the tables in place")
    parser.add_argument("pages", nargs="*", type=Path)
    args = parser.parse_args(argv)
    pages = args.pages or sorted((ROOT / "docs").glob("*.md"))
    stale = []
    for page in pages:
        try:
            text, targets = render(page)
        except LookupError as exc:
            print(f"param_tables: {exc}", file=sys.stderr)
            return 1
        if text != page.read_text():
            if args.write:
                page.write_text(text)
                print(f"param_tables: wrote {len(targets)} table(s) in {page}")
            else:
                stale.append(f"{page}: {', '.join(targets)}")
    for line in stale:
        print(f"param_tables: stale table(s) in {line} (run scripts/param_tables.py --write)",
              file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())

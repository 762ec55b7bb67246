"""The reference docs agree with the code, and the project's text speaks of the project.

- every parameter table in docs/ is the one scripts/param_tables.py generates from the code,
  and every config dataclass of the packages has a table;
- README and docs stay short enough to read (README 150 lines, docs/ 3,000);
- no work-history labels (rounds of work, issue numbers, dated experiment headings) in the
  README, docs, code, bench scripts or Makefile: history is git's and CHANGELOG.md's.
"""

from __future__ import annotations

import ast
import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "ros2_ws" / "src"


def _param_tables():
    script = ROOT / "scripts" / "param_tables.py"
    spec = importlib.util.spec_from_file_location("param_tables", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _config_classes() -> dict[str, int]:
    """``package.module.Class`` -> field count, for every config dataclass of the packages."""
    found = {}
    for path in sorted(SRC.glob("*/*/*.py")):
        if path.parent.name != path.parent.parent.name:  # only <pkg>/<pkg>/*.py
            continue
        tree = ast.parse(path.read_text())
        for node in tree.body:
            if not isinstance(node, ast.ClassDef):
                continue
            named = node.name.endswith(("Config", "Options", "Thresholds"))
            if not (named or node.name == "Recipe"):
                continue
            decorated = any("dataclass" in ast.unparse(d) for d in node.decorator_list)
            if not decorated:
                continue
            fields = sum(1 for b in node.body if isinstance(b, ast.AnnAssign))
            found[f"{path.parent.name}.{path.stem}.{node.name}"] = fields
    return found


def test_parameter_tables_match_the_code(capsys):
    tables = _param_tables()
    assert tables.main(["--check"]) == 0, capsys.readouterr().err


def test_every_config_dataclass_has_a_table():
    tables = _param_tables()
    documented = set()
    for page in sorted((ROOT / "docs").glob("*.md")):
        _, targets = tables.render(page)
        documented.update(targets)
    missing = sorted(set(_config_classes()) - documented)
    assert not missing, f"config dataclasses without a docs parameter table: {missing}"


def test_configuration_fits_in_a_head():
    counts = _config_classes()
    assert sum(counts.values()) <= 200, counts


def test_param_table_generator_reads_attributes(tmp_path):
    tables = _param_tables()
    page = tmp_path / "page.md"
    page.write_text("# x\n<!-- params: darces_matcher.config.MatchConfig -->\nstale\n"
                    "<!-- /params -->\n")
    assert tables.main(["--check", str(page)]) == 1
    assert tables.main(["--write", str(page)]) == 0
    text = page.read_text()
    assert "stale" not in text and "| parameter | default | what it does |" in text
    assert tables.main(["--check", str(page)]) == 0
    page.write_text("<!-- params: darces_matcher.config.NoSuchConfig -->\n<!-- /params -->\n")
    assert tables.main(["--check", str(page)]) == 1


def test_readme_and_docs_are_short():
    readme = (ROOT / "README.md").read_text().splitlines()
    assert len(readme) <= 150, f"README.md has {len(readme)} lines"
    docs = sum(len(p.read_text().splitlines()) for p in (ROOT / "docs").glob("*.md"))
    assert docs <= 3000, f"docs/ has {docs} lines"


HISTORY = re.compile(
    r"\b(?:(?:\d+(?:st|nd|rd|th)|first|second|third|fourth|fifth|sixth|seventh|eighth|ninth"
    r"|tenth|eleventh|twelfth|\w+teenth|twentieth|thirtieth|this|last|previous|earlier|later)"
    r" session|session \d+"
    r"|(?:twenty|thirty)-?(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth)"
    r"|(?:fourteen|fifteen|sixteen|seventeen|eighteen|nineteen|twentie|thirtie)th"
    r"|issues? \d+|issue-\d+)\b",
    re.IGNORECASE,
)


def _project_text() -> list[Path]:
    paths = [ROOT / "README.md", ROOT / "Makefile"]
    paths += sorted((ROOT / "docs").rglob("*.md"))
    paths += sorted(SRC.rglob("*.py")) + sorted(SRC.rglob("*.yaml"))
    paths += sorted(SRC.rglob("README.md"))
    paths += sorted((ROOT / "bench").glob("*.py")) + sorted((ROOT / "scripts").glob("*"))
    return [p for p in paths if p.is_file()]


@pytest.mark.parametrize("path", _project_text(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_work_history_labels(path):
    hits = [f"{i}: {line.strip()}" for i, line in enumerate(path.read_text().splitlines(), 1)
            if HISTORY.search(line)]
    where = path.relative_to(ROOT)
    assert not hits, f"{where} names rounds of work or issues:\n" + "\n".join(hits[:10])

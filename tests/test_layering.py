"""The packages are layered as docs/architecture.md draws them.

Checked on the source, by the imports each module makes (at its top or inside functions):
- no import cycle between the modules of the project;
- a CLI module (``cli.py``, ``*_cli.py``, ``__main__.py``) is imported by no other module:
  CLIs parse arguments and call libraries, nodes and libraries never import a CLI;
- a package imports only the packages below it (``ALLOWED``): the detection library never
  runs the matcher, the matcher never reaches into the detector, nothing but the bringup
  imports rover_bringup.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest

SRC = Path(__file__).resolve().parents[1] / "ros2_ws" / "src"

#: package -> the project packages its modules may import.
ALLOWED = {
    "roi_network": set(),
    "atacama_sim": {"roi_network"},
    "roi_detector": {"roi_network"},
    "orbital_gn": {"roi_network", "roi_detector"},
    "rover_vo": {"roi_network"},
    "darces_matcher": {"roi_network"},
    "rover_bringup": {"roi_network", "atacama_sim", "orbital_gn", "roi_detector", "rover_vo",
                      "darces_matcher"},
}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in ALLOWED:
        for path in sorted((SRC / pkg / pkg).rglob("*.py")):
            rel = path.relative_to(SRC / pkg).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def _graph() -> nx.DiGraph:
    modules = _modules()
    graph = nx.DiGraph()
    graph.add_nodes_from(modules)
    for name, path in modules.items():
        for target in _imports(name, path, set(modules)):
            if target not in ALLOWED:  # a package's __init__ is no module of its own here
                graph.add_edge(name, target)
    return graph


def _is_cli(module: str) -> bool:
    leaf = module.rpartition(".")[2]
    return leaf in ("cli", "__main__") or leaf.endswith("_cli")


def test_no_import_cycle():
    cycles = list(nx.simple_cycles(_graph()))
    assert not cycles, f"import cycles: {cycles[:5]}"


def test_no_module_imports_a_cli():
    bad = [(a, b) for a, b in _graph().edges if _is_cli(b) and not _is_cli(a)]
    assert not bad, f"modules importing a CLI module: {bad}"


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_packages_import_only_the_packages_below(package):
    allowed = ALLOWED[package] | {package}
    bad = sorted({(a, b) for a, b in _graph().edges
                  if a.split(".")[0] == package and b.split(".")[0] not in allowed})
    assert not bad, f"{package} imports beyond {sorted(ALLOWED[package])}: {bad}"


def test_the_check_sees_an_import_cycle(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "a.py").write_text("from pkg.b import f\n")
    (pkg / "b.py").write_text("def f():\n    from pkg import a\n")
    known = {"pkg.a", "pkg.b"}
    assert _imports("pkg.a", pkg / "a.py", known) == {"pkg.b"}
    assert _imports("pkg.b", pkg / "b.py", known) == {"pkg.a"}

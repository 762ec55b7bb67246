"""bench/darces_bench.py generality: a tagged table stands beside the main one."""

from __future__ import annotations

import json

import pytest


@pytest.fixture(scope="module")
def bench(bench_script):
    return bench_script("darces_bench")


def test_a_tagged_generality_table_is_its_own(bench, tmp_path, monkeypatch):
    monkeypatch.setattr(bench, "RESULTS", tmp_path)
    monkeypatch.setattr(bench, "WORK", tmp_path / "work")
    main = tmp_path / "darces_generality.md"
    main.write_text("the main table\n")
    bench.generality(["poisson_50"], 2, 0, 7, ["darces"], tag="large")
    assert main.read_text() == "the main table\n"
    report = json.loads((tmp_path / "darces_generality_large.json").read_text())
    assert [r["gn"] for r in report["rows"]] == ["poisson_50"]
    assert report["rows"][0]["clean"]["lns"] == 2
    assert "stress" not in report["rows"][0]
    assert "--methods darces --tag large --gns poisson_50" in report["command"]
    assert report["command"].endswith("generality --merge --tag large")
    table = (tmp_path / "darces_generality_large.md").read_text()
    assert "| poisson_50 |" in table
    assert (tmp_path / "work" / "darces_generality_large_parts" / "poisson_50.json").exists()
    # The merge rebuilds the tagged table from its own rows only.
    (tmp_path / "darces_generality_large.md").unlink()
    bench.merge_generality("large")
    assert (tmp_path / "darces_generality_large.md").read_text() == table
    assert main.read_text() == "the main table\n"

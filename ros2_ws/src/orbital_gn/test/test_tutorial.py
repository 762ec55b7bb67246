"""docs/orbital_labels.md's commands, as written, on images and labels made at test time."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest
from orbital_scene import make_labelled_image

from orbital_gn.cli import main

TUTORIAL = Path(__file__).resolve().parents[4] / "docs" / "orbital_labels.md"


def tutorial_commands() -> list[str]:
    """The lines of the fenced block after the ``<!-- tutorial -->`` marker."""
    text = TUTORIAL.read_text()
    block = re.search(r"<!-- tutorial -->\n```bash\n(.*?)```", text, re.S)
    assert block, f"{TUTORIAL}: no tutorial block"
    return [ln for ln in block.group(1).splitlines() if ln.strip()]


@pytest.mark.skipif(not TUTORIAL.is_file(), reason="docs/ not beside the package")
def test_the_tutorial_runs(tmp_path, monkeypatch, capsys):
    for name, seed in (("site_a", 101), ("site_b", 102), ("site_c", 103)):
        image, labels = make_labelled_image(tmp_path, seed)
        image.rename(tmp_path / f"{name}.tif")
        labels.rename(tmp_path / f"{name}_labels.geojson")
    region = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {},
              "geometry": {"type": "Polygon", "coordinates": [[[-75, -30], [-65, -30],
                                                               [-65, -20], [-75, -20],
                                                               [-75, -30]]]}}]}
    (tmp_path / "site_a_region.geojson").write_text(json.dumps(region))
    monkeypatch.chdir(tmp_path)
    commands = tutorial_commands()
    assert [c.split()[:2] for c in commands] == [["orbital_gn", "train"], ["orbital_gn", "eval"],
                                                 ["orbital_gn", "prepare"]]
    for cmd in commands:
        args = [*shlex.split(cmd)[1:], "--scheduler", "sync"]
        if args[0] == "prepare":
            args.append("--no-progress")
        assert main(args) == 0, (cmd, capsys.readouterr().err)
    ev = json.loads((tmp_path / "site_c_eval.json").read_text())
    assert ev["rock"]["recall"] > 0.7 and ev["outcrop"]["recall"] >= 0.75
    gn = json.loads((tmp_path / "site_c_gn.geojson").read_text())
    assert gn["metadata"]["domain_check"]["status"] in ("ok", "warn")

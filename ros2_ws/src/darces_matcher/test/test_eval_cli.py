"""The ``darces_eval`` CLI: report fields, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from darces_matcher.eval_cli import main
from darces_matcher.gn_generator import GnSpec, generate_gn


@pytest.fixture(scope="module")
def gn_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    geojson = pytest.importorskip("roi_network.geojson")
    path = tmp_path_factory.mktemp("gn") / "gn.geojson"
    geojson.write_geojson(generate_gn(GnSpec(n_rois=120), seed=3), path)
    return path


def test_report_fields(gn_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.json"
    code = main(["--gn", str(gn_file), "--max-lns", "8", "--outliers", "0.2",
                 "--methods", "darces,darces_original", "--json", str(out)])
    assert code == 0
    report = json.loads(out.read_text())
    assert report["lns"] == 8
    assert report["options"]["outliers"] == 0.2
    for name in ("darces", "darces_original"):
        r = report["methods"][name]
        assert r["lns"] == 8
        assert r["correct"] + r["false_fix"] + r["no_fix"] == 8
        assert r["correct_match"] + r["false_match"] + r["no_fix"] == 8
        assert abs(r["correct_rate"] + r["false_fix_rate"] + r["no_fix_rate"] - 1) < 1e-9
        assert r["time_ms"]["median"] > 0 and r["time_ms"]["p95"] >= r["time_ms"]["median"]
    assert report["methods"]["darces"]["false_match"] == 0


def test_corrupt_gn_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.geojson"
    bad.write_text("{ not json")
    assert main(["--gn", str(bad), "--json", str(tmp_path / "o.json")]) == 1
    assert "cannot read the GN" in capsys.readouterr().err
    missing = tmp_path / "missing.geojson"
    assert main(["--gn", str(missing), "--json", str(tmp_path / "o.json")]) == 1


def test_empty_gn_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty.geojson"
    empty.write_text(json.dumps({
        "type": "FeatureCollection",
        "metadata": {"crs": "EPSG:32719", "map_origin": [0.0, 0.0]},
        "features": [],
    }))
    code = main(["--gn", str(empty), "--json", str(tmp_path / "o.json")])
    assert code == 1
    assert "GN" in capsys.readouterr().err


def test_bad_options(tmp_path: Path) -> None:
    out = str(tmp_path / "o.json")
    assert main(["--synthetic", "60", "--methods", "nope", "--json", out]) == 2
    assert main(["--synthetic", "60", "--outliers", "1.5", "--json", out]) == 2


def test_baseline_subset(gn_file: Path, tmp_path: Path) -> None:
    """The baseline sees the first N LNs; darces is also summarised on them."""
    out = tmp_path / "out.json"
    assert main(["--gn", str(gn_file), "--max-lns", "6", "--baseline-max-lns", "3",
                 "--methods", "darces,darces_original", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["methods"]["darces"]["lns"] == 6
    assert report["methods"]["darces"]["same_subset_as_baselines"]["lns"] == 3
    assert report["methods"]["darces_original"]["lns"] == 3


def test_gn_smaller_than_a_route_is_a_clear_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 40 ROIs in a 100 m square: no two are 600 m apart, so the protocol has no LN.
    rng = np.random.default_rng(3)
    features = [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [float(x), float(y)]},
         "properties": {"id": i, "class": "rock", "area_m2": 1.0, "major_m": 1.2,
                        "minor_m": 1.0, "angle_rad": 0.0, "score": 1.0}}
        for i, (x, y) in enumerate(rng.uniform(0.0, 100.0, (40, 2)))
    ]
    small = tmp_path / "small.geojson"
    small.write_text(json.dumps({"type": "FeatureCollection", "features": features,
                                 "metadata": {"crs": "EPSG:32719", "map_origin": [0.0, 0.0]}}))
    out = tmp_path / "o.json"
    assert main(["--gn", str(small), "--json", str(out)]) == 1
    err = capsys.readouterr().err
    assert "found no LN" in err and str(small) in err
    assert not out.exists()

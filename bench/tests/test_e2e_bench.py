"""bench/e2e_bench.py's side-by-side variant (``--compare``) without running a graph: the
override parser, the variant's params file and its rows in the report."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml


@pytest.fixture(scope="module")
def e2e(bench_script):
    return bench_script("e2e_bench")


def test_overrides_are_parsed_and_bad_ones_named(e2e) -> None:
    assert e2e.parse_override("rover_vo:imu.sun_heading=false") == (
        "rover_vo", "imu.sun_heading", False)
    assert e2e.parse_override("darces_matcher:min_support=7") == (
        "darces_matcher", "min_support", 7)
    for bad in ("imu.sun_heading=false", "rover_vo:imu.sun_heading", ":x=1"):
        with pytest.raises(ValueError, match="NODE:PARAM=VALUE"):
            e2e.parse_override(bad)


def test_the_variant_params_file_keeps_the_base_and_sets_the_overrides(
        tmp_path: Path, e2e) -> None:
    base = tmp_path / "globloc.yaml"
    base.write_text(yaml.safe_dump({"rover_vo": {"ros__parameters": {"state_path": "$RUN_DIR/s"}}}))
    out = e2e.variant_params(base, [("rover_vo", "imu.sun_heading", False),
                                    ("ln_builder", "ln_path", "x")], tmp_path / "v.yaml")
    doc = yaml.safe_load(out.read_text())
    assert doc["rover_vo"]["ros__parameters"] == {"state_path": "$RUN_DIR/s",
                                                  "imu.sun_heading": False}
    assert doc["ln_builder"]["ros__parameters"] == {"ln_path": "x"}
    assert yaml.safe_load(base.read_text())["rover_vo"]["ros__parameters"] == {
        "state_path": "$RUN_DIR/s"}  # the base file is not touched


def test_the_report_gives_both_variants_and_their_spreads(e2e) -> None:
    def entry(variant, final):
        return {"bag": "bags/quick", "variant": variant, "nodes": {},
                "continuous": {"localized": True, "final_error_m": final,
                               "longest_stretch_without_fix_m": 120.0,
                               "error_at_stretch_end_m": 0.9}}
    report = {"tag": "t", "date": "d", "machine": "m", "rate": 5.0, "command": "c",
              "bags": [entry(None, 0.4), entry("no_sun", 1.2)],
              "spread": {"final_error_m": e2e._spread([0.4])},
              "compare": {"base": "as configured", "label": "no_sun",
                          "spread": {"final_error_m": e2e._spread([1.2])}}}
    md = e2e.markdown(report)
    assert "| quick | True |" in md and "| quick (no_sun) | True |" in md
    assert "| 120.0 / 0.90 |" in md
    assert "Spread over bags (as configured)" in md and "Spread over bags (no_sun)" in md
    assert "- final_error_m: n 1, min 1.20" in md

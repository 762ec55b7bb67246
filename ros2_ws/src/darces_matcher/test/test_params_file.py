"""The package's params file holds the parameters the node declares, at their defaults."""

from pathlib import Path

import pytest
import rclpy
import yaml

from roi_network.geojson import write_geojson
from roi_network.params import node_parameters

CONFIG = Path(__file__).resolve().parents[1] / "config" / "darces_matcher.yaml"


def test_params_file_holds_the_declared_defaults(tmp_path, gn):
    from darces_matcher.matcher_node import MatcherNode

    gn_path = tmp_path / "gn.geojson"
    write_geojson(gn, gn_path)
    rclpy.init(args=["--ros-args", "-p", f"gn_path:={gn_path}"])
    try:
        node = MatcherNode()
        try:
            declared = {p: node.get_parameter(p).value for p in node._parameters}
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()
    listed = node_parameters(yaml.safe_load(CONFIG.read_text()), "darces_matcher")
    listed.pop("gn_path")
    for key, value in listed.items():
        assert key in declared, f"{CONFIG.name}: the node declares no parameter '{key}'"
        same = declared[key] == pytest.approx(value) if isinstance(value, float) \
            else declared[key] == value
        assert same, f"{CONFIG.name}: {key} is {value!r}, the node's default {declared[key]!r}"
    tuned = {k for k in declared if k.startswith(("match.", "localization."))}
    assert tuned <= set(listed), f"{CONFIG.name} leaves out {sorted(tuned - set(listed))}"

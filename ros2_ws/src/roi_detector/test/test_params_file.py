"""The package's params file holds the parameters the nodes declare, at their defaults."""

from pathlib import Path

import pytest
import rclpy
import yaml

from roi_network.params import node_parameters

CONFIG = Path(__file__).resolve().parents[1] / "config" / "roi_detector.yaml"


def _declared(node_class, args):
    """Parameter name -> value of a node made with ``--ros-args ARGS`` (this process)."""
    rclpy.init(args=["--ros-args", *args])
    try:
        node = node_class()
        try:
            return {p: node.get_parameter(p).value for p in node._parameters}
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


@pytest.mark.parametrize("name", ["roi_detector", "ln_builder"])
def test_params_file_holds_the_declared_defaults(name):
    from roi_detector.detector_node import RoiDetectorNode
    from roi_detector.ln_builder_node import LnBuilderNode

    node_class = {"roi_detector": RoiDetectorNode, "ln_builder": LnBuilderNode}[name]
    args = ["-p", "base_to_left_camera:=[0.0, 0.0, 1.0, 0.5, -0.5, 0.5, -0.5]"] \
        if name == "roi_detector" else []
    declared = _declared(node_class, args)
    listed = node_parameters(yaml.safe_load(CONFIG.read_text()), name)
    assert listed, f"{CONFIG.name} has no parameters for {name}"
    for key, value in listed.items():
        assert key in declared, f"{CONFIG.name}: {name} declares no parameter '{key}'"
        assert declared[key] == pytest.approx(value) if isinstance(value, float) \
            else declared[key] == value, f"{CONFIG.name}: {name}.{key} is {declared[key]!r}"

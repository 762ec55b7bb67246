"""Options: the params YAML round trip, the modes, unknown keys and bad values named."""

from __future__ import annotations

from pathlib import Path

import pytest

from rover_vo.config import (
    VoConfig,
    config_from_flat,
    config_from_params_file,
    flat_parameters,
    read_ros_params,
)

CONFIG = Path(__file__).resolve().parents[1] / "config" / "rover_vo.yaml"


def test_package_params_file_holds_the_defaults():
    assert config_from_params_file(CONFIG) == VoConfig()
    assert set(read_ros_params(CONFIG)) == set(flat_parameters(VoConfig()))


def test_nested_and_dotted_keys_and_modes(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    base_to_left_camera: [0, 0, 1, 0, 0, 0, 1]\n"
                 "    other_node_parameter: 1\n"
                 "rover_vo:\n  ros__parameters:\n    mode: vo\n    features:\n"
                 "      max_corners: 300\n    motion.min_inliers: 40\n"
                 "    state_path: /tmp/state.json\n")
    cfg = config_from_params_file(f)
    assert (cfg.mode, cfg.features.max_corners, cfg.motion.min_inliers) == ("vo", 300, 40)
    assert not cfg.use_imu
    assert VoConfig().mode == "paper" and VoConfig().use_imu


@pytest.mark.parametrize("text, key", [
    ("rover_vo:\n  ros__parameters:\n    max_corners: 300\n", "max_corners"),
    ("rover_vo:\n  ros__parameters:\n    window:\n      keyframe_max_frames: 4\n",
     "window.keyframe_max_frames"),
    ("/**:\n  ros__parameters:\n    features.nope: 1\n", "features.nope"),
])
def test_unknown_keys_of_a_params_file_are_named(tmp_path, text, key):
    f = tmp_path / "p.yaml"
    f.write_text(text)
    with pytest.raises(ValueError, match=rf"p\.yaml: unknown parameter '{key}'"):
        config_from_params_file(f)


@pytest.mark.parametrize("values, text", [
    ({"features.nope": 1}, "features.nope"),
    ({"features.max_corners": "many"}, "features.max_corners"),
    ({"features.rectify": 1}, "features.rectify"),
    ({"mode": "keyframes"}, "mode 'keyframes'"),
])
def test_bad_values_are_named(values, text):
    with pytest.raises(ValueError, match=text):
        config_from_flat(values)


def test_not_a_params_file(tmp_path):
    f = tmp_path / "x.yaml"
    f.write_text("- a list\n")
    with pytest.raises(ValueError, match=r"x\.yaml"):
        config_from_params_file(f)

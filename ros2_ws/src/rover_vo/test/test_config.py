"""Options: the params YAML round trip, the mode presets, bad values named."""

from __future__ import annotations

from pathlib import Path

import pytest

from rover_vo.config import VoConfig, config_from_flat, flat_parameters, read_ros_params

CONFIG = Path(__file__).resolve().parents[1] / "config" / "rover_vo.yaml"


def test_package_params_file_holds_the_defaults():
    assert config_from_flat(read_ros_params(CONFIG)) == VoConfig()
    assert set(read_ros_params(CONFIG)) == set(flat_parameters(VoConfig()))


def test_nested_and_dotted_keys_and_mode_presets(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    base_to_left_camera: [0, 0, 1, 0, 0, 0, 1]\n"
                 "rover_vo:\n  ros__parameters:\n    mode: vo\n    features:\n"
                 "      max_corners: 300\n    motion.min_inliers: 40\n")
    cfg = config_from_flat(read_ros_params(f))
    assert (cfg.mode, cfg.features.max_corners, cfg.motion.min_inliers) == ("vo", 300, 40)
    r = cfg.resolved()
    assert r.window.frame_to_frame and not r.imu.use_imu
    k = VoConfig(mode="keyframes").resolved()
    assert not k.window.frame_to_frame and k.imu.use_imu
    p = VoConfig().resolved()
    assert p.mode == "paper" and p.window.frame_to_frame and p.imu.use_imu


@pytest.mark.parametrize("values, text", [
    ({"features.nope": 1}, "features.nope"),
    ({"features.max_corners": "many"}, "features.max_corners"),
    ({"imu.use_imu": 1}, "imu.use_imu"),
    ({"mode": "fast"}, "mode 'fast'"),
])
def test_bad_values_are_named(values, text):
    with pytest.raises(ValueError, match=text):
        config_from_flat(values)


def test_not_a_params_file(tmp_path):
    f = tmp_path / "x.yaml"
    f.write_text("- a list\n")
    with pytest.raises(ValueError, match=r"x\.yaml"):
        read_ros_params(f)

"""The colcon workspace holds the seven packages of the design, each a proper
ament_python package that `make setup` has built and installed."""

import configparser
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_share_directory

SRC = Path(__file__).resolve().parents[1] / "ros2_ws" / "src"
PACKAGES = ["roi_network", "atacama_sim", "orbital_gn", "roi_detector", "rover_vo",
            "darces_matcher", "rover_bringup"]


def test_exactly_the_design_packages():
    assert sorted(p.parent.name for p in SRC.glob("*/package.xml")) == sorted(PACKAGES)


@pytest.mark.parametrize("name", PACKAGES)
def test_package_is_ament_python_and_installed(name):
    pkg = SRC / name
    root = ET.parse(pkg / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == name
    assert root.find("export/build_type").text == "ament_python"
    assert (pkg / "resource" / name).is_file()
    assert (pkg / name / "__init__.py").is_file()
    assert (pkg / "config").is_dir() and (pkg / "test").is_dir()
    cfg = configparser.ConfigParser()
    cfg.read(pkg / "setup.cfg")
    assert cfg["install"]["install_scripts"] == f"$base/lib/{name}"
    share = Path(get_package_share_directory(name))
    assert (share / "package.xml").is_file()

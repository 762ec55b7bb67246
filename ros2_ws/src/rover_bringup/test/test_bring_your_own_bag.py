"""The guide docs/bring_your_own_bag.md: its example's commands, read from the guide's
fenced block, run on EuRoC's calibration (sensor.yaml files written at test time) and a
bag that carries the CameraInfo they make."""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rover_bringup.cli import main
from rover_bringup.rectify import read_calibration_yaml

ROOT = Path(__file__).resolve().parents[4]
GUIDE = ROOT / 'docs' / 'bring_your_own_bag.md'


fb = sys.modules['rover_bringup_test_fieldbag']  # loaded by conftest.py


def guide_example() -> list[list[str]]:
    """The commands of the guide's example block (the first ``bash`` block of its
    "Example" section), comments and blank lines left out."""
    text = GUIDE.read_text()
    section = text.split('\n## Example', 1)[1]
    block = re.search(r'```bash\n(.*?)```', section, re.DOTALL)
    assert block, f'{GUIDE}: no bash block in its Example section'
    return [shlex.split(line, comments=True) for line in block.group(1).splitlines()
            if line.split('#', 1)[0].strip()]


def test_the_guides_example_runs(tmp_path, monkeypatch, capsys):
    """EuRoC's calibration through the guide's commands: the CameraInfo pair, a bag that
    carries it (what the user records), its rover.yaml, and globloc run's checks."""
    from rover_bringup.run import RunOptions, _prepare

    commands = guide_example()
    assert [c[:2] for c in commands] == [['globloc', 'camera-info'], ['globloc', 'rover-yaml']]
    monkeypatch.chdir(tmp_path)
    cam0, cam1 = (Path(a) for a in commands[0][2:4])
    for name, path in (('cam0', cam0), ('cam1', cam1)):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(fb.EUROC_CAM.format(name=name, **fb.EUROC[name]))
    assert main(commands[0][1:]) == 0
    out = Path(commands[0][commands[0].index('--out') + 1])
    left, right = (read_calibration_yaml(out / n) for n in ('left.yaml', 'right.yaml'))
    # The recording: the rectified cameras in /tf_static, as camera-info printed them.
    err = capsys.readouterr().err
    printed = re.findall(r'(left|right) +(\[[^]]+\])', err)
    poses = {side: yaml.safe_load(pose) for side, pose in printed}

    def matrix(pose):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = Rotation.from_quat(pose[3:]).as_matrix(), pose[:3]
        return m

    tf = [('base_link', 'imu0', fb.BODY_IN_BASE), ('imu0', 'cam0', matrix(poses['left'])),
          ('imu0', 'cam1', matrix(poses['right']))]
    bag = Path(commands[1][2])
    fb.write_field_bag(bag, {'left': [left] * 4, 'right': [right] * 4}, tf=tf)
    assert main(commands[1][1:]) == 0
    capsys.readouterr()
    params = yaml.safe_load((bag / 'rover.yaml').read_text())['/**']['ros__parameters']
    base_T_left = fb.BODY_IN_BASE @ matrix(poses['left'])
    assert params['camera_height_m'] == pytest.approx(base_T_left[2, 3], abs=1e-6)
    assert params['camera_tilt_deg'] == pytest.approx(
        np.degrees(np.arcsin(-base_T_left[2, 2])), abs=1e-4)
    assert abs(params['camera_tilt_deg'] - 15.0) < 2.0
    assert params['baseline_m'] == pytest.approx(0.110081, abs=1e-5)
    assert params['imu_rate_hz'] == pytest.approx(200.0)
    assert (params['image_width'], params['image_height']) == (752, 480)
    # What the guide says the commands give.
    said = GUIDE.read_text().split('\n## Example', 1)[1]
    reported = re.search(r'reports `([^`]+)`', said).group(1)
    assert reported in err
    height, tilt = re.search(r'camera ([0-9.]+) m above the ground and tilted ([0-9.]+) deg',
                             said.replace('\n', ' ')).groups()
    assert f"{params['camera_height_m']:.2f}" == height
    assert f"{params['camera_tilt_deg']:.1f}" == tilt
    # globloc run's checks find nothing missing.
    _prepare(RunOptions(bag=bag))
    err = capsys.readouterr().err
    assert 'publish nothing' not in err and 'rover.yaml' not in err and 'stamped' not in err

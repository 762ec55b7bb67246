"""``globloc rover-yaml`` refuses a calibration it cannot use and skips, naming it once,
an unusable CameraInfo among usable ones. The bags carry EuRoC's rectified pair."""

from __future__ import annotations

import sys

import pytest
import yaml

from rover_bringup.cli import main

fb = sys.modules['rover_bringup_test_fieldbag']  # loaded by conftest.py


def test_one_unusable_camera_info_is_skipped_and_named_once(tmp_path, capsys):
    pair, tf = fb.euroc_pair(tmp_path)
    infos = {'left': [pair.left] * 5, 'right': [pair.right] * 5}
    infos['left'] = [fb.with_value(pair.left, 'k', 0, 0.0)] + [pair.left] * 4
    infos['right'] = [pair.right] * 2 + [fb.with_value(pair.right, 'p', 3, 0.0)] * 2 + [pair.right]
    bag = fb.write_field_bag(tmp_path / 'bag', infos, tf=tf)
    assert main(['rover-yaml', str(bag)]) == 0
    err = capsys.readouterr().err
    assert err.count('/stereo/left/camera_info at 1403715273.712 s: K[0] (fx) = 0: skipped '
                     '(1 of the 5 messages of /stereo/left/camera_info); the calibration is '
                     'that of the one at 1403715273.762 s') == 1
    assert err.count('/stereo/right/camera_info at 1403715273.812 s: P[3] (-fx * baseline) = 0'
                     ': no baseline') == 1
    assert 'with 1 more (2 of the 5 messages of /stereo/right/camera_info)' in err
    params = yaml.safe_load((bag / 'rover.yaml').read_text())['/**']['ros__parameters']
    assert params['fx'] == pytest.approx(pair.fx)
    assert params['baseline_m'] == pytest.approx(pair.baseline_m, abs=1e-6)


@pytest.mark.parametrize(('side', 'name', 'index', 'value', 'message'), [
    ('left', 'k', 0, 0.0, '/stereo/left/camera_info at 1403715273.712 s: K[0] (fx) = 0 '
                          '(every one of its 3 messages is unusable)'),
    ('left', 'k', 4, -1.0, 'K[4] (fy) = -1'),
    ('right', 'p', 5, 0.0, '/stereo/right/camera_info at 1403715273.712 s: P[5] (fy) = 0'),
    ('right', 'p', 3, 0.0, 'P[3] (-fx * baseline) = 0: no baseline'),
    ('right', 'p', 3, 48.0, 'P[3] (-fx * baseline) = 48 > 0: the right camera sits left of '
                            'the left one'),
    ('left', 'd', 1, float('nan'), 'D[1] = nan'),
    ('right', 'width', None, 640, '/stereo/left/camera_info says 752x480, '
                                  '/stereo/right/camera_info 640x480'),
])
def test_a_calibration_rover_yaml_cannot_use_is_refused(tmp_path, capsys, side, name, index,
                                                        value, message):
    pair, tf = fb.euroc_pair(tmp_path)
    fields = {'left': pair.left, 'right': pair.right}
    if index is None:
        fields[side] = {**fields[side], name: value}
    else:
        fields[side] = fb.with_value(fields[side], name, index, value)
    bag = fb.write_field_bag(tmp_path / 'bag', {s: [f] * 3 for s, f in fields.items()}, tf=tf)
    assert main(['rover-yaml', str(bag)]) == 1
    err = capsys.readouterr().err
    assert message in err and err.startswith('globloc: error: ')
    assert not (bag / 'rover.yaml').exists()


def test_images_of_another_size_than_their_camera_info_are_refused(tmp_path, capsys):
    pair, tf = fb.euroc_pair(tmp_path)
    bag = fb.write_field_bag(tmp_path / 'bag', {'left': [pair.left] * 2, 'right': [pair.right] * 2},
                          tf=tf, image_sizes={'right': (640, 480)})
    assert main(['rover-yaml', str(bag)]) == 1
    assert ('/stereo/right/image_raw at 1403715273.712 s is 640x480, /stereo/right/camera_info '
            'says 752x480') in capsys.readouterr().err

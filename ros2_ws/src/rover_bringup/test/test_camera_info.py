"""``globloc camera-info``: the rectified stereo CameraInfo pair of a raw calibration,
against a known geometry and on EuRoC's sensor.yaml files (written at test time)."""

from __future__ import annotations

import sys
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rover_bringup.cli import main
from rover_bringup.rectify import (
    RawCamera,
    RectifyError,
    read_calibration_yaml,
    read_sensor_yaml,
    rectify_pair,
    write_camera_info,
)

fb = sys.modules['rover_bringup_test_fieldbag']  # loaded by conftest.py


def _camera(source: str, body_T_camera: np.ndarray, fx: float, cx: float,
            d: list[float]) -> RawCamera:
    k = np.array([[fx, 0.0, cx], [0.0, fx * 1.01, 241.0], [0.0, 0.0, 1.0]])
    return RawCamera(source, body_T_camera, 640, 480, k, np.asarray(d, float))


def test_the_rectified_pair_of_a_known_geometry():
    """Points seen through two distorted cameras, 0.12 m apart and turned 1.5 deg from
    each other, land on one row of the rectified pair, with the disparity fx * B / Z."""
    import cv2

    from roi_network.images import Rectifier

    body_T_left = np.eye(4)
    body_T_left[:3, :3] = Rotation.from_euler('xyz', [3, -2, 40], degrees=True).as_matrix()
    body_T_left[:3, 3] = [0.1, -0.2, 0.3]
    left_T_right = np.eye(4)
    left_T_right[:3, :3] = Rotation.from_euler('yz', [1.5, 0.4], degrees=True).as_matrix()
    left_T_right[:3, 3] = [0.12, 0.003, -0.002]
    baseline = float(np.linalg.norm(left_T_right[:3, 3]))
    left = _camera('l', body_T_left, 500.0, 322.0, [-0.25, 0.07, 0.001, -0.0005, 0.0])
    right = _camera('r', body_T_left @ left_T_right, 505.0, 317.0, [-0.2, 0.05, -0.0008, 0.0])
    pair = rectify_pair(left, right)
    assert pair.baseline_m == pytest.approx(baseline, abs=1e-9)
    assert pair.right['p'][3] == pytest.approx(-pair.fx * baseline)
    assert pair.left['p'][3] == 0 and pair.left['p'][0] == pair.right['p'][0] == pair.fx
    # The rectified right camera sits on the rectified left one's +x axis, unrotated.
    rel = np.linalg.inv(pair.body_T_left) @ pair.body_T_right
    np.testing.assert_allclose(rel[:3, :3], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(rel[:3, 3], [baseline, 0, 0], atol=1e-9)
    assert pair.rotation_deg[1] > 0.5
    # Points 2-12 m ahead of the left camera, through each raw lens, then rectified.
    rng = np.random.default_rng(3)
    z = rng.uniform(2, 12, 40)
    xyz_left = np.column_stack([rng.uniform(-0.4, 0.4, 40) * z, rng.uniform(-0.3, 0.3, 40) * z,
                                z])
    xyz_right = (np.linalg.inv(left_T_right) @ np.column_stack([xyz_left, np.ones(40)]).T)[:3].T
    rect = {}
    for side, cam, pts in (('left', left, xyz_left), ('right', right, xyz_right)):
        raw, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.k, cam.d)
        f = getattr(pair, side)
        p = np.reshape(f['p'], (3, 4))
        rect[side] = cv2.undistortPoints(raw, cam.k, cam.d, R=np.reshape(f['r'], (3, 3)),
                                         P=p[:, :3]).reshape(-1, 2)
        # The nodes' Rectifier reads the fields as meant: its map takes a rectified pixel
        # to where the raw lens imaged that ray.
        info = SimpleNamespace(**f)
        rectifier = Rectifier(info)
        assert not rectifier.identity
        maps = cv2.convertMaps(*rectifier.maps, cv2.CV_32FC2)[0]
        u, v = 300, 200
        ray = np.reshape(f['r'], (3, 3)).T @ np.linalg.solve(p[:, :3], [u, v, 1.0])
        expected, _ = cv2.projectPoints(ray[None], np.zeros(3), np.zeros(3), cam.k, cam.d)
        np.testing.assert_allclose(maps[v, u], expected.ravel(), atol=0.05)
    np.testing.assert_allclose(rect['left'][:, 1], rect['right'][:, 1], atol=0.01)
    depth = (np.reshape(pair.left['r'], (3, 3)) @ xyz_left.T)[2]
    np.testing.assert_allclose(rect['left'][:, 0] - rect['right'][:, 0],
                               pair.fx * baseline / depth, atol=0.01)


def test_camera_info_of_euroc_files_and_what_it_refuses(tmp_path, capsys):
    cam0, cam1 = fb.write_euroc(tmp_path / 'calib')
    assert main(['camera-info', str(cam0), str(cam1), '--out', str(tmp_path / 'out')]) == 0
    err = capsys.readouterr().err
    assert 'baseline 0.11008 m' in err and 'ignores R' in err
    left, right = (read_calibration_yaml(tmp_path / 'out' / n) for n in ('left.yaml',
                                                                         'right.yaml'))
    # The baseline is the distance between the two cameras' centres in T_BS.
    centres = [np.reshape([float(v) for v in fb.EUROC[c]['t_bs'].split(',')], (4, 4))[:3, 3]
               for c in ('cam0', 'cam1')]
    assert -right['p'][3] / right['p'][0] == pytest.approx(np.linalg.norm(np.subtract(*centres)),
                                                           abs=1e-9)
    assert left['k'][0] == 458.654 and left['d'][:2] == [-0.28340811, 0.07395907]
    assert (left['width'], left['height'], left['distortion_model']) == (752, 480, 'plumb_bob')
    # Printed without --out: the same two documents.
    assert main(['camera-info', str(cam0), str(cam1)]) == 0
    docs = list(yaml.safe_load_all(capsys.readouterr().out))
    assert [d['camera_name'] for d in docs] == ['left', 'right']
    assert docs[1]['projection_matrix']['data'] == right['p']
    # Never overwritten without --force.
    assert main(['camera-info', str(cam0), str(cam1), '--out', str(tmp_path / 'out')]) == 1
    assert 'exists: not overwritten' in capsys.readouterr().err
    # The cameras given the wrong way round, a vertical pair, sizes that differ.
    with pytest.raises(RectifyError, match=r"on the first one's -x side .* left camera first"):
        write_camera_info(cam1, cam0)
    a, b = read_sensor_yaml(cam0), read_sensor_yaml(cam1)
    b.body_T_camera = a.body_T_camera.copy()
    b.body_T_camera[:3, 3] += a.body_T_camera[:3, 1] * 0.1  # below the left camera
    with pytest.raises(RectifyError, match='not beside it along x'):
        rectify_pair(a, b)
    b = read_sensor_yaml(cam1)
    b.width = 640
    with pytest.raises(RectifyError, match='752x480 and 640x480'):
        rectify_pair(a, b)
    # A file in OpenCV's dialect reads the same; bad fields are named with the file.
    text = cam0.read_text()
    opencv = '%YAML:1.0\n' + text.replace('T_BS:', 'T_BS: !!opencv-matrix')
    (tmp_path / 'cv.yaml').write_text(opencv)
    np.testing.assert_array_equal(read_sensor_yaml(tmp_path / 'cv.yaml').k, a.k)
    for bad, message in (
            (text.replace('radial-tangential', 'equidistant'),
             "distortion_model 'equidistant': this command reads radial-tangential"),
            (text.replace('458.654', '0.0'), r'intrinsics\[0\] \(fu\) = 0'),
            (text.replace('[752, 480]', '[752]'), 'resolution: 2 numbers expected'),
            (text.replace('0.0148655429818', '.nan'), r'T_BS\[0\] = nan'),
            (text.replace('0.999557249008', '0.5'), 'T_BS is not a rigid transform')):
        (tmp_path / 'bad.yaml').write_text(bad)
        with pytest.raises(RectifyError, match=f'bad.yaml: {message}'):
            read_sensor_yaml(tmp_path / 'bad.yaml')

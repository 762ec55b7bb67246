"""``globloc rover-yaml``: a field bag's rover.yaml from its /tf_static, CameraInfo and IMU.

The bags here are written at test time: a rover whose cameras hang off a mast and a
pan-tilt head (five frames between base_link and each optical frame), recorded as
robot_state_publisher latches them.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rover_bringup.cli import main
from rover_bringup.errors import GloblocError
from rover_bringup.extrinsics import (
    CalibrationError,
    bag_calibration,
    frame_transform,
    rover_parameters,
)

FX, BASELINE, TILT_DEG, PAN_DEG = 457.0, 0.2, 20.0, 10.0
#: optical frame in its camera link (x forward, y left, z up -> z forward, x right, y down)
OPTICAL = Rotation.from_matrix([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])


def _tree() -> list[tuple[str, str, list[float], Rotation]]:
    """(parent, child, translation, rotation) of the rover's static frames."""
    return [
        ('base_link', 'mast', [0.4, 0.0, 0.9], Rotation.identity()),
        ('mast', 'pan', [0.0, 0.0, 0.5], Rotation.from_euler('z', PAN_DEG, degrees=True)),
        ('pan', 'tilt', [0.0, 0.0, 0.14], Rotation.from_euler('y', TILT_DEG, degrees=True)),
        ('tilt', 'left_camera_link', [0.0, BASELINE / 2, 0.0], Rotation.identity()),
        ('tilt', 'right_camera_link', [0.0, -BASELINE / 2, 0.0], Rotation.identity()),
        ('left_camera_link', 'left_camera_optical', [0.0, 0.0, 0.0], OPTICAL),
        ('right_camera_link', 'right_camera_optical', [0.0, 0.0, 0.0], OPTICAL),
        ('base_link', 'imu_link', [0.1, 0.0, 0.3], Rotation.from_euler('x', 180, degrees=True)),
    ]


def _tree_at(pan_deg: float, tilt_deg: float):
    """:func:`_tree` with the head at other angles."""
    out = []
    for p, c, t, r in _tree():
        if (p, c) == ('mast', 'pan'):
            r = Rotation.from_euler('z', pan_deg, degrees=True)
        elif (p, c) == ('pan', 'tilt'):
            r = Rotation.from_euler('y', tilt_deg, degrees=True)
        out.append((p, c, t, r))
    return out


def _expected(child: str, tree=None) -> np.ndarray:
    """``child`` in base_link, composed by hand along :func:`_tree` (or ``tree``)."""
    parent_of = {c: (p, t, r) for p, c, t, r in (tree or _tree())}
    out = np.eye(4)
    while child != 'base_link':
        parent, t, r = parent_of[child]
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = r.as_matrix(), t
        out = step @ out
        child = parent
    return out


#: The pan and tilt joints of :func:`_tree`'s head, (parent, child) -> (joint, axis).
MAST_JOINTS = {('mast', 'pan'): ('head_pan', 'z'), ('pan', 'tilt'): ('head_tilt', 'y')}


def _urdf() -> str:
    """:func:`_tree` as a URDF whose head pans and tilts on :data:`MAST_JOINTS`."""
    joints = []
    for parent, child, t, r in _tree():
        xyz = ' '.join(str(v) for v in t)
        if (parent, child) in MAST_JOINTS:
            name, axis = MAST_JOINTS[(parent, child)]
            vec = {'y': '0 1 0', 'z': '0 0 1'}[axis]
            joints.append(f'<joint name="{name}" type="revolute"><parent link="{parent}"/>'
                          f'<child link="{child}"/><origin xyz="{xyz}" rpy="0 0 0"/>'
                          f'<axis xyz="{vec}"/><limit lower="-3.0" upper="3.0" effort="1" '
                          f'velocity="1"/></joint>')
        else:
            rpy = ' '.join(str(v) for v in r.as_euler('xyz'))
            joints.append(f'<joint name="{parent}_to_{child}" type="fixed"><parent '
                          f'link="{parent}"/><child link="{child}"/><origin xyz="{xyz}" '
                          f'rpy="{rpy}"/></joint>')
    links = {f for p, c, _t, _r in _tree() for f in (p, c)}
    return ('<?xml version="1.0"?><robot name="field_rover">'
            + ''.join(f'<link name="{k}"/>' for k in sorted(links)) + ''.join(joints)
            + '</robot>')


def write_field_bag(path, tree=True, camera_frame='left_camera_optical', imu=True,
                    baseline=BASELINE, imu_hz=200.0, right_late_ms=None, images=30,
                    right_images=None, mast=False, urdf=True):
    """A bag directory ``path`` (rosbag/ only) recording a field rover's calibration;
    with ``right_late_ms``, ``images`` stereo pairs at 10 Hz, the right camera's stamped
    that late and stopping after ``right_images`` (None: none missing). With ``mast`` the
    head's pan and tilt are moving joints: /tf_static leaves them out, /joint_states
    holds their angles (``PAN_DEG``, ``TILT_DEG``) and, with ``urdf``, /robot_description
    the URDF."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    stamp = lambda ns: T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)  # noqa: E731
    header = lambda ns, frame: T['std_msgs/msg/Header'](stamp=stamp(ns), frame_id=frame)  # noqa: E731
    path.mkdir(parents=True)
    with Writer(path / 'rosbag', version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        def conn(topic, msgtype):
            return writer.add_connection(topic, msgtype, typestore=store)

        if tree:
            tfs = []
            for parent, child, t, r in _tree():
                if mast and (parent, child) in MAST_JOINTS:
                    continue
                q = r.as_quat()
                tfs.append(T['geometry_msgs/msg/TransformStamped'](
                    header=header(0, parent), child_frame_id=child,
                    transform=T['geometry_msgs/msg/Transform'](
                        translation=T['geometry_msgs/msg/Vector3'](x=t[0], y=t[1], z=t[2]),
                        rotation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2],
                                                                   w=q[3]))))
            msg = T['tf2_msgs/msg/TFMessage'](transforms=tfs)
            writer.write(conn('/tf_static', 'tf2_msgs/msg/TFMessage'), 0,
                         store.serialize_cdr(msg, 'tf2_msgs/msg/TFMessage'))
        if mast and urdf:
            msg = T['std_msgs/msg/String'](data=_urdf())
            writer.write(conn('/robot_description', 'std_msgs/msg/String'), 0,
                         store.serialize_cdr(msg, 'std_msgs/msg/String'))
        if mast:
            msg = T['sensor_msgs/msg/JointState'](
                header=header(1, ''), name=['head_pan', 'head_tilt'],
                position=np.radians([PAN_DEG, TILT_DEG]), velocity=np.zeros(2),
                effort=np.zeros(0))
            writer.write(conn('/joint_states', 'sensor_msgs/msg/JointState'), 1,
                         store.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))
        for side in ('left', 'right'):
            frame = camera_frame if side == 'left' else 'right_camera_optical'
            tx = 0.0 if side == 'left' else -FX * baseline
            info = T['sensor_msgs/msg/CameraInfo'](
                header=header(1, frame), height=480, width=640, distortion_model='plumb_bob',
                d=np.zeros(5), k=np.array([FX, 0, 319.5, 0, FX, 239.5, 0, 0, 1.0]),
                r=np.eye(3).ravel(), p=np.array([FX, 0, 319.5, tx, 0, FX, 239.5, 0, 0, 0, 1, 0]),
                binning_x=0, binning_y=0,
                roi=T['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0,
                                                          width=0, do_rectify=False))
            writer.write(conn(f'/stereo/{side}/camera_info', 'sensor_msgs/msg/CameraInfo'), 1,
                         store.serialize_cdr(info, 'sensor_msgs/msg/CameraInfo'))
        if right_late_ms is not None:  # 10 Hz pairs, their payload no image
            image = 'sensor_msgs/msg/CompressedImage'
            sides = {side: conn(f'/stereo/{side}/image_raw/compressed', image)
                     for side in ('left', 'right')}
            for k in range(images):
                for side, late in (('left', 0), ('right', round(right_late_ms * 1e6))):
                    if side == 'right' and right_images is not None and k >= right_images:
                        continue
                    ns = 10**9 + k * 100_000_000 + late
                    m = T[image](header=header(ns, f'{side}_camera_optical'), format='jpeg',
                                 data=np.zeros(4, np.uint8))
                    writer.write(sides[side], ns, store.serialize_cdr(m, image))
        if imu:
            c = conn('/imu/data', 'sensor_msgs/msg/Imu')
            v3 = T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
            for k in range(200):
                ns = 10**9 + round(k * 1e9 / imu_hz)
                m = T['sensor_msgs/msg/Imu'](
                    header=header(ns, 'imu_link'),
                    orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9), angular_velocity=v3,
                    angular_velocity_covariance=np.zeros(9), linear_acceleration=v3,
                    linear_acceleration_covariance=np.zeros(9))
                writer.write(c, ns, store.serialize_cdr(m, 'sensor_msgs/msg/Imu'))
    return path


def test_tree_composed_to_the_parameters_the_nodes_read(tmp_path):
    bag = write_field_bag(tmp_path / 'field')
    params, warnings = rover_parameters(bag_calibration(bag / 'rosbag'))
    for key, frame in (('base_to_left_camera', 'left_camera_optical'),
                       ('base_to_right_camera', 'right_camera_optical'),
                       ('base_to_imu', 'imu_link')):
        got = np.asarray(params[key])
        want = _expected(frame)
        np.testing.assert_allclose(got[:3], want[:3, 3], atol=1e-9)
        np.testing.assert_allclose(Rotation.from_quat(got[3:]).as_matrix(), want[:3, :3],
                                   atol=1e-8)
    assert params['baseline_m'] == pytest.approx(BASELINE)
    assert params['camera_tilt_deg'] == pytest.approx(TILT_DEG, abs=1e-6)
    assert params['camera_height_m'] == pytest.approx(1.54)
    assert params['imu_rate_hz'] == pytest.approx(200.0)
    assert (params['fx'], params['cx'], params['image_width']) == (FX, 319.5, 640)
    assert any('datasheet' in w for w in warnings)
    # The vo's rig reads the file the CLI writes.
    from rover_vo.rig import pose_matrix

    assert main(['rover-yaml', str(bag)]) == 0
    text = (bag / 'rover.yaml').read_text()
    assert text.startswith('# Rover extrinsics') and '# NOTE: ' in text
    written = yaml.safe_load(text)['/**']['ros__parameters']
    np.testing.assert_allclose(pose_matrix(written['base_to_left_camera'], 'x'),
                               _expected('left_camera_optical'), atol=1e-8)
    # Never overwritten without --force.
    assert main(['rover-yaml', str(bag)]) == 1
    assert (bag / 'rover.yaml').read_text() == text
    assert main(['rover-yaml', str(bag), '--force']) == 0


def test_what_the_bag_lacks_or_contradicts_is_named(tmp_path, capsys):
    with pytest.raises(CalibrationError, match='no /tf_static transforms'):
        rover_parameters(bag_calibration(write_field_bag(tmp_path / 'a', tree=False)
                                         / 'rosbag'))
    # A camera frame that is the link (x forward), not its optical child.
    cal = bag_calibration(write_field_bag(tmp_path / 'b', camera_frame='left_camera_link')
                          / 'rosbag')
    with pytest.raises(CalibrationError, match=r"'left_camera_link' .* not an optical frame"):
        rover_parameters(cal)
    params, _ = rover_parameters(cal, frames={'left': 'left_camera_optical'})  # --left-frame
    assert params['left_camera_frame'] == 'left_camera_optical'
    with pytest.raises(CalibrationError, match="from frame 'chassis' to frame"):
        rover_parameters(cal, base_frame='chassis')
    # The tree's baseline and the CameraInfo's disagree.
    cal = bag_calibration(write_field_bag(tmp_path / 'c', baseline=0.25) / 'rosbag')
    with pytest.raises(CalibrationError, match=r'baseline of 0\.2500 m'):
        rover_parameters(cal)
    # No IMU: the file is still written, without base_to_imu, and says so.
    params, warnings = rover_parameters(bag_calibration(write_field_bag(tmp_path / 'd',
                                                                        imu=False) / 'rosbag'))
    assert 'base_to_imu' not in params and any('no /imu/data frame' in w for w in warnings)
    assert main(['rover-yaml', str(tmp_path / 'a')]) == 1
    assert 'no /tf_static transforms' in capsys.readouterr().err


def test_frame_transform_inverts_edges_and_names_the_frames():
    a_T_b = np.eye(4)
    a_T_b[:3, 3] = [1, 2, 3]
    transforms = {('a', 'b'): a_T_b}
    np.testing.assert_allclose(frame_transform(transforms, 'b', 'a', 'x'), np.linalg.inv(a_T_b))
    with pytest.raises(CalibrationError, match=r"x: /tf_static joins no chain .*frames: a, b"):
        frame_transform(transforms, 'a', 'c', 'x')


def test_run_warns_of_a_missing_rover_yaml_and_names_the_command(tmp_path, capsys):
    from rover_bringup.run import RunOptions, _prepare

    bag = write_field_bag(tmp_path / 'field')
    _prepare(RunOptions(bag=bag))
    err = capsys.readouterr().err
    assert f'{bag / "rover.yaml"} not found' in err
    assert f'globloc rover-yaml {bag}' in err
    assert main(['rover-yaml', str(bag)]) == 0
    capsys.readouterr()
    _prepare(RunOptions(bag=bag))
    assert 'rover.yaml' not in capsys.readouterr().err


def test_run_warns_of_a_mast_without_joint_states(tmp_path, capsys):
    from rover_bringup.run import RunOptions, _prepare

    bag = write_field_bag(tmp_path / 'field', mast=True)
    assert main(['rover-yaml', str(bag)]) == 0
    capsys.readouterr()
    _prepare(RunOptions(bag=bag))
    assert 'records no /joint_states' not in capsys.readouterr().err  # the bag records them
    plain = write_field_bag(tmp_path / 'plain')
    (plain / 'rover.yaml').write_text((bag / 'rover.yaml').read_text())
    _prepare(RunOptions(bag=plain))
    err = capsys.readouterr().err
    assert "puts the cameras on a mast (head_pan, head_tilt)" in err
    assert 'records no /joint_states' in err
    text = (bag / 'rover.yaml').read_text().replace('head_tilt', 'head_pan')
    (plain / 'rover.yaml').write_text(text)
    with pytest.raises(GloblocError, match=r"mast\.tilt_joint"):
        _prepare(RunOptions(bag=plain))


def test_the_simulators_rover_yaml_comes_back_from_its_tf_static(tmp_path):
    """A simulator bag dressed as a field bag (roi_network.testing.write_tf_static_copy:
    its rover.yaml's frames as /tf_static, no rover.yaml) gets its extrinsics back."""
    from atacama_sim.camera import StereoRig
    from atacama_sim.config import make_config
    from atacama_sim.truth import rover_params, write_rover_yaml
    from roi_network.testing import write_tf_static_copy

    cfg = make_config('tiny', 7)
    rig = StereoRig.from_config(cfg.camera)
    sim = write_field_bag(tmp_path / 'sim', tree=False, baseline=cfg.camera.baseline_m,
                          imu_hz=rover_params(rig, cfg)['/**']['ros__parameters']['imu_rate_hz'])
    write_rover_yaml(sim / 'rover.yaml', rig, cfg)
    field = write_tf_static_copy(sim, tmp_path / 'field')
    assert not (field / 'rover.yaml').exists()
    assert main(['rover-yaml', str(field)]) == 0
    load = lambda p: yaml.safe_load(p.read_text())['/**']['ros__parameters']  # noqa: E731
    want, got = load(sim / 'rover.yaml'), load(field / 'rover.yaml')
    for key in ('base_to_left_camera', 'base_to_right_camera', 'base_to_imu'):
        np.testing.assert_allclose(got[key][:3], want[key][:3], atol=1e-9)
        rot = Rotation.from_quat(got[key][3:]) * Rotation.from_quat(want[key][3:]).inv()
        assert rot.magnitude() < 1e-8, key
    for key in ('baseline_m', 'camera_height_m', 'camera_tilt_deg', 'imu_rate_hz'):
        assert got[key] == pytest.approx(want[key], abs=1e-6), key


def test_run_warns_of_cameras_stamped_beyond_the_sync_tolerance(tmp_path, capsys):
    from rover_bringup.extrinsics import stereo_stamp_offsets
    from rover_bringup.run import RunOptions, _prepare

    near = write_field_bag(tmp_path / 'near', right_late_ms=3.0)
    far = write_field_bag(tmp_path / 'far', right_late_ms=14.0)
    offsets = stereo_stamp_offsets(far / 'rosbag')
    assert len(offsets) == 20 and offsets[10] == pytest.approx(0.014)
    for bag in (near, far):
        main(['rover-yaml', str(bag)])
    capsys.readouterr()
    _prepare(RunOptions(bag=near))  # within the 5 ms default
    assert 'stamped' not in capsys.readouterr().err
    _prepare(RunOptions(bag=far))
    err = capsys.readouterr().err
    for node, key in (('rover_vo', 'features.stereo_sync_tolerance_s'),
                      ('roi_detector', 'stereo_sync_tolerance_s')):
        assert f"14.0 ms apart (median of the first 20), beyond {node}'s {key} (5 ms)" in err
    # A params file raises roi_detector's tolerance: only rover_vo is left to warn of.
    params = {'roi_detector': {'ros__parameters': {'stereo_sync_tolerance_s': 0.02}}}
    (tmp_path / 'params.yaml').write_text(yaml.safe_dump(params))
    _prepare(RunOptions(bag=far, params=tmp_path / 'params.yaml'))
    err = capsys.readouterr().err
    assert "rover_vo's" in err and "roi_detector's" not in err


def test_the_sync_tolerance_is_read_as_the_node_gets_it(tmp_path, capsys):
    """Nested keys, a leading slash, the wildcard and rover.yaml set the tolerance the
    warning compares with, as they set the node's."""
    from rover_bringup.run import RunOptions, _prepare, node_parameter

    key = 'features.stereo_sync_tolerance_s'
    files = [{'/**': {'ros__parameters': {'features': {'stereo_sync_tolerance_s': 0.01}}}},
             {'/rover_vo': {'ros__parameters': {'features.stereo_sync_tolerance_s': 0.03}}}]
    assert node_parameter(files, 'rover_vo', key, 0.005) == 0.03
    assert node_parameter(files[:1], 'rover_vo', key, 0.005) == 0.01
    assert node_parameter(files[:1], 'rover_vo', 'features.other', 0.005) == 0.005
    far = write_field_bag(tmp_path / 'far', right_late_ms=14.0)
    main(['rover-yaml', str(far)])
    params = {'rover_vo': {'ros__parameters': {'features': {'stereo_sync_tolerance_s': 0.02}}},
              '/roi_detector': {'ros__parameters': {'stereo_sync_tolerance_s': 0.02}}}
    (tmp_path / 'params.yaml').write_text(yaml.safe_dump(params))
    capsys.readouterr()
    _prepare(RunOptions(bag=far, params=tmp_path / 'params.yaml'))
    assert 'stamped' not in capsys.readouterr().err
    # rover.yaml comes after the params file: its tolerance wins.
    rover = yaml.safe_load((far / 'rover.yaml').read_text())
    rover['roi_detector'] = {'ros__parameters': {'stereo_sync_tolerance_s': 0.01}}
    (far / 'rover.yaml').write_text(yaml.safe_dump(rover))
    _prepare(RunOptions(bag=far, params=tmp_path / 'params.yaml'))
    err = capsys.readouterr().err
    assert "roi_detector's stereo_sync_tolerance_s (10 ms)" in err and "rover_vo's" not in err


def test_stamp_offsets_of_a_right_camera_that_stops_early(tmp_path, monkeypatch):
    """Only the left images taken while the right camera streamed are compared, and the
    bag is not read to its end."""
    from rosbags.highlevel import AnyReader

    from rover_bringup.extrinsics import READ_LIMIT, stereo_stamp_offsets

    bag = write_field_bag(tmp_path / 'bag', right_late_ms=3.0, images=400, right_images=5)
    read = []
    messages = AnyReader.messages

    def counted(self, *args, **kwargs):
        for item in messages(self, *args, **kwargs):
            read.append(item[0].topic)
            yield item

    monkeypatch.setattr(AnyReader, 'messages', counted)
    offsets = stereo_stamp_offsets(bag / 'rosbag')
    assert 5 <= len(offsets) <= 6
    assert offsets[:5] == pytest.approx([0.003] * 5)
    assert read.count('/stereo/left/image_raw/compressed') == READ_LIMIT * 2 * 20


def test_a_pan_tilt_head_comes_from_the_urdf_and_the_joint_names(tmp_path):
    from roi_network.mast import MastKinematics
    from roi_network.params import node_parameters

    bag = write_field_bag(tmp_path / 'field', mast=True)
    assert main(['rover-yaml', str(bag)]) == 0
    text = (bag / 'rover.yaml').read_text()
    assert "mast joints 'head_pan' and 'head_tilt'" in text
    params = node_parameters(yaml.safe_load(text), 'rover_vo')
    kin = MastKinematics.from_params(params)
    assert kin.joints == ('head_pan', 'head_tilt') and kin.pan_limits == (-3.0, 3.0)
    for pan, tilt in ((PAN_DEG, TILT_DEG), (-120.0, 35.0)):
        want = _expected('left_camera_optical', _tree_at(pan, tilt))
        np.testing.assert_allclose(kin.base_T_left(np.radians(pan), np.radians(tilt)), want,
                                   atol=1e-8)
    # At the recorded angles the fixed-camera parameters are the same as a static tree's.
    for key, frame in (('base_to_left_camera', 'left_camera_optical'),
                       ('base_to_right_camera', 'right_camera_optical')):
        got = np.asarray(params[key])
        np.testing.assert_allclose(got[:3], _expected(frame)[:3, 3], atol=1e-8)


def test_a_moving_head_without_its_urdf_or_joints_is_named(tmp_path):
    with pytest.raises(CalibrationError, match=r'head_pan, head_tilt.*no /robot_description'):
        rover_parameters(bag_calibration(write_field_bag(tmp_path / 'a', mast=True,
                                                         urdf=False) / 'rosbag'))
    bag = write_field_bag(tmp_path / 'b', mast=True)
    cal = bag_calibration(bag / 'rosbag')
    cal.joint_angles = {'pan': 0.0, 'tilt': 0.0}
    with pytest.raises(CalibrationError, match="'head_pan' and 'head_tilt' not in the names "
                                               "of /joint_states"):
        rover_parameters(cal)
    cal.urdf = cal.urdf.replace('type="revolute"', 'type="prismatic"', 1)
    with pytest.raises(CalibrationError, match="'head_pan' \\(prismatic\\)"):
        rover_parameters(cal)
    cal.urdf = '<robot><joint name="x"'
    with pytest.raises(CalibrationError, match='not a URDF document'):
        rover_parameters(cal)


def test_run_gives_the_matcher_the_bags_dtm_unless_the_params_set_one(tmp_path):
    """A dtm.tif beside the bag becomes darces_matcher's dtm_path in <run>/params.yaml; a
    params file's own dtm_path (even '', no DTM) is kept."""
    from rover_bringup.run import RunOptions, _prepare, _write_params

    bag = write_field_bag(tmp_path / 'bag')
    main(['rover-yaml', str(bag)])
    run = tmp_path / 'run'
    run.mkdir()

    def matcher_params(options):
        _write_params(_prepare(options), run, {'BAG_DIR': str(bag), 'RUN_DIR': str(run)})
        return yaml.safe_load((run / 'params.yaml').read_text()).get(
            'darces_matcher', {}).get('ros__parameters', {})

    assert 'dtm_path' not in matcher_params(RunOptions(bag=bag))
    (bag / 'dtm.tif').write_bytes(b'')  # only its presence is read here
    assert matcher_params(RunOptions(bag=bag))['dtm_path'] == str(bag / 'dtm.tif')
    (tmp_path / 'params.yaml').write_text(yaml.safe_dump(
        {'darces_matcher': {'ros__parameters': {'dtm_path': ''}}}))
    assert matcher_params(RunOptions(bag=bag, params=tmp_path / 'params.yaml'))['dtm_path'] == ''

"""``globloc run``: nodes in their own processes, outputs recorded, the run's status
(crashes, restarts and interrupts: test_reliability.py).

The graph is a test node (fake_pipeline_node.py, given as an explicit ``command:``) that turns
IMU messages into /vo/odometry and /global_pose and latches a /global_network, plus a node
whose executable is not built; then test nodes that publish nothing, or no /global_pose.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from types import ModuleType

import pytest
import yaml

pytestmark = pytest.mark.ros

HERE = Path(__file__).resolve().parent
FAKE = HERE / 'fake_pipeline_node.py'


def _setup(tmp_path: Path, bagfactory: ModuleType, mode: str, name: str) -> tuple[Path, list]:
    """A project bag dir (rosbag/ + rover.yaml), a graph file and a params file."""
    bag_dir = tmp_path / 'bags' / 'tiny'
    spec = bagfactory.write_bag(bag_dir / 'rosbag', bagfactory.BagSpec(duration_s=2.0))
    (bag_dir / 'rover.yaml').write_text('/**:\n  ros__parameters:\n    camera_height: 1.25\n')
    (tmp_path / 'graph.yaml').write_text(
        'nodes:\n'
        f'  - {{name: {name}, command: [$PYTHON, {FAKE}],\n'
        '     outputs: [/vo/odometry, /global_pose, /global_network]}\n'
        '  - {name: later, package: rover_bringup, executable: no_such_node}\n'
    )
    (tmp_path / 'params.yaml').write_text(
        f'{name}:\n  ros__parameters:\n    mode: {mode}\n    bag_dir: $BAG_DIR/gn.geojson\n'
    )
    return bag_dir, spec.expected[bagfactory.IMU_TOPIC]


def _run(
    globloc_cmd: list[str], tmp_path: Path, bag_dir: Path, env: dict[str, str], *extra: str
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*globloc_cmd, 'run', str(bag_dir), '--graph', str(tmp_path / 'graph.yaml'),
         '--params', str(tmp_path / 'params.yaml'), '--out', str(tmp_path / 'out'),
         '--run-id', 'r1', '--rate', '10', '--drain', '1', *extra],
        env=env, capture_output=True, text=True, timeout=120, check=False,
    )


def test_run_records_outputs(
    tmp_path: Path, bagfactory: ModuleType, ros_env: dict[str, str], globloc_cmd: list[str]
):
    bag_dir, imu = _setup(tmp_path, bagfactory, 'echo', 'fake_vo')
    # Default discovery settings and default --settle: the configuration users get.
    result = _run(globloc_cmd, tmp_path, bag_dir, ros_env)
    run_dir = tmp_path / 'out' / 'tiny' / 'r1'
    # Everything ran and published, but a node of the graph never started: degraded.
    assert result.returncode == 3, result.stderr
    assert ('globloc: warning: node later (package rover_bringup, executable no_such_node) '
            'is not built yet: skipped') in result.stderr
    reason = ('later never started: node later (package rover_bringup, executable '
              'no_such_node) is not built yet')
    assert result.stderr.splitlines()[-2:] == [
        f'globloc: degraded: {reason}',
        f'globloc: status: degraded (exit status 3; {run_dir / "run.yaml"})']

    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    assert (report['status'], report['exit_code']) == ('degraded', 3)
    assert report['degraded'] == [reason] and report['errors'] == []
    fake, later = report['nodes']
    assert (fake['name'], fake['status'], fake['exit_code']) == ('fake_vo', 'ran', 0)
    assert fake['published'] == {'/vo/odometry': 200, '/global_pose': 20,
                                 '/global_network': 1}
    assert (later['name'], later['status']) == ('later', 'not built')
    assert report['tools']['globloc_player']['exit_code'] == 0
    counts = report['outputs']['messages']
    assert counts['/vo/odometry'] == len(imu) == 200
    assert counts['/global_pose'] == 20 and counts['/global_network'] == 1
    assert counts['/rois/tracks'] == 0
    assert report['params_files_used'] == [
        str(run_dir / 'params.yaml'), str(bag_dir / 'rover.yaml')]

    # Parameters: $BAG_DIR substituted, rover.yaml passed after the params file.
    log = (run_dir / 'logs' / 'fake_vo.log').read_text()
    assert f'bag_dir={bag_dir.resolve()}/gn.geojson' in log and 'camera_height=1.25' in log
    assert (run_dir / 'logs' / 'globloc_player.log').is_file()

    # The bag, read by rosbags: types, offered QoS, sim-time receive stamps.
    from rosbags.rosbag2 import Reader

    from rover_bringup.qos import qos_from_offers

    with Reader(run_dir / 'outputs') as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns['/vo/odometry'].msgtype == 'nav_msgs/msg/Odometry'
        assert conns['/global_pose'].msgtype == 'geometry_msgs/msg/PoseWithCovarianceStamped'
        assert qos_from_offers(conns['/global_network'].ext.offered_qos_profiles).transient_local
        assert qos_from_offers(conns['/vo/odometry'].ext.offered_qos_profiles).reliable
        times = [t for _, t, _ in reader.messages()]
        assert min(times) >= bagfactory.T0_NS and max(times) <= imu[-1]['stamp'] + 10**9

    # ... and by the mcap library with the ROS 2 decoder (what Foxglove uses).
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with (run_dir / 'outputs' / 'outputs.mcap').open('rb') as fh:
        decoded = [
            (channel.topic, msg)
            for _, channel, _, msg in make_reader(
                fh, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages()
        ]
    odom = [m for t, m in decoded if t == '/vo/odometry']
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in odom] == [
        m['stamp'] for m in imu]
    assert [round(m.pose.pose.position.x) for m in odom] == list(range(len(imu)))
    poses = [m for t, m in decoded if t == '/global_pose']
    assert [m.header.frame_id for m in poses] == ['map'] * 20



def test_silent_node_and_no_global_pose_make_the_run_degraded(
    tmp_path: Path, bagfactory: ModuleType, ros_env: dict[str, str], globloc_cmd: list[str]
):
    """A node that publishes nothing but its status, a matcher that never localizes: the
    run ends degraded (exit 3), one line each, from the nodes' own status topics."""
    bag_dir, imu = _setup(tmp_path, bagfactory, 'echo', 'unused')
    (tmp_path / 'graph.yaml').write_text(
        'nodes:\n'
        f'  - {{name: fake_vo, command: [$PYTHON, {FAKE}], outputs: [/vo/odometry]}}\n'
        f'  - {{name: fake_matcher, command: [$PYTHON, {FAKE}],\n'
        '     outputs: [/global_pose, /matcher/status]}\n')
    (tmp_path / 'params.yaml').write_text(yaml.safe_dump({
        'fake_vo': {'ros__parameters': {'mode': 'silent'}},
        'fake_matcher': {'ros__parameters': {'mode': 'no_fix'}}}))
    result = _run(globloc_cmd, tmp_path, bag_dir, ros_env)
    run_dir = tmp_path / 'out' / 'tiny' / 'r1'
    assert result.returncode == 3, result.stderr
    assert 'Traceback' not in result.stderr
    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    counts = report['outputs']['messages']
    n_vo, n_matcher = counts['/vo/status'], counts['/matcher/status']
    assert n_vo == n_matcher == len(imu) // 10  # every status message recorded
    reasons = [
        f'fake_vo published nothing on /vo/odometry; its last /vo/status (of {n_vo}): '
        f'"imu_propagation: 0 inliers", pairs 0, imu_samples {len(imu) - 9}, '
        f'bad_input.camera_info {n_vo}',
        f'fake_matcher published nothing on /global_pose; its last /matcher/status (of '
        f'{n_matcher}): "not localized: none (too_few_nodes)", state searching, reason '
        'too_few_nodes, ln_size 3',
    ]
    assert (report['status'], report['exit_code'], report['degraded']) == (
        'degraded', 3, reasons)
    assert result.stderr.splitlines()[-3:] == [
        *(f'globloc: degraded: {r}' for r in reasons),
        f'globloc: status: degraded (exit status 3; {run_dir / "run.yaml"})']

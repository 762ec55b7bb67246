"""Unit tests of the ROS-free modules: QoS policy, playback timing, bags, graph, recording."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from rosbags.interfaces import QosHistory, QosReliability

from rover_bringup.bag import BagReadError, locate_bag, open_bag
from rover_bringup.errors import GloblocError
from rover_bringup.graph import (
    Availability,
    NodeSpec,
    load_graph,
    load_params,
    node_command,
    resolve,
    substitute,
)
from rover_bringup.playback import NS_PER_S, PlaybackClock, Progress
from rover_bringup.qos import (
    DEFAULT_DEPTH,
    LATCHED_QOS,
    SENSOR_DATA_QOS,
    TopicQos,
    playback_qos,
    qos_from_offers,
    to_bag_qos,
)
from rover_bringup.recording import OutputBag, count_messages
from rover_bringup.share import config_file
from rover_bringup.topics import OUTPUT_TOPICS, design_qos

# --- QoS -------------------------------------------------------------------------------------


def test_jazzy_recorded_sensor_qos_maps_to_best_effort_default_depth(bagfactory: ModuleType):
    qos = qos_from_offers([bagfactory.SENSOR_QOS_AS_RECORDED])
    assert qos == TopicQos(reliable=False, transient_local=False, depth=DEFAULT_DEPTH)


def test_several_publishers_reliable_only_if_all_are(bagfactory: ModuleType):
    mixed = qos_from_offers([bagfactory.RELIABLE_QOS, bagfactory.SENSOR_QOS])
    assert mixed is not None and not mixed.reliable
    assert qos_from_offers([bagfactory.RELIABLE_QOS]) == TopicQos(depth=10)
    assert qos_from_offers([]) is None


def test_playback_deepens_volatile_history_but_keeps_latched_depth():
    assert playback_qos(SENSOR_DATA_QOS, min_depth=1000).depth == 1000
    assert not playback_qos(SENSOR_DATA_QOS).reliable
    assert playback_qos(LATCHED_QOS) == LATCHED_QOS


def test_design_qos_per_topic():
    assert not design_qos('/imu/data').reliable
    assert design_qos('/global_network').transient_local
    assert design_qos('/global_pose') == TopicQos()
    assert design_qos('/not/in/design') == TopicQos()


def test_bag_qos_record_round_trip():
    record = to_bag_qos(LATCHED_QOS)
    assert record.history == QosHistory.KEEP_LAST and record.depth == 1
    assert record.reliability == QosReliability.RELIABLE
    assert qos_from_offers([record]) == LATCHED_QOS


# --- playback timing -----------------------------------------------------------------------


def test_playback_clock_scales_bag_time_by_rate():
    clock = PlaybackClock(bag_start_ns=5 * NS_PER_S, wall_start=100.0, rate=10.0)
    assert clock.wall_time_of(15 * NS_PER_S) == pytest.approx(101.0)
    assert clock.bag_time_at(100.5) == 10 * NS_PER_S


def test_unpaced_clock_is_always_due():
    clock = PlaybackClock(bag_start_ns=0, wall_start=7.0, rate=0.0)
    assert not clock.paced
    assert clock.wall_time_of(10**12) == 7.0


def test_progress_line_and_period():
    progress = Progress(start_ns=0, end_ns=10 * NS_PER_S, period_s=2.0, sent=42)
    assert progress.line(5 * NS_PER_S) == 'bag time 5.00/10.00 s (50%), 42 msgs sent'
    assert not progress.due(0.0)  # arms the timer
    assert not progress.due(1.9)
    assert progress.due(2.0)
    assert not progress.due(3.0)


# --- bags ------------------------------------------------------------------------------------


def test_locate_project_bag_dir_and_rosbag_dir(tmp_path: Path, bagfactory: ModuleType):
    bagfactory.write_bag(tmp_path / 'quick' / 'rosbag', bagfactory.BagSpec(duration_s=0.1))
    project = locate_bag(tmp_path / 'quick')
    direct = locate_bag(tmp_path / 'quick' / 'rosbag')
    assert project.rosbag == tmp_path / 'quick' / 'rosbag'
    assert project.name == direct.name == 'quick'


def test_locate_errors(tmp_path: Path):
    with pytest.raises(BagReadError, match=r'bag directory not found: .*nope'):
        locate_bag(tmp_path / 'nope')
    with pytest.raises(BagReadError, match=r'no metadata\.yaml'):
        locate_bag(tmp_path)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_topics_and_start_offset(tmp_path: Path, bagfactory: ModuleType, storage: str):
    spec = bagfactory.write_bag(
        tmp_path / 'b', bagfactory.BagSpec(duration_s=1.0, storage=storage)
    )
    with open_bag(tmp_path / 'b') as bag:
        imu = bag.topics[bagfactory.IMU_TOPIC]
        assert (imu.count, imu.msgtype, imu.qos_recorded) == (100, 'sensor_msgs/msg/Imu', True)
        assert not imu.qos.reliable
        assert bag.topics[bagfactory.POSE_TOPIC].qos.reliable
        assert bag.start_ns == bagfactory.T0_NS
        assert bag.end_ns == spec.expected[bagfactory.IMU_TOPIC][-1]['stamp']
        start = bag.start_ns + NS_PER_S // 2
        stamps = [s for _, s, _ in bag.messages([bagfactory.IMU_TOPIC], start)]
        assert len(stamps) == 50 and stamps[0] == start and stamps == sorted(stamps)
        with pytest.raises(BagReadError, match='topic /nope is not in bag'):
            bag.select(['/nope'])


def test_bag_without_recorded_qos_falls_back_to_design(tmp_path: Path, bagfactory: ModuleType):
    bagfactory.write_bag(tmp_path / 'b', bagfactory.BagSpec(duration_s=0.1, record_qos=False))
    with open_bag(tmp_path / 'b') as bag:
        imu = bag.topics[bagfactory.IMU_TOPIC]
        assert not imu.qos_recorded and imu.qos == SENSOR_DATA_QOS


# --- graph -----------------------------------------------------------------------------------


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_graph_entries(tmp_path: Path):
    nodes = load_graph(_write(tmp_path / 'g.yaml', (
        'nodes:\n'
        '  - {name: a, package: p, executable: e}\n'
        '  - {name: b, command: [$PYTHON, x.py]}\n'
    )))
    assert nodes == [NodeSpec('a', 'p', 'e'), NodeSpec('b', command=('$PYTHON', 'x.py'))]


@pytest.mark.parametrize(('text', 'message'), [
    ('nodes: 3', 'top-level "nodes:" list'),
    ('nodes: [{package: p}]', 'nodes\\[0\\]: expected a mapping with a "name"'),
    ('nodes: [{name: a}]', 'give either "command" or "package" and "executable"'),
    ('nodes: [{name: a, command: []}]', 'non-empty list'),
    ('nodes: [{name: a, command: [x], colour: red}]', "unknown key 'colour'"),
    ('nodes: [{name: a, command: [x]}, {name: a, command: [y]}]', 'a is used twice'),
    ('nodes: [', 'cannot read graph file'),
])
def test_graph_errors(tmp_path: Path, text: str, message: str):
    with pytest.raises(GloblocError, match=message):
        load_graph(_write(tmp_path / 'g.yaml', text))


def test_params_layout_and_substitution(tmp_path: Path):
    params = load_params(_write(tmp_path / 'p.yaml', (
        "n:\n  ros__parameters:\n    path: $BAG_DIR/gn.geojson\n    list: ['${RUN_DIR}/x', 3]\n"
        '    price: $5\n'
    )))
    out = substitute(params, {'BAG_DIR': '/b', 'RUN_DIR': '/r'})
    assert out == {'n': {'ros__parameters': {
        'path': '/b/gn.geojson', 'list': ['/r/x', 3], 'price': '$5'}}}
    with pytest.raises(GloblocError, match='ros__parameters'):
        load_params(_write(tmp_path / 'bad.yaml', 'n: {path: 3}\n'))


def test_resolve_not_built_missing_and_command(tmp_path: Path):
    prefix = tmp_path / 'install'
    (prefix / 'share/ament_index/resource_index/packages').mkdir(parents=True)
    (prefix / 'share/ament_index/resource_index/packages/pkg').touch()
    (prefix / 'lib/pkg').mkdir(parents=True)
    exe = prefix / 'lib/pkg/built'
    exe.write_text('#!/bin/sh\n')
    exe.chmod(0o755)
    prefixes = [str(prefix)]
    ready = resolve(NodeSpec('n', 'pkg', 'built'), {}, prefixes)
    assert ready.availability is Availability.READY and ready.argv == (str(exe),)
    not_built = resolve(NodeSpec('n', 'pkg', 'later'), {}, prefixes)
    assert not_built.availability is Availability.NOT_BUILT
    assert not_built.reason == 'node n (package pkg, executable later) is not built yet: skipped'
    missing = resolve(NodeSpec('n', 'nopkg', 'x'), {}, prefixes)
    assert missing.availability is Availability.MISSING
    assert 'package nopkg is not installed' in missing.reason
    command = resolve(NodeSpec('n', command=('$PYTHON', 'x.py')), {'PYTHON': str(exe)}, [])
    assert command.argv == (str(exe), 'x.py')
    gone = resolve(NodeSpec('n', command=('/no/such/exe',)), {}, [])
    assert gone.availability is Availability.MISSING and '/no/such/exe' in gone.reason
    needs = NodeSpec('n', 'pkg', 'built', requires=('$BAG_DIR/gn.geojson',))
    no_input = resolve(needs, {'BAG_DIR': str(tmp_path)}, prefixes)
    assert no_input.availability is Availability.NO_INPUT
    assert no_input.reason == (f'node n (package pkg, executable built) needs '
                               f'{tmp_path}/gn.geojson, which does not exist: skipped')
    (tmp_path / 'gn.geojson').touch()
    assert resolve(needs, {'BAG_DIR': str(tmp_path)}, prefixes).argv == (str(exe),)
    argv = node_command(ready, [Path('/p.yaml')])
    assert argv == [str(exe), '--ros-args', '-r', '__node:=n', '-p', 'use_sim_time:=true',
                    '--params-file', '/p.yaml']


def test_default_graph_and_params_are_valid():
    import os

    nodes = load_graph(config_file('graph.yaml'))
    assert [n.name for n in nodes] == [
        'gn_server', 'rover_vo', 'roi_detector', 'ln_builder', 'darces_matcher']
    params = load_params(config_file('globloc.yaml'))
    assert set(params) <= {n.name for n in nodes} | {'/**'}
    prefixes = os.environ['AMENT_PREFIX_PATH'].split(os.pathsep)
    # Every package of the graph is in the workspace: each node is built or "not built yet".
    for node in nodes:
        assert resolve(node, {}, prefixes).availability is not Availability.MISSING


# --- recording -------------------------------------------------------------------------------


def test_output_bag_holds_messages_until_clock_runs(tmp_path: Path, bagfactory: ModuleType):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    contract = OUTPUT_TOPICS['/global_pose']
    t = ts.types
    msg = t[contract.msgtype](
        t['std_msgs/msg/Header'](t['builtin_interfaces/msg/Time'](1, 2), 'map'),
        t['geometry_msgs/msg/PoseWithCovariance'](
            t['geometry_msgs/msg/Pose'](
                t['geometry_msgs/msg/Point'](1.0, 2.0, 0.0),
                t['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0),
            ),
            np.zeros(36),
        ),
    )
    data = ts.serialize_cdr(msg, contract.msgtype)
    out = OutputBag(tmp_path / 'outputs')
    out.add_topic('/global_pose', contract.msgtype, [to_bag_qos(contract.qos)])
    out.write('/global_pose', None, data)  # before the first /clock
    out.write('/global_pose', 7 * NS_PER_S, data)
    out.close()
    assert count_messages(tmp_path / 'outputs') == {'/global_pose': 2}
    with Reader(tmp_path / 'outputs') as reader:
        assert [t for _, t, _ in reader.messages()] == [7 * NS_PER_S, 7 * NS_PER_S]
        (conn,) = reader.connections
        assert qos_from_offers(conn.ext.offered_qos_profiles) == contract.qos
    with (tmp_path / 'outputs' / 'outputs.mcap').open('rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        decoded = [m.header.frame_id for _, _, _, m in reader.iter_decoded_messages()]
    assert decoded == ['map', 'map']


def _run_watchdog(tmp_path: Path, then: str) -> tuple[int, str, float]:
    """A child process arms the teardown watchdog (status 3, 0.3 s), then runs ``then``."""
    import subprocess
    import sys
    import time

    script = tmp_path / 'child.py'
    script.write_text(
        'import time\n'
        'from rover_bringup.play import _exit_if_teardown_hangs\n'
        '_exit_if_teardown_hangs(3, 0.3)\n'
        f'{then}\n'
    )
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=30, check=False
    )
    return done.returncode, done.stderr, time.monotonic() - t0


def test_play_teardown_watchdog_exits_with_the_playback_status(tmp_path: Path):
    # A teardown that blocks (here: a 20 s sleep) ends at the watchdog, with the status
    # playback decided and a line that says so.
    code, stderr, wall = _run_watchdog(tmp_path, 'time.sleep(20)')
    assert code == 3, stderr
    assert 'teardown still running after 0.3 s; exiting with status 3' in stderr
    assert wall < 15
    # A teardown that finishes is not held up by the armed watchdog, nor its status changed.
    code, stderr, wall = _run_watchdog(tmp_path, 'raise SystemExit(0)')
    assert code == 0 and 'teardown' not in stderr, stderr


def test_sensor_problems_name_what_the_pipeline_cannot_read():
    from rover_bringup.topics import sensor_problems

    others = {'/stereo/left/camera_info': 'sensor_msgs/msg/CameraInfo',
              '/stereo/right/camera_info': 'sensor_msgs/msg/CameraInfo',
              '/imu/data': 'sensor_msgs/msg/Imu'}
    compressed = dict.fromkeys(('/stereo/left/image_raw/compressed',
                                '/stereo/right/image_raw/compressed'),
                               'sensor_msgs/msg/CompressedImage')
    raw = dict.fromkeys(('/stereo/left/image_raw', '/stereo/right/image_raw'),
                        'sensor_msgs/msg/Image')
    assert sensor_problems(others | compressed, 'b') == []
    assert sensor_problems(others | raw, 'b') == []  # a field bag's raw transport
    problems = sensor_problems({'/imu/data': 'sensor_msgs/msg/Temperature', **raw}, 'b.mcap')
    assert len(problems) == 3
    assert 'b.mcap: no /stereo/left/camera_info (sensor_msgs/msg/CameraInfo)' in problems[0]
    assert '/imu/data is sensor_msgs/msg/Temperature' in problems[2]
    problems = sensor_problems(others, 'b.mcap')
    assert len(problems) == 1 and 'b.mcap: no stereo image pair' in problems[0]

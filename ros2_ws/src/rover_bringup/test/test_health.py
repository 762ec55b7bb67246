"""A run's verdict without ROS: which node did not do its part, said from the recorded
counts and the nodes' own status topics; the graph's ``outputs``; the status ``globloc
eval`` reads back; the run's signal handler."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import yaml

from rover_bringup.errors import GloblocError
from rover_bringup.graph import load_graph
from rover_bringup.health import LastStatus, NodeRun, degraded_reasons, read_statuses
from rover_bringup.run_outputs import run_status, run_status_lines

VO_STATUS = LastStatus(95, 'imu_propagation: 0 inliers', {
    'state': 'imu_propagation', 'features': '0', 'pairs': '0', 'imu_samples': '1900',
    'bad_input.camera_info': '95', 'bad_input.imu': '0'})
MATCHER_STATUS = LastStatus(12, 'not localized: none (too_few_nodes)', {
    'state': 'searching', 'event': 'none', 'reason': 'too_few_nodes', 'ln_size': '3',
    'votes': '0'})


def test_a_run_whose_nodes_published_everything_is_not_degraded():
    nodes = [NodeRun('rover_vo', ('/vo/odometry',)),
             NodeRun('darces_matcher', ('/global_pose', '/matcher/status')),
             NodeRun('gn_server')]  # skipped for want of a GN: nothing expected
    counts = {'/vo/odometry': 10, '/global_pose': 3, '/matcher/status': 4}
    assert degraded_reasons(nodes, counts, {'/vo/status': VO_STATUS}) == []


def test_a_silent_node_is_named_with_its_topic_and_its_own_counts():
    (line,) = degraded_reasons([NodeRun('rover_vo', ('/vo/odometry',))],
                               {'/vo/status': 95}, {'/vo/status': VO_STATUS})
    assert line == ('rover_vo published nothing on /vo/odometry; its last /vo/status (of 95): '
                    '"imu_propagation: 0 inliers", pairs 0, imu_samples 1900, '
                    'bad_input.camera_info 95')


def test_no_global_pose_quotes_the_matcher_reason():
    (line,) = degraded_reasons(
        [NodeRun('darces_matcher', ('/global_pose', '/matcher/status'))],
        {'/matcher/status': 12}, {'/matcher/status': MATCHER_STATUS})
    assert line == ('darces_matcher published nothing on /global_pose; its last '
                    '/matcher/status (of 12): "not localized: none (too_few_nodes)", state '
                    'searching, reason too_few_nodes, ln_size 3')


def test_silent_nodes_without_status_name_their_input_and_log():
    nodes = [NodeRun('rover_vo', ('/vo/odometry',)),
             NodeRun('roi_detector', ('/rois/detections', '/rois/tracks')),
             NodeRun('ln_builder', ('/local_network',)),
             NodeRun('darces_matcher', ('/global_pose', '/matcher/status'))]
    assert degraded_reasons(nodes, {'/rois/tracks': 0}, {}) == [
        'rover_vo published nothing on /vo/odometry; no /vo/status either (its log: '
        'logs/rover_vo.log)',
        'roi_detector published nothing on /rois/detections, /rois/tracks; no /rois/status '
        'either, 0 /vo/odometry recorded (its log: logs/roi_detector.log)',
        'ln_builder published nothing on /local_network; 0 /rois/tracks recorded (its log: '
        'logs/ln_builder.log)',
        'darces_matcher published nothing on /global_pose, /matcher/status; 0 '
        '/local_network recorded (its log: logs/darces_matcher.log)',
    ]


def test_restarts_early_exits_and_nodes_never_started():
    nodes = [NodeRun('darces_matcher', ('/global_pose',), restart_codes=(-9, 0)),
             NodeRun('rover_vo', exited_early=0),
             NodeRun('later', ('/vo/odometry',), not_started='node later (package p, '
                     'executable e) is not built yet')]
    assert degraded_reasons(nodes, {'/global_pose': 5}, {}) == [
        'darces_matcher exited (status -9, 0) and was restarted 2 times: its outputs have a '
        'gap',
        'rover_vo exited (status 0) before the end of the run',
        'later never started: node later (package p, executable e) is not built yet',
    ]


def _diagnostics(ts, name: str, message: str, values: dict[str, str], sec: int):
    arr, st = ts.types['diagnostic_msgs/msg/DiagnosticArray'], ts.types[
        'diagnostic_msgs/msg/DiagnosticStatus']
    kv, header = ts.types['diagnostic_msgs/msg/KeyValue'], ts.types['std_msgs/msg/Header']
    stamp = ts.types['builtin_interfaces/msg/Time'](sec=sec, nanosec=0)
    msg = arr(header(stamp, ''), [st(0, name, message, '', [kv(k, v) for k, v in
                                                             values.items()])])
    return ts.serialize_cdr(msg, arr.__msgtype__)


def test_read_statuses_keeps_the_last_message_of_each_status_topic(tmp_path: Path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / 'outputs'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {t: writer.add_connection(t, 'diagnostic_msgs/msg/DiagnosticArray',
                                          typestore=ts)
                 for t in ('/vo/status', '/matcher/status', '/other/status')}
        for i in range(3):
            writer.write(conns['/vo/status'], (100 + i) * 10**9, _diagnostics(
                ts, 'rover_vo', f'vision: {i} inliers', {'pairs': str(i)}, 100 + i))
        writer.write(conns['/matcher/status'], 101 * 10**9, _diagnostics(
            ts, 'darces_matcher', 'not localized', {'reason': 'too_few_nodes'}, 101))
        writer.write(conns['/other/status'], 101 * 10**9, b'\x00\x01')
    statuses = read_statuses(bag)
    assert set(statuses) == {'/vo/status', '/matcher/status'}
    assert statuses['/vo/status'] == LastStatus(3, 'vision: 2 inliers', {'pairs': '2'})
    assert statuses['/matcher/status'].values == {'reason': 'too_few_nodes'}
    with pytest.raises(GloblocError, match='cannot read outputs bag'):
        read_statuses(tmp_path / 'missing')
    # A bag without any status topic (a graph of test nodes): nothing, not its other topics.
    with Writer(tmp_path / 'other', version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/local_network', 'sensor_msgs/msg/PointCloud2',
                                     typestore=ts)
        writer.write(conn, 10**9, b'\x00\x01\x00\x00')
    assert read_statuses(tmp_path / 'other') == {}


def test_graph_outputs_override_the_defaults_and_are_checked(tmp_path: Path):
    graph = tmp_path / 'graph.yaml'
    graph.write_text('nodes:\n'
                     '  - {name: vo, package: rover_vo, executable: rover_vo}\n'
                     '  - {name: m, package: darces_matcher, executable: darces_matcher,\n'
                     '     outputs: [/matcher/status]}\n'
                     '  - {name: t, command: [python3, x.py], outputs: [/vo/odometry]}\n'
                     '  - {name: u, command: [python3, x.py]}\n')
    vo, m, t, u = load_graph(graph)
    assert vo.expected_outputs == ('/vo/odometry',)
    assert m.expected_outputs == ('/matcher/status',)
    assert t.expected_outputs == ('/vo/odometry',) and u.expected_outputs == ()
    graph.write_text('nodes:\n  - {name: t, command: [python3], outputs: [vo/odometry]}\n')
    with pytest.raises(GloblocError, match=r'nodes\[0\]: "outputs" must be a list of topic'):
        load_graph(graph)


def test_run_status_for_eval(tmp_path: Path):
    assert run_status(tmp_path)['status'] == 'unknown'
    (tmp_path / 'run.yaml').write_text(yaml.safe_dump({'status': 'degraded', 'exit_code': 3,
                                                       'degraded': ['a silent', 'b restarted'],
                                                       'errors': []}))
    status = run_status(tmp_path)
    assert status == {'status': 'degraded', 'exit_code': 3,
                      'reasons': ['a silent', 'b restarted']}
    assert run_status_lines(status) == ['run status: degraded', '  a silent', '  b restarted']
    (tmp_path / 'run.yaml').write_text(yaml.safe_dump({
        'status': 'interrupted', 'exit_code': 130, 'interrupted_by': 'SIGINT',
        'degraded': [], 'errors': []}))
    assert run_status(tmp_path)['reasons'] == [
        'interrupted by SIGINT: the outputs end where the run was stopped']
    (tmp_path / 'run.yaml').write_text(yaml.safe_dump({'status': 'ok', 'errors': []}))
    assert run_status_lines(run_status(tmp_path)) == []
    (tmp_path / 'run.yaml').write_text(yaml.safe_dump({'errors': []}))  # an older run
    assert run_status(tmp_path)['status'] == 'unknown'


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_the_run_handler_catches_both_signals_even_when_sigint_is_ignored(sig: int):
    from rover_bringup.run import _Interrupt

    before = signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a background job inherits it
    try:
        with _Interrupt() as interrupt:
            # Before anything started: the signal ends the run at once.
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), sig)
            assert interrupt() and interrupt.name == signal.Signals(sig).name
            assert interrupt.event.is_set()
        with _Interrupt() as interrupt:
            interrupt.raising = False  # processes running: only recorded
            os.kill(os.getpid(), sig)
            os.kill(os.getpid(), signal.SIGTERM)  # a second one changes nothing
            assert interrupt.name == signal.Signals(sig).name
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # restored
    finally:
        signal.signal(signal.SIGINT, before)

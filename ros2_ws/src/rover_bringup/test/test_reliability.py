"""Reliability of ``globloc run``: a node killed mid-run is restarted and the real matcher
re-fixes, and the run says it is degraded; SIGINT or SIGTERM stops the graph, restarting
nothing, and leaves a readable outputs bag; a bag cut short or with corrupt data gets a
clear message and keeps what was recorded."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path
from types import ModuleType

import numpy as np
import psutil
import pytest
import yaml
from scipy.spatial.transform import Rotation

pytestmark = pytest.mark.ros

HERE = Path(__file__).resolve().parent
LN_SOURCE = HERE / 'ln_source_node.py'
FAKE = HERE / 'fake_pipeline_node.py'
SPEED = 20.0  # m/s of the LN source's rover (a short bag covers a long route)


def _wait_for(cond, timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            raise AssertionError(f'timed out waiting for {what}')
        time.sleep(0.1)


def _read(path: Path) -> str:
    try:
        return path.read_text(errors='replace')
    except OSError:
        return ''


def _matcher_graph(tmp_path: Path, bagfactory: ModuleType, duration_s: float) -> Path:
    """A bag dir (IMU bag, GN, truth trajectory), a graph of the LN source and the real
    darces_matcher node, and its params file."""
    from darces_matcher.gn_generator import generate_gn
    from roi_network.geojson import write_geojson
    from roi_network.records import xy

    bag_dir = tmp_path / 'bags' / 'route'
    spec = bagfactory.write_bag(bag_dir / 'rosbag', bagfactory.BagSpec(duration_s=duration_s))
    gn = generate_gn(seed=11)
    write_geojson(gn, bag_dir / 'gn.geojson')
    pts = xy(gn.records)
    start = pts[np.argmin(pts[:, 0])] + [0.0, -5.0]  # as ln_source_node.route_start
    (bag_dir / 'truth').mkdir()
    rows = []
    for m in spec.expected[bagfactory.IMU_TOPIC]:
        s = SPEED * (m['stamp'] - bagfactory.T0_NS) * 1e-9
        rows.append(f"{m['stamp'] * 1e-9:.9f} {start[0] + s:.6f} {start[1]:.6f} 0 0 0 0 1\n")
    (bag_dir / 'truth' / 'trajectory.tum').write_text(''.join(rows))
    (tmp_path / 'graph.yaml').write_text(
        'nodes:\n'
        f'  - {{name: ln_source, command: [$PYTHON, {LN_SOURCE}]}}\n'
        '  - {name: darces_matcher, package: darces_matcher, executable: darces_matcher,\n'
        '     requires: [$BAG_DIR/gn.geojson]}\n')
    (tmp_path / 'params.yaml').write_text(yaml.safe_dump({
        'ln_source': {'ros__parameters': {
            'gn_path': '$BAG_DIR/gn.geojson', 't0_ns': bagfactory.T0_NS, 'speed_mps': SPEED}},
        'darces_matcher': {'ros__parameters': {'gn_path': '$BAG_DIR/gn.geojson'}},
    }))
    return bag_dir


def _fake_graph(tmp_path: Path, name: str, mode: str, bag_s: float, bagfactory,
                outputs: str = '') -> Path:
    """A bag dir of ``bag_s`` seconds and a graph of the fake pipeline node in ``mode``
    (``outputs``: the graph entry's list of topics it must publish, e.g. ``[/vo/odometry]``;
    '': none checked)."""
    bag_dir = tmp_path / 'bags' / 'tiny'
    bagfactory.write_bag(bag_dir / 'rosbag', bagfactory.BagSpec(duration_s=bag_s))
    (tmp_path / 'graph.yaml').write_text(
        f'nodes:\n  - {{name: {name}, command: [$PYTHON, {FAKE}]'
        + (f', outputs: {outputs}' if outputs else '') + '}\n')
    (tmp_path / 'params.yaml').write_text(
        f'{name}:\n  ros__parameters:\n    mode: {mode}\n    marker: {tmp_path / "marker"}\n')
    return bag_dir


def _start_run(globloc_cmd, tmp_path: Path, bag_dir: Path, env, *extra: str,
               sigint=signal.SIG_DFL):
    return subprocess.Popen(
        [*globloc_cmd, 'run', str(bag_dir), '--graph', str(tmp_path / 'graph.yaml'),
         '--params', str(tmp_path / 'params.yaml'), '--out', str(tmp_path / 'out'),
         '--run-id', 'r1', '--settle', '1', *extra],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,  # its own process group, as a shell job: Ctrl-C reaches all
        # SIGINT as a terminal gives it (SIG_DFL), even when pytest runs where it is ignored
        # (a background job): a process that inherits SIG_IGN keeps ignoring it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, sigint))


def _stop_if_running(proc: subprocess.Popen) -> None:
    """SIGTERM a run still going (a failed test), and wait for it."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)


def _node_process(root: psutil.Process, name: str) -> psutil.Process:
    for child in root.children(recursive=True):
        try:
            if f'__node:={name}' in child.cmdline():
                return child
        except psutil.Error:
            continue
    raise AssertionError(f'no process of node {name}')


def test_killed_matcher_is_restarted_and_refixes(
    tmp_path: Path, bagfactory: ModuleType, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str], globloc, sigkill_shm_cleanup: None,
):
    # Long enough for the restarted matcher to load its GN index (seconds on a loaded
    # machine) and get odometry again before the bag ends.
    bag_dir = _matcher_graph(tmp_path, bagfactory, duration_s=16.0)
    proc = _start_run(globloc_cmd, tmp_path, bag_dir, fast_discovery_env, '--rate', '1',
                      '--drain', '2')
    log = tmp_path / 'out' / 'route' / 'r1' / 'logs' / 'darces_matcher.log'
    try:
        _wait_for(lambda: 'first_fix' in _read(log) or proc.poll() is not None, 60,
                  'the first fix')
        assert proc.poll() is None, proc.communicate()
        victim = _node_process(psutil.Process(proc.pid), 'darces_matcher')
        victim.send_signal(signal.SIGKILL)  # dies without cleaning up, as a crash does
        _, err = proc.communicate(timeout=120)
    finally:
        _stop_if_running(proc)
    assert proc.returncode == 3, err  # degraded: the matcher was restarted
    assert 'globloc: warning: darces_matcher exited (status -9) while running: restarting it ' \
           '(1 of at most 3' in err
    reason = 'darces_matcher exited (status -9) and was restarted 1 time: its outputs have a gap'
    assert f'globloc: degraded: {reason}' in err
    run_dir = tmp_path / 'out' / 'route' / 'r1'
    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    matcher = next(n for n in report['nodes'] if n['name'] == 'darces_matcher')
    assert matcher['restarts'] == 1 and matcher['restarted_after_exit_codes'] == [-9]
    assert matcher['status'] == 'ran' and report['status'] == 'degraded'
    assert report['degraded'] == [reason]
    text = _read(log)
    assert text.count('first_fix') == 2, text  # the new matcher re-fixed from the latched LN
    assert '[globloc] darces_matcher exited (status -9)' in text
    assert report['outputs']['messages']['/global_alignment'] >= 2

    # The run, judged: poses from both incarnations, right, and no false fix.
    result = globloc(['eval', str(run_dir), '--json', '--no-plots'])
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary['localized'] and summary['false_fixes'] == 0
    assert summary['max_error_m'] < 1.0
    assert summary['consistency_3sigma'] >= 0.99


def test_node_restarted_once_makes_the_run_degraded(
    tmp_path: Path, bagfactory: ModuleType, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str],
):
    bag_dir = _fake_graph(tmp_path, 'fake_vo', 'crash_once', 8.0, bagfactory, '[/vo/odometry]')
    proc = _start_run(globloc_cmd, tmp_path, bag_dir, fast_discovery_env, '--rate', '1')
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 3, err
    assert err.count('fake_vo exited (status 3) while running: restarting it (1 of at most 3') \
        == 1
    reason = 'fake_vo exited (status 3) and was restarted 1 time: its outputs have a gap'
    run_dir = tmp_path / 'out' / 'tiny' / 'r1'
    assert err.splitlines()[-2:] == [
        f'globloc: degraded: {reason}',
        f'globloc: status: degraded (exit status 3; {run_dir / "run.yaml"})']
    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    assert (report['status'], report['exit_code'], report['degraded'], report['errors']) == (
        'degraded', 3, [reason], [])
    assert report['nodes'][0]['published']['/vo/odometry'] > 0  # the second incarnation's


def test_node_out_of_restarts_ends_the_run(
    tmp_path: Path, bagfactory: ModuleType, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str],
):
    bag_dir = _fake_graph(tmp_path, 'crasher', 'crash', 20.0, bagfactory)
    proc = _start_run(globloc_cmd, tmp_path, bag_dir, fast_discovery_env, '--rate', '1',
                      '--max-restarts', '2')
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1
    assert 'Traceback' not in err
    assert err.count('crasher exited (status 3) while running: restarting it') == 2
    assert 'globloc: error: node crasher crashed (exit status 3); last lines of' in err
    # The tail of its log (20 lines), not the whole log.
    assert 'fake failure detail line 29' in err
    assert 'fake failure detail line 10' in err
    assert 'fake failure detail line 9\n' not in err
    report = yaml.safe_load((tmp_path / 'out' / 'tiny' / 'r1' / 'run.yaml').read_text())
    assert report['status'] == 'failed'
    node = report['nodes'][0]
    assert node['restarts'] == 2 and node['crashed'] and node['exit_code'] == 3


def _check_outputs_readable(run_dir: Path) -> dict[str, int]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader

    with Reader(run_dir / 'outputs') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert sum(1 for _ in reader.messages()) == sum(counts.values())
    with (run_dir / 'outputs' / 'outputs.mcap').open('rb') as fh:
        n = sum(1 for _ in make_reader(fh, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages())
    assert n == sum(counts.values())
    return counts


#: How a user's interrupt reaches ``globloc run``: (signal, sent to the whole process group
#: as a terminal's Ctrl-C is, SIGINT ignored by inheritance as in a job a non-interactive
#: shell started in the background; the ROS children install their own handlers anyway).
INTERRUPTS = {
    'sigint-group-inherited-ignored': (signal.SIGINT, True, True),
    'sigterm-group': (signal.SIGTERM, True, False),
    'sigterm-run-only': (signal.SIGTERM, False, False),
}


@pytest.mark.parametrize('how', sorted(INTERRUPTS))
def test_interrupt_stops_the_graph_without_restarts_and_keeps_the_outputs(
    how: str, tmp_path: Path, bagfactory: ModuleType, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str],
):
    sig, group, inherit_ignored = INTERRUPTS[how]
    bag_dir = _fake_graph(tmp_path, 'fake_vo', 'echo', 30.0, bagfactory)
    proc = _start_run(globloc_cmd, tmp_path, bag_dir, fast_discovery_env, '--rate', '1',
                      sigint=signal.SIG_IGN if inherit_ignored else signal.SIG_DFL)
    player_log = tmp_path / 'out' / 'tiny' / 'r1' / 'logs' / 'globloc_player.log'
    try:
        _wait_for(lambda: 'bag time 2.' in _read(player_log) or proc.poll() is not None, 60,
                  'two seconds of playback')
        if proc.poll() is not None:  # ended before it could be interrupted: say how
            _, err = proc.communicate()
            pytest.fail(f'globloc run exited ({proc.returncode}) before two seconds of '
                        f'playback:\n{err[-3000:]}\nplayer log:\n{_read(player_log)[-2000:]}')
        children = psutil.Process(proc.pid).children(recursive=True)
        if group:
            os.killpg(proc.pid, sig)  # what Ctrl-C in the terminal does
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert 'Traceback' not in err and 'restarting it' not in err, err
    # The run's own output after the interrupt: one line (the player's echo of its log
    # before it is the player's; its "play interrupted" is muted).
    after = [ln for ln in err.splitlines()
             if ln.startswith('globloc:') and not ln.startswith('globloc: run ')]
    assert len(after) == 1, err
    name = signal.Signals(sig).name
    assert after[0].startswith(f'globloc: interrupted by {name}: graph stopped'), after
    assert not [c for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
    run_dir = tmp_path / 'out' / 'tiny' / 'r1'
    counts = _check_outputs_readable(run_dir)
    assert 100 <= counts['/vo/odometry'] < 3000  # part of the bag, all of it kept
    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    assert (report['status'], report['interrupted_by'], report['errors']) == (
        'interrupted', name, [])
    assert all(n['status'] == 'ran' and 'restarts' not in n for n in report['nodes'])
    assert [n['exit_code'] for n in report['nodes']] == [0]  # stopped, not killed
    # The TUM export of what was recorded.
    rows = [ln for ln in (run_dir / 'vo.tum').read_text().splitlines() if ln[0] != '#']
    assert len(rows) == counts['/vo/odometry']



def test_a_run_whose_caller_died_still_stops_its_graph_on_sigterm(
    tmp_path: Path, bagfactory: ModuleType, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str],
):
    """The process that started the run dies (its end of the run's stderr pipe closes),
    then the run gets SIGTERM: it still stops every child and writes run.yaml, though it
    cannot say so."""
    bag_dir = _fake_graph(tmp_path, 'fake_vo', 'echo', 30.0, bagfactory)
    proc = _start_run(globloc_cmd, tmp_path, bag_dir, fast_discovery_env, '--rate', '1')
    player_log = tmp_path / 'out' / 'tiny' / 'r1' / 'logs' / 'globloc_player.log'
    try:
        _wait_for(lambda: 'bag time 2.' in _read(player_log) or proc.poll() is not None, 60,
                  'two seconds of playback')
        assert proc.poll() is None, 'the run ended before it could be interrupted'
        children = psutil.Process(proc.pid).children(recursive=True)
        proc.stdout.close()
        proc.stderr.close()  # the caller is gone: the run's next line meets a closed pipe
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130
    assert not [c for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
    report = yaml.safe_load((tmp_path / 'out' / 'tiny' / 'r1' / 'run.yaml').read_text())
    assert (report['status'], report['interrupted_by']) == ('interrupted', 'SIGTERM')


def _corrupt_copy(src: Path, dst: Path, topic: str, every: int) -> int:
    """Copy a bag, truncating the CDR bytes of every ``every``-th message of ``topic``;
    returns how many were corrupted."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    n, corrupted = 0, 0
    with Reader(src) as reader, Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        out = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts,
                                      offered_qos_profiles=c.ext.offered_qos_profiles)
               for c in reader.connections}
        for conn, stamp, raw in reader.messages():
            if conn.topic == topic:
                n += 1
                if n % every == 0:
                    raw, corrupted = bytes(raw[:9]), corrupted + 1
            w.write(out[conn.id], stamp, raw)
    return corrupted


def test_bag_with_corrupt_messages_plays_the_rest(
    tmp_path: Path, bagfactory: ModuleType, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str],
):
    bag_dir = _fake_graph(tmp_path, 'fake_vo', 'echo', 3.0, bagfactory, '[/vo/odometry]')
    (bag_dir / 'rosbag').rename(tmp_path / 'clean')
    corrupted = _corrupt_copy(tmp_path / 'clean', bag_dir / 'rosbag', bagfactory.IMU_TOPIC, 20)
    n_imu = 300  # 3 s at 100 Hz
    assert corrupted == n_imu // 20
    proc = _start_run(globloc_cmd, tmp_path, bag_dir, fast_discovery_env, '--rate', '5')
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err
    assert '/imu/data: corrupt message at bag time' in err
    assert f'corrupt messages skipped: /imu/data {corrupted}' in err
    run_dir = tmp_path / 'out' / 'tiny' / 'r1'
    counts = _check_outputs_readable(run_dir)
    # Every good IMU message became one odometry message; the node never died.
    assert counts['/vo/odometry'] == n_imu - corrupted
    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    assert report['status'] == 'ok' and 'restarts' not in report['nodes'][0]
    assert report['degraded'] == [] and err.splitlines()[-1] == 'globloc: status: ok'


def test_bag_cut_short_is_a_clear_error_before_anything_starts(
    tmp_path: Path, bagfactory: ModuleType, globloc,
):
    bag_dir = tmp_path / 'bags' / 'tiny'
    bagfactory.write_bag(bag_dir / 'rosbag', bagfactory.BagSpec(duration_s=2.0))
    mcap = bag_dir / 'rosbag' / 'rosbag.mcap'
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size * 2 // 3])  # no end marker
    (tmp_path / 'graph.yaml').write_text(
        f'nodes:\n  - {{name: fake_vo, command: [$PYTHON, {FAKE}]}}\n')
    result = globloc(['run', str(bag_dir), '--graph', str(tmp_path / 'graph.yaml'),
                      '--out', str(tmp_path / 'out')])
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'globloc: error: cannot read bag {mcap.parent}')
    assert 'cut short' in lines[0] or 'magic' in lines[0]
    assert not (tmp_path / 'out').exists()  # nothing started, nothing half-written


def test_cut_short_bag_is_salvaged(tmp_path: Path, bagfactory: ModuleType, globloc):
    bag_dir = tmp_path / 'bags' / 'tiny'
    # 40 s: about 1.8 MB, two complete 1 MiB chunks before the cut.
    spec = bagfactory.write_bag(bag_dir / 'rosbag', bagfactory.BagSpec(duration_s=40.0))
    total = sum(len(v) for v in spec.expected.values())
    from rosbags.rosbag2 import Reader

    with Reader(bag_dir / 'rosbag') as reader:
        original = [bytes(raw) for c, _, raw in reader.messages()
                    if c.topic == bagfactory.IMU_TOPIC]
    mcap = bag_dir / 'rosbag' / 'rosbag.mcap'
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size * 9 // 10])
    result = globloc(['play', str(bag_dir)])
    assert result.returncode == 1 and 'globloc salvage' in result.stderr
    out = tmp_path / 'salvaged'
    result = globloc(['salvage', str(bag_dir), '--out', str(out)])
    assert result.returncode == 0, result.stderr
    assert 'reading stopped at: EndOfFile' in result.stderr

    from rover_bringup.qos import qos_from_offers

    with Reader(out) as reader:
        n = sum(1 for _ in reader.messages())
        conns = {c.topic: c for c in reader.connections}
        # Every message before the cut, in order, bytes unchanged.
        imu = [bytes(raw) for c, _, raw in reader.messages()
               if c.topic == bagfactory.IMU_TOPIC]
    assert 0 < n < total
    assert conns[bagfactory.IMU_TOPIC].msgtype == 'sensor_msgs/msg/Imu'
    assert not qos_from_offers(conns[bagfactory.IMU_TOPIC].ext.offered_qos_profiles).reliable
    assert len(imu) > 1000 and imu == original[:len(imu)]
    # A second salvage into the same place is refused, nothing overwritten.
    result = globloc(['salvage', str(bag_dir), '--out', str(out)])
    assert result.returncode == 1 and 'exists already' in result.stderr


@pytest.fixture(scope='module')
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulator bag (tiny preset, denser rocks so that its short route builds an LN) with
    the truth catalogue as its GN (the test is about restarts, not the orbital detector)."""
    import shutil

    from atacama_sim.config import make_config
    from atacama_sim.generate import generate

    out = tmp_path_factory.mktemp('bags') / 'sim'
    generate(make_config('tiny', 1, {
        'rocks': {'major_per_km2': 6000.0, 'cluster_sigma_m': 5.0},
        'route': {'length_m': 16.0, 'roi_range_m': 6.0, 'rois_target': (4, 10)}}),
        out, progress=False)
    shutil.copy(out / 'truth' / 'rois.geojson', out / 'gn.geojson')
    return out


def _bag_time(player_log: Path) -> float:
    times = [float(line.split('bag time ')[1].split('/')[0])
             for line in _read(player_log).splitlines() if 'bag time ' in line]
    return times[-1] if times else 0.0


def test_each_node_of_the_real_graph_killed_once(
    tmp_path: Path, sim_bag: Path, fast_discovery_env: dict[str, str],
    globloc_cmd: list[str], globloc, sigkill_shm_cleanup: None,
):
    """The product graph (package graph and params) on a simulator bag, each node SIGKILLed
    once mid-run: each is restarted; rover_vo goes on in the same odom frame; ln_builder
    comes back with the LN it had; the run ends well and nothing is localized falsely."""
    proc = subprocess.Popen(
        [*globloc_cmd, 'run', str(sim_bag), '--out', str(tmp_path / 'out'), '--run-id', 'r1',
         '--rate', '2', '--settle', '1'],
        env=fast_discovery_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    run_dir = tmp_path / 'out' / 'sim' / 'r1'
    logs = run_dir / 'logs'
    # The route loops back near its start at 40 s, then drives away: rover_vo is killed
    # 4 m from its odom origin, where a new odom frame would show.
    schedule = [('roi_detector', 24.0), ('ln_builder', 36.0), ('gn_server', 44.0),
                ('darces_matcher', 52.0), ('rover_vo', 66.0)]
    ln_nodes_at_kill = 0
    try:
        for name, bag_s in schedule:
            _wait_for(lambda b=bag_s: _bag_time(logs / 'globloc_player.log') >= b
                      or proc.poll() is not None, 120, f'bag time {bag_s} s')
            assert proc.poll() is None, proc.communicate()
            if name == 'rover_vo':
                assert (run_dir / 'rover_vo_state.json').exists()
            if name == 'ln_builder' and (run_dir / 'ln.geojson').exists():
                ln_nodes_at_kill = len(json.loads((run_dir / 'ln.geojson').read_text())
                                       ['features'])
            _node_process(psutil.Process(proc.pid), name).send_signal(signal.SIGKILL)
            _wait_for(lambda n=name: f'[globloc] {n} exited (status -9)' in _read(
                logs / f'{n}.log') or proc.poll() is not None, 30, f'{name} restarted')
        _, err = proc.communicate(timeout=180)
    finally:
        _stop_if_running(proc)
    assert proc.returncode == 3, err  # degraded: every node was restarted
    report = yaml.safe_load((run_dir / 'run.yaml').read_text())
    assert report['status'] == 'degraded'
    restarted = [r for r in report['degraded'] if 'restarted' in r]
    assert restarted == [
        f'{name} exited (status -9) and was restarted 1 time: its outputs have a gap'
        for name in ('gn_server', 'rover_vo', 'roi_detector', 'ln_builder', 'darces_matcher')]
    for node in report['nodes']:
        assert node['status'] == 'ran' and node['restarts'] == 1, node
        assert node['restarted_after_exit_codes'] == [-9]
    for name, _ in schedule:
        assert 'Traceback' not in _read(logs / f'{name}.log'), name

    # rover_vo resumed its odom frame: no jump back to the origin in the odometry.
    assert 'resuming the odom frame saved in' in _read(logs / 'rover_vo.log')
    vo = np.loadtxt(run_dir / 'vo.tum', comments='#', ndmin=2)
    steps = np.linalg.norm(np.diff(vo[:, 1:3], axis=0), axis=1)
    assert steps.max() < 2.0, steps.max()
    truth = np.loadtxt(sim_bag / 'truth' / 'trajectory.tum')
    p = np.array([np.interp(vo[:, 0], truth[:, 0], truth[:, k]) for k in (1, 2)]).T
    q0 = [np.interp(vo[0, 0], truth[:, 0], truth[:, k]) for k in (4, 5, 6, 7)]
    yaw0 = Rotation.from_quat(q0).as_euler('ZYX')[0]
    c, s = np.cos(yaw0), np.sin(yaw0)
    in_odom = (p - p[0]) @ np.array([[c, -s], [s, c]])  # truth in the first pose's frame
    after = vo[:, 0] > truth[0, 0] + 66.0
    assert after.sum() >= 3
    err = np.linalg.norm(vo[:, 1:3] - in_odom, axis=1)
    assert err[after].max() < 2.5, err

    # ln_builder came back with its LN; the LN only grew.
    final = json.loads((run_dir / 'ln.geojson').read_text())['features']
    if ln_nodes_at_kill:
        assert f'{ln_nodes_at_kill} nodes' in _read(logs / 'ln_builder.log')
    assert len(final) >= ln_nodes_at_kill

    # The run, judged: no false fix through the gaps.
    result = globloc(['eval', str(run_dir), '--json', '--no-plots'])
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert not summary['localized'] or summary['false_fixes'] == 0, summary

"""Bad input gives one ``globloc: error: ...`` line naming the problem, non-zero, no traceback."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest

HERE = Path(__file__).resolve().parent


def _one_error_line(result, *needles: str) -> str:
    assert result.returncode == 1, result.stderr
    assert 'Traceback' not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith('globloc: error: ')
    for needle in needles:
        assert needle in lines[0]
    return lines[0]


def test_missing_bag_dir(tmp_path: Path, globloc):
    missing = tmp_path / 'no_such_bag'
    result = globloc(['play', str(missing)])
    assert _one_error_line(result) == f'globloc: error: bag directory not found: {missing}'


def test_dir_without_bag(tmp_path: Path, globloc):
    _one_error_line(globloc(['play', str(tmp_path)]), f'cannot read bag {tmp_path}',
                    'no metadata.yaml')


def test_truncated_mcap(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=1.0))
    mcap = tmp_path / 'bag' / 'bag.mcap'
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    _one_error_line(globloc(['play', str(tmp_path / 'bag')]),
                    f'cannot read bag {tmp_path / "bag"}: ', 'magic is invalid')


@pytest.mark.ros
def test_garbled_mcap_fails_during_playback(
    tmp_path: Path, bagfactory: ModuleType, globloc, ros_env: dict[str, str]
):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=10.0))
    mcap = tmp_path / 'bag' / 'bag.mcap'
    data = bytearray(mcap.read_bytes())
    for i in range(100_000, 200_000, 997):  # chunk headers in the middle: found only on read
        data[i] ^= 0xFF
    mcap.write_bytes(bytes(data))
    result = globloc(['play', str(tmp_path / 'bag'), '--rate', '0', '--wait-subscribers', '0'],
                     env=ros_env)
    assert result.returncode == 1, result.stderr
    assert 'Traceback' not in result.stderr
    errors = [line for line in result.stderr.splitlines() if 'error' in line]
    assert len(errors) == 1
    assert errors[0].startswith(f'globloc: error: cannot read bag {mcap.parent}')


def test_unknown_message_type(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_custom_type_bag(tmp_path / 'bag', topics=['/foo'])
    line = _one_error_line(globloc(['play', str(tmp_path / 'bag')]))
    assert line == ('globloc: error: topic /foo has message type foo_msgs/msg/Bar which is not '
                    'available in this ROS install')


def test_unknown_topic(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    _one_error_line(globloc(['play', str(tmp_path / 'bag'), '--topics', '/nope']),
                    'topic /nope is not in bag')


def _graph(tmp_path: Path, entry: str) -> list[str]:
    (tmp_path / 'graph.yaml').write_text(f'nodes:\n  - {entry}\n')
    (tmp_path / 'params.yaml').write_text('{}\n')
    return ['--graph', str(tmp_path / 'graph.yaml'), '--params', str(tmp_path / 'params.yaml'),
            '--out', str(tmp_path / 'out')]


def test_run_missing_executable(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    args = _graph(tmp_path, '{name: ghost, command: [/no/such/node_exe]}')
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), *args]),
                    'node ghost', 'executable /no/such/node_exe not found')
    assert not (tmp_path / 'out').exists()  # nothing started, nothing written


def test_run_missing_package(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    args = _graph(tmp_path, '{name: vo, package: no_such_pkg, executable: vo}')
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), *args]),
                    'node vo (package no_such_pkg, executable vo)',
                    'package no_such_pkg is not installed')


def test_run_strict_refuses_unbuilt_node(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    args = _graph(tmp_path, '{name: later, package: rover_bringup, executable: no_such_node}')
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), '--strict', *args]),
                    'node later (package rover_bringup, executable no_such_node) is not built')


def test_run_unknown_message_type(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_custom_type_bag(tmp_path / 'bag', topics=['/foo'])
    args = _graph(tmp_path, '{name: later, package: rover_bringup, executable: no_such_node}')
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), *args]), 'foo_msgs/msg/Bar')


def test_bad_graph_file(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    args = _graph(tmp_path, '{name: x}')
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), *args]), 'nodes[0]')

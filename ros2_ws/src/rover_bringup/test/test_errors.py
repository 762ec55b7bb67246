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
                    'available in this ROS install')  # nothing else to play


@pytest.mark.ros
def test_topics_of_types_not_installed_are_left_out(tmp_path: Path, bagfactory: ModuleType,
                                                    globloc, ros_env: dict[str, str]):
    """A field bag records topics of packages this install lacks (/tf_static's tf2_msgs):
    the others play, and one warning names what was left out; named with --topics, such
    a topic is an error."""
    bagfactory.write_custom_type_bag(tmp_path / 'bag', topics=['/foo', '/tf_static'],
                                     imu_messages=20)
    result = globloc(['play', str(tmp_path / 'bag'), '--rate', '0', '--wait-subscribers', '0'],
                     env=ros_env)
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if 'warning' in line]
    assert len(warnings) == 1
    assert '/foo (foo_msgs/msg/Bar), /tf_static (foo_msgs/msg/Bar)' in warnings[0]
    assert 'not played' in warnings[0]
    _one_error_line(globloc(['play', str(tmp_path / 'bag'), '--topics', '/foo', '/imu/data']),
                    'topic /foo has message type foo_msgs/msg/Bar which is not available')


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


ORIGIN = (403446.0, 7334375.0)
FAKE_ENTRY = f'{{name: fake_vo, command: [$PYTHON, {HERE / "fake_pipeline_node.py"}]}}'


def _orbital(path: Path, crs: str) -> None:
    """A 400 m x 400 m orbital image whose corner is 200 m west and north of ORIGIN."""
    import numpy as np
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, 'w', driver='GTiff', width=200, height=200, count=1,
                       dtype='uint8', crs=crs,
                       transform=from_origin(ORIGIN[0] - 200, ORIGIN[1] + 200, 2.0, 2.0)) as d:
        d.write(np.zeros((1, 200, 200), np.uint8))


def _gn(path: Path, crs: str, offset_m: float = 0.0) -> None:
    """A 20-ROI GN (map origin ORIGIN) on a line ``offset_m`` east of the image centre."""
    import numpy as np

    from roi_network.geojson import write_geojson
    from roi_network.network import MapFrame, RoiNetwork
    from roi_network.records import empty_records

    gn = empty_records(20)
    gn['x'], gn['y'], gn['id'], gn['label'] = offset_m + np.linspace(-50, 50, 20), 0.0, \
        range(20), 1
    write_geojson(RoiNetwork(gn, 'map', MapFrame(crs, ORIGIN)), path)


def test_run_refuses_a_gn_in_another_crs(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    _orbital(tmp_path / 'bag' / 'orbital.tif', 'EPSG:32719')
    _gn(tmp_path / 'bag' / 'gn.geojson', 'EPSG:32619')  # UTM 19 north: another map frame
    args = _graph(tmp_path, FAKE_ENTRY)
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), *args]),
                    f'GN {tmp_path / "bag" / "gn.geojson"} is in EPSG:32619',
                    'orbital image', 'in EPSG:32719', 'orbital_gn prepare')
    assert not (tmp_path / 'out').exists()  # nothing started, nothing written


def test_run_refuses_an_unreadable_gn(tmp_path: Path, bagfactory: ModuleType, globloc):
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))
    (tmp_path / 'bag' / 'gn.geojson').write_text('{"type": "FeatureCollection", "feat')
    args = _graph(tmp_path, FAKE_ENTRY)
    _one_error_line(globloc(['run', str(tmp_path / 'bag'), *args]),
                    f'GN {tmp_path / "bag" / "gn.geojson"} cannot be used')
    assert not (tmp_path / 'out').exists()


def test_gn_of_another_area_is_a_warning(tmp_path: Path):
    from rover_bringup.gn_check import check_gn

    _orbital(tmp_path / 'orbital.tif', 'EPSG:32719')
    warnings: list[str] = []
    _gn(tmp_path / 'gn.geojson', 'EPSG:32719')
    check_gn(tmp_path, warnings.append)
    assert warnings == []  # the GN lies on the image
    _gn(tmp_path / 'gn.geojson', 'EPSG:32719', offset_m=5000.0)  # 5 km east of it
    check_gn(tmp_path, warnings.append)
    assert len(warnings) == 1 and '20 of 20 ROIs lie outside' in warnings[0]
    assert 'another area' in warnings[0]


def test_eval_refuses_a_gn_in_another_map_frame_than_the_truth(tmp_path: Path):
    from rover_bringup.errors import GloblocError
    from rover_bringup.gn_check import check_truth_frame

    (tmp_path / 'truth').mkdir()
    _gn(tmp_path / 'truth' / 'rois.geojson', 'EPSG:32719')
    _gn(tmp_path / 'gn.geojson', 'EPSG:32719')
    check_truth_frame(tmp_path)  # the same frame: nothing to say
    _gn(tmp_path / 'gn.geojson', 'EPSG:32619')
    with pytest.raises(GloblocError, match='different map frames'):
        check_truth_frame(tmp_path)

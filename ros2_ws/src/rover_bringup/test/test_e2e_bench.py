"""bench/e2e_bench.py on what exists today: the paper's end-of-route alignment on a run
made here, and the whole bench (run, eval, comparison, CPU, latency) on a graph of the real
matcher fed by a test LN source."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import yaml

HERE = Path(__file__).resolve().parent
BENCH = HERE.parents[3] / 'bench' / 'e2e_bench.py'


@pytest.fixture(scope='module')
def bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location('e2e_bench_under_test', BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _tum_rows(t, xy):
    return ''.join(f'{ti:.9f} {x:.6f} {y:.6f} 0 0 0 0 1\n' for ti, (x, y) in zip(t, xy,
                                                                                 strict=True))


def test_end_of_route_alignment_of_a_drifting_vo(tmp_path: Path, bench: ModuleType):
    from darces_matcher.gn_generator import generate_gn
    from roi_network.geojson import write_geojson
    from roi_network.records import xy
    from roi_network.transform import Rigid2D
    from rover_bringup.run_outputs import records_csv

    gn = generate_gn(seed=11)
    bag = tmp_path / 'bag'
    (bag / 'truth').mkdir(parents=True)
    write_geojson(gn, bag / 'gn.geojson')
    pts = xy(gn.records)
    start = pts[np.argmin(pts[:, 0])]
    truth_T = Rigid2D(0.8, *start)  # map_T_odom
    t = 100.0 + np.arange(0, 600.0)
    route = start + np.c_[t - t[0], np.zeros(len(t))]  # 600 m east at 1 m/s
    (bag / 'truth' / 'trajectory.tum').write_text(_tum_rows(t, route))
    run = tmp_path / 'run'
    run.mkdir()
    # VO with a 0.5 % scale drift: the one-fit alignment spreads it along the route.
    odom = truth_T.inverse().apply(route) * 1.005
    (run / 'vo.tum').write_text(_tum_rows(t, odom))
    dist = np.min(np.linalg.norm(pts[:, None] - route[None, ::20], axis=2), axis=1)
    ln = gn.records[np.argsort(dist)[:30]].copy()
    ln_odom = truth_T.inverse().apply(xy(ln))
    ln['x'], ln['y'] = ln_odom[:, 0], ln_odom[:, 1]
    (run / 'local_network.csv').write_text(records_csv(ln))

    result = bench.end_of_route_alignment(run, bag)
    assert result['status'] == 'fix', result
    # Exact LN: the fit is the true alignment; the error is the VO's own drift, 0.5 % of
    # the distance from the odom origin (3 m at the end of 600 m).
    assert result['final_error_m'] == pytest.approx(3.0, abs=0.2)
    assert result['rmse_m'] < result['final_error_m']

    (run / 'local_network.csv').unlink()
    assert bench.end_of_route_alignment(run, bag)['status'] == 'n/a'


@pytest.mark.ros
def test_bench_runs_and_compares_on_the_matcher_graph(
    tmp_path: Path, bench: ModuleType, bagfactory: ModuleType,
    fast_discovery_env: dict[str, str], monkeypatch,
):
    test_rel = importlib.util.spec_from_file_location('rel_for_bench',
                                                      HERE / 'test_reliability.py')
    rel = importlib.util.module_from_spec(test_rel)
    test_rel.loader.exec_module(rel)
    bag_dir = rel._matcher_graph(tmp_path, bagfactory, duration_s=5.0)
    # The bench's paper protocol reads the last LN from the run (local_network.csv).
    for k, v in fast_discovery_env.items():
        monkeypatch.setenv(k, v)
    results = tmp_path / 'results'
    code = bench.main([str(bag_dir), '--rate', '5', '--out', str(tmp_path / 'out'),
                       '--tag', 'test', '--graph', str(tmp_path / 'graph.yaml'),
                       '--params', str(tmp_path / 'params.yaml'), '--results', str(results)])
    assert code == 0
    report = json.loads((results / 'e2e_test.json').read_text())
    (entry,) = report['bags']
    assert entry['run_status'] == 0
    assert entry['nodes'] == {'ln_source': 'ran', 'darces_matcher': 'ran'}
    c = entry['continuous']
    assert c['localized'] and c['false_fixes'] == 0 and c['final_error_m'] < 1.0
    assert entry['end_of_route']['status'] == 'fix'
    assert entry['end_of_route']['final_error_m'] < 1.0
    assert entry['cpu_s']['darces_matcher'] > 0 and 'globloc_play' in entry['cpu_s']
    lat = entry['latency']
    # The recorder's receive time is its sim time: /clock ticks at most 100 times per wall
    # second, so it may read up to rate / 100 bag seconds behind the pose's stamp.
    assert lat['global_poses'] == c['global_poses']
    assert lat['latency_bag_s']['median'] >= -5.0 / 100.0
    md = (results / 'e2e_test.md').read_text()
    assert '| route | True |' in md
    run = yaml.safe_load((Path(entry['run_dir']) / 'run.yaml').read_text())
    assert run['outputs']['files']['local_network.csv'] == 24


def test_rois_passed_counts_by_the_closest_point_along_the_route(bench: ModuleType):
    route = np.c_[np.arange(0.0, 400.0, 0.5), np.zeros(800)]  # 400 m east
    rois = np.array([[50.0, 10.0], [150.0, -3.0], [199.0, 14.0], [250.0, 2.0],
                     [390.0, -5.0]])
    assert bench.rois_passed(route, rois, (100, 200, 300)) == {100: 1, 200: 3, 300: 4}
    # A route that turns back: a ROI is passed where the route comes closest to it.
    back = np.vstack([route, route[::-1] + np.array([0.0, 20.0])])  # back at 419.5 m
    assert bench.rois_passed(back, np.array([[100.0, 19.0]]), (200, 700, 720)) == {
        200: 0, 700: 0, 720: 1}
    assert bench.rois_passed(route, np.zeros((0, 2)), (100,)) == {100: 0}


def test_cpu_sampler_names_a_child_by_its_command_after_exec(bench: ModuleType):
    """A child sampled between its fork and its exec carries its parent's command line;
    once it runs its node, its CPU is the node's, not ``globloc run``'s."""
    run_cmd = ['python', '-m', 'rover_bringup.cli', 'run', 'bags/quick']

    class Times:
        def __init__(self, s: float) -> None:
            self.user, self.system = s, 0.0

    class Proc:
        def __init__(self, pid: int, cmdline: list[str]) -> None:
            self.pid, self.cmd, self.cpu = pid, cmdline, 1.0

        def oneshot(self):
            import contextlib
            return contextlib.nullcontext()

        def cpu_times(self) -> Times:
            return Times(self.cpu)

        def cmdline(self) -> list[str]:
            return self.cmd

    root, child = Proc(1, run_cmd), Proc(2, run_cmd)  # forked, not yet exec'd
    root.children = lambda recursive=True: [child]
    sampler = bench.CpuSampler(root)
    sampler._sample()
    assert sampler.per_name() == {'globloc_run': 2.0}
    child.cmd = ['ln_builder', '--ros-args', '-r', '__node:=ln_builder']  # exec'd
    child.cpu = 5.0
    sampler._sample()
    assert sampler.per_name() == {'globloc_run': 1.0, 'ln_builder': 5.0}
    child.cmd = []  # exited: its name stays
    sampler._sample()
    assert sampler.per_name() == {'globloc_run': 1.0, 'ln_builder': 5.0}


def test_a_tag_in_use_is_refused_before_anything_runs(tmp_path: Path, bench: ModuleType,
                                                      capsys: pytest.CaptureFixture):
    held = bench.claim_tag(tmp_path, 'busy')
    assert held is not None
    assert bench.claim_tag(tmp_path, 'busy') is None  # a second claim, as another run's
    assert bench.claim_tag(tmp_path, 'free') is not None
    bag = tmp_path / 'bag'
    bag.mkdir()
    assert bench.main([str(bag), '--tag', 'busy', '--results', str(tmp_path),
                       '--out', str(tmp_path / 'out')]) == 1
    assert 'another e2e_bench is running with --tag busy' in capsys.readouterr().err
    assert not (tmp_path / 'out').exists() and not (tmp_path / 'e2e_busy.md').exists()
    held.close()  # the run ends: the tag is free again
    assert bench.claim_tag(tmp_path, 'busy') is not None

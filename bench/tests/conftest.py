"""Shared fixtures of bench/tests/: a script of bench/ (not a package) imported under test."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

BENCH_DIR = Path(__file__).resolve().parents[1]


def load_bench(name: str) -> ModuleType:
    """The module ``bench/<name>.py``, registered as ``<name>_under_test``."""
    spec = importlib.util.spec_from_file_location(f"{name}_under_test", BENCH_DIR / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def bench_script():
    """:func:`load_bench`, as a fixture (bench/ is not on sys.path under importlib)."""
    return load_bench


def make_replay_run(tmp_path: Path) -> tuple[Path, Path]:
    """A run directory and its bag for bench/replay_matcher.py (and the scripts built on
    it): an outputs bag with a growing LN and the odometry of a straight 600 m drive past a
    generated GN (seed 11), the GN as the bag's gn.geojson, a truth trajectory."""
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from darces_matcher.gn_generator import generate_gn
    from roi_network.geojson import write_geojson
    from roi_network.pointcloud import to_pointcloud2
    from roi_network.records import xy
    from roi_network.transform import Rigid2D

    gn = generate_gn(seed=11)
    bag = tmp_path / "bag"
    (bag / "truth").mkdir(parents=True)
    write_geojson(gn, bag / "gn.geojson")
    pts = xy(gn.records)
    start = pts[np.argmin(pts[:, 0])]
    truth_T = Rigid2D(0.8, *start)  # map_T_odom
    t = 100.0 + np.arange(0.0, 600.0)
    route = start + np.c_[t - t[0], np.zeros(len(t))]  # 600 m east at 1 m/s
    (bag / "truth" / "trajectory.tum").write_text(
        "".join(f"{ti:.9f} {x:.6f} {y:.6f} 0 0 0 0 1\n" for ti, (x, y) in zip(t, route,
                                                                            strict=True)))
    odom = truth_T.inverse().apply(route)
    # ROIs within 25 m of the route join the LN when the rover passes them.
    d_route = np.min(np.linalg.norm(pts[:, None] - route[None, ::10], axis=2), axis=1)
    near = np.flatnonzero(d_route <= 25.0)
    seen_at = np.clip(pts[near, 0] - start[0], 0.0, 599.0)
    order = np.argsort(seen_at)
    near, seen_at = near[order], seen_at[order]
    rng = np.random.default_rng(1)
    ln_all = gn.records[near].copy()
    ln_xy = truth_T.inverse().apply(xy(ln_all)) + rng.normal(0.0, 0.2, (len(near), 2))
    ln_all["x"], ln_all["y"] = ln_xy[:, 0], ln_xy[:, 1]
    ln_all["cov_xx"] = ln_all["cov_yy"] = 0.5**2
    ln_all["id"] = np.arange(len(near))

    ts = get_typestore(Stores.ROS2_JAZZY)
    m = ts.types
    run = tmp_path / "run"
    run.mkdir()
    yaw_odom = -0.8
    quat = m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw_odom / 2)),
                                            w=float(np.cos(yaw_odom / 2)))
    cov = np.diag([0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4]).ravel()
    with Writer(run / "outputs", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        co = w.add_connection("/vo/odometry", "nav_msgs/msg/Odometry", typestore=ts)
        cl = w.add_connection("/local_network", "sensor_msgs/msg/PointCloud2", typestore=ts)
        sent = 0
        for k, (ti, (x, y)) in enumerate(zip(t, odom, strict=True)):
            stamp = m["builtin_interfaces/msg/Time"](sec=int(ti), nanosec=0)
            header = m["std_msgs/msg/Header"](stamp=stamp, frame_id="odom")
            pose = m["geometry_msgs/msg/Pose"](
                position=m["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quat)
            pwc = m["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov)
            vec = m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            twist = m["geometry_msgs/msg/TwistWithCovariance"](
                twist=m["geometry_msgs/msg/Twist"](linear=vec, angular=vec),
                covariance=np.zeros(36))
            msg = m["nav_msgs/msg/Odometry"](header=header, child_frame_id="base_link",
                                             pose=pwc, twist=twist)
            w.write(co, int(ti * 1e9), ts.serialize_cdr(msg, "nav_msgs/msg/Odometry"))
            n = int(np.searchsorted(seen_at, k, side="right"))
            if n > sent:
                sent = n
                cloud = to_pointcloud2(ln_all[:n], "odom")
                cloud.header.stamp.sec = int(ti)
                w.write(cl, int(ti * 1e9), serialize_message(cloud))
    return run, bag


@pytest.fixture(scope="session")
def replay_run():
    """:func:`make_replay_run`, as a fixture."""
    return make_replay_run

"""The gn_server node in its own process: publishes the GN once, latched; bad files exit 2."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from orbital_scene import scene
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from roi_network.geojson import write_geojson
from roi_network.pointcloud import from_pointcloud2

pytestmark = pytest.mark.ros

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def _exe() -> str:
    exe = shutil.which("gn_server")
    assert exe, "gn_server executable not on PATH (source env.sh)"
    return exe


def _run_bad(path, domain) -> subprocess.CompletedProcess:
    return subprocess.run([_exe(), "--ros-args", "-p", f"gn_path:={path}"], env=_env(domain),
                          capture_output=True, text=True, timeout=30)


def _one_line(result, *words):
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, result.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_missing_gn_file_exits_2_naming_it(tmp_path):
    missing = tmp_path / "missing.geojson"
    _one_line(_run_bad(missing, 70 + os.getpid() % 20), str(missing), "not found")


def test_malformed_gn_file_exits_2_naming_it(tmp_path):
    bad = tmp_path / "bad.geojson"
    bad.write_text('{"type": "FeatureCollection", "features": [')
    _one_line(_run_bad(bad, 71 + os.getpid() % 20), str(bad), "not valid JSON")
    nometa = tmp_path / "nometa.geojson"
    nometa.write_text('{"type": "FeatureCollection", "features": []}')
    _one_line(_run_bad(nometa, 72 + os.getpid() % 20), str(nometa), "metadata")


def test_publishes_global_network_latched(tmp_path):
    _, gn = scene(4, size=200, n_rocks=12, n_outcrops=2)
    gn.metadata["domain_check"] = {"status": "out_of_distribution", "reasons": [
        {"check": "gsd_m", "level": "out_of_distribution", "message": "ground sample "
         "distance 0.6 is 2.4 times above the training images' 0.25-0.25"}]}
    path = tmp_path / "gn.geojson"
    write_geojson(gn, path)
    domain = 73 + os.getpid() % 20
    proc = subprocess.Popen([_exe(), "--ros-args", "-p", f"gn_path:={path}"], env=_env(domain),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        time.sleep(1.0)  # subscribe late: transient local must still deliver
        node = rclpy.create_node("gn_server_test", context=ctx)
        executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        got: list[PointCloud2] = []
        status: list[DiagnosticArray] = []
        node.create_subscription(PointCloud2, "/global_network", got.append, LATCHED)
        node.create_subscription(DiagnosticArray, "/gn_server/status", status.append, LATCHED)
        end = time.monotonic() + 20
        while (not got or not status) and time.monotonic() < end and proc.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        assert got, f"no /global_network (node output: {proc.stdout and proc.poll()})"
        # The GN's domain check is passed on.
        assert status, "no /gn_server/status"
        values = {kv.key: kv.value for kv in status[0].status[0].values}
        assert values["domain_check"] == "out_of_distribution"
        assert "ground sample distance" in values["reason_0"]
        msg = got[0]
        assert msg.header.frame_id == "map"
        records = from_pointcloud2(msg)
        assert len(records) == len(gn)
        np.testing.assert_array_equal(records["id"], gn.records["id"])
        np.testing.assert_allclose(records["x"], gn.records["x"])
        # Published once: no second message.
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
        assert len(got) == 1
        assert proc.poll() is None, "gn_server died"
    finally:
        rclpy.shutdown(context=ctx)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=10)
    out = proc.stdout.read()
    assert "domain check out_of_distribution: ground sample distance" in out, out

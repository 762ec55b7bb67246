"""The darces_matcher node in its own process, driven by a test node over ROS 2."""

import os
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation

from darces_matcher.gn_generator import generate_gn
from darces_matcher.localization import Alignment, compose_pose
from roi_network.geojson import write_geojson
from roi_network.pointcloud import to_pointcloud2
from roi_network.records import xy
from roi_network.transform import Rigid2D

pytestmark = pytest.mark.ros

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
TRUTH = Rigid2D(0.8, 120.0, -40.0)  # map_T_odom the node must find


def _ros_env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


def _local_network(gn, n=24, seed=3):
    """An LN of the GN nodes nearest a 600 m route, in the odom frame of TRUTH."""
    rng = np.random.default_rng(seed)
    pts = xy(gn.records)
    start = pts[np.argmin(pts[:, 0])]
    route = start + np.linspace(0, 1, 50)[:, None] * np.array([600.0, 0.0])
    dist = np.min(np.linalg.norm(pts[:, None] - route[None], axis=2), axis=1)
    ln = gn.records[np.argsort(dist)[:n]].copy()
    odom = TRUTH.inverse().apply(xy(ln)) + rng.normal(0, 0.2, (n, 2))
    ln["x"], ln["y"] = odom[:, 0], odom[:, 1]
    ln["cov_xx"] = ln["cov_yy"] = 0.5**2
    return ln


def _odometry(x, y, yaw, stamp_s):
    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.header.stamp.sec = stamp_s
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    q = Rotation.from_euler("z", yaw).as_quat()
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    msg.pose.covariance = list(np.diag([0.1, 0.1, 0.1, 0.01, 0.01, 0.02]).ravel())
    return msg


def _plane_height(x):
    """The synthetic DTM's ground: a plane rising 0.1 m per metre east, 12 m at map 0."""
    return 0.1 * np.asarray(x) + 12.0


def _write_plane_dtm(path, gn, crs=None) -> None:
    """A DTM of :func:`_plane_height` over map [-500, 2500] x [-500, 1500] at 5 m posts,
    in the GN's CRS (or ``crs``), stating a 0.3 m vertical sigma."""
    from roi_network.dtm import write_dtm

    x = -500.0 + 5.0 * (np.arange(600) + 0.5)
    y = 1500.0 - 5.0 * (np.arange(400) + 0.5)
    ox, oy = gn.map_frame.origin
    write_dtm(path, np.tile(_plane_height(x), (len(y), 1)), crs or gn.map_frame.crs,
              west=ox - 500.0, north=oy + 1500.0, posting=5.0, vertical_sigma_m=0.3,
              datum="test plane")


@pytest.fixture(params=[False], ids=["no_dtm"])
def matcher_process(request, tmp_path):
    gn = generate_gn(seed=11)
    # A GN orbital_gn prepare judged doubtful: the matcher passes the verdict on.
    gn.metadata["domain_check"] = {"status": "warn", "reasons": [
        {"level": "warn", "message": "weighted entropy 0.9 bits is 1.6 times below the "
         "training images' 1.43-1.45"}]}
    gn_path = tmp_path / "gn.geojson"
    write_geojson(gn, gn_path)
    args = ["-p", f"gn_path:={gn_path}"]
    if request.param:
        _write_plane_dtm(tmp_path / "dtm.tif", gn)
        args += ["-p", f"dtm_path:={tmp_path / 'dtm.tif'}"]
    domain = 60 + os.getpid() % 40
    exe = shutil.which("darces_matcher")
    assert exe, "darces_matcher executable not on PATH (source env.sh)"
    proc = subprocess.Popen([exe, "--ros-args", *args],
                            env=_ros_env(domain), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    yield gn, domain, proc
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)


class _Driver:
    """The test's side of the matcher node: publishers of its inputs, subscribers of its
    outputs (``got``), on its own context in the node's domain."""

    def __init__(self, gn, domain: int, proc: subprocess.Popen) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.proc = proc
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("matcher_test_driver", context=self.ctx)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.got: dict[str, list] = {"alignment": [], "pose": [], "status": []}
        self.node.create_subscription(TransformStamped, "/global_alignment",
                                      self.got["alignment"].append, LATCHED)
        self.node.create_subscription(PoseWithCovarianceStamped, "/global_pose",
                                      self.got["pose"].append, 10)
        self.status_sub = self.node.create_subscription(DiagnosticArray, "/matcher/status",
                                                        self.got["status"].append, 10)
        self.ln_pub = self.node.create_publisher(type(to_pointcloud2(gn.records[:0], "odom")),
                                                 "/local_network", LATCHED)
        self.odom_pub = self.node.create_publisher(Odometry, "/vo/odometry", 10)

    def spin_until(self, cond, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not cond() and time.monotonic() < end and self.proc.poll() is None:
            self.executor.spin_once(timeout_sec=0.05)
        return cond()

    def close(self) -> None:
        # The node goes before the context: a latched LN left alive would reach the next
        # test's matcher (same domain).
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.mark.parametrize("matcher_process", [False, True], ids=["no_dtm", "dtm"],
                         indirect=True)
def test_node_publishes_alignment_and_global_pose(matcher_process, request):
    """Once the LN is fixed every odometry message gives a /global_pose in map. Its z:
    with a DTM the ground's height under the published x, y with the DTM's variance
    (0.3 m sigma plus the slope term); without, not estimated (variance 1e6 m^2), though
    the odometry claims 0.1 m^2."""
    with_dtm = "[dtm]" in request.node.name
    gn, domain, proc = matcher_process
    drv = _Driver(gn, domain, proc)
    got, ln_pub, odom_pub, spin_until = drv.got, drv.ln_pub, drv.odom_pub, drv.spin_until
    try:
        # Before any LN: odometry gives no global pose.
        assert spin_until(lambda: odom_pub.get_subscription_count() > 0, 15), proc.stdout
        odom_pub.publish(_odometry(0.0, 0.0, 0.0, 1))
        spin_until(lambda: False, 0.5)
        assert got["pose"] == []

        ln_pub.publish(to_pointcloud2(_local_network(gn), "odom", stamp=2_000_000_000))
        assert spin_until(lambda: got["alignment"], 20), "no /global_alignment"
        a = got["alignment"][-1]
        assert (a.header.frame_id, a.child_frame_id) == ("map", "odom")
        yaw = 2 * np.arctan2(a.transform.rotation.z, a.transform.rotation.w)
        assert abs(np.angle(np.exp(1j * (yaw - TRUTH.yaw)))) < np.radians(0.5)
        assert np.hypot(a.transform.translation.x - TRUTH.tx,
                        a.transform.translation.y - TRUTH.ty) < 1.0

        poses = [(10.0, 5.0, 0.3), (25.0, -4.0, -0.2), (40.0, 2.0, 1.0)]
        for k, (x, y, th) in enumerate(poses):
            odom_pub.publish(_odometry(x, y, th, 3 + k))
        # The node subscribes before it builds its index, so the odometry sent before the
        # LN may be taken after the fix, and published too: judge the poses after the LN.
        def after_ln():
            return [m for m in got["pose"] if m.header.stamp.sec >= 3]

        assert spin_until(lambda: len(after_ln()) == len(poses), 10)
        for msg, (x, y, th) in zip(after_ln(), poses, strict=True):
            assert msg.header.frame_id == "map"
            expected = TRUTH.apply([x, y])
            p = msg.pose.pose.position
            assert np.hypot(p.x - expected[0], p.y - expected[1]) < 1.0
            q = msg.pose.pose.orientation
            got_yaw = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_euler("xyz")[2]
            assert abs(np.angle(np.exp(1j * (got_yaw - th - TRUTH.yaw)))) < np.radians(0.5)
            cov = np.array(msg.pose.covariance).reshape(6, 6)
            assert cov[0, 0] > 0.1 and np.allclose(cov, cov.T)
            if with_dtm:
                assert p.z == pytest.approx(_plane_height(p.x), abs=1e-4)
                slope_var = 0.1**2 * cov[0, 0]
                assert cov[2, 2] == pytest.approx(0.3**2 + slope_var, rel=1e-6)
            else:
                assert cov[2, 2] == 1e6 and np.count_nonzero(cov[2]) == 1
        assert proc.poll() is None, "matcher node died"
    finally:
        drv.close()


def test_bad_gn_file_is_a_one_line_error(tmp_path):
    missing = tmp_path / "missing.geojson"
    result = subprocess.run(
        [shutil.which("darces_matcher"), "--ros-args", "-p", f"gn_path:={missing}"],
        env=_ros_env(61 + os.getpid() % 40), capture_output=True, text=True, timeout=30)
    assert result.returncode == 1
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(missing) in lines[0], result.stderr


def test_dtm_in_another_crs_is_a_one_line_error(tmp_path):
    gn = generate_gn(seed=11)
    gn_path, dtm_path = tmp_path / "gn.geojson", tmp_path / "dtm.tif"
    write_geojson(gn, gn_path)
    _write_plane_dtm(dtm_path, gn, crs="EPSG:32633")
    result = subprocess.run(
        [shutil.which("darces_matcher"), "--ros-args", "-p", f"gn_path:={gn_path}",
         "-p", f"dtm_path:={dtm_path}"],
        env=_ros_env(62 + os.getpid() % 40), capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(dtm_path) in lines[0] and "EPSG:32719" in lines[0], \
        result.stderr


def test_compose_pose_propagates_alignment_uncertainty():
    align = Alignment(Rigid2D(np.pi / 2, 5.0, 0.0), np.diag([0.0, 0.0, 1e-4]), 10, 10)
    q0 = Rotation.from_euler("z", 0.1).as_quat()
    pos, quat, cov = compose_pose(align, np.array([100.0, 0.0, 1.0]), q0, np.zeros(36))
    np.testing.assert_allclose(pos, [5.0, 100.0, 1.0], atol=1e-9)
    assert Rotation.from_quat(quat).as_euler("xyz")[2] == pytest.approx(np.pi / 2 + 0.1)
    # 1e-4 rad^2 yaw variance at 100 m lever arm: 1 m^2 across the lever (map x here).
    assert cov[0, 0] == pytest.approx(1.0) and cov[1, 1] == pytest.approx(0.0, abs=1e-12)
    assert cov[5, 5] == pytest.approx(1e-4)


def test_gn_of_another_area_stays_unlocalized_and_says_so(matcher_process):
    """The rover drives where the GN is not (another area's constellation): the LN grows,
    no pose and no alignment are published, and /matcher/status says 'not localized'."""
    from diagnostic_msgs.msg import DiagnosticStatus

    gn, domain, proc = matcher_process
    elsewhere = generate_gn(seed=12)
    drv = _Driver(gn, domain, proc)
    got, ln_pub, odom_pub, spin_until = drv.got, drv.ln_pub, drv.odom_pub, drv.spin_until
    try:
        assert spin_until(lambda: odom_pub.get_subscription_count() > 0
                          and ln_pub.get_subscription_count() > 0
                          and drv.status_sub.get_publisher_count() > 0, 15), proc.stdout
        spin_until(lambda: False, 1.0)  # /matcher/status is volatile: be matched first
        ln = _local_network(elsewhere, n=24)
        for k, n in enumerate((8, 16, 24)):
            ln_pub.publish(to_pointcloud2(ln[:n], "odom", stamp=(2 + k) * 1_000_000_000))
            odom_pub.publish(_odometry(10.0 * k, 0.0, 0.0, 2 + k))
            assert spin_until(lambda n=n: any(
                kv.key == "ln_size" and kv.value == str(n)
                for m in got["status"] for kv in m.status[0].values), 20), n
        spin_until(lambda: False, 1.0)
        assert got["pose"] == [] and got["alignment"] == []
        last = got["status"][-1].status[0]
        values = {kv.key: kv.value for kv in last.values}
        assert last.level == DiagnosticStatus.WARN
        assert last.message.startswith("not localized") and values["state"] == "searching"
        assert last.message.endswith("; GN domain check warn")
        assert values["gn_domain_check"] == "warn"
        assert proc.poll() is None, "matcher node died"
    finally:
        drv.close()

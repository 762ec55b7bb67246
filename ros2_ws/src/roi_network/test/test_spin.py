"""spin_until_shutdown: a busy node stops promptly and cleanly on SIGTERM, every time."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time

import pytest

pytestmark = pytest.mark.ros

# A node that publishes to itself at 500 Hz, so that SIGTERMs land in every phase of the
# executor loop (callbacks, wait-set building, waiting): the race rclpy.spin loses.
NODE = textwrap.dedent('''
    import sys
    import rclpy
    from std_msgs.msg import String
    from roi_network.spin import spin_until_shutdown

    rclpy.init()
    node = rclpy.create_node('spin_probe')
    pub = node.create_publisher(String, 'spin_probe', 10)
    got = []
    node.create_subscription(String, 'spin_probe', got.append, 10)
    node.create_timer(0.002, lambda: pub.publish(String(data='x')))
    print('spinning', flush=True)
    spin_until_shutdown(node)
    node.destroy_node()
    rclpy.try_shutdown()
    print(f'stopped after {len(got)} messages', flush=True)
''')


def test_sigterm_stops_a_busy_node_within_a_second():
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 50),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    rng = random.Random(7)
    procs = [subprocess.Popen([sys.executable, '-c', NODE], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(8)]
    try:
        for proc in procs:
            assert proc.stdout.readline().strip() == 'spinning', proc.stderr.read()
        for proc in procs:
            time.sleep(rng.uniform(0.05, 0.4))
            proc.send_signal(signal.SIGTERM)
            start = time.monotonic()
            out, err = proc.communicate(timeout=10)
            assert time.monotonic() - start < 3.0
            assert proc.returncode == 0, err
            assert out.startswith('stopped after '), (out, err)
            assert 'Traceback' not in err
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


RUN_NODE = textwrap.dedent('''
    import sys
    from roi_network.spin import run_node

    def bad_node():
        raise ValueError("/nowhere/gn.geojson: GN file not found")

    sys.exit(run_node(bad_node, "probe_node", error_status=int(sys.argv[1])))
''')


@pytest.mark.parametrize("status", [1, 2])
def test_run_node_reports_a_node_that_cannot_start_in_one_line(status):
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 50),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    done = subprocess.run([sys.executable, "-c", RUN_NODE, str(status)], env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == status
    assert done.stderr.strip().splitlines()[-1] == (
        "probe_node: error: /nowhere/gn.geojson: GN file not found")
    assert "Traceback" not in done.stderr


DESTROY_PROBE = textwrap.dedent('''
    import sys
    from rclpy.node import Node
    from std_msgs.msg import String
    from roi_network.spin import run_node

    class Probe(Node):
        def __init__(self):
            super().__init__("destroy_probe")
            self.create_subscription(String, "destroy_probe", lambda msg: None, 10)
            self.create_timer(0.05, lambda: None)
            print("spinning", flush=True)

        def destroy_node(self):
            print(f"context ok at destroy: {self.context.ok()}", flush=True)
            super().destroy_node()

    sys.exit(run_node(Probe, "destroy_probe"))
''')


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_run_node_destroys_the_node_before_the_context_on_a_signal(sig):
    # rclpy's own handlers shut the context down from the signal, and the node's entities
    # were then destroyed on a dead context: rover_vo crashed so (SIGSEGV) in one CI run.
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 50),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-c", DESTROY_PROBE], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "spinning", proc.stderr.read()
        time.sleep(0.3)
        proc.send_signal(sig)
        start = time.monotonic()
        out, err = proc.communicate(timeout=10)
        assert time.monotonic() - start < 3.0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert out.strip() == "context ok at destroy: True", (out, err)
    assert "Traceback" not in err

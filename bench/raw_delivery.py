"""Raw stereo images through `globloc play` into a subscriber in another process, with the
player's Fast DDS profile (rover_bringup/config/fastdds_player.xml) and without it.

A field bag's stereo pairs are often raw ``sensor_msgs/Image`` (640x480 rgb8: 922 KB), where
the simulator records the contract's compressed ones (~60 KB). Fast DDS's default
shared-memory segment (512 KB) holds no such image: they go over UDP fragments, and
best-effort ones are lost. This counts what arrives.

    python bench/raw_delivery.py [--bag RAW_BAG] [--trials 3] [--rates 2 5]

Without ``--bag`` it generates the ``tiny`` preset (seed 7) and its raw-image copy
(``roi_network.testing.write_raw_image_copy``) under ``out/bench/raw_delivery/``. Writes
``bench/results/raw_delivery.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
TOPICS = ("/stereo/left/image_raw", "/stereo/right/image_raw")
# A profile that changes no transport: the player on Fast DDS's defaults.
NO_TRANSPORT_PROFILE = ROOT / "ros2_ws/src/rover_bringup/test/fastdds_fast_discovery.xml"


def raw_bag(work: Path) -> Path:
    """The tiny preset (seed 7) with raw images, generated once."""
    from atacama_sim.config import make_config
    from atacama_sim.generate import generate
    from roi_network.testing import write_raw_image_copy

    raw = work / "tiny_raw"
    if not (raw / "rosbag").is_dir():
        shutil.rmtree(work, ignore_errors=True)
        generate(make_config("tiny", 7), work / "tiny", progress=False)
        write_raw_image_copy(work / "tiny", raw)
    return raw


def count_delivery(bag: Path, rate: float, profile: bool, domain: int) -> dict:
    """Play the raw image topics once; the images a best-effort subscriber received."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    if not profile:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(NO_TRANSPORT_PROFILE)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = rclpy.create_node("raw_delivery", context=ctx)
        ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        got = dict.fromkeys(TOPICS, 0)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic in TOPICS:
            node.create_subscription(
                Image, topic, lambda _m, t=topic: got.__setitem__(t, got[t] + 1), qos)
        player = subprocess.Popen([shutil.which("globloc"), "play", str(bag), "--rate",
                                   str(rate), "--wait-subscribers", "20", "--topics", *TOPICS],
                                  env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True)
        while player.poll() is None:
            ex.spin_once(timeout_sec=0.05)
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        if player.returncode != 0:
            raise RuntimeError(f"globloc play failed: {player.stderr.read()}")
        return dict(got)
    finally:
        rclpy.try_shutdown(context=ctx)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, help="a bag directory with raw stereo images")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--rates", type=float, nargs="+", default=[2.0, 5.0])
    ap.add_argument("--name", default="raw_delivery")
    args = ap.parse_args()
    bag = args.bag or raw_bag(ROOT / "out" / "bench" / "raw_delivery")
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([bag / "rosbag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        sent = {c.topic: c.msgcount for c in r.connections if c.topic in TOPICS}
    if set(sent) != set(TOPICS):
        raise SystemExit(f"{bag}: no raw stereo pair ({', '.join(TOPICS)})")
    rows = []
    for rate in args.rates:
        for profile in (False, True):
            for trial in range(args.trials):
                got = count_delivery(bag, rate, profile, 70 + trial)
                rows.append({"rate": rate, "player_profile": profile, "trial": trial,
                             "sent": sent, "received": got})
                print(f"rate {rate:g}, profile {profile}, trial {trial}: {got}", flush=True)
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.name}.json").write_text(json.dumps(
        {"bag": str(bag), "made": stamp, "machine": platform.machine(), "load": load,
         "rows": rows}, indent=1))
    lines = [f"# Raw stereo images through `globloc play` ({args.name})", "",
             f"Made by `python bench/raw_delivery.py{' --bag ' + str(bag) if args.bag else ''}"
             f" --trials {args.trials} --rates {' '.join(f'{r:g}' for r in args.rates)}` on "
             f"{stamp} ({platform.machine()}, {os.cpu_count()} cores, load average {load}). "
             f"Bag: `{bag}`, {sent[TOPICS[0]]} stereo pairs of raw `sensor_msgs/Image` "
             "(640x480 rgb8, 922 KB each), played into a best-effort subscriber (depth 10) "
             "in another process.", "",
             "| rate | player's Fast DDS profile | left images received (per trial) | "
             "right images received |", "|---|---|---|---|"]
    for rate in args.rates:
        for profile in (False, True):
            sel = [r for r in rows if r["rate"] == rate and r["player_profile"] == profile]
            lines.append(
                f"| {rate:g}x | {'yes (32 MB shared memory)' if profile else 'no (defaults)'} | "
                + ", ".join(f"{r['received'][TOPICS[0]]}/{sent[TOPICS[0]]}" for r in sel)
                + " | "
                + ", ".join(f"{r['received'][TOPICS[1]]}/{sent[TOPICS[1]]}" for r in sel)
                + " |")
    (RESULTS / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

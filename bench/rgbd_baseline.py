"""A second third-party odometry for bench/vo_bench.py: OpenCV contrib's dense RGB-D
odometry (``cv2.rgbd.RgbdOdometry``, Steinbruecker et al. 2011: photometric alignment of
the left image with depth) on the stereo pairs of a bag, depth from SGBM.

It needs ``opencv-contrib-python-headless`` (pinned below), whose ``cv2`` would shadow the
project's ``opencv-python-headless``: it is installed into its own folder and this script
runs in its own process with that folder first on ``PYTHONPATH`` (vo_bench.py does both).

    python bench/rgbd_baseline.py BAG_DIR OUT_DIR      # OUT_DIR/vo.tum, OUT_DIR/vo_report.json
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CONTRIB = "opencv-contrib-python-headless==4.14.0.94"
SITE = Path(__file__).resolve().parents[1] / ".cache" / "opencv-contrib"


def ensure_contrib() -> Path:
    """The folder holding the pinned contrib wheel, installed there if missing."""
    if not (SITE / "cv2").is_dir():
        cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target",
               str(SITE), CONTRIB]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-1500:]}")
    return SITE


def stereo_pairs(bag: Path):
    """``(t_ns, left, right, rig)`` for each complete stereo pair of the bag, in order."""
    from rover_vo.bag import read_messages, rover_params
    from rover_vo.messages import (
        TOPIC_LEFT_INFO,
        TOPIC_RIGHT_INFO,
        decode_image,
        side_of,
        stamp_ns,
    )
    from rover_vo.rig import rig_from_camera_info

    params = rover_params(bag)
    infos: dict[str, object] = {}
    pending: dict[int, dict] = {}
    rig = None
    for topic, msg in read_messages(bag):
        if topic in (TOPIC_LEFT_INFO, TOPIC_RIGHT_INFO):
            infos[topic] = msg
            continue
        if side_of(topic) is None:
            continue
        pair = pending.setdefault(stamp_ns(msg), {})
        pair[side_of(topic)] = msg
        if len(pair) < 2 or len(infos) < 2:
            continue
        t_ns = stamp_ns(msg)
        del pending[t_ns]
        if rig is None:
            rig = rig_from_camera_info(infos[TOPIC_LEFT_INFO], infos[TOPIC_RIGHT_INFO], params)
        left, right = decode_image(pair["left"]), decode_image(pair["right"])
        if left is not None and right is not None:
            yield t_ns, left, right, rig


def rgbd_odometry(bag: Path, out: Path, max_depth_m: float = 20.0, max_depth_diff_m: float = 2.0,
                  levels: int = 4, method: str = "rgbd") -> dict:
    import cv2

    from roi_network.files import write_atomic
    from rover_vo.state import OdomState
    from rover_vo.tum import write_tum

    if not hasattr(cv2, "rgbd"):
        raise RuntimeError(f"cv2 from {cv2.__file__} has no rgbd module (needs {CONTRIB})")
    cv2.setNumThreads(1)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=48, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 speckleWindowSize=50, speckleRange=2)
    odom = None
    prev = None
    T_odom_cam = None
    base_T_cam = None
    velocity = np.eye(4)  # the last motion, the next one's initial guess
    states, lost, cpu = [], 0, 0.0
    for t_ns, left, right, rig in stereo_pairs(bag):
        c0 = time.process_time()
        small_l, small_r = cv2.pyrDown(left), cv2.pyrDown(right)
        disp = sgbm.compute(small_l, small_r).astype(np.float32) / 16.0
        depth = np.zeros_like(disp)
        ok = disp > 1.0
        depth[ok] = (rig.fx / 2.0) * rig.baseline_m / disp[ok]
        depth[depth > max_depth_m] = 0.0
        mask = (depth > 0).astype(np.uint8)
        if odom is None:
            K = np.array([[rig.fx / 2, 0, (rig.cx - 0.5) / 2], [0, rig.fy / 2, (rig.cy - 0.5) / 2],
                          [0, 0, 1]], dtype=np.float64)
            iters = np.array([7] * (levels - 1) + [10], np.int32)
            if method == "rgbd":
                odom = cv2.rgbd.RgbdOdometry_create(K, 0.5, max_depth_m, max_depth_diff_m, iters)
            else:  # photometric + point-to-plane ICP
                odom = cv2.rgbd.RgbdICPOdometry_create(K, 0.5, max_depth_m, max_depth_diff_m,
                                                       0.25, iters)
            base_T_cam = np.asarray(rig.base_T_left, dtype=float)
            T_odom_cam = base_T_cam.copy()  # odom = base_link at the first pair
        else:
            found, Rt = odom.compute(prev[0], prev[1], prev[2], small_l, depth, mask,
                                     initRt=np.linalg.inv(velocity))
            if found:
                motion = np.linalg.inv(Rt)  # dst_p = Rt src_p: the camera moved by inv(Rt)
                velocity = motion
            else:
                lost += 1
                motion = velocity  # constant velocity through a failure
            T_odom_cam = T_odom_cam @ motion
        prev = (small_l, depth, mask)
        cpu += time.process_time() - c0
        T = T_odom_cam @ np.linalg.inv(base_T_cam)
        states.append(OdomState(t_ns * 1e-9, T[:3, :3].copy(), T[:3, 3].copy()))
    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / "vo.tum", states,
              header=f"OpenCV {cv2.__version__} rgbd.RgbdOdometry on SGBM depth of {bag}")
    report = {"pairs": len(states), "lost": lost, "cpu_s": round(cpu, 2),
              "pairs_per_cpu_s": round(len(states) / max(cpu, 1e-9), 3)}
    write_atomic(out / "vo_report.json", json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    extra = json.loads(sys.argv[3]) if len(sys.argv) > 3 else {}
    print(json.dumps(rgbd_odometry(Path(sys.argv[1]), Path(sys.argv[2]), **extra)))

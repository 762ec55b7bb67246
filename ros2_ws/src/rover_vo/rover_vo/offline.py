"""Offline odometry on a bag directory: the estimator over the bag's messages in bag order
(read with rosbags, no ROS graph), its outputs written as files, and the figures of the
run (speed, memory, where each pose came from). It never reads ``truth/``.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from roi_network.files import write_atomic
from roi_network.mast import MastError
from roi_network.trajectory import POSE_COVARIANCE_FILE, write_pose_covariance
from rover_vo.bag import BagError, read_messages, rover_params
from rover_vo.config import VoConfig, flat_parameters
from rover_vo.estimator import VoEstimator
from rover_vo.sun_heading import SunSetupError
from rover_vo.tum import write_tum

#: Files :func:`odometry` writes into its output directory.
TUM_FILE = "vo.tum"
REPORT_FILE = "vo_report.json"


def peak_rss_mb() -> float:
    """Peak resident set size of this process (MB): ``VmHWM`` of ``/proc/self/status``.

    Not ``getrusage``'s ``ru_maxrss``: Linux carries that across ``fork`` and ``execve``,
    so a process started by a big parent (the bench) reports the parent's peak.
    ``ru_maxrss`` is the fallback where ``/proc`` is missing.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


#: ``--progress`` prints a line every this many pairs or this much bag time, whichever
#: comes first, and a final line.
PROGRESS_PAIRS = 100
PROGRESS_BAG_S = 10.0


class Progress:
    """``--progress`` lines on stderr: pairs, bag time since the first pose, distance."""

    def __init__(self, est: VoEstimator) -> None:
        self.est = est
        self.pairs = 0
        self.t0: float | None = None
        self.last_t: float | None = None

    def _line(self, outputs: list, prefix: str = "") -> str:
        est = self.est
        span = outputs[-1].state.t - outputs[0].state.t if outputs else 0.0
        dist = est.state.distance_m if est.state is not None else 0.0
        bad = sum(est.counts.bad.values())
        return (f"  {prefix}{len(outputs)} poses, {span:.1f} s of bag, {dist:.1f} m"
                + (f", {bad} bad inputs" if bad else ""))

    def update(self, outputs: list) -> None:
        """A line when 100 poses or 10 s of bag time passed since the last one."""
        if not outputs or len(outputs) == self.pairs:
            return
        t = outputs[-1].state.t
        if self.last_t is None:
            self.last_t = outputs[0].state.t
        if len(outputs) - self.pairs >= PROGRESS_PAIRS or t - self.last_t >= PROGRESS_BAG_S:
            print(self._line(outputs), file=sys.stderr)
            self.pairs, self.last_t = len(outputs), t

    def final(self, outputs: list) -> None:
        """The end of the bag."""
        print(self._line(outputs, "done: "), file=sys.stderr)


def run_odometry(bag_dir: str | Path, config: VoConfig, progress: bool = False) -> dict:
    """Run the estimator over a bag; returns the outputs and figures for the report.

    Returns:
        ``{"outputs": [VoOutput], "status": {...}, "seconds": float, "cpu_seconds": float,
        "estimator_cpu_seconds": float, "rss_mb": [(pair index, MB)], "config": {...},
        "mast": bool, "bad_input": one line of the bad input (counts, the first of each)}``.

    Raises:
        BagError: the bag cannot be read, its rover.yaml's mast or sun sensor is
            malformed, or a
            ``/joint_states`` message does not fit the mast (the message names the field).
    """
    import psutil

    params = rover_params(bag_dir)
    try:
        est = VoEstimator(config, params, raise_joint_state_errors=True)
    except (MastError, SunSetupError) as exc:
        raise BagError(f"{Path(bag_dir) / 'rover.yaml'}: {exc}") from None
    outputs = []
    proc = psutil.Process()
    rss = []
    t0, c0 = time.perf_counter(), time.process_time()
    feed_cpu = 0.0
    said = Progress(est) if progress else None
    for topic, msg in read_messages(bag_dir):
        c = time.process_time()
        try:
            new = est.feed(topic, msg)
        except MastError as exc:
            raise BagError(f"{Path(bag_dir) / 'rosbag'}: {exc}") from None
        feed_cpu += time.process_time() - c
        outputs += new
        if new and len(outputs) % 100 == 0:
            rss.append((len(outputs), proc.memory_info().rss / 2**20))
        if said is not None:
            said.update(outputs)
    outputs += est.finish()
    if said is not None:
        said.final(outputs)
    return {"outputs": outputs, "status": est.status(), "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0, "estimator_cpu_seconds": feed_cpu,
            "rss_mb": rss, "config": flat_parameters(est.cfg), "mast": est.has_mast,
            "bad_input": est.bad_input_summary()}


def odometry(bag_dir: str | Path, config: VoConfig, out: str | Path,
             progress: bool = False) -> dict[str, Any]:
    """Run the estimator over a bag and write ``out/vo.tum`` (TUM: ``t x y z qx qy qz qw``,
    base_link in odom), ``out/vo_covariance.txt`` (each pose's 6x6 covariance) and
    ``out/vo_report.json``; returns the report.

    Raises:
        BagError: the bag cannot be read, or no stereo pair gave a pose.
    """
    bag = Path(bag_dir)
    result = run_odometry(bag, config, progress=progress)
    outputs = result["outputs"]
    if not outputs:
        est_status = result["status"]
        why = result["bad_input"] or "no bad input counted"
        raise BagError(f"{bag}: no stereo pair gave a pose ({est_status['pairs']} pairs "
                       f"read): {why}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / TUM_FILE, [o.state for o in outputs],
              header=f"rover_vo {config.mode}: base_link in odom, from {bag}")
    write_pose_covariance(out / POSE_COVARIANCE_FILE, [o.state.t for o in outputs],
                          [o.state.cov for o in outputs], note=f"rover_vo {config.mode}")
    sources: dict[str, int] = {}
    for o in outputs:
        sources[o.source] = sources.get(o.source, 0) + 1
    final = outputs[-1].state
    rss = [r for _, r in result["rss_mb"]]
    report = {
        "bag": str(bag), "mode": config.mode, "pairs": len(outputs),
        "distance_m": round(final.distance_m, 3),
        "wall_s": round(result["seconds"], 3), "cpu_s": round(result["cpu_seconds"], 3),
        "pairs_per_cpu_s": round(len(outputs) / max(result["cpu_seconds"], 1e-9), 3),
        "estimator_cpu_s": round(result["estimator_cpu_seconds"], 3),
        "estimator_pairs_per_cpu_s": round(
            len(outputs) / max(result["estimator_cpu_seconds"], 1e-9), 3),
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "rss_mb_first_last": [round(rss[0], 1), round(rss[-1], 1)] if rss else None,
        "sources": sources, "mast": result["mast"], "status": result["status"],
        "final_position_sigma_m": round(float(np.sqrt(np.trace(final.cov[:2, :2]))), 4),
        "final_yaw_sigma_deg": round(float(np.degrees(np.sqrt(final.cov[5, 5]))), 4),
        "threads": {"OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
                    "opencv": _cv_threads()},
        "config": result["config"],
    }
    write_atomic(out / REPORT_FILE, json.dumps(report, indent=2) + "\n")
    return report


def _cv_threads() -> int:
    import cv2

    return int(cv2.getNumThreads())

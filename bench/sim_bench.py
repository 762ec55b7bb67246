"""Benchmark of the atacama_sim bag generator.

Generates one preset in this process and records: generation time (total, per stereo
frame, per phase), peak resident memory, bag size, ROI counts, route statistics and ORB
features per left frame (OpenCV ORB, nfeatures=3000, every 10th frame).

    source env.sh
    python bench/sim_bench.py --preset atacama_1km --seed 1 --out bags/atacama_1km

Writes RESULTS/sim_results.json (one entry per preset and seed, updated in place) and
RESULTS/sim_results.md (a table of every entry), and prints the entry; RESULTS is
$BENCH_RESULTS, else out/bench/results/.
``--md-only`` rewrites the markdown from the JSON without generating anything.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import threading
import time
from pathlib import Path

import cv2
import numpy as np

#: Where result files go: $BENCH_RESULTS, else out/bench/results/.
RESULTS = Path(os.environ.get("BENCH_RESULTS")
               or Path(__file__).resolve().parents[1] / "out" / "bench" / "results")


def dir_size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def orb_counts(bag: Path, every: int = 10) -> list[int]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    orb = cv2.ORB_create(nfeatures=3000)
    counts = []
    with AnyReader([bag / "rosbag"],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections
                 if c.topic == "/stereo/left/image_raw/compressed"]
        for i, (conn, _t, raw) in enumerate(reader.messages(connections=conns)):
            if i % every:
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            img = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE)
            counts.append(len(orb.detect(img, None)))
    return counts


def write_markdown(results: dict, path: Path) -> None:
    """A table of the recorded results, for people."""
    lines = ["# atacama_sim generation benchmark", "",
             "Produced by `python bench/sim_bench.py --preset <preset> --seed 1` "
             "(see the script); raw figures in `sim_results.json`. The machine has 2 cores "
             "shared with other jobs, so wall times are upper bounds; CPU time is the sum "
             "over the generator's threads (llvmpipe renders on 2 threads) and its "
             "image-developing worker process.", "",
             "| figure | " + " | ".join(results) + " |",
             "|---|" + "---|" * len(results)]

    def row(name: str, get) -> None:
        lines.append(f"| {name} | " + " | ".join(str(get(e)) for e in results.values()) + " |")

    row("total wall time (s)", lambda e: e["total_s"])
    row("total CPU time (s)", lambda e: e["cpu_s"])
    row("CPU time generator / developing worker (s)",
        lambda e: " / ".join(map(str, e.get("cpu_s_main_worker", ["-", "-"]))))
    row("wall time per stereo frame, all included (s)", lambda e: e["s_per_stereo_frame"])
    row("render time per stereo frame (s)", lambda e: e["render_s_per_stereo_frame"])
    row("world / orbital / traverse (s)", lambda e: " / ".join(
        str(e["phases_s"][k]) for k in ("world_s", "orbital_s", "traverse_s")))
    row("peak RSS (MB)", lambda e: e["peak_rss_mb"])
    row("worker peak RSS (MB)", lambda e: e.get("worker_peak_rss_mb", "-"))
    row("peak RSS generator + worker, sampled at 2 Hz (MB)",
        lambda e: e.get("peak_rss_total_mb", "-"))
    row("bag directory (MB)", lambda e: e["bag_dir_mb"])
    row("rosbag (MB)", lambda e: e["rosbag_mb"])
    row("stereo frames", lambda e: e["route"]["stereo_frames"])
    row("route length / net (m)", lambda e: f"{e['route']['length_m']} / {e['route']['net_m']}")
    row("major ROIs (rocks + outcrops)", lambda e: f"{e['rois']['total']} "
        f"({e['rois']['rocks']} + {e['rois']['outcrops']})")
    row("ROIs within 15 m of the route", lambda e: e["rois"]["within_roi_range_of_route"])
    row("ROIs seen by the left camera (>= 200 px)",
        lambda e: e["rois"]["seen_by_left_camera_200px"])
    row("clutter rocks", lambda e: e["rois"]["clutter_rocks"])
    row("ORB features per left frame (mean / min)", lambda e: (
        f"{e['orb_features_per_left_frame']['mean']} / "
        f"{e['orb_features_per_left_frame']['min']}"))
    path.write_text("\n".join(lines) + "\n")


class RssSampler:
    """Peak RSS of this process, of its children, and of both together, sampled at 2 Hz.

    ``getrusage(RUSAGE_CHILDREN).ru_maxrss`` is no measure of a spawned worker: it counts the
    parent's pages the child held between fork and exec. Sampling sees what each really holds.
    """

    def __init__(self) -> None:
        import psutil

        self._me = psutil.Process()
        self.peak_children_mb = 0.0
        self.peak_total_mb = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        import psutil

        while not self._stop.wait(0.5):
            children = 0.0
            for child in self._me.children(recursive=True):
                try:
                    children += child.memory_info().rss / 2**20
                except psutil.Error:
                    continue
            total = self._me.memory_info().rss / 2**20 + children
            self.peak_children_mb = max(self.peak_children_mb, children)
            self.peak_total_mb = max(self.peak_total_mb, total)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="atacama_1km")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--results", type=Path, default=RESULTS / "sim_results.json")
    ap.add_argument("--md-only", action="store_true")
    args = ap.parse_args()
    md = args.results.with_suffix(".md")
    if args.md_only:
        write_markdown(json.loads(args.results.read_text()), md)
        return
    out = args.out or Path("bags") / args.preset

    from atacama_sim.config import make_config
    from atacama_sim.generate import generate

    cfg = make_config(args.preset, args.seed)
    def children_cpu() -> float:
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return ru.ru_utime + ru.ru_stime

    t0 = time.perf_counter()
    c0, k0 = time.process_time(), children_cpu()
    with RssSampler() as rss:
        stats = generate(cfg, out, progress=True)
    wall = time.perf_counter() - t0
    # this process plus the image-developing worker (waited for when the pool closes)
    cpu_main, cpu_worker = time.process_time() - c0, children_cpu() - k0
    peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    orb = orb_counts(out)
    n = stats["route"]["stereo_frames"]
    entry = {
        "preset": args.preset, "seed": args.seed, "out": str(out),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "note": "shared 2-core machine: other jobs may have run meanwhile"},
        "total_s": round(wall, 1),
        "cpu_s": round(cpu_main + cpu_worker, 1),
        "cpu_s_main_worker": [round(cpu_main, 1), round(cpu_worker, 1)],
        "s_per_stereo_frame": round(stats["timing_s"]["traverse_s"] / max(1, n), 3),
        "render_s_per_stereo_frame": stats["render_s_per_stereo_frame"],
        "phases_s": stats["timing_s"],
        "peak_rss_mb": round(peak_rss_mb, 1),
        "worker_peak_rss_mb": round(rss.peak_children_mb, 1),
        "peak_rss_total_mb": round(rss.peak_total_mb, 1),
        "bag_dir_mb": round(dir_size(out) / 1e6, 1),
        "rosbag_mb": round(dir_size(out / "rosbag") / 1e6, 1),
        "orbital_tif_mb": round((out / "orbital.tif").stat().st_size / 1e6, 1),
        "rois": stats["rois"],
        "route": stats["route"],
        "messages": stats["messages"],
        "orb_features_per_left_frame": {"mean": round(float(np.mean(orb)), 1),
                                        "min": int(np.min(orb)), "max": int(np.max(orb)),
                                        "frames_sampled": len(orb)},
    }
    results = json.loads(args.results.read_text()) if args.results.exists() else {}
    results[f"{args.preset} seed {args.seed}"] = entry
    args.results.write_text(json.dumps(results, indent=1) + "\n")
    write_markdown(results, md)
    print(json.dumps(entry, indent=1))


if __name__ == "__main__":
    main()

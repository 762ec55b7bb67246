"""``atacama_sim generate --preset {atacama_1km,quick,tiny} --seed N --out bags/NAME
[--set SECTION.FIELD=VALUE ...] [--no-panoramas]``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from atacama_sim.config import PRESETS, add_site, make_config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="atacama_sim",
                                     description="Synthetic Atacama-style world and bag writer.")
    sub = parser.add_subparsers(dest="command", required=True)
    gen = sub.add_parser("generate", help="write a bag directory (DESIGN.md layout)")
    gen.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    gen.add_argument("--seed", type=int, default=1)
    gen.add_argument("--out", type=Path, required=True, help="bag directory, e.g. bags/quick")
    gen.add_argument("--crs", default=None,
                     help="projected CRS (default EPSG:32719; e.g. IAU_2015:49910 for Mars)")
    gen.add_argument("--site-lonlat", type=float, nargs=2, default=None,
                     metavar=("LON", "LAT"), help="map-frame origin, degrees")
    gen.add_argument("--orbital-only", action="store_true",
                     help="the orbital image, truth and world.yaml only: no traverse, no "
                          "rosbag (training data for orbital_gn train)")
    gen.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                     help="override one field of the preset's configuration (repeatable; "
                     "a YAML value: e.g. camera.width=1024 camera.hfov_deg=60 "
                     "route.length_m=600 imu.gravity=3.721); world.yaml records the result")
    gen.add_argument("--no-panoramas", action="store_true",
                     help="no stereo panoramas at the stops: the mast stays at the drive "
                          "pose (mast.panoramas=false; rover.yaml still states the mast)")
    gen.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)

    try:
        overrides = parse_overrides(args.set)
    except ValueError as exc:
        parser.error(str(exc))
    if args.no_panoramas:
        overrides.setdefault("mast", {})["panoramas"] = False
    add_site(overrides, args.crs, tuple(args.site_lonlat) if args.site_lonlat else None)
    try:
        cfg = make_config(args.preset, args.seed, overrides)
    except (KeyError, TypeError, ValueError) as exc:
        parser.error(f"--set: {exc}")
    from atacama_sim.generate import generate  # deferred: heavy imports

    stats = generate(cfg, args.out, progress=not args.no_progress,
                     orbital_only=args.orbital_only)
    summary = {k: stats[k] for k in ("rois", "route", "panoramas", "timing_s",
                                     "render_s_per_stereo_frame")}
    print(json.dumps(summary, indent=1))
    return 0


def parse_overrides(items: list[str]) -> dict:
    """Nested overrides for :func:`~atacama_sim.config.make_config` from
    ``SECTION.FIELD=VALUE`` strings (VALUE read as YAML: numbers, lists, strings).

    Raises:
        ValueError: naming an item that is not of that form.
    """
    import yaml

    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        path = key.strip().split(".")
        if not sep or len(path) < 2 or not all(path):
            raise ValueError(f"--set {item!r}: expected SECTION.FIELD=VALUE (e.g. "
                             "camera.width=1024)")
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ValueError(f"--set {item!r}: the value is not YAML ({exc})") from None
        node = out
        for part in path[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"--set {item!r}: {part} is set as a value and a section")
        node[path[-1]] = parsed
    return out


if __name__ == "__main__":
    sys.exit(main())

"""``orbital_gn``: offline GN preparation (train, prepare, eval).

    orbital_gn train  [BAG_DIR...] [--image ORTHO.tif --labels LABELS.geojson
                      [--region REGION.geojson]]... --out models/orbital.npz [--recipe R]
    orbital_gn prepare ORTHO.tif --out GN.geojson [--model M] [--preview GN.png] [--strict]
                                 [--scheduler ADDR] [--workers N] [--tile-px N]
                                 [--sun-azimuth DEG --sun-elevation DEG]
    orbital_gn eval   --gn GN.geojson --truth BAG_DIR/truth/rois.geojson [--json OUT]
    orbital_gn eval   --image ORTHO.tif --labels LABELS.geojson [--region REGION.geojson]
                      [--gn GN.geojson | --model M] [--json OUT]

Errors are one line on stderr naming the file, exit status 2; no partial output file.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

from orbital_gn.labels import LabelFileError
from orbital_gn.raster import OrthoImageError, Sun
from orbital_gn.recipe import RECIPES
from roi_detector.classifier import ModelFileError
from roi_network.geojson import GeoJsonFormatError


def _progress_factory(enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    def make(what: str, total: int):
        return tqdm(total=total, desc=what, unit="tile", file=sys.stderr, leave=False)

    return make


def _write_json_atomic(doc, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=2) + "\n")
    tmp.replace(path)


def cmd_prepare(args) -> int:
    from orbital_gn.prepare import Model, load_model, prepare_gn
    from roi_network.geojson import write_geojson

    if (args.sun_azimuth is None) != (args.sun_elevation is None):
        raise ValueError("--sun-azimuth and --sun-elevation go together (degrees clockwise "
                         "from north, degrees above the horizon)")
    sun = (Sun.checked(args.sun_azimuth, args.sun_elevation, "--sun-azimuth/--sun-elevation")
           if args.sun_azimuth is not None else None)
    model = Model(RECIPES[args.recipe]) if args.model == "none" else load_model(args.model)
    t0 = time.perf_counter()
    gn, warnings = prepare_gn(args.ortho, model, tile_px=args.tile_px, scheduler=args.scheduler,
                              workers=args.workers,
                              progress=_progress_factory(not args.no_progress),
                              origin=tuple(args.origin) if args.origin else None, sun=sun)
    elapsed = time.perf_counter() - t0
    for w in warnings:
        print(f"orbital_gn prepare: warning: {w}", file=sys.stderr)
    domain = gn.metadata["domain_check"]
    if args.strict and domain["status"] == "out_of_distribution":
        raise OrthoImageError(f"{args.ortho}: domain check out_of_distribution (--strict): "
                              f"{len(domain['reasons'])} reason(s) above; no GN written")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    gn.metadata["elapsed_s"] = round(elapsed, 2)
    write_geojson(gn, out)
    n_rock = int((gn.records["label"] == 1).sum())
    recipe = gn.metadata["recipe"]["name"]  # the no-sun fallback's when it was used
    print(f"{out}: {len(gn)} ROIs ({n_rock} rocks, {len(gn) - n_rock} outcrops) from "
          f"{args.ortho} in {elapsed:.1f} s (recipe {recipe}; domain check "
          f"{domain['status']})")
    if args.preview:
        from orbital_gn.preview import draw_preview

        draw_preview(args.ortho, gn, args.preview)
        print(f"{args.preview}: preview")
    return 0


class _Pair(argparse.Action):
    """``--image`` starts a training image; ``--labels`` and ``--region`` belong to the
    ``--image`` before them."""

    def __call__(self, parser, namespace, value, option_string=None):
        items = getattr(namespace, "pairs", None) or []
        if self.dest == "image":
            items.append({"image": value})
        elif not items:
            parser.error(f"{option_string} {value}: give --image ORTHO.tif before it")
        elif self.dest in items[-1]:
            parser.error(f"{option_string} {value}: --image {items[-1]['image']} already has "
                         f"{option_string} {items[-1][self.dest]}")
        else:
            items[-1][self.dest] = value
        namespace.pairs = items


def _image_label_pairs(args) -> list[tuple[str, str, str | None]]:
    """(image, labels, region or None) of each ``--image``, in the order given."""
    out = []
    for p in getattr(args, "pairs", None) or []:
        if "labels" not in p:
            raise ValueError(f"--image {p['image']} has no --labels LABELS.geojson after it")
        out.append((p["image"], p["labels"], p.get("region")))
    return out


def cmd_train(args) -> int:
    from orbital_gn.train import TrainingImage, train_model

    sources = [TrainingImage.of_bag(b) for b in args.bags]
    sources += [TrainingImage(Path(i), Path(lab), Path(r) if r else None)
                for i, lab, r in _image_label_pairs(args)]
    if not sources:
        raise ValueError("nothing to train on: give bag directories and/or --image ORTHO.tif "
                         "--labels LABELS.geojson pairs")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    notes: list[str] = []
    prov = train_model(sources, RECIPES[args.recipe], out, scheduler=args.scheduler,
                       workers=args.workers, notes=notes)
    for n in notes:
        print(f"orbital_gn train: warning: {n}", file=sys.stderr)
    size = out.stat().st_size
    print(f"{out}: recipe {args.recipe}, {len(sources)} image(s), seeds "
          f"{prov['training']['seeds']}, {json.dumps(prov['training']['samples'])}, "
          f"{size / 1024:.0f} KiB")
    return 0


def _eval_on_labels(args):
    """(GN, truth, result extras) for ``eval --image --labels``: the GN given or prepared,
    restricted with the labels to their region."""
    from orbital_gn.evaluate import crs_xy
    from orbital_gn.labels import read_labels
    from orbital_gn.prepare import load_model, map_origin_of, prepare_gn
    from orbital_gn.raster import open_ortho
    from roi_network import RoiNetwork
    from roi_network.geojson import read_geojson

    info = open_ortho(args.image)
    if args.gn:
        gn = read_geojson(args.gn)
    else:
        gn, warnings = prepare_gn(args.image, load_model(args.model), scheduler=args.scheduler,
                                  workers=args.workers)
        for w in warnings:
            print(f"orbital_gn eval: warning: {w}", file=sys.stderr)
    origin = gn.map_frame.origin if gn.map_frame else map_origin_of(info)
    labels = read_labels(args.labels, info, origin, args.region)
    for n in labels.notes():
        print(f"orbital_gn eval: warning: {n}", file=sys.stderr)
    inside = labels.region.contains(crs_xy(gn))
    gn_in = RoiNetwork(gn.records[inside], "map", gn.map_frame, gn.metadata)
    extras = {"labels": labels.counts, "region": labels.region.source,
              "gn_outside_region": int((~inside).sum()),
              "domain_check": (gn.metadata.get("domain_check") or {}).get("status")}
    return gn_in, labels.truth, extras


def cmd_eval(args) -> int:
    from orbital_gn.evaluate import evaluate, route_xy
    from roi_network.geojson import read_geojson

    if bool(args.image) != bool(args.labels) or (args.labels and args.truth):
        raise ValueError("eval takes --gn GN --truth TRUTH, or --image ORTHO --labels "
                         "LABELS [--gn GN]")
    if args.labels:
        gn, truth, extras = _eval_on_labels(args)
        route = None
        result = evaluate(gn, truth, route)
        result |= extras
        result["labels_file"] = str(args.labels)
    else:
        if not (args.gn and args.truth):
            raise ValueError("eval takes --gn GN --truth TRUTH, or --image ORTHO --labels "
                             "LABELS [--gn GN]")
        gn = read_geojson(args.gn)
        truth = read_geojson(args.truth)
        traj = (Path(args.trajectory) if args.trajectory
                else Path(args.truth).parent / "trajectory.tum")
        route = route_xy(traj, truth) if traj.is_file() else None
        result = evaluate(gn, truth, route)
        result["truth_file"] = str(args.truth)
    result["gn"] = str(args.gn or args.image)
    if args.json:
        _write_json_atomic(result, Path(args.json))
    for name in ("rock", "rock_ge_1m2", "outcrop"):
        r = result[name]
        p = "n/a" if r["precision"] is None else f"{100 * r['precision']:.1f} %"
        rc = "n/a" if r["recall"] is None else f"{100 * r['recall']:.1f} %"
        print(f"{name:12s} precision {p:>8s} ({r['true_positives']}/{r['detections']})  "
              f"recall {rc:>8s} ({r['found']}/{r['truth']})")
    for b, r in result.get("rock_bins_m2", {}).items():
        rc = "n/a" if r["recall"] is None else f"{100 * r['recall']:.1f} %"
        p = "n/a" if r["precision"] is None else f"{100 * r['precision']:.1f} %"
        print(f"  rock {b:>6s} m^2  precision {p:>8s}  recall {rc:>8s} ({r['found']}/{r['truth']})")
    if "near_route" in result:
        nr = result["near_route"]
        f = "n/a" if nr["fraction"] is None else f"{100 * nr['fraction']:.1f} %"
        print(f"truth ROIs within {nr['radius_m']:g} m of the route held by the GN: {f} "
              f"({nr['in_gn']}/{nr['truth']})")
    return 0


def _label_args(p, what: str) -> None:
    p.add_argument("--image", action=_Pair, help=f"{what} (repeatable), followed by its "
                   "--labels [--region]")
    p.add_argument("--labels", action=_Pair, help="label GeoJSON of the --image before it: "
                   "points or polygons with a 'class' property (rock | outcrop), any CRS")
    p.add_argument("--region", action=_Pair, help="polygon GeoJSON of the ground the "
                   "--labels cover (default: the label file's extent)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="orbital_gn", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    pr = sub.add_parser("prepare", help="the GN of a georeferenced orthoimage")
    pr.add_argument("ortho", help="orthoimage (GeoTIFF or any raster GDAL reads)")
    pr.add_argument("--out", required=True, help="output GN GeoJSON")
    pr.add_argument("--model", default=None,
                    help="model file (default: the committed one); 'none': candidates only")
    pr.add_argument("--recipe", choices=sorted(RECIPES), default="no_sun",
                    help="recipe with --model none (a model file carries its own)")
    pr.add_argument("--preview", help="PNG of the GN drawn over the image")
    pr.add_argument("--scheduler", help="dask.distributed scheduler address (default: "
                    "local processes); 'sync' runs in-process")
    pr.add_argument("--workers", type=int, default=2, help="local worker processes")
    pr.add_argument("--tile-px", type=int, default=None, help="window core side, pixels")
    pr.add_argument("--origin", type=float, nargs=2, metavar=("EASTING", "NORTHING"),
                    help="map-frame origin (default: raster centre rounded to 1 m)")
    pr.add_argument("--sun-azimuth", type=float, metavar="DEG",
                    help="sun azimuth at acquisition, degrees clockwise from north (a "
                    "sun-aware model needs it; default: the raster's SUN_AZIMUTH_DEG tag)")
    pr.add_argument("--sun-elevation", type=float, metavar="DEG",
                    help="sun elevation above the horizon, degrees (0, 90] (default: the "
                    "raster's SUN_ELEVATION_DEG tag)")
    pr.add_argument("--strict", action="store_true",
                    help="refuse an image the domain check finds out_of_distribution "
                    "(exit 2, no GN written)")
    pr.add_argument("--no-progress", action="store_true")
    pr.set_defaults(func=cmd_prepare)
    tr = sub.add_parser("train", help="train the classifiers from labelled images")
    tr.add_argument("bags", nargs="*", help="simulator bag directories (orbital.tif + truth/)")
    _label_args(tr, "training image")
    tr.add_argument("--out", required=True, help="model file (.npz)")
    tr.add_argument("--recipe", choices=sorted(RECIPES), default="no_sun",
                    help="recipe to train (default no_sun: needs no sun direction)")
    tr.add_argument("--scheduler")
    tr.add_argument("--workers", type=int, default=2)
    tr.set_defaults(func=cmd_train)
    ev = sub.add_parser("eval", help="detection quality against a truth catalogue or labels")
    ev.add_argument("--gn", help="the GN (default with --image: prepared now)")
    ev.add_argument("--truth", help="BAG_DIR/truth/rois.geojson")
    ev.add_argument("--image", help="orthoimage the labels are of")
    ev.add_argument("--labels", help="label GeoJSON (points or polygons, property 'class')")
    ev.add_argument("--region", help="polygon GeoJSON of the labelled ground (default: the "
                    "label file's extent)")
    ev.add_argument("--model", default=None, help="model for the GN prepared with --image "
                    "(default: the committed one)")
    ev.add_argument("--scheduler")
    ev.add_argument("--workers", type=int, default=2)
    ev.add_argument("--trajectory", help="route (TUM); default: truth/trajectory.tum beside it")
    ev.add_argument("--json", help="write the figures as JSON")
    ev.set_defaults(func=cmd_eval)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    try:
        return args.func(args)
    except (OrthoImageError, ModelFileError, GeoJsonFormatError, LabelFileError,
            FileNotFoundError,
            ValueError, KeyError, OSError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"orbital_gn {args.cmd}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"orbital_gn {args.cmd}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

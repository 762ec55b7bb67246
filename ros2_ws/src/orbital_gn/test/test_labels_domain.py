"""orbital_gn on a user's own labels (train, eval), the domain check in every GN, the
physical sanity of its rocks, and bad input. Fixtures: small synthetic orthoimages with
label files made at test time (orbital_scene.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from orbital_scene import (
    GSD,
    SUN_TAGS,
    label_features,
    make_labelled_image,
    scene,
    write_labels,
    write_tif,
)
from rasterio.transform import from_origin

from orbital_gn.cli import main
from orbital_gn.domain import (
    check_domain,
    cumulative_number,
    fit_k,
    fractional_area,
    rock_abundance,
)
from orbital_gn.labels import LabelFileError, polygon_footprint, read_labels
from orbital_gn.prepare import load_model, map_origin_of
from orbital_gn.raster import open_ortho
from orbital_gn.recipe import NO_SUN
from orbital_gn.train import TrainingImage, labelled_candidates
from roi_network import OUTCROP, ROCK
from roi_network.geojson import read_geojson


@pytest.fixture(scope="module")
def sites(tmp_path_factory):
    root = tmp_path_factory.mktemp("sites")
    return [make_labelled_image(root, 101), make_labelled_image(root, 102, crs="EPSG:32720")]


@pytest.fixture(scope="module")
def label_model(sites, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "labels.npz"
    args = ["train", "--out", str(out), "--recipe", "no_sun", "--scheduler", "sync"]
    for image, labels in sites:
        args += ["--image", str(image), "--labels", str(labels)]
    assert main(args) == 0
    return out


def _one_error_line(capsys, *words):
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]
    return err[0]


# ---- label files ----

def test_polygon_footprint_of_an_ellipse():
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    th = 0.6
    x = 403000 + 3 * np.cos(t) * math.cos(th) - 1 * np.sin(t) * math.sin(th)
    y = 7334000 + 3 * np.cos(t) * math.sin(th) + 1 * np.sin(t) * math.cos(th)
    area, cx, cy, cov = polygon_footprint([np.column_stack([x, y])[::-1]])  # clockwise
    assert area == pytest.approx(math.pi * 3, rel=1e-3)
    assert (cx, cy) == (pytest.approx(403000, abs=1e-6), pytest.approx(7334000, abs=1e-6))
    w = np.linalg.eigvalsh(cov)
    assert 4 * math.sqrt(w[1]) == pytest.approx(6.0, rel=1e-3)  # full major axis


@pytest.mark.parametrize(("crs", "polygons"), [("OGC:CRS84", True), ("EPSG:32620", False),
                                               ("EPSG:4326", True)])
def test_labels_in_another_crs_are_reprojected(tmp_path, crs, polygons):
    rgb, truth = scene(5)
    image = write_tif(tmp_path / "o.tif", rgb)
    path = write_labels(tmp_path / "l.geojson", label_features(truth, crs, polygons),
                        None if crs == "OGC:CRS84" else crs)
    info = open_ortho(image)
    ls = read_labels(path, info, truth.map_frame.origin)
    assert ls.counts["outside_image"] == 0 and len(ls.truth) == len(truth)
    a, b = ls.truth.records, truth.records
    np.testing.assert_allclose(a["x"], b["x"], atol=0.01)
    np.testing.assert_allclose(a["y"], b["y"], atol=0.01)
    np.testing.assert_array_equal(a["label"], b["label"])
    if polygons:
        np.testing.assert_allclose(a["area_m2"], np.pi * b["major_m"] * b["minor_m"] / 4,
                                   rtol=0.05)


def test_classes_other_than_rock_and_outcrop_are_named_and_refused(tmp_path, capsys):
    rgb, truth = scene(5)
    image = write_tif(tmp_path / "o.tif", rgb)
    feats = label_features(truth)
    feats[0]["properties"]["class"] = "boulder"
    feats[3]["properties"]["class"] = "crater"
    feats[4]["properties"]["class"] = "Crater"
    del feats[5]["properties"]["class"]
    feats[6]["properties"]["class"] = "ROCK"  # any case is a rock
    path = write_labels(tmp_path / "l.geojson", feats)
    with pytest.raises(LabelFileError) as exc:
        read_labels(path, open_ortho(image), (0.0, 0.0))
    msg = str(exc.value)
    for word in (str(path), "'boulder' (features 0)", "'crater' (features 3)",
                 "'Crater' (features 4)", "None (features 5)"):
        assert word in msg, msg
    assert "'ROCK'" not in msg
    rc = main(["train", "--image", str(image), "--labels", str(path), "--out",
               str(tmp_path / "m.npz"), "--scheduler", "sync"])
    assert rc == 2 and not (tmp_path / "m.npz").exists()
    _one_error_line(capsys, str(path), "'boulder'")


def test_labels_outside_the_image_are_counted_and_skipped(tmp_path):
    rgb, truth = scene(5)
    image = write_tif(tmp_path / "o.tif", rgb)
    feats = label_features(truth, polygons=False)
    far = label_features(truth, "EPSG:32719", polygons=False)[:3]
    for f in far:  # 2 km east of the image
        f["geometry"]["coordinates"][0] += 2000.0
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:32719", "OGC:CRS84", always_xy=True)
    for f in far:
        f["geometry"]["coordinates"] = list(tr.transform(*f["geometry"]["coordinates"]))
    region = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {},
              "geometry": {"type": "Polygon", "coordinates": [[[-70, -25], [-69, -25],
                                                               [-69, -24], [-70, -24],
                                                               [-70, -25]]]}}]}
    (tmp_path / "region.geojson").write_text(json.dumps(region))
    path = write_labels(tmp_path / "l.geojson", feats + far)
    ls = read_labels(path, open_ortho(image), truth.map_frame.origin, tmp_path / "region.geojson")
    assert ls.counts["outside_image"] == 3 and len(ls.truth) == len(truth)
    assert ls.notes() == [f"{path}: 3 of {len(truth) + 3} labels lie outside the image and "
                          "are skipped"]
    wrong = write_labels(tmp_path / "w.geojson", far)
    with pytest.raises(LabelFileError, match="none of its 3 labels lies inside"):
        read_labels(wrong, open_ortho(image), truth.map_frame.origin)


def test_the_region_bounds_what_is_labelled(tmp_path):
    rgb, truth = scene(6)
    image = write_tif(tmp_path / "o.tif", rgb, tags=SUN_TAGS)
    path = write_labels(tmp_path / "l.geojson", label_features(truth, "EPSG:32719"),
                        "EPSG:32719")
    ox, oy = truth.map_frame.origin
    west = [[ox - 100, oy - 100], [ox, oy - 100], [ox, oy + 100], [ox - 100, oy + 100]]
    region = {"type": "FeatureCollection", "crs": {"type": "name", "properties": {
        "name": "EPSG:32719"}}, "features": [{"type": "Feature", "properties": {},
                                              "geometry": {"type": "Polygon",
                                                           "coordinates": [west + west[:1]]}}]}
    (tmp_path / "west.geojson").write_text(json.dumps(region))
    whole = labelled_candidates(TrainingImage(image, path), NO_SUN, "sync")
    half = labelled_candidates(TrainingImage(image, path, tmp_path / "west.geojson"), NO_SUN,
                               "sync")
    n_west = int((truth.records["x"] < 0).sum())
    assert half.notes and f"{len(truth) - n_west} of {len(truth)}" in half.notes[0]
    for label in (ROCK, OUTCROP):
        assert 0 < len(half.samples[label][1]) < len(whole.samples[label][1])
    assert half.profile["region_km2"] == pytest.approx(whole.profile["area_km2"] / 2,
                                                       rel=0.02)
    # Without a region, the labels' extent (less than the image).
    assert half.profile["region_km2"] < whole.profile["region_km2"] < whole.profile["area_km2"]


# ---- train and eval on labels ----

def test_a_model_trained_on_labels_detects_a_held_out_image(tmp_path, label_model, capsys):
    model = load_model(label_model)
    prov = model.meta["provenance"]
    assert prov["training"]["seeds"] == [None, None] and prov["training"]["bags"] == []
    assert [i["labels_kind"] for i in prov["training"]["images"]] == ["label file"] * 2
    profiles = prov["domain"]["images"]
    assert len(profiles) == 2
    for p in profiles:
        assert p["gsd_m"] == pytest.approx(GSD) and p["colour"] == "rgb"
        assert p["rock_detections_per_km2"] > 0 and 0.5 <= p["rock_score_mean"] <= 1
        assert p["hessian_rock_std"] > 0 and p["entropy_mean"] > 0
    image, labels = make_labelled_image(tmp_path, 103)  # a site no training used
    gn_path = tmp_path / "gn.geojson"
    assert main(["prepare", str(image), "--model", str(label_model), "--out", str(gn_path),
                 "--no-progress", "--scheduler", "sync", "--strict"]) == 0
    domain = read_geojson(gn_path).metadata["domain_check"]
    # Like its training images; its rocks (0.2-1.6 m^2, 40 on 80 x 80 m) are not a Mars
    # site's: only the physical checks may say so.
    assert {r["check"] for r in domain["reasons"]} <= {"rock_abundance", "rock_size_frequency"}
    assert set(domain["figures"]) >= {"gsd_m", "gray_mean", "hessian_rock_std",
                                      "entropy_mean", "rock_detections_per_km2",
                                      "rock_score_mean"}
    capsys.readouterr()
    assert main(["eval", "--image", str(image), "--labels", str(labels), "--gn", str(gn_path),
                 "--json", str(tmp_path / "ev.json")]) == 0
    ev = json.loads((tmp_path / "ev.json").read_text())
    assert ev["rock"]["recall"] > 0.7 and ev["rock"]["precision"] > 0.7
    assert ev["outcrop"]["recall"] >= 0.75
    assert ev["labels"]["rock"] > 20 and ev["gn_outside_region"] >= 0
    assert "precision" in capsys.readouterr().out


def test_train_pairs_images_with_labels(tmp_path, sites, capsys):
    (image, labels), _ = sites
    rc = main(["train", "--image", str(image), "--out", str(tmp_path / "m.npz")])
    assert rc == 2
    _one_error_line(capsys, f"--image {image} has no --labels LABELS.geojson after it")
    with pytest.raises(SystemExit):
        main(["train", "--labels", str(labels), "--out", str(tmp_path / "m.npz")])
    assert "--labels" in capsys.readouterr().err
    rc = main(["train", "--out", str(tmp_path / "m.npz")])
    assert rc == 2
    _one_error_line(capsys, "nothing to train on")


# ---- the domain check ----

def test_an_unlike_image_is_out_of_distribution_and_strict_refuses(tmp_path, label_model,
                                                                   capsys):
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (320, 320, 3), dtype=np.uint8)  # no terrain of the model's
    image = write_tif(tmp_path / "noise.tif", noise)
    out = tmp_path / "gn.geojson"
    args = ["prepare", str(image), "--model", str(label_model), "--out", str(out),
            "--no-progress", "--scheduler", "sync"]
    assert main(args) == 0
    err = capsys.readouterr().err
    domain = read_geojson(out).metadata["domain_check"]
    assert domain["status"] == "out_of_distribution"
    checks = {r["check"]: r for r in domain["reasons"]}
    assert checks["gray_std"]["level"] == "out_of_distribution"
    # One warning per reason, naming the file.
    lines = [ln for ln in err.splitlines() if "domain check" in ln]
    assert len(lines) == len(domain["reasons"])
    assert all(ln.startswith(f"orbital_gn prepare: warning: {image}: domain check ")
               for ln in lines)
    out.unlink()
    assert main([*args, "--strict"]) == 2 and not out.exists()
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith(f"orbital_gn prepare: error: {image}: domain check "
                              "out_of_distribution (--strict)")


def test_check_domain_levels():
    training = [{"image": "a", "colour": "rgb", "gsd_m": 0.25, "gray_mean": 120.0,
                 "rock_detections_per_km2": 100.0},
                {"image": "b", "colour": "rgb", "gsd_m": 0.25, "gray_mean": 130.0,
                 "rock_detections_per_km2": 200.0}]
    base = {"colour": "rgb", "gsd_m": 0.25, "gray_mean": 125.0, "rock_detections_per_km2": 150}
    assert check_domain(base, training)["status"] == "ok"
    for change, check, level in (({"gsd_m": 0.30}, None, "ok"),
                                 ({"gsd_m": 0.35}, "gsd_m", "warn"),
                                 ({"gsd_m": 0.6}, "gsd_m", "out_of_distribution"),
                                 ({"gray_mean": 160.0}, "gray_mean", "warn"),
                                 ({"rock_detections_per_km2": 60.0}, None, "ok"),
                                 ({"rock_detections_per_km2": 40.0},
                                  "rock_detections_per_km2", "warn"),
                                 ({"rock_detections_per_km2": 5000.0},
                                  "rock_detections_per_km2", "out_of_distribution"),
                                 ({"colour": "gray"}, "colour", "warn")):
        result = check_domain(base | change, training)
        assert result["status"] == level, (change, result)
        assert [r["check"] for r in result["reasons"]] == ([check] if check else [])
    gsd = check_domain(base | {"gsd_m": 0.6}, training)["reasons"][0]["message"]
    assert gsd == ("ground sample distance, m/px 0.6 is 2.4 times above the training "
                   "images' 0.25-0.25")
    none = check_domain(base, None)
    assert none["status"] == "warn" and "no training-image profile" in \
        none["reasons"][0]["message"]


# ---- physical sanity ----

def _model_rocks(k: float, area_m2: float, rng) -> np.ndarray:
    """Rock diameters >= 0.5 m drawn from Golombek and Rapp's N_k(D) over ``area_m2``."""
    d = np.linspace(0.5, 6.0, 2000)
    n = np.array([cumulative_number(k, x) for x in d]) * area_m2
    count = rng.poisson(n[0])
    u = rng.uniform(0, n[0], count)
    return np.interp(u, n[::-1], d[::-1])  # inverse of the cumulative number


def test_golombek_rapp_model_and_the_fit():
    for k in (0.01, 0.05, 0.2):
        assert fit_k(fractional_area(k, 1.5), 1.5) == pytest.approx(k, rel=1e-6)
        # N is the integral of -dF/dD / (pi D^2 / 4): against a numeric integral.
        from scipy.integrate import quad

        q = 1.79 + 0.152 / k
        n, _ = quad(lambda x, k=k, q=q: k * q * math.exp(-q * x) / (math.pi * x * x / 4),
                    1.0, 60.0, epsabs=0.0, epsrel=1e-10)
        assert cumulative_number(k, 1.0) == pytest.approx(n, rel=1e-6)
    assert fit_k(0.0, 1.0) == 0.0 and math.isinf(fit_k(0.9, 1.0))


def test_rock_abundance_of_a_model_population_and_of_impossible_ones():
    rng = np.random.default_rng(3)
    area = 250_000.0
    d = _model_rocks(0.05, area, rng)
    rocks = rock_abundance(np.pi * d**2 / 4, area)
    assert rocks["k"] == pytest.approx(0.05, rel=0.15)
    assert rocks["larger_rocks_ratio"] == pytest.approx(1.0, abs=0.25)
    ok = check_domain({}, [{"image": "a", "colour": "rgb"}], rocks)
    assert ok["status"] == "ok", ok["reasons"]
    # A quarter of the ground under 1-2 m^2 "rocks": no Mars site is that rocky.
    dense = rock_abundance(rng.uniform(1.0, 2.0, 40_000), area)
    result = check_domain({}, [{"image": "a", "colour": "rgb"}], dense)
    assert result["status"] == "out_of_distribution"
    assert {r["check"] for r in result["reasons"]} >= {"rock_abundance"}
    # Rocks all of one size (texture blobs, say): no larger ones where the model has some.
    same = rock_abundance(np.full(500, 1.0), area)
    reasons = {r["check"]: r for r in check_domain({}, [{"colour": "rgb"}], same)["reasons"]}
    assert reasons["rock_size_frequency"]["level"] == "out_of_distribution"
    assert "times fewer" in reasons["rock_size_frequency"]["message"]
    # Rocks all of 2-6 m^2: flatter than any curve of the model's family.
    flat = rock_abundance(rng.uniform(2.0, 6.0, 300), area)
    reasons = {r["check"]: r for r in check_domain({}, [{"colour": "rgb"}], flat)["reasons"]}
    assert "even its flattest size-frequency (k = 40 %)" in \
        reasons["rock_size_frequency"]["message"]


# ---- bad input ----

def test_a_gsd_too_coarse_for_the_rocks_is_refused(tmp_path, sites, capsys):
    rgb, _ = scene(5)
    coarse = write_tif(tmp_path / "coarse.tif", rgb,
                       transform=from_origin(403000.0, 7334000.0, 0.6, 0.6))
    out = tmp_path / "gn.geojson"
    rc = main(["prepare", str(coarse), "--out", str(out), "--no-progress", "--scheduler",
               "sync"])
    assert rc == 2 and not out.exists()
    _one_error_line(capsys, str(coarse), "ground sample distance 0.6 m/px is too coarse",
                    "a 0.6 m^2 rock (0.87 m across) spans 1.5 px",
                    "the smallest rock this image shows 3 px across is 2.54 m^2",
                    "at most 0.29 m/px")
    _, labels = sites[0]
    rc = main(["train", "--image", str(coarse), "--labels", str(labels), "--out",
               str(tmp_path / "m.npz"), "--scheduler", "sync"])
    assert rc == 2
    _one_error_line(capsys, str(coarse), "too coarse")


def test_an_image_without_georeference_is_refused_naming_it(tmp_path, sites, capsys):
    rgb, _ = scene(5, size=64, n_rocks=2, n_outcrops=0)
    image = write_tif(tmp_path / "nocrs.tif", rgb, crs=None)
    _, labels = sites[0]
    for args in (["train", "--image", str(image), "--labels", str(labels), "--out",
                  str(tmp_path / "m.npz")],
                 ["eval", "--image", str(image), "--labels", str(labels)]):
        assert main([*args, "--scheduler", "sync"]) == 2
        _one_error_line(capsys, str(image), "no georeference")


def test_an_image_mostly_nodata_is_said(tmp_path, label_model, capsys):
    rgb, _ = scene(8)
    rgb[:230] = 0
    image = write_tif(tmp_path / "holes.tif", rgb, nodata=0)
    out = tmp_path / "gn.geojson"
    assert main(["prepare", str(image), "--model", str(label_model), "--out", str(out),
                 "--no-progress", "--scheduler", "sync"]) == 0
    err = capsys.readouterr().err
    assert f"{image}: 72 % of the image is nodata" in err, err
    assert "the GN covers 0.0018 of its 0.0064 km^2" in err


def test_model_without_profile_says_so(tmp_path, sites):
    from orbital_gn.prepare import Model, domain_check_of

    model = load_model(None)
    model = Model(model.recipe, model.classifiers, {"provenance": {}}, "old.npz")
    result = domain_check_of(model, {"colour": "rgb"}, np.zeros(0, dtype=[
        ("label", "u1"), ("score", "f4"), ("area_m2", "f4")]), {})
    assert result["status"] == "warn"
    assert result["reasons"][0]["check"] == "training_profile"


def test_labels_of_an_image_in_its_own_origin(tmp_path, sites):
    image, labels = sites[1]  # labels in EPSG:32720, image in EPSG:32719
    info = open_ortho(image)
    ls = read_labels(labels, info, map_origin_of(info))
    assert ls.counts["outside_image"] == 0 and ls.counts["rock"] > 20
    assert ls.truth.map_frame.crs == "EPSG:32719"

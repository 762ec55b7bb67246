"""orbital_gn: tiled == untiled, training and the model file, evaluation, CLI and bad input.
Fixtures are small synthetic orthoimages written at test time (orbital_scene.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from orbital_scene import GSD, make_bag, scene, write_tif
from rasterio.transform import from_origin

from orbital_gn.cli import main
from orbital_gn.evaluate import evaluate, match
from orbital_gn.prepare import Model, load_model, prepare_gn
from orbital_gn.raster import OrthoImageError, Sun, open_ortho
from orbital_gn.recipe import NO_SUN, PAPER, SUN_AWARE
from orbital_gn.train import TrainingError, train_model
from roi_network import OUTCROP, ROCK
from roi_network.geojson import read_geojson


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    return [make_bag(root, 101), make_bag(root, 102)]


@pytest.fixture(scope="module")
def model_file(bags, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "m.npz"
    train_model(bags, NO_SUN, out, scheduler="sync")
    return out


def _key(gn):
    r = gn.records
    return np.column_stack([r["id"], r["label"], r["x"], r["y"], r["area_m2"], r["major_m"],
                            r["minor_m"], r["score"]])


# no_sun's candidates are sun_aware's without the shift: sun_aware covers both.
@pytest.mark.parametrize("recipe", [PAPER, SUN_AWARE], ids=["paper", "sun_aware"])
def test_tiled_equals_untiled(bags, recipe):
    ortho = bags[0] / "orbital.tif"
    whole, _ = prepare_gn(ortho, Model(recipe), tile_px=10_000, scheduler="sync")
    tiled, _ = prepare_gn(ortho, Model(recipe), tile_px=70, scheduler="sync")
    assert len(whole) > 5
    np.testing.assert_allclose(_key(tiled), _key(whole), rtol=0, atol=1e-6)


def test_tiled_equals_untiled_with_classifiers(bags, model_file):
    model = load_model(model_file)
    ortho = bags[1] / "orbital.tif"
    whole, _ = prepare_gn(ortho, model, tile_px=10_000, scheduler="sync")
    tiled, _ = prepare_gn(ortho, model, tile_px=96, scheduler="sync")
    np.testing.assert_allclose(_key(tiled), _key(whole), rtol=0, atol=1e-6)


def test_trained_model_detects_rocks_and_outcrops(tmp_path, model_file):
    bag = make_bag(tmp_path, 103)  # a scene no training used
    model = load_model(model_file)
    prov = model.meta["provenance"]
    assert prov["training"]["seeds"] == [101, 102]
    assert prov["recipe"]["name"] == "no_sun"
    assert "scikit-learn" in model.meta["library_versions"]
    assert model_file.stat().st_size < 1_000_000
    gn, warnings = prepare_gn(bag / "orbital.tif", model, scheduler="sync")
    # The scene is like its training scenes; its rocks (0.2-1.6 m^2, 40 on 80 x 80 m) are
    # not a Mars site's: only the physical checks may say so.
    domain = gn.metadata["domain_check"]
    assert {r["check"] for r in domain["reasons"]} <= {"rock_abundance", "rock_size_frequency"}
    assert domain["status"] in ("ok", "warn")
    assert [w for w in warnings if "domain check" not in w] == []
    result = evaluate(gn, read_geojson(bag / "truth" / "rois.geojson"))
    assert result["rock"]["recall"] > 0.7 and result["rock"]["precision"] > 0.7
    assert result["outcrop"]["recall"] >= 0.75
    meta = gn.metadata
    assert meta["gsd_m"] == pytest.approx(GSD) and len(meta["source_sha256"]) == 64
    assert meta["model"]["training"]["seeds"] == [101, 102]


def test_training_refuses_an_evaluation_seed(tmp_path):
    bag = make_bag(tmp_path, 2)
    with pytest.raises(TrainingError, match="evaluation seed"):
        train_model([bag], NO_SUN, tmp_path / "m.npz", scheduler="sync")
    assert not (tmp_path / "m.npz").exists()


def test_match_rule_radius_and_class():
    _, truth = scene(5, size=200, n_rocks=10, n_outcrops=1)
    gn = type(truth)(truth.records.copy(), "map", truth.map_frame)
    rocks = np.flatnonzero(gn.records["label"] == ROCK)
    gn.records["x"][rocks[0]] += 0.9  # within 1 m: still a match
    gn.records["x"][rocks[1]] += 5.0  # far: a false detection and a missed rock
    gn.records["label"][rocks[2]] = OUTCROP  # wrong class
    result = evaluate(gn, truth)
    n_rock = rocks.size
    assert result["rock"]["true_positives"] == n_rock - 2
    assert result["rock"]["recall"] == pytest.approx((n_rock - 2) / n_rock)
    assert result["outcrop"]["detections"] == 2 and result["outcrop"]["true_positives"] == 1
    det_match, hit = match(gn, truth, ROCK)
    assert (det_match == -1).sum() == 1 and hit.sum() == n_rock - 2
    # Centre error of the matched rocks: all exact but the one moved by 0.9 m.
    err = result["rock"]["centre_error_m"]
    assert err["median"] == pytest.approx(0.0, abs=1e-9)
    assert 0.0 < err["p90"] <= 0.9 + 1e-9


def test_cli_prepare_eval_and_preview(tmp_path, bags, model_file, capsys):
    out = tmp_path / "gn.geojson"
    rc = main(["prepare", str(bags[0] / "orbital.tif"), "--out", str(out), "--model",
               str(model_file), "--preview", str(tmp_path / "gn.png"), "--no-progress",
               "--scheduler", "sync"])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["metadata"]["crs"] == "EPSG:32719"
    assert doc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32719"
    assert (tmp_path / "gn.png").stat().st_size > 1000
    rc = main(["eval", "--gn", str(out), "--truth", str(bags[0] / "truth" / "rois.geojson"),
               "--json", str(tmp_path / "ev.json")])
    assert rc == 0
    ev = json.loads((tmp_path / "ev.json").read_text())
    assert ev["rock"]["recall"] > 0.5
    assert "precision" in capsys.readouterr().out


def test_one_band_uint16_with_nodata(tmp_path):
    rgb, truth = scene(7)
    gray = (rgb.mean(axis=2) * 200).astype(np.uint16)
    gray[:40, :] = 65535
    path = write_tif(tmp_path / "pan.tif", gray, nodata=65535)
    info = open_ortho(path)
    assert info.bands == (1, 1, 1) and info.stretch is not None
    gn, warnings = prepare_gn(path, Model(NO_SUN), scheduler="sync")
    assert [w for w in warnings if "domain check" not in w] == [] and len(gn) > 5
    assert gn.metadata["domain_check"]["reasons"][0]["message"].startswith("candidates only")
    result = evaluate(gn, truth)
    assert result["rock"]["recall"] > 0.5
    # Nothing is detected in the nodata band.
    assert (gn.records["y"] < truth.map_frame.origin[1] + 0).any()
    top = 403000.0, 7334000.0 - 40 * GSD
    assert not (gn.records["y"] + gn.map_frame.origin[1] > top[1] - 1e-9).any()


# ---- bad input: each a one-line error (exit 2) and no output file, or an empty GN with
# a warning ----

def _prepare(tmp_path, ortho, capsys):
    out = tmp_path / "gn.geojson"
    rc = main(["prepare", str(ortho), "--out", str(out), "--model", "none", "--no-progress",
               "--scheduler", "sync"])
    return rc, out, capsys.readouterr()


def _assert_error(rc, out, captured, *words):
    assert rc == 2 and not out.exists()
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(lines) == 1, captured.err
    for w in words:
        assert w in lines[0], lines[0]
    assert "Traceback" not in captured.err


def test_bad_input_corrupt_file(tmp_path, capsys):
    p = tmp_path / "corrupt.tif"
    p.write_bytes(b"II*\x00" + bytes(range(256)) * 8)
    _assert_error(*_prepare(tmp_path, p, capsys), str(p), "not a readable raster")


def test_bad_input_truncated_file(tmp_path, capsys):
    rgb, _ = scene(3)
    p = write_tif(tmp_path / "full.tif", rgb)
    data = p.read_bytes()
    t = tmp_path / "truncated.tif"
    t.write_bytes(data[: len(data) // 2])
    _assert_error(*_prepare(tmp_path, t, capsys), str(t))


def test_bad_input_missing_file(tmp_path, capsys):
    _assert_error(*_prepare(tmp_path, tmp_path / "nope.tif", capsys), "nope.tif", "not found")


def test_bad_input_no_crs(tmp_path, capsys):
    rgb, _ = scene(3, size=64, n_rocks=2, n_outcrops=0)
    p = write_tif(tmp_path / "nocrs.tif", rgb, crs=None)
    _assert_error(*_prepare(tmp_path, p, capsys), str(p), "no georeference")


def test_bad_input_geographic_crs(tmp_path, capsys):
    rgb, _ = scene(3, size=64, n_rocks=2, n_outcrops=0)
    p = write_tif(tmp_path / "geo.tif", rgb, crs="EPSG:4326",
                  transform=from_origin(-69.9, -24.1, 2e-6, 2e-6))
    _assert_error(*_prepare(tmp_path, p, capsys), str(p), "geographic", "reproject")


def _assert_empty_with_warning(rc, out, captured, word):
    assert rc == 0 and out.exists()
    assert len(read_geojson(out)) == 0
    assert "warning" in captured.err and word in captured.err
    assert "Traceback" not in captured.err


def test_bad_input_all_nodata(tmp_path, capsys):
    p = write_tif(tmp_path / "nodata.tif", np.zeros((64, 64, 3), np.uint8), nodata=0)
    _assert_empty_with_warning(*_prepare(tmp_path, p, capsys), "nodata")


def test_bad_input_single_pixel(tmp_path, capsys):
    p = write_tif(tmp_path / "one.tif", np.full((1, 1, 3), 120, np.uint8))
    _assert_empty_with_warning(*_prepare(tmp_path, p, capsys), "smaller than the smallest ROI")


def test_bad_input_constant_image(tmp_path, capsys):
    p = write_tif(tmp_path / "flat.tif", np.full((64, 64, 3), 120, np.uint8))
    _assert_empty_with_warning(*_prepare(tmp_path, p, capsys), "no texture")


def test_bad_model_file(tmp_path, capsys):
    rgb, _ = scene(3, size=64, n_rocks=2, n_outcrops=0)
    p = write_tif(tmp_path / "ok.tif", rgb)
    bad = tmp_path / "model.npz"
    bad.write_bytes(b"junk")
    out = tmp_path / "gn.geojson"
    rc = main(["prepare", str(p), "--out", str(out), "--model", str(bad), "--no-progress"])
    _assert_error(rc, out, capsys.readouterr(), str(bad))


def test_open_ortho_rejects_non_square_pixels(tmp_path):
    rgb, _ = scene(3, size=64, n_rocks=2, n_outcrops=0)
    p = write_tif(tmp_path / "rect.tif", rgb, transform=from_origin(403000, 7334000, 0.25, 0.5))
    with pytest.raises(OrthoImageError, match="not square"):
        open_ortho(p)


def test_paths_in_metadata(tmp_path, bags):
    gn, _ = prepare_gn(bags[0] / "orbital.tif", Model(PAPER), scheduler="sync")
    assert Path(gn.metadata["source_image"]).name == "orbital.tif"
    assert gn.metadata["recipe"]["name"] == "paper"


def test_distributed_scheduler_gives_the_same_gn(bags):
    from distributed import LocalCluster

    ortho = bags[0] / "orbital.tif"
    local, _ = prepare_gn(ortho, Model(NO_SUN), tile_px=128, scheduler="sync")
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as cluster:
        seen = []

        class Bar:
            def __init__(self, what, total):
                seen.append((what, total))

            def update(self, n):
                seen.append(n)

            def close(self):
                pass

        remote, _ = prepare_gn(ortho, Model(NO_SUN), tile_px=128,
                               scheduler=cluster.scheduler_address, progress=Bar)
    np.testing.assert_allclose(_key(remote), _key(local), rtol=0, atol=1e-6)
    assert ("detection", 9) in seen and seen.count(1) >= 9


def test_bad_input_no_roi(tmp_path, capsys):
    # Fine soil grain only: no dark or pale region reaches the smallest ROI's area.
    rng = np.random.default_rng(0)
    soil = np.clip(130 + rng.normal(0, 3.0, (96, 96, 1)) * np.ones(3), 0, 255).astype(np.uint8)
    p = write_tif(tmp_path / "soil.tif", soil)
    _assert_empty_with_warning(*_prepare(tmp_path, p, capsys), "no ROI found")


def _rock_offsets(gn, truth):
    """Distances (m) from each truth rock to the nearest detected rock."""
    from scipy.spatial import cKDTree

    d = gn.records[gn.records["label"] == ROCK]
    t = truth.records[truth.records["label"] == ROCK]
    dist, _ = cKDTree(np.column_stack([d["x"], d["y"]])).query(np.column_stack([t["x"], t["y"]]))
    return dist[dist < 2.0]


def test_sun_aware_centres_rocks_from_the_raster_metadata(bags):
    # The scene's shadows fall south-east (its orbital.tif says: sun at azimuth 315 deg).
    ortho = bags[0] / "orbital.tif"
    truth = read_geojson(bags[0] / "truth" / "rois.geojson")
    plain, _ = prepare_gn(ortho, Model(NO_SUN), scheduler="sync")
    aware, _ = prepare_gn(ortho, Model(SUN_AWARE), scheduler="sync")
    assert aware.metadata["sun"] == {"azimuth_deg": 315.0, "elevation_deg": 45.0,
                                     "source": "raster metadata "
                                               "SUN_AZIMUTH_DEG/SUN_ELEVATION_DEG"}
    # Same candidates; rocks moved back towards the sun, closer to the truth.
    assert len(aware) == len(plain)
    off_plain, off_aware = _rock_offsets(plain, truth), _rock_offsets(aware, truth)
    assert off_aware.size >= off_plain.size >= 10
    assert np.median(off_aware) < 0.7 * np.median(off_plain)
    # The option wins over the metadata: the opposite sun pushes them further away.
    wrong, _ = prepare_gn(ortho, Model(SUN_AWARE), scheduler="sync", sun=Sun(135.0, 45.0))
    assert wrong.metadata["sun"]["source"].startswith("given")
    assert np.median(_rock_offsets(wrong, truth)) > np.median(off_plain)


def test_sun_aware_model_trains_and_prepares(tmp_path, bags):
    out = tmp_path / "sun.npz"
    prov = train_model(bags, SUN_AWARE, out, scheduler="sync")
    assert prov["recipe"]["sun_aware"] and prov["recipe"]["shadow_kappa"] > 0
    model = load_model(out)
    assert model.recipe is SUN_AWARE
    assert "sun_ring_contrast" in model.classifiers["rock_orbital"].feature_names
    gn, _ = prepare_gn(bags[1] / "orbital.tif", model, scheduler="sync")
    result = evaluate(gn, read_geojson(bags[1] / "truth" / "rois.geojson"))
    assert result["rock"]["recall"] > 0.7 and result["rock"]["precision"] > 0.7


def _prepare_sun(tmp_path, ortho, capsys, *extra):
    out = tmp_path / "gn.geojson"
    rc = main(["prepare", str(ortho), "--out", str(out), "--model", "none", "--recipe",
               "sun_aware", "--no-progress", "--scheduler", "sync", *extra])
    return rc, out, capsys.readouterr()


@pytest.mark.parametrize("extra, words", [
    (["--sun-azimuth", "35"], ["--sun-azimuth and --sun-elevation go together"]),
    (["--sun-azimuth", "35", "--sun-elevation", "0"], ["sun elevation", "(0, 90]"]),
    (["--sun-azimuth", "35", "--sun-elevation", "120"], ["sun elevation", "(0, 90]"]),
    (["--sun-azimuth", "nan", "--sun-elevation", "40"], ["sun azimuth", "not a finite"]),
], ids=["azimuth-alone", "elevation-0", "elevation-120", "azimuth-nan"])
def test_sun_options_bad_values(tmp_path, bags, capsys, extra, words):
    _assert_error(*_prepare_sun(tmp_path, bags[0] / "orbital.tif", capsys, *extra), *words)


def test_sun_aware_without_a_sun_direction(tmp_path, capsys):
    rgb, _ = scene(9, size=120, n_rocks=8, n_outcrops=1)
    ortho = write_tif(tmp_path / "nosun.tif", rgb)  # no SUN_* metadata
    _assert_error(*_prepare_sun(tmp_path, ortho, capsys), str(ortho), "needs the sun direction",
                  "--sun-azimuth")
    # Given on the command line, it runs.
    rc, out, _ = _prepare_sun(tmp_path, ortho, capsys, "--sun-azimuth", "315",
                              "--sun-elevation", "45")
    assert rc == 0 and out.exists()
    assert json.loads(out.read_text())["metadata"]["sun"]["azimuth_deg"] == 315.0


def test_bad_sun_metadata(tmp_path, capsys):
    rgb, _ = scene(9, size=120, n_rocks=8, n_outcrops=1)
    ortho = write_tif(tmp_path / "badsun.tif", rgb,
                      tags={"SUN_AZIMUTH_DEG": "north", "SUN_ELEVATION_DEG": "40"})
    _assert_error(*_prepare_sun(tmp_path, ortho, capsys), str(ortho), "SUN_AZIMUTH_DEG")

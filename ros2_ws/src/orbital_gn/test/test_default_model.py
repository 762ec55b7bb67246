"""The committed default model, and the GN preparation hook of `globloc run`."""

from __future__ import annotations

import shutil

import pytest
from orbital_scene import make_bag, scene, write_tif

from orbital_gn.prepare import default_model_path, load_model, no_sun_model_path, prepare_gn
from roi_network.geojson import read_geojson


def test_default_model_is_committed_and_loads():
    path = default_model_path()
    assert path.is_file(), f"{path}: the committed default model is missing"
    assert path.stat().st_size <= 1_000_000
    model = load_model(None)
    assert set(model.classifiers) == {"rock_orbital", "outcrop_orbital"}
    training = model.meta["provenance"]["training"]
    assert training["seeds"] and not set(training["seeds"]) & {1, 2, 3}
    assert model.meta["provenance"]["recipe"]["name"] == model.recipe.name
    # The default needs the sun direction; the model used without it is committed too.
    assert model.recipe.name == "sun_aware"
    assert model.without_sun == str(no_sun_model_path())
    assert no_sun_model_path().stat().st_size <= 1_000_000
    no_sun = load_model(no_sun_model_path())
    assert no_sun.recipe.name == "no_sun" and no_sun.without_sun is None
    assert not set(no_sun.meta["provenance"]["training"]["seeds"]) & {1, 2, 3}


def test_default_model_without_a_sun_direction_falls_back(tmp_path):
    rgb, _ = scene(11, size=200, n_rocks=15, n_outcrops=2)
    ortho = write_tif(tmp_path / "nosun.tif", rgb)  # no SUN_* metadata
    gn, warnings = prepare_gn(ortho, load_model(None), scheduler="sync")
    assert any("no sun direction" in w and "orbital_no_sun.npz" in w for w in warnings)
    assert gn.metadata["recipe"]["name"] == "no_sun"
    assert gn.metadata["sun"]["source"] == "not used by the recipe"


def test_globloc_run_hook_prepares_a_missing_gn(tmp_path):
    pytest.importorskip("rover_bringup")
    if shutil.which("orbital_gn") is None:
        pytest.skip("orbital_gn not on PATH (source env.sh)")
    from rover_bringup.run import prepare_gn_if_missing

    bag = make_bag(tmp_path, 104)
    prepare_gn_if_missing(bag)
    gn = read_geojson(bag / "gn.geojson")
    assert len(gn) > 0 and gn.map_frame.crs == "EPSG:32719"
    assert (bag / "gn.png").is_file()
    # An existing GN is left alone.
    before = (bag / "gn.geojson").stat().st_mtime_ns
    prepare_gn_if_missing(bag)
    assert (bag / "gn.geojson").stat().st_mtime_ns == before

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from roi_strategies import roi_records

from roi_network.geojson import (
    GeoJsonFormatError,
    domain_reasons,
    domain_status,
    read_geojson,
    validate_crs,
    write_geojson,
)
from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import empty_records

UTM19S = MapFrame("EPSG:32719", (377_000.0, 7_465_000.0))


def _gn(n=3):
    records = empty_records(n)
    records["x"] = np.arange(n) * 10.5
    records["y"] = -np.arange(n) * 3.25
    records["id"] = np.arange(n) + 1
    records["label"] = [1, 2, 1][:n] + [1] * max(0, n - 3)
    records["area_m2"] = 2.5
    return RoiNetwork(records, "map", UTM19S, {"source_image": "orbital.tif", "gsd_m": 0.25})


@settings(deadline=None, max_examples=40,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(roi_records())
def test_round_trip_is_exact(tmp_path, records):
    net = RoiNetwork(records, "map", UTM19S, {"source_image": "orbital.tif", "gsd_m": 0.25})
    path = tmp_path / "gn.geojson"
    write_geojson(net, path)
    back = read_geojson(path)
    assert back.records.tobytes() == records.tobytes()
    assert back.map_frame == UTM19S
    assert back.frame_id == "map"
    assert back.metadata == {"source_image": "orbital.tif", "gsd_m": 0.25}


def test_coordinates_are_projected_and_crs_is_declared(tmp_path):
    path = tmp_path / "gn.geojson"
    write_geojson(_gn(), path)
    doc = json.loads(path.read_text())
    assert doc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32719"
    assert doc["metadata"]["crs"] == "EPSG:32719"
    first = doc["features"][1]
    assert first["geometry"]["coordinates"][:2] == [377_010.5, 7_464_996.75]
    assert first["properties"]["class"] == "outcrop"


def test_point_moved_in_qgis_follows_geometry(tmp_path):
    path = tmp_path / "gn.geojson"
    write_geojson(_gn(), path)
    doc = json.loads(path.read_text())
    doc["features"][0]["geometry"]["coordinates"][0] += 5.0
    path.write_text(json.dumps(doc))
    assert read_geojson(path).records["x"][0] == pytest.approx(5.0)


def test_mars_crs_is_accepted(tmp_path):
    net = _gn()
    net.map_frame = MapFrame("IAU_2015:49910", (0.0, 0.0))
    path = tmp_path / "mars.geojson"
    write_geojson(net, path)
    assert read_geojson(path).map_frame.crs == "IAU_2015:49910"


def _broken(tmp_path, edit):
    path = tmp_path / "gn.geojson"
    write_geojson(_gn(), path)
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["features"][0]["properties"].pop("area_m2"), "feature 0.*'area_m2'"),
        (lambda d: d["features"][1]["properties"].update(score="high"), "feature 1.*'score'"),
        (lambda d: d["features"][2]["properties"].update({"class": "crater"}), "'class'"),
        (lambda d: d["features"][0]["properties"].update(id=-3), "'id'"),
        (lambda d: d["metadata"].update(crs="EPSG:4326"), "is not a projected CRS"),
        (lambda d: d["metadata"].update(crs="EPSG:999999"), "'metadata.crs'"),
        (lambda d: d.pop("metadata"), "'metadata'"),
        (lambda d: d["metadata"].update(map_origin=[1.0]), "'metadata.map_origin'"),
        (lambda d: d["features"][0].update(geometry={"type": "LineString"}), "'geometry'"),
        (lambda d: d.update(type="Feature"), "'type'"),
        (lambda d: d["metadata"].update(domain_check={"status": "fine"}),
         "'metadata.domain_check.status'"),
        (lambda d: d["metadata"].update(domain_check="ok"), "'metadata.domain_check'"),
    ],
)
def test_invalid_input_names_the_field(tmp_path, edit, match):
    path = _broken(tmp_path, edit)
    with pytest.raises(GeoJsonFormatError, match=match) as info:
        read_geojson(path)
    assert str(path) in str(info.value)


def test_corrupt_and_missing_files(tmp_path):
    bad = tmp_path / "bad.geojson"
    bad.write_text('{"type": "FeatureCollection", "features": [')
    with pytest.raises(GeoJsonFormatError, match="not valid JSON"):
        read_geojson(bad)
    with pytest.raises(FileNotFoundError, match=r"nope\.geojson"):
        read_geojson(tmp_path / "nope.geojson")


def test_failed_write_keeps_previous_file(tmp_path):
    path = tmp_path / "gn.geojson"
    write_geojson(_gn(), path)
    before = path.read_text()
    net = _gn()
    net.records["score"][1] = np.nan
    with pytest.raises(GeoJsonFormatError, match="'score'"):
        write_geojson(net, path)
    assert path.read_text() == before


def test_network_without_crs_cannot_be_written(tmp_path):
    with pytest.raises(GeoJsonFormatError, match="'map_frame'"):
        write_geojson(RoiNetwork(_gn().records, "odom"), tmp_path / "x.geojson")


def test_domain_check_status_round_trips(tmp_path):
    path = tmp_path / "gn.geojson"
    assert domain_status(_gn()) == "unknown" and domain_reasons(_gn()) == []
    net = _gn()
    net.metadata["domain_check"] = {"status": "warn", "reasons": [
        {"check": "gsd_m", "level": "warn", "message": "ground sample distance 0.4 ..."}]}
    write_geojson(net, path)
    back = read_geojson(path)
    assert domain_status(back) == "warn"
    assert domain_reasons(back) == ["ground sample distance 0.4 ..."]


def test_a_crs_with_north_east_axes_cannot_carry_the_map_frame():
    # New Zealand Transverse Mercator: northing first; the map frame is east, north
    with pytest.raises(GeoJsonFormatError, match="has axes north, east"):
        validate_crs("EPSG:2193", "metadata.crs")
    assert validate_crs("EPSG:32719", "metadata.crs") == "EPSG:32719"

"""roi_network.dtm: an elevation model written, read back in map coordinates, and refused
with a message naming the file when it cannot be used."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from roi_network.dtm import (
    DEFAULT_VERTICAL_SIGMA_M,
    UNKNOWN_VARIANCE_M2,
    DtmFormatError,
    read_dtm,
    write_dtm,
    z_is_estimated,
)
from roi_network.network import MapFrame

FRAME = MapFrame("EPSG:32719", (350000.0, 7400000.0))
#: A 2 m grid 40 x 30 posts whose upper-left corner is map (-20, 30).
WEST, NORTH, POST = 350000.0 - 20.0, 7400000.0 + 30.0, 2.0


def _plane(rows: int = 30, cols: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heights of the plane z = 0.1 x - 0.05 y + 3 at the post centres (map x, y)."""
    x = -20.0 + POST * (np.arange(cols) + 0.5)
    y = 30.0 - POST * (np.arange(rows) + 0.5)
    xx, yy = np.meshgrid(x, y)
    return 0.1 * xx - 0.05 * yy + 3.0, xx, yy


def _write(path, heights, **kw) -> None:
    args = {"crs": "EPSG:32719", "west": WEST, "north": NORTH, "posting": POST,
            "vertical_sigma_m": 0.4, "datum": "test datum"}
    args.update(kw)
    write_dtm(path, heights, **args)


def test_a_plane_reads_back_exactly_in_map_coordinates(tmp_path):
    heights, _, _ = _plane()
    path = tmp_path / "dtm.tif"
    _write(path, heights)
    dtm = read_dtm(path, FRAME)
    assert dtm.vertical_sigma_m == 0.4 and dtm.sigma_stated and dtm.datum == "test datum"
    x = np.array([-19.0, 0.0, 13.3, 58.9])
    y = np.array([29.0, 0.0, -7.7, -29.0])
    z, grad = dtm.height(x, y)
    np.testing.assert_allclose(z, 0.1 * x - 0.05 * y + 3.0, atol=1e-5)
    np.testing.assert_allclose(grad, np.tile([0.1, -0.05], (4, 1)), atol=1e-5)
    # Off the grid (more than half a post beyond the outer post centres): unknown.
    z, grad = dtm.height(np.array([-21.5, 0.0, 61.0]), np.array([0.0, 31.5, 0.0]))
    assert np.isnan(z).all() and np.isnan(grad).all()


def test_ground_z_variance_is_the_posts_plus_the_slope_through_the_horizontal_error(tmp_path):
    heights, _, _ = _plane()
    path = tmp_path / "dtm.tif"
    _write(path, heights)
    dtm = read_dtm(path, FRAME)
    cov = np.array([[4.0, 0.0], [0.0, 1.0]])
    z, _g, var = dtm.ground_z(10.0, 5.0, cov)
    assert z == pytest.approx(0.1 * 10.0 - 0.05 * 5.0 + 3.0, abs=1e-5)
    # 0.4^2 + 0.1^2 * 4 + 0.05^2 * 1
    assert var == pytest.approx(0.16 + 0.04 + 0.0025, rel=1e-4)
    z_above, _, _ = dtm.ground_z(10.0, 5.0, cov, height_above_ground_m=0.5)
    assert z_above == pytest.approx(z + 0.5)


def test_nodata_posts_give_unknown_heights_and_a_missing_sigma_the_default(tmp_path):
    heights, _, _ = _plane()
    heights[10:12, 10:12] = np.nan
    path = tmp_path / "dtm.tif"
    _write(path, heights)
    with rasterio.open(path, "r+") as ds:
        ds.update_tags(VERTICAL_SIGMA_M="about 1 m")
    with pytest.raises(DtmFormatError, match="VERTICAL_SIGMA_M = 'about 1 m'"):
        read_dtm(path, FRAME)
    plain = tmp_path / "plain.tif"  # a DTM of one's own: no tags
    with rasterio.open(path) as src:
        profile = src.profile
        data = src.read()
    with rasterio.open(plain, "w", **profile) as dst:
        dst.write(data)
    dtm = read_dtm(plain, FRAME)
    assert dtm.vertical_sigma_m == DEFAULT_VERTICAL_SIGMA_M and not dtm.sigma_stated
    assert "assumed" in dtm.describe()
    # Post (10, 10) is at map x = -20 + 21 = 1, y = 30 - 21 = 9.
    z, _ = dtm.height(np.array([1.0, 30.0]), np.array([9.0, -20.0]))
    assert np.isnan(z[0]) and np.isfinite(z[1])


@pytest.mark.parametrize(("case", "message"), [
    ("crs", "is in EPSG:32633, the GN in EPSG:32719"),
    ("bands", "2 bands, expected 1"),
    ("rotated", "not north-up with square posts"),
    ("empty", "no finite height"),
    ("garbage", "cannot be read"),
])
def test_a_dtm_that_cannot_be_used_is_refused_naming_the_file(tmp_path, case, message):
    heights, _, _ = _plane()
    path = tmp_path / f"{case}.tif"
    if case == "crs":
        _write(path, heights, crs="EPSG:32633")
    elif case == "empty":
        _write(path, np.full_like(heights, np.nan))
    elif case == "garbage":
        path.write_bytes(b"not a tiff")
    else:
        from rasterio.transform import Affine

        t = (Affine(POST, 0.3, WEST, 0.0, -POST, NORTH) if case == "rotated"
             else Affine(POST, 0.0, WEST, 0.0, -POST, NORTH))
        count = 2 if case == "bands" else 1
        with rasterio.open(path, "w", driver="GTiff", width=40, height=30, count=count,
                           dtype="float32", crs="EPSG:32719", transform=t) as dst:
            dst.write(np.repeat(heights[None].astype(np.float32), count, axis=0))
    with pytest.raises(DtmFormatError, match=message) as err:
        read_dtm(path, FRAME)
    assert str(path) in str(err.value)


def test_unknown_variance_is_not_an_estimate():
    assert not z_is_estimated(UNKNOWN_VARIANCE_M2)
    assert not z_is_estimated(float("nan")) and not z_is_estimated(float("inf"))
    assert z_is_estimated(0.1) and z_is_estimated(0.0)

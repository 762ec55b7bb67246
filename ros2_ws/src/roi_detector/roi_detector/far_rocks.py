"""Rocks beyond the reach of the elevation map: dark blobs in the left image, tracked
across pairs and triangulated from the rover's own motion.

A fixed forward camera sees a rock that the route passes 10-15 m beside only from 17-26 m
away, where a stereo point's range error (``Z^2 / (fx B) * sigma_d``: 1.3 m at 20 m for
the 0.2 m baseline) smears it over the ground around it: the elevation map, which stops at
``max_range_m``, never measures it. Its bearing, though, is known to a pixel, and while
the rover drives past, the bearing turns: rays from camera positions metres apart
intersect at the rock (motion stereo, a baseline of metres instead of 0.2 m). With its
range known, the rock's angular size gives its width and height. This is the paper's
per-image detection (Sec. 4.2: ROIs found in each image, tracked as they enter and leave
the view) with the rover's odometry as the stereo baseline.

- **Blobs** (:func:`dark_blobs`): pixels darker than ``DARK_VALUE`` relative to the
  median brightness of the ground the pair sees (the same test as the map's dark rock
  seeds: desert rocks are varnished, the soil is not), in connected components; each
  blob's stereo disparity gives a rough range (metres off at 20 m), enough to keep the
  blobs ``min_depth_m`` to ``max_depth_m`` deep and to start a track.
- **Tracks** (:class:`FarRockTracker`): a blob joins the track whose rock projects
  nearest to it in the pair's image (within ``GATE_PX`` plus half the blob), each track
  keeping the odom ray of every view; the rock's position is the weighted least-squares
  intersection of those rays' bearings on the ground plane (across each bearing, the
  bearing error at its range; along it, the blob's stereo range at its error), its height
  the median of the rays at that range. When the track closes, the fit is redone with
  the bearing and range errors that its own residuals give (variance component
  estimation): the priors are the same for every track, the blobs are not.
- **Measurement**: at the triangulated range, per view, width = angular width x range and
  height = range x (tan elevation of the blob's top - tan elevation of its bottom), their
  medians over the views; area = pi/4 width^2 (the footprint seen edge-on is unknown).
- **A candidate** when the views span ``min_parallax_deg`` of bearing, the rays meet
  within ``MAX_RESIDUAL_PX`` (a static object: a blob that slides with the view is not
  one), the rock was seen from at most ``MAX_NEAREST_M``, and its height and area pass
  the paper's rover thresholds (Sec. 4.2).
- **Classification** (Sec. 4.3): with a classifier, the paper's "Rock Rover" decides
  which tracks are rocks (every track that passes the geometric tests, in place of the
  size thresholds: from 12-40 m a rock's dark blob gives its area at a median 0.62 of
  the truth, too scattered for the thresholds), on
  :func:`far_rock_features`: the paper's appearance features (RGB, HSV, gray, Gabor,
  weighted entropy) of its blob and the ground ring around it, the median over its
  views, with the track's geometry.

Pure numpy/OpenCV: no ROS, no truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import cv2
import numpy as np

from roi_detector.candidates import Region
from roi_detector.features import PAPER_GROUPS, feature_halo_px, feature_names, region_features
from roi_detector.metrics import weighted_entropy
from roi_detector.stereo import StereoCamera

#: Weighted-entropy window of a blob's appearance (pixels, full resolution; the rover
#: metrics' 7 px at half resolution is 14 px here, but a far blob is 12-200 px).
ENTROPY_SIZE_PX: Final = 7
#: The track geometry that :func:`far_rock_features` adds to the appearance.
GEOMETRY_NAMES: Final = ("far_log_width_m", "far_height_m", "far_log_nearest_m",
                         "far_log_views", "far_parallax_deg", "far_residual_px",
                         "far_relief", "far_dark_value", "far_dark_saturation")


#: Blob pixels are darker than this, relative to the median value (HSV) of the ground
#: the pair sees (the map's ROCK_DARK_VALUE).
DARK_VALUE = 0.55
#: And less saturated than this, relative to the ground's median saturation: a shadow
#: keeps the soil's colour (only darker), a rock is greyer.
MAX_SATURATION = 0.9
#: Smallest blob, pixels.
MIN_BLOB_PX = 12
#: Association gate beyond half the blob's size, pixels.
GATE_PX = 6.0
#: A track not seen in this many consecutive pairs where it is in view is closed.
MAX_MISSED = 3
#: Least spread of the bearings of a track that the Rock Rover decides, deg (the spread
#: is one of its features; with the stereo ranges at their estimated errors a track seen
#: over a few degrees is placed as well as the others).
CLASSIFIED_MIN_PARALLAX_DEG = 0.0
#: 1-sigma error of a blob's centroid, pixels: the prior of the fit while the track is
#: followed.
BEARING_SIGMA_PX = 1.0
#: RMS distance of the views' rays from the triangulated rock, in pixels at each view's
#: range, of a rock.
MAX_RESIDUAL_PX = 2.5
#: The paper's rover rock height and area thresholds (m, m^2), of a far-rock candidate.
MIN_HEIGHT_M = 0.25
MIN_AREA_M2 = 0.6
#: 1-sigma error of a blob's median disparity, which places it along its ray, pixels:
#: the prior of the fit while the track is followed.
DISPARITY_SIGMA_PX = 0.5
#: The bearing scale that variance component estimation gives a closed track is at least
#: this share of BEARING_SIGMA_PX (a short track's residuals can be near zero by chance).
MIN_BEARING_SCALE = 0.5
#: 1 sigma of where the dark blob sits on the rock (its dark, shaded part, not its
#: outline), times the rock's measured width, added to the position covariance.
CENTRE_SIGMA_WIDTH = 0.5
#: 1-sigma odometry error per metre between the views (relative drift across the track),
#: added to the position covariance.
ODOM_SIGMA_PER_M = 0.01
#: A rock must have been seen from at most this far, m (at 30 m a 0.25 m height is 4
#: pixels).
MAX_NEAREST_M = 30.0
#: Tracks whose rocks are closer than this are one rock, m; and a far rock this close to
#: a map rock is that rock.
MERGE_M = 1.5
#: A rover that moved less than this since a track's latest view stands still: a mast
#: that turned the camera away then does not close the track, m.
STILL_M = 0.05


@dataclass(frozen=True)
class FarRockConfig:
    """What a user tunes of the far rocks (metres, pixels of the full-resolution image).

    Attributes:
        min_depth_m: blobs nearer than this (stereo depth) are the elevation map's, m.
        max_depth_m: blobs farther than this are not followed, m.
        min_views: least views of a rock.
        min_parallax_deg: least spread of the bearings of a far-rock candidate's views
            (the rules without a classifier), deg.
        min_score: a track the Rock Rover decides is a rock when its probability is
            above this.
    """

    min_depth_m: float = 12.0
    max_depth_m: float = 40.0
    min_views: int = 6
    min_parallax_deg: float = 4.0
    min_score: float = 0.5

    def passes_geometry(self, parallax_deg, residual_px, nearest_m, classified=False):
        """The geometric tests of a far track (bearing spread, ray residual, nearest
        range): scalars or arrays, elementwise. ``classified``: those of a track that
        the classifier decides in place of the size thresholds
        (:data:`CLASSIFIED_MIN_PARALLAX_DEG`)."""
        least = CLASSIFIED_MIN_PARALLAX_DEG if classified else self.min_parallax_deg
        return (np.asarray(parallax_deg) >= least) & \
            (np.asarray(residual_px) <= MAX_RESIDUAL_PX) & \
            (np.asarray(nearest_m) <= MAX_NEAREST_M)


@dataclass
class Blob:
    """One dark blob of a left image.

    Attributes:
        uv: centroid (pixels).
        box: ``(u0, v0, u1, v1)`` inclusive pixel bounds.
        n_px: pixel count.
        depth_m: median stereo depth of its pixels (blobs with fewer than 3 are dropped).
        appearance: with ``describe``: the paper's appearance features of the blob
            (:func:`blob_appearance`), then its value and saturation relative to the
            ground's (2 more entries).
    """

    uv: np.ndarray
    box: tuple[int, int, int, int]
    n_px: int
    depth_m: float
    appearance: np.ndarray | None = field(default=None, repr=False)


def far_feature_names() -> tuple[str, ...]:
    """Names of :func:`far_rock_features`' entries."""
    return feature_names(PAPER_GROUPS) + GEOMETRY_NAMES


def blob_appearance(rgb_u8: np.ndarray, gray_u8: np.ndarray, footprint: np.ndarray,
                    box: tuple[int, int, int, int]) -> np.ndarray:
    """The paper's appearance features (RGB, HSV, gray, Gabor, weighted entropy;
    :func:`roi_detector.features.region_features`) of one blob, against the ring of
    ground around it, on a crop of the full-resolution image.

    Args:
        rgb_u8: (H, W, 3) uint8 RGB image.
        gray_u8: (H, W) uint8 gray of it.
        footprint: the blob's pixels in its box (bool, ``(v1 - v0 + 1, u1 - u0 + 1)``).
        box: the blob's ``(u0, v0, u1, v1)`` inclusive bounds.
    """
    h, w = gray_u8.shape
    m = feature_halo_px() + ENTROPY_SIZE_PX
    u0, v0, u1, v1 = box
    r0, c0, r1, c1 = max(v0 - m, 0), max(u0 - m, 0), min(v1 + 1 + m, h), min(u1 + 1 + m, w)
    gray = np.ascontiguousarray(gray_u8[r0:r1, c0:c1])
    rgb01 = rgb_u8[r0:r1, c0:c1].astype(np.float32) / 255.0
    foot = np.asarray(footprint, bool)
    rows, cols = np.nonzero(foot)
    pos = np.column_stack([cols, rows]).astype(float)
    cov = np.cov(pos.T) + np.eye(2) / 12 if len(pos) > 1 else np.eye(2) / 12
    region = Region(float(rows.mean() + v0 - r0), float(cols.mean() + u0 - c0), 0.0,
                    int(foot.sum()), cov, (v0 - r0, u0 - c0, v1 + 1 - r0, u1 + 1 - c0), 0.0,
                    0, foot)
    return region_features(region, rgb01, gray, weighted_entropy(gray, ENTROPY_SIZE_PX),
                           PAPER_GROUPS)


# 10. Dark blobs (docs/roi_detector.md, Method).
def dark_blobs(bgr: np.ndarray, disp: np.ndarray, camera: StereoCamera,
               cfg: FarRockConfig = FarRockConfig(), describe: bool = False) -> list[Blob]:
    """Dark blobs of a left image between ``min_depth_m`` and ``max_depth_m`` deep, not
    touching the image border.

    Args:
        bgr: the left image (full resolution).
        disp: its disparity (full-resolution pixels) on any integer subsampling of the
            image grid (the pipeline's half-resolution grid), NaN where invalid.
        camera: the stereo model.
        describe: also compute each blob's appearance (for the classifier).
    """
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    sat, value = hsv[..., 1].astype(np.float32), hsv[..., 2].astype(np.float32)
    step = max(1, round(bgr.shape[0] / disp.shape[0]))
    valid = np.isfinite(disp)
    if valid.sum() < 100:
        return []
    grid = (slice(None, valid.shape[0] * step, step), slice(None, valid.shape[1] * step, step))
    ground_value = float(np.median(value[grid][valid]))
    ground_sat = float(np.median(sat[grid][valid]))
    dark = (value < DARK_VALUE * max(ground_value, 1.0)) & \
        (sat < MAX_SATURATION * max(ground_sat, 1.0))
    n, lab, stats, cents = cv2.connectedComponentsWithStats(dark.astype(np.uint8), connectivity=8)
    out = []
    if describe:
        rgb_u8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        gray_u8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    for k in range(1, n):
        x0, y0, w, h, area = stats[k]
        # Too small, or cut by the image border (its centroid and size are not the rock's).
        if area < MIN_BLOB_PX or x0 == 0 or y0 == 0 or x0 + w == bgr.shape[1] or \
                y0 + h == bgr.shape[0]:
            continue
        # The disparity grid's rows and columns inside the blob's box (grid row i is
        # image row i * step), and the labels at those same image pixels.
        r0, c0 = -(-y0 // step), -(-x0 // step)
        r1 = min((y0 + h - 1) // step, disp.shape[0] - 1)
        c1 = min((x0 + w - 1) // step, disp.shape[1] - 1)
        if r1 < r0 or c1 < c0:
            continue
        sub = lab[r0 * step:r1 * step + 1:step, c0 * step:c1 * step + 1:step]
        d = disp[r0:r1 + 1, c0:c1 + 1]
        d = d[(sub == k) & np.isfinite(d)]
        if d.size < 3:
            continue
        depth = camera.fxb / float(np.median(d))
        if not cfg.min_depth_m <= depth <= cfg.max_depth_m:
            continue
        blob = Blob(np.asarray(cents[k], float), (int(x0), int(y0), int(x0 + w - 1),
                                                  int(y0 + h - 1)), int(area), depth)
        if describe:
            box = lab[y0:y0 + h, x0:x0 + w] == k
            blob.appearance = np.concatenate([
                blob_appearance(rgb_u8, gray_u8, box, blob.box),
                [float(value[y0:y0 + h, x0:x0 + w][box].mean()) / max(ground_value, 1.0),
                 float(sat[y0:y0 + h, x0:x0 + w][box].mean()) / max(ground_sat, 1.0)]])
        out.append(blob)
    return out


@dataclass
class _View:
    t: float
    centre: np.ndarray  # camera centre, odom (3,)
    ray: np.ndarray  # unit ray of the blob centroid, odom (3,)
    width_rad: float  # angular width
    tan_top: float  # tan of the elevation of the blob's top and bottom (odom, gravity)
    tan_bottom: float
    travelled: float  # odometry path length at the view
    range_m: float  # stereo range of the blob along the ground (NaN: none)
    range_sigma_m: float
    appearance: np.ndarray | None = None  # the blob's (Blob.appearance)


@dataclass
class FarTrack:
    """A dark blob followed across pairs (odom)."""

    id: int
    views: list[_View] = field(default_factory=list)
    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    missed: int = 0
    odom_cov: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    #: The camera of its latest view and the rover's position then (odom): a mast that
    #: looks away while the rover stands does not close it.
    camera: StereoCamera | None = None
    rover_xy: np.ndarray | None = None

    # 12. Triangulation (and ``refine``: re-weighted by the track's own errors).
    def triangulate(self, sigma_rad: float, range_scale: float = 1.0) -> np.ndarray:
        """Least-squares intersection of the views' bearings on the ground plane (across
        each bearing: the bearing error ``sigma_rad`` at the range; along it: the stereo
        range, at its error times ``range_scale``); the height: the median of the views'
        centroid rays at that range. Returns the fit's (2, 2) information matrix."""
        a = np.zeros((2, 2))
        b = np.zeros(2)
        for v in self.views:
            c, d = v.centre[:2], v.ray[:2] / max(float(np.linalg.norm(v.ray[:2])), 1e-9)
            rng = max(float(np.linalg.norm(self.point[:2] - c)), 1.0)
            along = np.outer(d, d)
            info = (np.eye(2) - along) / (rng * sigma_rad) ** 2
            m = c
            if np.isfinite(v.range_m):
                info = info + along / (v.range_sigma_m * range_scale) ** 2
                m = c + d * v.range_m
            a += info
            b += info @ m
        if np.linalg.cond(a) < 1e8:
            xy = np.linalg.solve(a, b)
            z = [v.centre[2] + np.linalg.norm(xy - v.centre[:2]) * v.ray[2] /
                 max(float(np.linalg.norm(v.ray[:2])), 1e-9) for v in self.views]
            self.point = np.array([xy[0], xy[1], float(np.median(z))])
        return a

    def refine(self, sigma_rad: float, min_scale: float, iterations: int = 3
               ) -> tuple[float, np.ndarray]:
        """Variance component estimation: re-fit with the bearing error and the stereo
        range scale that the views' own residuals give (each the RMS of its normalised
        residuals, corrected for the fitted degrees of freedom), ``iterations`` times.
        The bearing error stays at least ``min_scale`` x ``sigma_rad``.

        Returns:
            the estimated bearing error (rad) and the last fit's information matrix.
        """
        sb, sr = sigma_rad, 1.0
        info = self.triangulate(sb, sr)
        n = len(self.views)
        dof = n / max(n - 1, 1)
        for _ in range(iterations):
            eb, er = [], []
            for v in self.views:
                d = v.ray[:2] / max(float(np.linalg.norm(v.ray[:2])), 1e-9)
                off = self.point[:2] - v.centre[:2]
                rng = max(float(np.linalg.norm(off)), 1.0)
                eb.append((d[0] * off[1] - d[1] * off[0]) / rng)
                if np.isfinite(v.range_m):
                    er.append((float(off @ d) - v.range_m) / v.range_sigma_m)
            sb = max(float(np.sqrt(np.mean(np.square(eb)) * dof)), min_scale * sigma_rad)
            if er:
                sr = max(float(np.sqrt(np.mean(np.square(er)) * dof)), 1e-3)
            info = self.triangulate(sb, sr)
        return sb, info


@dataclass
class FarRock:
    """A track, measured (odom).

    Attributes:
        track_id: the track's id.
        xy, z: the triangulated rock.
        cov: (2, 2) x-y covariance: ray geometry at the bearing error, scaled by the
            residual, plus the relative odometry drift over the views and the odometry
            covariance at the last view.
        width_m, height_m, area_m2: the rock's size (see the module).
        n_views, parallax_deg, residual_px, nearest_m: what the rock tests
            read.
        candidate: every rule of a candidate passed (Sec. 4.2).
        passed: what the LN gets: without a classifier, a candidate; with one, a track
            it decides (every track that passes the geometric tests) that it scores a
            rock.
        features: :func:`far_rock_features` (None when the blobs carry no appearance).
        score: the Rock Rover's score (NaN: no classifier, or a track it does not
            decide).
    """

    track_id: int
    xy: np.ndarray
    z: float
    cov: np.ndarray
    width_m: float
    height_m: float
    area_m2: float
    n_views: int
    parallax_deg: float
    residual_px: float
    nearest_m: float
    candidate: bool
    passed: bool
    features: np.ndarray | None = field(default=None, repr=False)
    score: float = float("nan")


def far_rock_features(appearance: list[np.ndarray], width_m: float, height_m: float,
                      nearest_m: float, n_views: int, parallax_deg: float,
                      residual_px: float) -> np.ndarray:
    """A far rock's classifier features (:func:`far_feature_names`): the median of its
    views' blob appearance, then the track's geometry (log width, height, log nearest
    range, log views, bearing spread, ray residual, height over width) and the blob's
    relative value and saturation."""
    app = np.median(np.stack(appearance), axis=0)
    geo = [np.log(max(width_m, 1e-3)), height_m, np.log(max(nearest_m, 0.1)),
           np.log(n_views), parallax_deg, residual_px, height_m / max(width_m, 1e-3)]
    return np.concatenate([app[:-2], geo, app[-2:]]).astype(np.float32)


class FarRockTracker:
    """Dark blobs of every pair -> tracks -> triangulated rocks (odom).

    A track is measured once, when it closes (its rock left the view, or was missed in
    ``max_missed`` pairs that had it in view): :meth:`rocks` are those of closed tracks.

    Args:
        cfg: parameters.
        classifier: the Rock Rover's vote share of (N, F) :func:`far_rock_features`
            (the blobs must then carry their appearance); None: the rules alone decide.
    """

    def __init__(self, cfg: FarRockConfig = FarRockConfig(),
                 classifier: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self.cfg = cfg
        self.classifier = classifier
        self.tracks: list[FarTrack] = []
        self.measured: list[FarRock] = []
        self._next = 1
        self._travelled = 0.0
        self._last_xy: np.ndarray | None = None
        self._fx = 1.0

    # 11. Tracks: each blob joins the open track whose rock projects nearest.
    def add(self, blobs: list[Blob], t: float, r_odom_base: np.ndarray,
            t_odom_base: np.ndarray, camera: StereoCamera,
            odom_cov: np.ndarray | None = None) -> None:
        """Associate one pair's blobs with the open tracks (pose: base_link in odom, with
        its x-y covariance)."""
        r_ob, t_ob = np.asarray(r_odom_base, float), np.asarray(t_odom_base, float)
        self._fx = camera.fx
        if self._last_xy is not None:
            self._travelled += float(np.linalg.norm(t_ob[:2] - self._last_xy))
        self._last_xy = t_ob[:2].copy()
        cov = np.zeros((2, 2)) if odom_cov is None else np.asarray(odom_cov, float)
        r_oc = r_ob @ camera.r_base_cam
        centre = r_ob @ camera.t_base_cam + t_ob
        # Where each open track's rock falls in this image.
        pred = np.full((len(self.tracks), 2), np.nan)
        for i, tr in enumerate(self.tracks):
            pc = r_oc.T @ (tr.point - centre)
            if pc[2] > 1.0:
                pred[i] = (camera.fx * pc[0] / pc[2] + camera.cx,
                           camera.fy * pc[1] / pc[2] + camera.cy)
        taken = np.zeros(len(self.tracks), bool)
        sigma = BEARING_SIGMA_PX / camera.fx
        new = []
        for blob in sorted(blobs, key=lambda b: -b.n_px):
            half = 0.5 * np.array([blob.box[2] - blob.box[0] + 1, blob.box[3] - blob.box[1] + 1])
            d = np.abs(pred - blob.uv)
            ok = ~taken & np.all(d <= half + GATE_PX, axis=1)
            view = self._view(blob, t, r_oc, centre, camera)
            if ok.any():
                i = int(np.flatnonzero(ok)[np.argmin(np.hypot(*d[ok].T))])
                taken[i] = True
                tr = self.tracks[i]
                tr.views.append(view)
                tr.missed = 0
                tr.odom_cov = cov
                tr.camera, tr.rover_xy = camera, t_ob[:2].copy()
                tr.triangulate(sigma)
            else:
                start = centre + view.ray * blob.depth_m / max(float(view.ray @ r_oc[:, 2]), 0.1)
                new.append(FarTrack(self._next, [view], start, odom_cov=cov, camera=camera,
                                    rover_xy=t_ob[:2].copy()))
                self._next += 1
        keep = []
        for i, tr in enumerate(self.tracks):
            if not taken[i]:
                in_view = bool(np.isfinite(pred[i]).all() and 0 <= pred[i, 0] < camera.width
                               and 0 <= pred[i, 1] < camera.height)
                tr.missed += 1 if in_view else 0
                if not in_view and self._looked_away(tr, camera, t_ob):
                    keep.append(tr)  # a mast panned at a stop: the rock is not gone
                    continue
                if tr.missed > MAX_MISSED or not in_view:
                    self._close(tr)
                    continue
            keep.append(tr)
        self.tracks = keep + new

    @staticmethod
    def _looked_away(tr: FarTrack, camera: StereoCamera, t_ob: np.ndarray) -> bool:
        """Whether the camera left ``tr``'s rock out of view only because a mast turned it
        while the rover stood (within :data:`STILL_M` of where the track was last seen):
        the track stays open for the views after the panorama."""
        if tr.camera is None or tr.camera is camera or tr.rover_xy is None:
            return False
        return float(np.linalg.norm(t_ob[:2] - tr.rover_xy)) < STILL_M and \
            not camera.same_mount(tr.camera)

    def close_all(self) -> None:
        """Close every open track (end of the drive)."""
        for tr in self.tracks:
            self._close(tr)
        self.tracks = []

    def _close(self, tr: FarTrack) -> None:
        if len(tr.views) >= self.cfg.min_views:
            self.measured.append(self._measure(tr))

    def _view(self, blob: Blob, t: float, r_oc: np.ndarray, centre: np.ndarray,
              camera: StereoCamera) -> _View:
        def ray(u: float, v: float) -> np.ndarray:
            d = r_oc @ np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0])
            return d / np.linalg.norm(d)

        u0, v0, u1, v1 = blob.box
        uc, vc = blob.uv
        left, right = ray(u0 - 0.5, vc), ray(u1 + 0.5, vc)
        top, bottom = ray(uc, v0 - 0.5), ray(uc, v1 + 0.5)

        def tan_el(d: np.ndarray) -> float:
            return float(d[2] / max(np.hypot(d[0], d[1]), 1e-9))

        centroid = ray(uc, vc)
        # Stereo range along the ray; its error from the disparity error of the blob's
        # median disparity.
        cos = float(centroid @ r_oc[:, 2])
        rng = blob.depth_m / max(cos, 0.1) * float(np.linalg.norm(centroid[:2]))
        sigma = rng * blob.depth_m / camera.fxb * DISPARITY_SIGMA_PX
        return _View(t, centre, centroid, float(np.arccos(np.clip(left @ right, -1, 1))),
                     tan_el(top), tan_el(bottom), self._travelled,
                     rng, sigma,
                     blob.appearance)

    # 14. The far rocks' Rock Rover decides every measured track.
    def rocks(self, classified: bool = True) -> list[FarRock]:
        """The closed tracks that pass every rock test, one per rock: a rock whose blob
        was followed by several tracks (lost and found again) is the best-viewed of them,
        the others within :data:`MERGE_M` dropped. ``classified=False``: the candidates, as
        if there were no classifier (benchmarks)."""
        kept: list[FarRock] = []
        for r in sorted((r for r in self.measured if (r.passed if classified else r.candidate)),
                        key=lambda r: -r.n_views):
            if all(np.linalg.norm(r.xy - k.xy) > MERGE_M for k in kept):
                kept.append(r)
        return kept

    # 13. Measurement and geometry of a closed track.
    def _measure(self, tr: FarTrack) -> FarRock:
        cfg = self.cfg
        sigma = BEARING_SIGMA_PX / self._fx
        # Variance component estimation: the track placed with the bearing and stereo
        # range errors its own residuals give.
        fitted = tr.refine(sigma, MIN_BEARING_SCALE)
        c = np.array([v.centre for v in tr.views])
        rays = np.array([v.ray for v in tr.views])
        rho = np.maximum(np.hypot(*(tr.point[:2] - c[:, :2]).T), 0.5)
        rng = np.maximum(np.linalg.norm(tr.point - c, axis=1), 0.5)
        # Distance of the rock from each bearing (ground plane), in pixels at that range.
        d2 = rays[:, :2] / np.maximum(np.linalg.norm(rays[:, :2], axis=1), 1e-9)[:, None]
        off = tr.point[:2] - c[:, :2]
        perp = np.abs(off[:, 0] * d2[:, 1] - off[:, 1] * d2[:, 0])
        residual = float(np.sqrt(np.mean((perp / rho) ** 2))) * self._fx
        bearings = np.arctan2(rays[:, 1], rays[:, 0])
        spread = float(np.rad2deg(np.ptp(np.unwrap(bearings))))
        widths = np.array([v.width_rad for v in tr.views]) * rho
        heights = np.array([v.tan_top - v.tan_bottom for v in tr.views]) * rho
        height = float(np.median(heights))
        width = float(np.median(widths))
        area = float(np.pi / 4 * width * width)
        # The fit's own covariance (bearings and stereo ranges at their estimated errors)
        # and where the blob sits on the rock.
        cov = np.linalg.pinv(fitted[1]) + np.eye(2) * (CENTRE_SIGMA_WIDTH * width) ** 2
        # The relative odometry drift over the views, the odometry at the last view.
        span = tr.views[-1].travelled - tr.views[0].travelled
        cov = cov + np.eye(2) * (ODOM_SIGMA_PER_M * span) ** 2 + tr.odom_cov
        geometric = bool(cfg.passes_geometry(spread, residual, rng.min()))
        candidate = geometric and height > MIN_HEIGHT_M and area > MIN_AREA_M2
        decidable = bool(cfg.passes_geometry(spread, residual, rng.min(), classified=True))
        app = [v.appearance for v in tr.views if v.appearance is not None]
        feats = far_rock_features(app, width, height, float(rng.min()), len(tr.views),
                                  spread, residual) if app else None
        score, passed = float("nan"), candidate
        if self.classifier is not None:
            # The Rock Rover decides, in place of the size thresholds, every track that
            # passed its geometric tests.
            passed = False
            if decidable:
                if feats is None:
                    raise ValueError("far rocks: a classifier needs the blobs' appearance "
                                     "(dark_blobs(describe=True))")
                score = float(self.classifier(feats[None])[0])
                passed = score > cfg.min_score
        return FarRock(tr.id, tr.point[:2].copy(), float(tr.point[2]), cov, width, height,
                       area, len(tr.views), spread, residual, float(rng.min()), candidate,
                       passed, feats, score)

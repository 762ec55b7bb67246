"""A local elevation map of the drive (odom), built from every stereo pair, and the rocks
and outcrops found in it.

The paper detects ROIs in each rover image and tracks them. One view of a rock 6-15 m
ahead, seen by a 45 deg camera, shows its front flank only, and its area and height from
that view swing by a factor of 3 from pair to pair. Rovers have long fused their stereo
into a height map of the terrain around them (MER's GESTALT, Maimone et al. 2007); this
module does that, then measures ROIs the way the orbital catalogue defines them: top-down
footprint area, and height above the ground around them.

- **Integration**: every stereo point is placed in odom with the pair's odometry pose and
  accumulated per cell (:data:`CELL_M`) as an inverse-variance weighted mean height, the
  variance being the vertical part of the stereo range error (``Z^2 / (fx B) * sigma_d``
  along the ray). A rolling window centred near the rover holds the map: cells that fall
  out of it are forgotten (what was found there stays in the ROI list).
- **Ground**: a grey-scale opening of the height map (a square ``GROUND_WINDOW_M`` wide,
  wider than the largest rock), smoothed: the low envelope that follows terrain swells
  but not rocks.
- **Rocks**: dark cells standing > ``rock_seed_height_m`` above the ground, grown down
  to ``ROCK_GROW_HEIGHT_M`` over dark cells (hysteresis), one region per peak; kept when
  the region's height above the
  ring of ground around it exceeds the paper's 0.25 m and the convex hull of its cells
  (a rock's far side is seen late or never) exceeds the paper's 0.6 m^2, and its shape is
  a rock's (:func:`rock_shape_reason`: not taller than wide, as a wall or a box is, and
  not a strip); the map rocks' Rock Rover of the rover model decides which are rocks.
- **Outcrops**: grey tabular slabs. Each pair's colour saturation and value are
  normalised by the pair's medians (auto-exposure and sun cancel) and mapped like the
  height, averaged over a small neighbourhood (``OUTCROP_COLOUR_SIGMA_M``); connected
  cells far less saturated than the soil (``OUTCROP_MAX_SATURATION``), not dark
  (``OUTCROP_MIN_VALUE``) and not standing ``MAX_OUTCROP_HEIGHT_M`` above the ground,
  over > 5.5 m^2 (the paper's threshold), are the candidates; the map outcrops' Outcrop
  Rover of the rover model decides which are outcrops. An outcrop keeps the
  largest footprint a round measured (a slab wider than the cells a round examines is
  cut at their border once the rover has passed).
- **Persistence** (the tracking of the paper's Sec. 4.2, done on the map): each detection
  round's regions are associated with the ROIs found so far by centre distance
  (``max(1 m, half the major axis)``); an ROI counts the rounds that found it and the
  rounds that re-examined its cells, and is reported while found in at least
  ``min_hit_ratio`` of them and in ``min_rounds`` (a stereo artefact flickers, a rock
  stays); its measurement is the latest (the map has integrated every view so far; an
  outcrop's, the largest), its observation count the number of stereo pairs that saw
  its cells (at least: the most that saw one of them), which the Local Network's
  ``min_obs`` applies to.

Pure numpy/scipy/OpenCV: no ROS, no truth.
"""

from __future__ import annotations

import functools
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from roi_network.records import OUTCROP, ROCK, empty_records

#: Map cell side, m.
CELL_M = 0.1
#: Side of the rolling map window around the rover, m.
WINDOW_M = 64.0
#: 1-sigma disparity error that weights each stereo point, pixels.
DISPARITY_SIGMA_PX = 0.5
#: Smallest vertical 1-sigma of a point (texture, rendering, JPEG), m.
HEIGHT_FLOOR_M = 0.02
#: Terrain gradient that turns the horizontal part of a point's range error into a height
#: error of the cell it lands in: far views of a rock face land in the ground around it
#: and weigh less (0.5, a rock's flank: a view from 15 m weighs ~1/40 of one from 6 m).
PLACEMENT_GRADIENT = 0.5
#: Side of the grey opening that finds the ground (wider than the largest rock), m.
GROUND_WINDOW_M = 3.2
#: The ground is found on cells this large, m, each at GROUND_PERCENTILE of its cells.
GROUND_CELL_M = 0.4
#: Percentile of the fine cells' heights that a ground cell takes.
GROUND_PERCENTILE = 25.0
#: A rock region grows over cells this high above the ground, m.
ROCK_GROW_HEIGHT_M = 0.1
#: Larger rock regions are terrain, not one rock, m^2.
ROCK_MAX_AREA_M2 = 9.0
#: A rock region's major axis is at most this many GROUND_WINDOW_M (a longer region is a
#: ridge or a crest, which the ground's opening keeps in its narrow direction only).
ROCK_MAX_LENGTH_WINDOWS = 1.5
#: Least observed fraction of the ring of ground around a rock region to measure its
#: height (a rock's far side is hidden).
ROCK_MIN_RING_SEEN = 0.25
#: Least height over equivalent diameter (footprint at half height) of a rock.
ROCK_MIN_RELIEF_RATIO = 0.25
#: Seed cells closer than this are one peak of the watershed, m.
ROCK_PEAK_MERGE_M = 0.3
#: A rock region's footprint: its cells above this fraction of its peak height.
ROCK_FOOTPRINT_FRACTION = 0.35
#: Rock seeds, and the low cells a rock grows over, are darker than this relative value
#: (the cell's brightness over the median of the pairs that saw it): desert rocks are
#: darker than the soil, stereo noise and terrain bumps are soil-coloured.
ROCK_DARK_VALUE = 0.55
#: A region with no dark seed is a rock candidate when a cell stands this high above the
#: ground less its spread across views, and must then measure this high, m.
ROCK_PALE_SEED_HEIGHT_M = 0.45
#: Cells with less accumulated weight are unobserved, 1/m^2.
MIN_CELL_WEIGHT = 3.0
#: Cells seen by fewer stereo pairs are unobserved.
MIN_PAIRS = 3
#: Cells whose height spreads more than this across the pairs that saw them are
#: unobserved (a stereo mismatch of one view), m.
MAX_CELL_SD_M = 0.4
#: Cap of one pair's weight in a cell, 1/m^2.
MAX_PAIR_WEIGHT = 2500.0
#: 1-sigma error of a map ROI's centre (cell size, partial views), m.
CENTRE_SIGMA_M = 0.15

# What a rock is not (:func:`rock_shape_reason`), tested on each rock region that passed
# the paper's area and height and the relief ratio, before the Rock Rover. A boulder is a
# compact blob (the paper's Hessian blobs), about half as high as it is wide (height over
# diameter 0.3-0.8 on Mars, Golombek et al. 2008); a wall, a post, a box or a board on its
# edge is a vertical face, and the map's mean heights halve it: its cells hold points
# from its foot to its top. On the demo drive (quick, truth odometry) the regions of true
# rocks measured top over width 0.39-1.80 and minor over major axis 0.33-0.95.
#: A rock's top (:data:`TOP_SIGMAS`) is at most this many times its width (the
#: footprint's minor axis, which the stereo smear widens by 0.3-0.4 m at 10-15 m).
ROCK_MAX_TOP_OVER_WIDTH = 2.0
#: A rock's footprint is a blob: its minor axis is at least this fraction of its major
#: axis (a wall or a fence seen along its length maps as a strip).
ROCK_MIN_MINOR_OVER_MAJOR = 0.25
#: A cell's top: its mean height plus this many within-cell spreads (points spread evenly
#: from the foot of a face to its top reach sqrt(3) sigma above their mean).
TOP_SIGMAS = float(np.sqrt(3.0))
#: The reasons :func:`rock_shape_reason` gives (counted per reason in ``rejected``).
SHAPE_REASONS = ("taller than wide", "elongated")


def rock_shape_reason(top_m: float, major_m: float, minor_m: float) -> str | None:
    """Why a rock region is not a rock by its shape, or None when it is a rock's.

    Args:
        top_m: the region's top above the ground around it (95th percentile of its
            cells' mean heights plus :data:`TOP_SIGMAS` within-cell spreads), m.
        major_m, minor_m: the footprint's full axes, m.

    Returns:
        ``"taller than wide"`` (top over minor axis above
        :data:`ROCK_MAX_TOP_OVER_WIDTH`: a wall, a post, a tall box, a board on its
        edge), ``"elongated"`` (minor over major axis below
        :data:`ROCK_MIN_MINOR_OVER_MAJOR`: a low wall, a fence, a ridge), or None.
    """
    if top_m > ROCK_MAX_TOP_OVER_WIDTH * max(minor_m, 1e-6):
        return "taller than wide"
    if minor_m < ROCK_MIN_MINOR_OVER_MAJOR * major_m:
        return "elongated"
    return None

# The outcrop rule: a map outcrops' Outcrop Rover is trained on its candidates, and a
# rover model records it (MAP_OUTCROP_RULE) so that a map with another rule refuses it.
#: Outcrop cells' colour saturation, relative to the median of the pairs that saw them,
#: is below this (the simulator's outcrops measure 0.36 of the soil's, its gravel 0.58:
#: the Outcrop Rover tells those apart).
OUTCROP_MAX_SATURATION = 0.6
#: And their relative value (brightness) above this (outcrops are grey slabs, pale or
#: not; the complement of ROCK_DARK_VALUE).
OUTCROP_MIN_VALUE = 0.55
#: The paper's rover outcrop area threshold, on the convex hull of the region's cells, m^2.
OUTCROP_MIN_AREA_M2 = 5.5
#: The saturation and value are averaged over a Gaussian this wide before the tests
#: (a slab seen from afar is observed in sparse stripes of cells), m.
OUTCROP_COLOUR_SIGMA_M = 0.2
#: Iterations of the opening that removes specks from the pale mask.
OUTCROP_OPENING = 1
#: A region's cells cover at least this fraction of OUTCROP_MIN_AREA_M2 (a slab seen
#: in part).
OUTCROP_MIN_CELLS_FRACTION = 0.5
#: Outcrops are slabs: regions standing higher than this are not, m.
MAX_OUTCROP_HEIGHT_M = 0.45
#: The outcrop rule a rover model records (``map_outcrop_rule`` in its provenance): a
#: map outcrops' Outcrop Rover trained on another rule's candidates is refused.
MAP_OUTCROP_RULE: dict = {
    "outcrop_max_saturation": OUTCROP_MAX_SATURATION, "outcrop_min_value": OUTCROP_MIN_VALUE,
    "outcrop_min_area_m2": OUTCROP_MIN_AREA_M2,
    "outcrop_colour_sigma_m": OUTCROP_COLOUR_SIGMA_M, "outcrop_opening": OUTCROP_OPENING,
    "outcrop_min_cells_fraction": OUTCROP_MIN_CELLS_FRACTION,
    "max_outcrop_height_m": MAX_OUTCROP_HEIGHT_M}


@dataclass(frozen=True)
class ElevationMapConfig:
    """What a user tunes of the map's ROIs (odom metres unless stated).

    Attributes:
        max_range_m: stereo points farther from the camera than this are not mapped (the
            range error grows as Z^2; with a 45 deg field of view the ROIs the route
            passes 2.5-6 m beside are in view only 6-20 m ahead), m.
        rock_seed_height_m: dark cells this high above the ground seed a rock, m.
        rock_min_height_m: least height of a rock above the plane of the ground around
            it, as the map measures it (the paper's rover threshold), m.
        rock_min_area_m2: least convex-hull footprint of a rock (the paper's rover
            threshold), m^2.
        detect_every: a detection round every this many integrated stereo pairs.
        min_hit_ratio: an ROI is reported while found in at least this fraction of the
            detection rounds that re-examined its cells.
        min_rounds: and in at least this many rounds.
        map_rock_min_score: with a map-rock Rock Rover, a rock is reported while its
            probability at its latest measurement is above this.
        map_outcrop_min_score: with a map outcrops' Outcrop Rover, an outcrop is reported
            while its probability at its kept measurement is above this.
    """

    max_range_m: float = 20.0
    rock_seed_height_m: float = 0.25
    rock_min_height_m: float = 0.25
    rock_min_area_m2: float = 0.6
    detect_every: int = 3
    min_hit_ratio: float = 0.5
    min_rounds: int = 2
    map_rock_min_score: float = 0.5
    map_outcrop_min_score: float = 0.5


#: The features of a map rock region (:meth:`ElevationMap._rock_features`), the map-rock
#: Rock Rover's input: its measurement (height, log area, relief ratio, log major axis,
#: minor over major, cells over hull, the highest cell less its spread, the median spread
#: across views, the median height over the rock's), its colour (median and 10th
#: percentile relative brightness, dark share, the ring's brightness less its own, median
#: relative saturation), its ground (observed share of the ring, the ring plane's
#: residual spread and slope), the dark bumpy share of the cells 0.5-2.5 m around it,
#: whether it is a pale region, and how it was observed (log of the most pairs, of the
#: median pairs and of the median weight of its cells).
MAP_ROCK_FEATURES: tuple[str, ...] = (
    "height_m", "log_area_m2", "relief", "log_major_m", "minor_over_major", "hull_fill",
    "peak_low_m", "spread_m", "median_over_height", "value", "value_p10", "dark_share",
    "ring_contrast", "saturation", "ring_seen", "ring_roughness_m", "ring_slope",
    "clutter_share", "pale", "log_pairs_max", "log_pairs_median", "log_weight_median")


#: The features of a map outcrop region (:meth:`ElevationMap._outcrop_features`), the map
#: outcrops' Outcrop Rover's input: its footprint (log area of the hull, cells over hull,
#: log major axis, minor over major), its relief (95th percentile and median height above
#: the ground, the spread of its heights, the share of its cells with a height observed),
#: its colour per cell (median, 10th and 90th percentile relative saturation and value),
#: the soil around it (the ring 0.3-1.5 m outside: its median saturation and value less
#: the region's), the rocks in and around it (the share of its cells, and of the ring's,
#: that stand above the rocks' grow height and are dark), and how it was observed (log of
#: the most and the median pairs that saw its cells, of the median colour samples).
MAP_OUTCROP_FEATURES: tuple[str, ...] = (
    "log_area_m2", "hull_fill", "log_major_m", "minor_over_major", "height_m",
    "height_median_m", "height_spread_m", "seen_share", "saturation", "saturation_p10",
    "saturation_p90", "value", "value_p10", "value_p90", "ring_saturation_contrast",
    "ring_value_contrast", "rock_share", "ring_rock_share", "log_pairs_max",
    "log_pairs_median", "log_samples_median")


@dataclass
class MapRoi:
    """An ROI of the elevation map (odom)."""

    id: int
    label: int
    xy: np.ndarray
    z: float
    area_m2: float
    height_m: float
    major_m: float
    minor_m: float
    angle_rad: float
    rounds: int = 1
    examined: int = 1
    n_pairs: int = 0
    odom_cov: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    last_t: float = 0.0
    #: A rock's :data:`MAP_ROCK_FEATURES` at its latest measurement, an outcrop's
    #: :data:`MAP_OUTCROP_FEATURES` at its kept one (None: a record built elsewhere).
    features: np.ndarray | None = None
    #: The map rocks' Rock Rover's probability at that measurement, or the map outcrops'
    #: Outcrop Rover's (NaN: not classified).
    score: float = float("nan")


class ElevationMap:
    """Rolling elevation and colour map in odom, with its ROIs.

    Args:
        cfg: parameters.
        rock_classifier: the map-rock Rock Rover, (N, F) :data:`MAP_ROCK_FEATURES` ->
            (N,) probability of a rock; each rock region measured is scored, and a rock
            is reported while its latest score is above ``cfg.map_rock_min_score``
            (:meth:`consistent`). None: the rules alone decide.
        outcrop_classifier: the map outcrops' Outcrop Rover, (N, F)
            :data:`MAP_OUTCROP_FEATURES` -> (N,) probability of an outcrop; an outcrop
            is reported while the score of its kept measurement is above
            ``cfg.map_outcrop_min_score``. None: the rules alone decide.
    """

    def __init__(self, cfg: ElevationMapConfig = ElevationMapConfig(),
                 rock_classifier: Callable[[np.ndarray], np.ndarray] | None = None,
                 outcrop_classifier: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> None:
        self.cfg = cfg
        self.rock_classifier = rock_classifier
        self.outcrop_classifier = outcrop_classifier
        self.n = round(WINDOW_M / CELL_M)
        self.origin = None  # odom x, y of cell (0, 0)'s corner
        # Per cell, over the pairs that saw it: the sum of the pairs' weights, of weight *
        # mean height and of weight * mean height^2 (mean and spread across views), and
        # the number of pairs.
        self.w = np.zeros((self.n, self.n), np.float32)
        self.wz = np.zeros((self.n, self.n), np.float32)
        self.wzz = np.zeros((self.n, self.n), np.float32)
        # ... and of weight * the spread (variance) of the heights within the cell in
        # each pair (a vertical face's cells hold points from its foot to its top).
        self.wvv = np.zeros((self.n, self.n), np.float32)
        self.npairs = np.zeros((self.n, self.n), np.float32)
        # Appearance samples per cell and the sums of their relative saturation and value.
        self.nb = np.zeros((self.n, self.n), np.float32)
        self.bs = np.zeros((self.n, self.n), np.float32)
        self.bv = np.zeros((self.n, self.n), np.float32)
        self.rois: list[MapRoi] = []
        self._next_id = 1
        self._pairs = 0
        self._touched: list[np.ndarray] = []  # cell index boxes touched since last round
        #: Diagnostics: if set, called for every rock region a detection round examines,
        #: ``trace(verdict, centre_xy_odom, measured)``, verdict one of ``small``,
        #: ``ring_unseen``, ``low``, ``area``, ``flat``, a :data:`SHAPE_REASONS` (the
        #: test that rejected it) or ``rock``.
        self.trace: Callable[[str, np.ndarray, dict], None] | None = None
        #: Rock regions rejected by their shape, per reason (:func:`rock_shape_reason`).
        self.rejected: Counter[str] = Counter()

    # -- integration -----------------------------------------------------------------

    def _recentre(self, xy: np.ndarray) -> None:
        """Keep the rover in the central half of the window; shift the grids if not."""
        half = 0.5 * WINDOW_M
        if self.origin is None:
            self.origin = np.floor((xy - half) / CELL_M) * CELL_M
            return
        centre = self.origin + half
        if np.all(np.abs(xy - centre) < 0.25 * WINDOW_M):
            return
        new_origin = np.floor((xy - half) / CELL_M) * CELL_M
        shift = np.round((new_origin - self.origin) / CELL_M).astype(int)
        for name in ("w", "wz", "wzz", "wvv", "npairs", "nb", "bs", "bv"):
            setattr(self, name, _shifted(getattr(self, name), shift))
        self.origin = new_origin

    def integrate(self, points_base: np.ndarray, appearance: np.ndarray | None,
                  r_odom_base: np.ndarray, t_odom_base: np.ndarray,
                  camera_base: np.ndarray, fxb: float) -> None:
        """Add one stereo pair's points.

        Args:
            points_base: (H, W, 3) base_link points, NaN where invalid.
            appearance: (H, W, 2) colour saturation and value of the image at those
                points, each relative to the pair's median (see :func:`appearance`),
                or None.
            r_odom_base, t_odom_base: the pair's odometry pose (base_link in odom).
            camera_base: (3,) left camera centre in base_link, m.
            fxb: fx * baseline of the rig (pixels * m).
        """
        c = self.cfg
        p = points_base.reshape(-1, 3)
        ok = np.isfinite(p[:, 2])
        rel = p[ok] - camera_base
        dist = np.linalg.norm(rel, axis=1)
        keep = dist < c.max_range_m
        rel, dist = rel[keep], dist[keep]
        pts = p[ok][keep] @ r_odom_base.T + t_odom_base
        self._recentre(np.asarray(t_odom_base[:2], float))
        # Vertical sigma: the range error along the ray times the ray's vertical part.
        sig_r = dist**2 / fxb * DISPARITY_SIGMA_PX
        sig_r_per_m = sig_r / np.maximum(dist, 1e-6)
        sig_z = np.hypot(sig_r_per_m * np.abs(rel[:, 2]), HEIGHT_FLOOR_M)
        # A point misplaced along its ray lands in another cell: over terrain of gradient
        # g that is a height error of g times the horizontal part of the range error.
        sig_z = np.hypot(sig_z, PLACEMENT_GRADIENT * sig_r_per_m
                         * np.hypot(rel[:, 0], rel[:, 1]))
        wt = 1.0 / sig_z**2
        ij = np.floor((pts[:, :2] - self.origin) / CELL_M).astype(np.int64)
        inside = (ij >= 0).all(axis=1) & (ij < self.n).all(axis=1)
        ij, wt, z = ij[inside], wt[inside], pts[inside, 2]
        flat = ij[:, 0] * self.n + ij[:, 1]
        size = self.n * self.n
        # This pair's mean height per cell (inverse-variance weighted over its points),
        # then accumulated across pairs with the pair's weight, capped so that the many
        # near points of one view do not outvote the other views: a mismatch of one view
        # (a phantom height) shows as a spread across views.
        pw = np.bincount(flat, wt, size)
        hit = pw > 0
        pz = np.bincount(flat, wt * z, size)[hit] / pw[hit]
        pv = np.clip(np.bincount(flat, wt * z * z, size)[hit] / pw[hit] - pz * pz, 0.0, None)
        pw = np.minimum(pw[hit], MAX_PAIR_WEIGHT)
        for acc, v in ((self.w, pw), (self.wz, pw * pz), (self.wzz, pw * pz * pz),
                       (self.wvv, pw * pv), (self.npairs, 1.0)):
            acc.ravel()[hit] += v
        if appearance is not None:
            a = appearance.reshape(-1, 2)[ok][keep][inside]
            self.nb += np.bincount(flat, None, size).reshape(self.n, self.n)
            self.bs += np.bincount(flat, a[:, 0], size).reshape(self.n, self.n)
            self.bv += np.bincount(flat, a[:, 1], size).reshape(self.n, self.n)
        if len(ij):
            self._touched.append(np.r_[ij.min(axis=0), ij.max(axis=0)])
        self._pairs += 1

    # -- detection -------------------------------------------------------------------

    def due(self) -> bool:
        """True when a detection round is due (every ``detect_every`` pairs)."""
        return self._pairs > 0 and self._pairs % self.cfg.detect_every == 0 and \
            bool(self._touched)

    def pending(self) -> bool:
        """True when cells were touched since the last detection round."""
        return bool(self._touched)

    def detect(self, t: float, odom_cov: np.ndarray | None = None) -> list[MapRoi]:
        """One detection round over the cells touched since the last one (plus a margin):
        update the ROI list and return the regions found this round (odom)."""
        if not self._touched or self.origin is None:
            return []
        box = np.array(self._touched)
        self._touched = []
        margin = int(np.ceil(2 * GROUND_WINDOW_M / CELL_M))
        i0, j0 = np.maximum(box[:, :2].min(axis=0) - margin, 0)
        i1, j1 = np.minimum(box[:, 2:].max(axis=0) + margin + 1, self.n)
        found = self._regions(slice(i0, i1), slice(j0, j1))
        cov = np.zeros((2, 2)) if odom_cov is None else np.asarray(odom_cov, float)
        # 9. Persistence: each region joins the ROI it matches (``_associate``).
        matched = set()
        for r in found:
            r.odom_cov, r.last_t = cov, t
            matched.add(self._associate(r))
        # ROIs whose cells were re-examined (inside the touched box) and not found again.
        lo = box[:, :2].min(axis=0) * CELL_M + self.origin
        hi = (box[:, 2:].max(axis=0) + 1) * CELL_M + self.origin
        for r in self.rois:
            if r.id not in matched and np.all(r.xy >= lo) and np.all(r.xy <= hi):
                r.examined += 1
        return found

    def _regions(self, si: slice, sj: slice) -> list[MapRoi]:
        z, seen, sd = self.heights(si, sj, with_sd=True)
        if seen.sum() < 50:
            return []
        # 4. Ground.
        ground = ground_surface(z, seen, GROUND_WINDOW_M / CELL_M,
                                max(1, round(GROUND_CELL_M / CELL_M)),
                                GROUND_PERCENTILE)
        rel = np.where(seen, z - ground, 0.0)
        out: list[MapRoi] = []
        off = np.array([si.start, sj.start])
        # The relative value and saturation of the cells: the rocks' dark test reads the
        # value, the map rocks' features both.
        colour = None
        if self.nb.any():
            nb = np.maximum(self.nb[si, sj], 1)
            colour = (self.bv[si, sj] / nb, self.bs[si, sj] / nb)
        val = colour[0] if colour is not None else None
        # 5.-6. Rock regions and the map rocks' Rock Rover (``_rocks``). Rock seeds stand
        # high in every view: the mean less one spread across views (a stereo mismatch of
        # one view is a high spread, not a rock).
        out += self._rocks(rel, np.where(seen, rel - sd, 0.0), z, seen, off, val, colour)
        if colour is not None:
            # 7.-8. Outcrop regions and the Outcrop Rover (``_outcrops``).
            out += self._outcrops(rel, ground, seen, si, sj, off, colour)
        return out

    def heights(self, si: slice = slice(None), sj: slice = slice(None), with_sd: bool = False):
        """Mean height (odom z, NaN where unobserved) and the observed mask of a window;
        with ``with_sd`` also the spread of the height across the pairs (m)."""
        w = self.w[si, sj]
        mean = self.wz[si, sj] / np.maximum(w, 1e-9)
        var = self.wzz[si, sj] / np.maximum(w, 1e-9) - mean**2
        seen = (w >= MIN_CELL_WEIGHT) & (self.npairs[si, sj] >= MIN_PAIRS) & \
            (var <= MAX_CELL_SD_M**2)
        z = np.where(seen, mean, np.nan)
        if with_sd:
            return z, seen, np.sqrt(np.clip(var, 0.0, None))
        return z, seen

    def averaged_colour(self, sigma_m: float, si: slice = slice(None),
                        sj: slice = slice(None)):
        """The relative saturation and value of a window's cells averaged over a
        Gaussian ``sigma_m`` wide, each cell weighted by its colour samples (whether or
        not its height is observed), and the cells that hold colour after averaging
        (weight > 0.5): ``(have, sat, val)``."""
        s = sigma_m / CELL_M
        n = ndimage.gaussian_filter(self.nb[si, sj], s)
        sat = ndimage.gaussian_filter(self.bs[si, sj], s) / np.maximum(n, 1e-6)
        val = ndimage.gaussian_filter(self.bv[si, sj], s) / np.maximum(n, 1e-6)
        return n > 0.5, sat, val

    def _cell_spread(self, ij: np.ndarray) -> np.ndarray:
        """The spread of the heights within each of the cells ``ij`` (indices in the
        whole map) in the pairs that saw them (weighted mean variance, its root), m."""
        i, j = ij.T
        return np.sqrt(self.wvv[i, j] / np.maximum(self.w[i, j], 1e-9))

    def _cell_xy(self, ij: np.ndarray) -> np.ndarray:
        """Odom x, y of the centres of cells ``ij`` (indices in the whole map)."""
        return (ij + 0.5) * CELL_M + self.origin

    def _measure(self, label: int, cells: np.ndarray, off: np.ndarray, z_ground: float,
                 height: float) -> MapRoi | None:
        xy = self._cell_xy(cells + off)
        if len(xy) < 3:
            return None
        hull = cv2.convexHull(xy.astype(np.float32))
        # The centre of the footprint's convex hull: a rock seen from one side maps as a
        # crescent (its top and far side hidden), whose hull still spans the rock.
        mo = cv2.moments(hull)
        centre = np.array([mo["m10"], mo["m01"]]) / mo["m00"] if mo["m00"] > 0 else \
            xy.mean(axis=0)
        area = float(cv2.contourArea(hull)) + CELL_M * np.sqrt(len(xy)) * CELL_M
        area = max(area, len(xy) * CELL_M**2)
        w, v = np.linalg.eigh(np.cov(xy.T) + np.eye(2) * CELL_M**2 / 12)
        w = np.clip(w, 0.0, None)
        ci, cj = (cells + off).T
        # The pairs that saw its cells, at least: the most that saw one of them (a slab
        # beside the route is seen from afar, each of its cells by one or two pairs of
        # the many that saw it; its median cell had kept it out of the LN's min_obs).
        n_pairs = int(self.npairs[ci, cj].max())
        return MapRoi(0, label, centre, z_ground, area, height,
                      4 * float(np.sqrt(w[1])), 4 * float(np.sqrt(w[0])),
                      float(np.arctan2(v[1, 1], v[0, 1])), n_pairs=n_pairs)

    def _rocks(self, rel, rel_low, z, seen, off, val=None, colour=None) -> list[MapRoi]:
        c = self.cfg
        seeds = rel_low > c.rock_seed_height_m
        grow = rel > ROCK_GROW_HEIGHT_M
        if val is not None:
            dark = val < ROCK_DARK_VALUE
            grow &= dark | (rel > c.rock_seed_height_m)
            pale_seeds = seeds & (rel_low > ROCK_PALE_SEED_HEIGHT_M)
            seeds &= dark
        else:
            pale_seeds = np.zeros_like(seeds)
        lab, n = ndimage.label(grow)
        keep = np.zeros(n + 1, bool)
        keep[np.unique(lab[seeds & grow])] = True
        keep[0] = False
        # A region of cells of any brightness that stands rock_pale_seed_height_m is a
        # rock candidate too (pale rocks, and sunlit faces, are as bright as the soil or
        # brighter), when it holds no dark seed: the dark regions are left as they are.
        pale = np.zeros(n + 1, bool)
        pale[np.unique(lab[pale_seeds & grow])] = True
        pale &= ~keep
        pale[0] = False
        seeds = (seeds & keep[lab]) | (pale_seeds & pale[lab])
        keep |= pale
        mask = keep[lab]
        pale_cells = pale[lab]
        lab, n = self._split_peaks(rel, seeds & mask, mask)
        out = []
        if n == 0:
            return out
        ring_all = ndimage.binary_dilation(mask, iterations=5) & ~mask
        # A pale region stands on its height alone: it must measure
        # rock_pale_seed_height_m, as its seeds do.
        is_pale = np.asarray(ndimage.maximum(pale_cells.astype(np.uint8), lab,
                                             np.arange(n + 1))) > 0
        for k, sl in enumerate(ndimage.find_objects(lab), start=1):
            if sl is None:
                continue
            pad = tuple(slice(max(s.start - 6, 0), s.stop + 6) for s in sl)
            reg = lab[pad] == k
            cells = np.argwhere(reg)
            corner = np.array([pad[0].start, pad[1].start])
            trace = functools.partial(self._trace_region, cells + corner + off)
            if len(cells) * CELL_M**2 < 0.25 * c.rock_min_area_m2:
                trace("small", n_cells=len(cells))
                continue
            # The ground around the rock: a plane through the ring of cells 0.1-0.5 m
            # outside it (a slope is no rock), which must be mostly observed (at the
            # edge of the seen terrain the ground is a guess).
            ring = ndimage.binary_dilation(reg, iterations=5) & ring_all[pad]
            ring_seen = ring & seen[pad]
            plane = None
            if ring_seen.sum() >= max(8, ROCK_MIN_RING_SEEN * ring.sum()):
                plane = _plane(np.argwhere(ring_seen), z[pad][ring_seen])
            if plane is None:
                trace("ring_unseen", ring_seen=float(ring_seen.sum() / max(ring.sum(), 1)))
                continue
            above = z[pad][reg] - (plane[0] * cells[:, 0] + plane[1] * cells[:, 1] + plane[2])
            height = float(np.percentile(above, 95))
            min_height = max(c.rock_min_height_m, ROCK_PALE_SEED_HEIGHT_M) if is_pale[k] \
                else c.rock_min_height_m
            if height <= min_height:
                trace("low", height_m=height)
                continue
            r = self._measure(ROCK, cells + corner, off, float(np.median(z[pad][ring_seen])),
                              height)
            if r is None or not c.rock_min_area_m2 < r.area_m2 < ROCK_MAX_AREA_M2 or \
                    r.major_m > ROCK_MAX_LENGTH_WINDOWS * GROUND_WINDOW_M:
                trace("area", height_m=height, area_m2=None if r is None else r.area_m2,
                      major_m=None if r is None else r.major_m)
                continue
            # Rocks are not flat: height over equivalent diameter is 0.3-0.8 for boulders
            # (Golombek et al. 2008 on Mars); a broad low bump is terrain. The diameter is
            # the footprint at half the height (full width at half maximum): the skirt of
            # cells a little above the ground (stereo smear around the rock, grown at
            # 0.1 m) widens the footprint but not the width at half height.
            upper = above >= 0.5 * height
            if upper.sum() >= 3:
                # The rock's centre: that of its cells above half its height (the
                # footprint at half height, as the relief test below measures it). The
                # smear a tall rock leaves behind it, along the rays and lower than the
                # rock, widens the footprint and would move the hull's centroid off it.
                r.xy = self._cell_xy(cells[upper] + corner + off).mean(axis=0)
            half = max(int(np.count_nonzero(upper)), 1) * CELL_M**2
            relief = height / np.sqrt(4 * half / np.pi)
            # 5b. What a rock is not: a region taller than wide, or a strip.
            spread = self._cell_spread(cells + corner + off)
            top = float(np.percentile(above + TOP_SIGMAS * spread, 95))
            reason = rock_shape_reason(top, r.major_m, r.minor_m) \
                if relief >= ROCK_MIN_RELIEF_RATIO else None
            if reason is not None:
                self.rejected[reason] += 1
                trace(reason, height_m=height, top_m=top, area_m2=r.area_m2,
                      major_m=r.major_m, minor_m=r.minor_m)
                continue
            if relief >= ROCK_MIN_RELIEF_RATIO:
                r.features = self._rock_features(
                    r, lab == k, ring_seen, pad, plane, above, rel, rel_low, seen, off,
                    colour, relief, len(cells), bool(is_pale[k]))
                if self.rock_classifier is not None:
                    r.score = float(self.rock_classifier(r.features[None])[0])
                out.append(r)
            trace("rock" if relief >= ROCK_MIN_RELIEF_RATIO else "flat", height_m=height,
                  area_m2=r.area_m2, relief=float(relief), top_m=top, major_m=r.major_m,
                  minor_m=r.minor_m)
        return out

    def _rock_features(self, r: MapRoi, reg_full: np.ndarray, ring_seen: np.ndarray,
                       pad: tuple, plane: np.ndarray, above: np.ndarray, rel: np.ndarray,
                       rel_low: np.ndarray, seen: np.ndarray, off: np.ndarray,
                       colour: tuple | None, relief: float, n_cells: int,
                       pale: bool) -> np.ndarray:
        """The :data:`MAP_ROCK_FEATURES` of a rock region (window arrays; ``reg_full``
        the region's mask over the window, ``ring_seen`` the observed ring over ``pad``,
        ``colour`` the relative value and saturation maps or None)."""
        val, sat = colour if colour is not None else (None, None)
        reg = reg_full[pad]
        i0, j0 = off
        npairs = self.npairs[i0:i0 + rel.shape[0], j0:j0 + rel.shape[1]]
        weight = self.w[i0:i0 + rel.shape[0], j0:j0 + rel.shape[1]]
        sd = (rel - rel_low)[pad][reg]
        nan = float("nan")
        if val is not None:
            v_reg = val[pad][reg]
            v_ring = val[pad][ring_seen]
            value = float(np.median(v_reg))
            dark = float(np.mean(v_reg < ROCK_DARK_VALUE))
            contrast = float(np.median(v_ring)) - value if len(v_ring) else nan
            value_lo = float(np.percentile(v_reg, 10))
        else:
            value = dark = contrast = value_lo = nan
        saturation = float(np.median(sat[pad][reg])) if sat is not None else nan
        # The ground's roughness and slope under the ring's plane.
        ij = np.argwhere(ring_seen)
        zr = rel[pad][ring_seen]
        resid = zr - (plane[0] * ij[:, 0] + plane[1] * ij[:, 1])
        roughness = float(np.std(resid - np.median(resid)))
        slope = float(np.hypot(plane[0], plane[1]) / CELL_M)
        # Clutter around it: the share of the observed cells 0.5-2.5 m outside the region
        # that stand above the grow height and are dark (a field of small rocks, which
        # the map can merge into one false rock, is a crowd of such cells).
        near = round(0.5 / CELL_M)
        far = round(2.5 / CELL_M)
        rows, cols = np.nonzero(reg_full)
        box = (slice(max(rows.min() - far, 0), rows.max() + far + 1),
               slice(max(cols.min() - far, 0), cols.max() + far + 1))
        rb = reg_full[box]
        annulus = ndimage.binary_dilation(rb, iterations=far) & \
            ~ndimage.binary_dilation(rb, iterations=near) & seen[box]
        bumpy = rel[box] > ROCK_GROW_HEIGHT_M
        if val is not None:
            bumpy &= val[box] < ROCK_DARK_VALUE
        clutter = float(bumpy[annulus].mean()) if annulus.any() else 0.0
        hull_fill = n_cells * CELL_M**2 / max(r.area_m2, 1e-6)
        feats = np.array([
            r.height_m, np.log(r.area_m2), relief, np.log(max(r.major_m, 1e-3)),
            r.minor_m / max(r.major_m, 1e-3), hull_fill, float(np.max(rel_low[pad][reg])),
            float(np.median(sd)), float(np.percentile(above, 50)) / max(r.height_m, 1e-3),
            value, value_lo, dark, contrast, saturation,
            float(ring_seen.sum()) / max(float(ndimage.binary_dilation(
                reg, iterations=5).sum() - reg.sum()), 1.0),
            roughness, slope, clutter, float(pale),
            np.log1p(float(npairs[pad][reg].max())), np.log1p(float(np.median(npairs[pad][reg]))),
            np.log1p(float(np.median(weight[pad][reg]))),
        ], np.float32)
        # A map without colour leaves the colour features undefined: 0, as the classifier
        # reads them (a model is trained on maps with colour).
        return np.nan_to_num(feats, nan=0.0)

    def _trace_region(self, cells: np.ndarray, verdict: str, /, **measured) -> None:
        """Report a rock region (cell indices in the window) to :attr:`trace`, if set."""
        if self.trace is not None:
            self.trace(verdict, self._cell_xy(cells.mean(axis=0)), measured)

    def _split_peaks(self, rel: np.ndarray, seeds: np.ndarray, mask: np.ndarray):
        """Label ``mask`` with one region per peak: seed cells within
        ``rock_peak_merge_m`` of each other are one peak, and every other cell of the mask
        goes to the peak it climbs to (watershed on the height). A rock and the clutter
        rocks of its apron, or two rocks, joined by cells just above the ground would
        otherwise be one region, its footprint the hull of all of them."""
        from skimage.segmentation import watershed

        it = max(1, round(ROCK_PEAK_MERGE_M / CELL_M / 2))
        markers, n = ndimage.label(ndimage.binary_dilation(seeds, iterations=it) & mask)
        if n == 0:
            return np.zeros(mask.shape, np.int32), 0
        lab = watershed(-rel, markers, mask=mask)
        # Each region's footprint: its cells above a fraction of its peak height (the low
        # cells a region climbs from, debris or stereo smear, shared with the next peak,
        # are not the rock).
        peak = ndimage.maximum(rel, lab, np.arange(n + 1))
        lab = np.where(rel >= ROCK_FOOTPRINT_FRACTION * np.asarray(peak)[lab], lab, 0)
        return lab, n

    def _outcrops(self, rel, ground, seen, si, sj, off, colour) -> list[MapRoi]:
        """The outcrop regions of the window ``si``, ``sj`` (``colour``: its cells'
        relative value and saturation, as :meth:`_regions` reads them)."""
        nb = self.nb[si, sj]
        if (nb > 0).sum() < 100:
            return []
        # The colour averaged over a small neighbourhood, every cell with colour samples
        # contributing (a slab seen from afar is observed in sparse stripes of cells, and
        # its per-cell colour scatters across the thresholds).
        have, sat, val = self.averaged_colour(OUTCROP_COLOUR_SIGMA_M, si, sj)
        low = ~(seen & (rel >= MAX_OUTCROP_HEIGHT_M))
        pale = self.outcrop_colour(have, sat, val) & low
        pale = ndimage.binary_opening(pale, iterations=OUTCROP_OPENING)
        pale = ndimage.binary_closing(pale, iterations=3) & have
        lab, _ = ndimage.label(pale)
        out = []
        for k, sl in enumerate(ndimage.find_objects(lab), start=1):
            if sl is None:
                continue
            reg = lab[sl] == k
            if reg.sum() * CELL_M**2 < OUTCROP_MIN_CELLS_FRACTION * OUTCROP_MIN_AREA_M2:
                continue
            cells = np.argwhere(reg) + np.array([sl[0].start, sl[1].start])
            rel_reg = rel[sl][reg & seen[sl]]
            height = float(np.percentile(rel_reg, 95)) if len(rel_reg) else 0.0
            if height > MAX_OUTCROP_HEIGHT_M:
                continue
            r = self._measure(OUTCROP, cells, off, float(np.nanmedian(ground[sl][reg])), height)
            if r is not None and r.area_m2 >= OUTCROP_MIN_AREA_M2:
                r.features = self._outcrop_features(r, lab == k, rel, seen, colour, nb,
                                                    self.npairs[si, sj])
                if self.outcrop_classifier is not None:
                    r.score = float(self.outcrop_classifier(r.features[None])[0])
                out.append(r)
        return out

    def outcrop_colour(self, have: np.ndarray, sat: np.ndarray,
                       val: np.ndarray) -> np.ndarray:
        """The cells (holding colour: ``have``) whose relative saturation ``sat`` and
        value ``val`` are an outcrop's. Outcrops are grey slabs: far less saturated than
        the reddish soil (:data:`OUTCROP_MAX_SATURATION`) and not dark (rocks, desert
        pavement and rock shadows are dark: :data:`OUTCROP_MIN_VALUE`)."""
        return have & (sat < OUTCROP_MAX_SATURATION) & (val > OUTCROP_MIN_VALUE)

    def _outcrop_features(self, r: MapRoi, reg_full: np.ndarray, rel: np.ndarray,
                          seen: np.ndarray, colour: tuple, nb: np.ndarray,
                          npairs: np.ndarray) -> np.ndarray:
        """The :data:`MAP_OUTCROP_FEATURES` of an outcrop region (window arrays:
        ``reg_full`` its mask, ``rel`` the height above the ground, ``colour`` the cells'
        relative value and saturation, ``nb`` their colour samples, ``npairs`` the pairs
        that saw them)."""
        val, sat = colour
        rows, cols = np.nonzero(reg_full)
        far = round(1.5 / CELL_M)
        box = (slice(max(rows.min() - far, 0), rows.max() + far + 1),
               slice(max(cols.min() - far, 0), cols.max() + far + 1))
        reg = reg_full[box]
        ring = ndimage.binary_dilation(reg, iterations=far) & \
            ~ndimage.binary_dilation(reg, iterations=round(0.3 / CELL_M))
        rs, rv, rh, rsn, nbb = (a[box] for a in (sat, val, rel, seen, nb))
        hv = nbb > 0
        in_c = reg & hv
        ring_c = ring & hv
        nan = float("nan")

        def pct(a, q):
            return float(np.percentile(a, q)) if len(a) else nan

        s_in, v_in = rs[in_c], rv[in_c]
        h_in = rh[reg & rsn]
        rocky = (rh > ROCK_GROW_HEIGHT_M) & rsn & (rv < ROCK_DARK_VALUE)
        npairs = npairs[box][reg]
        feats = np.array([
            np.log(max(r.area_m2, 1e-3)), reg.sum() * CELL_M**2 / max(r.area_m2, 1e-6),
            np.log(max(r.major_m, 1e-3)), r.minor_m / max(r.major_m, 1e-3), r.height_m,
            pct(h_in, 50), float(np.std(h_in)) if len(h_in) else nan,
            float((reg & rsn).sum()) / max(float(reg.sum()), 1.0),
            pct(s_in, 50), pct(s_in, 10), pct(s_in, 90),
            pct(v_in, 50), pct(v_in, 10), pct(v_in, 90),
            pct(rs[ring_c], 50) - pct(s_in, 50), pct(rv[ring_c], 50) - pct(v_in, 50),
            float(rocky[reg].mean()), float(rocky[ring & rsn].mean()) if (ring & rsn).any()
            else 0.0,
            np.log1p(float(npairs.max())), np.log1p(float(np.median(npairs))),
            np.log1p(float(np.median(nbb[in_c]))) if in_c.any() else 0.0,
        ], np.float32)
        return np.nan_to_num(feats, nan=0.0)

    def _associate(self, r: MapRoi) -> int:
        """Merge ``r`` into the ROI it coincides with, or add it; returns its id."""
        best, best_d = None, np.inf
        for old in self.rois:
            if old.label != r.label:
                continue
            d = float(np.hypot(*(old.xy - r.xy)))
            gate = max(1.0, 0.5 * max(old.major_m, r.major_m))
            if d < gate and d < best_d:
                best, best_d = old, d
        if best is None:
            r.id = self._next_id
            self._next_id += 1
            self.rois.append(r)
            return r.id
        r.id, r.rounds, r.examined = best.id, best.rounds + 1, best.examined + 1
        # The latest measurement (the map has fused every view so far); an outcrop's only
        # when no smaller than the one kept: a slab wider than the cells a round examines
        # is cut at their border once the rover has passed it.
        if r.label != OUTCROP or r.area_m2 >= best.area_m2:
            for name in ("xy", "z", "area_m2", "height_m", "major_m", "minor_m",
                         "angle_rad", "odom_cov", "last_t", "n_pairs", "features", "score"):
                setattr(best, name, getattr(r, name))
        best.rounds, best.examined = r.rounds, r.examined
        return best.id

    def consistent(self) -> list[MapRoi]:
        """The ROIs the map reports: found in at least ``min_rounds`` rounds and
        ``min_hit_ratio`` of the rounds that examined their cells, and, a rock scored by
        the map-rock Rock Rover, scoring above ``map_rock_min_score`` at its latest
        measurement, an outcrop scored by the map outcrops' Outcrop Rover, above
        ``map_outcrop_min_score`` at its kept one."""
        c = self.cfg
        floor = {ROCK: c.map_rock_min_score, OUTCROP: c.map_outcrop_min_score}
        return [r for r in self.rois if self.persists(r) and not r.score <= floor[r.label]]

    def persists(self, r: MapRoi) -> bool:
        """``r`` was found in at least ``min_rounds`` detection rounds and in
        ``min_hit_ratio`` of the rounds that examined its cells (its score aside)."""
        c = self.cfg
        return r.rounds >= c.min_rounds and r.rounds >= c.min_hit_ratio * r.examined

    def to_records(self, rois: list[MapRoi] | None = None) -> np.ndarray:
        """ROI records (odom) of ``rois`` (default: :meth:`consistent`) with covariance:
        centre error plus odometry at the latest round that measured each ROI; ``n_obs``
        is the number of stereo pairs that saw its cells (at least: the most that saw
        one of them)."""
        if rois is None:
            rois = self.consistent()
        rec = empty_records(len(rois))
        for i, r in enumerate(rois):
            s2 = CENTRE_SIGMA_M**2 + (0.1 * r.major_m) ** 2
            rec[i]["id"], rec[i]["label"] = r.id, r.label
            rec[i]["x"], rec[i]["y"], rec[i]["z"] = r.xy[0], r.xy[1], r.z
            rec[i]["area_m2"], rec[i]["height_m"] = r.area_m2, r.height_m
            rec[i]["major_m"], rec[i]["minor_m"] = r.major_m, r.minor_m
            rec[i]["angle_rad"] = r.angle_rad
            rec[i]["score"] = r.score if np.isfinite(r.score) else 1.0
            rec[i]["cov_xx"] = s2 + r.odom_cov[0, 0]
            rec[i]["cov_xy"] = r.odom_cov[0, 1]
            rec[i]["cov_yy"] = s2 + r.odom_cov[1, 1]
            rec[i]["n_obs"] = r.n_pairs
        return rec


def ground_surface(z: np.ndarray, seen: np.ndarray, window_cells: float, block: int = 4,
                   percentile: float = 25.0) -> np.ndarray:
    """Low envelope of a height map (same shape as ``z``).

    On blocks of ``block`` x ``block`` cells, each at the ``percentile`` of its observed
    cells (a single bad cell does not pull the ground down), unobserved blocks filled
    from the nearest observed one: a grey opening over a square ``window_cells`` wide,
    then a mean filter of half that width (the opening's tops are flat), interpolated
    back to the cells.
    """
    n0, n1 = z.shape
    p0, p1 = -n0 % block, -n1 % block
    zp = np.pad(np.where(seen, z, np.nan), ((0, p0), (0, p1)), constant_values=np.nan)
    blocks = zp.reshape(zp.shape[0] // block, block, zp.shape[1] // block, block)
    blocks = blocks.transpose(0, 2, 1, 3).reshape(blocks.shape[0], blocks.shape[2], -1)
    have = np.isfinite(blocks).any(axis=-1)
    if not have.any():
        return np.full(z.shape, np.nan)
    coarse = np.full(have.shape, np.nan)
    coarse[have] = np.nanpercentile(blocks[have], percentile, axis=-1)
    idx = ndimage.distance_transform_edt(~have, return_distances=False, return_indices=True)
    filled = coarse[tuple(idx)]
    k = max(3, round(window_cells / block) | 1)
    opened = ndimage.grey_opening(filled, size=(k, k), mode="nearest")
    smooth = ndimage.uniform_filter(opened, size=max(3, k // 2 | 1), mode="nearest")
    up = cv2.resize(smooth.astype(np.float32), (smooth.shape[1] * block, smooth.shape[0] * block),
                    interpolation=cv2.INTER_LINEAR)
    return up[:n0, :n1]


def is_monochrome(bgr: np.ndarray) -> bool:
    """True when the three channels of a BGR image are the same (a grey image): it has
    no colour for :func:`appearance` to measure."""
    return bool(np.array_equal(bgr[..., 0], bgr[..., 1])
                and np.array_equal(bgr[..., 1], bgr[..., 2]))


def appearance(bgr: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H, W, 2) colour saturation and value (HSV) of an image, each divided by its median
    over the ``valid`` pixels (the ground the pair sees): exposure and sun cancel."""
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    sv = hsv[..., 1:].astype(np.float32)
    if valid.any():
        med = np.median(sv[valid], axis=0)
        sv /= np.maximum(med, 1.0)
    return sv


def _plane(ij: np.ndarray, z: np.ndarray) -> np.ndarray | None:
    """Least-squares plane z = a i + b j + c through cells (trimmed once); None if < 8."""
    if len(z) < 8:
        return None
    a = np.column_stack([ij[:, 0], ij[:, 1], np.ones(len(z))])
    coef, *_ = np.linalg.lstsq(a, z, rcond=None)
    r = z - a @ coef
    keep = np.abs(r) <= max(2.5 * np.median(np.abs(r)), 0.02)
    if keep.sum() >= 8:
        coef, *_ = np.linalg.lstsq(a[keep], z[keep], rcond=None)
    return coef


def _shifted(a: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``a`` moved by ``-shift`` cells (the grid origin moved by ``+shift``), zero-filled."""
    out = np.zeros_like(a)
    n0, n1 = a.shape
    di, dj = int(shift[0]), int(shift[1])
    src_i = slice(max(di, 0), min(n0 + di, n0))
    dst_i = slice(max(-di, 0), min(n0 - di, n0))
    src_j = slice(max(dj, 0), min(n1 + dj, n1))
    dst_j = slice(max(-dj, 0), min(n1 - dj, n1))
    if src_i.start < src_i.stop and src_j.start < src_j.stop:
        out[dst_i, dst_j] = a[src_i, src_j]
    return out

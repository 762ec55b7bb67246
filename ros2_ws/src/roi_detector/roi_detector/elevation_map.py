"""A local elevation map of the drive (odom), built from every stereo pair, and the rocks
and outcrops found in it.

The paper detects ROIs in each rover image and tracks them. One view of a rock 6-15 m
ahead, seen by a 45 deg camera, shows its front flank only, and its area and height from
that view swing by a factor of 3 from pair to pair. Rovers have long fused their stereo
into a height map of the terrain around them (MER's GESTALT, Maimone et al. 2007); this
module does that, then measures ROIs the way the orbital catalogue defines them: top-down
footprint area, and height above the ground around them.

- **Integration**: every stereo point is placed in odom with the pair's odometry pose and
  accumulated per cell (``cell_m``) as an inverse-variance weighted mean height, the
  variance being the vertical part of the stereo range error (``Z^2 / (fx B) * sigma_d``
  along the ray). A rolling window centred near the rover holds the map: cells that fall
  out of it are forgotten (what was found there stays in the ROI list).
- **Ground**: a grey-scale opening of the height map (a square ``ground_window_m`` wide,
  wider than the largest rock), smoothed: the low envelope that follows terrain swells
  but not rocks.
- **Rocks**: dark cells standing > ``rock_seed_height_m`` above the ground, grown down
  to ``rock_grow_height_m`` over dark cells (hysteresis), one region per peak; kept when
  the region's height above the
  ring of ground around it exceeds the paper's 0.25 m and the convex hull of its cells
  (a rock's far side is seen late or never) exceeds the paper's 0.6 m^2.
- **Outcrops**: grey tabular slabs. Each pair's colour saturation and value are
  normalised by the pair's medians (auto-exposure and sun cancel) and mapped like the
  height (optionally averaged over a small neighbourhood, ``outcrop_colour_sigma_m``);
  connected cells far less saturated than the soil (``outcrop_max_saturation``), not
  dark (``outcrop_min_value``) and not standing ``max_outcrop_height_m`` above the
  ground, over > 5.5 m^2 (the paper's threshold). An outcrop keeps the
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
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy import ndimage

from roi_network.records import OUTCROP, ROCK, empty_records

#: Where a rock region's node is placed (``ElevationMapConfig.rock_centre``).
ROCK_CENTRES = ("upper", "hull")


@dataclass(frozen=True)
class ElevationMapConfig:
    """Map, ground and ROI parameters (odom metres unless stated).

    Attributes:
        cell_m: map cell side.
        window_m: side of the rolling map window around the rover.
        max_range_m: stereo points farther from the camera are not mapped: the range
            error grows as Z^2 (1.3 m along the ray at 20 m for the MER-like bench, but
            only ~0.1 m of it vertical at that grazing angle). Not less: with a 45 deg
            field of view, the ROIs the route passes 2.5-6 m beside are in view only
            6-20 m ahead.
        disparity_sigma_px: 1-sigma disparity error that weights each point.
        height_floor_m: smallest vertical sigma of a point (texture, rendering, JPEG).
        placement_gradient: terrain gradient that turns the horizontal part of a
            point's range error into a height error of the cell it lands in. The
            vertical part alone is small at the grazing angles of far points (0.13 m at
            15 m for the 0.2 m baseline), while their horizontal error is ~1 m: far
            views of a rock face land in the ground around it and the ground's in the
            rock, averaging its height away. 0.5 (a rock's flank) makes a view from
            15 m weigh ~1/40 of one from 6 m (chosen on the training bags s101/s102:
            docs/roi_detector.md); 0 is the vertical error alone.
        ground_window_m: side of the opening that finds the ground (wider than the
            largest rock footprint, ~2.8 m across).
        rock_seed_height_m: cells this high above the ground seed a rock (paper: 0.25).
        rock_grow_height_m: a rock region grows over cells this high.
        rock_min_height_m: least height of a rock above the plane of the ground around
            it, as the map measures it. The paper's rover threshold is 0.25 m of the
            rock; the map under-measures rocks (their top and far side are seen at a
            grazing angle or not at all: on the training bag train_quick_s101 the rocks
            found measured 0.30-0.58 m for 0.5-1.2 m), while the stereo noise of the
            70 deg lens makes bumps of 0.26-0.36 m: 0.35 kept 4 of those 6 rocks and
            dropped 12 of 13 false ones there. With far views weighted down
            (``placement_gradient``) heights are measured less low, and 0.30 is the
            threshold chosen with it on s101/s102. With dark seeds (``rock_dark_value``)
            the soil-coloured bumps are gone and the paper's 0.25 is the threshold again
            (0.18 doubled the false rocks; docs/roi_detector.md).
        rock_min_area_m2: the paper's rover rock threshold.
        rock_max_area_m2: larger regions are terrain, not one rock.
        rock_max_length_windows: a rock region's major axis is at most this many
            ``ground_window_m``. The ground's opening assumes every rock narrower than
            its window, and finds the ground under it; a region much longer than the
            window is a ridge or a crest of the terrain, which the opening keeps in its
            narrow direction only. 1.5 (4.8 m): the catalogued rocks of five bags measure
            up to 3.6 m (truth) and their map nodes up to 3.6 m; the map rocks above
            4.8 m on the held-out bags s113 and s114 (4.9-8.2 m long, 2.8-4.8:1) were
            all false (docs/roi_detector.md, 2026-11-27, sixth session). 0: no limit.
        rock_min_ring_seen: the observed fraction of the ring of ground around a rock
            region below which its height cannot be measured (the far side of a rock
            is hidden: a quarter is enough).
        rock_min_relief_ratio: a rock's height over the equivalent diameter of its
            footprint at half that height is at least this (flatter regions are
            terrain swells).
        min_cell_weight: cells with less accumulated weight (1/m^2) are unobserved
            (3: the weighted mean height within 0.58 m, 1 sigma: far views count, and
            the rock tests below (dark seeds, relief, ring) reject what their noise
            makes; 30 before the dark test, which lost the rocks seen only from afar).
        min_pairs: cells seen by fewer stereo pairs are unobserved.
        max_cell_sd_m: cells whose height spreads more than this across the pairs that
            saw them (a stereo mismatch of one view) are unobserved.
        max_pair_weight: cap of one pair's weight in a cell (1/m^2).
        ground_cell_m: the ground is found on cells this large, each at the
            ``ground_percentile`` of its fine cells (robust to single bad cells).
        outcrop_max_saturation: outcrop cells' colour saturation, relative to the
            median of the pairs that saw them, is below this. The simulator's outcrops
            have 0.36 of the soil's saturation by their albedos, its gravel patches
            0.58: with the averaged colour (``AVERAGED_OUTCROPS``) 0.6 took gravel for
            outcrops (on 8 training bags, 27 of 51 outcrop nodes false), 0.5 none.
        outcrop_min_value: and their value (brightness) above this. Outcrops are grey
            slabs, pale or not: on the training bags they measure 0.74-1.54 of the
            soil's brightness; ``AVERAGED_OUTCROPS`` uses 0.55, the complement of
            ``rock_dark_value``.
        outcrop_min_area_m2: the paper's rover outcrop threshold, on the convex hull of
            the region's cells (as a rock's footprint).
        outcrop_colour_sigma_m: > 0: the saturation and value are averaged over a
            Gaussian this wide (weighted by the colour samples of each cell, whether or
            not its height is observed) before the tests. A slab beside the route is
            seen from afar, in sparse stripes of cells whose colour scatters across the
            thresholds, and the per-cell test breaks it into pieces (on 5 training
            bags, at the best moment of the drive, 5 of 15 counted outcrops found per
            cell, 12 averaged). 0 (default): per observed cell.
        outcrop_opening: iterations of the opening that removes specks from the pale
            mask.
        outcrop_min_cells_fraction: a region's cells must cover at least this fraction
            of ``outcrop_min_area_m2`` (its hull the whole): a slab seen in part.
        outcrop_soil_ratio: > 0: a cell is also pale when its saturation is under this
            fraction of the soil's around it: the saturation of the cells within
            ``outcrop_soil_sigma_m`` (a Gaussian) that hold colour and are not pale by
            ``outcrop_max_saturation``. A slab seen from afar or in part measures
            0.6-0.9 of the frame's saturation where its soil measures 1.0-1.2
            (``bench/roi_diag.py --outcrops``); 0 (default): the absolute test alone.
        max_outcrop_height_m: outcrops are slabs; regions standing higher are not.
        detect_every: a detection round every this many integrated pairs.
        centre_sigma_m: 1-sigma error of a map ROI's centre (cell size, partial views).
        min_hit_ratio: an ROI is reported while found in at least this fraction of the
            detection rounds that re-examined its cells.
        min_rounds: and in at least this many rounds.
        rock_split_peaks: one region per peak (watershed on the height from the seed
            cells, seeds within ``rock_peak_merge_m`` being one peak): a rock and the
            clutter rocks of its apron joined by cells just above the ground are split
            instead of measured as one footprint. False: connected regions.
        rock_peak_merge_m: seed cells closer than this are one peak.
        rock_footprint_fraction: with ``rock_split_peaks``, a region's footprint is its
            cells higher than this fraction of its peak (the low cells it climbs from,
            debris or stereo smear shared with the next peak, are not the rock): 0.35
            found 36 of 75 rocks at 40 of 42 true nodes where 0 found 35 at 39 of 43
            and 0.5 found 27 (quick and atacama_1km s1-s3, truth odometry).
        rock_dark_value: rock seeds, and the low cells a rock region grows over, must be
            darker than this relative value (the cell's brightness over the median of
            the pairs that saw it; cells higher than ``rock_seed_height_m`` grow
            whatever their brightness). Desert rocks are darker than the soil around
            them (varnish; on the bags rock cells measure 0.26-0.45, the soil 0.6-1.2),
            while stereo noise and terrain bumps are soil-coloured: this made rock
            precision 91 % from 57 % on quick and atacama_1km s1-s3 (truth odometry,
            docs/roi_detector.md), the same at 0.65. 0 turns the test off (rocks as
            bright as the ground).
        rock_pale_seed_height_m: > 0: a connected region that holds no dark seed is a
            rock candidate too when one of its cells, of any brightness, stands this
            high above the ground less its spread across views; it must then measure
            this high above the plane of its ring (``rock_min_height_m`` otherwise).
            Regions with a dark seed are left as they are. Pale rocks, and sunlit
            faces, are as bright as the soil or brighter: on the held-out bag
            train_1km_s113, two counted rocks of 1.0 and 1.9 m^2, 0.64-0.67 m tall,
            6.6 and 8.4 m from the route, measured 1.16-1.28 of the soil's brightness
            and stood 0.45-0.8 m in the map, and no region was grown on them. The soil-coloured
            bumps that ``rock_dark_value`` keeps out measure 0.26-0.36 m. 0: dark seeds
            only.
        rock_centre: where a rock region's node is placed. ``"upper"``: the centroid of
            its cells above half its height (the footprint at half height, which the
            relief test measures); ``"hull"``: the centroid of its footprint's convex
            hull (until 2026-11-27, eighth session). The smear a tall rock leaves behind
            it along the rays, lower than the rock, widens the footprint away from the
            camera. Over the rock nodes of five bags (truth odometry), "upper" moved 20
            nodes nearer their rock by more than 5 cm and 9 further, and the median node
            error went from 0.38 to 0.20 m on atacama_1km_s1 (docs/roi_detector.md,
            Measured). The area and the other measurements are the footprint's either
            way.
        map_rock_min_score: with a map-rock Rock Rover (``ElevationMap(rock_classifier=)``),
            a rock is reported while its probability at its latest measurement is above
            this.
        map_outcrop_min_score: with a map outcrops' Outcrop Rover
            (``ElevationMap(outcrop_classifier=)``), an outcrop is reported while its
            probability at its kept measurement is above this.
    """

    cell_m: float = 0.1
    window_m: float = 64.0
    max_range_m: float = 20.0
    disparity_sigma_px: float = 0.5
    height_floor_m: float = 0.02
    placement_gradient: float = 0.5
    ground_window_m: float = 3.2
    rock_seed_height_m: float = 0.25
    rock_grow_height_m: float = 0.1
    rock_min_height_m: float = 0.25
    rock_min_area_m2: float = 0.6
    rock_max_area_m2: float = 9.0
    rock_max_length_windows: float = 1.5
    rock_min_ring_seen: float = 0.25
    rock_min_relief_ratio: float = 0.25
    min_cell_weight: float = 3.0
    min_pairs: int = 3
    max_cell_sd_m: float = 0.4
    max_pair_weight: float = 2500.0
    ground_cell_m: float = 0.4
    ground_percentile: float = 25.0
    outcrop_max_saturation: float = 0.6
    outcrop_min_value: float = 0.8
    outcrop_min_area_m2: float = 5.5
    outcrop_colour_sigma_m: float = 0.0
    outcrop_opening: int = 2
    outcrop_min_cells_fraction: float = 1.0
    outcrop_soil_ratio: float = 0.0
    outcrop_soil_sigma_m: float = 3.0
    max_outcrop_height_m: float = 0.45
    detect_every: int = 3
    centre_sigma_m: float = 0.15
    min_hit_ratio: float = 0.5
    min_rounds: int = 2
    rock_split_peaks: bool = True
    rock_peak_merge_m: float = 0.3
    rock_dark_value: float = 0.55
    rock_footprint_fraction: float = 0.35
    rock_pale_seed_height_m: float = 0.45
    rock_centre: str = "upper"
    map_rock_min_score: float = 0.5
    map_outcrop_min_score: float = 0.5

    def __post_init__(self) -> None:
        if self.rock_centre not in ROCK_CENTRES:
            raise ValueError(f"unknown rock_centre '{self.rock_centre}' (one of "
                             f"{ROCK_CENTRES})")


#: The outcrop rule on the colour averaged over 0.2 m (``replace(cfg, **AVERAGED_OUTCROPS)``;
#: docs/roi_detector.md, 2026-11-26, late). With truth odometry it finds 8 of the four
#: evaluation bags' 13 counted outcrops where the default finds 6, at 8/12 true nodes
#: for 6/6. End to end, with rover_vo's odometry, seed 2's LN got 7 outcrop nodes, 6 of
#: them false, and the run never fixed: not the default.
AVERAGED_OUTCROPS: dict = dict(outcrop_colour_sigma_m=0.2, outcrop_max_saturation=0.5,
                               outcrop_min_value=0.55, outcrop_opening=1,
                               outcrop_min_cells_fraction=0.5)
#: The averaged colour's candidates for the map outcrops' Outcrop Rover: saturation < 0.6,
#: where the averaged rule alone took gravel patches for outcrops (on 8 training bags 21
#: of 26 counted outcrops found, at 24 of 51 true nodes; docs/roi_detector.md,
#: 2026-11-26, late); the classifier decides (``RoverConfig.classify_map_outcrops``).
AVERAGED_WIDE_OUTCROPS: dict = {**AVERAGED_OUTCROPS, "outcrop_max_saturation": 0.6}
#: :data:`AVERAGED_WIDE_OUTCROPS` and, besides, the cells under 0.75 of the local soil's
#: saturation (``outcrop_soil_ratio``): candidates of slabs seen from afar or in part.
SOIL_RELATIVE_OUTCROPS: dict = {**AVERAGED_WIDE_OUTCROPS, "outcrop_soil_ratio": 0.75}
#: The outcrop rule per observed cell, saturation < 0.6 and value > 0.8 (the default
#: until 2026-11-28, eighteenth session, decided by the rule alone).
PER_CELL_OUTCROPS: dict = dict(outcrop_colour_sigma_m=0.0, outcrop_max_saturation=0.6,
                               outcrop_min_value=0.8, outcrop_opening=2,
                               outcrop_min_cells_fraction=1.0)
#: The outcrop rules by name (``roi_detector ln --outcrops``, the node's ``outcrops``
#: parameter): ``per_cell``, :data:`PER_CELL_OUTCROPS`; ``averaged``,
#: :data:`AVERAGED_OUTCROPS`; ``averaged_wide``, :data:`AVERAGED_WIDE_OUTCROPS`;
#: ``soil_relative``, :data:`SOIL_RELATIVE_OUTCROPS`.
OUTCROP_RULES: dict[str, dict] = {"per_cell": PER_CELL_OUTCROPS, "averaged": AVERAGED_OUTCROPS,
                                  "averaged_wide": AVERAGED_WIDE_OUTCROPS,
                                  "soil_relative": SOIL_RELATIVE_OUTCROPS}
#: The outcrop rule of the rover pipeline's default configuration (``RoverConfig``, the
#: CLI's and the node's ``outcrops``): the candidates of the map outcrops' Outcrop Rover,
#: which decides them by default (``RoverConfig.classify_map_outcrops``) and is trained
#: on them (``roi_detector train --outcrops``).
DEFAULT_OUTCROP_RULE = "averaged_wide"
#: The fields of :class:`ElevationMapConfig` that make an outcrop rule: a map outcrops'
#: Outcrop Rover records them, and is refused by a map whose rule differs.
OUTCROP_RULE_FIELDS: tuple[str, ...] = (
    "outcrop_max_saturation", "outcrop_min_value", "outcrop_min_area_m2",
    "outcrop_colour_sigma_m", "outcrop_opening", "outcrop_min_cells_fraction",
    "max_outcrop_height_m", "outcrop_soil_ratio", "outcrop_soil_sigma_m")


def outcrop_rule_of(cfg: ElevationMapConfig) -> dict:
    """The :data:`OUTCROP_RULE_FIELDS` of ``cfg``."""
    return {k: getattr(cfg, k) for k in OUTCROP_RULE_FIELDS}


def complete_outcrop_rule(rule: dict) -> dict:
    """Every :data:`OUTCROP_RULE_FIELDS` of ``rule``, those it leaves out at their
    defaults: a rule of :data:`OUTCROP_RULES`, or one a model records
    (:func:`outcrop_rule_of`) without the fields it predates (they were at their
    defaults when it was trained)."""
    return {**outcrop_rule_of(ElevationMapConfig()), **rule}


def outcrop_rule(name: str, cfg: ElevationMapConfig | None = None) -> ElevationMapConfig:
    """``cfg`` (default: the defaults) with the outcrop rule ``name`` of
    :data:`OUTCROP_RULES`; ValueError naming the rules for any other name."""
    if name not in OUTCROP_RULES:
        raise ValueError(f"unknown outcrop rule '{name}' (one of {tuple(OUTCROP_RULES)})")
    return replace(cfg or ElevationMapConfig(), **complete_outcrop_rule(OUTCROP_RULES[name]))


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
        self.n = round(cfg.window_m / cfg.cell_m)
        self.origin = None  # odom x, y of cell (0, 0)'s corner
        # Per cell, over the pairs that saw it: the sum of the pairs' weights, of weight *
        # mean height and of weight * mean height^2 (mean and spread across views), and
        # the number of pairs.
        self.w = np.zeros((self.n, self.n), np.float32)
        self.wz = np.zeros((self.n, self.n), np.float32)
        self.wzz = np.zeros((self.n, self.n), np.float32)
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
        #: ``ring_unseen``, ``low``, ``area``, ``flat`` (the test that rejected it) or
        #: ``rock`` (``bench/roi_diag.py``).
        self.trace: Callable[[str, np.ndarray, dict], None] | None = None

    # -- integration -----------------------------------------------------------------

    def _recentre(self, xy: np.ndarray) -> None:
        """Keep the rover in the central half of the window; shift the grids if not."""
        half = 0.5 * self.cfg.window_m
        if self.origin is None:
            self.origin = np.floor((xy - half) / self.cfg.cell_m) * self.cfg.cell_m
            return
        centre = self.origin + half
        if np.all(np.abs(xy - centre) < 0.25 * self.cfg.window_m):
            return
        new_origin = np.floor((xy - half) / self.cfg.cell_m) * self.cfg.cell_m
        shift = np.round((new_origin - self.origin) / self.cfg.cell_m).astype(int)
        for name in ("w", "wz", "wzz", "npairs", "nb", "bs", "bv"):
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
        sig_r = dist**2 / fxb * c.disparity_sigma_px
        sig_r_per_m = sig_r / np.maximum(dist, 1e-6)
        sig_z = np.hypot(sig_r_per_m * np.abs(rel[:, 2]), c.height_floor_m)
        # A point misplaced along its ray lands in another cell: over terrain of gradient
        # g that is a height error of g times the horizontal part of the range error.
        sig_z = np.hypot(sig_z, c.placement_gradient * sig_r_per_m
                         * np.hypot(rel[:, 0], rel[:, 1]))
        wt = 1.0 / sig_z**2
        ij = np.floor((pts[:, :2] - self.origin) / c.cell_m).astype(np.int64)
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
        pw = np.minimum(pw[hit], c.max_pair_weight)
        for acc, v in ((self.w, pw), (self.wz, pw * pz), (self.wzz, pw * pz * pz),
                       (self.npairs, 1.0)):
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

    def detect(self, t: float, odom_cov: np.ndarray | None = None) -> list[MapRoi]:
        """One detection round over the cells touched since the last one (plus a margin):
        update the ROI list and return the regions found this round (odom)."""
        c = self.cfg
        if not self._touched or self.origin is None:
            return []
        box = np.array(self._touched)
        self._touched = []
        margin = int(np.ceil(2 * c.ground_window_m / c.cell_m))
        i0, j0 = np.maximum(box[:, :2].min(axis=0) - margin, 0)
        i1, j1 = np.minimum(box[:, 2:].max(axis=0) + margin + 1, self.n)
        found = self._regions(slice(i0, i1), slice(j0, j1))
        cov = np.zeros((2, 2)) if odom_cov is None else np.asarray(odom_cov, float)
        matched = set()
        for r in found:
            r.odom_cov, r.last_t = cov, t
            matched.add(self._associate(r))
        # ROIs whose cells were re-examined (inside the touched box) and not found again.
        lo = box[:, :2].min(axis=0) * c.cell_m + self.origin
        hi = (box[:, 2:].max(axis=0) + 1) * c.cell_m + self.origin
        for r in self.rois:
            if r.id not in matched and np.all(r.xy >= lo) and np.all(r.xy <= hi):
                r.examined += 1
        return found

    def _regions(self, si: slice, sj: slice) -> list[MapRoi]:
        c = self.cfg
        z, seen, sd = self.heights(si, sj, with_sd=True)
        if seen.sum() < 50:
            return []
        ground = ground_surface(z, seen, c.ground_window_m / c.cell_m,
                                max(1, round(c.ground_cell_m / c.cell_m)),
                                c.ground_percentile)
        rel = np.where(seen, z - ground, 0.0)
        out: list[MapRoi] = []
        off = np.array([si.start, sj.start])
        # The relative value and saturation of the cells: the rocks' dark test reads the
        # value, the map rocks' features both.
        colour = None
        if self.nb.any():
            nb = np.maximum(self.nb[si, sj], 1)
            colour = (self.bv[si, sj] / nb, self.bs[si, sj] / nb)
        val = colour[0] if colour is not None and c.rock_dark_value > 0 else None
        # Rock seeds stand high in every view: the mean less one spread across views (a
        # stereo mismatch of one view is a high spread, not a rock).
        out += self._rocks(rel, np.where(seen, rel - sd, 0.0), z, seen, off, val, colour)
        if colour is not None:
            out += self._outcrops(rel, ground, seen, si, sj, off, colour)
        return out

    def heights(self, si: slice = slice(None), sj: slice = slice(None), with_sd: bool = False):
        """Mean height (odom z, NaN where unobserved) and the observed mask of a window;
        with ``with_sd`` also the spread of the height across the pairs (m)."""
        c = self.cfg
        w = self.w[si, sj]
        mean = self.wz[si, sj] / np.maximum(w, 1e-9)
        var = self.wzz[si, sj] / np.maximum(w, 1e-9) - mean**2
        seen = (w >= c.min_cell_weight) & (self.npairs[si, sj] >= c.min_pairs) & \
            (var <= c.max_cell_sd_m**2)
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
        s = sigma_m / self.cfg.cell_m
        n = ndimage.gaussian_filter(self.nb[si, sj], s)
        sat = ndimage.gaussian_filter(self.bs[si, sj], s) / np.maximum(n, 1e-6)
        val = ndimage.gaussian_filter(self.bv[si, sj], s) / np.maximum(n, 1e-6)
        return n > 0.5, sat, val

    def _cell_xy(self, ij: np.ndarray) -> np.ndarray:
        """Odom x, y of the centres of cells ``ij`` (indices in the whole map)."""
        return (ij + 0.5) * self.cfg.cell_m + self.origin

    def _measure(self, label: int, cells: np.ndarray, off: np.ndarray, z_ground: float,
                 height: float) -> MapRoi | None:
        c = self.cfg
        xy = self._cell_xy(cells + off)
        if len(xy) < 3:
            return None
        hull = cv2.convexHull(xy.astype(np.float32))
        # The centre of the footprint's convex hull: a rock seen from one side maps as a
        # crescent (its top and far side hidden), whose hull still spans the rock.
        mo = cv2.moments(hull)
        centre = np.array([mo["m10"], mo["m01"]]) / mo["m00"] if mo["m00"] > 0 else \
            xy.mean(axis=0)
        area = float(cv2.contourArea(hull)) + c.cell_m * np.sqrt(len(xy)) * c.cell_m
        area = max(area, len(xy) * c.cell_m**2)
        w, v = np.linalg.eigh(np.cov(xy.T) + np.eye(2) * c.cell_m**2 / 12)
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
        grow = rel > c.rock_grow_height_m
        if val is not None:
            dark = val < c.rock_dark_value
            grow &= dark | (rel > c.rock_seed_height_m)
            pale_seeds = seeds & (rel_low > c.rock_pale_seed_height_m) \
                if c.rock_pale_seed_height_m > 0 else np.zeros_like(seeds)
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
        if c.rock_split_peaks:
            lab, n = self._split_peaks(rel, seeds & mask, mask)
        else:
            lab, n = ndimage.label(mask)
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
            if len(cells) * c.cell_m**2 < 0.25 * c.rock_min_area_m2:
                trace("small", n_cells=len(cells))
                continue
            # The ground around the rock: a plane through the ring of cells 0.1-0.5 m
            # outside it (a slope is no rock), which must be mostly observed (at the
            # edge of the seen terrain the ground is a guess).
            ring = ndimage.binary_dilation(reg, iterations=5) & ring_all[pad]
            ring_seen = ring & seen[pad]
            plane = None
            if ring_seen.sum() >= max(8, c.rock_min_ring_seen * ring.sum()):
                plane = _plane(np.argwhere(ring_seen), z[pad][ring_seen])
            if plane is None:
                trace("ring_unseen", ring_seen=float(ring_seen.sum() / max(ring.sum(), 1)))
                continue
            above = z[pad][reg] - (plane[0] * cells[:, 0] + plane[1] * cells[:, 1] + plane[2])
            height = float(np.percentile(above, 95))
            min_height = max(c.rock_min_height_m, c.rock_pale_seed_height_m) if is_pale[k] \
                else c.rock_min_height_m
            if height <= min_height:
                trace("low", height_m=height)
                continue
            r = self._measure(ROCK, cells + corner, off, float(np.median(z[pad][ring_seen])),
                              height)
            if r is None or not c.rock_min_area_m2 < r.area_m2 < c.rock_max_area_m2 or \
                    (c.rock_max_length_windows > 0
                     and r.major_m > c.rock_max_length_windows * c.ground_window_m):
                trace("area", height_m=height, area_m2=None if r is None else r.area_m2,
                      major_m=None if r is None else r.major_m)
                continue
            # Rocks are not flat: height over equivalent diameter is 0.3-0.8 for boulders
            # (Golombek et al. 2008 on Mars); a broad low bump is terrain. The diameter is
            # the footprint at half the height (full width at half maximum): the skirt of
            # cells a little above the ground (stereo smear around the rock, grown at
            # 0.1 m) widens the footprint but not the width at half height.
            upper = above >= 0.5 * height
            if c.rock_centre == "upper" and upper.sum() >= 3:
                # The rock's centre: that of its cells above half its height (the
                # footprint at half height, as the relief test below measures it). The
                # smear a tall rock leaves behind it, along the rays and lower than the
                # rock, widens the footprint and had moved the hull's centroid off it.
                r.xy = self._cell_xy(cells[upper] + corner + off).mean(axis=0)
            half = max(int(np.count_nonzero(upper)), 1) * c.cell_m**2
            relief = height / np.sqrt(4 * half / np.pi)
            if relief >= c.rock_min_relief_ratio:
                r.features = self._rock_features(
                    r, lab == k, ring_seen, pad, plane, above, rel, rel_low, seen, off,
                    colour, relief, len(cells), bool(is_pale[k]))
                if self.rock_classifier is not None:
                    r.score = float(self.rock_classifier(r.features[None])[0])
                out.append(r)
            trace("rock" if relief >= c.rock_min_relief_ratio else "flat", height_m=height,
                  area_m2=r.area_m2, relief=float(relief))
        return out

    def _rock_features(self, r: MapRoi, reg_full: np.ndarray, ring_seen: np.ndarray,
                       pad: tuple, plane: np.ndarray, above: np.ndarray, rel: np.ndarray,
                       rel_low: np.ndarray, seen: np.ndarray, off: np.ndarray,
                       colour: tuple | None, relief: float, n_cells: int,
                       pale: bool) -> np.ndarray:
        """The :data:`MAP_ROCK_FEATURES` of a rock region (window arrays; ``reg_full``
        the region's mask over the window, ``ring_seen`` the observed ring over ``pad``,
        ``colour`` the relative value and saturation maps or None)."""
        c = self.cfg
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
            dark = float(np.mean(v_reg < c.rock_dark_value))
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
        slope = float(np.hypot(plane[0], plane[1]) / c.cell_m)
        # Clutter around it: the share of the observed cells 0.5-2.5 m outside the region
        # that stand above the grow height and are dark (a field of small rocks, which
        # the map can merge into one false rock, is a crowd of such cells).
        near = round(0.5 / c.cell_m)
        far = round(2.5 / c.cell_m)
        rows, cols = np.nonzero(reg_full)
        box = (slice(max(rows.min() - far, 0), rows.max() + far + 1),
               slice(max(cols.min() - far, 0), cols.max() + far + 1))
        rb = reg_full[box]
        annulus = ndimage.binary_dilation(rb, iterations=far) & \
            ~ndimage.binary_dilation(rb, iterations=near) & seen[box]
        bumpy = rel[box] > c.rock_grow_height_m
        if val is not None:
            bumpy &= val[box] < (c.rock_dark_value or 0.55)
        clutter = float(bumpy[annulus].mean()) if annulus.any() else 0.0
        hull_fill = n_cells * c.cell_m**2 / max(r.area_m2, 1e-6)
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

        c = self.cfg
        it = max(1, round(c.rock_peak_merge_m / c.cell_m / 2))
        markers, n = ndimage.label(ndimage.binary_dilation(seeds, iterations=it) & mask)
        if n == 0:
            return np.zeros(mask.shape, np.int32), 0
        lab = watershed(-rel, markers, mask=mask)
        if c.rock_footprint_fraction > 0:
            # Each region's footprint: its cells above a fraction of its peak height (the
            # low cells a region climbs from, debris or stereo smear, shared with the
            # next peak, are not the rock).
            peak = ndimage.maximum(rel, lab, np.arange(n + 1))
            lab = np.where(rel >= c.rock_footprint_fraction * np.asarray(peak)[lab], lab, 0)
        return lab, n

    def _outcrops(self, rel, ground, seen, si, sj, off, colour) -> list[MapRoi]:
        """The outcrop regions of the window ``si``, ``sj`` (``colour``: its cells'
        relative value and saturation, as :meth:`_regions` reads them)."""
        c = self.cfg
        nb = self.nb[si, sj]
        if (nb > 0).sum() < 100:
            return []
        if c.outcrop_colour_sigma_m > 0:
            # The colour averaged over a small neighbourhood, every cell with colour
            # samples contributing (a slab seen from afar is observed in sparse stripes of
            # cells, and its per-cell colour scatters across the thresholds).
            have, sat, val = self.averaged_colour(c.outcrop_colour_sigma_m, si, sj)
            low = ~(seen & (rel >= c.max_outcrop_height_m))
        else:
            have = seen & (nb > 0)
            val, sat = colour
            low = rel < c.max_outcrop_height_m
        pale = self.outcrop_colour(have, sat, val) & low
        pale = ndimage.binary_opening(pale, iterations=c.outcrop_opening)
        pale = ndimage.binary_closing(pale, iterations=3) & have
        lab, _ = ndimage.label(pale)
        out = []
        for k, sl in enumerate(ndimage.find_objects(lab), start=1):
            if sl is None:
                continue
            reg = lab[sl] == k
            if reg.sum() * c.cell_m**2 < c.outcrop_min_cells_fraction * c.outcrop_min_area_m2:
                continue
            cells = np.argwhere(reg) + np.array([sl[0].start, sl[1].start])
            rel_reg = rel[sl][reg & seen[sl]]
            height = float(np.percentile(rel_reg, 95)) if len(rel_reg) else 0.0
            if height > c.max_outcrop_height_m:
                continue
            r = self._measure(OUTCROP, cells, off, float(np.nanmedian(ground[sl][reg])), height)
            if r is not None and r.area_m2 >= c.outcrop_min_area_m2:
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
        the reddish soil (``outcrop_max_saturation``; and, with ``outcrop_soil_ratio``,
        than the soil around them) and not dark (rocks, desert pavement and rock shadows
        are dark: ``outcrop_min_value``)."""
        c = self.cfg
        grey = sat < c.outcrop_max_saturation
        if c.outcrop_soil_ratio > 0:
            grey |= sat < c.outcrop_soil_ratio * self._soil_saturation(have & ~grey, sat)
        return have & grey & (val > c.outcrop_min_value)

    def _soil_saturation(self, soil: np.ndarray, sat: np.ndarray) -> np.ndarray:
        """The saturation of the ``soil`` cells around each cell (Gaussian,
        ``outcrop_soil_sigma_m``), inf where none is near."""
        c = self.cfg
        # On blocks of ~0.5 m (the soil varies over metres): sums per block, filtered,
        # each cell given its block's value.
        f = max(1, round(0.5 / c.cell_m))
        h, w_ = soil.shape
        ph, pw = -h % f, -w_ % f

        def blocks(a):
            a = np.pad(a.astype(np.float32), ((0, ph), (0, pw)))
            return a.reshape(a.shape[0] // f, f, a.shape[1] // f, f).sum(axis=(1, 3))

        s = c.outcrop_soil_sigma_m / (c.cell_m * f)
        w = ndimage.gaussian_filter(blocks(soil), s)
        ws = ndimage.gaussian_filter(blocks(np.where(soil, sat, 0.0)), s)
        bg = np.where(w > 1e-3, ws / np.maximum(w, 1e-6), np.inf)
        return np.repeat(np.repeat(bg, f, axis=0), f, axis=1)[:h, :w_]

    def _outcrop_features(self, r: MapRoi, reg_full: np.ndarray, rel: np.ndarray,
                          seen: np.ndarray, colour: tuple, nb: np.ndarray,
                          npairs: np.ndarray) -> np.ndarray:
        """The :data:`MAP_OUTCROP_FEATURES` of an outcrop region (window arrays:
        ``reg_full`` its mask, ``rel`` the height above the ground, ``colour`` the cells'
        relative value and saturation, ``nb`` their colour samples, ``npairs`` the pairs
        that saw them)."""
        c = self.cfg
        val, sat = colour
        rows, cols = np.nonzero(reg_full)
        far = round(1.5 / c.cell_m)
        box = (slice(max(rows.min() - far, 0), rows.max() + far + 1),
               slice(max(cols.min() - far, 0), cols.max() + far + 1))
        reg = reg_full[box]
        ring = ndimage.binary_dilation(reg, iterations=far) & \
            ~ndimage.binary_dilation(reg, iterations=round(0.3 / c.cell_m))
        rs, rv, rh, rsn, nbb = (a[box] for a in (sat, val, rel, seen, nb))
        hv = nbb > 0
        in_c = reg & hv
        ring_c = ring & hv
        nan = float("nan")

        def pct(a, q):
            return float(np.percentile(a, q)) if len(a) else nan

        s_in, v_in = rs[in_c], rv[in_c]
        h_in = rh[reg & rsn]
        rocky = (rh > c.rock_grow_height_m) & rsn & (rv < (c.rock_dark_value or 0.55))
        npairs = npairs[box][reg]
        feats = np.array([
            np.log(max(r.area_m2, 1e-3)), reg.sum() * c.cell_m**2 / max(r.area_m2, 1e-6),
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
            s2 = self.cfg.centre_sigma_m**2 + (0.1 * r.major_m) ** 2
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

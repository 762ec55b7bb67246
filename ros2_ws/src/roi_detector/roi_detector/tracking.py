"""ROI tracking across stereo pairs (paper Sec. 4.2) in the odom frame.

Each detection is placed in odom with the odometry pose of its stereo pair and compared
with the tracks so far: when it coincides with a track (its centre within the track's
footprint ellipse, widened by the stereo range error), the track's ellipse and position
are updated; otherwise a new track starts. A track is confirmed after ``min_obs``
observations. Tracks are never dropped when the ROI leaves the view, so the route
passing by an ROI again extends the same track (re-visit), as long as the odometry drift
since is within the gate.

Uncertainty model (per track, odom x-y, m^2): each observation's centre has a stereo
covariance (range error along the line of sight, a lateral error across it, plus the
scatter of a partly seen footprint) rotated into odom; the track's position is their
information-weighted mean, and its covariance that mean's covariance plus the odometry
position covariance at the observations (averaged: odometry errors of observations a few
metres apart are nearly the same error, so they do not average out).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from roi_network.records import OUTCROP, ROCK, empty_records

#: The association gate widens by this many stereo range sigmas of the observation.
GATE_RANGE_SIGMAS = 3.0
#: A track is kept (published, fed to the LN) only while it was detected in at least
#: this fraction of the pairs that had its centre in view within range: rocks are
#: re-detected pair after pair, terrain swells and clutter flicker.
MIN_HIT_RATIO = 0.5
#: 1-sigma error of an observed centre across the line of sight, m.
LATERAL_SIGMA_M = 0.05
#: Extra centre error as a fraction of the footprint's major axis (a partly seen ROI's
#: centre moves as more of it is seen).
FOOTPRINT_SIGMA_FRAC = 0.15
#: Per-track observations kept for the medians of area and height.
MAX_OBS_KEPT = 64


@dataclass(frozen=True)
class TrackerConfig:
    """Association and confirmation parameters.

    Attributes:
        gate_m: smallest association radius, metres.
        min_obs: observations that confirm a track.
    """

    gate_m: float = 1.0
    min_obs: int = 3


@dataclass
class Observation:
    """One detection placed in odom.

    Attributes:
        t: stamp, seconds. xy: (2,) centre in odom, m. z: ground height in odom, m.
        cov: (2, 2) stereo covariance of the centre in odom, m^2.
        odom_cov: (2, 2) odometry position covariance at the stamp, m^2.
        label: classified label (ROCK / OUTCROP). score: classifier score in [0, 1].
        area_m2, height_m: footprint area and height. moments: (2, 2) footprint second
        moments in odom, m^2.
    """

    t: float
    xy: np.ndarray
    z: float
    cov: np.ndarray
    odom_cov: np.ndarray
    label: int
    score: float
    area_m2: float
    height_m: float
    moments: np.ndarray


@dataclass
class Track:
    """An ROI followed across stereo pairs, in odom."""

    id: int
    info: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    info_xy: np.ndarray = field(default_factory=lambda: np.zeros(2))
    odom_cov_sum: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    z_sum: float = 0.0
    n_obs: int = 0
    label_votes: dict[int, float] = field(default_factory=lambda: {ROCK: 0.0, OUTCROP: 0.0})
    score_sum: float = 0.0
    areas: list[float] = field(default_factory=list)
    heights: list[float] = field(default_factory=list)
    moments_sum: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    first_t: float = 0.0
    last_t: float = 0.0
    n_missed: int = 0

    @property
    def xy(self) -> np.ndarray:
        """Information-weighted centre in odom, metres."""
        return np.linalg.solve(self.info, self.info_xy)

    @property
    def label(self) -> int:
        """Class with the most classifier score over the observations."""
        return max(self.label_votes, key=lambda k: self.label_votes[k])

    @property
    def covariance(self) -> np.ndarray:
        """(2, 2) odom x-y covariance of the centre: stereo mean + odometry, m^2."""
        return np.linalg.inv(self.info) + self.odom_cov_sum / max(self.n_obs, 1)

    @property
    def ellipse(self) -> tuple[float, float, float]:
        """(major, minor, angle) of the mean footprint second moments (full axes, m)."""
        m = self.moments_sum / max(self.n_obs, 1)
        w, v = np.linalg.eigh(m)
        w = np.clip(w, 0.0, None)
        return 4 * float(np.sqrt(w[1])), 4 * float(np.sqrt(w[0])), float(np.arctan2(v[1, 1],
                                                                                   v[0, 1]))

    def add(self, obs: Observation, max_kept: int) -> None:
        """Update the track with one observation."""
        w = np.linalg.inv(obs.cov)
        self.info = self.info + w
        self.info_xy = self.info_xy + w @ obs.xy
        self.odom_cov_sum = self.odom_cov_sum + obs.odom_cov
        self.z_sum += obs.z
        if self.n_obs == 0:
            self.first_t = obs.t
        self.n_obs += 1
        self.last_t = obs.t
        self.label_votes[obs.label] = self.label_votes.get(obs.label, 0.0) + max(obs.score, 1e-3)
        self.score_sum += obs.score
        self.moments_sum = self.moments_sum + obs.moments
        if len(self.areas) < max_kept:
            self.areas.append(obs.area_m2)
            self.heights.append(obs.height_m)


def observation_covariance(bearing_odom: np.ndarray, range_sigma: float,
                           major_m: float) -> np.ndarray:
    """(2, 2) odom covariance of an observed centre: range error along the line of sight
    ``bearing_odom`` (unit x-y), lateral error across it, footprint scatter on both."""
    b = np.asarray(bearing_odom, float)
    b = b / max(float(np.hypot(*b)), 1e-9)
    n = np.array([-b[1], b[0]])
    extra = (FOOTPRINT_SIGMA_FRAC * major_m) ** 2
    return ((range_sigma**2 + extra) * np.outer(b, b)
            + (LATERAL_SIGMA_M**2 + extra) * np.outer(n, n))


class Tracker:
    """The set of tracks of a drive, in odom."""

    def __init__(self, cfg: TrackerConfig = TrackerConfig(), first_id: int = 1) -> None:
        self.cfg = cfg
        self.tracks: list[Track] = []
        self._next_id = first_id
        self._pair_t: float | None = None

    def update(self, observations: list[Observation]) -> list[Track]:
        """Associate one stereo pair's observations with the tracks; return those touched.

        Each track takes at most one observation per pair (the nearest), so two ROIs
        side by side never fold into one track in a single frame.
        """
        touched: list[Track] = []
        self._pair_t = observations[0].t if observations else None
        centres = np.array([t.xy for t in self.tracks]) if self.tracks else np.zeros((0, 2))
        taken: set[int] = set()
        for obs in sorted(observations, key=lambda o: -o.area_m2):
            best, best_d = None, np.inf
            if len(centres):
                d = np.hypot(*(centres - obs.xy).T)
                for i in np.argsort(d)[:5]:
                    if i in taken:
                        continue
                    tr = self.tracks[i]
                    gate = max(self.cfg.gate_m, 0.5 * tr.ellipse[0]) + \
                        GATE_RANGE_SIGMAS * float(np.sqrt(np.trace(obs.cov) / 2))
                    if d[i] < gate and d[i] < best_d:
                        best, best_d = int(i), float(d[i])
            if best is None:
                tr = Track(self._next_id)
                self._next_id += 1
                self.tracks.append(tr)
                centres = np.vstack([centres, obs.xy])
                best = len(self.tracks) - 1
            else:
                tr = self.tracks[best]
            tr.add(obs, MAX_OBS_KEPT)
            centres[best] = tr.xy
            taken.add(best)
            touched.append(tr)
        return touched

    def confirmed(self) -> list[Track]:
        """Tracks with at least ``min_obs`` observations."""
        return [t for t in self.tracks if t.n_obs >= self.cfg.min_obs]

    def mark_missed(self, in_view) -> None:
        """Count a miss for every track not touched by this pair whose centre
        ``in_view(xy_odom)`` says the pair saw."""
        for t in self.tracks:
            if t.last_t != self._pair_t and in_view(t.xy):
                t.n_missed += 1

    def consistent(self) -> list[Track]:
        """Tracks detected in at least :data:`MIN_HIT_RATIO` of the pairs that saw them."""
        r = MIN_HIT_RATIO
        return [t for t in self.tracks if t.n_obs >= r * (t.n_obs + t.n_missed)]


def tracks_to_records(tracks: list[Track]) -> np.ndarray:
    """ROI records (odom) of tracks: centre, voted class, medians, ellipse, covariance."""
    rec = empty_records(len(tracks))
    for r, t in zip(rec, tracks, strict=True):
        x, y = t.xy
        major, minor, angle = t.ellipse
        cov = t.covariance
        r["x"], r["y"], r["z"] = x, y, t.z_sum / max(t.n_obs, 1)
        r["id"], r["label"] = t.id, t.label
        r["area_m2"] = float(np.median(t.areas)) if t.areas else 0.0
        r["height_m"] = float(np.median(t.heights)) if t.heights else 0.0
        r["major_m"], r["minor_m"], r["angle_rad"] = major, minor, angle
        votes = sum(t.label_votes.values())
        r["score"] = t.label_votes[t.label] / votes if votes > 0 else 0.0
        r["cov_xx"], r["cov_xy"], r["cov_yy"] = cov[0, 0], cov[0, 1], cov[1, 1]
        r["n_obs"] = t.n_obs
    return rec

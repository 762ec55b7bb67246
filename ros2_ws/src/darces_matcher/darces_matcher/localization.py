"""Localization while driving: a filter over the map -> odom alignment (no rclpy).

The matcher re-matches the LN each time it grows; each fix is a measurement of the
alignment ``map_T_odom`` (x, y, yaw) with a covariance. :class:`MapOdomFilter` keeps one
estimate of that alignment and its covariance:

- **Prediction (drift).** ``map_T_odom`` is, by definition, what makes the odometry pose
  land on the true pose: as visual odometry drifts, the true alignment drifts with it. Each
  odometry pose grows the covariance by process noise proportional to the distance driven
  since the previous one (a random walk of the VO error): ``drift_xy_m2_per_m`` on the
  position, ``drift_yaw_rad2_per_m`` on the heading, the heading error rotating the
  alignment about the rover's current position (the lever arm of the whole route behind
  it does not matter, only where the rover is now). When the odometry's heading is
  bounded by absolute updates (rover_vo's sun heading: ``heading_bound_rad2`` given to
  :meth:`MapOdomFilter.predict`), the heading error no longer walks: the alignment's
  heading variance grows by the random walk only up to its value at the last fix plus
  that bound (the odometry's yaw variance now and at the fix: twice its yaw variance),
  and a fix's lag drift in heading is capped the same way.
- **Update (a fix).** A fix of the whole LN is most accurate where the LN is, not where the
  rover is now: the measurement covariance is inflated by the drift accumulated between
  the point of the route nearest the LN's centroid and the rover. Successive fixes of a
  growing LN share most of their nodes, so their errors are strongly correlated and a
  Kalman update (which assumes independent measurements) would shrink the covariance too
  fast. They are fused by *covariance intersection* (Julier and Uhlmann 1997), consistent
  whatever the correlation: ``P^-1 = w P0^-1 + (1 - w) R^-1`` with ``w`` minimising
  ``det P``. A bigger LN gives a tighter fix, which the fusion then follows, so the
  estimate refines as the LN grows.
- **Local refit.** A fix is refitted on its inlier pairs whose LN node lies within
  ``LOCAL_RADIUS_M`` of the last ``LOCAL_ROUTE_M`` metres of the route, when there are
  at least ``LOCAL_MIN_PAIRS`` of them: the pairs the rover saw recently say where it is
  now, where a fit of the whole LN spreads the VO's drift over the whole route.
- **Gate and switch.** A fix whose Mahalanobis distance to the estimate (``P + R``) exceeds
  ``gate_chi2`` contradicts it: it is *held* (event ``held``), not fused. When
  ``confirm_matches`` consecutive contradicting fixes agree with each other (each within the
  gate of the previous one, drift between them included), the LN has confirmed them: the
  estimate is replaced by the latest (``switched``). A consistent fix in between discards
  the held ones. The first fix needs no confirmation (the matcher's own ambiguity tests
  are trusted).

:func:`global_pose` maps an odometry pose into ``map`` with the estimate. Its horizontal
and heading covariance is the alignment's (propagated through the lever arm): the
alignment's covariance already holds the drift since the last fix, and the VO's own
covariance (the drift since the start of the drive) would count the same error twice.
Roll and pitch keep the odometry's covariance. Height (:func:`ground_altitude`): with an
orbital elevation model, the model's height under the rover's x, y (base_link sits on
the ground), with the model's vertical variance plus the horizontal covariance through
the slope; without one (or off it) z is not estimated, and its variance says so
(:data:`~roi_network.dtm.UNKNOWN_VARIANCE_M2`): the odometry's z is a height change since
the start of the drive, not a map altitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from darces_matcher.ln_drift import PLANAR
from darces_matcher.result import MatchResult
from darces_matcher.vote import alignment_jacobian
from roi_network.dtm import UNKNOWN_VARIANCE_M2, ElevationModel
from roi_network.transform import Rigid2D, wrap_angle

Event = Literal["first_fix", "refined", "held", "switched", "kept", "none"]

#: Events after which the published alignment changed.
ALIGNMENT_EVENTS = ("first_fix", "refined", "switched")
#: Consecutive, mutually consistent fixes needed for the first fix.
CONFIRM_FIRST = 1
#: Floor of a fix's one-sigma position error, metres.
MIN_MATCH_SIGMA_M = 0.1
#: Floor of a fix's one-sigma heading error, radians.
MIN_MATCH_SIGMA_YAW_RAD = 1e-3
#: Spacing of the stored odometry path samples (for the LN's lag), metres.
PATH_STEP_M = 1.0
#: The local refit takes the inlier pairs whose LN node lies within ``LOCAL_RADIUS_M``
#: of the last this many metres of the route.
LOCAL_ROUTE_M = 150.0
#: See ``LOCAL_ROUTE_M``, metres.
LOCAL_RADIUS_M = 20.0
#: Fewest pairs for the local refit (else the whole-LN fit).
LOCAL_MIN_PAIRS = 6
#: Floor of the per-node one-sigma residual the local refit's covariance assumes, metres.
LOCAL_SIGMA_FLOOR_M = 0.3


@dataclass(frozen=True)
class Alignment:
    """The published map -> odom alignment.

    Attributes:
        map_T_odom: pose of ``odom`` in ``map``.
        covariance: (3, 3) covariance of (x, y, yaw), m^2 / rad^2.
        support: LN nodes matched by the last fix fused.
        ln_size: LN nodes at that time.
    """

    map_T_odom: Rigid2D
    covariance: np.ndarray
    support: int
    ln_size: int


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of :class:`MapOdomFilter`.

    Attributes:
        drift_xy_m2_per_m: growth of the alignment's position variance per metre driven,
            m^2/m (0.01: 1 m one-sigma after 100 m, i.e. 1 % drift over 100 m).
        drift_yaw_rad2_per_m: growth of its heading variance per metre driven, rad^2/m
            (3e-6: 1 deg one-sigma after 100 m).
        gate_chi2: Mahalanobis gate (squared, 3 degrees of freedom) beyond which a fix
            contradicts the estimate (16.27: 99.9 %).
        confirm_matches: consecutive, mutually consistent contradicting fixes needed to
            switch (1: switch at once).
    """

    drift_xy_m2_per_m: float = 0.01
    drift_yaw_rad2_per_m: float = 3e-6
    gate_chi2: float = 16.27
    confirm_matches: int = 3

    def __post_init__(self) -> None:
        for name in ("drift_xy_m2_per_m", "drift_yaw_rad2_per_m"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"FilterConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not self.gate_chi2 > 0.0:
            raise ValueError(f"FilterConfig.gate_chi2 must be > 0, got {self.gate_chi2}")
        if self.confirm_matches < 1:
            raise ValueError(
                f"FilterConfig.confirm_matches must be >= 1, got {self.confirm_matches}")


def _vector(t: Rigid2D) -> np.ndarray:
    return np.array([t.tx, t.ty, t.yaw])


def _rigid(x: np.ndarray) -> Rigid2D:
    return Rigid2D(float(x[2]), float(x[0]), float(x[1]))


def _difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a - b
    d[2] = wrap_angle(d[2])
    return d


def _symmetric(m: np.ndarray) -> np.ndarray:
    return 0.5 * (m + m.T)


def covariance_intersection(
    x0: np.ndarray, p0: np.ndarray, x1: np.ndarray, p1: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse two estimates of (x, y, yaw) with unknown correlation.

    Args:
        x0, x1: (3,) estimates (x, y in metres, yaw in radians).
        p0, p1: (3, 3) their covariances.

    Returns:
        The fused estimate and covariance; the weight minimises the fused determinant
        (unit-free, unlike the trace, which would mix m^2 and rad^2).
    """
    i0, i1 = np.linalg.inv(p0), np.linalg.inv(p1)
    d = _difference(x1, x0)  # fuse around x0 so the yaw never wraps mid-sum
    best = None
    for w in np.linspace(0.0, 1.0, 101):
        info = w * i0 + (1.0 - w) * i1
        sign, logdet = np.linalg.slogdet(info)
        if sign > 0 and (best is None or logdet > best[0]):
            best = (logdet, w, info)
    _, w, info = best
    p = np.linalg.inv(info)
    x = x0 + p @ ((1.0 - w) * i1 @ d)
    x[2] = wrap_angle(x[2])
    return x, _symmetric(p)


def fit_with_covariance(
    src: np.ndarray, dst: np.ndarray, sigma_floor_m: float = 0.0
) -> tuple[Rigid2D, np.ndarray]:
    """Least-squares rigid fit ``dst ~ T(src)`` and the covariance of T's (tx, ty, yaw).

    Args:
        src: (N, 2) points in ``odom``, metres, N >= 3.
        dst: (N, 2) corresponding points in ``map``, metres.
        sigma_floor_m: lower bound of the per-point one-sigma residual, metres.

    Returns:
        The transform and its (3, 3) covariance ``sigma^2 (J^T J)^-1``, with ``sigma^2``
        the residual variance (2N - 3 degrees of freedom), at least ``sigma_floor_m^2``.
    """
    t = Rigid2D.fit(src, dst)
    res = t.apply(src) - dst
    sigma2 = max(float((res**2).sum()) / max(2 * len(src) - 3, 1), sigma_floor_m**2)
    jac = alignment_jacobian(np.asarray(src, dtype=float), t.yaw)
    return t, sigma2 * np.linalg.inv(np.einsum("nai,naj->ij", jac, jac))


@dataclass
class _Held:
    x: np.ndarray
    r: np.ndarray
    distance_m: float
    result: MatchResult
    ln_size: int


@dataclass
class MapOdomFilter:
    """Estimate of map -> odom fused from successive fixes and the odometry's drift.

    Call :meth:`predict` with every odometry pose and :meth:`update` with every match
    result; read :attr:`alignment` (None until the first fix).

    Attributes:
        config: the parameters.
        x: (3,) estimate (tx, ty, yaw) of map_T_odom, None before the first fix.
        p: (3, 3) its covariance.
        distance_m: odometry distance driven so far, metres.
        switches: times the estimate was replaced by confirmed contradicting fixes.
        held: contradicting fixes waiting for confirmation (oldest first).
    """

    config: FilterConfig = field(default_factory=FilterConfig)
    x: np.ndarray | None = None
    p: np.ndarray | None = None
    distance_m: float = 0.0
    switches: int = 0
    held: list[_Held] = field(default_factory=list)
    _support: int = 0
    _ln_size: int = 0
    _last_xy: np.ndarray | None = None
    _path_d: list[float] = field(default_factory=list)
    _path_xy: list[np.ndarray] = field(default_factory=list)
    #: Bound of the odometry's heading error change (rad^2), None while it drifts freely.
    heading_bound_rad2: float | None = None
    _yaw_var_fix: float = 0.0  # the alignment's heading variance after the last fix

    @property
    def localized(self) -> bool:
        """True after the first fix."""
        return self.x is not None

    @property
    def alignment(self) -> Alignment | None:
        """The current estimate, or None before the first fix."""
        if self.x is None:
            return None
        return Alignment(_rigid(self.x), self.p.copy(), self._support, self._ln_size)

    def drift_noise(self, x: np.ndarray, rover_xy: np.ndarray, d_m: float) -> np.ndarray:
        """Process noise of the alignment ``x`` over ``d_m`` metres driven at ``rover_xy``
        (its heading part at most ``heading_bound_rad2`` when that is set).

        Args:
            x: (3,) alignment (tx, ty, yaw).
            rover_xy: (2,) the rover's position in ``odom``, metres.
            d_m: distance driven, metres.

        Returns:
            (3, 3) covariance increment: the VO's position and heading error (the
            configured random walk per metre times ``d_m``), the heading error rotating
            the alignment about the rover's position in ``map``.
        """
        c = self.config
        q = np.diag([c.drift_xy_m2_per_m, c.drift_xy_m2_per_m, c.drift_yaw_rad2_per_m]) * d_m
        if self.heading_bound_rad2 is not None:
            q[2, 2] = min(q[2, 2], self.heading_bound_rad2)
        rover_map = _rigid(x).apply(np.asarray(rover_xy, dtype=float))
        lever = x[:2] - rover_map
        g = np.array([[1.0, 0.0, -lever[1]], [0.0, 1.0, lever[0]], [0.0, 0.0, 1.0]])
        return g @ q @ g.T

    def predict(self, odom_xy: np.ndarray, heading_bound_rad2: float | None = None) -> None:
        """Account for the drive from the previous odometry pose to ``odom_xy`` (odom, m):
        the configured random walk per metre driven (a VO's own covariance since the
        start of the drive need not be its honest error).

        Args:
            odom_xy: (2,) the rover's position in ``odom``, metres.
            heading_bound_rad2: while the odometry's heading is bounded by absolute
                updates, the most its error can change (rad^2; e.g. twice its yaw
                variance); None: it drifts, the random walk holds.
        """
        if heading_bound_rad2 is not None and not (math.isfinite(heading_bound_rad2)
                                                   and heading_bound_rad2 >= 0.0):
            heading_bound_rad2 = None
        self.heading_bound_rad2 = heading_bound_rad2
        xy = np.asarray(odom_xy, dtype=float)[:2]
        if self._last_xy is None:
            self._last_xy = xy
            self._path_d.append(0.0)
            self._path_xy.append(xy)
            return
        step = float(np.linalg.norm(xy - self._last_xy))
        self._last_xy = xy
        if step == 0.0:
            return
        self.distance_m += step
        if self.x is not None:
            self.p = _symmetric(self.p + self.drift_noise(self.x, xy, step))
            if heading_bound_rad2 is not None:
                cap = self._yaw_var_fix + heading_bound_rad2
                if self.p[2, 2] > cap:
                    # scale the heading's row and column: the covariance stays one
                    d = np.array([1.0, 1.0, math.sqrt(cap / self.p[2, 2])])
                    self.p = _symmetric(self.p * np.outer(d, d))
        if self.distance_m - self._path_d[-1] >= PATH_STEP_M:
            self._path_d.append(self.distance_m)
            self._path_xy.append(xy)

    def lag_m(self, ln_xy: np.ndarray) -> float:
        """Distance driven since the point of the route nearest the LN's centroid, m."""
        if len(ln_xy) == 0 or not self._path_xy:
            return 0.0
        centroid = np.asarray(ln_xy, dtype=float).mean(axis=0)
        path = np.asarray(self._path_xy)
        k = int(np.argmin(np.linalg.norm(path - centroid, axis=1)))
        return max(self.distance_m - self._path_d[k], 0.0)

    def local_fit(
        self, result: MatchResult, ln_xy: np.ndarray, gn_xy: np.ndarray
    ) -> tuple[Rigid2D, np.ndarray, np.ndarray] | None:
        """Refit a fix on its inlier pairs near the recent route.

        A fit of the whole LN spreads the VO's drift over the whole route; the pairs the
        rover saw recently say where it is now. Returns (transform, covariance, the LN
        nodes used) or None when fewer than ``LOCAL_MIN_PAIRS`` qualify or they are
        degenerate.
        """
        if len(result.inliers) < LOCAL_MIN_PAIRS or not self._path_xy:
            return None
        path_d = np.asarray(self._path_d)
        recent = np.asarray(self._path_xy)[path_d >= self.distance_m - LOCAL_ROUTE_M]
        if self._last_xy is not None:
            recent = np.vstack([recent, self._last_xy])
        pairs = np.asarray(result.inliers, dtype=np.int64).reshape(-1, 2)
        src, dst = ln_xy[pairs[:, 0]], gn_xy[pairs[:, 1]]
        near = np.min(np.linalg.norm(src[:, None] - recent[None], axis=2), axis=1)
        keep = near <= LOCAL_RADIUS_M
        if keep.sum() < LOCAL_MIN_PAIRS:
            return None
        try:
            t, cov = fit_with_covariance(src[keep], dst[keep], LOCAL_SIGMA_FLOOR_M)
        except (ValueError, np.linalg.LinAlgError):
            return None
        if not np.all(np.isfinite(cov)):
            return None
        return t, cov, src[keep]

    def measurement(
        self, result: MatchResult, ln_xy: np.ndarray, gn_xy: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """A fix as a measurement of the current alignment: (3,) value, (3, 3) covariance.

        With the GN's positions ``gn_xy`` (map, m), the fix is refitted on its recent
        pairs (:meth:`local_fit`) when there are enough of them.
        """
        local = self.local_fit(result, ln_xy, gn_xy) if gn_xy is not None else None
        if local is not None:
            t, cov, used = local
        else:
            t, cov, used = result.map_T_odom, result.covariance, ln_xy
            if cov is None or np.shape(cov) != (3, 3) or not np.all(np.isfinite(cov)):
                raise ValueError("MatchResult.covariance must be a finite (3, 3) matrix on a fix")
        z = _vector(t)
        r = _symmetric(np.asarray(cov, dtype=float))
        r += np.diag([MIN_MATCH_SIGMA_M**2, MIN_MATCH_SIGMA_M**2, MIN_MATCH_SIGMA_YAW_RAD**2])
        rover = self._last_xy if self._last_xy is not None else np.zeros(2)
        r += self.drift_noise(z, rover, self.lag_m(used))
        return z, _symmetric(r)

    def update(
        self, result: MatchResult, ln_xy: np.ndarray, gn_xy: np.ndarray | None = None
    ) -> Event:
        """Fold one match result of the LN whose node positions (odom, m) are ``ln_xy``.

        ``gn_xy`` (the GN's node positions, map, m, indexed like ``result.inliers``)
        enables the local refit of :meth:`measurement`.

        Returns:
            ``first_fix``, ``refined`` (fused), ``held`` (contradicting, waiting for
            confirmation), ``switched`` (confirmed contradiction replaced the estimate),
            ``kept`` (no fix, estimate unchanged) or ``none`` (no fix, not localized).
        """
        if not result.is_fix or result.map_T_odom is None:
            return "kept" if self.localized else "none"
        ln_xy = np.asarray(ln_xy, dtype=float).reshape(-1, 2)
        z, r = self.measurement(result, ln_xy, gn_xy)
        n = len(ln_xy)
        if self.x is not None:
            d = _difference(z, self.x)
            if d @ np.linalg.solve(self.p + r, d) <= self.config.gate_chi2:
                self.x, self.p = covariance_intersection(self.x, self.p, z, r)
                self._support, self._ln_size = result.support, n
                self.held.clear()
                self._yaw_var_fix = float(self.p[2, 2])
                return "refined"
        if self.held:
            last = self.held[-1]
            # The held fix's covariance grew by the drift driven since it was made.
            rover = self._last_xy if self._last_xy is not None else np.zeros(2)
            grown = last.r + self.drift_noise(last.x, rover, self.distance_m - last.distance_m)
            d = _difference(z, last.x)
            if d @ np.linalg.solve(grown + r, d) > self.config.gate_chi2:
                self.held.clear()  # contradicts the held ones too: start over
        self.held.append(_Held(z, r, self.distance_m, result, n))
        first = self.x is None
        needed = CONFIRM_FIRST if first else self.config.confirm_matches
        if len(self.held) < needed:
            return "held"
        self.x, self.p = z, r
        self._support, self._ln_size = result.support, n
        self.held.clear()
        self._yaw_var_fix = float(self.p[2, 2])
        if first:
            return "first_fix"
        self.switches += 1
        return "switched"


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation by ``yaw`` radians about z."""
    return np.array([0.0, 0.0, np.sin(yaw / 2.0), np.cos(yaw / 2.0)])


def compose_pose(
    alignment: Alignment,
    position: np.ndarray,
    quaternion: np.ndarray,
    covariance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map an odometry pose (odom -> base_link) into ``map``.

    Args:
        alignment: the map -> odom alignment (2D: x, y, yaw).
        position: (3,) base_link position in ``odom``, metres.
        quaternion: (4,) orientation (x, y, z, w) in ``odom``.
        covariance: (6, 6) odometry pose covariance (x, y, z, roll, pitch, yaw), in odom.

    Returns:
        Position (3,), quaternion (4,) and (6, 6) covariance in ``map``. The covariance
        adds the alignment's (x, y, yaw) uncertainty, propagated through the lever arm
        of the position in ``odom``, to the odometry covariance rotated into ``map``.
    """
    t = alignment.map_T_odom
    xy = t.apply(np.asarray(position[:2], dtype=float))
    pos = np.array([xy[0], xy[1], float(position[2])])
    rot = Rotation.from_quat(yaw_quaternion(t.yaw)) * Rotation.from_quat(quaternion)
    # Odometry covariance: position block rotated by yaw (z, angles unchanged to first
    # order for a rotation about z).
    r6 = np.eye(6)
    r6[:2, :2] = t.rotation
    cov = r6 @ np.asarray(covariance, dtype=float).reshape(6, 6) @ r6.T
    # Alignment covariance through d(map xy)/d(tx, ty, yaw) of the odom position.
    jac = np.zeros((6, 3))
    jac[:2] = alignment_jacobian(np.asarray(position[:2], dtype=float)[None], t.yaw)[0]
    jac[5, 2] = 1.0  # map yaw = alignment yaw + odom yaw
    cov += jac @ alignment.covariance @ jac.T
    return pos, rot.as_quat(), cov


def global_pose(
    alignment: Alignment,
    position: np.ndarray,
    quaternion: np.ndarray,
    odom_covariance: np.ndarray,
    dtm: ElevationModel | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rover's pose in ``map`` from an odometry pose and the filtered alignment.

    Args:
        alignment: the filter's estimate (its covariance includes the drift since the
            last fix).
        position: (3,) base_link position in ``odom``, metres.
        quaternion: (4,) orientation (x, y, z, w) in ``odom``.
        odom_covariance: (6, 6) odometry covariance (x, y, z, roll, pitch, yaw).
        dtm: the orbital elevation model in ``map``, or None.

    Returns:
        Position (3,), quaternion (4,), (6, 6) covariance in ``map``: x, y, yaw from the
        alignment through the lever arm (the odometry's own x, y, yaw covariance, drift
        since the start, is already in the alignment's), roll, pitch from the odometry,
        z from :func:`ground_altitude`.
    """
    cov = np.array(odom_covariance, dtype=float).reshape(6, 6)
    cov[PLANAR, :] = 0.0
    cov[:, PLANAR] = 0.0
    pos, quat, cov = compose_pose(alignment, position, quaternion, cov)
    pos, cov = ground_altitude(pos, cov, dtm)
    return pos, quat, cov


def ground_altitude(position: np.ndarray, covariance: np.ndarray,
                    dtm: ElevationModel | None) -> tuple[np.ndarray, np.ndarray]:
    """The map pose's z and its covariance row from the elevation model under it.

    base_link's origin is on the ground under the rover (DESIGN.md Frames): z is the
    model's height at (x, y), ``z = h(x, y) + e`` with ``e`` the model's vertical error,
    so its covariance with every other coordinate ``s`` is ``g^T cov((x, y), s)`` (``g``
    the model's gradient) and its variance ``sigma_v^2 + g^T C_xy g``. Without a model, or
    off it, z keeps its value (the odometry's height change since the start) and is marked
    not estimated: variance :data:`~roi_network.dtm.UNKNOWN_VARIANCE_M2`, no correlation.

    Args:
        position: (3,) map position.
        covariance: (6, 6) map pose covariance (x, y, z, roll, pitch, yaw).
        dtm: the elevation model, or None.

    Returns:
        The position and covariance with z replaced (new arrays).
    """
    pos = np.array(position, dtype=float)
    cov = np.array(covariance, dtype=float).reshape(6, 6)
    cov[2, :] = 0.0
    cov[:, 2] = 0.0
    z = math.nan
    if dtm is not None:
        z, grad, var = dtm.ground_z(pos[0], pos[1], cov[:2, :2])
    if not math.isfinite(z):
        cov[2, 2] = UNKNOWN_VARIANCE_M2
        return pos, cov
    pos[2] = z
    cross = grad @ cov[:2, :]
    cov[2, :] = cross
    cov[:, 2] = cross
    cov[2, 2] = var
    return pos, cov

"""Stereo geometry of the rover's rectified pair: disparity, 3D points, local ground.

Frames: ``base_link`` (x forward, y left, z up, origin on the ground under the rover
centre) and the left optical frame (z forward, x right, y down). The camera model comes
only from the pipeline's inputs: CameraInfo (K of the left camera, ``P[3] = -fx * B`` of
the right one) and the left camera's pose in base_link: the ``base_to_left_camera``
extrinsic of ``rover.yaml``, or, on a pan-tilt mast, the pair's own pose
(:class:`roi_network.mast.CameraPoser`, :meth:`StereoCamera.at_pose`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.mast import same_pose


@dataclass(frozen=True)
class StereoCamera:
    """Rectified stereo pair: left intrinsics, baseline and left-camera pose in base_link.

    Attributes:
        fx, fy, cx, cy: left (= right) rectified intrinsics, pixels.
        baseline_m: distance between the optical centres, metres.
        width, height: image size, pixels.
        r_base_cam: (3, 3) rotation of optical-frame vectors into base_link.
        t_base_cam: (3,) left optical centre in base_link, metres.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    width: int
    height: int
    r_base_cam: np.ndarray
    t_base_cam: np.ndarray

    @classmethod
    def from_camera_info(cls, k: np.ndarray, right_p: np.ndarray, width: int, height: int,
                         base_to_left_camera) -> StereoCamera:
        """Build the model from CameraInfo fields and the left camera's pose.

        Args:
            k: the left camera's rectified intrinsics (9 values, row-major 3x3: its
                CameraInfo P's left 3x3, :class:`~roi_detector.inputs.FrameMaker`).
            right_p: right CameraInfo ``p`` (12 values); ``p[3] = -fx * baseline``.
            width, height: image size, pixels.
            base_to_left_camera: ``[x, y, z, qx, qy, qz, qw]``, left optical frame in
                base_link (rover.yaml), or its 4x4 matrix ``base_T_left`` (a mast's pose
                at the pair's stamp).

        Raises:
            ValueError: naming the field that is inconsistent.
        """
        k = np.asarray(k, float).reshape(3, 3)
        p = np.asarray(right_p, float).reshape(3, 4)
        if not (k[0, 0] > 0 and k[1, 1] > 0):
            raise ValueError(f"/stereo/left/camera_info: rectified focal lengths fx = "
                             f"{k[0, 0]:g}, fy = {k[1, 1]:g} (its P[0], P[5]): expected "
                             "positive")
        baseline = -p[0, 3] / p[0, 0] if p[0, 0] else 0.0
        if not baseline > 0:
            raise ValueError(f"/stereo/right/camera_info: P[3] = {p[0, 3]:g} with P[0] = "
                             f"{p[0, 0]:g}: no positive baseline (expected P[3] = -fx * "
                             "baseline)")
        pose = np.asarray(base_to_left_camera, float)
        if pose.shape == (4, 4):
            rot, centre = pose[:3, :3].copy(), pose[:3, 3].copy()
        elif pose.shape == (7,):
            rot, centre = Rotation.from_quat(pose[3:]).as_matrix(), pose[:3].copy()
        else:
            raise ValueError("rover.yaml: field 'base_to_left_camera' must be "
                             "[x, y, z, qx, qy, qz, qw]")
        return cls(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                   float(baseline), int(width), int(height), rot, centre)

    def at_pose(self, base_t_left: np.ndarray) -> StereoCamera:
        """The same rig with its left camera at another pose in base_link (4x4
        ``base_T_left``: a mast panned or tilted)."""
        m = np.asarray(base_t_left, float)
        return replace(self, r_base_cam=m[:3, :3].copy(), t_base_cam=m[:3, 3].copy())

    @property
    def base_t_left(self) -> np.ndarray:
        """4x4 pose of the left optical frame in base_link."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.r_base_cam, self.t_base_cam
        return m

    def same_mount(self, other: StereoCamera) -> bool:
        """Whether ``other``'s left camera sits at this one's pose in base_link (a mast at
        rest; :func:`roi_network.mast.same_pose`)."""
        return same_pose(self.base_t_left, other.base_t_left)

    @property
    def fxb(self) -> float:
        """fx * baseline (pixel metres): depth Z = fxb / disparity."""
        return self.fx * self.baseline_m

    def rays_base(self) -> np.ndarray:
        """(H, W, 3) unit-depth ray directions of every pixel, in base_link axes."""
        vv, uu = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        rays = np.stack([(uu - self.cx) / self.fx, (vv - self.cy) / self.fy,
                         np.ones_like(uu)], axis=-1)
        return rays @ self.r_base_cam.T

    def project_base(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths Z (N,) of base_link points (N, 3)."""
        pc = (np.asarray(points, float) - self.t_base_cam) @ self.r_base_cam
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.column_stack([self.fx * pc[:, 0] / z + self.cx,
                                  self.fy * pc[:, 1] / z + self.cy])
        return uv, z


#: SGBM uniqueness margin, percent.
UNIQUENESS_RATIO = 5


@dataclass(frozen=True)
class StereoConfig:
    """SGBM and range parameters.

    Attributes:
        num_disparities: SGBM search range (pixels, multiple of 16): the nearest depth is
            fx * B / num_disparities (1.6 m at 96 px for the MER-like bench: the
            ground at the bottom of the view is at about 2 m).
        block_size: SGBM matching block (pixels, odd).
        max_range_m: points farther than this (metres, depth) are dropped: stereo range
            error grows as Z^2 and the heights of rocks become unreliable beyond it.
    """

    num_disparities: int = 96
    block_size: int = 5
    max_range_m: float = 20.0


def disparity(left_gray: np.ndarray, right_gray: np.ndarray,
              config: StereoConfig = StereoConfig()) -> np.ndarray:
    """Left-image disparity (pixels, float32) of a rectified pair; NaN where invalid.

    OpenCV's semi-global block matching (3-way mode: one pass, the cheapest of its
    modes at the same accuracy on this imagery).
    """
    n = config.num_disparities
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=n, blockSize=config.block_size,
        P1=8 * config.block_size**2, P2=32 * config.block_size**2,
        uniquenessRatio=UNIQUENESS_RATIO, speckleWindowSize=50, speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    # SGBM leaves the leftmost n columns without disparity; padding both images on the
    # left by n columns lets those pixels match whatever of them the right image sees.
    pad = ((0, 0), (n, 0))
    d = sgbm.compute(np.pad(left_gray, pad), np.pad(right_gray, pad))[:, n:]
    d = d.astype(np.float32) / 16.0
    d[d <= 0.5] = np.nan
    return d


def mask_depth_edges(disp: np.ndarray, window_px: int = 5,
                     max_relative_range: float = 0.15) -> np.ndarray:
    """``disp`` with the pixels at depth discontinuities set to NaN.

    Block matching mixes the foreground and the background at an occlusion edge: the
    pixels along a rock's outline take disparities in between, which put points in the
    air behind the rock, a streak along the viewing ray (worse the lower ``fx * B``).
    A pixel is dropped when the disparities within ``window_px`` of it span more than
    ``max_relative_range`` of its own (a rock 8 m away in front of ground 12 m away: 0.33;
    smooth ground near the bottom of a 70 deg image: under 0.06). Invalid neighbours
    do not count.
    """
    if max_relative_range <= 0:
        return disp
    k = np.ones((window_px, window_px), np.uint8)
    valid = np.isfinite(disp)
    hi = cv2.dilate(np.where(valid, disp, 0.0).astype(np.float32), k)
    lo = cv2.erode(np.where(valid, disp, np.float32(1e6)).astype(np.float32), k)
    out = disp.copy()
    with np.errstate(invalid="ignore"):
        out[valid & ((hi - lo) > max_relative_range * disp)] = np.nan
    return out


def points_base(disp: np.ndarray, camera: StereoCamera, rays: np.ndarray | None = None,
                max_range_m: float = np.inf) -> np.ndarray:
    """(H, W, 3) base_link points of every pixel from its disparity; NaN where invalid.

    Args:
        disp: disparity (pixels) at the camera's resolution.
        camera: the stereo model (same resolution as ``disp``).
        rays: cached ``camera.rays_base()``.
        max_range_m: depth beyond which points are NaN (metres).
    """
    if rays is None:
        rays = camera.rays_base()
    z = camera.fxb / disp
    z[~(z <= max_range_m)] = np.nan
    return rays * z[..., None] + camera.t_base_cam


def range_sigma_m(depth_m: np.ndarray | float, camera: StereoCamera,
                  disparity_sigma_px: float = 0.3) -> np.ndarray | float:
    """1-sigma depth error (metres) of a stereo point at depth Z: Z^2 / (fx B) * sigma_d."""
    return np.asarray(depth_m) ** 2 / camera.fxb * disparity_sigma_px


def local_ground_height(points: np.ndarray, cell_m: float = 0.25, window_m: float = 4.0,
                        percentile: float = 30.0) -> np.ndarray:
    """Height (metres) of every point above the local ground surface under it.

    The ground is a plane fitted to the view (trimmed least squares: the slope), refined
    by a robust low envelope of the residuals on a base_link x-y grid: per cell the
    median residual, then a windowed low percentile over ``window_m`` (wider than the
    largest rock, so a rock never holds its own ground up),
    then a mean filter. Cells with no point take the nearest cell's value. Hand-written
    because no library fits a terrain surface under occluding obstacles in one view.

    Args:
        points: (H, W, 3) base_link points, NaN where invalid.
        cell_m: grid cell size, metres.
        window_m: side of the ground window, metres.
        percentile: the low percentile of cell residuals taken as ground.

    Returns:
        (H, W) height above ground, metres; NaN where the point is invalid.
    """
    from scipy import ndimage

    out = np.full(points.shape[:2], np.nan, np.float32)
    ok = np.isfinite(points[..., 2])
    if ok.sum() < 50:
        return out
    p = points[ok]
    coef = fit_surface(p[:: max(1, len(p) // 4000)])
    resid = p[:, 2] - surface_z(coef, p[:, 0], p[:, 1])
    ix = np.floor(p[:, 0] / cell_m).astype(np.int64)
    iy = np.floor(p[:, 1] / cell_m).astype(np.int64)
    ix -= ix.min()
    iy -= iy.min()
    shape = (int(ix.max()) + 1, int(iy.max()) + 1)
    flat = ix * shape[1] + iy
    # Per-cell median residual over one point in four (cells hold tens of points):
    # sort by cell then value, take the middle element.
    step = 4 if len(p) > 20000 else 1
    order = np.lexsort((resid[::step], flat[::step]))
    fs, rs = flat[::step][order], resid[::step][order]
    starts = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
    counts = np.diff(np.r_[starts, len(fs)])
    grid = np.full(shape, np.nan)
    grid.ravel()[fs[starts]] = rs[starts + counts // 2]
    valid = np.isfinite(grid)
    idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    filled = grid[tuple(idx)]
    size = max(3, round(window_m / cell_m) | 1)
    ground = ndimage.percentile_filter(filled, percentile, size=size, mode="nearest")
    ground = ndimage.uniform_filter(ground, size=max(3, size // 2), mode="nearest")
    out[ok] = resid - ground[ix, iy]
    return out


def surface_z(coef: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """z of the ground plane ``coef`` (see :func:`fit_surface`) at (x, y), metres."""
    return coef[0] + coef[1] * x + coef[2] * y


def fit_surface(points: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Ground plane z = c0 + c1 x + c2 y through (N, 3) base_link points, trimmed so that
    points standing above it (rocks) stop pulling it up. Returns 3 coefficients.

    A plane, not a higher-order surface: the points are dense near the rover and sparse
    far away, where a quadratic term swings freely; the residual undulation is left to
    the windowed low envelope of :func:`local_ground_height`.
    """
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    a = np.column_stack([np.ones_like(x), x, y])
    keep = np.ones(len(z), bool)
    coef = np.zeros(3)
    for _ in range(iterations):
        if keep.sum() < 12:
            break
        coef, *_ = np.linalg.lstsq(a[keep], z[keep], rcond=None)
        r = z - a @ coef
        scale = 1.4826 * np.median(np.abs(r[keep])) + 0.01
        keep = np.abs(r) < 2.5 * scale
    return coef


def fit_plane(points: np.ndarray, iterations: int = 2, trim_m: float = 0.1) -> np.ndarray | None:
    """Least-squares plane z = a x + b y + c through (N, 3) points, trimmed of outliers.

    Returns ``(a, b, c)`` or None with fewer than 10 points.
    """
    p = points[np.isfinite(points).all(axis=1)]
    if len(p) < 10:
        return None
    keep = np.ones(len(p), bool)
    coef = None
    for _ in range(iterations + 1):
        a = np.column_stack([p[keep, 0], p[keep, 1], np.ones(keep.sum())])
        coef, *_ = np.linalg.lstsq(a, p[keep, 2], rcond=None)
        resid = p[:, 2] - (coef[0] * p[:, 0] + coef[1] * p[:, 1] + coef[2])
        keep = np.abs(resid) < max(trim_m, 2.5 * np.median(np.abs(resid)))
        if keep.sum() < 10:
            break
    return coef

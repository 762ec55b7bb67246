"""Detection metrics of the paper's Sec. 4.1: Hessian eigenvalues and weighted local entropy.

Imagery-agnostic: every function takes a 2-D gray image (rows x cols) and returns per-pixel
maps of the same shape. Scales are in pixels; a caller with a ground sample distance turns
metres into pixels with :func:`sigma_px_from_gsd`.
"""

from __future__ import annotations

from typing import Final

import cv2
import numpy as np
from scipy import ndimage

#: sigma_e^2 of the entropy weight w(i) = 1 - G(mu, sigma_e) (paper Eq. 2), grey levels^2.
PAPER_SIGMA_E2: Final = 8.0


def sigma_px_from_gsd(scale_m: float, gsd_m: float) -> float:
    """The Gaussian scale in pixels of a feature scale in metres.

    Args:
        scale_m: Gaussian sigma on the ground, metres (a blob of radius r responds most at
            sigma = r / sqrt(2)).
        gsd_m: ground sample distance, metres per pixel (> 0).

    Returns:
        sigma in pixels.
    """
    if not gsd_m > 0:
        raise ValueError(f"gsd_m must be > 0, got {gsd_m}")
    return float(scale_m) / float(gsd_m)


def to_gray_u8(image: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """A uint8 gray image (256 grey levels, the alphabet of Eq. 2) from any image.

    Args:
        image: (H, W) or (H, W, 3) RGB array, any numeric dtype.
        lo, hi: the input values mapped to 0 and 255 (default: uint8 input is kept as is;
            other dtypes must pass them, e.g. percentiles of the whole raster, so that
            tiles of one raster share one mapping).

    Returns:
        (H, W) uint8 gray (ITU-R BT.601 luma for RGB).
    """
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114
    elif img.ndim != 2:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got shape {img.shape}")
    if lo is None or hi is None:
        if image.dtype == np.uint8:
            return np.clip(np.rint(img), 0, 255).astype(np.uint8)
        raise ValueError("to_gray_u8: lo and hi are required for non-uint8 images")
    scale = 255.0 / max(float(hi) - float(lo), 1e-12)
    return np.clip(np.rint((img.astype(np.float64) - lo) * scale), 0, 255).astype(np.uint8)


def hessian_eigenvalues(gray: np.ndarray, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues of the scale-normalised Hessian (paper Eq. 1) at scale ``sigma_px``.

    Second derivatives are Gaussian derivatives at ``sigma_px`` multiplied by sigma^2
    (Lindeberg's normalisation), so responses at different scales compare. A dark blob on a
    bright background (a rock with its shadow) gives two large positive eigenvalues; a bright
    plateau (a pale outcrop) two large negative ones.

    Args:
        gray: (H, W) image, any numeric dtype (grey levels).
        sigma_px: Gaussian scale, pixels (> 0).

    Returns:
        (lambda_max, lambda_min): two (H, W) float32 maps, lambda_max >= lambda_min, in grey
        levels (scale-normalised). Borders use reflection.
    """
    if not sigma_px > 0:
        raise ValueError(f"sigma_px must be > 0, got {sigma_px}")
    g = np.asarray(gray, dtype=np.float32)
    norm = np.float32(sigma_px**2)
    # scipy's Gaussian derivative filters: order=(row, col).
    hrr = ndimage.gaussian_filter(g, sigma_px, order=(2, 0), mode="reflect") * norm
    hcc = ndimage.gaussian_filter(g, sigma_px, order=(0, 2), mode="reflect") * norm
    hrc = ndimage.gaussian_filter(g, sigma_px, order=(1, 1), mode="reflect") * norm
    half_trace = 0.5 * (hrr + hcc)
    root = np.sqrt(0.25 * (hrr - hcc) ** 2 + hrc**2)
    return (half_trace + root).astype(np.float32), (half_trace - root).astype(np.float32)


def hessian_halo_px(sigma_px: float) -> int:
    """Pixels of context :func:`hessian_eigenvalues` needs so that a window's core is exact.

    scipy truncates its Gaussians at 4 sigma.
    """
    return int(np.ceil(4.0 * sigma_px)) + 1


def local_contrast(gray: np.ndarray, background_sigma_px: float) -> np.ndarray:
    """Grey level minus the local background (a Gaussian mean at ``background_sigma_px``).

    Not one of the paper's metrics: the improved recipe thresholds it (dark rocks and their
    shadows below, pale outcrops above the background), since a sigma threshold on raw
    Hessian eigenvalues also fires on soil texture.

    Args:
        gray: (H, W) image, any numeric dtype (grey levels).
        background_sigma_px: scale of the background, pixels (> 0).

    Returns:
        (H, W) float32, grey levels (negative where darker than the surroundings).
    """
    if not background_sigma_px > 0:
        raise ValueError(f"background_sigma_px must be > 0, got {background_sigma_px}")
    g = np.asarray(gray, dtype=np.float32)
    return g - ndimage.gaussian_filter(g, background_sigma_px, mode="reflect")


def weighted_entropy(gray_u8: np.ndarray, size_px: int,
                     sigma_e2: float = PAPER_SIGMA_E2) -> np.ndarray:
    """Weighted local entropy of the paper's Eq. 2 over a square neighbourhood.

    LE^w(p) = -sum_i w(i) p(i) log2 p(i), with p the grey-level histogram of the
    ``size_px`` x ``size_px`` neighbourhood of p, and w(i) = 1 - G(i; mu, sigma_e) where mu
    is the neighbourhood mean and G a Gaussian of variance ``sigma_e2`` with unit peak: grey
    levels close to the local mean count little, so the metric separates strong intensity
    differences (a rock against soil) from weak ones, which plain entropy does not.

    Implementation (no library computes Eq. 2): one box filter of the indicator image per
    grey level present, counts looked up in tables of -p log2 p and of G.

    Args:
        gray_u8: (H, W) uint8 image.
        size_px: odd neighbourhood side, pixels (>= 3, <= 15 so that counts fit uint8).
        sigma_e2: variance of the weight's Gaussian, grey levels^2 (paper: 8).

    Returns:
        (H, W) float32 map, bits. Borders use reflection.
    """
    g = np.asarray(gray_u8)
    if g.dtype != np.uint8 or g.ndim != 2:
        raise ValueError(f"gray_u8 must be a 2-D uint8 array, got {g.dtype} {g.shape}")
    if size_px % 2 != 1 or not 3 <= size_px <= 15:
        raise ValueError(f"size_px must be odd and in [3, 15], got {size_px}")
    n = size_px * size_px
    counts = np.arange(256, dtype=np.float64)
    p = counts / n
    with np.errstate(divide="ignore", invalid="ignore"):
        plogp = np.where(counts > 0, -p * np.log2(np.where(p > 0, p, 1.0)), 0.0)
    lut_h = plogp.astype(np.float32)
    # The neighbourhood mean, rounded to a grey level: the weight w(i) is then a table
    # lookup of mu per grey level i (one cv2.LUT instead of an exp per pixel and level).
    mean = cv2.blur(g.astype(np.float32), (size_px, size_px), borderType=cv2.BORDER_REFLECT_101)
    mean_u8 = np.clip(np.rint(mean), 0, 255).astype(np.uint8)
    mus = np.arange(256, dtype=np.float64)
    out = np.zeros(g.shape, dtype=np.float32)
    ksize = (size_px, size_px)
    for level in np.flatnonzero(np.bincount(g.ravel(), minlength=256)):
        indicator = (g == level).view(np.uint8)
        c = cv2.boxFilter(indicator, cv2.CV_8U, ksize, normalize=False,
                          borderType=cv2.BORDER_REFLECT_101)
        h = cv2.LUT(c, lut_h)
        lut_w = (1.0 - np.exp(-((level - mus) ** 2) / (2.0 * sigma_e2))).astype(np.float32)
        out += cv2.LUT(mean_u8, lut_w) * h
    return out


def weighted_entropy_at(gray_u8: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                        size_px: int, sigma_e2: float = PAPER_SIGMA_E2) -> np.ndarray:
    """:func:`weighted_entropy` at chosen pixels only (the same values, Eq. 2).

    For a few scattered pixels (the candidates' own and surrounding pixels, which the
    features read) this is much cheaper than the whole map: each pixel's neighbourhood is
    compared with itself, so that p(g_q) = count(g == g_q) / n and
    LE^w = -(1/n) sum_q w(g_q) log2 p(g_q) over the n neighbours q.

    Args:
        gray_u8: (H, W) uint8 image.
        rows, cols: (N,) integer pixel coordinates inside the image.
        size_px: odd neighbourhood side, pixels (3..15).
        sigma_e2: variance of the weight's Gaussian, grey levels^2.

    Returns:
        (N,) float32, bits. Borders use reflection, as :func:`weighted_entropy`.
    """
    g = np.asarray(gray_u8)
    if g.dtype != np.uint8 or g.ndim != 2:
        raise ValueError(f"gray_u8 must be a 2-D uint8 array, got {g.dtype} {g.shape}")
    if size_px % 2 != 1 or not 3 <= size_px <= 15:
        raise ValueError(f"size_px must be odd and in [3, 15], got {size_px}")
    rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
    if rows.size == 0:
        return np.zeros(0, np.float32)
    half = size_px // 2
    padded = np.pad(g, half, mode="reflect")
    dr, dc = np.mgrid[0:size_px, 0:size_px]
    dr, dc = dr.ravel()[None, :], dc.ravel()[None, :]
    n = size_px * size_px
    out = np.empty(rows.size, np.float32)
    # Chunks keep the (chunk, n, n) comparison cube small (cache-sized).
    chunk = max(1, 1_000_000 // (n * n))
    for i in range(0, rows.size, chunk):
        nb = padded[rows[i:i + chunk, None] + dr, cols[i:i + chunk, None] + dc]
        counts = (nb[:, :, None] == nb[:, None, :]).sum(axis=2)
        # The neighbourhood mean rounded as in weighted_entropy (no ties: n is odd).
        mean = np.rint(nb.sum(axis=1, dtype=np.float32) * np.float32(1.0 / n))
        d = nb.astype(np.float32) - mean[:, None]
        w = 1.0 - np.exp(-(d * d) / np.float32(2.0 * sigma_e2))
        out[i:i + chunk] = -(w * np.log2(counts * np.float32(1.0 / n))).sum(axis=1) / n
    return out


def entropy_halo_px(size_px: int) -> int:
    """Pixels of context :func:`weighted_entropy` needs so that a window's core is exact."""
    return size_px // 2 + 1

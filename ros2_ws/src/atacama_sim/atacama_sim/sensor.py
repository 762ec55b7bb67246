"""Image formation after the renderer: exposure, vignetting, noise, gamma, JPEG."""

from __future__ import annotations

import cv2
import numpy as np

from atacama_sim.config import CameraConfig


class CameraSensor:
    """Auto-exposure shared by the stereo pair (one exposure per pair, smoothed over frames,
    like a rover's synchronised cameras), cos^4 vignetting, shot + read noise, gamma."""

    def __init__(self, cfg: CameraConfig, fx: float) -> None:
        self.cfg = cfg
        h, w = cfg.height, cfg.width
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / fx ** 2
        self.vignette = (1.0 / (1.0 + r2) ** 2).astype(np.float32)[..., None]
        self.exposure: float | None = None

    def expose(self, rad_left: np.ndarray) -> float:
        """Update and return the exposure (radiance -> fraction of full well)."""
        level = float(np.mean(rad_left * self.vignette)) + 1e-6
        target = self.cfg.exposure_target ** (1 / self.cfg.gamma)  # linear target
        new = target / level
        a = self.cfg.exposure_smoothing
        self.exposure = new if self.exposure is None else (1 - a) * self.exposure + a * new
        return self.exposure

    def image(self, rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """8-bit RGB image (H, W, 3) of a linear radiance image."""
        assert self.exposure is not None
        fw = self.cfg.full_well_e
        e = np.clip(rad * self.vignette * (self.exposure * fw), 0, fw)
        e += rng.standard_normal(e.shape, dtype=np.float32) * np.sqrt(
            e + self.cfg.read_noise_e ** 2)
        v = np.clip(e / fw, 0, 1) ** self.cfg.gamma
        return (v * 255 + 0.5).astype(np.uint8)

    def jpeg(self, rgb: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1],
                               [cv2.IMWRITE_JPEG_QUALITY, self.cfg.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return buf.tobytes()

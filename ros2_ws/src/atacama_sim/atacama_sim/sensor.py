"""Image formation after the renderer: exposure, vignetting, noise, gamma, JPEG."""

from __future__ import annotations

import cv2
import numpy as np

from atacama_sim.config import CameraConfig

#: JPEG quality of the compressed images (OpenCV's 0-100 scale).
JPEG_QUALITY = 93
#: Full-well capacity, electrons (sets the shot noise).
FULL_WELL_E = 12000.0
#: Read noise, electrons rms.
READ_NOISE_E = 12.0
#: Mean image level (0-1, after gamma) that the auto-exposure aims at.
EXPOSURE_TARGET = 0.42
#: Per-frame weight of the new exposure in its moving average.
EXPOSURE_SMOOTHING = 0.3
#: Gamma of the 8-bit encoding (value = linear ** GAMMA).
GAMMA = 1 / 2.2


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
        target = EXPOSURE_TARGET ** (1 / GAMMA)  # linear target
        new = target / level
        a = EXPOSURE_SMOOTHING
        self.exposure = new if self.exposure is None else (1 - a) * self.exposure + a * new
        return self.exposure

    def image(self, rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """8-bit RGB image (H, W, 3) of a linear radiance image."""
        assert self.exposure is not None
        fw = FULL_WELL_E
        e = np.clip(rad * self.vignette * (self.exposure * fw), 0, fw)
        e += rng.standard_normal(e.shape, dtype=np.float32) * np.sqrt(
            e + READ_NOISE_E ** 2)
        v = np.clip(e / fw, 0, 1) ** GAMMA
        return (v * 255 + 0.5).astype(np.uint8)

    def jpeg(self, rgb: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1],
                               [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return buf.tobytes()


class StereoDeveloper:
    """Image formation of the stereo pairs in frame order: exposure (stateful, smoothed),
    sensor noise from the frame's own random stream, JPEG encoding.

    Runs in a worker process during generation (see :func:`developer_pool`), so that it
    overlaps the rendering of the next pair; a single worker keeps frames in order, which
    the smoothed exposure needs.
    """

    def __init__(self, cfg: CameraConfig, fx: float, seed: int) -> None:
        self.sensor = CameraSensor(cfg, fx)
        self.seed = seed

    def __call__(self, i: int, rad_left: np.ndarray, rad_right: np.ndarray,
                 keep_left: bool) -> tuple[bytes, bytes, np.ndarray | None]:
        """JPEG bytes of frame ``i`` (left, right) and, if asked, the 8-bit left image."""
        from atacama_sim.config import rng_for

        left = rad_left.astype(np.float32)
        self.sensor.expose(left)
        rng = rng_for(self.seed, f"frame{i}")
        imgs = [self.sensor.image(left, rng),
                self.sensor.image(rad_right.astype(np.float32), rng)]
        return (self.sensor.jpeg(imgs[0]), self.sensor.jpeg(imgs[1]),
                imgs[0] if keep_left else None)


_DEVELOPER: StereoDeveloper | None = None


def _init_worker(cfg: CameraConfig, fx: float, seed: int) -> None:
    global _DEVELOPER
    _DEVELOPER = StereoDeveloper(cfg, fx, seed)


def _develop(*args):
    assert _DEVELOPER is not None
    return _DEVELOPER(*args)


def developer_pool(cfg: CameraConfig, fx: float, seed: int):
    """A one-process pool running :class:`StereoDeveloper` (``pool.submit(develop, ...)``).

    The worker is spawned, not forked: the parent holds an EGL context and a large world.
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"),
                               initializer=_init_worker, initargs=(cfg, fx, seed))


develop = _develop

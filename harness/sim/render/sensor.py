"""Sensor model: exposure / gain / illumination -> pixel values, and read noise from precomputed tiles.

Brightness (Exposure's docstring) scales the static background in one saturating OpenCV pass
(``cv2.convertScaleAbs`` on the uint16 radiance), the only full-frame work besides the noise.
Noise is Gaussian read noise of ``noise_dn * gain`` DN per channel: a bank of precomputed noise
tiles (one per sigma level, each larger than the image) is added and subtracted with saturating
``cv2.add``/``cv2.subtract`` at a random offset per frame and camera, drawn from a generator
seeded by (renderer seed, frame index, camera index), so every frame is reproducible on its own.
"""

from __future__ import annotations

import cv2
import numpy as np

from harness.sim.render.primitives import DN_PER_RADIANCE
from harness.sim.render.static import RADIANCE_SCALE

__all__ = ["NoiseBank", "background_dn"]

_TILE_PAD = 64  #: random offsets in [0, 64) x [0, 64)
_LEVEL_STEP_DN = 0.25  #: noise sigmas are rounded to this step


def background_dn(radiance_u16: np.ndarray, brightness: float, out: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8 pixel values of the stored background radiance at ``brightness``, saturated."""
    return cv2.convertScaleAbs(radiance_u16, dst=out, alpha=float(brightness) * DN_PER_RADIANCE / RADIANCE_SCALE)


class NoiseBank:
    """Noise tiles of one image size, built lazily per sigma level (seeded, hence reproducible).

    Each level holds two uint8 tiles, the positive and the negative part of N(0, sigma^2) noise,
    of shape (H + 64, W + 64, 3); ``add`` applies a (H, W) window of both.
    """

    def __init__(self, width: int, height: int, *, seed: int = 0):
        self.width, self.height, self.seed = int(width), int(height), int(seed)
        self._levels: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _tiles(self, level: int):
        tiles = self._levels.get(level)
        if tiles is None:
            rng = np.random.default_rng([self.seed, self.width, self.height, level])
            shape = (self.height + _TILE_PAD, self.width + _TILE_PAD, 3)
            n = np.round(rng.normal(0.0, level * _LEVEL_STEP_DN, shape))
            tiles = (np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8))
            self._levels[level] = tiles
        return tiles

    def add(self, image: np.ndarray, sigma_dn: float, rng: np.random.Generator) -> np.ndarray:
        """Add noise of ``sigma_dn`` to ``image`` (H, W, 3) uint8 in place (saturating); returns it."""
        level = int(round(sigma_dn / _LEVEL_STEP_DN))
        if level <= 0:
            return image
        pos, neg = self._tiles(level)
        oy, ox = rng.integers(0, _TILE_PAD, 2)
        win = (slice(oy, oy + self.height), slice(ox, ox + self.width))
        cv2.add(image, pos[win], dst=image)
        cv2.subtract(image, neg[win], dst=image)
        return image

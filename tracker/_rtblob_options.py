"""Options of the RTBlob baseline (Lampert & Peters 2012), validated once at construction.

Kept apart from :mod:`tracker.rtblob` so that the per-camera detector and the tracker can both
import them without a cycle. See docs/rtblob.md for what each option means in the published system.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from checks.arrays import describe

__all__ = ["AUTO_DIRECT_MAX_SIDE", "COLOUR_SPACES", "CORRELATION_METHODS", "RTBlobOptions", "SUBPIXEL_METHODS"]

#: valid ``colour_space`` keys (the implementations live in ``tracker._rtblob_detect``)
COLOUR_SPACES = ("rgb", "chromaticity")
#: valid ``correlation`` keys: FFT through scipy / numpy / OpenCV, OpenCV's filter2D (direct for
#: kernels up to 11 x 11, its own DFT above), or ``auto``: filter2D for kernels up to 11 x 11 (r < 6 px),
#: scipy's FFT above or when ``fft_size`` is set (the crossover measured by ``rt2 bench rtblob``)
CORRELATION_METHODS = ("auto", "scipy", "numpy", "opencv", "filter2d")
#: largest kernel side for which ``auto`` picks filter2D
AUTO_DIRECT_MAX_SIDE = 11
#: valid ``subpixel`` keys: "none" is the published integer arg-max
SUBPIXEL_METHODS = ("none", "parabola")


def _choice(value, name: str, valid: tuple) -> None:
    if value not in valid:
        raise ValueError(f"unknown {name} {value!r}; valid: {list(valid)}")


def _positive(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {describe(value)}") from None
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return v


@dataclass(frozen=True)
class RTBlobOptions:
    """How the RTBlob baseline detects and triangulates. Frozen: build a new one to change it.

    reference_rgb : (3,) the object colour, 8-bit RGB levels (default: table-tennis orange)
    colour_space : ``rgb`` (distance of RGB / 255) or ``chromaticity`` (distance of
        ``(r, g, b) / (r + g + b)``, brightness-invariant)
    colour_sigma : width of the Gaussian colour similarity, in units of the colour space
        (fractions of full scale, 0..1); 0.25 suits ``rgb``, about 0.08 ``chromaticity``
    template_radius_px : disk radius in pixels: one number for every camera, one per camera
        (rig order), or None to derive it per camera as ``fx * ball_radius_m / expected_distance_m``
    expected_distance_m : camera-to-ball distance the template is sized for when
        ``template_radius_px`` is None, metres
    ball_radius_m : ball radius, metres (ITTF ball: 20 mm)
    min_score : smallest accepted peak response (the mean likelihood inside the disk at the
        maximum, 0..1); below it the camera reports "not seen". 0 reports every maximum.
    pairs : the fixed stereo pairs, camera indices (rig order) or names; each triangulated alone
    correlation : how Eq. (2) is computed, see ``CORRELATION_METHODS``; all give the same response
        to float32 rounding, so this is a speed choice only
    fft_size : (height, width) of the zero-padded FFT, or None for the smallest fast size that
        avoids wrap-around (``H + r``, ``W + r`` rounded up); must be at least that; FFT methods only
    subpixel : ``none`` (published: integer arg-max) or ``parabola`` (3-point fit per axis; ours)
    pixel_sigma_px : pixel noise propagated into ``covariance_m2``; None reports no covariance
    """

    reference_rgb: tuple = (255.0, 120.0, 0.0)
    colour_space: str = "rgb"
    colour_sigma: float = 0.25
    template_radius_px: float | tuple | None = None
    expected_distance_m: float = 3.0
    ball_radius_m: float = 0.02
    min_score: float = 0.2
    pairs: tuple = ((0, 1), (2, 3))
    correlation: str = "auto"
    fft_size: tuple | None = None
    subpixel: str = "none"
    pixel_sigma_px: float | None = 1.0

    def __post_init__(self):
        ref = np.asarray(self.reference_rgb, dtype=float) if _numeric(self.reference_rgb) else None
        if ref is None or ref.shape != (3,) or not np.isfinite(ref).all() or (ref < 0).any() or (ref > 255).any():
            raise ValueError(f"reference_rgb must be three numbers in [0, 255], got {describe(self.reference_rgb)}")
        object.__setattr__(self, "reference_rgb", tuple(float(v) for v in ref))
        _choice(self.colour_space, "colour_space", COLOUR_SPACES)
        _positive(self.colour_sigma, "colour_sigma")
        r = self.template_radius_px
        if r is not None:
            radii = r if isinstance(r, (tuple, list)) else (r,)
            if not radii:
                raise ValueError("template_radius_px must be a number, one number per camera, or None; got ()")
            vals = tuple(_positive(v, "template_radius_px") for v in radii)
            if min(vals) < 1.0:
                raise ValueError(f"template_radius_px must be at least 1 px, got {r!r}")
            object.__setattr__(self, "template_radius_px", vals if isinstance(r, (tuple, list)) else vals[0])
        _positive(self.expected_distance_m, "expected_distance_m")
        _positive(self.ball_radius_m, "ball_radius_m")
        try:
            ms = float(self.min_score)
        except (TypeError, ValueError):
            raise ValueError(f"min_score must be a number in [0, 1], got {describe(self.min_score)}") from None
        if not 0.0 <= ms <= 1.0:
            raise ValueError(f"min_score must be a number in [0, 1], got {self.min_score!r}")
        object.__setattr__(self, "pairs", _check_pairs(self.pairs))
        _choice(self.correlation, "correlation", CORRELATION_METHODS)
        if self.fft_size is not None:
            fs = self.fft_size
            ints = isinstance(fs, (tuple, list)) and len(fs) == 2 and all(isinstance(v, (int, np.integer)) for v in fs)
            if not ints or min(fs) <= 0:
                raise ValueError(f"fft_size must be (height, width) positive integers or None, got {describe(fs)}")
            if self.correlation == "filter2d":
                raise ValueError("fft_size applies to the FFT correlations only, not correlation='filter2d'")
            object.__setattr__(self, "fft_size", (int(fs[0]), int(fs[1])))
        _choice(self.subpixel, "subpixel", SUBPIXEL_METHODS)
        if self.pixel_sigma_px is not None:
            _positive(self.pixel_sigma_px, "pixel_sigma_px")


def _numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _check_pairs(pairs) -> tuple:
    if not isinstance(pairs, (tuple, list)) or not pairs:
        raise ValueError(f"pairs must be a non-empty sequence of camera pairs, got {describe(pairs)}")
    out = []
    for p in pairs:
        if not isinstance(p, (tuple, list)) or len(p) != 2:
            raise ValueError(f"each entry of pairs must be two cameras (index or name), got {describe(p)}")
        for c in p:
            ok_int = isinstance(c, (int, np.integer)) and not isinstance(c, bool) and c >= 0
            if not (ok_int or (isinstance(c, str) and c)):
                raise ValueError(f"pairs must hold camera indices >= 0 or names, got {describe(c)} in {p!r}")
        if p[0] == p[1]:
            raise ValueError(f"a pair needs two different cameras, got {tuple(p)!r}")
        out.append(tuple(int(c) if isinstance(c, (int, np.integer)) else c for c in p))
    return tuple(out)

"""RTBlob per-camera detection: colour likelihood, disk correlation by FFT, arg-max.

Lampert & Peters 2012 (RTblob), as summarised in the RT2 paper (Sec. 1.2): "uses a reference
orange color and convolves the resulting image with a circular pattern using the fast Fourier
Transform", the object being "the spatial maximum of a linear filtering operation". Our exact
formulas (docs/rtblob.md):

    (1) L(p) = exp(-||c(p) - c_ref||^2 / (2 sigma^2))          colour likelihood per pixel
    (2) S = L (*) D_r,  D_r = 1[|q| <= r] / |D_r|              disk correlation, by FFT
    (3) p* = argmax_p S(p);  "not seen" if S(p*) < min_score   one pixel per camera

``c`` is RGB / 255 (``rgb``) or ``(r, g, b) / (r + g + b)`` (``chromaticity``). In ``rgb`` the
Gaussian of (1) factorises over channels, so it is three 256-entry look-up tables and two products;
``chromaticity`` does not factorise (the division couples the channels) and runs as one compiled
pass over the pixels (:func:`_chromaticity_likelihood`, tested equal to :func:`likelihood_reference`).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np
import scipy.fft

from checks.arrays import describe
from tracker._rtblob_options import AUTO_DIRECT_MAX_SIDE, RTBlobOptions
from tracker.images import check_image
from checks.numba_cache import key_cache_on_callees

__all__ = ["RTBlobDetector", "disk_template", "likelihood_reference"]


def disk_template(radius_px: float) -> np.ndarray:
    """(2k+1, 2k+1) float32 disk ``|q| <= r`` (k = floor(r)) normalised to sum 1, Eq. (2)."""
    k = int(np.floor(radius_px))
    y, x = np.mgrid[-k : k + 1, -k : k + 1]
    disk = (x * x + y * y <= radius_px * radius_px + 1e-9).astype(np.float32)
    return disk / disk.sum()


def likelihood_reference(image: np.ndarray, options: RTBlobOptions) -> np.ndarray:
    """Plain float64 Eq. (1), no look-up tables: the reference the fast path is tested against.

    image : (H, W, 3) uint8 RGB; returns (H, W) float64 in (0, 1]
    """
    c = image.astype(float) / 255.0
    ref = np.asarray(options.reference_rgb) / 255.0
    if options.colour_space == "chromaticity":
        c, ref = _chromaticity(c), _chromaticity(ref[None, None])[0, 0]
    d2 = ((c - ref) ** 2).sum(axis=-1)
    return np.exp(-d2 / (2.0 * options.colour_sigma**2))


def _chromaticity(c: np.ndarray) -> np.ndarray:
    s = c.sum(axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = c / s
    out[np.broadcast_to(s == 0, out.shape)] = 1.0 / 3.0  # black: no chroma, call it grey
    return out


@numba.njit(cache=True, nogil=True)
def _chromaticity_likelihood(image, ref, inv_two_sigma2, out):
    """Eq. (1) in chromaticity, one pass: image (H, W, 3) uint8, ref (3,) chromaticity, out (H, W) float32.

    Same arithmetic as :func:`likelihood_reference` (float64 per pixel; black pixels are grey).
    """
    H, W = out.shape
    third = 1.0 / 3.0
    for y in range(H):
        for x in range(W):
            r = float(image[y, x, 0])
            g = float(image[y, x, 1])
            b = float(image[y, x, 2])
            s = r + g + b
            if s > 0.0:
                dr = r / s - ref[0]
                dg = g / s - ref[1]
                db = b / s - ref[2]
            else:
                dr = third - ref[0]
                dg = third - ref[1]
                db = third - ref[2]
            out[y, x] = np.exp(-(dr * dr + dg * dg + db * db) * inv_two_sigma2)


class RTBlobDetector:
    """One camera's RTBlob detector: Eq. (1)-(3) on (H, W, 3) uint8 RGB images of one size.

    image_size : (width, height) in pixels
    radius_px : disk template radius, pixels (>= 1)
    options : :class:`RTBlobOptions` (colour, correlation method, FFT size, min_score, subpixel)

    The FFT buffers and the template spectrum are allocated once; a detector is therefore not
    safe to share between threads (build one per thread).
    """

    def __init__(self, image_size, radius_px: float, options: RTBlobOptions = RTBlobOptions()):
        if not isinstance(options, RTBlobOptions):
            raise ValueError(f"options must be RTBlobOptions, got {describe(options)}")
        try:
            size = np.asarray(image_size, dtype=float)
        except (TypeError, ValueError):
            size = np.zeros(0)
        if size.shape != (2,) or not np.isfinite(size).all() or (size < 1).any() or (size != np.round(size)).any():
            raise ValueError(f"image_size must be (width, height) positive integers, got {describe(image_size)}")
        try:
            r = float(radius_px)
        except (TypeError, ValueError):
            r = np.nan
        if not (np.isfinite(r) and r >= 1.0):
            raise ValueError(f"radius_px must be a number >= 1, got {describe(radius_px)}")
        self.options = options
        self.image_size = (int(size[0]), int(size[1]))
        self.radius_px = r
        self.template = disk_template(r)
        self._init_lut()
        method = options.correlation
        if method == "auto":  # same response either way; pick the faster (measured crossover)
            small = self.template.shape[0] <= AUTO_DIRECT_MAX_SIDE and options.fft_size is None
            method = "filter2d" if small else "scipy"
        self.correlation = method  #: the correlation method in use (``auto`` resolved)
        self.fft_size = None  #: (height, width) of the padded FFT; None for filter2d
        if method != "filter2d":
            self._init_fft()

    def _init_lut(self) -> None:
        ref = np.asarray(self.options.reference_rgb) / 255.0
        levels = np.arange(256)[:, None] / 255.0
        # Eq. (1) factorised over channels: exp(-sum_k d_k^2 / 2s^2) = prod_k exp(-d_k^2 / 2s^2).
        lut = np.exp(-((levels - ref[None]) ** 2) / (2.0 * self.options.colour_sigma**2))
        self._lut = lut.astype(np.float32).reshape(1, 256, 3)
        self._ref_chroma = _chromaticity(ref[None, None])[0, 0].astype(np.float64)
        self._inv_two_sigma2 = 1.0 / (2.0 * self.options.colour_sigma**2)

    def _init_fft(self) -> None:
        W, H = self.image_size
        k = self.template.shape[0] // 2
        need = (H + k, W + k)  # zero padding >= k on one side avoids wrap-around of Eq. (2)
        if self.options.fft_size is None:
            real = self.correlation in ("scipy", "numpy")
            fast = (lambda n: scipy.fft.next_fast_len(n, real=True)) if real else cv2.getOptimalDFTSize
            self.fft_size = (int(fast(need[0])), int(fast(need[1])))
        elif self.options.fft_size[0] < need[0] or self.options.fft_size[1] < need[1]:
            raise ValueError(
                f"fft_size {self.options.fft_size} is too small for {W}x{H} images and a radius-{self.radius_px:g} "
                f"px disk: need at least (height, width) = {need}"
            )
        else:
            self.fft_size = self.options.fft_size
        Hp, Wp = self.fft_size
        # Template centred on the origin with wrap-around, so S[y, x] is the disk centred at (x, y).
        kp = np.zeros((Hp, Wp), np.float32)
        yy, xx = np.mgrid[-k : k + 1, -k : k + 1]
        kp[yy % Hp, xx % Wp] = self.template
        self._buf = np.zeros((Hp, Wp), np.float32)  # rows >= H, columns >= W stay zero forever
        if self.correlation == "scipy":
            self._spec = np.conj(scipy.fft.rfft2(kp))
        elif self.correlation == "numpy":
            self._spec = np.conj(np.fft.rfft2(kp))
        else:
            self._spec = cv2.dft(kp)  # CCS packed; conjugated in mulSpectrums

    def __repr__(self) -> str:
        w, h = self.image_size
        return f"RTBlobDetector({w}x{h}, r={self.radius_px:g} px, {self.correlation}, fft {self.fft_size})"

    # -- public, validated ------------------------------------------------------------------------
    def likelihood(self, image) -> np.ndarray:
        """Eq. (1). image : (H, W, 3) uint8 RGB; returns (H, W) float32 in [0, 1]."""
        self._check(image)
        out = np.empty(image.shape[:2], np.float32)
        self._likelihood_into(image, out)
        return out

    def response(self, image) -> np.ndarray:
        """Eq. (2): (H, W) float32, the mean likelihood inside the disk centred on each pixel."""
        self._check(image)
        return self._response(image).copy()

    def detect(self, image) -> tuple[np.ndarray, float]:
        """Eq. (3). image : (H, W, 3) uint8 RGB.

        returns uv_px (2,) distorted pixel of the maximum (NaN, NaN when the peak response is below
        ``min_score``), and score, the peak response in [0, 1]
        """
        self._check(image)
        return self.detect_unchecked(image)

    # -- hot path (inputs trusted) ----------------------------------------------------------------
    def _check(self, image) -> None:
        check_image(image, image_size=self.image_size)

    def _likelihood_into(self, image: np.ndarray, out: np.ndarray) -> None:
        if self.options.colour_space == "rgb":
            t = cv2.LUT(np.ascontiguousarray(image), self._lut)  # (H, W, 3) float32 per-channel factors
            np.multiply(t[:, :, 0], t[:, :, 1], out=out)
            out *= t[:, :, 2]
        else:
            _chromaticity_likelihood(np.ascontiguousarray(image), self._ref_chroma, self._inv_two_sigma2, out)

    def _response(self, image: np.ndarray) -> np.ndarray:
        W, H = self.image_size
        method = self.correlation
        if method == "filter2d":
            L = np.empty((H, W), np.float32)
            self._likelihood_into(image, L)
            return cv2.filter2D(L, cv2.CV_32F, self.template, borderType=cv2.BORDER_CONSTANT)
        Hp, Wp = self.fft_size
        self._likelihood_into(image, self._buf[:H, :W])  # the rest of the buffer stays zero
        if method == "scipy":
            S = scipy.fft.irfft2(scipy.fft.rfft2(self._buf) * self._spec, s=(Hp, Wp))
        elif method == "numpy":
            S = np.fft.irfft2(np.fft.rfft2(self._buf) * self._spec, s=(Hp, Wp))
        else:  # opencv: only the first H rows are non-zero in, and needed out
            F = cv2.dft(self._buf, nonzeroRows=H)
            F = cv2.mulSpectrums(F, self._spec, 0, conjB=True)
            S = cv2.idft(F, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE, nonzeroRows=H)
        return S[:H, :W]

    def detect_unchecked(self, image: np.ndarray) -> tuple[np.ndarray, float]:
        """:meth:`detect` on an image the caller has already checked (the tracker's frame-set boundary)."""
        S = self._response(image)
        H, W = S.shape
        y, x = divmod(int(np.argmax(S)), W)
        score = float(S[y, x])
        if score < self.options.min_score:
            return np.full(2, np.nan), score
        u, v = float(x), float(y)
        if self.options.subpixel == "parabola":
            u += _parabola(S, y, x, 0, 1) if 0 < x < W - 1 else 0.0
            v += _parabola(S, y, x, 1, 0) if 0 < y < H - 1 else 0.0
        return np.array([u, v]), score


def _parabola(S: np.ndarray, y: int, x: int, dy: int, dx: int) -> float:
    """Vertex offset of the parabola through three samples around the maximum, in [-0.5, 0.5]."""
    a, b, c = float(S[y - dy, x - dx]), float(S[y, x]), float(S[y + dy, x + dx])
    den = a - 2.0 * b + c
    if den >= 0.0:  # flat or not a maximum along this axis
        return 0.0
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel

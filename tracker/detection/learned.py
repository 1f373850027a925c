"""The learned detector stage: a small fully convolutional heatmap network that sees shape and context.

The paper's single 5x5 filter tests one pixel's colour; it cannot tell a white ball from a lamp, a
shelf or a white sneaker. This stage is a CenterNet-like network (a few convolutions, ~10k weights):
from an RGB frame it computes, on a grid of ``stride`` pixels, a ball *heat* logit (is a ball centre
in this cell?), the centre's sub-cell offset and the ball's log diameter. Candidates are the local
maxima of the heat above ``threshold``, best first; centres are sub-pixel (cell + offset), boxes and
areas come from the diameter (so the pipeline's 3D size test reads them like Algorithm 1's blobs).

Scale. Frames whose longer side exceeds ``max_side_px`` are shrunk (``cv2.INTER_AREA``) so that the
longer side is ``max_side_px``: the cost of a full frame is bounded (a VGA frame's) and the balls meet
the network at the sizes it was trained on (``diameter_range_px``, network pixels). A window search
takes the window plus ``context_px`` network pixels around it (what the network needs to see the
ball's surroundings), at the same scale.

Full frames in two passes (``coarse_side_px`` < ``max_side_px``): the network first runs on the frame
shrunk to ``coarse_side_px`` with ``coarse_threshold``; each of its ``coarse_candidates`` best peaks is then
searched as a window at the full scale, where the stage's own threshold decides and the centre is refined. Those
windows see ``coarse_context_px`` network pixels around them (``context_px`` where it is not set): a tracker's window
follows a ball it knows and keeps its context small (its cost), while a coarse peak's window must show the network
enough of the surroundings to score the ball as the full frame would (the shipped white stage: 24 px, not its
windows' 8; with 8, a large or smeared ball's heat at full scale fell to 0.2-0.4 where one pass over the frame gave it
0.5-0.7: README Results, "The coarse peaks' context"). Like the large balls' search below, only before the
confirmation's second look: a tracker's cameras search their whole frames with the windows' context (tried there, the
semi-real 3D flights gave positions in as many frame sets or more, fewer of them OK).
The coarse pass pays only where it removes most of the pixels: it is taken when the frame at the network's
scale is at least ``COARSE_MIN_RATIO`` times the coarse side (a 1080p frame at 960 px: a quarter of the
pixels); a VGA frame takes one pass, which ``rt2 bench detector`` measured faster than two there.

Large balls. The network learned balls of ``diameter_range_px`` (network pixels); a ball close to a camera can be
wider at the full scale (the caliscope session's near cameras: balls of 40-145 px at 1280x720, up to 109 network
pixels), where its heat stays low or it is not found at all, while the coarse pass, at a smaller scale, finds it. A
coarse peak whose diameter at the full scale exceeds ``BIG_SHARE`` of the largest trained diameter is also searched
as a window at the scale where it measures ``REFIT_SHARE`` of it, and the better of the two searches is kept, where it
is still that large there. Only before the confirmation's second look (single images, the label page's proposals,
``rt2 label --auto``), which judges what it adds: a tracker's cameras report the heat alone, and on the semi-real 3D
flights the search gave them positions in more frame sets, every one of those wrong (none OK), and one OK position fewer
(README Results, "The coarse pass over large frames").

Inference is ONNX Runtime on the CPU, one intra-op thread per call (the pipeline runs cameras on its
own threads): the fastest of the torch-free runtimes we measured for this network (OpenCV's dnn module
took 1.5-2.2x as long, a numpy im2col version longer still). The ONNX graph (exported by ``rt2 train``
from torch) takes the uint8 RGB frame as ``(1, H, W, 3)`` and does the conversion itself; its bytes
live in the model's ``.npz`` beside the 5x5 filter (``learned_*`` fields).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from checks.numba_cache import key_cache_on_callees
from checks.per_thread import PerThread
from tracker.detection.confirm import CONFIRM_FIELDS, ConfirmNet
from tracker.detection.onnx_session import SessionFactory

__all__ = ["LearnedStage", "LEARNED_FIELDS", "decode_heatmap", "decode_placed", "learned_scale"]

#: the model file's fields of this stage (all or none)
LEARNED_FIELDS = ("learned_onnx", "learned_stride", "learned_max_side_px", "learned_threshold", "learned_diameter_range_px",
                  "learned_context_px", "learned_description")


#: a full frame takes the coarse pass first when its longer side at the network's scale is at least this
#: many times ``coarse_side_px`` (module docstring)
COARSE_MIN_RATIO = 1.5
#: a coarse peak whose ball would be wider than this share of the network's largest trained diameter at the full scale
#: is searched again where it is ``REFIT_SHARE`` of it (module docstring, "Large balls")
BIG_SHARE = 40.0 / 48.0
REFIT_SHARE = 28.0 / 48.0


def learned_scale(height: int, width: int, max_side_px: int) -> float:
    """The factor a frame of ``height x width`` is resized by before the network (1 = as it is)."""
    side = max(int(height), int(width))
    return 1.0 if side <= max_side_px else max_side_px / side


#: the 3x3 neighbourhood of a heat peak
_NEIGHBOURS = np.ones((3, 3), np.uint8)


def decode_heatmap(out: np.ndarray, threshold_logit: float, k: int, stride: int, backend: str = "numba"):
    """Candidates of one network output.

    out : (4, h, w) float32: heat logit, offset u, offset v (cells), log diameter (network pixels)
    backend : "numba" (compiled, the default: a window's map in a few microseconds) or "numpy" (the reference;
        tests check they agree)
    returns (uv (n, 2) network pixels, heat logits (n,), diameters (n,) network pixels), best first, n <= k:
    the local maxima (3x3) of the heat above ``threshold_logit`` (compared in float32; ties in row-major order)
    """
    if backend == "numba":
        return _decode_numba(np.ascontiguousarray(out, dtype=np.float32), np.float32(threshold_logit), int(k), float(stride))
    if backend != "numpy":
        raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
    heat = np.ascontiguousarray(out[0])
    flat = heat.ravel()
    above = np.flatnonzero(flat > np.float32(threshold_logit))  # few cells: the peak test only there
    if len(above) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    vals = flat[above]
    peak = vals >= cv2.dilate(heat, _NEIGHBOURS).ravel()[above]
    idx, vals = above[peak], vals[peak]
    if len(idx) > 1:
        order = np.argsort(-vals, kind="stable")[:k]
        idx, vals = idx[order], vals[order]
    rows, cols = np.divmod(idx, heat.shape[1])
    o = out.reshape(4, -1)[1:, idx].astype(np.float64)
    # cell (r, c) covers pixels [stride*c, stride*c + stride); its centre is pixel stride*(c + 0.5) - 0.5
    uv = np.empty((len(idx), 2))
    uv[:, 0] = (cols + 0.5 + o[0]) * stride - 0.5
    uv[:, 1] = (rows + 0.5 + o[1]) * stride - 0.5
    # math.exp, as the compiled twin's: numpy's own exp (SIMD, chosen by the CPU) may differ from it in the last bit
    return uv, vals.astype(np.float64), np.array([math.exp(x) for x in np.clip(o[2], -2.0, 6.0).tolist()], np.float64)


@numba.njit(cache=True, nogil=True)
def _decode_numba(out, th, k, stride):
    """:func:`decode_heatmap` compiled: the same peaks, order and values."""
    _, h, w = out.shape
    idx = np.empty(h * w, np.int64)
    vals = np.empty(h * w, np.float32)
    n = 0
    for r in range(h):
        for c in range(w):
            v = out[0, r, c]
            if not v > th:
                continue
            peak = True
            for rr in range(max(r - 1, 0), min(r + 2, h)):
                for cc in range(max(c - 1, 0), min(c + 2, w)):
                    if out[0, rr, cc] > v:
                        peak = False
            if peak:
                idx[n] = r * w + c
                vals[n] = v
                n += 1
    order = np.argsort(-vals[:n], kind="mergesort")[:k]
    m = len(order)
    uv = np.empty((m, 2))
    sc = np.empty(m)
    d = np.empty(m)
    for j in range(m):
        i = idx[order[j]]
        r = i // w
        c = i - r * w
        uv[j, 0] = (c + 0.5 + np.float64(out[1, r, c])) * stride - 0.5
        uv[j, 1] = (r + 0.5 + np.float64(out[2, r, c])) * stride - 0.5
        sc[j] = np.float64(vals[order[j]])
        d[j] = math.exp(min(max(np.float64(out[3, r, c]), -2.0), 6.0))
    return uv, sc, d


def decode_placed(out: np.ndarray, threshold_logit: float, kk: int, stride: int, placement, box, k: int, backend: str = "numba"):
    """Candidates of one network output placed in the image: :func:`decode_heatmap`'s best ``kk`` peaks, moved from
    the network's pixels to the image's and kept where their centre lies in ``box``, at most ``k`` of them.

    placement : ``(sx, sy, bx0, by0)``: a network pixel's size in image pixels and the image pixel of the network
        input's corner (pixel centres: ``u_img + 0.5 = (u_net + 0.5) sx + bx0``); diameters scale by ``(sx + sy) / 2``
    box : ``(x0, y0, x1, y1)``: only centres inside it are kept (``x0 - 0.5 < u < x1 - 0.5``, same for v)
    backend : "numba" (one compiled call: a window search's post-processing in a few microseconds) or "numpy" (the
        reference; tests check they agree)
    returns (uv (n, 2) image pixels, scores (n,) heat probabilities, diameters (n,) image pixels), best first
    """
    sx, sy, bx0, by0 = placement
    x0, y0, x1, y1 = box
    if backend == "numba":
        return _decode_placed_numba(out if out.dtype == np.float32 and out.flags.c_contiguous else np.ascontiguousarray(out, dtype=np.float32),
                                    np.float32(threshold_logit), int(kk), float(stride), float(sx), float(sy), float(bx0), float(by0),
                                    int(x0), int(y0), int(x1), int(y1), int(k))
    if backend != "numpy":
        raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
    uv, heat, d = decode_heatmap(out, threshold_logit, kk, stride, backend="numpy")
    sx, sy = float(sx), float(sy)
    if sx != 1.0 or sy != 1.0:
        uv[:, 0] = (uv[:, 0] + 0.5) * sx - 0.5
        uv[:, 1] = (uv[:, 1] + 0.5) * sy - 0.5
        d *= 0.5 * (sx + sy)
    if bx0 or by0:
        uv[:, 0] += float(bx0)
        uv[:, 1] += float(by0)
    inside = (uv[:, 0] > x0 - 0.5) & (uv[:, 0] < x1 - 0.5) & (uv[:, 1] > y0 - 0.5) & (uv[:, 1] < y1 - 0.5)
    heat = heat[inside][:k]
    return uv[inside][:k], np.array([1.0 / (1.0 + math.exp(-x)) for x in heat.tolist()], np.float64), d[inside][:k]


@numba.njit(cache=True, nogil=True)
def _decode_placed_numba(out, th, kk, stride, sx, sy, bx0, by0, x0, y0, x1, y1, k):
    """:func:`decode_placed` compiled: the same arithmetic in the same order."""
    uv, sc, d = _decode_numba(out, th, kk, stride)
    scaled = sx != 1.0 or sy != 1.0
    f = 0.5 * (sx + sy)
    n = 0
    for j in range(len(sc)):
        if n == k:
            break
        u, v, dj = uv[j, 0], uv[j, 1], d[j]
        if scaled:
            u = (u + 0.5) * sx - 0.5
            v = (v + 0.5) * sy - 0.5
            dj = dj * f
        if bx0 != 0.0 or by0 != 0.0:
            u += bx0
            v += by0
        if u > x0 - 0.5 and u < x1 - 0.5 and v > y0 - 0.5 and v < y1 - 0.5:
            uv[n, 0], uv[n, 1], sc[n], d[n] = u, v, 1.0 / (1.0 + math.exp(-sc[j])), dj
            n += 1
    return uv[:n], sc[:n], d[:n]


@dataclass(frozen=True, eq=False)
class LearnedStage:
    """The heatmap network of a model file and how to run it.

    onnx : the network, ONNX bytes (input ``(1, H, W, 3)`` uint8 RGB; output ``(1, 4, H/stride, W/stride)``)
    stride : output cell size, network pixels
    max_side_px : frames with a longer side are shrunk to it first
    threshold : a candidate's heat probability at least (the network's operating point, chosen by training)
    diameter_range_px : (2,) ball diameters it was trained on, network pixels
    context_px : network pixels searched around a window (the surroundings the network sees)
    description : how it was trained, on what
    coarse_side_px : full frames: the longer side of the first, coarse pass (0 = one pass at ``max_side_px``)
    coarse_threshold : the coarse pass's heat threshold (a probability)
    coarse_candidates : the coarse peaks searched again at full scale
    coarse_context_px : network pixels searched around each coarse peak's window at full scale before the second look
        (None: ``context_px``; module docstring)
    track_threshold : the heat probability a tracker's cameras report candidates down to (None: ``threshold``).
        Lower than ``threshold``, the single image's operating point: in a rig the robust consensus (three
        cameras that agree, the 3D size test) rejects a camera's false alarms, while a camera that misses the
        ball costs the frame set that camera's evidence
    size_ratio : the 3D size test's threshold this stage's diameters need (None: the tracker's own): the 99th
        percentile of its diameter / the ball's true diameter on semi-real frames of its training cameras, written
        by ``rt2 train-shipped``. A network's diameter spreads wider than a blob's (the shipped white stage: median
        1.00, 99th percentile 1.53 on its training cameras' balls), and a tracker whose size test stops at 1.3
        rejects true positions (``TrackerOptions.model_size_ratio``)
    filter_refines : whether the model's 5x5 filter sees this stage's balls (it refines their centres,
        :class:`~tracker.detection.detector.DetectorOptions` ``refine_with_filter``); False where the file's
        filter is of another colour (the white model keeps the orange filter for ``rt2-paper``) or another look (the
        real-camera orange model keeps the filter trained on renders; the ball's edge centres its balls better)
    confirm : optional :class:`~tracker.detection.confirm.ConfirmNet`: on a whole frame, the heat's best candidates
        looked at again, each on its crop at the ball's scale; their score becomes ``sqrt(p * heat)``, and a
        caller's threshold (a tracker's ``track_threshold``) applies to it there, or else the confirmation's own
        single-image threshold (``ConfirmNet.threshold``); a window keeps the heat and ``threshold``
    """

    onnx: bytes
    stride: int = 4
    max_side_px: int = 640
    threshold: float = 0.5
    diameter_range_px: tuple = (4.0, 40.0)
    context_px: int = 24
    description: str = ""
    coarse_side_px: int = 0
    coarse_threshold: float = 0.1
    coarse_candidates: int = 8
    filter_refines: bool = True
    track_threshold: float | None = None
    size_ratio: float | None = None
    confirm: ConfirmNet | None = None
    coarse_context_px: int | None = None

    def __post_init__(self):
        where = "LearnedStage"
        if self.confirm is not None and not isinstance(self.confirm, ConfirmNet):
            raise ValueError(f"{where}: confirm must be a ConfirmNet or None, got {type(self.confirm).__name__}")
        if not isinstance(self.onnx, (bytes, bytearray)) or len(self.onnx) < 16:
            raise ValueError(f"{where}: onnx must be the network's ONNX bytes, got {type(self.onnx).__name__} of length "
                             f"{len(self.onnx) if hasattr(self.onnx, '__len__') else '?'}")
        lowest = dict(stride=1, max_side_px=1, context_px=0, coarse_side_px=0, coarse_candidates=1, coarse_context_px=0)
        for name, lo in lowest.items():
            v = getattr(self, name)
            if v is None and name == "coarse_context_px":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"{where}: {name} must be {'None or ' if name == 'coarse_context_px' else ''}an integer >= {lo}, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.coarse_side_px and not 8 * self.stride <= self.coarse_side_px < self.max_side_px:
            raise ValueError(f"{where}: coarse_side_px must be 0 or in [{8 * self.stride}, max_side_px = {self.max_side_px}), got {self.coarse_side_px}")
        if self.max_side_px < 8 * self.stride:
            raise ValueError(f"{where}: max_side_px ({self.max_side_px}) must be at least 8 strides ({8 * self.stride})")
        if not isinstance(self.filter_refines, (bool, np.bool_)):
            raise ValueError(f"{where}: filter_refines must be True or False, got {self.filter_refines!r}")
        object.__setattr__(self, "filter_refines", bool(self.filter_refines))
        for name in ("threshold", "coarse_threshold", "track_threshold"):
            t = getattr(self, name)
            if name == "track_threshold" and t is None:
                continue
            if isinstance(t, bool) or not isinstance(t, (int, float, np.floating)) or not 0.0 < float(t) < 1.0:
                raise ValueError(f"{where}: {name} must be a probability in (0, 1), got {t!r}")
            object.__setattr__(self, name, float(t))
        r = self.size_ratio
        if r is not None:
            if isinstance(r, bool) or not isinstance(r, (int, float, np.floating, np.integer)) or not (math.isfinite(r) and 1.0 <= r <= 10.0):
                raise ValueError(f"{where}: size_ratio must be None or a ratio in [1, 10], got {r!r}")
            object.__setattr__(self, "size_ratio", float(r))
        d = np.asarray(self.diameter_range_px, np.float64).reshape(-1)
        if d.shape != (2,) or not np.isfinite(d).all() or not 0 < d[0] <= d[1]:
            raise ValueError(f"{where}: diameter_range_px must be [min, max] with 0 < min <= max, got {self.diameter_range_px!r}")
        object.__setattr__(self, "diameter_range_px", (float(d[0]), float(d[1])))
        object.__setattr__(self, "onnx", bytes(self.onnx))
        object.__setattr__(self, "_sessions", PerThread(SessionFactory(self.onnx)))
        object.__setattr__(self, "_threshold_logit", math.log(self.threshold / (1.0 - self.threshold)))

    # -- inference -------------------------------------------------------------------------------
    def run(self, image: np.ndarray) -> np.ndarray:
        """(4, h, w) float32 network output of an (H, W, 3) uint8 RGB image at the network's scale (no resizing)."""
        return self._sessions.get().run(None, {"image": np.ascontiguousarray(image)[None]})[0][0]

    def scale_of(self, height: int, width: int) -> float:
        return learned_scale(height, width, self.max_side_px)

    def candidates(self, image: np.ndarray, window=None, k: int = 4, threshold: float | None = None, frame_shape=None, confirm: bool = True):
        """Ball candidates of a trusted (H, W, 3) uint8 RGB image, or of one box of it.

        window : None or ``(x0, y0, x1, y1)``: only candidates whose centre lies in the box (the network also
            sees ``context_px`` network pixels around it)
        threshold : score at least, a probability (None: the stage's own, or on a whole frame with the second look the
            confirmation's ``threshold``); with the second look it applies to the confirmed scores
        frame_shape : when ``image`` is a part of a camera frame (a tracker's neighbourhood view), that frame's
            shape: the part is searched at the frame's scale, in one pass
        confirm : on a whole frame, the confirmation network's second look where the stage has one (False: the heat alone)
        returns (uv (n, 2) image pixels, scores (n,) probabilities: the confirmation's on a whole frame where it ran,
        else the heat's; diameters (n,) image pixels), best first
        """
        h, w = image.shape[:2] if frame_shape is None else frame_shape[:2]
        scale = learned_scale(h, w, self.max_side_px)
        whole = window is None and frame_shape is None
        look = self.confirm if whole and confirm else None
        kk, th = (k, threshold) if look is None else (max(k, look.candidates), look.gate)
        if whole and self.coarse_side_px and max(h, w) * scale >= COARSE_MIN_RATIO * self.coarse_side_px:
            uv, sc, d = self._two_passes(image, kk, th, second_look=look is not None)
        else:
            uv, sc, d = self._one_pass(image, window, kk, th, scale)
        if look is None:
            return uv, sc, d
        p = look.rescore(image, uv, sc, d)
        keep = np.flatnonzero(p >= (look.threshold if threshold is None else threshold))
        keep = keep[np.argsort(-p[keep], kind="stable")][:k]
        return uv[keep], p[keep], d[keep]

    def aligned_window(self, window, height: int, width: int) -> tuple:
        """A window holding ``window`` ``(x0, y0, x1, y1)`` (clipped to the frame) of a ``height x width`` frame whose search gives the network
        the very input a full-frame pass gives it there: the box it sees (the window plus ``context_px``) starts
        and ends on the frame's grid of 8 network pixels (the network's coarsest stride) after the resize, so
        the resized pixels and the cells are the full frame's; only the box's edges differ (the network sees no
        further). Where the frame's scale has no such grid in whole pixels, the window as it is."""
        s = self.scale_of(height, width)
        period = next((p for p in range(1, 257) if abs(p * s / 8 - round(p * s / 8)) < 1e-9 and round(p * s / 8) >= 1), None)
        if period is None:
            return tuple(int(v) for v in window)
        m = self.context_px / s
        cm = int(math.ceil(m - 1e-9))
        x0, y0, x1, y1 = (int(v) for v in window)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)

        def lo(v):  # the box starts at the grid point at or below v - m: window start = grid + ceil(m), or 0
            g = (max(int(math.floor(v - m)), 0) // period) * period
            return g + cm if g else 0

        def hi(v, size):  # the box ends at the grid point at or above v + m: window end = grid - ceil(m), or the frame's end
            g = -(-int(math.ceil(v + m)) // period) * period
            return size if g >= size else g - cm

        ax0, ay0, ax1, ay1 = lo(x0), lo(y0), hi(x1, width), hi(y1, height)
        if not (ax0 <= x0 and ay0 <= y0 and ax1 >= x1 and ay1 >= y1):
            return x0, y0, x1, y1
        return ax0, ay0, ax1, ay1

    def _two_passes(self, image, k: int, threshold, second_look: bool = False):
        """Full frame: the coarse pass's best peaks, each searched again as a window at full scale (module docstring);
        ``second_look`` (the confirmation will judge the candidates): the windows with ``coarse_context_px`` of context,
        and a peak too large for the full scale also where it fits (module docstring, "Large balls")."""
        h, w = image.shape[:2]
        ctx = self.coarse_context_px if second_look else None  # the peaks' windows' context (None: the stage's windows')
        uv, _, d = self._one_pass(image, None, self.coarse_candidates, self.coarse_threshold, learned_scale(h, w, self.coarse_side_px))
        if len(uv) == 0:
            return uv, np.zeros(0), d
        s = self.scale_of(h, w)
        big = BIG_SHARE * self.diameter_range_px[1]  # network pixels: a ball wider at the full scale is searched again
        found = []
        for (u, v), dd in zip(uv, d):
            half = max(2 * self.stride / s, 0.75 * dd)  # the coarse centre is within a coarse cell; the ball fits
            x0, y0 = max(0, int(math.floor(u - half))), max(0, int(math.floor(v - half)))
            x1, y1 = min(w, int(math.ceil(u + half)) + 1), min(h, int(math.ceil(v + half)) + 1)
            if x0 < x1 and y0 < y1:
                f = self._one_pass(image, (x0, y0, x1, y1), 1, threshold, s, context=ctx)
                if second_look and dd * s > big:  # too large for the network at the full scale: again where it fits
                    g = self._one_pass(image, (x0, y0, x1, y1), 1, threshold, REFIT_SHARE * self.diameter_range_px[1] / dd)
                    if len(g[1]) and g[2][0] * s > big and (len(f[1]) == 0 or g[1][0] > f[1][0]):
                        f = g
                found.append(f)
        found = [f for f in found if len(f[1])]
        if not found:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        uv = np.concatenate([f[0] for f in found])
        sc = np.concatenate([f[1] for f in found])
        d = np.concatenate([f[2] for f in found])
        order = np.argsort(-sc, kind="stable")
        uv, sc, d = uv[order], sc[order], d[order]
        keep = []  # two coarse peaks on one ball find it twice: keep the better
        for i in range(len(sc)):
            if all(np.hypot(*(uv[i] - uv[j])) > 0.5 * max(d[i], d[j]) for j in keep):
                keep.append(i)
        keep = keep[:k]
        return uv[keep], sc[keep], d[keep]

    def network_input(self, image, window, s: float, context: int | None = None) -> tuple:
        """What a pass hands the network for ``image`` (or for ``window`` ``(x0, y0, x1, y1)`` of it, with ``context``
        network pixels around it; None: ``context_px``) shrunk by ``s``: ``(input (h, w, 3) uint8 padded to whole cells, placement (sx, sy, bx0, by0) of its pixels in
        the image, the searched box (x0, y0, x1, y1))``."""
        h, w = image.shape[:2]
        if window is None:
            x0 = y0 = 0
            x1, y1 = w, h
        else:
            x0, y0, x1, y1 = (int(v) for v in window)
        # the box the network sees, in image pixels: the window plus the context, inside the image
        m = (self.context_px if context is None else context) / s
        bx0, by0 = max(0, int(math.floor(x0 - m))), max(0, int(math.floor(y0 - m)))
        bx1, by1 = min(w, int(math.ceil(x1 + m))), min(h, int(math.ceil(y1 + m)))
        crop = image[by0:by1, bx0:bx1]
        if s != 1.0:
            nw, nh = max(1, int(round((bx1 - bx0) * s))), max(1, int(round((by1 - by0) * s)))
            crop = cv2.resize(crop, (nw, nh), interpolation=cv2.INTER_AREA)
            sx, sy = (bx1 - bx0) / nw, (by1 - by0) / nh
        else:
            sx = sy = 1.0
        ch, cw = crop.shape[:2]
        st = self.stride
        ph, pw = (-ch) % st, (-cw) % st  # the network's input is a whole number of cells
        if ph or pw:
            crop = cv2.copyMakeBorder(crop, 0, ph, 0, pw, cv2.BORDER_REFLECT_101 if min(ch, cw) > 1 else cv2.BORDER_REPLICATE)
        return crop, (sx, sy, bx0, by0), (x0, y0, x1, y1)

    def _one_pass(self, image, window, k: int, threshold, s: float, context: int | None = None):
        """Candidates of ``image`` (or of ``window`` in it, with ``context`` network pixels around it; None: ``context_px``)
        with the image shrunk by ``s``."""
        th = self._threshold_logit if threshold is None else math.log(threshold / (1.0 - threshold))
        crop, placement, box = self.network_input(image, window, s, context)
        kk = 4 * k if window is not None else k  # some peaks of the context may fall outside the window
        return decode_placed(self.run(crop), th, kk, self.stride, placement, box, k)

    # -- files (fields of the model's .npz) ----------------------------------------------------------
    def to_fields(self) -> dict:
        return dict(learned_onnx=np.frombuffer(self.onnx, np.uint8), learned_stride=np.array(self.stride),
                    learned_max_side_px=np.array(self.max_side_px), learned_threshold=np.array(self.threshold),
                    learned_diameter_range_px=np.array(self.diameter_range_px), learned_context_px=np.array(self.context_px),
                    learned_description=np.array(self.description),
                    learned_coarse=np.array([self.coarse_side_px, self.coarse_threshold, self.coarse_candidates]
                                            + ([] if self.coarse_context_px is None else [self.coarse_context_px]), np.float64),
                    learned_refine=np.array(self.filter_refines),
                    **({} if self.track_threshold is None else {"learned_track_threshold": np.array(self.track_threshold)}),
                    **({} if self.size_ratio is None else {"learned_size_ratio": np.array(self.size_ratio)}),
                    **({} if self.confirm is None else self.confirm.to_fields()))

    @classmethod
    def from_fields(cls, data: dict, src: str) -> "LearnedStage | None":
        """The stage stored in a model file's fields, or None when the file has none."""
        present = [k for k in LEARNED_FIELDS if k in data]
        if not present:
            if any(k in data for k in CONFIRM_FIELDS):
                raise ValueError(f"{src}: a confirmation network ({', '.join(k for k in CONFIRM_FIELDS if k in data)}) without a learned stage")
            return None
        missing = [k for k in LEARNED_FIELDS if k not in data]
        if missing:
            raise ValueError(f"{src}: learned stage fields incomplete, missing {missing}")
        onnx = data["learned_onnx"]
        if onnx.dtype != np.uint8 or onnx.ndim != 1:
            raise ValueError(f"{src}: field 'learned_onnx' must be the ONNX bytes as a uint8 vector, got dtype {onnx.dtype} shape {onnx.shape}")
        for k in LEARNED_FIELDS[1:-1]:
            if data[k].dtype.kind not in "biuf":
                raise ValueError(f"{src}: field {k!r} must be numbers, got dtype {data[k].dtype}")
        for k in ("learned_stride", "learned_max_side_px", "learned_context_px"):
            if data[k].shape != () or not float(data[k]).is_integer():
                raise ValueError(f"{src}: field {k!r} must be an integer, got {data[k]!r}")
        if data["learned_description"].dtype.kind != "U":
            raise ValueError(f"{src}: field 'learned_description' must be a string, got dtype {data['learned_description'].dtype}")
        coarse = {}
        if "learned_coarse" in data:  # optional: [side px, threshold, candidates(, the peaks' windows' context px)] of the coarse pass
            c = data["learned_coarse"]
            if (c.dtype.kind not in "biuf" or c.shape not in ((3,), (4,)) or not np.isfinite(c).all() or not float(c[0]).is_integer()
                    or not float(c[2]).is_integer() or (c.shape == (4,) and not float(c[3]).is_integer())):
                raise ValueError(f"{src}: field 'learned_coarse' must be [side px, threshold, candidates] and optionally the peaks' windows' "
                                 f"context px (integers, a probability), got {c!r}")
            coarse = dict(coarse_side_px=int(c[0]), coarse_threshold=float(c[1]), coarse_candidates=int(c[2]),
                          **({"coarse_context_px": int(c[3])} if c.shape == (4,) else {}))
        if "learned_refine" in data:  # optional: whether the file's filter refines the stage's centres (default yes)
            r = data["learned_refine"]
            if r.dtype != np.bool_ or r.shape != ():
                raise ValueError(f"{src}: field 'learned_refine' must be a boolean, got dtype {r.dtype} shape {r.shape}")
            coarse["filter_refines"] = bool(r)
        if "learned_track_threshold" in data:  # optional: the tracker's operating point (default: the threshold)
            t = data["learned_track_threshold"]
            if t.dtype.kind not in "f" or t.shape != ():
                raise ValueError(f"{src}: field 'learned_track_threshold' must be a probability (a float), got dtype {t.dtype} shape {t.shape}")
            coarse["track_threshold"] = float(t)
        if "learned_size_ratio" in data:  # optional: the size test's threshold the stage's diameters need (default: the tracker's)
            r = data["learned_size_ratio"]
            if r.dtype.kind not in "f" or r.shape != ():
                raise ValueError(f"{src}: field 'learned_size_ratio' must be a ratio (a float), got dtype {r.dtype} shape {r.shape}")
            coarse["size_ratio"] = float(r)
        confirm = ConfirmNet.from_fields(data, src)  # optional: the second look at a whole frame's candidates
        if confirm is not None:
            coarse["confirm"] = confirm
        try:
            stage = cls(onnx=onnx.tobytes(), stride=int(data["learned_stride"]), max_side_px=int(data["learned_max_side_px"]),
                        threshold=float(data["learned_threshold"]), diameter_range_px=tuple(np.asarray(data["learned_diameter_range_px"], float).reshape(-1)),
                        context_px=int(data["learned_context_px"]), description=str(data["learned_description"]), **coarse)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{src}: {exc}") from None
        problem = stage.check()
        if problem:
            raise ValueError(f"{src}: field 'learned_onnx': {problem}")
        return stage

    def check(self) -> str | None:
        """None when the network loads and maps a small frame to the expected output; else what is wrong."""
        try:
            out = self.run(np.zeros((8 * self.stride, 8 * self.stride, 3), np.uint8))
        except Exception as exc:  # a damaged graph: ONNX Runtime's own message, on one line
            return f"not a network this rt2 can run ({type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''})"
        if out.shape != (4, 8, 8):
            return f"the network maps a {8 * self.stride}x{8 * self.stride} frame to shape {out.shape}, expected (4, 8, 8)"
        if not np.isfinite(out).all():
            return "the network's output is not finite"
        return None


key_cache_on_callees(globals())  # an edit of a helper it compiles in (another file too) recompiles a kernel

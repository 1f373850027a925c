"""Training the learned detector stage (:class:`tracker.detection.learned.LearnedStage`): a small heatmap
network, CenterNet-like, fitted in torch on the CPU and exported to ONNX for inference without torch.

The network (:func:`build_net`): the uint8 RGB frame in, ``x / 255 - 0.5``; a 4x4 convolution of stride 4
(16 channels: every pixel of each 4x4 cell seen, so balls of a few pixels keep their shape); three 3x3
convolutions at stride 8 (16 channels, dilations 1, 2, 4: what surrounds the ball, up to ~120 pixels);
upsampled to stride 4 and joined to the stride-4 features; a 1x1 convolution to four maps: the heat
logit, the centre's offset in the cell (u, v) and the log diameter. About 10k weights.

Targets (:func:`targets`): a Gaussian bump on the heat at each ball's centre (sigma from its diameter,
at least half a cell), offset and log diameter at the centre's cell. Loss: CenterNet's penalty-reduced
focal loss on the heat plus L1 on offset and log diameter at the centre cells.

Samples (:func:`sample_patches`): square patches of the training images at random scales (the balls'
sizes spread over the stage's diameter range), half of them on a ball, with the photometric changes of
:mod:`harness.experiments.detector.augment` (white balance, exposure, gamma, lamp tint, motion blur or
defocus, gain noise, JPEG). Everything random comes from the seeded ``rng``; torch is seeded too and runs
on one thread, so the same data and seed give the same weights.
"""

from __future__ import annotations

import math
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

from harness.experiments.detector.augment import AugmentOptions, jpeg, optics
from tracker.detection.learned import LearnedStage, learned_scale

__all__ = ["FitTask", "LearnedItem", "LearnedTrainOptions", "build_net", "deploy_onnx", "export_onnx", "fit_learned", "averaged", "contrast_crops", "ema_problem", "fade_balls", "items_at_scale", "moving_average", "false_alarms", "kept_passes", "mine_false_peaks", "auto_workers", "run_fit", "run_fits", "sample_patches", "with_contrast",
           "stage_candidates", "targets"]

STRIDE = 4

#: the network's layouts (:func:`build_net`): "s8" = the stride-4 and stride-8 branches (module docstring, the
#: default); "s16" adds a stride-16 branch of 32 channels (two 3x3 convolutions, dilations 1 and 2, residual) whose
#: features join the stride-8 ones in place of the dilation-4 layer: more context (~250 pixels), ~10 % more
#: arithmetic. Trained by the white recipe (3000 steps, seed 0) it did worse than s8 on every held-out figure
#: (docs/results_history.md), so s8 stays the default
ARCHS = ("s8", "s16")
DEFAULT_ARCH = "s8"


def ema_problem(decay) -> str | None:
    """None when ``decay`` is a moving average's decay per step (0 = none, up to below 1); else what is wrong with it."""
    if isinstance(decay, bool) or not isinstance(decay, (int, float)) or not 0.0 <= decay < 1.0:
        return f"must be a decay per step from 0 (none) to below 1, got {decay!r}"
    return None


def moving_average(torch, net, decay: float):
    """The exponential moving average of ``net``'s weights with ``decay`` per step (torch's ``AveragedModel``, updated
    with ``update_parameters(net)`` after each step), or None for a decay of 0; :func:`averaged` gives the network to keep."""
    if not decay:
        return None
    from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

    return AveragedModel(net, multi_avg_fn=get_ema_multi_avg_fn(decay))


def averaged(net, average, decay: float) -> tuple:
    """``(the network to keep, what the training's log line says of it)``: the moving average's when there is one."""
    if average is None:
        return net, ""
    return average.module, f"; the weights' moving average kept (decay {decay:g} per step)"


@dataclass(frozen=True)
class LearnedTrainOptions:
    """Options of :func:`fit_learned`.

    iterations : optimiser steps; batch : patches per step; patch_px : patch side (network pixels)
    lr : Adam's learning rate (cosine decay to 5 % of it); weight_decay : Adam's L2
    p_ball : share of patches centred near a ball
    scale_range : patches are taken at a random scale in this range (log-uniform), after the frame's own
        scale to the network (``max_side_px``)
    diameter_range_px : ball diameters (network pixels) a patch's balls are kept within by its scale
    arch : the network's layout (one of ``ARCHS``; fine-tuning keeps the layout of the state it starts from)
    max_side_px : frames are shrunk to this longer side first (the stage's; :func:`tracker.detection.learned.learned_scale`)
    augment : photometric augmentation of the patches (:mod:`harness.experiments.detector.augment`)
    p_light : share of patches with a light source drawn in, away from their balls (:func:`draw_light`: a lamp's
        saturated core and glow, what a white ball's detector mistakes for one; 0 = none, no random draw)
    p_mined : share of patches centred on the network's own false alarms in its training images (:func:`mine_false_peaks`,
        bootstrapping: what it mistakes for a ball, shown again as a negative), mined every ``mine_every`` steps from
        then on; 0 = none, no random draw
    mine_every : steps between two minings (the first after this many steps; none at the last step)
    mine_first : mine once more before the first step too (a network continued from one already trained: its false
        alarms are there from the start)
    p_faded : share of the patches with balls whose balls are faded into their surroundings (:func:`fade_balls`: their
        contrast cut to ``FADE_CONTRAST`` of it, as a dim ball in a dark frame, a grey ball on a grey floor or a smear
        is); 0 = none, no random draw
    ema : the network kept is the exponential moving average of its weights over the steps, with this decay per step
        (``torch.optim.swa_utils.AveragedModel``, as detectors' trainings keep one: YOLO's ModelEMA, timm's
        ModelEmaV2); 0 = the last step's weights (no average)
    """

    iterations: int = 1500
    batch: int = 24
    patch_px: int = 128
    lr: float = 3e-3
    weight_decay: float = 1e-5
    p_ball: float = 0.6
    scale_range: tuple = (0.6, 1.6)
    diameter_range_px: tuple = (4.0, 48.0)
    max_side_px: int = 640
    augment: bool = True
    arch: str = DEFAULT_ARCH
    p_light: float = 0.0
    p_mined: float = 0.0
    mine_every: int = 1000
    mine_first: bool = False
    ema: float = 0.0
    p_faded: float = 0.0

    def __post_init__(self):
        for name in ("iterations", "batch", "patch_px", "max_side_px", "mine_every"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"LearnedTrainOptions.{name} must be a positive integer, got {v!r}")
        if self.patch_px % (2 * STRIDE):
            raise ValueError(f"LearnedTrainOptions.patch_px must be a multiple of {2 * STRIDE}, got {self.patch_px}")
        if self.arch not in ARCHS:
            raise ValueError(f"LearnedTrainOptions.arch must be one of {list(ARCHS)}, got {self.arch!r}")
        for name in ("p_light", "p_mined", "p_faded"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                raise ValueError(f"LearnedTrainOptions.{name} must be a share between 0 and 1, got {v!r}")
        if ema_problem(self.ema):
            raise ValueError(f"LearnedTrainOptions.ema {ema_problem(self.ema)}")
        if not (0 < self.scale_range[0] <= self.scale_range[1]):
            raise ValueError(f"LearnedTrainOptions.scale_range must be (lo, hi) with 0 < lo <= hi, got {self.scale_range!r}")


@dataclass(frozen=True, eq=False)
class LearnedItem:
    """One training image at the network's scale: ``image`` (H, W, 3) uint8 RGB, ``centers`` (n, 2) rt2 pixels,
    ``diameters`` (n,) pixels, ``weight`` (how often it is sampled, relative), ``name`` (for messages)."""

    image: np.ndarray
    centers: np.ndarray
    diameters: np.ndarray
    weight: float = 1.0
    name: str = ""


def items_at_scale(pairs, max_side_px: int, weight: float = 1.0) -> list[LearnedItem]:
    """``(image, LabelledImage)`` pairs -> :class:`LearnedItem` shrunk as the stage shrinks frames (``max_side_px``)."""
    out = []
    for image, li in pairs:
        h, w = image.shape[:2]
        s = learned_scale(h, w, max_side_px)
        c = np.asarray(li.centers_px, np.float64).reshape(-1, 2)
        d = np.minimum(li.boxes_xywh[:, 2], li.boxes_xywh[:, 3]).astype(np.float64) if len(c) else np.zeros(0)
        if s != 1.0:
            nw, nh = max(1, int(round(w * s))), max(1, int(round(h * s)))
            image = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA)
            sx, sy = nw / w, nh / h
            c = (c + 0.5) * np.array([sx, sy]) - 0.5
            d = d * 0.5 * (sx + sy)
        out.append(LearnedItem(np.ascontiguousarray(image), c, d, weight, str(li.path)))
    return out


def targets(centers, diameters, size: int, stride: int = STRIDE):
    """Heat (g, g), offsets (2, g, g), log diameters (g, g) and centre mask (g, g) of a ``size`` x ``size`` patch, g = size / stride."""
    g = size // stride
    heat = np.zeros((g, g), np.float32)
    off = np.zeros((2, g, g), np.float32)
    logd = np.zeros((g, g), np.float32)
    mask = np.zeros((g, g), np.float32)
    ys, xs = np.mgrid[0:g, 0:g].astype(np.float32)
    for (u, v), d in zip(np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)):
        cu, cv_ = (u + 0.5) / stride - 0.5, (v + 0.5) / stride - 0.5  # centre in cell units (cell centres at integers)
        ci, cj = int(round(cv_)), int(round(cu))
        if not (0 <= ci < g and 0 <= cj < g):
            continue
        sigma = max(0.5, d / stride / 6.0)
        bump = np.exp(-((xs - cu) ** 2 + (ys - cv_) ** 2) / (2 * sigma * sigma))
        heat = np.maximum(heat, bump.astype(np.float32))
        heat[ci, cj] = 1.0
        off[0, ci, cj], off[1, ci, cj] = cu - cj, cv_ - ci
        logd[ci, cj] = math.log(max(d, 1.0))
        mask[ci, cj] = 1.0
    return heat, off, logd, mask


def sample_patches(items: list[LearnedItem], n: int, rng: np.random.Generator, opts: LearnedTrainOptions, aug: AugmentOptions | None = None,
                   mined=()):
    """n training patches: (images (n, P, P, 3) uint8, heat (n, g, g), offsets (n, 2, g, g), log diameters (n, g, g), masks (n, g, g)).

    mined : ``(item index, u, v)`` false alarms of the network (:func:`mine_false_peaks`); a share ``opts.p_mined`` of
        the patches is centred near one of them (no random draw while there are none)"""
    p = opts.patch_px
    weights = np.array([it.weight for it in items], np.float64)
    weights /= weights.sum()
    with_ball = [i for i, it in enumerate(items) if len(it.centers)]
    w_b = weights[with_ball] / weights[with_ball].sum() if with_ball else None  # once, not per patch
    imgs = np.empty((n, p, p, 3), np.uint8)
    g = p // STRIDE
    heat = np.empty((n, g, g), np.float32)
    off = np.empty((n, 2, g, g), np.float32)
    logd = np.empty((n, g, g), np.float32)
    mask = np.empty((n, g, g), np.float32)
    lo, hi = np.log(opts.scale_range)
    for k in range(n):
        if len(mined) and rng.random() < opts.p_mined:  # near a false alarm: the balls it holds keep their targets
            i, u, v = mined[int(rng.integers(len(mined)))]
            it = items[int(i)]
            s = math.exp(rng.uniform(lo, hi))
            side = p / s
            cu, cv_ = np.array([u, v]) + rng.uniform(-0.3, 0.3, 2) * side
        elif with_ball and rng.random() < opts.p_ball:
            it = items[with_ball[int(rng.choice(len(with_ball), p=w_b))]]
            j = int(rng.integers(len(it.centers)))
            s = math.exp(rng.uniform(lo, hi))
            d = it.diameters[j] * s  # keep the ball inside the trained range
            dmin, dmax = opts.diameter_range_px
            if d < dmin or d > dmax:
                s = float(np.clip(d, dmin, dmax)) / max(it.diameters[j], 1e-3)
            side = p / s
            cu, cv_ = it.centers[j] + rng.uniform(-0.4, 0.4, 2) * side
        else:
            it = items[int(rng.choice(len(items), p=weights))]
            s = math.exp(rng.uniform(lo, hi))
            side = p / s
            h, w = it.image.shape[:2]
            cu, cv_ = rng.uniform(0, max(w - 1, 1)), rng.uniform(0, max(h - 1, 1))
        # the patch: a square of `side` image pixels centred at (cu, cv_), resampled to p x p (borders reflected);
        # rt2 pixel centres (integers): x_patch = a (x_img - c) + p / 2 - 0.5
        a = p / side
        m = np.array([[a, 0.0, p / 2 - 0.5 - a * cu], [0.0, a, p / 2 - 0.5 - a * cv_]])
        patch = _warp(it.image, m, p, a)
        c = it.centers * a + m[:, 2] if len(it.centers) else np.zeros((0, 2))
        dd = it.diameters * a
        if rng.random() < 0.5:
            patch = np.ascontiguousarray(patch[:, ::-1])
            c = c.copy()
            c[:, 0] = p - 1 - c[:, 0]
        if opts.p_faded and len(c) and rng.random() < opts.p_faded:  # before the exposure: the frame's own dimming on top
            patch = fade_balls(patch, rng, c, dd)
        if opts.augment:
            patch = photometric(patch, rng, aug or _PATCH_AUGMENT)
        if opts.p_light and rng.random() < opts.p_light:  # after the exposure: a lamp's core stays saturated
            patch = draw_light(patch, rng, c, dd)
        imgs[k] = patch
        heat[k], off[k], logd[k], mask[k] = targets(c, dd, p)
    return imgs, heat, off, logd, mask


#: a drawn light's core radius, pixels of the patch (log-uniform), and how far its glow reaches, in core radii
LIGHT_RADIUS_PX = (4.0, 40.0)
LIGHT_GLOW = (0.15, 1.5)


def draw_light(patch: np.ndarray, rng: np.random.Generator, centers, diameters, tries: int = 5) -> np.ndarray:
    """``patch`` (P, P, 3) uint8 with a light source drawn in where it covers none of the balls at ``centers`` (n, 2) of
    ``diameters`` (n,) (a copy; the patch itself where no place is found in ``tries``): an ellipse (axes ratio 1-1.8) of a
    saturated, near-white core (a camera clips a lamp; a white ball's own highlight is a small part of it), its glow
    falling off outside it, often cut by the patch's edge, as a ceiling lamp or a window's reflection is. A white
    ball's detector mistakes them for balls (the caliscope session's ceiling lamp, README Results)."""
    p = patch.shape[0]
    r = math.exp(rng.uniform(*np.log(LIGHT_RADIUS_PX)))
    b = r / rng.uniform(1.0, 1.8)
    ang = rng.uniform(0.0, math.pi)
    glow = rng.uniform(*LIGHT_GLOW)
    reach = r * (1.0 + 2.5 * glow)
    c, d = np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)
    for _ in range(tries):
        cx, cy = rng.uniform(-0.5 * r, p - 1 + 0.5 * r, 2)
        if (np.hypot(c[:, 0] - cx, c[:, 1] - cy) > reach + 0.5 * d + 2.0).all():
            break
    else:
        return patch
    y, x = np.mgrid[0:p, 0:p].astype(np.float32)
    ca, sa = math.cos(ang), math.sin(ang)
    xr, yr = (x - cx) * ca + (y - cy) * sa, -(x - cx) * sa + (y - cy) * ca
    rho = np.sqrt((xr / r) ** 2 + (yr / b) ** 2)
    alpha = np.where(rho <= 1.0, 1.0, rng.uniform(0.3, 1.0) * np.exp(-(((rho - 1.0) / glow) ** 2))).astype(np.float32)
    colour = np.full(3, 255.0, np.float32)
    if rng.random() < 0.3:  # a warm or cool lamp: one channel under the clip
        colour[int(rng.integers(3))] = rng.uniform(215.0, 250.0)
    out = patch.astype(np.float32) * (1.0 - alpha[..., None]) + colour * alpha[..., None]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


#: a faded ball's contrast against its surroundings, a share of its own (uniform; :func:`fade_balls`)
FADE_CONTRAST = (0.25, 0.7)


def fade_balls(patch: np.ndarray, rng: np.random.Generator, centers, diameters) -> np.ndarray:
    """A copy of ``patch`` (P, P, 3) uint8 whose balls at ``centers`` (n, 2) of ``diameters`` (n,) (patch pixels) are
    faded into their surroundings: each ball's disc (and a pixel around it) becomes ``bg + a (patch - bg)``, ``bg`` the
    patch with the ball painted out (``cv2.inpaint``, Telea: what is around it, carried in), ``a`` drawn from
    ``FADE_CONTRAST`` for each ball, the disc's edge feathered over a pixel. The ball keeps its place, size and shading,
    at a fraction of its contrast: the held-out balls the heat misses most are dim or grey against what is around them
    (README Results)."""
    p = patch.shape[0]
    c, d = np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)
    inside = (c[:, 0] > -0.5 * d) & (c[:, 0] < p - 1 + 0.5 * d) & (c[:, 1] > -0.5 * d) & (c[:, 1] < p - 1 + 0.5 * d)
    if not inside.any():
        return patch
    y, x = np.mgrid[0:p, 0:p].astype(np.float32)
    keep = np.ones((p, p), np.float32)  # 1 = the patch as it is, a = the ball's contrast
    hole = np.zeros((p, p), np.uint8)
    for (cx, cy), di in zip(c[inside], d[inside]):
        r = 0.5 * float(di) + 1.0
        dist = np.hypot(x - np.float32(cx), y - np.float32(cy))
        w = np.clip(r + 0.5 - dist, 0.0, 1.0)  # 1 inside the disc, 0 a pixel beyond it
        a = np.float32(rng.uniform(*FADE_CONTRAST))
        keep = np.minimum(keep, 1.0 - w * (1.0 - a))
        hole[dist <= r + 1.0] = 255
    bg = cv2.inpaint(np.ascontiguousarray(patch), hole, 3, cv2.INPAINT_TELEA).astype(np.float32)
    out = bg + keep[..., None] * (patch.astype(np.float32) - bg)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


#: mining false alarms (:func:`mine_false_peaks`): a peak counts from this heat, at most this many per image (best
#: first), and none within this many diameters of a labelled ball (at least ``MINE_MIN_AWAY_PX``)
MINE_HEAT = 0.2
MINE_PER_IMAGE = 4
MINE_AWAY_DIAMETERS = 1.0
MINE_MIN_AWAY_PX = 8.0


def _off_the_balls(uv: np.ndarray, centers, diameters, min_away_px: float) -> np.ndarray:
    """Which of the points ``uv`` (n, 2) lie off every ball (``centers`` (m, 2), ``diameters`` (m,)): farther than
    ``MINE_AWAY_DIAMETERS`` of its diameter, and ``min_away_px``."""
    if not len(centers):
        return np.ones(len(uv), bool)
    c = np.asarray(centers, np.float64).reshape(-1, 2)
    away = np.maximum(MINE_AWAY_DIAMETERS * np.asarray(diameters, np.float64), min_away_px)
    return (np.hypot(uv[:, None, 0] - c[None, :, 0], uv[:, None, 1] - c[None, :, 1]) > away[None, :]).all(axis=1)


def mine_false_peaks(torch, net, items: list[LearnedItem]) -> tuple:
    """The network's false alarms in its training images: ``((item index, u, v), ...)`` of the heat's peaks
    (:func:`tracker.detection.learned.decode_heatmap`: local maxima, best first) of at least ``MINE_HEAT`` off every
    labelled ball (farther than ``MINE_AWAY_DIAMETERS`` of its diameter, and ``MINE_MIN_AWAY_PX``), the
    ``MINE_PER_IMAGE`` best of each image, at the items' own scale (the network's).
    Bootstrapping (Sung and Poggio's hard negatives): patches drawn near them teach the network what it mistakes for
    a ball in these images: arms, lamps, shelves, a shoe."""
    from tracker.detection.learned import decode_heatmap

    threshold_logit = math.log(MINE_HEAT / (1.0 - MINE_HEAT))
    out = []
    was_training = net.training
    net.eval()
    try:
        with torch.no_grad():
            for idx, it in enumerate(items):
                im = it.image
                h, w = im.shape[:2]
                ph, pw = -h % (2 * STRIDE), -w % (2 * STRIDE)
                if ph or pw:
                    im = np.pad(im, ((0, ph), (0, pw), (0, 0)), mode="edge")
                o = net(torch.from_numpy(np.ascontiguousarray(im))[None])[0].numpy()
                uv, _, _ = decode_heatmap(o, threshold_logit, o.shape[1] * o.shape[2], STRIDE)
                keep = (uv[:, 0] < w) & (uv[:, 1] < h) & _off_the_balls(uv, it.centers, it.diameters, MINE_MIN_AWAY_PX)
                out += [(idx, float(u), float(v)) for u, v in uv[keep][:MINE_PER_IMAGE]]
    finally:
        net.train(was_training)
    return tuple(out)


def false_alarms(stage: LearnedStage, images, labelled) -> int:
    """How many false alarms a fit would mine from ``stage``'s network in ``images`` (their ``LabelledImage`` s
    ``labelled``): candidates of heat at least ``MINE_HEAT``, the ``MINE_PER_IMAGE`` best of each image, off every
    labelled ball by :func:`mine_false_peaks`'s rule (at the network's scale). None: mining would find nothing there."""
    from harness.experiments.detector.scores import truth_of

    n = 0
    for image, li in zip(images, labelled):
        uv, _, _ = stage.candidates(image, None, k=MINE_PER_IMAGE, threshold=MINE_HEAT)
        c, d = truth_of(li)
        n += int(_off_the_balls(uv, c, d, MINE_MIN_AWAY_PX / stage.scale_of(*image.shape[:2])).sum())
    return n


#: the patches' photometric changes (the sampler chooses scale and flip)
_PATCH_AUGMENT = AugmentOptions(scale_range=(1.0, 1.0), p_flip=0.0)


def photometric(patch: np.ndarray, rng: np.random.Generator, opts: AugmentOptions = _PATCH_AUGMENT) -> np.ndarray:
    """The photometric part of :func:`harness.experiments.detector.augment.augment` for a small patch, with
    the same ranges, in fewer passes (per-channel gain and gamma as one lookup table; a lamp's tint as a
    smooth gradient): optics (motion blur or defocus), white balance x exposure, gamma, lamp tint, gain
    noise, JPEG."""
    out = optics(patch, rng, opts)
    gains = rng.uniform(*opts.wb_range, size=3) * rng.uniform(*opts.exposure_range)
    gamma = float(rng.uniform(*opts.gamma_range))
    v = np.arange(256, dtype=np.float64)[:, None] / 255.0
    lut = np.clip(np.clip(v * gains[None, :], 0.0, 1.0) ** gamma * 255.0, 0, 255)
    x = cv2.LUT(out, np.rint(lut).astype(np.uint8).reshape(1, 256, 3)).astype(np.float32)
    h, w = x.shape[:2]
    if rng.random() < opts.p_lamp:  # a smooth warm or cool tint rising across the patch
        ang = rng.uniform(0, 2 * math.pi)
        ramp = (np.cos(ang) * np.arange(w)[None, :] / w + np.sin(ang) * np.arange(h)[:, None] / h).astype(np.float32)
        ramp = (ramp - ramp.min()) / max(float(np.ptp(ramp)), 1e-6)
        tint = rng.uniform(0.0, 0.5) * np.array([1.0, rng.uniform(0.7, 1.0), rng.uniform(0.4, 1.0)], np.float32) * 255.0
        if rng.random() < 0.5:
            tint = tint[::-1]
        x += ramp[..., None] * tint
    x += rng.standard_normal(x.shape, dtype=np.float32) * np.float32(rng.uniform(0, opts.noise_dn))
    return jpeg(np.clip(np.rint(x), 0, 255).astype(np.uint8), rng, opts)


def _warp(image: np.ndarray, m: np.ndarray, p: int, a: float) -> np.ndarray:
    """``cv2.warpAffine(image, m, (p, p))`` with reflected borders, reading only the part of the image the patch
    covers (blurred first when shrinking by more than 0.8: warpAffine has no area averaging)."""
    h, w = image.shape[:2]
    side = p / a
    x0, y0 = -m[0, 2] / a, -m[1, 2] / a  # the image point that lands on patch pixel (0, 0)
    pad = 3 + (1.5 / a if a < 0.8 else 0)
    ix0, iy0 = max(int(math.floor(x0 - pad)), 0), max(int(math.floor(y0 - pad)), 0)
    ix1, iy1 = min(int(math.ceil(x0 + side + pad)) + 1, w), min(int(math.ceil(y0 + side + pad)) + 1, h)
    # a patch reaching past the image reflects the image's own border: warp from the whole image then
    touches = ix0 == 0 or iy0 == 0 or ix1 == w or iy1 == h or ix1 - ix0 < 2 or iy1 - iy0 < 2
    if touches:
        ix0 = iy0 = 0
        src = image
    else:
        src = image[iy0:iy1, ix0:ix1]
    if a < 0.8:
        src = cv2.GaussianBlur(src, (0, 0), 0.5 / a)
    mm = m.copy()
    mm[0, 2] += a * ix0
    mm[1, 2] += a * iy0
    return cv2.warpAffine(src, mm, (p, p), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def arch_of_state(state: dict) -> str:
    """The layout (one of ``ARCHS``) a state dict of :func:`build_net` belongs to (by its layers' names)."""
    return "s16" if any(k.startswith("q") for k in state) else "s8"


def build_net(torch, c4: int = 16, c8: int = 16, arch: str = DEFAULT_ARCH, c16: int = 32):
    """The heatmap network (module docstring) as a torch module taking (N, H, W, 3) uint8 RGB, H and W multiples of
    4 (the stage pads its input to whole cells; odd stride-8 and stride-16 grids are padded by the convolutions)."""
    nn = torch.nn
    F = torch.nn.functional
    if arch not in ARCHS:
        raise ValueError(f"unknown network layout {arch!r}; valid: {list(ARCHS)}")

    class HeatmapNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.a = nn.Conv2d(3, c4, 4, stride=4)
            self.b = nn.Conv2d(c4, c8, 3, stride=2, padding=1)
            self.c = nn.Conv2d(c8, c8, 3, padding=1)
            if arch == "s16":  # the stride-16 branch, joined to the stride-8 features before the dilated layer
                self.q1 = nn.Conv2d(c8, c16, 3, stride=2, padding=1)
                self.q2 = nn.Conv2d(c16, c16, 3, padding=1)
                self.q3 = nn.Conv2d(c16, c16, 3, padding=2, dilation=2)
                self.q4 = nn.Conv2d(c16, c8, 1)
            self.d = nn.Conv2d(c8, c8, 3, padding=2, dilation=2)
            if arch == "s8":
                self.e = nn.Conv2d(c8, c8, 3, padding=4, dilation=4)
            self.head = nn.Conv2d(c4 + c8, 4, 1)
            with torch.no_grad():
                self.head.bias[:] = torch.tensor([-4.0, 0.0, 0.0, 2.5])  # few balls; offsets 0; diameter ~12 px

        def forward(self, image):
            x = image.permute(0, 3, 1, 2).float() * (1.0 / 255.0) - 0.5
            a = F.relu(self.a(x))
            b = F.relu(self.b(a))
            b = F.relu(self.c(b))
            if arch == "s16":
                q = F.relu(self.q1(b))
                q = F.relu(self.q2(q)) + q
                q = F.relu(self.q3(q)) + q
                b = b + F.interpolate(self.q4(q), size=b.shape[2:], mode="nearest")
            b = F.relu(self.d(b)) + b
            if arch == "s8":
                b = F.relu(self.e(b)) + b
            u = F.interpolate(b, size=a.shape[2:], mode="nearest")
            return self.head(torch.cat([a, u], 1))

    return HeatmapNet()


def export_onnx(torch, net) -> bytes:
    """The network as ONNX bytes: input ``image`` (1, H, W, 3) uint8, output ``out`` (1, 4, H/4, W/4).

    The graph (:func:`deploy_onnx`) computes ``net``'s function rearranged for inference, from its weights (the
    initializers keep the state dict's names and values, so :func:`state_of_onnx` reads them back as they were)."""
    return deploy_onnx({k: v.detach().cpu().numpy() for k, v in net.state_dict().items()})


def deploy_onnx(state: dict) -> bytes:
    """The ONNX graph of a :func:`build_net` network from its weights (``state``: name -> array), arranged for
    inference; the same function as the torch module to float rounding (a test checks, both layouts):

    * ``x / 255 - 0.5`` is folded into the first convolution (weights / 255, bias - 0.5 sum(weights)): two
      passes over the frame fewer;
    * the 1x1 head over ``[a, upsample(b)]`` is split into ``head_a(a) + upsample(head_b(b))`` (a 1x1
      convolution commutes with nearest upsampling): the stride-8 features are upsampled as 4 maps instead
      of 16 and never concatenated;
    * the upsampling's size is one ``Shape`` of the stride-4 map (the traced graph had a dozen shape nodes,
      each a fixed cost that dominates a window search).

    The derived weights are constant subgraphs of the stored ones, which ONNX Runtime folds once when a
    session is made (``rt2 bench detector``'s ``learned`` rows time it; docs/detector.md)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    arch = arch_of_state(state)
    w = {k: np.asarray(v, np.float32) for k, v in state.items()}
    c4 = w["a.weight"].shape[0]
    nodes, inits = [], [numpy_helper.from_array(v, k) for k, v in w.items()]

    def const(name, value, dtype=np.float32):
        inits.append(numpy_helper.from_array(np.asarray(value, dtype), name))

    def node(op, ins, outs, **attrs):
        nodes.append(helper.make_node(op, ins, outs, **attrs))

    def conv_relu(x, name, out, k, stride=1, dilation=1, residual=None):
        pad = dilation * (k // 2)
        node("Conv", [x, f"{name}.weight", f"{name}.bias"], [f"{out}_conv"], kernel_shape=[k, k], strides=[stride, stride],
             pads=[pad] * 4, dilations=[dilation, dilation])
        node("Relu", [f"{out}_conv"], [out if residual is None else f"{out}_relu"])
        if residual is not None:
            node("Add", [f"{out}_relu", residual], [out])

    def upsample_to(x, like, out):  # nearest, torch's F.interpolate(size=...) as traced: asymmetric, floor
        node("Shape", [like], [f"{out}_size"], start=2)
        node("Resize", [x, "", "", f"{out}_size"], [out], mode="nearest", coordinate_transformation_mode="asymmetric",
             nearest_mode="floor", axes=[2, 3])

    # the first convolution with x / 255 - 0.5 folded in (constant subgraph)
    const("k_inv255", 1.0 / 255.0)
    const("k_half", 0.5)
    const("k_axes123", [1, 2, 3], np.int64)
    node("Mul", ["a.weight", "k_inv255"], ["a_w_folded"])
    node("ReduceSum", ["a.weight", "k_axes123"], ["a_w_sum"], keepdims=0)
    node("Mul", ["a_w_sum", "k_half"], ["a_w_half_sum"])
    node("Sub", ["a.bias", "a_w_half_sum"], ["a_b_folded"])
    node("Transpose", ["image"], ["image_nchw"], perm=[0, 3, 1, 2])  # uint8: a quarter of the bytes of float
    node("Cast", ["image_nchw"], ["x"], to=TensorProto.FLOAT)
    node("Conv", ["x", "a_w_folded", "a_b_folded"], ["a_conv"], kernel_shape=[4, 4], strides=[4, 4])
    node("Relu", ["a_conv"], ["fa"])
    conv_relu("fa", "b", "fb1", 3, stride=2)
    conv_relu("fb1", "c", "fb2", 3)
    fb = "fb2"
    if arch == "s16":
        conv_relu(fb, "q1", "fq1", 3, stride=2)
        conv_relu("fq1", "q2", "fq2", 3, residual="fq1")
        conv_relu("fq2", "q3", "fq3", 3, dilation=2, residual="fq2")
        node("Conv", ["fq3", "q4.weight", "q4.bias"], ["fq4"])
        upsample_to("fq4", fb, "fq_up")
        node("Add", [fb, "fq_up"], ["fb3"])
        fb = "fb3"
    conv_relu(fb, "d", "fb4", 3, dilation=2, residual=fb)
    fb = "fb4"
    if arch == "s8":
        conv_relu(fb, "e", "fb5", 3, dilation=4, residual=fb)
        fb = "fb5"
    # the head split over its two inputs (constant subgraph: the two halves of its weights)
    const("k_0", [0], np.int64)
    const("k_c4", [c4], np.int64)
    const("k_end", [1 << 30], np.int64)
    const("k_axis1", [1], np.int64)
    node("Slice", ["head.weight", "k_0", "k_c4", "k_axis1"], ["head_w_a"])
    node("Slice", ["head.weight", "k_c4", "k_end", "k_axis1"], ["head_w_b"])
    node("Conv", ["fa", "head_w_a", "head.bias"], ["head_a"])
    node("Conv", [fb, "head_w_b"], ["head_b"])
    upsample_to("head_b", "head_a", "head_b_up")
    node("Add", ["head_a", "head_b_up"], ["out"])
    graph = helper.make_graph(nodes, "rt2_heatmap", [helper.make_tensor_value_info("image", TensorProto.UINT8, [1, "h", "w", 3])],
                              [helper.make_tensor_value_info("out", TensorProto.FLOAT, [1, 4, "gh", "gw"])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=8, producer_name="rt2")
    onnx.checker.check_model(model)
    return model.SerializeToString()


def _loss(torch, out, heat, off, logd, mask):
    """CenterNet's penalty-reduced focal loss on the heat + L1 on offset and log diameter at the centres."""
    p = torch.sigmoid(out[:, 0]).clamp(1e-4, 1 - 1e-4)
    pos = mask
    neg_w = (1 - heat) ** 4
    n_pos = pos.sum().clamp(min=1.0)
    focal = -(pos * (1 - p) ** 2 * torch.log(p) + (1 - pos) * neg_w * p ** 2 * torch.log(1 - p)).sum() / n_pos
    l_off = (torch.abs(out[:, 1:3] - off).sum(1) * pos).sum() / n_pos
    l_d = (torch.abs(out[:, 3] - logd) * pos).sum() / n_pos
    return focal + l_off + 0.2 * l_d


def optimiser_step(opt, loss, avg: float | None, bar) -> float:
    """One step of ``opt`` on ``loss``; returns the running loss ``avg`` (None before the first step) updated, shown on
    the progress ``bar`` (or None)."""
    opt.zero_grad()
    loss.backward()
    opt.step()
    lv = float(loss.detach())
    avg = lv if avg is None else 0.98 * avg + 0.02 * lv
    if bar is not None:
        bar.update(1)
        bar.set_postfix(loss=f"{avg:.3f}")
    return avg


def fit_learned(items: list[LearnedItem], opts: LearnedTrainOptions, seed: int, *, init: bytes | None = None, state=None,
                log=print, progress: bool = False):
    """Fit the heatmap network; returns ``(state_dict, onnx bytes)``.

    items : training images at the network's scale (:func:`items_at_scale`, drawn balls, backgrounds without balls)
    state : a torch state dict to start from (fine-tuning), or None (from scratch)
    """
    import torch

    if not any(len(it.centers) for it in items):
        raise ValueError(f"no ball among the {len(items)} training images of the learned stage: nothing to learn")
    torch.manual_seed(seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # bit-for-bit repeatable sums
    try:
        rng = np.random.default_rng([seed, 35])
        net = build_net(torch, arch=opts.arch if state is None else arch_of_state(state))
        if state is not None:
            net.load_state_dict(state)
        # foreach: the multi-tensor update, the same arithmetic per element as the one-tensor loop (the same bytes; a
        # test compares them), in three quarters of its time (1.1 against 1.45 ms a step alone)
        opt = torch.optim.Adam(net.parameters(), lr=opts.lr, weight_decay=opts.weight_decay, foreach=True)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda i: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(i, opts.iterations) / opts.iterations)))
        average = moving_average(torch, net, opts.ema)
        net.train()
        bar = None
        if progress:
            from harness.common.progress import progress_bar

            bar = progress_bar(total=opts.iterations, desc="learned stage", unit="step", leave=False)
        avg = None
        # the next batch's patches are sampled on a second thread while the network trains on one (torch runs on a
        # single thread, for repeatable sums): the sampling took most of rt2 train's time. One batch at a time, each
        # begun when the one before is taken: the generator draws in the same order, so the same patches
        # Mining (opts.p_mined) takes place between two steps, after the next batch was sampled: the batches after it
        # draw near its false alarms (handed to each as an argument: the sampling thread never sees them change)
        mined = ()
        if opts.p_mined and opts.mine_first:
            mined = mine_false_peaks(torch, net, items)
            log(f"learned stage: before its first step, {len(mined)} false alarms mined in {len(items)} training images")
        with ThreadPoolExecutor(1, thread_name_prefix="rt2-patches") as pool:
            ahead = pool.submit(sample_patches, items, opts.batch, rng, opts, None, mined)
            for i in range(opts.iterations):
                imgs, heat, off, logd, mask = ahead.result()
                if opts.p_mined and i and i % opts.mine_every == 0 and i + 1 < opts.iterations:
                    mined = mine_false_peaks(torch, net, items)
                    log(f"learned stage: step {i}, {len(mined)} false alarms mined in {len(items)} training images")
                if i + 1 < opts.iterations:
                    ahead = pool.submit(sample_patches, items, opts.batch, rng, opts, None, mined)
                out = net(torch.from_numpy(imgs))
                loss = _loss(torch, out, torch.from_numpy(heat), torch.from_numpy(off), torch.from_numpy(logd), torch.from_numpy(mask))
                avg = optimiser_step(opt, loss, avg, bar)
                sched.step()
                if average is not None:
                    average.update_parameters(net)
        if bar is not None:
            bar.close()
        kept, note = averaged(net, average, opts.ema)
        log(f"learned stage: {opts.iterations} steps of {opts.batch} patches, final loss {avg:.3f}{note}")
        state = {k: v.detach().clone() for k, v in kept.state_dict().items()}
        return state, export_onnx(torch, kept)
    finally:
        torch.set_num_threads(threads)


def stage_candidates(stage: LearnedStage, images, k: int = 4, threshold: float | None = None):
    """Per image the stage's candidates ``(uv (n, 2), scores (n,), diameters (n,))`` (full frames)."""
    return [stage.candidates(im, None, k=k, threshold=threshold) for im in images]


class FitTask(NamedTuple):
    """One call of :func:`fit_learned`, picklable (a worker process runs it: :func:`run_fits`)."""

    items: list
    opts: LearnedTrainOptions
    seed: int
    state: dict | None


#: ``workers=None`` runs the cross-validation's fits on worker processes only when they add up to at least this many
#: optimiser steps: a worker's start (a fresh interpreter importing torch, ~4 s on the 2-core machine) costs shorter
#: ones more than it saves (a step takes ~25 ms there)
MIN_PARALLEL_STEPS = 1000
#: and on at most this many processes (a 3-fold cross-validation of two candidates has six fits)
MAX_AUTO_WORKERS = 6
#: a worker's memory besides its task's images: the interpreter with torch, numpy and OpenCV, and a fit's network
WORKER_BASE_BYTES = 500_000_000


def auto_workers(tasks, available_bytes: int | None = -1) -> int:
    """The processes ``workers=None`` runs ``tasks`` (:class:`FitTask` s) on: the CPUs this process may use, at most
    :data:`MAX_AUTO_WORKERS` and the number of fits, and as many as the memory available holds (each
    :data:`WORKER_BASE_BYTES` and twice its largest task's images: the pickled copy and the one it trains on);
    1 when the fits add up to fewer than :data:`MIN_PARALLEL_STEPS`.
    available_bytes : the memory available (default: Linux ``MemAvailable``; None: not known, no bound)"""
    import os

    if sum(t.opts.iterations for t in tasks) < MIN_PARALLEL_STEPS:
        return 1
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    n = max(1, min(cpus, MAX_AUTO_WORKERS, len(tasks)))
    if available_bytes == -1:
        from harness.common.memory import available_memory_bytes

        available_bytes = available_memory_bytes()
    if available_bytes is not None:
        per_worker = WORKER_BASE_BYTES + 2 * max(sum(int(it.image.nbytes) for it in t.items) for t in tasks)
        n = min(n, int(available_bytes // per_worker))
    return max(1, n)


def run_fit(task: FitTask):
    """``(state, onnx bytes)`` of one fit, silent (the cross-validation's fits log nothing of their own)."""
    return fit_learned(task.items, task.opts, task.seed, state=task.state, log=lambda message: None)


def run_fits(tasks: list[FitTask], workers: int = 1, *, keys=None):
    """Yield ``(key, (state, onnx bytes))`` for every fit as it finishes (``keys``: one per task, default its index).

    The studies' executor runs them (:class:`harness.common.executor.Executor`): ``workers`` 1 in this process, more
    on that many fresh worker processes (one thread each for torch and the BLAS, as here; they die with this process);
    SIGINT / SIGTERM stop them and raise :class:`harness.common.executor.SweepInterrupted`. A fit's network depends
    on its task alone (its seed, its data; torch on one thread), so the results are the same bytes whichever process
    ran them. Two fits on the 2-core machine take ~1.4x one fit's time (each also samples its patches on a second thread)."""
    from harness.common.executor import Executor, SweepOptions

    keys = list(range(len(tasks))) if keys is None else list(keys)
    if len(keys) != len(tasks):
        raise ValueError(f"run_fits: {len(keys)} keys for {len(tasks)} tasks")
    with Executor(SweepOptions(workers=max(1, min(int(workers), len(tasks))))) as ex:
        for j, result in ex.map(run_fit, tasks):
            yield keys[j], result


# -- the stage for rt2 train: shipped, fine-tuned or from scratch, chosen by cross-validation ---------------
#: heat thresholds searched for the operating point (probabilities)
THRESHOLD_GRID = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
#: the tracker's operating point of a trained stage (:attr:`tracker.detection.learned.LearnedStage.track_threshold`):
#: its cameras report candidates down to this heat (or the stage's threshold, when lower). Measured on the semi-real
#: caliscope flights (``rt2 eval framesets --scene caliscope --ball white``, cameras and balls held out of training):
#: at 0.2 the white stage gave positions in 98 % of frame sets, none wrong; at its single-image threshold 0.4, 46 %
TRACK_THRESHOLD = 0.2
#: network pixels of context around a window search (:attr:`tracker.detection.learned.LearnedStage.context_px`) in
#: the stages training writes: on the semi-real caliscope flights contexts of 0-24 px gave the same 3D recall within
#: noise (90-98 %), 8 px no wrong position on two seeds; a 64x64 window then costs the network 80x80 pixels, not 112x112
WINDOW_CONTEXT_PX = 8
#: the candidates of the choice: "none" is the 5x5 filter alone (no learned stage written)
CHOICES = ("none", "shipped", "fine-tuned", "scratch")
#: a stage whose cross-validated recall is below this is not written by rt2 train (unless --force)
MIN_CV_RECALL = 0.5
#: the median ball at the network's scale, pixels: training a stage from scratch shrinks frames towards it
TARGET_DIAMETER_PX = 16.0


@dataclass(frozen=True)
class StageChoice:
    """One candidate stage's cross-validated figures: ``name`` (one of ``CHOICES``), ``threshold`` (its best heat
    threshold on the pooled out-of-fold candidates; NaN for "none", the filter alone at its own thresholds) and the
    :class:`DetectorScores` there (``scores``, top-K)."""

    name: str
    threshold: float
    scores: object

    @property
    def gain(self) -> float:
        return float(np.nan_to_num(self.scores.recall)) - float(self.scores.outlier_rate)

    def line(self) -> str:
        s = self.scores
        at = f"threshold {self.threshold:g}" if np.isfinite(self.threshold) else "the filter's thresholds"
        return (f"{self.name}: recall {100 * np.nan_to_num(s.recall):.1f}%, outliers {100 * s.outlier_rate:.1f}%, "
                f"median {s.median_center_error_px:.2f} px at {at}" + (f" ({s.n_images} images)" if self.name == "none" else ""))


def max_side_for(labelled, base_max_side: int | None = None) -> int:
    """The longer frame side the stage shrinks frames to: the base's when fine-tuning, else so that the median
    labelled ball is about ``TARGET_DIAMETER_PX`` across (never enlarging, at least 256, a multiple of 32)."""
    if base_max_side is not None:
        return int(base_max_side)
    d = np.concatenate([np.minimum(li.boxes_xywh[:, 2], li.boxes_xywh[:, 3]) for li in labelled if li.n_balls] or [np.zeros(0)])
    side = max(max(li.width, li.height) for li in labelled)
    if len(d) == 0:
        return int(min(side, 640))
    target = side * min(1.0, TARGET_DIAMETER_PX / float(np.median(d)))
    return int(min(side, max(256, 32 * round(target / 32))))


def _scores_at(truth, cands, threshold: float, k: int, min_diameter_px: float):
    """The scores of each image's first ``k`` candidates at ``threshold`` or above (``cands``: per image ``(uv, scores)``,
    best first): ``k`` = 1 is a single image's detection (``rt2 eval detector``'s ``ours`` with a learned stage), more is
    top-K (what a tracker's camera reports)."""
    from harness.experiments.detector.scores import score_detections

    found = [uv[sc >= threshold][:k] for uv, sc in cands]
    return score_detections("ours" if k == 1 else "topk", truth[0], truth[1], found, min_diameter_px=min_diameter_px)


def _best_threshold(truth, cands, k: int, min_diameter_px: float, grid=THRESHOLD_GRID, prefer: float | None = None, margin: float = 0.0):
    """(threshold, scores) of the threshold of ``grid`` with the best recall - outliers (ties: ``prefer`` where it is
    among the best or within ``margin`` of it, else the higher threshold); (None, None) for an empty grid."""
    best, scored = (None, None, None), []
    for th in grid:
        s = _scores_at(truth, cands, th, k, min_diameter_px)
        g = float(np.nan_to_num(s.recall)) - s.outlier_rate
        scored.append((g, th, s))
        if best[0] is None or g >= best[0] - 1e-12:
            best = (g, th, s)
    if prefer is not None:
        tie = [x for x in scored if abs(x[1] - prefer) < 1e-9 and x[0] >= best[0] - margin - 1e-12]
        if tie:
            best = tie[0]
    return best[1], best[2]


def one_ball(truth) -> float:
    """What one labelled ball of ``truth`` ((centres, diameters) per image) is worth in recall - outliers: the margin a
    choice other than the base's own (its stage, its operating point) must beat it by. On few labels the folds decide a
    ball or two by chance (22 frames of caliscope camera 2, seed 1: a fine-tune at a single-image threshold of 0.3
    won by one ball and put 5 of 48 later first candidates off the ball, where the shipped stage at its own 0.5 put
    none; README Results, "Few labels of one camera"), while the base was chosen on many more."""
    n = sum(len(np.asarray(c).reshape(-1, 2)) for c in truth[0])
    return 1.0 / n if n else 0.0


def single_image_threshold(truth, cands, top_k_threshold: float, min_diameter_px: float, prefer: float | None = None, margin: float = 0.0):
    """``(threshold, scores, kept)``: the single image's operating point, each image's first candidate (``k`` = 1) at the
    threshold of ``THRESHOLD_GRID`` up to ``top_k_threshold`` with the best recall - outliers (ties: ``prefer`` where it
    is among the best or within ``margin`` of it, else the higher), or
    ``top_k_threshold`` itself (``kept`` True) where none there finds more balls than false ones.

    Lower than the top-K threshold where an image's first candidate is the ball more often than not below it (the
    false ones ranked after it: the rally's 22 frames, 0.4 -> 0.3). Never higher: a higher threshold silences
    what outranks the ball in the labelled cameras (a lamp), and with it the balls of every camera that has no such
    lamp (auto labels of caliscope cameras 0-2, two of them with a lamp in view, scored on camera 3). A threshold that
    finds nothing is no operating point either: the top-K one at least proposes the ball where it outranks the rest."""
    th, s = _best_threshold(truth, cands, 1, min_diameter_px, grid=[t for t in THRESHOLD_GRID if t <= top_k_threshold + 1e-12], prefer=prefer,
                           margin=margin)
    if th is not None and float(np.nan_to_num(s.recall)) > s.outlier_rate:
        return th, s, False
    return top_k_threshold, _scores_at(truth, cands, top_k_threshold, 1, min_diameter_px), True


def _alone_scores(alone, images, labelled, k: int, min_diameter_px: float):
    """Top-K scores of the 5x5 filter alone (no learned stage, no verifier) on the images each of ``alone``'s
    ``(model, indices)`` pairs holds out."""
    from harness.experiments.detector.scores import score_detections, truth_of
    from tracker import BallDetector, DetectorOptions

    found, centers, diameters = [], [], []
    for model, indices in alone:
        det = BallDetector(model, DetectorOptions(method="ours", max_candidates=k, learned=False, verify=False))
        for i in indices:
            found.append(det.detect(images[i]).uv_px)
            c, d = truth_of(labelled[i])
            centers.append(c)
            diameters.append(d)
    return score_detections("topk", centers, diameters, found, min_diameter_px=min_diameter_px)


def state_of_onnx(onnx_bytes: bytes) -> dict:
    """The torch state dict of a network exported by :func:`export_onnx` (its initializers by name; ``onnx`` package)."""
    import onnx
    import torch
    from onnx import numpy_helper

    graph = onnx.load_from_string(onnx_bytes).graph
    return {t.name: torch.from_numpy(numpy_helper.to_array(t).copy()) for t in graph.initializer if t.name.endswith((".weight", ".bias"))}


#: a fine-tune's contrast crops (:func:`contrast_crops`): the base's candidates considered (at least this heat, best first)
CONTRAST_MIN_HEAT = 0.1
CONTRAST_PER_IMAGE = 8
#: half the side of a crop, network pixels (a crop holds the false candidate and a labelled ball within this of it)
CONTRAST_HALF_PX = 80
#: the share of a fine-tune's patches drawn from its contrast crops (when it has any)
CONTRAST_SHARE = 0.7


def contrast_crops(items: list[LearnedItem], candidates, labelled, indices) -> list[LearnedItem]:
    """Crops of the training images where the base is wrong next to a ball: around each of the base's own candidates
    (``candidates[i]``: ``(uv, scores)`` in image pixels, best first) that is off every labelled ball of image ``i``
    (farther than half its diameter, and 6 px), a square of ``2 CONTRAST_HALF_PX`` network pixels (clipped to the
    image) that holds a labelled ball, with that ball's label; only of the images ``indices``. A fine-tune draws most
    of its patches from them (``CONTRAST_SHARE``): on the auto labels of caliscope cameras 0-2 it kept the fine-tune
    from raising a held-out camera's bright window above the ball (README Results, "Labels for free"); crops around
    random labelled balls, or around the false candidates with no ball in them, did not."""
    from harness.experiments.detector.scores import truth_of

    out = []
    for i in indices:
        it, (uv, sc) = items[i], candidates[i]
        c, d = truth_of(labelled[i])
        if not len(it.centers) or not len(uv):
            continue
        h0, w0 = labelled[i].height, labelled[i].width
        sx, sy = it.image.shape[1] / w0, it.image.shape[0] / h0
        for u in uv[sc >= CONTRAST_MIN_HEAT][:CONTRAST_PER_IMAGE]:
            if np.min(np.linalg.norm(c - u, axis=1) - np.maximum(d / 2, 6.0)) < 0:
                continue  # on a ball: not a false candidate
            x, y = (u[0] + 0.5) * sx - 0.5, (u[1] + 0.5) * sy - 0.5
            x0, y0 = int(max(0, x - CONTRAST_HALF_PX)), int(max(0, y - CONTRAST_HALF_PX))
            x1, y1 = int(min(it.image.shape[1], x + CONTRAST_HALF_PX)), int(min(it.image.shape[0], y + CONTRAST_HALF_PX))
            if x1 - x0 < 64 or y1 - y0 < 64:
                continue
            cc = it.centers - [x0, y0]
            inside = (cc[:, 0] >= 0) & (cc[:, 0] < x1 - x0) & (cc[:, 1] >= 0) & (cc[:, 1] < y1 - y0)
            if inside.any():
                out.append(LearnedItem(np.ascontiguousarray(it.image[y0:y1, x0:x1]), cc[inside], it.diameters[inside], 1.0, it.name + " (contrast)"))
    return out


def with_contrast(rest: list[LearnedItem], crops: list[LearnedItem]) -> list[LearnedItem]:
    """``rest`` and the contrast ``crops`` weighted so that the crops give ``CONTRAST_SHARE`` of the patches."""
    if not crops:
        return rest
    w = CONTRAST_SHARE / (1 - CONTRAST_SHARE) * sum(it.weight for it in rest) / len(crops)
    return rest + [replace(c, weight=w) for c in crops]


def kept_passes(name: str, base: LearnedStage | None) -> dict:
    """What a trained stage keeps of ``base``, in the cross-validation and in the file: the base's network as it is
    ("shipped") or fine-tuned ("fine-tuned", a little changed, at the base's scale) searches full frames as the base
    does (its coarse pass: side, threshold, candidates, its peaks' windows' context); every stage, one from scratch
    too, keeps the base's confirmation network, which looks at crops, not at the heat network (without it a stage from
    scratch gave back a camera's ceiling lamp the confirmation had learned to reject: README Results, "Few labels of one
    camera"); a stage from scratch searches in one pass."""
    if base is None:
        return {}
    if name not in ("shipped", "fine-tuned"):
        return {} if base.confirm is None else dict(confirm=base.confirm)
    return dict(coarse_side_px=base.coarse_side_px, coarse_threshold=base.coarse_threshold, coarse_candidates=base.coarse_candidates,
                coarse_context_px=base.coarse_context_px, confirm=base.confirm)


def operating_points(name: str, base: LearnedStage | None, single_threshold: float, topk_threshold: float | None = None) -> dict:
    """The written stage's single-image threshold, ``single_threshold`` (chosen on the cross-validation's scores):
    the confirmation network's where the stage keeps the base's (:func:`kept_passes`; its scores are the confirmed
    ones), the heat keeping the base's own threshold (the base's network, or a fine-tune of it) or, a stage from scratch,
    ``topk_threshold`` (the top-K threshold the cross-validation chose for it); else the heat's."""
    confirm = kept_passes(name, base).get("confirm")
    if confirm is None:
        return dict(threshold=single_threshold)
    heat = base.threshold if name in ("shipped", "fine-tuned") else topk_threshold
    if heat is None:
        raise ValueError(f"operating_points: a stage {name!r} that keeps the base's confirmation network needs its top-K threshold")
    return dict(threshold=heat, confirm=replace(confirm, threshold=single_threshold))


def continue_steps(finetune_steps: int, scratch_steps: int) -> int:
    """Steps of a fit continued with its false alarms mined (:func:`train_stage`'s ``resume``): a quarter of a stage
    from scratch's, at least a fine-tune's."""
    return max(1, finetune_steps, scratch_steps // 4)


def train_stage(labelled, images, folds, *, base: LearnedStage | None, seed: int, k: int = 4, min_diameter_px: float = 6.0,
                finetune_steps: int = 150, scratch_steps: int = 400, batch: int = 16, patch_px: int = 96, extra=(),
                alone=None, mined: float = 0.0, resume: dict | None = None, states: dict | None = None, workers: int | None = 1,
                log=print, progress: bool = False):
    """The learned stage ``rt2 train`` writes, chosen by cross-validation; returns ``(stage, info)``.

    labelled : ``LabelledImage`` list (the user's labels); images : their (H, W, 3) uint8 RGB images
    folds : lists of indices of ``labelled``, time-contiguous (:func:`harness.experiments.detector.train.cv_folds`)
    base : the shipped (or ``--from``) model's stage, or None
    extra : more ``(image, LabelledImage)`` pairs trained on in every fit, never scored (e.g. ball-free backgrounds)
    Over the folds the base stage as it
    is, the base fine-tuned (``finetune_steps``) and a stage from scratch (``scratch_steps``) are scored on the frames
    each fit did not see (top-K candidates, each at its best threshold); the best by recall - outliers is refitted on
    every image (the base itself when it wins) with that threshold. ``info``: the choices' figures, the chosen one.
    alone : ``(BallSegmentationModel, indices of labelled)`` pairs, the 5x5 filter as ``rt2 train`` writes it, fitted
    without those images (a kept base model, a cross-validation fold's model or the validation split's): the choice
    "none", the filter alone scored top-K on those images, which wins ties (returned stage None)
    mined : ``LearnedTrainOptions.p_mined`` of every fit (fine-tuned, from scratch), mined at a third and two thirds of its steps
    states : a dict this call fills with its fits' networks (torch state dicts): ``{"folds": {(name, fold): state},
        "final": (name, state) or None}``
    resume : the ``states`` of a first call on the same images and folds: then every fit continues the first call's
        network of its choice and fold for ``continue_steps(finetune_steps, scratch_steps)`` steps with ``mined`` of its
        patches near its own false alarms (mined before its first step and half way), instead of training anew
        (hard-negative bootstrapping at a fraction of a second training's cost)
    workers : processes the cross-validation's fits run on (:func:`run_fits`; 1 = this process; None =
        :func:`auto_workers`); the networks, and so everything chosen and written, do not depend on it
    """
    from harness.experiments.detector.scores import truth_of

    if not any(li.n_balls for li in labelled):
        raise ValueError(f"no ball boxes among the {len(labelled)} images: the learned stage has nothing to learn")
    max_side = max_side_for(labelled, None if base is None else base.max_side_px)
    pairs = list(zip(images, labelled))
    items = items_at_scale(pairs, max_side)
    extra_items = items_at_scale(list(extra), max_side, weight=0.5)
    base_state = None if base is None else state_of_onnx(base.onnx)
    names = (["shipped", "fine-tuned"] if base is not None else []) + ["scratch"]
    oof = {n: [None] * len(labelled) for n in names}

    def stage_of(onnx_bytes, name):
        return LearnedStage(onnx_bytes, max_side_px=max_side, threshold=0.5, diameter_range_px=LearnedTrainOptions().diameter_range_px,
                            context_px=WINDOW_CONTEXT_PX if base is None else base.context_px, **kept_passes(name, base))

    def candidates(stage, idx):
        for i in idx:
            uv, sc, _ = stage.candidates(pairs[i][0], None, k=4 * k, threshold=min(THRESHOLD_GRID))
            yield i, (uv, sc)

    def fit_items(name, idx):  # what a fit of `name` trains on: the frames `idx`, the backgrounds, a fine-tune's contrast crops
        rest = [items[i] for i in idx] + extra_items
        crops = contrast_crops(items, oof["shipped"], labelled, idx) if name == "fine-tuned" else []
        return with_contrast(rest, crops), len(crops)

    if base is not None:
        for i, c in candidates(base, range(len(labelled))):
            oof["shipped"][i] = c
    if states is not None:
        states.update(folds={}, final=None)
    n_continue = continue_steps(finetune_steps, scratch_steps)

    def fit_task(name, train_items, fit_seed, start=None) -> FitTask:
        """One fit of ``name``, as :func:`run_fit` takes it; ``start`` (with ``resume``): the first call's network, continued."""
        if start is not None:
            opts = LearnedTrainOptions(iterations=n_continue, batch=batch, patch_px=patch_px, max_side_px=max_side, lr=1e-3,
                                       p_mined=mined, mine_every=max(1, -(-n_continue // 2)), mine_first=True)
            return FitTask(train_items, opts, fit_seed + 7, start)
        steps, state = (finetune_steps, base_state) if name == "fine-tuned" else (scratch_steps, None)
        opts = LearnedTrainOptions(iterations=steps, batch=batch, patch_px=patch_px, max_side_px=max_side,
                                   lr=1e-3 if state is not None else 3e-3, p_mined=0.0 if resume is not None else mined,
                                   mine_every=max(1, -(-steps // 3)))
        return FitTask(train_items, opts, fit_seed, state)

    def fit(name, train_items, fit_seed, start=None):
        """The fit on every image, here, logged: ``(state, onnx)``."""
        t = fit_task(name, train_items, fit_seed, start)
        return fit_learned(t.items, t.opts, t.seed, state=t.state, log=log, progress=progress)

    # the folds' fits are independent: run on `workers` processes (the same networks whichever ran them)
    keys, tasks = [], []
    for f, fold in enumerate(folds):
        inside = set(fold)
        fitted = [i for i in range(len(items)) if i not in inside]
        if not any(len(it.centers) for it in [items[i] for i in fitted] + extra_items):
            continue
        for name in names[1 if base is not None else 0:]:
            start = None if resume is None else resume["folds"][(name, f)]  # the same folds: the first call fitted it
            keys.append((name, f))
            tasks.append(fit_task(name, fit_items(name, fitted)[0], seed + 101 * f, start))
    left = Counter(f for _, f in keys)  # fits of each fold still running
    workers = auto_workers(tasks) if workers is None else int(workers)
    order = list(range(len(tasks))) if workers <= 1 else sorted(range(len(tasks)), key=lambda j: -tasks[j].opts.iterations)  # longest first: the workers end together
    for j, (state_f, onnx_f) in run_fits([tasks[j] for j in order], workers, keys=order):
        name, f = keys[j]
        if states is not None:
            states["folds"][(name, f)] = state_f
        for i, c in candidates(stage_of(onnx_f, name), folds[f]):
            oof[name][i] = c
        left[f] -= 1
        if not left[f]:
            log(f"learned stage: fold {f + 1}/{len(folds)} done")
    scored = [i for i in range(len(labelled)) if all(oof[n][i] is not None for n in names)]
    truth = ([truth_of(labelled[i])[0] for i in scored], [truth_of(labelled[i])[1] for i in scored])
    # a tie, or a win by no more than one labelled ball, keeps the base's own stage and operating point (the labels say nothing better)
    own = None if base is None else (base.threshold if base.confirm is None else base.confirm.threshold)
    prefer = {"shipped": own, "fine-tuned": own}
    margin = one_ball(truth)
    choices = [StageChoice(name, *_best_threshold(truth, [oof[name][i] for i in scored], k, min_diameter_px, prefer=prefer.get(name), margin=margin))
               for name in names]
    if alone:
        choices.insert(0, StageChoice("none", float("nan"), _alone_scores(alone, images, labelled, k, min_diameter_px)))
        names = ["none", *names]
    for c in choices:
        log(f"learned stage, {len(folds)}-fold cross-validation on {len(scored)} images: {c.line()}")
    best = max(choices, key=lambda c: (round(c.gain, 9), -names.index(c.name)))
    shipped = next((c for c in choices if c.name == "shipped"), None)
    if shipped is not None and best is not shipped and shipped.gain >= best.gain - margin - 1e-12:
        log(f"learned stage: the shipped stage kept: {best.name} scores {100 * (best.gain - shipped.gain):.1f} points better, "
            f"not more than one labelled ball ({100 * margin:.1f} points) of {len(scored)} images, which the folds decide by chance")
        best = shipped
    single, single_threshold = None, float("nan")
    if best.name != "none":  # what a single image gets: its best candidate, at its own best threshold on the same out-of-fold candidates
        single_threshold, single, kept = single_image_threshold(truth, [oof[best.name][i] for i in scored], best.threshold, min_diameter_px,
                                                                prefer=prefer.get(best.name), margin=margin)
        why = "; at no threshold do they find more balls than false ones, so the top-K one is kept" if kept else ""
        log(f"learned stage, single images ({best.name}: each image's best candidate at threshold {single_threshold:g}), "
            f"{len(folds)}-fold cross-validation: recall {100 * np.nan_to_num(single.recall):.1f}%, outliers {100 * single.outlier_rate:.1f}%{why}")
    thresholds = (f"thresholds {single_threshold:g} (single images) and {best.threshold:g} (top-K; tracking "
                  f"{min(best.threshold, TRACK_THRESHOLD):g}) by cross-validation")
    if best.name == "none":
        stage = None
    elif best.name == "shipped":
        stage = base.__class__(base.onnx, stride=base.stride, max_side_px=base.max_side_px,
                               diameter_range_px=base.diameter_range_px, context_px=base.context_px,
                               **{**kept_passes(best.name, base), **operating_points(best.name, base, single_threshold, best.threshold)}, filter_refines=base.filter_refines,
                               track_threshold=min(best.threshold, TRACK_THRESHOLD),
                               size_ratio=base.size_ratio,  # the same network: its diameters' record holds
                               description=base.description + f"; {thresholds} on {len(labelled)} images")
    else:
        steps = finetune_steps if best.name == "fine-tuned" else scratch_steps
        train_items, n_crops = fit_items(best.name, range(len(items)))
        if best.name == "fine-tuned":
            log(f"learned stage: fine-tuned with {n_crops} contrast crops (the base's own false candidates next to a ball)")
        start = None
        if resume is not None:
            first = resume.get("final")
            if first is not None and first[0] == best.name:
                start = first[1]
            else:  # the first call wrote another choice: this one's network first, as the first call would have fitted it
                log(f"learned stage: {best.name} on every image first, then continued with its false alarms mined")
                start = fit(best.name, train_items, seed)[0]
        state_all, onnx_all = fit(best.name, train_items, seed, start)
        if states is not None:
            states["final"] = (best.name, state_all)
        # a fine-tune starts from the base's network and keeps its size record (not measured again: the labels' boxes
        # are hand-drawn); a network trained from scratch has none (the tracker's own size test)
        inherited = base.size_ratio if best.name == "fine-tuned" and base is not None else None
        stage = LearnedStage(onnx_all, max_side_px=max_side, diameter_range_px=LearnedTrainOptions().diameter_range_px,
                             context_px=WINDOW_CONTEXT_PX if base is None else base.context_px, track_threshold=min(best.threshold, TRACK_THRESHOLD),
                             **{**kept_passes(best.name, base), **operating_points(best.name, base, single_threshold, best.threshold)},
                             filter_refines=True if base is None else base.filter_refines, size_ratio=inherited,
                             description=f"{best.name} on {len(labelled)} images ({steps} steps, seed {seed}; {thresholds})"
                             + ("" if not mined else f"; continued {n_continue} steps with {100 * mined:g} % of its patches near its own false alarms, "
                                "mined before its first step and half way" if resume is not None else
                                f"; {100 * mined:g} % of its patches near its own false alarms, mined at a third and two thirds of its steps")
                             + ("" if inherited is None else f"; size ratio {inherited:g}, the base's"))
    info = dict(choices=choices, chosen=best, folds=len(folds), max_side_px=max_side, single=single, single_threshold=single_threshold, k=k)
    return stage, info

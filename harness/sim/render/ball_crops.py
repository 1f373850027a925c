"""Real white balls: cut from labelled video frames with a matte, and pasted into other images.

:func:`cut_ball_crops` reads a COCO data set of one video with one loosely boxed ball per frame (the
real rally frames of ``../shared/data/real/phone_rally``) and returns per ball a :class:`BallCrop`:

1. **patch**: the box grown by ``MARGIN_BOXES`` of its size on every side (at least ``MIN_MARGIN_PX``);
2. **background** behind the ball: the same patch of a time-neighbouring frame of the set (the camera
   is static) when that frame's ball is elsewhere and its ring around the box (the patch outside the
   box grown by ``BOX_GROW_PX``) matches this frame's within ``NEIGHBOUR_MATCH_DN`` grey levels (mean
   absolute difference); else OpenCV's Telea inpainting of the grown box from the ring;
3. **matte**: in linear-ish light (sRGB levels ** ``GAMMA``), the ball colour ``C`` is the mean of the
   ``CORE_FRACTION`` pixels inside the grown box that differ most from the background ``B``; each
   pixel's alpha is how far it lies from ``B`` towards ``C`` (``(I - B) . (C - B) / |C - B|^2``, clipped
   to [0, 1], lightly smoothed), kept only on the blob around the ball (the connected part of
   alpha > ``BLOB_ALPHA`` holding the most alpha, grown by ``SUPPORT_GROW_PX``, inside the grown box,
   softened): a player's hand or the table's line beside the ball is not part of it;
4. **foreground**: the ball's own colour, premultiplied by alpha (``alpha * F`` with ``I = alpha F + (1 - alpha) B``),
   tending to ``C`` where alpha is small (where ``F`` cannot be solved for);
5. **geometry** from the matte's moments: the centre is the alpha-weighted centroid (sub-pixel), the
   diameter ``4 sqrt(lambda_min)`` of the covariance of ``min(alpha / ALPHA_FULL, 1)`` (the shaded rim of a
   ball, darker than its middle, still counts as ball) (a disc of diameter d has variance d^2 / 16 along
   every axis, and a motion-blurred capsule keeps it across its path), the blur path
   ``sqrt(12 (lambda_max - lambda_min))`` pixels along the major axis (a segment of length L adds L^2 / 12).

:func:`paste_ball` puts a crop into another image at a given centre and diameter: the matte and the
premultiplied foreground resampled by ``cv2.warpAffine`` (bilinear: sub-pixel placement, scale, optional
turn; low-passed first when shrunk, so small balls do not alias), optional motion blur along a
path (the average of ``ceil(2 |path|)`` shifted copies, at least 2) and defocus (Gaussian), the
ball's brightness moved part of the way to the destination's local light (the white level of
:func:`harness.sim.render.composite.local_look`), a gain and colour jitter, composited in
linear-ish light, and the destination's own noise level added where the ball covers the background.

Pixel convention: rt2's ((0, 0) = centre of the top-left pixel); COCO boxes have their corner frame
(``x = u - w / 2 + 0.5``). Every random number comes from the ``rng`` passed in.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from checks.files import MAX_DATA_BYTES, read_text_capped
from checks.time_order import parse_range, time_key
from harness.sim.render.composite import local_look

__all__ = ["BallCrop", "PasteResult", "cut_ball_crops", "paste_ball"]

GAMMA = 2.2  #: sRGB levels -> linear-ish light
MARGIN_BOXES = 0.5  #: patch margin around the box, in box sizes (the larger side)
MIN_MARGIN_PX = 8
BOX_GROW_PX = 4.0  #: the loose box grown by this: the ball (and its blur) lies inside
NEIGHBOUR_MATCH_DN = 4.0  #: a neighbouring frame's ring must match within this mean |difference| (grey levels)
NEIGHBOURS = 3  #: frames on each side tried as background, nearest first
CORE_FRACTION = 0.15  #: of the grown box's pixels: the ball's colour is their mean
BLOB_ALPHA = 0.3
SUPPORT_GROW_PX = 3
ALPHA_FULL = 0.6  #: the size is measured on min(alpha / ALPHA_FULL, 1): a ball's shaded rim counts as ball
MIN_CONTRAST = 1e-3  #: |C - B|^2 in linear light (0..1) below which a pixel's alpha is 0
ANTIALIAS_SIGMA = 0.5  #: a crop shrunk by s < 1 is first blurred by this x sqrt(1 / s^2 - 1) source pixels
MIN_FIT = 0.9  #: ``BallCrop.fit`` of a clean ball (a suggestion: 71 of the 83 rally balls reach it; the others are in a hand, on a bat, half hidden)


@dataclass(frozen=True)
class BallCrop:
    """One real ball cut from a frame (module docstring).

    rgb : (h, w, 3) uint8 RGB patch around the ball (as recorded)
    alpha : (h, w) float32 matte in [0, 1], 0 on the patch's border
    foreground : (h, w, 3) float32 premultiplied ball colour ``alpha * F``, linear-ish light in [0, 1]
    center_px : (2,) ball centre (u, v) inside the patch, rt2 pixels (alpha-weighted centroid)
    diameter_px : ball diameter, pixels (across its blur path)
    blur_px : (2,) blur path (du, dv) over the exposure, pixels (its sign is arbitrary)
    white_dn : (3,) the source frame's white level around the ball, RGB levels (``local_look``)
    contrast_dn : mean |C - B| between the ball's colour and its background, sRGB levels (low = a faint matte)
    fit : solidity of the matte's core (alpha > 0.5): its area / its convex hull's (a ball, round or smeared
        into a capsule, is convex: ~1; a ball in a hand or behind a bat's edge scores lower: filter with ``MIN_FIT``)
    source : the image's file name; image_id : its COCO id; frame : its position in the set's time order
    origin_px : (2,) the patch's top-left pixel in the source image (u, v)
    """

    rgb: np.ndarray
    alpha: np.ndarray
    foreground: np.ndarray
    center_px: np.ndarray
    diameter_px: float
    blur_px: np.ndarray
    white_dn: np.ndarray
    contrast_dn: float
    fit: float
    source: str
    image_id: int
    frame: int
    origin_px: tuple


@dataclass(frozen=True)
class PasteResult:
    """:func:`paste_ball`'s result.

    image : (H, W, 3) uint8 RGB, a new image with the ball
    center_px : (2,) the ball's centre (u, v), rt2 pixels; box_xywh : (4,) its COCO box [x, y, w, h]
    alpha : (H, W) float32 the pasted matte (0 where the ball is not)
    """

    image: np.ndarray
    center_px: np.ndarray
    box_xywh: np.ndarray
    alpha: np.ndarray


# -- cutting ---------------------------------------------------------------------------------------


def cut_ball_crops(coco, frames=None) -> list[BallCrop]:
    """The balls of a COCO data set of one video as :class:`BallCrop`, in the set's time order.

    coco : ``annotations.json`` or the folder holding it (image ``file_name`` relative to it)
    frames : None (all), a ``"START:STOP"`` range of the time order (file names, :func:`checks.time_order.time_key`),
        or a collection of COCO image ids
    Raises ValueError / FileNotFoundError naming the file and field of bad input.
    """
    path = Path(coco)
    path = path / "annotations.json" if path.is_dir() else path
    if not path.is_file():
        raise FileNotFoundError(f"ball crops: no COCO file {str(path)!r}")
    images, boxes = _read_coco(path)
    order = sorted(images, key=lambda i: time_key(images[i]))
    if frames is None:
        chosen = order
    elif isinstance(frames, str):
        start, stop = parse_range(frames, "frames")
        chosen = order[start:stop]
    else:
        ids = {int(i) for i in frames}
        unknown = sorted(ids - set(images))
        if unknown:
            raise ValueError(f"{path}: no image with id {unknown[:5]} (ids {min(images)}..{max(images)})")
        chosen = [i for i in order if i in ids]
    if not chosen:
        raise ValueError(f"{path}: frames {frames!r} select no image of the {len(order)}")
    cache: dict[int, np.ndarray] = {}

    def load(i: int) -> np.ndarray:
        if i not in cache:
            p = path.parent / images[i]
            bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"{path}: image {images[i]!r} (id {i}) cannot be read")
            cache[i] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            for old in [k for k in cache if k not in near(i)]:
                del cache[old]
        return cache[i]

    def near(i: int) -> set:
        k = chosen.index(i)
        return set(chosen[max(k - NEIGHBOURS - 1, 0):k + NEIGHBOURS + 2])

    crops = []
    for k, i in enumerate(chosen):
        neighbours = [chosen[j] for d in range(1, NEIGHBOURS + 1) for j in (k - d, k + d) if 0 <= j < len(chosen)]
        for box in boxes.get(i, []):
            crops.append(_cut_one(load, i, box, neighbours, boxes, images[i], order.index(i)))
    return crops


def _read_coco(path: Path) -> tuple[dict, dict]:
    """({image id: file name}, {image id: [(4,) box]}) of a COCO file, checked."""
    try:
        data = json.loads(read_text_capped(path, MAX_DATA_BYTES, "COCO file"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict) or not isinstance(data.get("images"), list) or not isinstance(data.get("annotations"), list):
        raise ValueError(f"{path}: a COCO file needs 'images' and 'annotations' lists")
    images, boxes = {}, {}
    for k, im in enumerate(data["images"]):
        if not isinstance(im, dict) or not isinstance(im.get("id"), int) or not isinstance(im.get("file_name"), str):
            raise ValueError(f"{path}: images[{k}] needs an integer 'id' and a 'file_name', got {str(im)[:80]}")
        images[im["id"]] = im["file_name"]
    for k, a in enumerate(data["annotations"]):
        b = a.get("bbox") if isinstance(a, dict) else None
        if not isinstance(b, list) or len(b) != 4 or not all(isinstance(v, (int, float)) for v in b) or b[2] <= 0 or b[3] <= 0:
            raise ValueError(f"{path}: annotations[{k}].bbox must be [x, y, w, h] with w, h > 0, got {b!r}")
        if a.get("image_id") not in images:
            raise ValueError(f"{path}: annotations[{k}].image_id {a.get('image_id')!r} is no image's id")
        boxes.setdefault(a["image_id"], []).append(np.array(b, float))
    if not images:
        raise ValueError(f"{path}: no images")
    return images, boxes


def _to_linear(rgb) -> np.ndarray:
    return (np.asarray(rgb, np.float32) / 255.0) ** GAMMA


def _to_levels(lin) -> np.ndarray:
    return 255.0 * np.clip(lin, 0.0, 1.0) ** (1.0 / GAMMA)


def _cut_one(load, i: int, box, neighbours, boxes, name: str, frame: int) -> BallCrop:
    image = load(i)
    H, W = image.shape[:2]
    x, y, bw, bh = box
    margin = max(MIN_MARGIN_PX, MARGIN_BOXES * max(bw, bh)) + BOX_GROW_PX
    x0, y0 = max(int(math.floor(x - margin)), 0), max(int(math.floor(y - margin)), 0)
    x1, y1 = min(int(math.ceil(x + bw + margin)), W), min(int(math.ceil(y + bh + margin)), H)
    patch = image[y0:y1, x0:x1]
    grown = np.zeros(patch.shape[:2], np.uint8)  # the box grown by BOX_GROW_PX, patch pixels
    gx0, gy0 = int(math.floor(x - BOX_GROW_PX)) - x0, int(math.floor(y - BOX_GROW_PX)) - y0
    gx1, gy1 = int(math.ceil(x + bw + BOX_GROW_PX)) - x0, int(math.ceil(y + bh + BOX_GROW_PX)) - y0
    grown[max(gy0, 0):gy1, max(gx0, 0):gx1] = 1
    background = _background(load, patch, grown, (x0, y0, x1, y1), neighbours, boxes)
    I, B = _to_linear(patch), _to_linear(background)
    D = I - B
    lum = D.mean(axis=2) * grown
    n_core = max(int(CORE_FRACTION * grown.sum()), 4)
    core = np.argsort(lum, axis=None)[-n_core:]
    C = I.reshape(-1, 3)[core].mean(axis=0)
    CB = C[None, None, :] - B
    den = (CB * CB).sum(axis=2)
    alpha = np.where(den > MIN_CONTRAST, (D * CB).sum(axis=2) / np.maximum(den, MIN_CONTRAST), 0.0)
    alpha = cv2.GaussianBlur(np.clip(alpha, 0, 1).astype(np.float32), (0, 0), 0.6) * grown
    alpha *= _support(alpha)
    alpha[[0, -1], :] = 0
    alpha[:, [0, -1]] = 0
    w_fit = np.clip(alpha / 0.4, 0, 1)[..., None]
    F = np.clip((I - (1 - alpha[..., None]) * B) / np.maximum(alpha[..., None], 1e-3), 0, 1)
    F = w_fit * F + (1 - w_fit) * C[None, None, :]
    centre = _moments(alpha)[0]
    _, diameter, blur = _moments(np.clip(alpha / ALPHA_FULL, 0.0, 1.0))
    look = local_look(image, (x0 + centre[0], y0 + centre[1]), diameter, frame_blur_px=0.0)
    contrast = float(np.abs(_to_levels(C)[None, :] - background[grown > 0].astype(np.float32)).mean())
    return BallCrop(rgb=patch.copy(), alpha=alpha.astype(np.float32), foreground=(alpha[..., None] * F).astype(np.float32),
                    center_px=centre, diameter_px=diameter, blur_px=blur, white_dn=look.white_dn, contrast_dn=contrast,
                    fit=_solidity(alpha),
                    source=name, image_id=int(i), frame=int(frame), origin_px=(x0, y0))


def _background(load, patch, grown, window, neighbours, boxes) -> np.ndarray:
    """(h, w, 3) uint8 estimate of the patch without its ball: a neighbouring frame's same patch whose ring
    matches and whose ball is elsewhere, else the grown box inpainted from the ring."""
    x0, y0, x1, y1 = window
    ring = grown == 0
    grey = cv2.cvtColor(patch, cv2.COLOR_RGB2GRAY).astype(np.float32)
    best, best_err = None, NEIGHBOUR_MATCH_DN
    for j in neighbours:
        if any(_overlaps(b, window) for b in boxes.get(j, [])):
            continue
        cand = load(j)[y0:y1, x0:x1]
        if cand.shape != patch.shape:
            continue
        err = float(np.abs(cv2.cvtColor(cand, cv2.COLOR_RGB2GRAY).astype(np.float32) - grey)[ring].mean())
        if err < best_err:
            best, best_err = cand, err
    if best is not None:
        return best.copy()
    return cv2.inpaint(patch, grown * 255, 5, cv2.INPAINT_TELEA)


def _overlaps(box, window) -> bool:
    x, y, w, h = box
    x0, y0, x1, y1 = window
    g = BOX_GROW_PX
    return x - g < x1 and x + w + g > x0 and y - g < y1 and y + h + g > y0


def _support(alpha: np.ndarray) -> np.ndarray:
    """(h, w) float32 soft mask of the blob around the ball (module docstring, step 3)."""
    n, labels = cv2.connectedComponents((alpha > BLOB_ALPHA).astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.ones_like(alpha)
    mass = np.bincount(labels.ravel(), weights=alpha.ravel(), minlength=n)
    mass[0] = 0
    blob = (labels == int(np.argmax(mass))).astype(np.uint8)
    k = 2 * SUPPORT_GROW_PX + 1
    blob = cv2.dilate(blob, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    return cv2.GaussianBlur(blob.astype(np.float32), (0, 0), 1.0)


def _moments(alpha: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre (2,) u, v; diameter px; blur path (2,) px) of a matte (module docstring, step 5)."""
    h, w = alpha.shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    m = float(alpha.sum())
    if m <= 0:
        return np.array([(w - 1) / 2, (h - 1) / 2]), 0.0, np.zeros(2)
    cu, cv = float((alpha * uu).sum() / m), float((alpha * vv).sum() / m)
    du, dv = uu - cu, vv - cv
    cov = np.array([[(alpha * du * du).sum(), (alpha * du * dv).sum()], [(alpha * du * dv).sum(), (alpha * dv * dv).sum()]]) / m
    lam, vec = np.linalg.eigh(cov)
    lam = np.maximum(lam, 0.0)
    length = math.sqrt(12.0 * max(lam[1] - lam[0], 0.0))
    return np.array([cu, cv]), 4.0 * math.sqrt(lam[0]), length * vec[:, 1]


def _solidity(alpha: np.ndarray) -> float:
    """``BallCrop.fit``: area of the matte's core (alpha > 0.5) / area of its convex hull."""
    core = (alpha > 0.5).astype(np.uint8)
    pts = cv2.findNonZero(core)
    if pts is None or len(pts) < 3:
        return 0.0
    hull = cv2.convexHull(pts)
    area = float(cv2.contourArea(hull)) + 0.5 * float(cv2.arcLength(hull, True)) + 1.0  # pixel centres -> pixel area
    return min(float(core.sum()) / area, 1.0)


# -- pasting ---------------------------------------------------------------------------------------


def paste_ball(image: np.ndarray, crop: BallCrop, center_px, diameter_px: float, rng: np.random.Generator, *,
               blur_px=(0.0, 0.0), defocus_px: float = 0.0, gain: float | None = None, colour_gain=None,
               light_match: float | None = None, noise: bool = True, angle_deg: float = 0.0) -> PasteResult:  # fmt: skip
    """``image`` (H, W, 3) uint8 RGB with ``crop``'s ball pasted at ``center_px`` (u, v, rt2 pixels), scaled to
    ``diameter_px`` (module docstring).

    blur_px : (du, dv) extra motion-blur path over the exposure, pixels (added to the crop's own smear)
    defocus_px : Gaussian sigma of the ball layer, pixels
    gain : brightness factor (None: uniform 0.85..1.15 from ``rng``); colour_gain : (3,) per-channel factor
        (None: each uniform 0.95..1.05); light_match : in [0, 1], how far the ball's white level moves to the
        destination's (None: uniform 0..0.5); noise : add the destination's noise level under the ball
    Returns a :class:`PasteResult` (the centre is ``center_px``; the box spans the scaled crop's smear and the extra blur).
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"paste_ball: image must be an (H, W, 3) uint8 RGB array, got {img.dtype} {img.shape}")
    cu, cv = (float(c) for c in np.asarray(center_px, float).reshape(2))
    if not (np.isfinite(diameter_px) and diameter_px > 0 and crop.diameter_px > 0):
        raise ValueError(f"paste_ball: diameter_px must be > 0 (crop {crop.source!r}: {crop.diameter_px}), got {diameter_px!r}")
    bu, bv = (float(b) for b in np.asarray(blur_px, float).reshape(2))
    gain = float(rng.uniform(0.85, 1.15)) if gain is None else float(gain)
    colour_gain = rng.uniform(0.95, 1.05, 3) if colour_gain is None else np.asarray(colour_gain, float).reshape(3)
    light_match = float(rng.uniform(0.0, 0.5)) if light_match is None else float(light_match)
    H, W = img.shape[:2]
    s = float(diameter_px) / crop.diameter_px
    ch, cw = crop.alpha.shape
    a = math.radians(float(angle_deg))
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    corners = np.array([[0, 0], [cw - 1, 0], [0, ch - 1], [cw - 1, ch - 1]], float) - crop.center_px
    reach = np.abs(s * corners @ rot.T).max(axis=0)  # the turned, scaled patch around the centre
    half_u = reach[0] + abs(bu) / 2 + 3 * defocus_px + 2
    half_v = reach[1] + abs(bv) / 2 + 3 * defocus_px + 2
    x0, x1 = max(int(math.floor(cu - half_u)), 0), min(int(math.ceil(cu + half_u)) + 1, W)
    y0, y1 = max(int(math.floor(cv - half_v)), 0), min(int(math.ceil(cv + half_v)) + 1, H)
    out = img.copy()
    full_alpha = np.zeros((H, W), np.float32)
    r = diameter_px / 2
    ext = s * np.abs(rot @ crop.blur_px) / 2 + np.abs([bu, bv]) / 2 + r
    box = np.array([cu - ext[0] + 0.5, cv - ext[1] + 0.5, 2 * ext[0], 2 * ext[1]])
    if x1 <= x0 or y1 <= y0:
        return PasteResult(out, np.array([cu, cv]), box, full_alpha)
    layers = np.dstack([crop.foreground, crop.alpha])  # (h, w, 4): premultiplied colour and alpha
    if s < 1.0:  # shrinking: low-pass first (warpAffine samples bilinearly; it has no area mode), or small balls alias
        layers = cv2.GaussianBlur(layers, (0, 0), ANTIALIAS_SIGMA * math.sqrt(1.0 / (s * s) - 1.0), borderType=cv2.BORDER_CONSTANT)
    n = max(2, int(math.ceil(2 * math.hypot(bu, bv)))) if (bu or bv) else 1
    acc = np.zeros((y1 - y0, x1 - x0, 4), np.float32)
    for t in (np.linspace(-0.5, 0.5, n) if n > 1 else [0.0]):
        tu, tv = cu + t * bu - x0, cv + t * bv - y0  # crop centre -> this window's point
        A = s * rot
        M = np.hstack([A, (np.array([tu, tv]) - A @ crop.center_px)[:, None]]).astype(np.float32)
        acc += cv2.warpAffine(layers, M, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    acc /= n
    if defocus_px > 0.05:
        acc = cv2.GaussianBlur(acc, (0, 0), float(defocus_px))
    premult, alpha = acc[..., :3], np.clip(acc[..., 3], 0.0, 1.0)
    look = local_look(img, (cu, cv), diameter_px, frame_blur_px=0.0)
    level = (np.asarray(look.white_dn, float) / np.maximum(crop.white_dn, 1.0)) ** (light_match * GAMMA)
    premult = premult * (gain ** GAMMA) * (colour_gain ** GAMMA) * level
    bg = _to_linear(img[y0:y1, x0:x1])
    comp = _to_levels(bg * (1.0 - alpha[..., None]) + premult)
    if noise and look.noise_dn > 0:
        comp += rng.standard_normal(comp.shape).astype(np.float32) * (look.noise_dn * alpha[..., None])
    out[y0:y1, x0:x1] = np.clip(np.rint(comp), 0, 255).astype(np.uint8)
    full_alpha[y0:y1, x0:x1] = alpha
    return PasteResult(out, np.array([cu, cv]), box, full_alpha)

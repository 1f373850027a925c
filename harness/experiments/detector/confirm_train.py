"""Training the learned stage's confirmation network (:mod:`tracker.detection.confirm`).

Examples come from the stage's own candidates on its training frames: every candidate of a whole frame (its
heat's best ``EXAMPLE_CANDIDATES`` at ``GATE`` or above: more than it looks at when it runs, for more of the
stage's false alarms) is a crop at its predicted diameter, a ball when it lies within
half the ball's diameter (and 3 px) of a labelled ball, not one beyond a diameter (and 6 px), left out between; and
``JITTER`` more crops of every labelled ball, its centre moved up to a fifth of its diameter and its size up to
25 % (the stage's centres and diameters are off by that much). The network sees the crop alone (the heat is the
other look: the two are combined at run time, :mod:`tracker.detection.confirm`). A batch is half balls, half not, each crop flipped at random and changed as the stage's patches
are (:func:`harness.experiments.detector.learned_train.photometric`: blur, white balance, exposure, gamma, lamp
tint, noise, JPEG). Torch trains it (one thread; the same seed gives the same network); the exported graph takes
uint8 crops and gives probabilities, and runs without torch. With a second context (``rt2 train-shipped
--confirm-context 6 2``, the white file) every example is cut out at both scales, a network is fitted on each
scale's crops as a single one would be, and the graph averages their probabilities (:func:`confirm_pair`).
"""

from __future__ import annotations

import math

import numpy as np

from tracker.detection.confirm import ConfirmNet, stacked_crop

__all__ = ["CANDIDATES", "CONTEXT", "GATE", "JITTER", "build_confirm_net", "confirm_examples", "confirm_net", "confirm_pair", "export_confirm", "fit_confirm"]

#: the heat's candidates of a frame looked at (at most), and the heat they need
CANDIDATES = 6
GATE = 0.05
#: the heat's candidates of a training frame made examples
EXAMPLE_CANDIDATES = 16
#: the share of the training frames searched again with light sources drawn in (:func:`with_lights`): the stage's
#: candidates on them are lamps, the white ball's detector's false alarms on held-out cameras (README Results)
LIT = 0.5
#: the share of the training frames searched again with look-alikes drawn in (:func:`with_lookalikes`; 0: none, as
#: the files of 2026-12-02 were made)
LOOKALIKES = 0.0
#: a look-alike's size (its longer side, pixels, log-uniform) and how many a frame gets
LOOKALIKE_SIDE_PX = (8.0, 160.0)
LOOKALIKES_PER_FRAME = 3
#: the share of the training frames searched again with bare skin and coloured glints drawn in (:func:`with_skin`; 0:
#: none, as the files of 2026-12-02 were made)
SKIN = 0.0
#: jittered crops of each labelled ball (more balls than the candidates alone give)
JITTER = 3
#: a crop: its side in candidate diameters (at least MIN_SIDE_PX), resampled to CROP_PX
CONTEXT = 6.0
CROP_PX = 48
MIN_SIDE_PX = 48.0


def with_lights(image: np.ndarray, centers, diameters, rng, n: int = 3) -> np.ndarray:
    """``image`` with ``n`` light sources drawn in away from its balls
    (:func:`harness.experiments.detector.learned_train.draw_light`, each in a random square of a third to a half of
    the frame's shorter side)."""
    from harness.experiments.detector.learned_train import draw_light

    out = image.copy()
    h, w = out.shape[:2]
    c, d = np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)
    for _ in range(n):
        side = int(min(h, w) * rng.uniform(1 / 3, 1 / 2))
        x0, y0 = int(rng.integers(0, w - side + 1)), int(rng.integers(0, h - side + 1))
        out[y0:y0 + side, x0:x0 + side] = draw_light(np.ascontiguousarray(out[y0:y0 + side, x0:x0 + side]), rng, c - [x0, y0], d)
    return out


def _place(rng, h: int, w: int, reach: float, c, d, tries: int, edge_share: float = 0.4, span: float | None = None):
    """A centre for something of ``reach`` pixels around it that covers none of the balls at ``c`` (n, 2) of ``d`` (n,)
    (``edge_share`` of the time across the frame's edge, its centre up to 0.3 ``span`` (default ``reach``) either
    side of it), or None where ``tries`` find none."""
    for _ in range(tries):
        if rng.random() < edge_share:
            edge = int(rng.integers(4))
            t = rng.uniform(0.0, 1.0)
            off = rng.uniform(-0.3, 0.3) * (reach if span is None else span)
            cx, cy = [(off, t * (h - 1)), (w - 1 - off, t * (h - 1)), (t * (w - 1), off), (t * (w - 1), h - 1 - off)][edge]
        else:
            cx, cy = rng.uniform(0, w - 1), rng.uniform(0, h - 1)
        if (np.hypot(c[:, 0] - cx, c[:, 1] - cy) > reach + 0.5 * d + 2.0).all():
            return cx, cy
    return None


def _level(image: np.ndarray, cx: float, cy: float, r: float) -> float:
    """The mean linear brightness (0-1) of ``image`` within ``r`` pixels of ``(cx, cy)`` (a thing there is lit as its
    surroundings are)."""
    h, w = image.shape[:2]
    x0, x1, y0, y1 = (int(np.clip(v, 0, m)) for v, m in ((cx - r, w), (cx + r + 1, w), (cy - r, h), (cy + r + 1, h)))
    around = image[y0:y1, x0:x1] if x1 > x0 and y1 > y0 else image
    return float(np.mean((around.astype(np.float32) / 255.0) ** 2.2))


def draw_lookalike(image: np.ndarray, rng: np.random.Generator, centers, diameters, reflectance, tries: int = 5) -> np.ndarray:
    """``image`` (h, w, 3) uint8 RGB with one thing of the ball's colour that is not a ball drawn in where it covers
    none of the balls at ``centers`` (n, 2) of ``diameters`` (n,) (a copy; the image itself where no place is found in
    ``tries``): a rotated rectangle or an irregular polygon, flat-lit (a gradient across it, not a sphere's shading),
    with corners, of a colour of ``reflectance`` ``((lo R, G, B), (hi R, G, B))`` linear, textured, its edge a little
    soft, often cut by the frame's edge: a box, a cloth, a cap or a sign of the ball's colour, which a detector
    that knows the colour and not the shape takes for the ball (the orange file's false alarms on held-out cameras)."""
    import cv2

    h, w = image.shape[:2]
    side = math.exp(rng.uniform(*np.log(LOOKALIKE_SIDE_PX)))
    c, d = np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)
    at = _place(rng, h, w, 0.75 * side, c, d, tries, span=side)
    if at is None:
        return image
    cx, cy = at
    ang = rng.uniform(0.0, math.pi)
    if rng.random() < 0.5:  # a rectangle
        a, b = 0.5 * side, 0.5 * side * rng.uniform(0.35, 1.0)
        pts = np.array([(-a, -b), (a, -b), (a, b), (-a, b)])
    else:  # an irregular polygon of 5-9 corners
        k = int(rng.integers(5, 10))
        th = np.sort(rng.uniform(0.0, 2 * math.pi, k))
        rad = 0.5 * side * rng.uniform(0.45, 1.0, k)
        pts = np.stack([rad * np.cos(th), rad * np.sin(th)], 1)
    rot = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
    pts = pts @ rot.T + (cx, cy)
    mask = np.zeros((h, w), np.float32)
    cv2.fillPoly(mask, [np.rint(pts * 4).astype(np.int32)], 1.0, lineType=cv2.LINE_AA, shift=2)
    sigma = rng.uniform(0.3, 1.5)
    mask = cv2.GaussianBlur(mask, (0, 0), sigma)
    lo, hi = (np.asarray(x, np.float64) for x in reflectance)
    refl = rng.uniform(lo, hi)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    g = rng.normal(size=2)
    g /= max(np.hypot(*g), 1e-9)
    ramp = ((x - cx) * g[0] + (y - cy) * g[1]) / max(side, 1.0)  # -0.5..0.5 across it
    # as bright as the surroundings allow: a thing in a dark room is dark
    level = _level(image, cx, cy, side)
    light = rng.uniform(0.4, 1.0) * min(1.0, 0.1 + 4.0 * level) * (1.0 + rng.uniform(0.0, 0.6) * ramp)
    texture = 1.0 + rng.uniform(0.0, 0.08) * cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), rng.uniform(0.5, 3.0)) * 3.0
    lin = np.clip(light[..., None] * texture[..., None] * refl[None, None, :].astype(np.float32), 0.0, 1.0)
    colour = 255.0 * lin ** (1 / 2.2)
    out = image.astype(np.float32) * (1.0 - mask[..., None]) + colour * mask[..., None]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


#: skin drawn in (:func:`draw_skin`): the limb's or face's width (pixels, log-uniform), its length in widths, and
#: how many a frame gets with its coloured glints (:func:`draw_glint`)
SKIN_WIDTH_PX = (14.0, 130.0)
SKIN_LENGTH = (1.0, 3.5)
SKIN_PER_FRAME = 2
GLINTS_PER_FRAME = 2
#: a glint's core radius (pixels, log-uniform)
GLINT_RADIUS_PX = (1.2, 5.0)


def draw_skin(image: np.ndarray, rng: np.random.Generator, centers, diameters, tries: int = 5) -> np.ndarray:
    """``image`` (h, w, 3) uint8 RGB with bare skin drawn in where it covers none of the balls at ``centers`` (n, 2) of
    ``diameters`` (n,) (a copy; the image itself where no place is found in ``tries``): a capsule (a forearm, an elbow,
    a finger) or an ellipse (a forehead, a knuckle, a knee) of a skin tone from dark to pale, shaded as a rounded
    body under one light, with the light's specular highlight on it (a white ball's detector's false alarms on
    held-out cameras: elbows and foreheads, README Results), as bright as its surroundings allow, its edge a little
    soft, often cut by the frame's edge."""
    import cv2

    h, w = image.shape[:2]
    width = math.exp(rng.uniform(*np.log(SKIN_WIDTH_PX)))
    length = width * (rng.uniform(*SKIN_LENGTH) if rng.random() < 0.6 else rng.uniform(1.3, 1.8))  # never round: a ball is
    c, d = np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)
    at = _place(rng, h, w, 0.5 * length + 4.0, c, d, tries)  # its soft edge within 4 px
    if at is None:
        return image
    cx, cy = at
    ang = rng.uniform(0.0, math.pi)
    m = int(math.ceil(0.5 * length)) + 8  # the shape and its softened edge: only these pixels change
    x0, x1, y0, y1 = max(0, int(cx) - m), min(w, int(cx) + m + 1), max(0, int(cy) - m), min(h, int(cy) + m + 1)
    y, x = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    ca, sa = math.cos(ang), math.sin(ang)
    xr, yr = (x - cx) * ca + (y - cy) * sa, -(x - cx) * sa + (y - cy) * ca
    half = 0.5 * width
    if length > 1.45 * width:  # a capsule: the distance from its axis's segment
        ax = np.maximum(np.abs(xr) - 0.5 * (length - width), 0.0) * np.sign(xr)
        nx, ny = ax / half, yr / half
    else:  # an ellipse of these axes
        nx, ny = xr / (0.5 * length), yr / half
    rho2 = nx * nx + ny * ny
    inside = (rho2 <= 1.0).astype(np.float32)
    mask = cv2.GaussianBlur(inside, (0, 0), rng.uniform(0.4, 1.5))
    nz = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
    nxi, nyi = nx * ca - ny * sa, nx * sa + ny * ca  # the surface's normal in the image's axes
    light = rng.normal(size=3)
    light[2] = abs(light[2]) + 0.6
    light /= np.linalg.norm(light)
    diffuse = np.clip(nxi * light[0] + nyi * light[1] + nz * light[2], 0.0, 1.0)
    half_v = light + (0.0, 0.0, 1.0)
    half_v /= np.linalg.norm(half_v)
    spec = np.clip(nxi * half_v[0] + nyi * half_v[1] + nz * half_v[2], 0.0, 1.0) ** rng.uniform(15.0, 80.0)
    tone = rng.uniform(0.0, 1.0)
    r = 0.06 + 0.6 * tone
    g = r * rng.uniform(0.33, 0.58)
    refl = np.array([r, g, g * rng.uniform(0.3, 0.75)], np.float32)  # linear: pale (0.75, 0.41, 0.26) to dark (0.27, 0.09, 0.02)
    level = _level(image, cx, cy, length)
    bright = rng.uniform(0.5, 1.3) * min(1.0, 0.1 + 4.0 * level)
    ambient = rng.uniform(0.15, 0.5)
    shade = bright * (ambient + (1.0 - ambient) * diffuse)
    gloss = bright * rng.uniform(0.2, 1.0) * spec
    # the texture from the whole frame's noise, as the skin of the figures in README Results was drawn (the same draws)
    strength = rng.uniform(0.0, 0.06)
    grain = cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), rng.uniform(0.5, 2.5))[y0:y1, x0:x1]
    texture = 1.0 + strength * grain * 3.0
    lin = np.clip(shade[..., None] * texture[..., None] * refl[None, None, :] + gloss[..., None], 0.0, 1.0)
    colour = 255.0 * lin ** (1 / 2.2)
    out = image.copy()
    part = image[y0:y1, x0:x1].astype(np.float32) * (1.0 - mask[..., None]) + colour * mask[..., None]
    out[y0:y1, x0:x1] = np.clip(np.rint(part), 0, 255).astype(np.uint8)
    return out


def draw_glint(image: np.ndarray, rng: np.random.Generator, centers, diameters, tries: int = 5) -> np.ndarray:
    """``image`` with a small coloured light drawn in away from the balls (a copy; the image itself where no place is
    found): a status LED or a screen's spot, a core of 1-5 px saturated in one hue (blue most often, green, red,
    amber) and its glow a few times wider, as a camera sees it out of focus; a white ball's detector's false alarms
    (README Results)."""
    h, w = image.shape[:2]
    r = math.exp(rng.uniform(*np.log(GLINT_RADIUS_PX)))
    glow = r * rng.uniform(1.5, 4.0)
    c, d = np.asarray(centers, np.float64).reshape(-1, 2), np.asarray(diameters, np.float64).reshape(-1)
    squash = rng.uniform(0.7, 1.0)  # its glow stretched along the rows by 1 / squash
    at = _place(rng, h, w, (r + 3.0 * glow) / squash, c, d, tries, edge_share=0.0)
    if at is None:
        return image
    cx, cy = at
    hue = [(0.25, 0.55, 1.0), (0.3, 1.0, 0.45), (1.0, 0.25, 0.2), (1.0, 0.7, 0.15)][int(rng.choice(4, p=[0.45, 0.25, 0.15, 0.15]))]
    colour = 255.0 * np.clip(np.array(hue, np.float32) * rng.uniform(0.75, 1.0) + rng.uniform(0.0, 0.3), 0.0, 1.0)
    reach = int(math.ceil((r + 3.0 * glow) / squash)) + 1
    x0, x1, y0, y1 = max(0, int(cx) - reach), min(w, int(cx) + reach + 1), max(0, int(cy) - reach), min(h, int(cy) + reach + 1)
    y, x = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    rho = np.hypot((x - cx) * squash, y - cy)
    alpha = np.where(rho <= r, 1.0, rng.uniform(0.4, 1.0) * np.exp(-(((rho - r) / glow) ** 2)))
    alpha = np.where(rho <= r + 3.0 * glow, alpha, 0.0).astype(np.float32)
    out = image.copy()
    part = out[y0:y1, x0:x1].astype(np.float32)
    out[y0:y1, x0:x1] = np.clip(np.rint(part * (1.0 - alpha[..., None]) + colour * alpha[..., None]), 0, 255).astype(np.uint8)
    return out


def with_skin(image: np.ndarray, centers, diameters, rng) -> np.ndarray:
    """``image`` with ``SKIN_PER_FRAME`` pieces of bare skin (:func:`draw_skin`) and ``GLINTS_PER_FRAME`` coloured
    glints (:func:`draw_glint`) drawn in away from its balls."""
    out = image
    for _ in range(SKIN_PER_FRAME):
        out = draw_skin(out, rng, centers, diameters)
    for _ in range(GLINTS_PER_FRAME):
        out = draw_glint(out, rng, centers, diameters)
    return out


def with_lookalikes(image: np.ndarray, centers, diameters, rng, reflectance, n: int = LOOKALIKES_PER_FRAME) -> np.ndarray:
    """``image`` with ``n`` look-alikes of the ball's colour drawn in away from its balls (:func:`draw_lookalike`)."""
    out = image
    for _ in range(n):
        out = draw_lookalike(out, rng, centers, diameters, reflectance)
    return out


def confirm_examples(stage, pairs, seed: int, *, jitter: int = JITTER, lit: float = 0.0, context: float = CONTEXT, context2: float | None = None,
                     lookalikes: float = LOOKALIKES, reflectance=None, skin: float = SKIN, log=print):
    """``(crops (n, P, P, 3) uint8, labels (n,) float32: 1 a ball)`` of ``pairs`` ``(image, LabelledImage)`` (module
    docstring); ``lit``: the share of the frames that are also searched with light sources drawn in (:func:`with_lights`);
    ``context``: a crop's side in candidate diameters; ``context2``: a second crop's (None: none), its three channels
    after the first's (``(n, P, P, 6)``); ``lookalikes``: the share of the frames also searched with things of the
    ball's colour ``reflectance`` (:func:`draw_lookalike`) drawn in; ``skin``: the share also searched with bare skin
    and coloured glints drawn in (:func:`with_skin`)."""
    if lookalikes and reflectance is None:
        raise ValueError("look-alikes need the ball's reflectance")
    contexts = (context,) if context2 is None else (context, context2)

    def crop(image, u, v, d):
        return stacked_crop(image, u, v, d, contexts, CROP_PX, MIN_SIDE_PX)

    from harness.experiments.detector.scores import truth_of

    rng = np.random.default_rng([seed, 61])
    crops, label = [], []
    n_cand = 0
    frames = []
    again = ((lit, lambda im, c, d: with_lights(im, c, d, rng)), (lookalikes, lambda im, c, d: with_lookalikes(im, c, d, rng, reflectance)),
             (skin, lambda im, c, d: with_skin(im, c, d, rng)))
    for image, li in pairs:
        frames.append((image, li, True))
        for share, draw in again:  # each share in turn, its draw only where it is set (a share of 0 draws nothing)
            if share and rng.random() < share:
                frames.append((draw(image, *truth_of(li)), li, False))
    for image, li, first in frames:
        c, d = truth_of(li)
        uv, _, dd = stage.candidates(image, None, k=EXAMPLE_CANDIDATES, threshold=GATE, confirm=False)
        n_cand += len(uv)
        for (u, v), di in zip(uv, dd):
            y = 0.0
            if len(c):
                dist = np.hypot(c[:, 0] - u, c[:, 1] - v)
                j = int(np.argmin(dist))
                if dist[j] <= max(0.5 * d[j], 3.0):
                    y = 1.0
                elif dist[j] <= max(d[j], 6.0):
                    continue
            crops.append(crop(image, u, v, di))
            label.append(y)
        for _ in range(jitter if first else 0):
            for (u, v), di in zip(c, d):
                dj = di * math.exp(rng.uniform(-0.25, 0.25))
                uj, vj = u + rng.uniform(-0.2, 0.2) * di, v + rng.uniform(-0.2, 0.2) * di
                crops.append(crop(image, uj, vj, dj))
                label.append(1.0)
    # a stage with (almost) no false alarms in its training frames (one barely trained) leaves nothing to tell the balls
    # from: random places of the frames, away from their balls, are the others then (as many as the balls)
    n_random, tries, n_before, missing = 0, 0, len(label), label.count(1.0) - label.count(0.0)
    while pairs and n_random < missing and tries < 20 * (n_before + n_random):
        image, li = pairs[tries % len(pairs)]
        tries += 1
        c, d = truth_of(li)
        h, w = image.shape[:2]
        u, v, di = rng.uniform(0, w - 1), rng.uniform(0, h - 1), math.exp(rng.uniform(math.log(6.0), math.log(48.0)))
        if len(c) and (np.hypot(c[:, 0] - u, c[:, 1] - v) <= np.maximum(d, 6.0) + di).any():
            continue
        crops.append(crop(image, u, v, di))
        label.append(0.0)
        n_random += 1
    y = np.array(label, np.float32)
    log(f"confirmation network: {len(y)} crops of {len(pairs)} frames ({len(frames) - len(pairs)} of them again with lights, look-alikes or skin drawn in; {n_cand} candidates of the stage; "
        f"{int(y.sum())} balls, {int((y == 0).sum())} not" + (f", {n_random} of them random places" if n_random else "") + ")")
    return np.array(crops, np.uint8).reshape(-1, CROP_PX, CROP_PX, 3 * len(contexts)), y


def confirm_net(torch, c: int = 16):
    class Confirm(torch.nn.Module):
        """Four 3x3 convolutions (three with 2x2 max pooling) on the crop, its features' mean and max, one linear
        layer: a logit."""

        def __init__(self):
            super().__init__()
            nn = torch.nn
            self.features = nn.Sequential(
                nn.Conv2d(3, c, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(c, 2 * c, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(2 * c, 2 * c, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(2 * c, 2 * c, 3, padding=1), nn.ReLU())
            self.head = nn.Linear(4 * c, 1)

        def forward(self, crops):  # crops (n, P, P, 3) float in [0, 255]
            f = self.features(crops.permute(0, 3, 1, 2) / 255.0 - 0.5)
            return self.head(torch.cat([f.mean((2, 3)), f.amax((2, 3))], 1))[:, 0]

    return Confirm()


def fit_confirm(crops, labels, *, steps: int, seed: int, batch: int = 64, lr: float = 2e-3, ema: float = 0.0, log=print,
                progress: bool = False) -> bytes:
    """The confirmation network fitted on :func:`confirm_examples`' arrays; its ONNX bytes (input ``crops`` uint8,
    output ``p``). Crops of six channels (two crops of each candidate): a network on each crop, each fitted as the one
    of a single crop would be (the same seed and draws), and a graph that gives the mean of their probabilities
    (:func:`confirm_pair`). ``ema``: the exponential moving average of the weights over the steps is kept, with this
    decay per step (as :class:`harness.experiments.detector.learned_train.LearnedTrainOptions`'s ``ema``; 0 = the last
    step's weights)."""
    from harness.experiments.detector.learned_train import ema_problem

    if ema_problem(ema):
        raise ValueError(f"the confirmation network's ema {ema_problem(ema)}")
    import torch

    pos, neg = np.flatnonzero(labels == 1), np.flatnonzero(labels == 0)
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError(f"the confirmation network needs balls and other candidates: {len(pos)} balls, {len(neg)} others")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # repeatable sums
    try:
        p = crops.shape[1]
        if crops.shape[3] == 3:
            return export_confirm(torch, _fit_one(torch, crops, labels, pos, neg, steps, seed, batch, lr, log, progress, "", ema), p)
        first = _fit_one(torch, crops[..., :3], labels, pos, neg, steps, seed, batch, lr, log, progress, " (first crop)", ema)
        second = _fit_one(torch, crops[..., 3:], labels, pos, neg, steps, seed, batch, lr, log, progress, " (second crop)", ema)
        return export_confirm(torch, confirm_pair(torch, first, second), p, 6)
    finally:
        torch.set_num_threads(threads)


def _fit_one(torch, crops, labels, pos, neg, steps: int, seed: int, batch: int, lr: float, log, progress: bool, what: str, ema: float = 0.0):
    """One network (:func:`confirm_net`) fitted on three-channel ``crops``: half balls, half not per batch, each crop
    flipped at random and changed as the stage's patches are; with ``ema``, the moving average of its weights."""
    from harness.experiments.detector.learned_train import averaged, moving_average, optimiser_step, photometric

    torch.manual_seed(seed)
    rng = np.random.default_rng([seed, 62])
    net = confirm_net(torch)
    opt = torch.optim.Adam(net.parameters(), lr=lr, foreach=True)
    average = moving_average(torch, net, ema)
    bar = None
    if progress:
        from harness.common.progress import progress_bar

        bar = progress_bar(total=steps, desc="confirmation network" + what, unit="step", leave=False)
    avg = None
    half = batch // 2
    p = crops.shape[1]
    for i in range(steps):
        if i == int(0.7 * steps):
            for g in opt.param_groups:
                g["lr"] = lr / 4
        idx = np.concatenate([rng.choice(pos, half), rng.choice(neg, batch - half)])
        xb = np.empty((batch, p, p, 3), np.uint8)
        for k, j in enumerate(idx):
            x = crops[j]
            if rng.random() < 0.5:
                x = x[:, ::-1]
            if rng.random() < 0.5:
                x = x[::-1]
            xb[k] = photometric(np.ascontiguousarray(x), rng)
        out = net(torch.from_numpy(xb).float())
        loss = torch.nn.functional.binary_cross_entropy_with_logits(out, torch.from_numpy(labels[idx]))
        avg = optimiser_step(opt, loss, avg, bar)
        if average is not None:
            average.update_parameters(net)
    if bar is not None:
        bar.close()
    kept, note = averaged(net, average, ema)
    log(f"confirmation network{what}: {steps} steps of {batch} crops, final loss {avg:.3f}{note}")
    return kept.eval()


def confirm_pair(torch, first, second):
    """A network of six-channel crops from two of three channels: ``first`` on channels 0-2, ``second`` on 3-5; its
    logit is the one of the mean of their probabilities (so :func:`export_confirm`'s sigmoid gives that mean)."""
    class Pair(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.first, self.second = first, second

        def forward(self, crops):
            p = 0.5 * (torch.sigmoid(self.first(crops[..., :3])) + torch.sigmoid(self.second(crops[..., 3:])))
            return torch.logit(p, eps=1e-7)

    return Pair()


def export_confirm(torch, net, p: int, channels: int = 3) -> bytes:
    import io

    class Deployed(torch.nn.Module):
        def __init__(self, inner):
            super().__init__()
            self.inner = inner

        def forward(self, crops):
            return torch.sigmoid(self.inner(crops.float()))

    buf = io.BytesIO()
    torch.onnx.export(Deployed(net), (torch.zeros(2, p, p, channels, dtype=torch.uint8),), buf, input_names=["crops"],
                      output_names=["p"], dynamic_axes={"crops": {0: "n"}, "p": {0: "n"}}, opset_version=17, dynamo=False)
    return buf.getvalue()


def _searched_again(lit: float, lookalikes: float, skin: float = 0.0) -> str:
    """The description's note of the frames searched again: the first share's words whole, the others' after it (the
    shipped files' words: lights alone as before)."""
    parts = [(x, what) for x, what in ((lit, "light sources"), (lookalikes, "things of the ball's colour"),
                                       (skin, "bare skin and coloured glints")) if x]
    if not parts:
        return ""
    (first, what), rest = parts[0], parts[1:]
    return f" ({100 * first:g} % of the frames searched again with {what} drawn in" + "".join(f", {100 * x:g} % with {w}" for x, w in rest) + ")"


def build_confirm_net(stage, pairs, *, steps: int, seed: int, description: str, lit: float = LIT, context: float = CONTEXT,
                      context2: float | None = None, lookalikes: float = LOOKALIKES, reflectance=None, skin: float = SKIN, ema: float = 0.0,
                      log=print, progress: bool = False) -> ConfirmNet:
    """A :class:`ConfirmNet` for ``stage`` trained on its candidates in ``pairs`` (``lit``: the share of them searched
    again with light sources drawn in; ``context``: a crop's side in candidate diameters; ``context2``: a second
    crop's, or None; ``lookalikes``: the share searched again with things of the ball's colour ``reflectance`` drawn in;
    ``skin``: the share searched again with bare skin and coloured glints drawn in; ``ema``: :func:`fit_confirm`'s)."""
    crops, labels = confirm_examples(stage, pairs, seed, lit=lit, context=context, context2=context2, lookalikes=lookalikes, reflectance=reflectance,
                                     skin=skin, log=log)
    onnx = fit_confirm(crops, labels, steps=steps, seed=seed, ema=ema, log=log, progress=progress)
    return ConfirmNet(onnx, crop_px=CROP_PX, context=context, context2=context2, min_side_px=MIN_SIDE_PX, candidates=CANDIDATES, gate=GATE,
                      description=f"{steps} steps of 64 crops, seed {seed}, on {int(labels.sum())} ball and {int((labels == 0).sum())} other crops"
                      + _searched_again(lit, lookalikes, skin)
                      + (f", the weights' moving average kept (decay {ema:g} per step)" if ema else "")
                      + (f", crops of {context:g} diameters" if context != CONTEXT and context2 is None else "")
                      + (f"; two networks so, one on crops of {context:g} diameters, one on crops of {context2:g}, their probabilities averaged"
                         if context2 is not None else "") + "; " + description)

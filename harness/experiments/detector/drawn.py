"""Labelled data sets of balls drawn into real, ball-free frames: training canvases for a model that must
transfer to real cameras, and a realistic stand-in for real photographs we may not train on.

Each source frame (a video's frames, or a COCO set's frames with their labelled balls painted out:
:func:`harness.experiments.detector.backgrounds.read_backgrounds`) is centre-cropped to the output's
aspect ratio and resized (``DrawnOptions.size``, default 640x480: a VGA camera). Then, seeded:

1. **balls**: ``balls`` per frame (none with probability ``p_empty``: the frame stays a ball-free
   negative), each through :func:`harness.sim.render.composite.draw_ball` with an ideal pinhole camera
   (focal ``focal_px``) at the depth that gives a diameter drawn log-uniformly in ``diameter_px``: the
   image's local white level, grey-world cast, sharpness and sensor noise; motion blur along a random
   image direction, up to ``max_blur_diameters`` ball diameters over the exposure; the ball's
   reflectance within the range real balls of its colour show (:data:`BALL_REFLECTANCE`); with
   probability ``p_near_skin`` the ball lies next to a skin-coloured pixel (hands hold and pick up
   balls), else anywhere;
2. **specular highlight** (probability ``p_specular``): a small soft bright spot on the ball's lit side;
3. **camera** (probability ``p_camera``): a Bayer mosaic and demosaic (the artefacts of a raw sensor),
   then :func:`harness.experiments.detector.augment.augment` without geometry (white balance,
   exposure, gamma, a lamp tint, motion blur or defocus, gain noise, JPEG).

The frame's labels are the drawn balls' boxes and exact centres (COCO with ``center_px``). Ball-free
frames stay ball-free: every detection there is a false alarm.

``python -m harness.experiments.detector.drawn --sources VIDEO|COCO@START:STOP ... --out DIR --seed 0
[--diameter-px 20:60] [--frames-per-video 48] [--p-empty 0.25]``
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = ["BALL_REFLECTANCE", "DrawnOptions", "draw_frame", "main", "make_set"]

#: per ball colour, the (lo, hi) linear reflectance per channel (R, G, B) a real ball of it shows
#: (orange: from pale yellow-orange to deep red-orange; the renderer's "orange" is (1.0, 0.42, 0.06))
BALL_REFLECTANCE = {
    "orange": ((0.80, 0.22, 0.01), (1.0, 0.62, 0.16)),
    "white": ((0.78, 0.76, 0.70), (0.95, 0.95, 0.92)),
}
BALL_RADIUS_M = 0.02
EXPOSURE_S = 0.01


@dataclass(frozen=True)
class DrawnOptions:
    """Options of :func:`make_set` (module docstring).

    size : (width, height) of the output frames, pixels
    diameter_px : (lo, hi) ball diameter range, pixels (log-uniform)
    balls : balls drawn per frame that has any
    p_empty : probability that a frame gets no ball
    colour : ball colour, a key of :data:`BALL_REFLECTANCE`
    focal_px : the pinhole camera's focal length, pixels
    max_blur_diameters : longest motion smear over the exposure, in ball diameters
    p_near_skin, p_specular, p_camera : probabilities of steps 1-3 of the module docstring
    """

    size: tuple = (640, 480)
    diameter_px: tuple = (20.0, 60.0)
    balls: int = 1
    p_empty: float = 0.25
    colour: str = "orange"
    focal_px: float = 600.0
    max_blur_diameters: float = 1.0
    p_near_skin: float = 0.5
    p_specular: float = 0.5
    p_camera: float = 0.8

    def __post_init__(self):
        w, h = self.size
        if not (int(w) == w and int(h) == h and w >= 32 and h >= 32):
            raise ValueError(f"DrawnOptions.size must be (width, height) of at least 32 px, got {self.size!r}")
        lo, hi = self.diameter_px
        if not (2.0 <= lo <= hi <= min(w, h) / 2):
            raise ValueError(f"DrawnOptions.diameter_px must be (lo, hi) with 2 <= lo <= hi <= half the image, got {self.diameter_px!r}")
        if isinstance(self.balls, bool) or not isinstance(self.balls, int) or self.balls < 1:
            raise ValueError(f"DrawnOptions.balls must be an integer >= 1, got {self.balls!r}")
        for name in ("p_empty", "p_near_skin", "p_specular", "p_camera"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"DrawnOptions.{name} must be a probability in [0, 1], got {getattr(self, name)!r}")
        if self.colour not in BALL_REFLECTANCE:
            raise ValueError(f"DrawnOptions.colour must be one of {sorted(BALL_REFLECTANCE)}, got {self.colour!r}")
        if not (self.focal_px > 0 and self.max_blur_diameters >= 0):
            raise ValueError("DrawnOptions.focal_px must be > 0 and max_blur_diameters >= 0")


def _crop_resize(image: np.ndarray, size) -> np.ndarray:
    """Centre crop of ``image`` to the aspect ratio of ``size`` (w, h), resized to it."""
    h, w = image.shape[:2]
    tw, th = size
    if w * th > h * tw:  # too wide
        cw, ch = int(round(h * tw / th)), h
    else:
        cw, ch = w, int(round(w * th / tw))
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    crop = image[y0 : y0 + ch, x0 : x0 + cw]
    interp = cv2.INTER_AREA if cw > tw else cv2.INTER_LINEAR
    return cv2.resize(crop, (int(tw), int(th)), interpolation=interp)


def _skin_pixels(image: np.ndarray) -> np.ndarray:
    """(n, 2) (u, v) of skin-coloured pixels (a common YCrCb box), on a 4 px grid."""
    ycc = cv2.cvtColor(image[::4, ::4], cv2.COLOR_RGB2YCrCb)
    m = (ycc[..., 0] > 60) & (ycc[..., 1] >= 138) & (ycc[..., 1] <= 173) & (ycc[..., 2] >= 77) & (ycc[..., 2] <= 127)
    v, u = np.nonzero(m)
    return np.stack([u * 4.0, v * 4.0], axis=1)


def _camera(size, focal_px: float):
    from tracker import Camera

    w, h = size
    K = np.array([[focal_px, 0.0, (w - 1) / 2], [0.0, focal_px, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return Camera("drawn", K, np.zeros(0), np.eye(3), np.zeros(3), (int(w), int(h)))


def _bayer(image: np.ndarray) -> np.ndarray:
    """An RGGB mosaic of ``image`` demosaiced again by OpenCV (bilinear): the colour fringes of a raw sensor."""
    h, w = image.shape[:2]
    mosaic = np.empty((h, w), np.uint8)
    mosaic[0::2, 0::2] = image[0::2, 0::2, 0]
    mosaic[0::2, 1::2] = image[0::2, 1::2, 1]
    mosaic[1::2, 0::2] = image[1::2, 0::2, 1]
    mosaic[1::2, 1::2] = image[1::2, 1::2, 2]
    return cv2.cvtColor(mosaic, cv2.COLOR_BayerBG2RGB)  # OpenCV names an RGGB mosaic "BG" (its second row)


def _highlight(image: np.ndarray, center_px, diameter_px: float, rng: np.random.Generator) -> np.ndarray:
    """A soft bright spot on the ball (a lamp's specular reflection), up to the image's white."""
    h, w = image.shape[:2]
    r = diameter_px / 2
    ang = rng.uniform(0, 2 * math.pi)
    off = rng.uniform(0.2, 0.55) * r
    cu, cv = center_px[0] + off * math.cos(ang), center_px[1] + off * math.sin(ang)
    sigma = max(rng.uniform(0.06, 0.15) * diameter_px, 0.6)
    half = int(math.ceil(3 * sigma)) + 1
    x0, x1 = max(int(cu) - half, 0), min(int(cu) + half + 1, w)
    y0, y1 = max(int(cv) - half, 0), min(int(cv) + half + 1, h)
    if x1 <= x0 or y1 <= y0:
        return image
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    g = np.exp(-((xx - cu) ** 2 + (yy - cv) ** 2) / (2 * sigma * sigma))[..., None] * np.float32(rng.uniform(0.4, 0.9))
    patch = image[y0:y1, x0:x1].astype(np.float32)
    out = image.copy()
    out[y0:y1, x0:x1] = np.clip(np.rint(patch + g * (255.0 - patch)), 0, 255).astype(np.uint8)
    return out


def draw_frame(image: np.ndarray, name: str, rng: np.random.Generator, opts: DrawnOptions = DrawnOptions()):
    """``(frame (h, w, 3) uint8 RGB, LabelledImage named ``name``)``: ``image`` (any size, RGB, ball-free)
    cropped and resized to ``opts.size`` with balls drawn in and the camera randomised (module docstring)."""
    from harness.experiments.detector.augment import AugmentOptions, augment
    from harness.experiments.detector.coco import LabelledImage
    from harness.sim.render.composite import draw_ball, edge_blur_px
    from harness.sim.render.scene_state import Ball

    frame = _crop_resize(image, opts.size)
    w, h = opts.size
    cam = _camera(opts.size, opts.focal_px)
    boxes, centers = [], []
    n = 0 if rng.random() < opts.p_empty else opts.balls
    blur = edge_blur_px(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)) if n else float("nan")
    skin = _skin_pixels(frame) if n else np.zeros((0, 2))
    lo, hi = BALL_REFLECTANCE[opts.colour]
    for _ in range(n):
        d = float(math.exp(rng.uniform(math.log(opts.diameter_px[0]), math.log(opts.diameter_px[1]))))
        margin = d / 2 + 1
        if len(skin) and rng.random() < opts.p_near_skin:
            s = skin[rng.integers(len(skin))]
            a = rng.uniform(0, 2 * math.pi)
            uv = s + rng.uniform(0.5, 1.0) * d * np.array([math.cos(a), math.sin(a)])
        else:
            uv = rng.uniform([0, 0], [w - 1, h - 1])
        uv = np.clip(uv, margin, [w - 1 - margin, h - 1 - margin])
        z = opts.focal_px * 2 * BALL_RADIUS_M / d
        pos = np.array([(uv[0] - (w - 1) / 2) * z / opts.focal_px, (uv[1] - (h - 1) / 2) * z / opts.focal_px, z])
        smear_px = rng.uniform(0, opts.max_blur_diameters) * d if rng.random() < 0.5 else 0.0
        a = rng.uniform(0, 2 * math.pi)
        vel = np.array([math.cos(a), math.sin(a), 0.0]) * smear_px * z / opts.focal_px / EXPOSURE_S
        ball = Ball(pos, vel, tuple(rng.uniform(lo, hi)), BALL_RADIUS_M)
        light = rng.normal(size=3) + np.array([0.0, -1.0, -1.0])  # mostly from above and in front
        fb = blur if np.isfinite(blur) else 0.0
        frame, truth = draw_ball(frame, cam, ball, EXPOSURE_S, rng, light_dir_world=light, frame_blur_px=fb)
        if rng.random() < opts.p_specular:
            frame = _highlight(frame, truth.center_px, truth.diameter_px, rng)
        if truth.box_xywh[2] > 0 and truth.box_xywh[3] > 0:
            boxes.append(truth.box_xywh)
            centers.append(truth.center_px)
    li = LabelledImage(name, w, h, np.array(boxes, float).reshape(-1, 4), np.array(centers, float).reshape(-1, 2),
                       ball_colours=(opts.colour,) * len(boxes))  # what the ball is: in warm light it may look orange
    if rng.random() < opts.p_camera:
        if rng.random() < 0.5:
            frame = _bayer(frame)
        frame, li = augment(frame, li, rng, AugmentOptions(scale_range=(1.0, 1.0), p_flip=0.0))
        li = dataclasses.replace(li, path=Path(name))
    return frame, li


def make_set(sources, out_dir, seed: int, opts: DrawnOptions = DrawnOptions(), *, frames_per_video: int = 48) -> Path:
    """Write ``out_dir/images/*.png`` and ``out_dir/annotations.json``: every frame of ``sources``
    (``rt2 train --backgrounds`` syntax) through :func:`draw_frame`, seeded per frame (``default_rng([seed, i])``)."""
    from harness.experiments.detector.backgrounds import read_backgrounds
    from harness.experiments.detector.coco import write_coco
    from harness.experiments.detector.train import load_image

    out_dir = Path(out_dir)
    if (out_dir / "annotations.json").exists():
        raise ValueError(f"--out {str(out_dir)!r} already holds an annotations.json")
    frames = read_backgrounds(sources, frames_per_video, load_image=load_image)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    labelled = []
    for i, (image, _) in enumerate(frames):
        name = f"images/d{i:05d}.png"
        frame, li = draw_frame(image, name, np.random.default_rng([seed, i]), opts)
        cv2.imwrite(str(out_dir / name), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        labelled.append(li)
    sources_text = " ".join(str(s) for s in sources)
    info = {"description": f"balls drawn into real frames: {sources_text}; seed {seed}; {opts}"}
    return write_coco(out_dir, labelled, info=info)


def _pair(text: str, option: str) -> tuple:
    try:
        lo, hi = (float(t) for t in text.split(":"))
    except ValueError:
        raise ValueError(f"{option} must be LO:HI (e.g. 20:60), got {text!r}") from None
    return lo, hi


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m harness.experiments.detector.drawn", description=__doc__.split("\n\n")[0])
    p.add_argument("--sources", nargs="+", required=True, help="videos, COCO sets (PATH@START:STOP) or folders of ball-free images")
    p.add_argument("--out", required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--diameter-px", default="20:60", help="LO:HI ball diameter, pixels (log-uniform; default 20:60)")
    p.add_argument("--size", default="640x480", help="WIDTHxHEIGHT of the frames (default 640x480)")
    p.add_argument("--frames-per-video", type=int, default=48)
    p.add_argument("--p-empty", type=float, default=0.25, help="share of frames left ball-free (default 0.25)")
    p.add_argument("--balls", type=int, default=1)
    p.add_argument("--colour", default="orange", choices=sorted(BALL_REFLECTANCE))
    p.add_argument("--p-camera", type=float, default=0.8, help="probability of the camera randomisation (default 0.8)")
    a = p.parse_args(argv)
    try:
        w, _, h = a.size.partition("x")
        opts = DrawnOptions(size=(int(w), int(h)), diameter_px=_pair(a.diameter_px, "--diameter-px"), balls=a.balls,
                            p_empty=a.p_empty, colour=a.colour, p_camera=a.p_camera)  # fmt: skip
        path = make_set(a.sources, a.out, a.seed, opts, frames_per_video=a.frames_per_video)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Real ball crops flown along a known 3D flight: one real ball pasted into every camera of a calibrated rig.

The semi-real frame sets' white ball (:mod:`harness.sim.semireal`, ``rt2 eval framesets --scene caliscope
--ball white``) is not drawn: it is a real ball cut from the real rally frames
(:func:`harness.sim.render.ball_crops.cut_ball_crops`, the clean ones: ``fit >= MIN_FIT``), pasted with
:func:`harness.sim.render.ball_crops.paste_ball`. Per frame set, :meth:`RealBalls.choose` picks the crop
and its look, and per camera :meth:`RealBalls.paste`:

* **where**: the centre is the camera's projection of the ball's centre (through its lens model), so the
  label is exact; the size is the apparent diameter of the ball at that depth through that lens
  (:func:`harness.sim.render.truth.ball_truths`: the equal-area diameter of its silhouette, ``2 f r / z``
  on the optical axis);
* **smear**: the projected flight over the exposure (``project(p + v T / 2) - project(p - v T / 2)``). The real
  crops carry their own motion blur (the rally phone's long shutter: a smear of 0.2-2 ball diameters); the
  crop is rotated so its smear lies along the projected flight, and the part of the flight's smear the
  crop does not already have is added as motion blur. A crop smeared more than the flight asks stays so
  (a floor): the frame set's crop is drawn among the ``NEAREST_CROPS`` crops whose smear ratio (smear /
  diameter) is nearest the flight's (median over the cameras);
* **look**: one gain, colour jitter and light match per frame set (the same ball in every camera), each
  camera's own local light, sharpness (:func:`harness.sim.render.composite.local_look`) and noise.

The truth (:class:`~harness.sim.render.truth.BallTruth`) per camera: the projected centre, the apparent
diameter (both NaN where the camera cannot see the ball: behind it, far outside its image, or where its lens
model no longer inverts, :func:`lens_valid`), the visibility (the pasted matte's mass over the whole ball's: the part inside the image) and the
pasted ball's box clipped to the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harness.sim.render.ball_crops import MIN_FIT, BallCrop, cut_ball_crops, paste_ball
from harness.sim.render.composite import local_look
from harness.sim.render.scene_state import Ball
from harness.sim.render.truth import BallTruth, ball_truths
from tracker import Camera

__all__ = ["NEAREST_CROPS", "RealBalls", "RealLook", "lens_valid"]

NEAREST_CROPS = 8  #: a frame set's crop is drawn among this many crops of the nearest smear ratio
MAX_OUTSIDE_PX = 200.0  #: a ball centre farther outside the image is not pasted
LENS_ROUNDTRIP = 1e-3  #: normalised units (~1 px at f = 1000 px): the lens model is trusted where it inverts


@dataclass(frozen=True)
class RealLook:
    """One frame set's real ball: the crop and the look shared by every camera.

    crop : the :class:`~harness.sim.render.ball_crops.BallCrop`; gain, colour_gain (3,), light_match: as
    :func:`~harness.sim.render.ball_crops.paste_ball` takes them
    """

    crop: BallCrop
    gain: float
    colour_gain: np.ndarray
    light_match: float


def lens_valid(camera: Camera, X_world: np.ndarray, radius_m: float) -> bool:
    """Whether the points ``X_world`` (n, 3) are in front of ``camera`` (deeper than ``radius_m``), project within
    ``MAX_OUTSIDE_PX`` of its image, and their projection undistorts back to their own ray (within
    ``LENS_ROUNDTRIP``, normalised units): far outside the calibrated field the distortion polynomial folds
    back and would place a point in the image that the camera cannot see."""
    Xc = camera.to_camera(X_world)
    if (Xc[:, 2] <= radius_m).any():
        return False
    uv = camera.project(X_world)
    w, h = camera.image_size
    if not (np.isfinite(uv).all() and (uv > -MAX_OUTSIDE_PX).all() and (uv < np.array([w, h]) + MAX_OUTSIDE_PX).all()):
        return False
    back = camera.undistort(uv)
    return bool(np.abs(back - Xc[:, :2] / Xc[:, 2:3]).max() < LENS_ROUNDTRIP)


class RealBalls:
    """The clean real ball crops of a COCO set of one video (module docstring).

    source : the COCO file or its folder (e.g. ``../shared/data/real/phone_rally``); frames : None (all) or a
    ``"START:STOP"`` range of its time order (e.g. ``"58:"``: balls the detector never trained on)
    """

    def __init__(self, source, frames: str | None = None):
        crops = [c for c in cut_ball_crops(source, frames) if c.fit >= MIN_FIT and c.diameter_px > 0]
        if not crops:
            raise ValueError(f"real balls {str(source)!r} (frames {frames}): no clean ball crop (fit >= {MIN_FIT})")
        self.crops = crops
        self.smear_ratio = np.array([math.hypot(*c.blur_px) / c.diameter_px for c in crops])

    def __repr__(self) -> str:
        return f"RealBalls({len(self.crops)} crops)"

    def choose(self, smear_ratio: float, rng: np.random.Generator) -> RealLook:
        """A frame set's :class:`RealLook`: a crop among the ``NEAREST_CROPS`` nearest ``smear_ratio`` (smear /
        diameter the flight asks for; NaN: any crop), and the shared look, from ``rng``."""
        if np.isfinite(smear_ratio):
            near = np.argsort(np.abs(self.smear_ratio - smear_ratio), kind="stable")[:NEAREST_CROPS]
        else:
            near = np.arange(len(self.crops))
        crop = self.crops[int(near[rng.integers(len(near))])]
        return RealLook(crop, float(rng.uniform(0.85, 1.15)), rng.uniform(0.95, 1.05, 3), float(rng.uniform(0.0, 0.5)))

    @staticmethod
    def smear_px(camera: Camera, ball: Ball, exposure_s: float) -> tuple[np.ndarray, float]:
        """The flight's smear in ``camera`` over the exposure: (du, dv) pixels and the apparent diameter, pixels
        (NaN when the ball is not in front of the camera or not near its image: see :func:`lens_valid`)."""
        half = 0.5 * float(exposure_s) * np.asarray(ball.velocity_mps, float)
        ends = np.array([ball.position_m - half, ball.position_m, ball.position_m + half])
        if not lens_valid(camera, ends, ball.radius_m):
            return np.full(2, np.nan), float("nan")
        uv = camera.project(ends)
        d = ball_truths(camera, (ball,), exposure_s, np.zeros(1))[0].diameter_px
        return uv[2] - uv[0], float(d)

    def paste(self, image: np.ndarray, camera: Camera, ball: Ball, exposure_s: float, look: RealLook,
              rng: np.random.Generator) -> tuple[np.ndarray, BallTruth, np.ndarray]:  # fmt: skip
        """``image`` (H, W, 3) uint8 RGB of ``camera`` with ``look``'s ball pasted at ``ball``'s place (module
        docstring): (new image, :class:`~harness.sim.render.truth.BallTruth`, (H, W) float32 pasted matte)."""
        truth = ball_truths(camera, (ball,), exposure_s, np.zeros(1))[0]
        smear, d = self.smear_px(camera, ball, exposure_s)
        h, w = image.shape[:2]
        if not (np.isfinite(d) and d > 0 and np.isfinite(smear).all()):
            return image.copy(), BallTruth(np.full(2, np.nan), float("nan"), 0.0, np.zeros(4)), np.zeros((h, w), np.float32)
        crop = look.crop
        s = d / crop.diameter_px
        crop_len = s * math.hypot(*crop.blur_px)
        flight_len = math.hypot(*smear)
        angle = 0.0
        if flight_len > 1e-9 and crop_len > 1e-9:  # the crop's smear axis onto the flight's direction
            angle = math.degrees(math.atan2(smear[1], smear[0]) - math.atan2(crop.blur_px[1], crop.blur_px[0]))
        extra = smear * (max(flight_len - crop_len, 0.0) / flight_len) if flight_len > 1e-9 else np.zeros(2)
        defocus = local_look(image, truth.center_px, d, frame_blur_px=0.0).defocus_px
        res = paste_ball(image, crop, truth.center_px, d, rng, blur_px=extra, defocus_px=defocus, gain=look.gain,
                         colour_gain=look.colour_gain, light_match=look.light_match, angle_deg=angle)
        whole = float(crop.alpha.sum()) * s * s
        vis = float(np.clip(res.alpha.sum() / whole, 0.0, 1.0)) if whole > 0 else 0.0
        x, y, bw, bh = res.box_xywh
        x0, y0 = np.clip([x, y], 0, [w, h])
        x1, y1 = np.clip([x + bw, y + bh], 0, [w, h])
        box = np.array([x0, y0, x1 - x0, y1 - y0]) if (x1 > x0 and y1 > y0) else np.zeros(4)
        return res.image, BallTruth(truth.center_px, truth.diameter_px, vis, box), res.alpha

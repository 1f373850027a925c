"""Set RTBlob up for the playing sessions the way its user would: stereo pairs, disk radius, colour and tolerance.

RTBlob (docs/rtblob.md) has fixed stereo pairs, a fixed disk template and a fixed colour model. Its
defaults (pairs 0+1 and 2+3, a ball at 3 m, pure orange (255, 120, 0) with an RGB tolerance of 0.25)
fit no particular lab. In our lab they fail before any error mode of RTBlob's own shows: the shaded
ball renders a dark orange, about (130, 55, 9), and with the RGB tolerance of 0.25 the reddish-brown
wooden floor is within 0.6 of it, so a large patch of floor out-scores the small, blurred flying ball
in every frame (``rt2 play compare --source vision`` before this set-up: 100 % of RTBlob's
positions > 10 cm off). Someone running RTBlob in this lab would, once, with a still ball held at a
few places in the cameras' view:

* pairs (:func:`choose_pairs`): number the cameras so that each fixed pair sees a common part of the
  flight -- of the pairings of the rig's cameras, the one under which the most points of the flight
  volume are seen by both cameras of at least one pair (then: of both pairs);
* disk radius per camera: the median apparent radius of the 40 mm ball over the calibration
  positions that camera sees (Eq. (2)'s template; one fixed size, as published);
* reference colour: the median RGB of the ball's central pixels (inside 0.3 of its apparent
  diameter), as the accuracy experiment's calibration does (harness/experiments/accuracy/calibration.py);
* colour space and tolerance (:func:`tune_colour`): look at the response images and pick, from a
  short list of (space, sigma), the one under which the ball's peak beats the best peak elsewhere
  in the most calibration images (ties: the larger median margin) -- "turn the colour threshold
  until the ball stands out", which any user of a colour tracker does;
* ``min_score``: half-way between the background's and the ball's typical peaks (the 95th
  percentile of the one and the 5th of the other) when they separate, else the default.

The calibration frames are the play scene (person, clutter, the robot at rest) with a still ball at
positions drawn uniformly in the flight volume where >= 2 cameras see it; they use their own seeds,
never a played ball's. Nothing here looks at more than one camera at a time or adds a check RTBlob
never had: the baseline stays a per-camera arg-max and fixed-pair stereo.
"""

from __future__ import annotations

import numpy as np

from harness.sim import lab

__all__ = ["COLOUR_GRID", "calibrate_rtblob", "calibration_samples", "choose_pairs", "tune_colour"]

#: (colour_space, colour_sigma) candidates of :func:`tune_colour`, as a user would try them
COLOUR_GRID = (("rgb", 0.25), ("rgb", 0.18), ("rgb", 0.12), ("rgb", 0.08), ("rgb", 0.05),
               ("chromaticity", 0.08), ("chromaticity", 0.05), ("chromaticity", 0.035),
               ("chromaticity", 0.025), ("chromaticity", 0.015))


def _pairings(idx: list) -> list:
    """Every way to split the camera indices ``idx`` (even count) into unordered pairs."""
    if not idx:
        return [[]]
    first, rest = idx[0], idx[1:]
    return [[(first, b)] + tail for k, b in enumerate(rest) for tail in _pairings(rest[:k] + rest[k + 1:])]


def choose_pairs(rig, box_m, step_m: float = 0.1) -> tuple:
    """The fixed stereo pairs (camera index tuples) of ``rig`` that best cover ``box_m`` (2, 3) (module docstring).

    An odd camera out is left unused, as RTBlob leaves cameras in no pair unused."""
    n = len(rig)
    if n < 2:
        raise ValueError(f"RTBlob needs at least 2 cameras for a stereo pair, the rig has {n}: {rig.names}")
    if n > 8:
        raise ValueError(f"choose_pairs tries every pairing of the cameras: at most 8 cameras, the rig has {n}")
    X = lab.workspace_grid(box_m, step_m)
    seen = lab.coverage(rig, X).seen  # (n_cams, N)
    best, best_key = None, None
    for drop in ([None] if n % 2 == 0 else range(n)):
        idx = [i for i in range(n) if i != drop]
        for pairing in _pairings(idx):
            both = np.stack([seen[a] & seen[b] for a, b in pairing])
            key = (float(both.any(axis=0).mean()), float(both.all(axis=0).mean()))
            if best_key is None or key > best_key:
                best, best_key = tuple(pairing), key
    return best


def calibration_samples(rig, renderer, kinematics, scene_options, box_m, *, n_frames: int = 8, seed: int = 12345):
    """Still-ball calibration images: a list of (camera index, (H, W, 3) image, BallTruth) with the ball
    at least 0.9 visible, from ``n_frames`` frame sets of the play scene (robot at rest at ``q_home``)
    with the ball at random points of ``box_m`` (2, 3) that >= 2 cameras see."""
    from harness.experiments.play.play_scene import PlayScene

    box = np.asarray(box_m, float)
    rng = np.random.default_rng(seed)
    cand = rng.uniform(box[0], box[1], size=(20 * n_frames, 3))
    cand = cand[lab.coverage(rig, cand).n_seeing >= 2][:n_frames]
    out = []
    for k, X in enumerate(cand):
        scene = PlayScene(kinematics, scene_options, seed=seed + 1 + k).scene_at(k, 0.0, kinematics.q_home, X, np.zeros(3))
        images, truths = renderer.render_labelled(scene)
        for i, (image, truth) in enumerate(zip(images, truths)):
            t = truth[0]
            if np.isfinite(t.center_px).all() and t.visibility >= 0.9:
                out.append((i, image, t))
    return out


def _central_pixels(image, truth) -> np.ndarray:
    (u, v), r = truth.center_px, 0.3 * truth.diameter_px
    yy, xx = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    return image[(xx - u) ** 2 + (yy - v) ** 2 <= r * r]


def _peaks(response: np.ndarray, truth, radius_px: float) -> tuple[float, float]:
    """(ball peak within 2 px of the true centre, best peak outside the ball's neighbourhood)."""
    (u, v) = truth.center_px
    yy, xx = np.mgrid[0:response.shape[0], 0:response.shape[1]]
    d2 = (xx - u) ** 2 + (yy - v) ** 2
    near = d2 <= 4.0
    far = d2 > (truth.diameter_px / 2 + radius_px + 2.0) ** 2
    return float(response[near].max()) if near.any() else 0.0, float(response[far].max())


def tune_colour(samples, reference_rgb, radius_px, grid=COLOUR_GRID) -> tuple[dict, list]:
    """Pick ``colour_space``, ``colour_sigma`` and ``min_score`` from ``samples`` (module docstring).

    samples : [(camera index, image, BallTruth)]; radius_px : (n_cams,) disk radius per camera
    returns ``({"colour_space", "colour_sigma", "min_score"}, table)`` with one row per grid entry:
    ``(space, sigma, share of images the ball wins, median margin, ball peak p5, background peak p95)``
    """
    from tracker import RTBlobDetector, RTBlobOptions

    if not len(samples) or not len(grid):
        raise ValueError(f"tune_colour needs calibration samples and a grid, got {len(samples)} samples, {len(grid)} grid entries")
    table = []
    for space, sigma in grid:
        opts = RTBlobOptions(reference_rgb=tuple(reference_rgb), colour_space=space, colour_sigma=sigma)
        dets = {}
        ball, bg = [], []
        for i, image, truth in samples:
            if i not in dets:
                dets[i] = RTBlobDetector((image.shape[1], image.shape[0]), float(radius_px[i]), opts)
            b, o = _peaks(dets[i].response(image), truth, float(radius_px[i]))
            ball.append(b)
            bg.append(o)
        ball, bg = np.array(ball), np.array(bg)
        table.append((space, sigma, float(np.mean(ball > bg)), float(np.median(ball - bg)),
                      float(np.percentile(ball, 5)), float(np.percentile(bg, 95))))
    space, sigma, _, _, ball_p5, bg_p95 = max(table, key=lambda r: (r[2], r[3]))
    min_score = 0.5 * (ball_p5 + bg_p95) if ball_p5 > bg_p95 else RTBlobOptions().min_score
    return {"colour_space": space, "colour_sigma": sigma, "min_score": round(float(min_score), 3)}, table


def calibrate_rtblob(rig, renderer, kinematics, scene_options, *, box_m=None, n_frames: int = 8, seed: int = 12345):
    """:class:`tracker.RTBlobOptions` for ``rig`` in the play scene, set up as its user would (module docstring).

    box_m : (2, 3) the flight volume to calibrate over (default: the rig's workspace box)
    """
    from tracker import RTBlobOptions

    box = np.asarray(rig.workspace_m if box_m is None else box_m, float)
    samples = calibration_samples(rig, renderer, kinematics, scene_options, box, n_frames=n_frames, seed=seed)
    px = np.concatenate([_central_pixels(im, t) for _, im, t in samples]) if samples else np.zeros((0, 3))
    if len(px) < 10:
        raise ValueError(f"RTBlob calibration found only {len(px)} ball pixels in {n_frames} frame sets; "
                         f"does the rig see the box {box.tolist()}?")
    reference = tuple(float(c) for c in np.median(px, axis=0))
    radius = np.full(len(rig), np.nan)
    for i in range(len(rig)):
        d = [t.diameter_px for j, _, t in samples if j == i]
        radius[i] = max(round(float(np.median(d)) / 2, 2), 1.0) if d else np.nan
    fallback = float(np.nanmedian(radius))
    radius = np.where(np.isfinite(radius), radius, fallback)
    colour, _ = tune_colour(samples, reference, radius)
    return RTBlobOptions(reference_rgb=reference, template_radius_px=tuple(float(r) for r in radius),
                         pairs=choose_pairs(rig, box), **colour)

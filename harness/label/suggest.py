"""Which frames to label next: the most uncertain and the most different ones, not consecutive near-copies.

The rule (``suggest``), for frames described by

* ``descriptors (n, d)``: a small image descriptor per frame (:func:`describe_image`: the frame shrunk
  to 16x12 pixels, log intensity per colour channel, zero mean and unit norm), so two near-copies of
  one scene are close and a new scene, a new ball position or new lighting is far;
* ``uncertainty (n,)`` in [0, 1]: one minus the detector's score margin (:func:`uncertainty`: the best
  candidate's score minus the second's); a frame without a candidate scores 0: no pixel blob passed the
  model's thresholds and shape test, the model is as sure as it can be that nothing is there. (Scoring it 1,
  "cannot tell", made the rule prefer the frames the model sees nothing in, and a model that sees the ball
  sees nothing mostly in ball-free frames: on renders of lab4_vga_v1 the 10 first suggestions held 3-7
  frames with a ball per camera, 6-7 with this rule; a frame without a ball teaches the detector little that
  the background of every labelled frame does not, see docs/label.md "Which frames it suggests");

is greedy farthest-point sampling weighted by uncertainty: each pick maximises
``d_i * (0.5 + 0.5 * uncertainty_i)``, where ``d_i`` is the descriptor distance from frame ``i`` to the
nearest frame already labelled or picked. With nothing labelled yet the first pick is the frame nearest
to the mean descriptor (the most typical scene), then the rule above. A frame that duplicates a
labelled one has ``d = 0`` and is never suggested before every distinct frame is.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["DESCRIPTOR_SIZE", "describe_image", "suggest", "uncertainty"]

#: (width, height) of the shrunken frame the descriptor is made of
DESCRIPTOR_SIZE = (16, 12)


def describe_image(image: np.ndarray) -> np.ndarray:
    """(d,) float descriptor of an (H, W, 3) uint8 RGB image: 16x12 area-averaged log colours, zero mean, unit norm."""
    small = cv2.resize(image, DESCRIPTOR_SIZE, interpolation=cv2.INTER_AREA).astype(np.float64)
    v = np.log1p(small).reshape(-1)
    v -= v.mean()
    norm = np.linalg.norm(v)
    return v / norm if norm > 0 else v


def uncertainty(scores) -> float:
    """1 - (best score - second best score) of one frame's detector candidates (scores in [0, 1]); 0 with none
    (nothing passed the detector: the model is sure, see the module docstring)."""
    s = np.sort(np.asarray(scores, float).reshape(-1))[::-1]
    if len(s) == 0:
        return 0.0
    second = s[1] if len(s) > 1 else 0.0
    return float(np.clip(1.0 - (s[0] - second), 0.0, 1.0))


def suggest(descriptors, uncertainties, labelled, k: int) -> list[int]:
    """Indices of up to ``k`` frames to label next, best first (the rule of the module docstring).

    descriptors : (n, d) float, one row per frame
    uncertainties : (n,) float in [0, 1]
    labelled : indices of frames already labelled (never suggested)
    """
    x = np.asarray(descriptors, float)
    u = np.asarray(uncertainties, float)
    if x.ndim != 2 or u.shape != (len(x),):
        raise ValueError(f"suggest: need descriptors (n, d) and uncertainties (n,), got {x.shape} and {u.shape}")
    n = len(x)
    done = np.zeros(n, bool)
    idx = np.asarray(sorted(set(int(i) for i in labelled)), int)
    if len(idx) and (idx.min() < 0 or idx.max() >= n):
        raise ValueError(f"suggest: labelled indices must be in [0, {n}), got {idx.tolist()}")
    done[idx] = True
    weight = 0.5 + 0.5 * np.clip(u, 0.0, 1.0)
    if done.any():
        sq = (x * x).sum(axis=1)
        d2 = sq[:, None] + sq[None, done] - 2.0 * x @ x[done].T  # (n, n_done) squared distances, no (n, n_done, d) array
        d = np.sqrt(np.maximum(d2, 0.0).min(axis=1))
    else:
        d = None
    picks: list[int] = []
    n_picks = min(k, n - int(done.sum()))
    while len(picks) < n_picks:
        if d is None:  # nothing labelled: the most typical frame first
            i = int(np.argmin(np.where(done, np.inf, np.linalg.norm(x - x.mean(axis=0), axis=1))))
            d = np.full(n, np.inf)
        else:
            i = int(np.argmax(np.where(done, -np.inf, d * weight)))
        picks.append(i)
        done[i] = True
        d = np.minimum(d, np.linalg.norm(x - x[i], axis=1))
    return picks

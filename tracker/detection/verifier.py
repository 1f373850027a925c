"""A small classifier on the crops of the top candidates: the second stage that the single 5x5 filter
cannot be (it tests a pixel's colour, not the shape of what surrounds it).

For every candidate blob of Algorithm 1 (centre ``(u, v)``, box side ``d``), the crop of side
``S = clip(context * d, min_side_px, max_side_px)`` around the centre is resampled to
``crop_px x crop_px`` (``cv2.getRectSubPix`` then ``cv2.resize`` with area averaging), each channel
mapped through ``log(p + 8)`` and the crop's mean subtracted (exposure drops out, colour ratios and
contrast to the surroundings stay). A two-layer perceptron (ReLU) maps the flattened crop to three
numbers: the ball logit and the ball centre's offset from the crop centre in units of ``S``.
Inference is numpy and OpenCV only (no torch); the weights live in the model's ``.npz`` next to the
filter (``BallSegmentationModel.verifier``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["CandidateVerifier"]

_LOG_OFFSET_DN = 8.0
_LUT = np.log(np.arange(256, dtype=np.float32) + np.float32(_LOG_OFFSET_DN))


@dataclass(frozen=True, eq=False)
class CandidateVerifier:
    """Two-layer perceptron on candidate crops.

    w1 : (F, H) float32, F = crop_px * crop_px * 3 (crop rows, columns, RGB channels, flattened in that order)
    b1 : (H,) float32
    w2 : (H, 3) float32, outputs (ball logit, offset u, offset v); offsets in units of the crop side
    b2 : (3,) float32
    crop_px : side of the resampled crop, pixels
    context : crop side / candidate box side
    min_side_px, max_side_px : limits of the crop side in the image, pixels
    threshold : candidates whose ball probability is below it are dropped
    refine_center : move each accepted candidate's centre by the predicted offset
    """

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    crop_px: int = 16
    context: float = 2.5
    min_side_px: float = 8.0
    max_side_px: float = 256.0
    threshold: float = 0.5
    refine_center: bool = True

    def __post_init__(self):
        where = "CandidateVerifier"
        if isinstance(self.crop_px, bool) or not isinstance(self.crop_px, (int, np.integer)) or not 4 <= self.crop_px <= 64:
            raise ValueError(f"{where}: crop_px must be an integer in [4, 64], got {self.crop_px!r}")
        f = int(self.crop_px) ** 2 * 3
        arrays = {}
        for name in ("w1", "b1", "w2", "b2"):
            arr = np.asarray(getattr(self, name))
            if arr.dtype.kind not in "biuf":
                raise ValueError(f"{where}: {name} must be real numbers, got dtype {arr.dtype}")
            arr = arr.astype(np.float32)
            if not np.isfinite(arr).all():
                raise ValueError(f"{where}: {name} must be finite")
            arrays[name] = arr
        h = arrays["b1"].shape[0] if arrays["b1"].ndim == 1 else -1
        shapes = {"w1": (f, h), "b1": (h,), "w2": (h, 3), "b2": (3,)}
        for name, shape in shapes.items():
            if h < 1 or arrays[name].shape != shape:
                raise ValueError(f"{where}: {name} must have shape {shape} for crop_px={self.crop_px}, got {arrays[name].shape}")
        for name in ("context", "min_side_px", "max_side_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"{where}: {name} must be a positive number, got {v!r}")
        if not self.min_side_px <= self.max_side_px:
            raise ValueError(f"{where}: need min_side_px <= max_side_px, got {self.min_side_px} and {self.max_side_px}")
        if not 0.0 < float(self.threshold) < 1.0:
            raise ValueError(f"{where}: threshold must be a probability in (0, 1), got {self.threshold!r}")
        for name, arr in arrays.items():
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "crop_px", int(self.crop_px))
        for name in ("context", "min_side_px", "max_side_px", "threshold"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "refine_center", bool(self.refine_center))

    @property
    def n_hidden(self) -> int:
        return int(self.b1.shape[0])

    def sides_px(self, box_sides_px) -> np.ndarray:
        """(n,) crop sides in the image for candidate box sides (n,), pixels."""
        return np.clip(self.context * np.asarray(box_sides_px, np.float64), self.min_side_px, self.max_side_px)

    def features(self, image: np.ndarray, centers_px, sides_px) -> np.ndarray:
        """(n, F) float32 crop features.

        image : (H, W, 3) uint8 RGB; centers_px : (n, 2) crop centres (u, v), rt2 pixels; sides_px : (n,) crop sides, pixels
        """
        c = self.crop_px
        centers = np.asarray(centers_px, np.float64).reshape(-1, 2)
        sides = np.asarray(sides_px, np.float64).reshape(-1)
        out = np.empty((len(centers), c, c, 3), np.uint8)
        for i, ((u, v), s) in enumerate(zip(centers, sides)):
            side = max(int(round(s)), c)
            patch = cv2.getRectSubPix(image, (side, side), (float(u), float(v)))
            out[i] = patch if side == c else cv2.resize(patch, (c, c), interpolation=cv2.INTER_AREA)
        x = _LUT[out].reshape(len(centers), -1)
        return x - x.mean(axis=1, keepdims=True)

    def predict(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n,) ball probabilities and (n, 2) centre offsets (units of the crop side) of (n, F) features."""
        hidden = np.maximum(features @ self.w1 + self.b1, 0.0)
        out = hidden @ self.w2 + self.b2
        return 1.0 / (1.0 + np.exp(-out[:, 0].astype(np.float64))), out[:, 1:3].astype(np.float64)

    def verify(self, image: np.ndarray, centers_px, box_sides_px) -> tuple[np.ndarray, np.ndarray]:
        """(n,) ball probabilities and (n, 2) centres (refined when ``refine_center``) of n candidates."""
        centers = np.asarray(centers_px, np.float64).reshape(-1, 2)
        if len(centers) == 0:
            return np.zeros(0), np.zeros((0, 2))
        sides = self.sides_px(box_sides_px)
        prob, offset = self.predict(self.features(image, centers, sides))
        if self.refine_center:
            centers = centers + offset * sides[:, None]
        return prob, centers

    # -- files (fields of the model's .npz) ------------------------------------------------------------
    def to_fields(self) -> dict:
        return dict(verifier_w1=self.w1, verifier_b1=self.b1, verifier_w2=self.w2, verifier_b2=self.b2,
                    verifier_crop_px=np.array(self.crop_px), verifier_context=np.array(self.context),
                    verifier_side_range_px=np.array([self.min_side_px, self.max_side_px]),
                    verifier_threshold=np.array(self.threshold), verifier_refine_center=np.array(int(self.refine_center)))

    @classmethod
    def from_fields(cls, data: dict, src: str) -> "CandidateVerifier | None":
        """The verifier stored in a model file's fields, or None when the file has none."""
        keys = ("verifier_w1", "verifier_b1", "verifier_w2", "verifier_b2", "verifier_crop_px", "verifier_context",
                "verifier_side_range_px", "verifier_threshold", "verifier_refine_center")
        present = [k for k in keys if k in data]
        if not present:
            return None
        missing = [k for k in keys if k not in data]
        if missing:
            raise ValueError(f"{src}: verifier fields incomplete, missing {missing}")
        for k in keys:
            if data[k].dtype.kind not in "biuf":
                raise ValueError(f"{src}: field {k!r} must be numbers, got dtype {data[k].dtype}")
        sides = np.asarray(data["verifier_side_range_px"], np.float64).reshape(-1)
        if sides.shape != (2,):
            raise ValueError(f"{src}: field 'verifier_side_range_px' must hold [min, max], got shape {data['verifier_side_range_px'].shape}")
        crop = data["verifier_crop_px"]
        if crop.shape != () or not float(crop).is_integer():
            raise ValueError(f"{src}: field 'verifier_crop_px' must be an integer, got {crop!r}")
        try:
            return cls(w1=data["verifier_w1"], b1=data["verifier_b1"], w2=data["verifier_w2"], b2=data["verifier_b2"],
                       crop_px=int(crop), context=float(data["verifier_context"]), min_side_px=float(sides[0]),
                       max_side_px=float(sides[1]), threshold=float(data["verifier_threshold"]),
                       refine_center=bool(int(data["verifier_refine_center"])))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{src}: {exc}") from None

"""``rt2 train``: fit the single-convolution ball segmentation model to box labels (paper section 2.1).

A 5x5 convolution + sigmoid on one pixel is logistic regression on that pixel's 5x5x3 patch, so
training samples patches, not whole images (details and measurements: docs/detector.md):

1. Targets from boxes (:func:`pixel_targets`): pixels within ``core_fraction`` of the radius of the
   disk inscribed in a box are *ball*; the rest of the box and a ``ring_px`` ring are *ignored*; all
   other pixels are *background*. ``--ball-colour`` keeps the boxes of one ball colour only
   (:func:`select_ball_colour`); the other balls become background.
2. Samples per training image: up to ``max_positives_per_image`` ball pixels and
   ``random_negatives_per_image`` background pixels. After every epoch, **hard negatives**: the
   pixels of the wrong candidates our detector reports with the current filter and thresholds.
3. Loss: class-balanced binary cross-entropy (ball 1/2, background 1/2 split between random and
   hard negatives) plus a small L2 penalty; full-batch L-BFGS in torch on the CPU.
4. Validation: a held-out split of the frame sets (``f000123_cam2.png`` and ``f000123_cam0.png`` go
   to the same side). After each epoch :func:`choose_thresholds` picks ``T_h``, ``T_l`` and the blob
   area range maximising ``recall - outlier_rate`` of our detector among the choices that find a ball
   (:func:`finds_a_ball`); the best epoch is kept, and its thresholds go into the weights file as the
   recommended defaults; when no choice finds a ball after any epoch, :class:`NoBallFoundError` says so.
   Progress: tqdm on stderr, one line of validation figures per epoch (ours and the paper's Algorithm 1).

Everything random is seeded by ``TrainOptions.seed``: the same data and seed give the same weights.
torch is imported inside :func:`train` only; the result is a plain ``.npz`` read by
``tracker.BallSegmentationModel`` (no torch at inference).
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tracker import BallDetector, BallSegmentationModel, DetectorOptions
from tracker.detection.blobs import find_blobs
from tracker.detection.model import BALL_COLOURS, INPUT_TRANSFORMS, logit, transform_lut

from harness.common.memory import available_memory_bytes
from harness.common.options import named_by_options
from harness.experiments.detector.subsets import image_camera

__all__ = [
    "BALL_COLOURS",
    "EXIT_WEAK_MODEL",
    "FILTER_CHOICES",
    "LEARNED_CHOICES",
    "MIN_WRITE_RECALL",
    "KEEP_BASE_CHOICES",
    "NoBallFoundError",
    "THRESHOLD_CHOICES",
    "TrainOptions",
    "add_arguments",
    "ball_colour",
    "choose_thresholds",
    "colour_note",
    "cv_folds",
    "cv_recall",
    "finds_a_ball",
    "load_image",
    "pixel_targets",
    "keeps_filter",
    "run",
    "select_ball_colour",
    "split_groups",
    "train",
    "written_scores",
]

#: candidate thresholds searched on the validation split: T_h every 0.25 in logit from 0.5 to 0.999
T_HIGH_GRID = tuple(float(round(1.0 / (1.0 + math.exp(-x)), 6)) for x in np.arange(0.0, 7.01, 0.25))
T_LOW_GRID = (0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5)
COLOUR_SATURATION_CUT = 0.4
#: how ``rt2 train`` chooses the thresholds (see :func:`train`)
THRESHOLD_CHOICES = ("auto", "split", "cv")
#: "auto" holds out a validation split only when it would hold at least this many images with a ball
AUTO_SPLIT_MIN_VAL_IMAGES = 40
#: when fine-tuning, cross-validation's thresholds replace the base model's only if they score better by more than this many balls
PRIOR_MARGIN_BALLS = 2
#: ``TrainOptions.keep_base`` / ``rt2 train --keep-base``: may fine-tuning end with the base model unchanged?
KEEP_BASE_CHOICES = ("auto", "never")
#: ``TrainOptions.learned`` / ``rt2 train --learned``: train the learned detector stage too?
LEARNED_CHOICES = ("auto", "on", "off")
#: ``TrainOptions.filter`` / ``rt2 train --filter``: fit the 5x5 filter, keep the base model's, or choose (see TrainOptions)
FILTER_CHOICES = ("auto", "fit", "keep")
#: how the learned stage's cross-validation folds images (:func:`learned_folds`)
LEARNED_FOLDS_BY = ("auto", "time", "camera")
#: where a model file's description turns from its filter to its learned stage (written here; ``rt2 train-shipped``
#: reads a base's filter part up to it)
LEARNED_MARK = "; learned stage: "
#: ``learned_folds_by`` "auto" folds by camera when every image names one of at least this many cameras
CAMERA_FOLDS_MIN_CAMERAS = 3
#: rt2 train's exit status when the model it chose finds too few balls in cross-validation (not written without --force)
EXIT_WEAK_MODEL = 3
#: the cross-validated recall below which rt2 train does not write the model (without --force)
MIN_WRITE_RECALL = 0.5


#: a fine-tune's optimiser steps at most (the learned stage's; 3/8 of ``--learned-steps`` below that)
FINETUNE_STEPS = 150
#: ``--learned-mined auto``: when the chosen stage's single images are off the ball in more than this share of the
#: cross-validation's images (a fixed false alarm of the camera, a lamp, outranks the ball), each of the stage's fits
#: is continued with ``MINED_SHARE`` of its patches near its own false alarms (``learned_train.continue_steps``), and
#: the better of the two by the cross-validation kept (the first on a tie)
MINE_WHEN_OUTLIERS = 0.2
MINED_SHARE = 0.3


def _check_workers(workers) -> None:
    """``--workers`` (``TrainOptions.workers``): None (by the fits' length) or an integer >= 1; else ValueError."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"--workers must be an integer >= 1, got {workers!r}")


#: ``rt2 train``'s options, by the :class:`TrainOptions` field each fills
TRAIN_FLAGS = {"epochs": "--epochs", "seed": "--seed", "val_fraction": "--val-fraction", "input_transform": "--input-transform",
               "ball_colour": "--ball-colour", "core_fraction": "--core-fraction", "augment_copies": "--augment",
               "threshold_choice": "--thresholds", "cv_folds": "--cv-folds", "verifier": "--verifier", "keep_base": "--keep-base",
               "learned": "--learned", "learned_folds": "--learned-folds", "learned_folds_by": "--learned-folds-by",
               "learned_steps": "--learned-steps", "learned_mined": "--learned-mined", "filter": "--filter", "allow_no_ball": "--force",
               "workers": "--workers"}


@dataclass(frozen=True)
class TrainOptions:
    """Options of :func:`train`.

    epochs : rounds of (hard-negative mining, L-BFGS fit, validation); the best epoch is kept
    val_fraction : share of the frame-set groups held out for validation and threshold choice
    input_transform, log_offset_dn : the model's per-channel input transform (see ``BallSegmentationModel``)
    random_negatives_per_image, hard_negatives_per_image, max_positives_per_image : samples per image
    hard_weight : share of the background half of the loss given to the mined hard negatives
    ring_px : width of the ignored ring around each inscribed ball disk, px
    core_fraction : ball pixels are those within this fraction of the inscribed disk's radius
    l2 : weight of the L2 penalty on the (standardised) kernel
    lbfgs_iters : L-BFGS iterations per epoch
    min_diameter_px : recall on validation counts balls at least this wide
    ball_colour : train for balls of this colour only ("any", "orange", "white"); the others are background
    seed : seeds the split, the sampling, the augmentation and torch
    augment_copies : augmented copies of every training image (:mod:`harness.experiments.detector.augment`:
        colour, exposure, gamma, blur, noise, JPEG, scale, flips); 0 = none
    verifier : also train a candidate verifier (:mod:`harness.experiments.detector.verifier_train`) on the
        filter's candidates, its threshold by cross-validation, and store it in the model
    finetune_l2 : weight of the L2 penalty towards the base model's weights when fine-tuning (replaces ``l2``;
        stronger, so a few labelled images adjust the base rather than replace it)
    threshold_choice : "auto", "split" or "cv" (see :func:`train`)
    cv_folds : folds of the "cv" threshold choice
    keep_base : when fine-tuning, "auto" writes the base model unchanged (weights and thresholds) unless the
        fine-tuned one scores better than the base on the held-out images (cross-validation's out-of-fold
        images, or the validation split) by more than ``PRIOR_MARGIN_BALLS`` balls' worth; "never" always
        writes the fine-tuned one (the behaviour before the guard)
    learned : "auto" also trains the learned detector stage (:mod:`harness.experiments.detector.learned_train`:
        no stage (the filter alone), the base's stage as it is, fine-tuned, or from scratch, chosen by
        cross-validation, the base's stage kept unless another scores more than one labelled ball better; ``rt2
        train``'s default); "on" the same without "no stage" among the choices; "off" (the default of this function: the filter studies) writes the filter alone (and drops
        a base model's stage)
    learned_folds : folds of the learned stage's cross-validation
    learned_folds_by : "time" (time-contiguous folds of whole frame sets, :func:`cv_folds`), "camera" (each fold whole
        cameras: every fit scored on cameras it never saw) or "auto" (default): by camera when every image names one of
        at least ``CAMERA_FOLDS_MIN_CAMERAS`` cameras (a rig's labels, ``rt2 label --auto``), else by time
        (:func:`learned_folds`)
    learned_steps : optimiser steps of a learned stage from scratch (fine-tuning takes 3/8 of them, at most
        ``FINETUNE_STEPS``: a few labels pull a shipped network away from what it knew)
    learned_mined : the share of a learned stage's training patches (fine-tuned or from scratch) centred on its own
        false alarms in the labelled images, mined at a third and two thirds of its steps (0 = none;
        :func:`harness.experiments.detector.learned_train.mine_false_peaks`), or "auto" (default): none, and where the
        chosen stage's single images are off the ball in more than ``MINE_WHEN_OUTLIERS`` of the cross-validation's
        images, each of its fits continued with ``MINED_SHARE`` (mined before its first step and half way), the better
        of the two by the cross-validation kept
    filter : the 5x5 filter (Algorithm 1's model): "fit" trains it as above; "keep" writes the base model's filter
        unchanged (needs a base and ``learned`` "auto" or "on": something must be trained); "auto" (default) keeps it when the
        learned stage is trained too and the base's stage does not take the filter's refinement
        (``LearnedStage.filter_refines`` False: the filter is of another ball, as the shipped white model's orange
        filter, or of another look, as the real-camera orange model's filter of renders; fitting it to these labels
        takes minutes for a filter ``rt2`` does not use on this ball), else fits it
    allow_no_ball : keep a threshold choice that finds no held-out ball when none does (the model written finds
        nothing, its figures say so: ``rt2 train --force``); False = :class:`NoBallFoundError`
    workers : processes the learned stage's cross-validation fits run on (1 = this process; None = by their length,
        ``rt2 train``'s default: :func:`harness.experiments.detector.learned_train.auto_workers`); the model written
        does not depend on it
    """

    epochs: int = 6
    val_fraction: float = 0.2
    input_transform: str = "log"
    log_offset_dn: float = 8.0
    random_negatives_per_image: int = 300
    hard_negatives_per_image: int = 40
    max_positives_per_image: int = 300
    hard_weight: float = 0.5
    ring_px: float = 1.5
    core_fraction: float = 0.6
    l2: float = 1e-4
    lbfgs_iters: int = 40
    min_diameter_px: float = 6.0
    ball_colour: str = "any"
    seed: int = 0
    augment_copies: int = 0
    verifier: bool = False
    finetune_l2: float = 1e-2
    threshold_choice: str = "auto"
    cv_folds: int = 4
    keep_base: str = "auto"
    learned: str = "off"
    learned_folds: int = 3
    learned_folds_by: str = "auto"
    learned_steps: int = 1600
    learned_mined: float | str = "auto"
    filter: str = "auto"
    allow_no_ball: bool = False
    workers: int | None = 1

    @classmethod
    def from_flags(cls, **given) -> "TrainOptions":
        """``rt2 train``'s options, ``given`` by field; a bad value's error names the command's option
        (``TRAIN_FLAGS``), not the field it fills."""
        with named_by_options("TrainOptions", TRAIN_FLAGS, {"TrainOptions.filter 'keep' with learned 'off'": "--filter keep with --learned off"}):
            return cls(**given)

    def __post_init__(self):
        _check_workers(self.workers)
        if not isinstance(self.allow_no_ball, bool):
            raise ValueError(f"TrainOptions.allow_no_ball must be True or False, got {self.allow_no_ball!r}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"TrainOptions.val_fraction must be in (0, 1), got {self.val_fraction!r}")
        for name in ("epochs", "random_negatives_per_image", "max_positives_per_image", "lbfgs_iters"):
            if getattr(self, name) < 1:
                raise ValueError(f"TrainOptions.{name} must be >= 1, got {getattr(self, name)!r}")
        if self.hard_negatives_per_image < 0 or self.ring_px < 0 or self.l2 < 0 or not self.finetune_l2 >= 0:
            raise ValueError("TrainOptions: hard_negatives_per_image, ring_px, l2 and finetune_l2 must be >= 0")
        if not 0.0 < self.core_fraction <= 1.0:
            raise ValueError(f"TrainOptions.core_fraction must be in (0, 1], got {self.core_fraction!r}")
        if not 0.0 <= self.hard_weight < 1.0:
            raise ValueError(f"TrainOptions.hard_weight must be in [0, 1), got {self.hard_weight!r}")
        if self.ball_colour not in BALL_COLOURS:
            raise ValueError(f"TrainOptions.ball_colour must be one of {BALL_COLOURS}, got {self.ball_colour!r}")
        if self.input_transform not in INPUT_TRANSFORMS:
            raise ValueError(f"TrainOptions.input_transform must be one of {INPUT_TRANSFORMS}, got {self.input_transform!r}")
        if self.threshold_choice not in THRESHOLD_CHOICES:
            raise ValueError(f"TrainOptions.threshold_choice must be one of {THRESHOLD_CHOICES}, got {self.threshold_choice!r}")
        if isinstance(self.augment_copies, bool) or not isinstance(self.augment_copies, int) or self.augment_copies < 0:
            raise ValueError(f"TrainOptions.augment_copies must be an integer >= 0, got {self.augment_copies!r}")
        if self.keep_base not in KEEP_BASE_CHOICES:
            raise ValueError(f"TrainOptions.keep_base must be one of {KEEP_BASE_CHOICES}, got {self.keep_base!r}")
        if isinstance(self.cv_folds, bool) or not isinstance(self.cv_folds, int) or self.cv_folds < 2:
            raise ValueError(f"TrainOptions.cv_folds must be an integer >= 2, got {self.cv_folds!r}")
        if self.learned not in LEARNED_CHOICES:
            raise ValueError(f"TrainOptions.learned must be one of {LEARNED_CHOICES}, got {self.learned!r}")
        if isinstance(self.learned_folds, bool) or not isinstance(self.learned_folds, int) or self.learned_folds < 2:
            raise ValueError(f"TrainOptions.learned_folds must be an integer >= 2, got {self.learned_folds!r}")
        if self.learned_folds_by not in LEARNED_FOLDS_BY:
            raise ValueError(f"TrainOptions.learned_folds_by must be one of {LEARNED_FOLDS_BY}, got {self.learned_folds_by!r}")
        if isinstance(self.learned_steps, bool) or not isinstance(self.learned_steps, int) or self.learned_steps < 1:
            raise ValueError(f"TrainOptions.learned_steps must be a positive integer, got {self.learned_steps!r}")
        v = self.learned_mined
        if v != "auto" and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0):
            raise ValueError(f"TrainOptions.learned_mined must be 'auto' or a share between 0 and 1, got {v!r}")
        if self.filter not in FILTER_CHOICES:
            raise ValueError(f"TrainOptions.filter must be one of {FILTER_CHOICES}, got {self.filter!r}")
        if self.filter == "keep" and self.learned == "off":
            raise ValueError("TrainOptions.filter 'keep' with learned 'off' trains nothing: keep the filter only while training the learned stage")


# -- data ------------------------------------------------------------------------------------------
def load_image(labelled) -> np.ndarray:
    """Read a labelled image as (H, W, 3) uint8 RGB, checking it against the label's width and height."""
    path = str(labelled.path)
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: cannot read the image (missing, or not an image format OpenCV reads)")
    if image.shape[:2] != (labelled.height, labelled.width):
        raise ValueError(
            f"{path}: image is {image.shape[1]}x{image.shape[0]} but its COCO entry says width={labelled.width}, height={labelled.height}"
        )
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def pixel_targets(labelled, ring_px: float = 1.5, core_fraction: float = 1.0) -> np.ndarray:
    """(H, W) int8 targets: 1 ball, -1 ignored, 0 background.

    Ball: pixels whose centre lies within ``core_fraction * r - 0.5`` of the centre of the disk
    inscribed in a box (radius ``r``); ignored: the rest of the box and a ``ring_px`` ring around it.
    """
    h, w = labelled.height, labelled.width
    target = np.zeros((h, w), np.int8)
    for x, y, bw, bh in labelled.boxes_xywh:
        x0, y0 = max(int(math.floor(x - ring_px)), 0), max(int(math.floor(y - ring_px)), 0)
        x1, y1 = min(int(math.ceil(x + bw + ring_px)), w), min(int(math.ceil(y + bh + ring_px)), h)
        if x0 >= x1 or y0 >= y1:
            continue
        # pixel (c, r) spans [c, c + 1] in COCO coordinates: its centre is (c + 0.5, r + 0.5)
        cols = np.arange(x0, x1) + 0.5
        rows = np.arange(y0, y1) + 0.5
        cu, cv, r = x + bw / 2, y + bh / 2, min(bw, bh) / 2
        d = np.hypot(cols[None, :] - cu, rows[:, None] - cv)
        sub = target[y0:y1, x0:x1]
        sub[sub == 0] = -1  # box + ring: ignored unless another ball claims it
        sub[d <= core_fraction * r - 0.5] = 1  # pixels essentially inside the (core of the) inscribed disk
    return target


def ball_colour(image: np.ndarray, box_xywh) -> str:
    """"orange" (a saturated ball) or "white", from the mean colour of the box's inscribed-disk core.

    The saturation ``(max - min) / max`` of that mean is above 0.65 for orange balls and below 0.15 for
    white ones in our renderer's data (shading, blur and exposure included); the cut is at ``COLOUR_SATURATION_CUT``.
    """
    h, w = image.shape[:2]
    x, y, bw, bh = (float(v) for v in box_xywh)
    r = 0.6 * min(bw, bh) / 2
    cols, rows = np.arange(w) + 0.5, np.arange(h) + 0.5
    c0, c1 = max(int(x), 0), min(int(math.ceil(x + bw)), w)
    r0, r1 = max(int(y), 0), min(int(math.ceil(y + bh)), h)
    d = np.hypot(cols[None, c0:c1] - (x + bw / 2), rows[r0:r1, None] - (y + bh / 2))
    px = image[r0:r1, c0:c1][d <= max(r, 0.75)].astype(np.float64)
    if len(px) == 0:
        return "white"
    m = px.mean(axis=0)
    return "orange" if (m.max() - m.min()) / max(m.max(), 1.0) > COLOUR_SATURATION_CUT else "white"


def select_ball_colour(labelled, colour: str, *, progress: bool = False):
    """Keep only the boxes of balls of ``colour`` ("any", "orange" or "white"): the colour a box's label declares
    (:attr:`LabelledImage.ball_colours`, the annotation's ``ball_colour``), else the one measured (:func:`ball_colour`).

    Balls of the other colour lose their boxes: for training they become background (an orange-ball
    model must not fire on white balls), for evaluation detections on them count as outliers.
    """
    from harness.common.progress import progress_bar

    if colour not in BALL_COLOURS:
        raise ValueError(f"ball colour must be one of {BALL_COLOURS}, got {colour!r}")
    if colour == "any":
        return list(labelled)
    out = []
    for li in progress_bar(labelled, desc=f"selecting {colour} balls", unit="img", disable=not progress, leave=False):
        if li.n_balls == 0:
            out.append(li)
            continue
        declared = li.ball_colours or (None,) * li.n_balls
        image = load_image(li) if None in declared else None
        keep = np.array([(c if c is not None else ball_colour(image, box)) == colour for c, box in zip(declared, li.boxes_xywh)])
        out.append(li.only(keep))
    return out


def colour_note(before, after, colour: str, what: str) -> str | None:
    """One line saying how many labelled balls of ``before`` :func:`select_ball_colour` left out for their measured colour
    (``after`` is what it kept) and what became of them (``what``); None where it left none out so (a ball left out
    by its label's ``ball_colour`` is what its label says)."""
    dropped = sum(li.n_balls for li in before) - sum(li.n_balls for li in after)
    said = sum(1 for li in before for c in li.ball_colours if c is not None and c != colour)
    if dropped - said <= 0:
        return None
    return (f"{dropped - said} of the {sum(li.n_balls for li in before)} labelled balls measure as not {colour} "
            f"(docs/detector.md, \"Ball colour\"): {what}; a label's \"ball_colour\": \"{colour}\" keeps a ball, "
            f"--ball-colour any keeps every ball")


def split_groups(labelled, val_fraction: float, rng: np.random.Generator):
    """Split images into (train, val) lists, keeping the cameras of one frame set together."""
    groups: dict[str, list] = {}
    for li in labelled:
        groups.setdefault(_group_key(li), []).append(li)
    keys = sorted(groups)
    if len(keys) < 2:
        raise ValueError(f"need images from at least 2 frame sets to hold out a validation split, got {len(keys)}")
    n_val = min(max(1, int(round(val_fraction * len(keys)))), len(keys) - 1)
    order = rng.permutation(len(keys))
    val_keys = {keys[i] for i in order[:n_val]}
    train = [li for k in keys if k not in val_keys for li in groups[k]]
    val = [li for k in keys if k in val_keys for li in groups[k]]
    return train, val


def _patches(padded: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(n, 75) uint8 patches ``P[i, j, c] = image[row + i - 2, col + j - 2, c]`` (padded by 2, REFLECT_101)."""
    di = np.arange(5)
    return padded[rows[:, None, None] + di[None, :, None], cols[:, None, None] + di[None, None, :]].reshape(len(rows), 75)


def _pad(image):
    return cv2.copyMakeBorder(image, 2, 2, 2, 2, cv2.BORDER_REFLECT_101)


def _sample_image(image, target, opts: TrainOptions, rng):
    pos_r, pos_c = np.nonzero(target == 1)
    if len(pos_r) > opts.max_positives_per_image:
        keep = rng.choice(len(pos_r), opts.max_positives_per_image, replace=False)
        pos_r, pos_c = pos_r[keep], pos_c[keep]
    neg = np.flatnonzero(target.reshape(-1) == 0)
    neg = rng.choice(neg, min(opts.random_negatives_per_image, len(neg)), replace=False)
    padded = _pad(image)
    w = image.shape[1]
    return _patches(padded, pos_r, pos_c), _patches(padded, neg // w, neg % w)


def _hard_negatives(model: BallSegmentationModel, image, target, n: int, t_high: float, t_low: float, blob_kw: dict) -> np.ndarray:
    """Patches of the wrong candidates our detector would report now (shape test passed), best pixels first.

    Ball and ignored pixels are masked out; each of up to 4 candidate blobs gives up to ``n // 4``
    of its highest-logit pixels. Large same-coloured regions that the shape test rejects anyway are
    not mined: the filter cannot tell their inside from a ball's, and needs not.
    """
    lg = model.logits(image)
    lg[target != 0] = -np.inf  # ball and ignored pixels are not negatives
    blobs = find_blobs(lg, logit(t_high), logit(t_low), max_blobs=4, **blob_kw)
    per_blob = max(n // 4, 1)
    rows, cols = [], []
    for x0, y0, x1, y1 in blobs.boxes:
        sub = lg[y0 : y1 + 1, x0 : x1 + 1]
        flat = np.flatnonzero(sub.reshape(-1) > logit(t_low))
        take = flat[np.argsort(-sub.reshape(-1)[flat], kind="stable")[:per_blob]]
        rows.append(y0 + take // sub.shape[1])
        cols.append(x0 + take % sub.shape[1])
    if not rows:
        return np.zeros((0, 75), np.uint8)
    return _patches(_pad(image), np.concatenate(rows), np.concatenate(cols))


# -- fitting ---------------------------------------------------------------------------------------
def _to_model(w, b, norm, opts: TrainOptions, t_high=0.5, t_low=0.2, area_range_px=(3.0, 3000.0), description=""):
    scale, offset = norm
    return BallSegmentationModel(
        kernel=np.asarray(w, np.float64).reshape(5, 5, 3),
        bias=float(b),
        colour_order="RGB",
        input_scale=scale,
        input_offset=offset,
        input_transform=opts.input_transform,
        log_offset_dn=opts.log_offset_dn,
        t_high=t_high,
        t_low=t_low,
        area_range_px=area_range_px,
        description=description,
        ball_colour=opts.ball_colour,
    )


def _fit(torch, w, b, sets, opts: TrainOptions, prior=None) -> float:
    """Class-balanced BCE + L2 by full-batch L-BFGS, in place on ``w`` (75,) and ``b`` (1,).

    sets : (features, label, weight) triples; the weights of the ball and background sets sum to 1/2 each
    prior : (75,) weights the L2 penalty pulls towards (a base model's, when fine-tuning); None = zero
    """
    bce = torch.nn.functional.binary_cross_entropy_with_logits
    opt = torch.optim.LBFGS([w, b], lr=1.0, max_iter=opts.lbfgs_iters, line_search_fn="strong_wolfe")
    terms = [(torch.from_numpy(x), torch.full((len(x),), float(y), dtype=torch.float64), wt) for x, y, wt in sets if len(x) and wt > 0]

    def loss_fn():
        d = w if prior is None else w - prior  # fine-tuning pulls towards the base model's weights
        return sum(wt * bce(x @ w + b, y) for x, y, wt in terms) + opts.l2 * (d * d).sum()

    def closure():
        opt.zero_grad()
        loss = loss_fn()
        loss.backward()
        return loss

    opt.step(closure)
    with torch.no_grad():
        return float(loss_fn())


def _area_range(labelled) -> tuple[float, float]:
    """Loose blob-area limits from the labelled balls: a quarter of the smallest disk to twice the largest box."""
    boxes = np.concatenate([li.boxes_xywh for li in labelled])
    d_min = float(np.minimum(boxes[:, 2], boxes[:, 3]).min())
    return max(2.0, 0.25 * math.pi / 4 * d_min**2), max(8.0, 2.0 * math.pi / 4 * float((boxes[:, 2] * boxes[:, 3]).max()))


def _ball_blob_areas(val_logits, truth, t_low: float, loose_area, opts: TrainOptions) -> np.ndarray:
    """Areas of the blobs (at ``T_l``, peak above ``T_l``) that sit on a labelled ball of at least min_diameter_px."""
    areas = []
    tl = logit(t_low)
    for lg, c, d in zip(val_logits, *truth):
        if len(c) == 0:
            continue
        b = find_blobs(lg, tl + 1e-3, tl, max_blobs=4, max_seeds=16, min_area_px=loose_area[0], max_area_px=loose_area[1])
        if len(b):
            near = np.linalg.norm(b.centers_px[:, None] - c[None], axis=2) <= d[None]
            areas += list(b.areas_px[near[:, d >= opts.min_diameter_px].any(axis=1)])
    return np.asarray(areas, float)


def _top1_per_threshold(val_logits, t_low: float, t_high_min: float, blob_kw: dict):
    """Per image (peak logit, centre) of the paper's argmax blob and of ours' first accepted blob at ``T_l``.

    Candidates come best first and a higher ``T_h`` only cuts the sequence of grown blobs earlier, so
    the result at any ``T_h >= t_high_min`` is these with ``peak >= logit(T_h)`` kept.
    """
    tl, th = logit(t_low), logit(t_high_min)
    paper, ours = [], []
    for lg in val_logits:
        b = find_blobs(lg, th, tl, max_blobs=1, max_seeds=1)
        paper.append((b.peak_logits[0], b.centers_px[0]) if len(b) else (-np.inf, None))
        b = find_blobs(lg, th, tl, max_blobs=1, **blob_kw)
        ours.append((b.peak_logits[0], b.centers_px[0]) if len(b) else (-np.inf, None))
    return paper, ours


class NoBallFoundError(ValueError):
    """No threshold choice of the grid finds a single held-out ball (:func:`choose_thresholds`): a model written with
    any of them would report nothing where the labels show balls."""


def finds_a_ball(s) -> bool:
    """Whether the scores ``s`` hit at least one ball (or there is none to hit: no ball of at least ``min_diameter_px``).

    A choice that reports nothing scores ``recall - outlier_rate = 0 - 0``: more than any detector whose wrong reports
    outnumber its hits (one fixed object that the filter scores above the ball is enough), so the net score alone would
    prefer a model that finds nothing. A threshold choice that finds no ball ranks below every one that finds some.
    """
    return s.n_balls == 0 or np.nan_to_num(s.recall) > 0


def choose_thresholds(val_logits, truth, loose_area, opts: TrainOptions):
    """Pick (T_h, T_l) and the blob-area range on validation images for our detector's best candidate.

    For each ``T_l`` of ``T_LOW_GRID`` the area range is [half the 1st, 1.5 x the 99th percentile] of
    the ball blobs' areas (within ``loose_area``); then ``T_h`` (> ``T_l``, from ``T_HIGH_GRID``) and
    ``T_l`` maximise ``recall - outlier_rate`` (misses and wrong reports cost the same) among the choices
    that find a ball (:func:`finds_a_ball`), ties going to the lower median centre error. Returns
    ``(t_high, t_low, area_range_px, ours_scores, paper_scores)``; raises :class:`NoBallFoundError` (naming
    the grid) when no choice finds any validation ball, rather than return one that reports nothing (unless
    ``opts.allow_no_ball``: then the best of them, whose scores say it finds nothing).
    """
    from harness.experiments.detector.scores import score_detections

    opt = DetectorOptions()

    def score(method, results, th):
        uv = [c[None] if c is not None and peak >= logit(th) else np.zeros((0, 2)) for peak, c in results]
        return score_detections(method, *truth, uv, min_diameter_px=opts.min_diameter_px)

    best = None
    for tl in T_LOW_GRID:
        areas = _ball_blob_areas(val_logits, truth, tl, loose_area, opts)
        area = (max(2.0, 0.5 * np.percentile(areas, 1)), 1.5 * np.percentile(areas, 99)) if len(areas) >= 5 else loose_area
        blob_kw = dict(max_seeds=opt.max_seeds, min_area_px=area[0], max_area_px=area[1], min_fill_ratio=opt.min_fill_ratio, max_aspect=opt.max_aspect)
        ths = [th for th in T_HIGH_GRID if th > tl]
        paper, ours = _top1_per_threshold(val_logits, tl, min(ths), blob_kw)
        for th in ths:
            s = score("ours", ours, th)
            key = (finds_a_ball(s), np.nan_to_num(s.recall) - s.outlier_rate, -np.nan_to_num(s.median_center_error_px, nan=np.inf))
            if best is None or key > best[0]:
                best = (key, th, tl, area, s, paper)
    (found, _, _), t_high, t_low, area, s_ours, paper = best
    if not found and not opts.allow_no_ball:
        raise NoBallFoundError(
            f"no threshold finds a ball: at every T_h ({min(T_HIGH_GRID):.3g}-{max(T_HIGH_GRID):.3g}) and T_l ({min(T_LOW_GRID):.3g}-"
            f"{max(T_LOW_GRID):.3g}) the detector's best candidate misses all {s_ours.n_balls} held-out balls of {len(val_logits)} images")
    return t_high, t_low, area, s_ours, score("paper", paper, t_high)


def _net_gain(s, b) -> float:
    """Recall minus outlier rate of the scores ``s`` over those of ``b`` (a recall of NaN, no ball, counts 0): what
    the base model's thresholds and the base model itself must be beaten by (``PRIOR_MARGIN_BALLS``). Scores that
    find a ball beat scores that find none by any margin (+inf; -inf the other way round: :func:`finds_a_ball`)."""
    if finds_a_ball(s) != finds_a_ball(b):
        return math.inf if finds_a_ball(s) else -math.inf
    return (np.nan_to_num(s.recall) - s.outlier_rate) - (np.nan_to_num(b.recall) - b.outlier_rate)


def score_thresholds(val_logits, truth, t_high: float, t_low: float, area, opts: TrainOptions):
    """(ours, paper) scores of fixed thresholds and area range on validation logits (best candidate per image)."""
    from harness.experiments.detector.scores import score_detections

    opt = DetectorOptions()
    blob_kw = dict(max_seeds=opt.max_seeds, min_area_px=area[0], max_area_px=area[1], min_fill_ratio=opt.min_fill_ratio, max_aspect=opt.max_aspect)
    paper, ours = _top1_per_threshold(val_logits, t_low, t_high, blob_kw)
    found = lambda results: [c[None] if c is not None else np.zeros((0, 2)) for _, c in results]  # noqa: E731
    return (score_detections("ours", *truth, found(ours), min_diameter_px=opts.min_diameter_px),
            score_detections("paper", *truth, found(paper), min_diameter_px=opts.min_diameter_px))


def _features(patches, lut, norm) -> np.ndarray:
    scale, offset = norm
    return lut[patches] * np.tile(scale, 25) + np.tile(offset, 25)


def _group_key(li) -> str:
    return str(Path(li.path).parent / re.sub(r"_cam\d+$", "", Path(li.path).stem))


def cv_folds(labelled, n_folds: int) -> list[list[int]]:
    """Indices of ``labelled`` in ``n_folds`` folds of whole frame sets, contiguous in time order
    (:func:`harness.experiments.detector.subsets.time_order`): near-copies of a video's consecutive
    frames stay in one fold, so a fold's figures are those of frames its model did not see."""
    from harness.experiments.detector.subsets import time_key

    groups: dict[str, list[int]] = {}
    for i, li in enumerate(labelled):
        groups.setdefault(_group_key(li), []).append(i)
    keys = sorted(groups, key=lambda k: (str(Path(k).parent), time_key(k)))
    n = min(n_folds, len(keys))
    if n < 2:
        raise ValueError(f"cross-validation needs images from at least 2 frame sets, got {len(keys)}")
    bounds = np.linspace(0, len(keys), n + 1).round().astype(int)
    return [[i for k in keys[bounds[f] : bounds[f + 1]] for i in groups[k]] for f in range(n)]


def camera_folds(labelled, n_folds: int) -> list[list[int]]:
    """Indices of ``labelled`` in up to ``n_folds`` folds of whole cameras (:func:`~harness.experiments.detector.subsets.
    image_camera`; the cameras in name order dealt round the folds): a fold's figures are those of cameras its model
    never saw. ValueError naming the files when an image names no camera, or when fewer than 2 cameras are named."""
    cams = [image_camera(li) for li in labelled]
    unnamed = [str(li.path) for li, c in zip(labelled, cams) if not c]
    if unnamed:
        raise ValueError(f"--learned-folds-by camera needs every image's camera (the COCO image field 'camera', or a name like "
                         f"f000012_cam2.png); {len(unnamed)} images name none, e.g. {unnamed[0]!r}")
    names = sorted(set(cams))
    if len(names) < 2:
        raise ValueError(f"--learned-folds-by camera needs images of at least 2 cameras, got {', '.join(names)}")
    n = min(n_folds, len(names))
    fold_of = {name: k % n for k, name in enumerate(names)}
    folds: list[list[int]] = [[] for _ in range(n)]
    for i, c in enumerate(cams):
        folds[fold_of[c]].append(i)
    return folds


def learned_folds(labelled, n_folds: int, by: str = "auto") -> tuple[list[list[int]], str]:
    """The learned stage's cross-validation folds and what they are (``"time"`` or ``"camera"``): ``by`` "time" is
    :func:`cv_folds`, "camera" :func:`camera_folds`, "auto" by camera when every image names one of at least
    ``CAMERA_FOLDS_MIN_CAMERAS`` cameras, else by time.

    Why by camera: a rig's labels (``rt2 label --auto``) hold every camera at every time, so a time fold's model has
    seen each camera's view; scored on cameras it never saw, the choice between the shipped, fine-tuned and new
    stage is of the one that carries to a view it did not learn (the auto labels of caliscope cameras 0-2 with the
    orange model for real cameras: by time a stage from scratch won, which found fewer of camera 3's balls than the
    shipped stage; by camera the fine-tune won, README "Labels for free")."""
    if by not in LEARNED_FOLDS_BY:
        raise ValueError(f"learned folds by must be one of {LEARNED_FOLDS_BY}, got {by!r}")
    if by == "auto":
        cams = [image_camera(li) for li in labelled]
        by = "camera" if all(cams) and len(set(cams)) >= CAMERA_FOLDS_MIN_CAMERAS else "time"
    return (camera_folds(labelled, n_folds) if by == "camera" else cv_folds(labelled, n_folds)), by


class _Fitter:
    """One fit of the filter (sampling, hard negatives per epoch, L-BFGS) on in-memory ``(image, labelled)`` items."""

    def __init__(self, torch, opts: TrainOptions, base: BallSegmentationModel | None, rng, progress: bool):
        self.torch, self.opts, self.base, self.rng, self.progress = torch, opts, base, rng, progress
        self.lut = transform_lut(opts.input_transform, opts.log_offset_dn).astype(np.float64)

    def fit(self, items, val=None, log=print, label: str = ""):
        """Fit on ``items``; with ``val`` items, choose thresholds there after every epoch and keep the best epoch.

        Returns dict(w, b, norm, t_high, t_low, area, ours, paper, epoch, history, n_pos, n_neg, n_hard, loose_area).
        """
        from tqdm import tqdm

        from harness.common.progress import progress_bar
        from harness.experiments.detector.scores import truth_of

        torch, opts, rng = self.torch, self.opts, self.rng
        if not any(li.n_balls for _, li in items):
            raise ValueError(f"no ball boxes among the {len(items)} training images: nothing to learn")
        targets = [pixel_targets(li, opts.ring_px, opts.core_fraction) for _, li in items]
        pos, neg = [], []
        for (im, _), tg in zip(items, targets):
            p, n = _sample_image(im, tg, opts, rng)
            pos.append(p)
            neg.append(n)
        pos, neg = np.concatenate(pos), np.concatenate(neg)
        lut = self.lut
        if self.base is not None:  # fine-tune: the base model's input scaling, weights as the start and the prior
            norm = (np.asarray(self.base.input_scale, np.float64), np.asarray(self.base.input_offset, np.float64))
            w0 = np.asarray(self.base.kernel, np.float64).reshape(75)
            b0 = float(self.base.bias)
        else:
            # Standardise each transformed channel (the two classes' means and spreads averaged, like the loss).
            tp, tn = lut[pos.reshape(-1, 3)], lut[neg.reshape(-1, 3)]
            mean = 0.5 * (tp.mean(0) + tn.mean(0))
            std = np.sqrt(0.5 * (tp.var(0) + tn.var(0))) + 1e-3
            norm = (1.0 / std, -mean / std)
            w0, b0 = np.zeros(75), 0.0
        xp, xn = _features(pos, lut, norm), _features(neg, lut, norm)
        xh = np.zeros((0, 75))
        loose_area = _area_range([li for _, li in items if li.n_balls])
        if self.base is not None:
            base_area = tuple(float(v) for v in self.base.area_range_px)
            loose_area = (min(loose_area[0], base_area[0]), max(loose_area[1], base_area[1]))
        w = torch.tensor(w0, dtype=torch.float64, requires_grad=True)
        b = torch.tensor([b0], dtype=torch.float64, requires_grad=True)
        prior = torch.tensor(w0, dtype=torch.float64)
        history, best = [], None
        t_high, t_low = (self.base.t_high, self.base.t_low) if self.base is not None else (0.5, 0.2)
        area = loose_area
        s_ours = s_paper = None
        if val is not None:
            val_images = [im for im, _ in val]
            truth = ([truth_of(li)[0] for _, li in val], [truth_of(li)[1] for _, li in val])
        bar = progress_bar(range(opts.epochs), desc=f"train{label}", unit="epoch", disable=not self.progress, leave=False)
        for epoch in bar:
            if (epoch > 0 or self.base is not None) and opts.hard_negatives_per_image > 0:  # mine our detector's current mistakes
                current = _to_model(w.detach().numpy(), b.item(), norm, opts)
                opt = DetectorOptions()
                kw = dict(max_seeds=opt.max_seeds, min_area_px=area[0], max_area_px=area[1], min_fill_ratio=opt.min_fill_ratio, max_aspect=opt.max_aspect)
                hard = [_hard_negatives(current, im, tg, opts.hard_negatives_per_image, t_high, t_low, kw) for (im, _), tg in zip(items, targets)]
                xh = np.concatenate([xh, _features(np.concatenate(hard), lut, norm)])
            h = opts.hard_weight if len(xh) else 0.0
            fit_opts = opts if self.base is None else dataclasses.replace(opts, l2=opts.finetune_l2)
            loss = _fit(torch, w, b, [(xp, 1, 0.5), (xn, 0, 0.5 * (1 - h)), (xh, 0, 0.5 * h)], fit_opts, prior)
            j = -epoch  # without validation: the last epoch
            if val is None:
                line = f"epoch {epoch + 1}/{opts.epochs}{label}: loss {loss:.4f}  hard negatives {len(xh)}"
                tqdm.write(line) if self.progress else log(line)
            else:
                current = _to_model(w.detach().numpy(), b.item(), norm, opts)
                try:
                    t_high, t_low, area, s_ours, s_paper = choose_thresholds([current.logits(im) for im in val_images], truth, loose_area, opts)
                except NoBallFoundError as exc:  # this epoch's filter is no candidate; the thresholds stay for the next mining
                    failure, j = exc, -np.inf
                    line = f"epoch {epoch + 1}/{opts.epochs}{label}: loss {loss:.4f}  hard negatives {len(xh)}  val: {exc}"
                else:
                    j = np.nan_to_num(s_ours.recall) - s_ours.outlier_rate
                    bar.set_postfix(loss=f"{loss:.4f}", recall=f"{s_ours.recall:.3f}", outliers=f"{s_ours.outlier_rate:.3f}")
                    line = (
                        f"epoch {epoch + 1}/{opts.epochs}{label}: loss {loss:.4f}  hard negatives {len(xh)}  val at T_h={t_high:g}, T_l={t_low:g}: "
                        f"ours recall {100 * s_ours.recall:.2f}% outliers {100 * s_ours.outlier_rate:.2f}% median {s_ours.median_center_error_px:.3f} px | "
                        f"paper recall {100 * s_paper.recall:.2f}% outliers {100 * s_paper.outlier_rate:.2f}%"
                    )
                tqdm.write(line) if self.progress else log(line)
            history.append(dict(epoch=epoch + 1, loss=loss, n_hard=len(xh), t_high=t_high, t_low=t_low, area_range_px=area,
                                ours=s_ours if np.isfinite(j) else None, paper=s_paper if np.isfinite(j) else None))
            if best is None or j > best[0] or val is None:
                best = (j, epoch, w.detach().numpy().copy(), b.item(), t_high, t_low, area, s_ours, s_paper)
        if not np.isfinite(best[0]):
            raise NoBallFoundError(f"{failure} (validation split, after each of the {opts.epochs} epochs)")
        _, epoch, w_best, b_best, t_high, t_low, area, s_ours, s_paper = best
        return dict(w=w_best, b=b_best, norm=norm, t_high=t_high, t_low=t_low, area=area, ours=s_ours, paper=s_paper, epoch=epoch + 1,
                    history=history, n_pos=len(xp), n_neg=len(xn), n_hard=len(xh), loose_area=loose_area)


def _items(labelled, opts: TrainOptions, rng, progress: bool, augment_opts=None, backgrounds=()):
    """Images in memory (and the ball-free ``backgrounds``), with ``opts.augment_copies`` augmented copies of each (:mod:`.augment`)."""
    from harness.common.progress import progress_bar
    from harness.experiments.detector.augment import AugmentOptions, augment

    items = [(load_image(li), li) for li in progress_bar(labelled, desc="reading", unit="img", disable=not progress, leave=False)]
    items += list(backgrounds)
    if opts.augment_copies:
        aug = AugmentOptions() if augment_opts is None else augment_opts
        items = items + [augment(im, li, rng, aug) for _ in range(opts.augment_copies) for im, li in items]
    return items


def _resolve_threshold_choice(labelled, opts: TrainOptions) -> str:
    if opts.threshold_choice != "auto":
        return opts.threshold_choice
    n_val_balls = opts.val_fraction * sum(li.n_balls > 0 for li in labelled)
    return "split" if n_val_balls >= AUTO_SPLIT_MIN_VAL_IMAGES else "cv"


def train(labelled, opts: TrainOptions = TrainOptions(), *, progress: bool = True, log=print, description: str = "",
          base: BallSegmentationModel | None = None, backgrounds=()):
    """Fit a :class:`BallSegmentationModel` to labelled images; returns ``(model, info)``.

    labelled : list of ``harness.experiments.detector.coco.LabelledImage`` (boxes of balls; images without boxes = background)
    base : a model to fine-tune (its input scaling, its weights as the start and as the prior the L2
        penalty pulls towards, its thresholds as the start); None trains from scratch
    backgrounds : ``(image, labelled without boxes)`` pairs of ball-free real frames
        (:func:`harness.experiments.detector.backgrounds.read_backgrounds`), added to every fit's
        training images (augmented like them), never to validation
    Threshold choice (``opts.threshold_choice``): "split" holds out ``val_fraction`` of the frame sets
    and keeps the best epoch there; "cv" trains on every image and chooses ``T_h``, ``T_l`` and the
    area range on the pooled out-of-fold logits of ``cv_folds`` models, each trained without one
    time-contiguous fold (:func:`cv_folds`); "auto" is "split" when the split would hold at least
    ``AUTO_SPLIT_MIN_VAL_IMAGES`` images with a ball, else "cv". When fine-tuning with "cv", the base
    model's thresholds and area range are the prior: cross-validation's choice replaces them only if it
    scores better on the out-of-fold logits by more than ``PRIOR_MARGIN_BALLS`` balls' worth, and the
    area range never narrows below the base's.
    info : dict with the split sizes, per-epoch history, the chosen epoch and thresholds and the
        validation (or cross-validation) scores there (ours and paper)
    """
    import torch  # training only

    torch.manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    if base is not None and base.input_transform != opts.input_transform:
        opts = dataclasses.replace(opts, input_transform=base.input_transform, log_offset_dn=base.log_offset_dn)
    # before any image is read: the augmented copies are held where the 5x5 filter is fitted (or a verifier trained),
    # the images themselves always
    kept_filter = keeps_filter(opts, base)
    check_memory(labelled, opts.augment_copies if opts.verifier or not kept_filter else 0, backgrounds)
    # the learned stage's folds, before any image is read (--learned-folds-by camera on labels it cannot fold: one line);
    # the colour's selection below keeps every image, in order
    folds, by = learned_folds(labelled, opts.learned_folds, opts.learned_folds_by) if opts.learned != "off" else (None, None)
    chosen = select_ball_colour(labelled, opts.ball_colour, progress=progress)
    note = colour_note(labelled, chosen, opts.ball_colour, "they are trained as background")
    if note:
        log(note)
    n_labelled = sum(li.n_balls for li in labelled)
    if n_labelled and not any(li.n_balls for li in chosen):  # every ball of another colour: the colour asked is wrong
        raise ValueError(f"--ball-colour {opts.ball_colour}: none of the {n_labelled} labelled balls is {opts.ball_colour} (by its "
                         f"label's ball_colour or its measured colour, docs/detector.md \"Ball colour\"): is the ball of "
                         f"another colour? (--ball-colour any keeps every ball)")
    labelled = chosen
    if kept_filter:
        if base is None:
            raise ValueError("--filter keep keeps the base model's filter: there is no base model (--from none)")
        if not any(li.n_balls for li in labelled):
            raise ValueError(f"no ball boxes among the {len(labelled)} images: nothing to learn")
        why = ("--filter keep" if opts.filter == "keep" else
               "its learned stage does not take the filter's refinement: the filter is of another ball or look; --filter fit trains it")
        log(f"the 5x5 filter: the base model's kept unchanged (T_h={base.t_high:g}, T_l={base.t_low:g}; {why})")
        desc = (f"{description}; " if description else "") + (
            f"{opts.ball_colour} balls, the base model's 5x5 filter kept unchanged ({why}), {len(labelled)} images, seed {opts.seed}")
        model = dataclasses.replace(base, description=desc)
        finfo = dict(n_train=len(labelled), n_val=0, n_pos=0, n_neg=0, n_hard=0, history=[], best_epoch=None, t_high=base.t_high,
                     t_low=base.t_low, area_range_px=tuple(float(v) for v in base.area_range_px), val_ours=None, val_paper=None,
                     threshold_choice="kept", kept_base=False, base_ours=None, filter_kept=True)
    else:
        model, finfo, desc = _fit_filter(torch, labelled, opts, base, rng, progress=progress, log=log, description=description,
                                         backgrounds=backgrounds)
    v_info = None
    if opts.verifier:
        from harness.experiments.detector.augment import augment
        from harness.experiments.detector.verifier_train import VerifierOptions, train_verifier

        vrng = np.random.default_rng([opts.seed, 11])
        originals = [(load_image(li), li) for li in labelled]
        augmented = [(i, *augment(im, li, vrng)) for _ in range(opts.augment_copies) for i, (im, li) in enumerate(originals)]
        verifier, v_info = train_verifier(model, originals, augmented, cv_folds(labelled, opts.cv_folds),
                                          VerifierOptions(cv_folds=opts.cv_folds), seed=opts.seed, log=log, progress=progress)
        s_v = v_info["cv"]
        model = dataclasses.replace(model, verifier=verifier, description=desc + (
            f"; verifier ({verifier.crop_px}x{verifier.crop_px} crops, {verifier.n_hidden} hidden units, threshold {verifier.threshold:g}): "
            f"{len(labelled)}-image cv recall {100 * s_v.recall:.2f}%, outliers {100 * s_v.outlier_rate:.2f}%, "
            f"median {s_v.median_center_error_px:.3f} px; candidates reach {100 * v_info['candidate_recall']:.1f}% of the balls"))
    l_info = None
    if opts.learned != "off":
        from harness.experiments.detector.learned_train import MINE_HEAT, continue_steps, false_alarms, train_stage

        log(f"learned stage: {len(folds)} cross-validation folds by {by}" + (
            "" if by == "time" else " (" + "; ".join(", ".join(sorted({image_camera(labelled[i]) for i in f})) for f in folds) + ")"))
        images = [load_image(li) for li in labelled]

        l_finetune = max(1, min(FINETUNE_STEPS, opts.learned_steps * 3 // 8))

        def stage_of(mined: float, **kw):
            return train_stage(labelled, images, folds, base=None if base is None else base.learned, seed=opts.seed,
                               scratch_steps=opts.learned_steps, finetune_steps=l_finetune,
                               extra=backgrounds, alone=finfo.get("alone") if opts.learned == "auto" else None, mined=mined,
                               workers=opts.workers, log=log, progress=progress, **kw)

        auto = opts.learned_mined == "auto"
        first_states: dict = {}
        stage, l_info = stage_of(0.0 if auto else float(opts.learned_mined), states=first_states if auto else None)
        l_info["mined"] = 0.0 if auto else float(opts.learned_mined)
        single = l_info.get("single")
        if auto and stage is not None and single is not None and single.outlier_rate > MINE_WHEN_OUTLIERS:
            missed = (f"learned stage: its single images are off the ball in {100 * single.outlier_rate:.1f}% of the cross-validation's "
                      f"images (over {100 * MINE_WHEN_OUTLIERS:g}%: something of this camera may outrank the ball)")
            n_false = false_alarms(stage, images, labelled)
            trial = {"kept": False, "with": None, "without": l_info["chosen"].line(), "false_alarms": n_false}
            if not n_false:  # its fits would mine nothing and train the same networks again
                log(f"{missed}, but its network has no false alarm of heat >= {MINE_HEAT:g} in the labelled frames to mine: not continued")
            else:
                log(f"{missed}; its network has {n_false} false alarms of heat >= {MINE_HEAT:g} there, so each of its fits is "
                    f"continued for {continue_steps(l_finetune, opts.learned_steps)} steps with {100 * MINED_SHARE:g}% of its patches near "
                    f"its own false alarms")
                stage2, info2 = stage_of(MINED_SHARE, resume=first_states)
                trial["with"] = info2["chosen"].line()
                trial["kept"] = round(info2["chosen"].gain, 9) > round(l_info["chosen"].gain, 9)  # a tie keeps the first
                log(f"learned stage: with its false alarms mined, {trial['with']}; without, {trial['without']}: "
                    f"the one {'with' if trial['kept'] else 'without'} them kept")
                if trial["kept"]:
                    stage, l_info = stage2, dict(info2, mined=MINED_SHARE)
            l_info["mining"] = trial
        l_info["folds_by"] = by
        c = l_info["chosen"]
        if stage is None:
            log("learned stage: none written (the 5x5 filter alone scored best in cross-validation)")
        model = dataclasses.replace(model, learned=stage, description=model.description + (
            f"{LEARNED_MARK}{c.name if stage is not None else 'none, the filter alone'} (of {', '.join(x.name for x in l_info['choices'])}) by {l_info['folds']}-fold cross-validation"
            + ("" if by == "time" else " (folds by camera)") + ": "
            + "; ".join(x.line() for x in l_info["choices"])))
    elif model.learned is not None:
        model = dataclasses.replace(model, learned=None)
    info = dict(finfo, verifier=v_info, learned=l_info)
    return model, info


def _fit_filter(torch, labelled, opts: TrainOptions, base, rng, *, progress: bool, log, description: str, backgrounds):
    """The 5x5 filter's part of :func:`train` (its docstring): returns ``(model, info, description)``."""
    from harness.experiments.detector.scores import truth_of

    base_area = None if base is None else tuple(float(v) for v in base.area_range_px)
    choice = _resolve_threshold_choice(labelled, opts)
    fitter = _Fitter(torch, opts, base, rng, progress)
    if choice == "split":
        train_set, val_set = split_groups(labelled, opts.val_fraction, rng)
        if not any(li.n_balls for li in train_set):
            raise ValueError(f"no ball boxes among the {len(train_set)} training images: nothing to learn")
        if not any(li.n_balls for li in val_set):
            raise ValueError(f"no ball boxes among the {len(val_set)} validation images (val_fraction {opts.val_fraction:g}, "
                             f"seed {opts.seed}): the thresholds and the recall cannot be measured; label more images "
                             "with balls, raise the validation fraction or change the seed (or use --thresholds cv)")
        val_items = [(load_image(li), li) for li in val_set]
        r = fitter.fit(_items(train_set, opts, rng, progress, backgrounds=backgrounds), val_items, log=log)
        n_train, n_val, how = len(train_set), len(val_set), "val"
        truths = [truth_of(li) for li in val_set]
        held_out = [im for im, _ in val_items], ([c for c, _ in truths], [d for _, d in truths])
    else:
        if not any(li.n_balls for li in labelled):
            raise ValueError(f"no ball boxes among the {len(labelled)} images: nothing to learn")
        folds = cv_folds(labelled, opts.cv_folds)
        originals = [(load_image(li), li) for li in labelled]
        oof_logits, oof_truth_c, oof_truth_d, loose, oof_images, fold_models = [], [], [], [], [], []

        for f, fold in enumerate(folds):
            inside = set(fold)
            rest = [li for i, li in enumerate(labelled) if i not in inside]
            if not any(li.n_balls for li in rest):
                continue
            r_f = fitter.fit(_items(rest, opts, rng, False, backgrounds=backgrounds), None, log=log, label=f" (fold {f + 1}/{len(folds)})")
            m_f = _to_model(r_f["w"], r_f["b"], r_f["norm"], opts)
            fold_models.append((m_f, fold))
            loose.append(r_f["loose_area"])
            for i in fold:
                im, li = originals[i]
                oof_logits.append(m_f.logits(im))
                oof_images.append(im)
                c, d = truth_of(li)
                oof_truth_c.append(c)
                oof_truth_d.append(d)
        if not any(len(c) for c in oof_truth_c):
            raise ValueError("cross-validation: no held-out fold holds a ball box; label more images with balls")
        loose_area = (min(a for a, _ in loose), max(b for _, b in loose))
        oof_truth = (oof_truth_c, oof_truth_d)
        t_high, t_low, area, s_ours, s_paper = choose_thresholds(oof_logits, oof_truth, loose_area, opts)
        if base is not None:  # the base model's thresholds are the prior: leave them only on clear evidence
            area = (min(area[0], base_area[0]), max(area[1], base_area[1]))
            b_ours, b_paper = score_thresholds(oof_logits, oof_truth, base.t_high, base.t_low, base_area, opts)
            n = max(s_ours.n_balls, 1)
            gain = _net_gain(s_ours, b_ours)
            if gain <= PRIOR_MARGIN_BALLS / n:
                log(f"thresholds: the base model's (T_h={base.t_high:g}, T_l={base.t_low:g}) kept; cross-validation's choice gains "
                    f"{100 * gain:.1f} points of recall - outliers on {n} balls, not more than {PRIOR_MARGIN_BALLS} balls' worth")
                t_high, t_low, area, s_ours, s_paper = base.t_high, base.t_low, base_area, b_ours, b_paper
        msg = (f"cross-validation over {len(folds)} time-contiguous folds of {len(labelled)} images: T_h={t_high:g}, T_l={t_low:g}: "
               f"ours recall {100 * s_ours.recall:.2f}% outliers {100 * s_ours.outlier_rate:.2f}% median {s_ours.median_center_error_px:.3f} px | "
               f"paper recall {100 * s_paper.recall:.2f}% outliers {100 * s_paper.outlier_rate:.2f}%")
        log(msg)
        r = fitter.fit(_items(labelled, opts, rng, progress, backgrounds=backgrounds), None, log=log, label=" (all images)")
        r.update(t_high=t_high, t_low=t_low, area=area, ours=s_ours, paper=s_paper)
        n_train, n_val, how = len(labelled), 0, f"{len(folds)}-fold cv"
        held_out = oof_images, oof_truth
    base_scores = None
    if base is not None:  # the base model scored on the same held-out images: fine-tuning must beat it to be kept
        base_scores = score_thresholds([base.logits(im) for im in held_out[0]], held_out[1], base.t_high, base.t_low, base_area, opts)
    epoch, t_high, t_low, area, s_ours, s_paper = r["epoch"], r["t_high"], r["t_low"], r["area"], r["ours"], r["paper"]
    summary = (
        f"{'best epoch ' + str(epoch) + '; ' if choice == 'split' else ''}{how} at T_h={t_high:g}, T_l={t_low:g}, area {area[0]:.0f}-{area[1]:.0f} px: "
        f"ours recall {100 * s_ours.recall:.2f}%, outliers {100 * s_ours.outlier_rate:.2f}%, median {s_ours.median_center_error_px:.3f} px; "
        f"paper recall {100 * s_paper.recall:.2f}%, outliers {100 * s_paper.outlier_rate:.2f}%"
    )
    log(summary)
    kept_base = False
    if base_scores is not None:
        b_ours = base_scores[0]
        n = max(s_ours.n_balls, b_ours.n_balls, 1)
        gain = _net_gain(s_ours, b_ours)
        base_line = (f"the base model on the same held-out images ({how}) at T_h={base.t_high:g}, T_l={base.t_low:g}: ours recall "
                     f"{100 * b_ours.recall:.2f}%, outliers {100 * b_ours.outlier_rate:.2f}%, median {b_ours.median_center_error_px:.3f} px")
        log(base_line)
        if opts.keep_base == "auto" and gain <= PRIOR_MARGIN_BALLS / n:
            kept_base = True
            verdict = (f"kept the base model unchanged (weights and thresholds): fine-tuning gains {100 * gain:.1f} points of recall - outliers "
                       f"on {n} held-out balls, not more than {PRIOR_MARGIN_BALLS} balls' worth")
            log(verdict)
            t_high, t_low, area = base.t_high, base.t_low, base_area
            s_ours, s_paper = base_scores
            summary = f"{verdict}; {base_line}"
    desc = f"{description}; " if description else ""
    origin = "fine-tuned from a base model" if base is not None else "trained from scratch"
    if kept_base:
        origin = "the base model kept unchanged (fine-tuning did not beat it on held-out images)"
    if backgrounds:
        origin += f", {len(backgrounds)} ball-free background images"
    desc += (f"{opts.ball_colour} balls, {opts.input_transform} input, {origin}, {n_train} train / {n_val} val images "
             f"(+{opts.augment_copies} augmented copies each), thresholds by {how}, seed {opts.seed}; {summary}")
    model = dataclasses.replace(base, description=desc) if kept_base else _to_model(r["w"], r["b"], r["norm"], opts, t_high, t_low, area, desc)
    if kept_base:  # the base never saw these images: all of them are held out
        alone = [(model, list(range(len(labelled))))]
    elif choice == "split":
        val_ids = {id(li) for li in val_set}
        alone = [(model, [i for i, li in enumerate(labelled) if id(li) in val_ids])]
    else:  # each fold's model at the thresholds chosen on all folds
        alone = [(dataclasses.replace(m_f, t_high=t_high, t_low=t_low, area_range_px=area), fold) for m_f, fold in fold_models]
    info = dict(n_train=n_train, n_val=n_val, n_pos=r["n_pos"], n_neg=r["n_neg"], n_hard=r["n_hard"], history=r["history"],
                best_epoch=epoch, t_high=t_high, t_low=t_low, area_range_px=area, val_ours=s_ours, val_paper=s_paper,
                threshold_choice=choice, kept_base=kept_base, base_ours=None if base_scores is None else base_scores[0], filter_kept=False,
                alone=alone)
    return model, info, desc


def keeps_filter(opts: TrainOptions, base) -> bool:
    """Whether :func:`train` keeps the base model's 5x5 filter unchanged (``TrainOptions.filter``)."""
    if opts.filter != "auto":
        return opts.filter == "keep"
    return (opts.learned != "off" and base is not None and base.learned is not None
            and not base.learned.filter_refines)


def cv_recall(info) -> tuple[float, str]:
    """The (cross-)validated recall of what ``rt2 train`` writes and what it is: the learned stage's when one was
    trained, else the filter's (top-K)."""
    scores, what = written_scores(info)
    return float(np.nan_to_num(scores.recall)), what


def written_scores(info):
    """The held-out :class:`~harness.experiments.detector.scores.DetectorScores` of what ``rt2 train`` writes and what
    it is: the learned stage's cross-validated ones when one was trained (top-K: every candidate a tracker's camera
    reports counts), else the filter's (validation split or cross-validation)."""
    if info.get("learned"):
        c = info["learned"]["chosen"]
        if c.name == "none":
            return c.scores, f"the filter alone, top-K (chosen over a learned stage by {info['learned']['folds']}-fold cross-validation)"
        return c.scores, f"the learned stage ({c.name}, {info['learned']['folds']}-fold cross-validation)"
    return info["val_ours"], f"the filter ({info['threshold_choice']})"


def figures_line(info, scores, what: str) -> str:
    """``rt2 train``'s last line of held-out figures: ``scores`` (:func:`written_scores`) named by what they count (``ours``:
    an image's detection; ``top-K``: its first K candidates, each extra one an outlier), and with a learned stage its
    single images' figures too (each image's best candidate at the written single-image threshold, the same cross-validation)."""
    learned = info.get("learned") or {}
    name = f"top-{learned.get('k', 4)}" if scores.method == "topk" else "ours"  # a learned stage's choices are scored top-K
    line = (f"held-out figures of the model written ({what}): {name} recall {100 * float(np.nan_to_num(scores.recall)):.2f}%, "
            f"outliers {100 * scores.outlier_rate:.2f}%, median {scores.median_center_error_px:.3f} px")
    single = learned.get("single")
    if single is not None:
        line += (f"; single images (each image's best candidate at threshold {learned['single_threshold']:g}): recall "
                 f"{100 * float(np.nan_to_num(single.recall)):.2f}%, outliers {100 * single.outlier_rate:.2f}%")
    return line


# -- command line ----------------------------------------------------------------------------------
SHIPPED_MODELS = {
    "orange": Path(__file__).resolve().parents[3] / "data" / "models" / "ball_seg_default.npz",
    "any": Path(__file__).resolve().parents[3] / "data" / "models" / "ball_seg_default.npz",
    "white": Path(__file__).resolve().parents[3] / "data" / "models" / "ball_seg_white.npz",
}


def _mined_share(text: str):
    """``--learned-mined``: 'auto' or a number (its range checked by :class:`TrainOptions`)."""
    import argparse

    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'auto' or a share between 0 and 1, got {text!r}") from None


def add_arguments(parser) -> None:
    from harness.experiments.detector.labels import LABEL_FORMATS

    parser.add_argument("--data", nargs="+", required=True, help="labelled sets (any --label-format): COCO folders or JSON files, YOLO data.yaml, labelme, CVAT XML, Label Studio JSON")
    parser.add_argument("--label-format", choices=("auto", *LABEL_FORMATS), default="auto",
                        help="format of the --data labels (default auto: found from the files; README 'Label formats')")
    parser.add_argument("--out", required=True, help="weights file to write (.npz)")
    parser.add_argument("--epochs", type=int, default=TrainOptions.epochs)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help="train once per seed, print the spread of the (cross-)validation figures and write the best seed's model "
                             "(default: --seed only)")
    parser.add_argument("--val-fraction", type=float, default=TrainOptions.val_fraction)
    parser.add_argument("--input-transform", choices=INPUT_TRANSFORMS, default=TrainOptions.input_transform,
                        help="per-channel input transform: 'log' (default; exposure-invariant colour) or 'linear' (the paper's raw RGB)")
    parser.add_argument("--core-fraction", type=float, default=TrainOptions.core_fraction,
                        help="ball pixels are those within this fraction of the box's inscribed radius (default 0.6)")
    parser.add_argument("--ball-colour", choices=BALL_COLOURS, default="any",
                        help="learn balls of this colour only; the others become background (default: any)")
    parser.add_argument("--max-images", type=int, default=None, help="use only the first N images (quick runs)")
    parser.add_argument("--from", dest="from_model", default="shipped",
                        help="fine-tune from this weights file (.npz); 'shipped' (default) = the shipped model of --ball-colour "
                             "(data/models/ball_seg_default.npz for orange/any, ball_seg_white.npz for white; scratch if absent); "
                             "'none' = train from scratch")
    parser.add_argument("--augment", type=int, default=None,
                        help="augmented copies of every training image (colour, exposure, gamma, blur, noise, JPEG, scale, flips); "
                             "default: 3 when fine-tuning, 0 from scratch")
    parser.add_argument("--thresholds", choices=THRESHOLD_CHOICES, default="auto",
                        help="how T_h, T_l and the area range are chosen: 'split' (a held-out validation split), 'cv' (cross-validation "
                             f"over time-contiguous folds of all images), 'auto' (default: split when it holds >= {AUTO_SPLIT_MIN_VAL_IMAGES} "
                             "images with a ball, else cv)")
    parser.add_argument("--verifier", action="store_true",
                        help="also train a small classifier on the candidates' crops (a second stage beyond the paper's filter; "
                             "numpy at run time) and store it in the model")
    parser.add_argument("--backgrounds", nargs="+", default=(),
                        help="ball-free real images added to training as background: videos (frames spread over each), COCO sets "
                             "(balls painted out; PATH@START:STOP takes those images in time order) or folders of images")
    parser.add_argument("--background-frames", type=int, default=8, help="frames taken from each --backgrounds video (default 8)")
    parser.add_argument("--keep-base", choices=KEEP_BASE_CHOICES, default="auto",
                        help="when fine-tuning: 'auto' (default) writes the base model unchanged unless the fine-tuned one beats it on the "
                             f"held-out images (cross-validation or the validation split) by more than {PRIOR_MARGIN_BALLS} balls' worth; "
                             "'never' always writes the fine-tuned one")
    parser.add_argument("--cv-folds", type=int, default=TrainOptions.cv_folds, help="folds of --thresholds cv (default 4)")
    parser.add_argument("--min-support", type=int, default=None,
                        help="leave out images whose rt2 label --auto labels have fewer agreeing cameras than this (hand labels are kept)")
    parser.add_argument("--time-range", default=None,
                        help="use only images START:STOP in time order (file names sorted as frame numbers), e.g. 0:58; "
                             "keeps later frames out of training")
    parser.add_argument("--camera", nargs="+", default=None, metavar="NAME",
                        help="train only on the images of these rig cameras (the COCO image field 'camera', as rt2 sim dataset and "
                             "rt2 label --auto write it), before --time-range: e.g. one camera's first frames, the others held out")
    parser.add_argument("--learned", choices=LEARNED_CHOICES, default="auto",
                        help="'auto' (default): also train the learned detector stage (a small heatmap network): no stage (the 5x5 "
                             "filter alone), the base model's stage as it is, fine-tuned, or from scratch, whichever cross-validation "
                             "over time-contiguous folds scores best (the base's own stage unless another scores more than one labelled ball "
                             "better); 'on': the same without 'no stage' (a stage is always written); "
                             "'off': the 5x5 filter alone")
    parser.add_argument("--learned-folds", type=int, default=TrainOptions.learned_folds,
                        help=f"folds of the learned stage's cross-validation (default {TrainOptions.learned_folds})")
    parser.add_argument("--learned-folds-by", choices=LEARNED_FOLDS_BY, default=TrainOptions.learned_folds_by,
                        help="how the learned stage's cross-validation folds the images: 'time' (time-contiguous frame sets), "
                             "'camera' (whole cameras: each fit scored on cameras it never saw) or 'auto' (default): by camera when "
                             f"every image names one of at least {CAMERA_FOLDS_MIN_CAMERAS} cameras (rt2 label --auto's labels), else by time")
    parser.add_argument("--learned-steps", type=int, default=TrainOptions.learned_steps,
                        help=f"optimiser steps of a learned stage from scratch; fine-tuning takes 3/8 of them, at most {FINETUNE_STEPS} "
                             f"(default {TrainOptions.learned_steps})")
    parser.add_argument("--learned-mined", type=_mined_share, default=TrainOptions.learned_mined,
                        help="the share of the learned stage's training patches centred on its own false alarms in the labelled "
                             "images, mined at a third and two thirds of its steps (0: none), or 'auto' (default): none, and where "
                             f"its single images are off the ball in over {100 * MINE_WHEN_OUTLIERS:g}%% of the cross-validation's "
                             f"images, each fit continued with {MINED_SHARE:g} and the better kept")
    parser.add_argument("--filter", choices=FILTER_CHOICES, default="auto",
                        help="the 5x5 filter: 'fit' trains it; 'keep' writes the base model's unchanged (with --learned auto); 'auto' "
                             "(default) keeps it when the base's learned stage does not take the filter's refinement (the shipped "
                             "white model: its filter is of the orange ball), else fits it")
    parser.add_argument("--force", action="store_true",
                        help=f"write the model even when its cross-validated recall is below {100 * MIN_WRITE_RECALL:.0f}%% "
                             f"(otherwise rt2 train exits {EXIT_WEAK_MODEL} without writing it)")
    parser.add_argument("--workers", type=int, default=None, metavar="W",
                        help="processes the learned stage's cross-validation fits run on (1 = this process; default: the "
                             "CPUs, at most one per fit and as many as the memory holds, when the fits add up to 1000 steps "
                             "or more, else 1); the model written does not depend on it")


def resolve_base(from_model: str, colour: str) -> tuple[BallSegmentationModel | None, str]:
    """``--from`` -> (base model or None, what it is, for the log and the weights file's description)."""
    if from_model == "none":
        return None, "scratch"
    if from_model == "shipped":
        path = SHIPPED_MODELS[colour]
        if not path.is_file():
            return None, f"scratch (no shipped {colour} model at {path})"
        return BallSegmentationModel.load(path), f"the shipped model {path.name}"
    path = Path(from_model)
    if path.suffix != ".npz":
        raise ValueError(f"--from must be a .npz weights file, 'shipped' or 'none', got {from_model!r}")
    return BallSegmentationModel.load(path), str(path)


#: the training's peak memory over its images and the copies it holds (measured: `rt2 train` fitting the filter on 58
#: rally frames of 1920x1080 with 3 copies, 1.44 GB of images, peaked at 3.27 GB, 0.37 GB of it the program itself)
MEMORY_PER_IMAGE_BYTE = 2.0


def check_memory(labelled, augment_copies: int, backgrounds=(), available: int | None = None) -> None:
    """Refuse (ValueError, one line) a training whose images and their augmented copies alone would not fit in the
    memory available: the training holds them all at once, and a machine out of memory kills a process, perhaps
    not this one (a tracker on the same machine). ``augment_copies``: the copies the training holds (0 where the
    filter is not fitted); the need: ``MEMORY_PER_IMAGE_BYTE`` x the bytes of the images and their copies."""
    per_copy = sum(int(li.width) * int(li.height) * 3 for li in labelled) + sum(int(im.nbytes) for im, _ in backgrounds)
    need = int(MEMORY_PER_IMAGE_BYTE * per_copy * (1 + int(augment_copies)))
    available = available_memory_bytes() if available is None else available
    if available is None or need <= available:
        return
    sizes = sorted({(int(li.width), int(li.height)) for li in labelled}, key=lambda wh: -wh[0] * wh[1])
    shown = ", ".join(f"{w}x{h}" for w, h in sizes[:3]) + (", ..." if len(sizes) > 3 else "")

    def size(n):
        return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"

    raise ValueError(f"{len(labelled)} images ({shown}) with {augment_copies} augmented copies each need about {size(need)} "
                     f"of memory to train on, {size(available)} are available: train on fewer (--max-images N, --time-range START:STOP, "
                     f"--min-support for auto labels) or with fewer copies (--augment 0)")


def run(args) -> int:
    import shlex
    import sys

    from harness.experiments.detector.labels import read_labels
    from harness.experiments.detector.subsets import select_cameras, take_range

    from harness.common.outputs import atomic_path, check_output_file

    out = Path(args.out)
    check_output_file(out, "--out", suffix=".npz")  # before the training, not after
    _check_workers(args.workers)  # before the images are read
    if args.max_images is not None and args.max_images < 1:
        raise ValueError(f"--max-images must be a positive number of images, got {args.max_images}")
    base, origin = resolve_base(args.from_model, args.ball_colour)
    augment = args.augment if args.augment is not None else (3 if base is not None else 0)
    seeds = args.seeds if args.seeds else [args.seed]
    # every option's value checked before the images are read, each named by its option
    options = TrainOptions.from_flags(epochs=args.epochs, seed=seeds[0], val_fraction=args.val_fraction, input_transform=args.input_transform,
                                      ball_colour=args.ball_colour, core_fraction=args.core_fraction, augment_copies=augment,
                                      threshold_choice=args.thresholds, cv_folds=args.cv_folds, verifier=args.verifier,
                                      keep_base=args.keep_base, learned=args.learned, learned_folds=args.learned_folds,
                                      learned_folds_by=args.learned_folds_by, learned_steps=args.learned_steps,
                                      learned_mined=args.learned_mined, filter=args.filter, allow_no_ball=args.force, workers=args.workers)
    labelled = [li for path in args.data for li in read_labels(path, args.label_format)]
    if args.camera:  # before --time-range: the time order is one camera's (as rt2 eval detector --camera)
        labelled = select_cameras(labelled, args.camera)
    labelled = take_range(labelled, args.time_range)
    if args.min_support is not None:  # rt2 label --auto's labels: only the surest
        from harness.experiments.autolabel.output import keep_supported

        labelled = keep_supported(labelled, args.data, args.min_support)
    if args.max_images is not None:
        labelled = labelled[: args.max_images]
    from harness.experiments.detector.backgrounds import read_backgrounds

    backgrounds = read_backgrounds(args.backgrounds, args.background_frames, load_image=load_image) if args.backgrounds else []
    cmd = "rt2 " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["train"] else "rt2 train"
    print(f"training from {origin} on {len(labelled)} images" + (f" + {len(backgrounds)} ball-free backgrounds" if backgrounds else "")
          + f", {augment} augmented copies each, seeds {seeds}")
    results = []
    for seed in seeds:
        opts = dataclasses.replace(options, seed=seed)
        picked = ([f"cameras {' '.join(args.camera)}"] if args.camera else []) + ([f"time range {args.time_range}"] if args.time_range else [])
        sources = f"data {', '.join(map(str, args.data))}" + (f" ({', '.join(picked)})" if picked else "")
        if backgrounds:
            sources += f"; backgrounds {', '.join(map(str, args.backgrounds))} ({len(backgrounds)} ball-free images)"
        try:
            model, info = train(labelled, opts, description=f"trained by `{cmd}` from {origin}; {sources}", base=base, backgrounds=backgrounds)
        except NoBallFoundError as exc:  # as a model that finds too few balls: nothing written, the same exit status
            print(f"rt2 train: {args.out} not written: {exc}; label more frames (with balls) or check --ball-colour; --force "
                  "writes it anyway", file=sys.stderr)
            return EXIT_WEAK_MODEL
        results.append((seed, model, info))
    held_out = [written_scores(info)[0] for _, _, info in results]  # of what each seed would write
    if len(results) > 1:
        print(f"{'seed':>5} {'recall':>8} {'outliers':>9} {'median px':>10}  (held-out figures of {written_scores(results[0][2])[1]})")
        for (seed, _, _), s in zip(results, held_out):
            print(f"{seed:5d} {100 * np.nan_to_num(s.recall):7.2f}% {100 * s.outlier_rate:8.2f}% {s.median_center_error_px:10.3f}")
        rec = np.array([np.nan_to_num(s.recall) for s in held_out])
        out_r = np.array([s.outlier_rate for s in held_out])
        print(f"spread over {len(results)} seeds: recall {100 * rec.min():.2f}-{100 * rec.max():.2f}%, outliers {100 * out_r.min():.2f}-{100 * out_r.max():.2f}%")
    b = max(range(len(results)), key=lambda i: (np.nan_to_num(held_out[i].recall) - held_out[i].outlier_rate, -results[i][0]))
    seed, model, info = results[b]
    if len(results) > 1:
        spread = ", ".join(f"seed {sd}: recall {100 * np.nan_to_num(s.recall):.1f}% outliers {100 * s.outlier_rate:.1f}%"
                           for (sd, _, _), s in zip(results, held_out))
        model = dataclasses.replace(model, description=model.description + f"; kept seed {seed} of [{spread}]")
    scores, what = written_scores(info)
    recall = float(np.nan_to_num(scores.recall))
    print(figures_line(info, scores, what))
    if recall < MIN_WRITE_RECALL:
        line = (f"rt2 train: {args.out} not written: the cross-validated recall of {what} is {100 * recall:.1f}% < "
                f"{100 * MIN_WRITE_RECALL:.0f}%; label more frames (with balls) or check --ball-colour; --force writes it anyway")
        if not args.force:
            print(line, file=sys.stderr)
            return EXIT_WEAK_MODEL
        print(line.replace("not written", "written anyway (--force)").replace("; --force writes it anyway", ""), file=sys.stderr)
    with atomic_path(out, "--out") as tmp:  # never a half-written model
        model.save(tmp)
    print(f"wrote {out}: T_h={model.t_high:g}, T_l={model.t_low:g} ({info['n_train']} train / {info['n_val']} val images"
          f"{', thresholds by cross-validation' if info['threshold_choice'] == 'cv' else ''}{f', seed {seed}' if len(results) > 1 else ''})"
          + ("; the base model unchanged: fine-tuning did not beat it on held-out images" if info.get("kept_base") else "")
          + ("; the base model's 5x5 filter kept" if info.get("filter_kept") else ""))
    return 0

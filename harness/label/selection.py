"""Do the frames ``rt2 label`` suggests train a better detector than consecutive ones? (``rt2 eval selection``)

On one labelled set of one or several cameras (each camera is one recording; ``cameras`` picks them), per
camera, in time order:

1. the earlier ``pool_fraction`` of the frames is the pool a user would label from; after a gap of
   ``gap_frames`` frames, the later frames are held out for evaluation, the same frames for both arms
   (consecutive frames are near-copies: a random split, or no gap, would test on copies of training frames);
2. arm **chosen**: the first ``n_chosen`` frames the page suggests on the pool with nothing labelled yet
   (:func:`harness.label.suggest.suggest` on the proposals of ``model``), the order a user labelling
   with the page follows;
3. arm **consecutive**: ``n_consecutive`` consecutive pool frames (what a user gets by labelling "the
   first 20 frames"); the start moves over the repeats: evenly spaced over the pool's possible starts, in
   an order drawn with the seed, so the arm is not judged on one lucky or unlucky stretch;
4. each arm trains a model exactly as ``rt2 train`` does with its defaults
   (:func:`~harness.experiments.detector.train.train`; fine-tuned from ``--from`` = the shipped model of
   the ball colour by default, 3 augmented copies when fine-tuning and none from scratch unless
   ``augment`` says otherwise, the same threshold choice), and ``rt2 eval detector``'s :func:`evaluate`
   scores it on the held-out frames (``ours``: the best candidate; ``topk``: any of K); the base model
   is scored there too, as it is (what the user has before labelling). An arm whose frames
   hold no ball trains no model: its user gets nothing, scored as 0 % recall.

Repeat ``r`` uses seed ``seed + r`` for both arms' trainings (and the consecutive start of that repeat);
the same options give the same figures. The verdict compares the arms over every (camera, seed) run:
the chosen arm must be at least as good at the median and at the worst run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from harness.experiments.detector.train import (KEEP_BASE_CHOICES, THRESHOLD_CHOICES, TrainOptions, load_image, resolve_base,
                                                select_ball_colour, train)
from harness.experiments.detector.subsets import camera_of, image_camera
from harness.experiments.studies.eval_detector import evaluate
from harness.label.suggest import describe_image, suggest, uncertainty
from tracker import BallDetector, DetectorOptions
from tracker.detection.model import BALL_COLOURS

__all__ = ["SelectionOptions", "camera_of", "frame_number", "run_selection", "split_cameras", "time_order"]

#: Roboflow appends ``_<ext>.rf.<hash>`` to exported file stems, rt2's data sets ``_cam<k>``: the frame number sits before
_NAME_SUFFIX = re.compile(r"(_(jpg|jpeg|png)\.rf\.[0-9a-f]+|_cam\d+)$", re.IGNORECASE)
_LAST_NUMBER = re.compile(r"(\d+)\D*$")
#: the figures the verdict compares (higher is better)
_VERDICT_KEYS = ("ours_recall", "topk_recall")


@dataclass(frozen=True)
class SelectionOptions:
    """Options of :func:`run_selection`.

    pool_fraction : the earlier share of each camera's frames (time order) the arms pick from
    gap_frames : frames skipped between the pool and the held-out frames (the rest after the gap is held out)
    n_chosen, n_consecutive : frames per arm
    repeats : trainings per arm and camera (seeds ``seed`` .. ``seed + repeats - 1``)
    epochs : ``rt2 train`` epochs per training
    seed : first seed
    from_model : ``rt2 train --from``: "shipped" (the shipped model of ``ball_colour``), "none" (scratch) or a .npz path
    augment : ``rt2 train --augment``; None = its default (3 when fine-tuning, 0 from scratch)
    threshold_choice : ``rt2 train --thresholds``
    ball_colour : ``rt2 train --ball-colour``
    cameras : the cameras to study (names as in the file names, e.g. "cam0"); empty = every camera of the set
    keep_base : ``rt2 train --keep-base``: "auto" keeps the base model when fine-tuning does not beat it on held-out
        labelled images, "never" always fine-tunes
    """

    pool_fraction: float = 0.6
    n_chosen: int = 10
    n_consecutive: int = 20
    repeats: int = 3
    epochs: int = TrainOptions.epochs
    seed: int = 0
    gap_frames: int = 2
    from_model: str = "shipped"
    augment: int | None = None
    threshold_choice: str = "auto"
    ball_colour: str = "any"
    cameras: tuple = ()
    keep_base: str = "auto"

    def __post_init__(self):
        if not 0.0 < self.pool_fraction < 1.0:
            raise ValueError(f"--pool-fraction must be in (0, 1), got {self.pool_fraction}")
        for name, option, low in (("n_chosen", "--chosen", 3), ("n_consecutive", "--consecutive", 3), ("repeats", "--repeats", 1),
                                  ("epochs", "--epochs", 1), ("gap_frames", "--gap", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"SelectionOptions.{name} ({option}) must be an integer >= {low}, got {v!r}")
        if self.augment is not None and (isinstance(self.augment, bool) or not isinstance(self.augment, int) or self.augment < 0):
            raise ValueError(f"SelectionOptions.augment (--augment) must be an integer >= 0, got {self.augment!r}")
        if self.threshold_choice not in THRESHOLD_CHOICES:
            raise ValueError(f"SelectionOptions.threshold_choice must be one of {THRESHOLD_CHOICES}, got {self.threshold_choice!r}")
        if self.ball_colour not in BALL_COLOURS:
            raise ValueError(f"SelectionOptions.ball_colour must be one of {BALL_COLOURS}, got {self.ball_colour!r}")
        if self.keep_base not in KEEP_BASE_CHOICES:
            raise ValueError(f"SelectionOptions.keep_base (--keep-base) must be one of {KEEP_BASE_CHOICES}, got {self.keep_base!r}")
        object.__setattr__(self, "cameras", tuple(self.cameras))
        if len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"--camera names a camera twice: {list(self.cameras)}")


def frame_number(path) -> int | None:
    """The frame number in an image file name: its last number, after dropping a Roboflow export suffix
    (``..._jpg.rf.<hash>``) or rt2's camera suffix (``f000123_cam2``); None without one."""
    from pathlib import Path

    stem = _NAME_SUFFIX.sub("", Path(path).stem)
    m = _LAST_NUMBER.search(stem)
    return int(m.group(1)) if m else None


def split_cameras(labelled, cameras=()) -> dict:
    """``{camera: [LabelledImage, ...]}`` of the ``cameras`` asked for (all when empty), in name order;
    ValueError naming the cameras the set has when one asked for is missing."""
    by_camera: dict = {}
    for li in labelled:
        by_camera.setdefault(image_camera(li), []).append(li)
    found = sorted(by_camera)
    missing = [c for c in cameras if c not in by_camera]
    if missing:
        have = ", ".join(repr(c) for c in found) if found != [""] else "none (its file names carry no camera: leave out --camera)"
        raise ValueError(f"--camera {' '.join(missing)}: not in the labelled set; its cameras: {have}")
    return {c: by_camera[c] for c in (cameras or found)}


def time_order(labelled) -> list:
    """The labelled images sorted by frame number (:func:`frame_number`); ValueError if a name has none or two share one."""
    numbers = [frame_number(li.path) for li in labelled]
    missing = [li.path.name for li, n in zip(labelled, numbers) if n is None]
    if missing:
        raise ValueError(f"cannot put the frames in time order: no frame number in the file name(s) {missing[:3]}")
    if len(set(numbers)) != len(numbers):
        raise ValueError("cannot put the frames in time order: two file names carry the same frame number "
                         "(several cameras in one set? their names need a camera: f000123_cam2 or cam2_s000123)")
    return [labelled[i] for i in np.argsort(numbers, kind="stable")]


def _choose(pool, model, n: int) -> list[int]:
    """The page's first ``n`` suggestions on ``pool`` with nothing labelled (as ``harness.label.session`` computes them)."""
    detector = BallDetector(model, DetectorOptions(method="ours"))
    desc, unc = [], []
    for li in pool:
        image = load_image(li)
        desc.append(describe_image(image))
        unc.append(uncertainty(detector.detect(image).scores))
    return suggest(np.array(desc), np.array(unc), [], n)


def _consecutive_starts(n_pool: int, opts: SelectionOptions) -> list[int]:
    """One start per repeat: evenly spaced over ``0 .. n_pool - n_consecutive``, in an order drawn with the seed."""
    last = n_pool - opts.n_consecutive
    starts = np.round(np.linspace(0, last, opts.repeats)).astype(int) if opts.repeats > 1 else np.array([last // 2])
    return [int(s) for s in np.random.default_rng(opts.seed).permutation(starts)]


def _split(frames, opts: SelectionOptions, camera: str):
    n_pool = int(round(opts.pool_fraction * len(frames)))
    pool, held_out = frames[:n_pool], frames[n_pool + opts.gap_frames:]
    name = f"camera {camera!r}: " if camera else ""
    if len(pool) < max(opts.n_consecutive, opts.n_chosen) or len(held_out) < 1:
        raise ValueError(f"{name}{len(frames)} frames give a pool of {len(pool)} and {len(held_out)} held out after a gap of "
                         f"{opts.gap_frames}; need a pool of at least {max(opts.n_consecutive, opts.n_chosen)} "
                         f"(--consecutive, --chosen) and a held-out frame: lower --pool-fraction, --gap or --consecutive")
    return pool, held_out


def _train_and_score(images, held_out, base, augment: int, opts: SelectionOptions, seed: int) -> dict:
    topts = TrainOptions(epochs=opts.epochs, seed=seed, augment_copies=augment, threshold_choice=opts.threshold_choice,
                         ball_colour=opts.ball_colour, keep_base=opts.keep_base)
    try:
        trained, info = train(images, topts, base=base, progress=False, log=lambda line: None)
    except ValueError as exc:  # e.g. no ball among the arm's frames: rt2 train refuses, the user has no model
        return {"error": str(exc), "ours": None, "topk": None, "kept_base": None}
    ours, topk = evaluate(trained, held_out, methods=("ours", "topk"), progress=False)
    return {"error": None, "ours": ours.as_json(), "topk": topk.as_json(), "kept_base": bool(info.get("kept_base"))}


def run_selection(labelled, model, opts: SelectionOptions = SelectionOptions(), *, log=print) -> dict:
    """Both arms on ``labelled`` (each camera one recording); returns the frames used and each training's held-out scores.

    labelled : list of ``LabelledImage``, any order (split by :func:`~harness.experiments.detector.subsets.image_camera`, sorted by :func:`time_order`)
    model : the ``BallSegmentationModel`` that proposes the ball (the page's ``--model``)
    """
    recordings = {c: time_order(images) for c, images in split_cameras(labelled, opts.cameras).items()}
    splits = {c: _split(frames, opts, c) for c, frames in recordings.items()}  # every camera checked before any training
    # held out as rt2 eval detector --ball-colour scores it: balls of the other colour are not labels there
    splits = {c: (pool, select_ball_colour(held, opts.ball_colour)) for c, (pool, held) in splits.items()}
    base, origin = resolve_base(opts.from_model, opts.ball_colour)
    augment = opts.augment if opts.augment is not None else (3 if base is not None else 0)
    log(f"training as rt2 train does: from {origin}, {augment} augmented copies, thresholds {opts.threshold_choice}, "
        f"{opts.epochs} epochs, seeds {opts.seed}-{opts.seed + opts.repeats - 1}")
    runs, cams = [], []
    for camera, frames in recordings.items():
        pool, held_out = splits[camera]
        chosen = _choose(pool, model, opts.n_chosen)
        starts = _consecutive_starts(len(pool), opts)
        name = f"{camera}: " if camera else ""
        log(f"{name}pool: frames 1-{len(pool)} of {len(frames)} (time order); held out: the {len(held_out)} frames after a gap of "
            f"{opts.gap_frames}; chosen by the page's rule: {sorted(i + 1 for i in chosen)} "
            f"({sum(pool[i].n_balls > 0 for i in chosen)} with a ball; pool: {sum(li.n_balls > 0 for li in pool)} of {len(pool)})")
        rec = {"camera": camera, "n_frames": len(frames), "n_pool": len(pool), "n_held_out": len(held_out),
               "chosen": sorted(i + 1 for i in chosen), "consecutive_starts": [s + 1 for s in starts], "base": None}
        if base is not None:  # what the user has before labelling anything: the model fine-tuning starts from
            ours, topk = evaluate(base, held_out, methods=("ours", "topk"), progress=False)
            rec["base"] = {"ours": ours.as_json(), "topk": topk.as_json()}
            log(f"{name}no labels (the base model as it is): held-out recall ours {100 * ours.recall:.1f}% top-K {100 * topk.recall:.1f}%, "
                f"outliers ours {100 * ours.outlier_rate:.1f}%")
        cams.append(rec)
        for r in range(opts.repeats):
            seed, start = opts.seed + r, starts[r]
            arms = {"chosen": [pool[i] for i in chosen], "consecutive": pool[start:start + opts.n_consecutive]}
            for arm, images in arms.items():
                row = {"camera": camera, "arm": arm, "seed": seed, "n_frames": len(images),
                       "n_with_ball": sum(li.n_balls > 0 for li in images),
                       "frames": [frames.index(li) + 1 for li in images], **_train_and_score(images, held_out, base, augment, opts, seed)}
                runs.append(row)
                what = ("" if arm == "chosen" else f", {start + 1}-{start + opts.n_consecutive}") + ("; base kept" if row["kept_base"] else "")
                if row["error"]:
                    log(f"{name}seed {seed} {arm:>11} ({len(images)} frames{what}): no model: {row['error']}")
                else:
                    o, k = row["ours"], row["topk"]
                    log(f"{name}seed {seed} {arm:>11} ({len(images)} frames{what}): held-out recall ours {100 * o['recall']:.1f}% "
                        f"top-K {100 * k['recall']:.1f}%, outliers ours {100 * o['outlier_rate']:.1f}%")
    stats = {s: _stat(runs, s) for s in ("median", "min", "max")}
    one = cams[0] if len(cams) == 1 else None
    return {"n_frames": sum(c["n_frames"] for c in cams), "n_pool": sum(c["n_pool"] for c in cams),
            "n_held_out": sum(c["n_held_out"] for c in cams), "chosen": one["chosen"] if one else None,
            "recordings": cams, "trained_from": origin, "augment_copies": augment,
            "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in
                        ((k, getattr(opts, k)) for k in SelectionOptions.__dataclass_fields__)},
            "runs": runs, **stats, "verdict": _verdict(stats)}


def _figures(row) -> dict:
    if row["error"]:  # no model: it finds nothing
        return {"ours_recall": 0.0, "topk_recall": 0.0, "ours_outlier_rate": None, "topk_outlier_rate": None,
                "ours_median_center_error_px": None, "topk_median_center_error_px": None}
    return {f"{m}_{k}": row[m][k] for m in ("ours", "topk") for k in ("recall", "outlier_rate", "median_center_error_px")}


def _stat(runs, how: str) -> dict:
    """Per arm, the ``how`` ("median", "min", "max") over its runs of every figure (None: no run had it)."""
    f = {"median": np.median, "min": np.min, "max": np.max}[how]
    out = {}
    for arm in ("chosen", "consecutive"):
        rows = [_figures(r) for r in runs if r["arm"] == arm]
        out[arm] = {}
        for key in rows[0]:
            v = [r[key] for r in rows if r[key] is not None]
            out[arm][key] = float(f(v)) if v else None
    return out


def _verdict(stats) -> dict:
    """``met``: the chosen arm's median and worst run are at least the consecutive arm's on every verdict figure;
    None when neither arm's model finds any held-out ball (the frames chosen make no difference then)."""
    med, low = stats["median"], stats["min"]
    if max(stats["max"]["chosen"]["topk_recall"], stats["max"]["consecutive"]["topk_recall"]) == 0.0:
        return {"met": None, "compared": list(_VERDICT_KEYS), "reason": "neither arm's model finds a held-out ball"}
    ok = all(med["chosen"][k] >= med["consecutive"][k] and low["chosen"][k] >= low["consecutive"][k] for k in _VERDICT_KEYS)
    return {"met": bool(ok), "compared": list(_VERDICT_KEYS), "reason": "median and worst run of each arm"}

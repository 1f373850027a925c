"""Do the frames ``rt2 label`` suggests train a better detector than consecutive ones? (``rt2 eval selection``)

On one labelled recording, in time order:

1. the earlier ``pool_fraction`` of the frames is the pool a user would label from; the later frames are
   held out for evaluation (consecutive frames are near-copies: a random split would test on copies);
2. arm **chosen**: the first ``n_chosen`` frames the page suggests on the pool with nothing labelled yet
   (:func:`harness.label.suggest.suggest` on the proposals of ``model``), the order a user labelling
   with the page follows;
3. arm **consecutive**: ``n_consecutive`` consecutive pool frames from a start drawn with the seed
   (what a user gets by labelling "the first 20 frames");
4. each arm trains a model with ``rt2 train``'s :func:`~harness.experiments.detector.train.train`
   (same options, same seed) and ``rt2 eval detector``'s :func:`evaluate` scores it on the held-out
   frames (``ours``: the best candidate; ``topk``: any of K).

Each repeat ``r`` uses seed ``seed + r`` for the consecutive start and both trainings; the same seed gives
the same figures.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.experiments.detector.train import TrainOptions, load_image, train
from harness.experiments.studies.eval_detector import evaluate
from harness.label.suggest import describe_image, suggest, uncertainty
from tracker import BallDetector, DetectorOptions

__all__ = ["SelectionOptions", "frame_number", "run_selection", "time_order"]

#: Roboflow appends ``_<ext>.rf.<hash>`` to exported file stems, rt2's data sets ``_cam<k>``: the frame number sits before
_NAME_SUFFIX = re.compile(r"(_(jpg|jpeg|png)\.rf\.[0-9a-f]+|_cam\d+)$", re.IGNORECASE)
_LAST_NUMBER = re.compile(r"(\d+)\D*$")


@dataclass(frozen=True)
class SelectionOptions:
    """Options of :func:`run_selection`.

    pool_fraction : the earlier share of the frames (time order) the arms pick from; the rest is held out
    n_chosen, n_consecutive : frames per arm
    repeats : trainings per arm (seeds ``seed`` .. ``seed + repeats - 1``)
    epochs : ``rt2 train`` epochs per training
    seed : first seed
    """

    pool_fraction: float = 0.6
    n_chosen: int = 10
    n_consecutive: int = 20
    repeats: int = 3
    epochs: int = TrainOptions.epochs
    seed: int = 0

    def __post_init__(self):
        if not 0.0 < self.pool_fraction < 1.0:
            raise ValueError(f"--pool-fraction must be in (0, 1), got {self.pool_fraction}")
        for name in ("n_chosen", "n_consecutive", "repeats", "epochs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 3 and name.startswith("n_") or v < 1:
                raise ValueError(f"SelectionOptions.{name} must be an integer >= {3 if name.startswith('n_') else 1}, got {v!r}")


def frame_number(path) -> int | None:
    """The frame number in an image file name: its last number, after dropping a Roboflow export suffix
    (``..._jpg.rf.<hash>``) or rt2's camera suffix (``f000123_cam2``); None without one."""
    stem = _NAME_SUFFIX.sub("", Path(path).stem)
    m = _LAST_NUMBER.search(stem)
    return int(m.group(1)) if m else None


def time_order(labelled) -> list:
    """The labelled images sorted by frame number (:func:`frame_number`); ValueError if a name has none or two share one."""
    numbers = [frame_number(li.path) for li in labelled]
    missing = [li.path.name for li, n in zip(labelled, numbers) if n is None]
    if missing:
        raise ValueError(f"cannot put the frames in time order: no frame number in the file name(s) {missing[:3]}")
    if len(set(numbers)) != len(numbers):
        raise ValueError("cannot put the frames in time order: two file names carry the same frame number")
    return [labelled[i] for i in np.argsort(numbers, kind="stable")]


def _choose(pool, model, n: int) -> list[int]:
    detector = BallDetector(model, DetectorOptions(method="ours"))
    desc, unc = [], []
    for li in pool:
        image = load_image(li)
        desc.append(describe_image(image))
        unc.append(uncertainty(detector.detect(image).scores))
    return suggest(np.array(desc), np.array(unc), [], n)


def run_selection(labelled, model, opts: SelectionOptions = SelectionOptions(), *, log=print) -> dict:
    """Both arms on ``labelled`` (one recording); returns the frames used and each training's held-out scores.

    labelled : list of ``LabelledImage`` of one camera, any order (sorted by :func:`time_order`)
    model : the ``BallSegmentationModel`` that proposes the ball (the page's ``--model``)
    """
    frames = time_order(labelled)
    n_pool = int(round(opts.pool_fraction * len(frames)))
    pool, held_out = frames[:n_pool], frames[n_pool:]
    if len(pool) < opts.n_consecutive or len(held_out) < 1:
        raise ValueError(f"{len(frames)} frames give a pool of {len(pool)} and {len(held_out)} held out; need a pool of at least "
                         f"{opts.n_consecutive} (--consecutive) and a held-out frame: lower --pool-fraction or --consecutive")
    chosen = _choose(pool, model, opts.n_chosen)
    log(f"pool: frames 1-{n_pool} of {len(frames)} (time order); held out: {len(held_out)} later frames; "
        f"chosen by the page's rule: {sorted(i + 1 for i in chosen)}")
    runs = []
    for r in range(opts.repeats):
        seed = opts.seed + r
        start = int(np.random.default_rng(seed).integers(0, len(pool) - opts.n_consecutive + 1))
        arms = {"chosen": [pool[i] for i in chosen], "consecutive": pool[start:start + opts.n_consecutive]}
        for arm, images in arms.items():
            trained, info = train(images, TrainOptions(epochs=opts.epochs, seed=seed), progress=False, log=lambda line: None)
            ours, topk = evaluate(trained, held_out, methods=("ours", "topk"), progress=False)
            row = {"arm": arm, "seed": seed, "n_frames": len(images),
                   "frames": [frames.index(li) + 1 for li in images], "ours": ours.as_json(), "topk": topk.as_json()}
            runs.append(row)
            log(f"seed {seed} {arm:>11} ({len(images)} frames{'' if arm == 'chosen' else f', {start + 1}-{start + opts.n_consecutive}'}): "
                f"held-out recall ours {100 * ours.recall:.1f}% top-K {100 * topk.recall:.1f}%, outliers ours {100 * ours.outlier_rate:.1f}%")
    return {"n_frames": len(frames), "n_pool": n_pool, "n_held_out": len(held_out), "chosen": sorted(i + 1 for i in chosen),
            "options": {k: getattr(opts, k) for k in SelectionOptions.__dataclass_fields__}, "runs": runs,
            "median": _medians(runs)}


def _medians(runs) -> dict:
    out = {}
    for arm in ("chosen", "consecutive"):
        rows = [r for r in runs if r["arm"] == arm]
        values = {f"{m}_{k}": [r[m][k] for r in rows if r[m][k] is not None]
                  for m in ("ours", "topk") for k in ("recall", "outlier_rate", "median_center_error_px")}
        out[arm] = {key: float(np.median(v)) if v else None for key, v in values.items()}  # None: no run had the figure
    return out

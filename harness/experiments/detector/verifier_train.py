"""Training of the candidate verifier (:class:`tracker.detection.verifier.CandidateVerifier`), ``rt2 train --verifier``.

After the 5x5 filter is fitted, its detector runs permissively on every training image (the
original and its augmented copies) and reports up to ``max_seeds`` candidates. Examples:

* each candidate within ``pos_radius`` ball diameters of a labelled ball is a *ball* example, with
  the offset to the labelled centre as the regression target; each candidate farther than one
  diameter from every ball is a *background* example (the mistakes the verifier must undo);
* ``jitter_per_ball`` crops around each labelled ball (centre moved by up to ``jitter`` diameters,
  side drawn as a blob's would be), so the ball class is seen even where the filter misses it;
* ``random_per_image`` crops at random places away from the balls.

The perceptron is fitted in torch (Adam, class-balanced cross-entropy + smooth-L1 on the offsets of
ball examples). Its threshold is chosen by cross-validation over time-contiguous folds of the
labelled images (:func:`harness.experiments.detector.train.cv_folds`): a verifier is trained without
each fold, scores that fold's candidates, and the threshold maximises ``recall - outlier_rate`` of
the first reported candidate over all images (pooled out-of-fold). Then the verifier is fitted on
every image. Seeded by the training seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker import BallDetector, DetectorOptions
from tracker.detection.verifier import CandidateVerifier

__all__ = ["VerifierOptions", "train_verifier"]

THRESHOLD_GRID = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98)


@dataclass(frozen=True)
class VerifierOptions:
    """Options of :func:`train_verifier` (see the module docstring)."""

    crop_px: int = 16
    context: float = 2.5
    hidden: int = 32
    steps: int = 300
    lr: float = 3e-3
    weight_decay: float = 1e-4
    max_seeds: int = 16
    pos_radius: float = 0.5
    jitter_per_ball: int = 6
    jitter: float = 0.3
    random_per_image: int = 8
    offset_weight: float = 4.0
    cv_folds: int = 4

    def __post_init__(self):
        for name in ("crop_px", "hidden", "steps", "max_seeds", "cv_folds"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"VerifierOptions.{name} must be a positive integer, got {v!r}")
        if not self.cv_folds >= 2:
            raise ValueError(f"VerifierOptions.cv_folds must be >= 2, got {self.cv_folds!r}")


def _examples(model, verifier_shape: CandidateVerifier, image, labelled, opts: VerifierOptions, rng):
    """(features, labels (n,), offsets (n, 2), candidate mask (n,)) of one image."""
    det = BallDetector(model, DetectorOptions(max_candidates=opts.max_seeds, max_seeds=opts.max_seeds, verify=False)).detect(image)
    centres, sides, labels, offsets, is_cand = [], [], [], [], []
    truth_c, truth_d = labelled.centers_px, np.minimum(labelled.boxes_xywh[:, 2], labelled.boxes_xywh[:, 3]) if labelled.n_balls else np.zeros(0)
    box_side = det.boxes_xywh[:, 2:].max(axis=1) if len(det) else np.zeros(0)
    crop_sides = verifier_shape.sides_px(box_side)
    for c, s in zip(det.uv_px, crop_sides):
        if len(truth_c):
            dist = np.linalg.norm(truth_c - c, axis=1)
            j = int(np.argmin(dist))
            if dist[j] <= opts.pos_radius * truth_d[j]:
                centres.append(c), sides.append(s), labels.append(1.0), offsets.append((truth_c[j] - c) / s), is_cand.append(True)
                continue
            if (dist <= truth_d).any():
                continue
        centres.append(c), sides.append(s), labels.append(0.0), offsets.append((0.0, 0.0)), is_cand.append(True)
    for c, d in zip(truth_c, truth_d):
        for _ in range(opts.jitter_per_ball):
            cj = c + rng.uniform(-opts.jitter, opts.jitter, 2) * d
            s = float(verifier_shape.sides_px([d * rng.uniform(0.6, 1.2)])[0])
            centres.append(cj), sides.append(s), labels.append(1.0), offsets.append((c - cj) / s), is_cand.append(False)
    h, w = image.shape[:2]
    ref = truth_d if len(truth_d) else np.array([max(float(np.sqrt(model.area_range_px.mean())), 4.0)])
    for _ in range(opts.random_per_image):
        c = rng.uniform([0, 0], [w - 1, h - 1])
        if len(truth_c) and (np.linalg.norm(truth_c - c, axis=1) <= 1.5 * truth_d).any():
            continue
        s = float(verifier_shape.sides_px([rng.choice(ref) * rng.uniform(0.6, 1.2)])[0])
        centres.append(c), sides.append(s), labels.append(0.0), offsets.append((0.0, 0.0)), is_cand.append(False)
    feats = verifier_shape.features(image, np.array(centres).reshape(-1, 2), np.array(sides)) if centres else np.zeros((0, 3 * opts.crop_px**2), np.float32)
    return feats, np.array(labels), np.array(offsets).reshape(-1, 2), np.array(is_cand, bool), det


def _fit(torch, feats, labels, offsets, opts: VerifierOptions, seed: int):
    torch.manual_seed(seed)
    x = torch.from_numpy(np.ascontiguousarray(feats, np.float32))
    y = torch.from_numpy(labels.astype(np.float32))
    off = torch.from_numpy(offsets.astype(np.float32))
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], opts.hidden), torch.nn.ReLU(), torch.nn.Linear(opts.hidden, 3))
    optim = torch.optim.Adam(net.parameters(), lr=opts.lr, weight_decay=opts.weight_decay)
    n_pos = max(float(y.sum()), 1.0)
    n_neg = max(float(len(y) - y.sum()), 1.0)
    weight = torch.where(y > 0, 0.5 / n_pos, 0.5 / n_neg)
    pos = y > 0
    for _ in range(opts.steps):
        optim.zero_grad()
        out = net(x)
        loss = (weight * torch.nn.functional.binary_cross_entropy_with_logits(out[:, 0], y, reduction="none")).sum()
        if pos.any():
            loss = loss + opts.offset_weight * torch.nn.functional.smooth_l1_loss(out[pos, 1:], off[pos], beta=0.05)
        loss.backward()
        optim.step()
    l1, l2 = net[0], net[2]
    return [t.detach().numpy().astype(np.float32) for t in (l1.weight.T, l1.bias, l2.weight.T, l2.bias)]


def _choose_threshold(per_image, truth):
    """Threshold of :data:`THRESHOLD_GRID` maximising recall - outlier_rate of the first candidate, and its scores."""
    from harness.experiments.detector.scores import score_detections

    best = None
    for t in THRESHOLD_GRID:
        found = []
        for prob, uv in per_image:
            keep = np.flatnonzero(prob >= t)
            found.append(uv[keep[np.argmax(prob[keep])]][None] if len(keep) else np.zeros((0, 2)))
        s = score_detections("ours", *truth, found)
        key = (np.nan_to_num(s.recall) - s.outlier_rate, t)
        if best is None or key > best[0]:
            best = (key, t, s)
    return best[1], best[2]


def train_verifier(model, originals, augmented, folds, opts: VerifierOptions, *, seed: int, log=print, progress: bool = False):
    """Fit a verifier for ``model``'s candidates; returns ``(CandidateVerifier, info)``.

    originals : list of ``(image, labelled)``, the labelled images (cross-validation scores these)
    augmented : list of ``(origin index, image, labelled)`` augmented copies (training only)
    folds : lists of indices into ``originals`` (time-contiguous folds)
    """
    import torch  # training only

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a tiny network: threads only wait for each other (badly so on a shared machine)
    try:
        return _train_verifier(torch, model, originals, augmented, folds, opts, seed=seed, log=log, progress=progress)
    finally:
        torch.set_num_threads(threads)


def _train_verifier(torch, model, originals, augmented, folds, opts: VerifierOptions, *, seed: int, log, progress: bool):
    from tqdm import tqdm

    from harness.experiments.detector.scores import truth_of

    rng = np.random.default_rng([seed, 7])
    f = 3 * opts.crop_px**2
    shape = CandidateVerifier(np.zeros((f, 1)), np.zeros(1), np.zeros((1, 3)), np.zeros(3), crop_px=opts.crop_px, context=opts.context,
                              min_side_px=max(opts.crop_px / 2, 4.0), max_side_px=max(8.0 * float(np.sqrt(model.area_range_px[1])), 16.0))
    rows = []  # (origin, feats, labels, offsets, is_cand, det or None)
    work = [(i, im, li, True) for i, (im, li) in enumerate(originals)] + [(o, im, li, False) for o, im, li in augmented]
    for origin, im, li, original in tqdm(work, desc="verifier examples", unit="img", disable=not progress, leave=False):
        feats, labels, offsets, is_cand, det = _examples(model, shape, im, li, opts, rng)
        rows.append((origin, feats, labels, offsets, is_cand, det if original else None, im))
    truth = ([truth_of(li)[0] for _, li in originals], [truth_of(li)[1] for _, li in originals])

    def stack(sel):
        return (np.concatenate([r[1] for r in sel]), np.concatenate([r[2] for r in sel]), np.concatenate([r[3] for r in sel]))

    per_image = [None] * len(originals)
    for k, fold in enumerate(folds):
        inside = set(fold)
        train_rows = [r for r in rows if r[0] not in inside]
        feats, labels, offsets = stack(train_rows)
        if labels.sum() == 0:
            continue
        v = CandidateVerifier(*_fit(torch, feats, labels, offsets, opts, seed + 1000 * (k + 1)), crop_px=opts.crop_px, context=opts.context,
                              min_side_px=shape.min_side_px, max_side_px=shape.max_side_px)
        for r in rows:
            if r[0] in inside and r[5] is not None:
                det = r[5]
                prob, uv = v.verify(r[6], det.uv_px, det.boxes_xywh[:, 2:].max(axis=1)) if len(det) else (np.zeros(0), np.zeros((0, 2)))
                per_image[r[0]] = (prob, uv)
    per_image = [p if p is not None else (np.zeros(0), np.zeros((0, 2))) for p in per_image]
    threshold, s_cv = _choose_threshold(per_image, truth)
    feats, labels, offsets = stack(rows)
    weights = _fit(torch, feats, labels, offsets, opts, seed)
    verifier = CandidateVerifier(*weights, crop_px=opts.crop_px, context=opts.context, min_side_px=shape.min_side_px,
                                 max_side_px=shape.max_side_px, threshold=threshold)
    cand = [r[5] for r in rows if r[5] is not None]
    cand_recall = _candidate_recall(cand, truth)
    log(f"verifier: {int(labels.sum())} ball / {int(len(labels) - labels.sum())} background crops; candidates reach "
        f"{100 * cand_recall:.1f}% of the balls; {len(folds)}-fold cv at threshold {threshold:g}: recall {100 * s_cv.recall:.2f}%, "
        f"outliers {100 * s_cv.outlier_rate:.2f}%, median {s_cv.median_center_error_px:.3f} px")
    return verifier, dict(threshold=threshold, cv=s_cv, candidate_recall=cand_recall, n_examples=len(labels), n_ball=int(labels.sum()))


def _candidate_recall(dets, truth) -> float:
    hit = n = 0
    for det, c, d in zip(dets, *truth):
        for cj, dj in zip(c, d):
            n += 1
            hit += bool(len(det)) and bool((np.linalg.norm(det.uv_px - cj, axis=1) <= dj).any())
    return hit / n if n else float("nan")

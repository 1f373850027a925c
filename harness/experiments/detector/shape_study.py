"""A study of a ball-scale shape stage for white balls on real frames (not a shipped detector).

A 5x5 colour filter cannot tell a white ball from the white things around it. This study measures
whether a stage that sees the ball's *scale* can propose it, and what a crop classifier then makes of
the proposals:

1. **Proposer.** On the image downscaled by ``scale`` (``cv2.INTER_AREA``), each channel mapped by
   ``log(p + 8)``: for every channel and every ``(inner, outer)`` box pair, the inner box mean and the
   inner mean minus the mean of the ring between the boxes (``cv2.boxFilter``): ``3 * 2 * len(boxes)``
   features per pixel, standardised, then a logistic regression on the features and their pairwise
   products (LBFGS, L2). Positives: pixels near a labelled centre; negatives: random far pixels, then
   (second round) the first round's strongest local maxima away from the ball (hard negatives).
   Candidates are the local maxima of the response (``nms_px`` neighbourhood at the small scale), best first.
2. **Verifier.** :class:`~tracker.detection.verifier.CandidateVerifier`'s crop features (16x16
   log-chroma crops of a fixed side ``crop_side_px``) into a 768-16-3 perceptron (dropout, weight decay,
   Adam): ball logit and centre offset. Positives: jittered crops at the labelled balls; negatives: the
   proposer's candidates away from the ball and on the same frames with the balls painted out.
3. **Figures** on the held-out frames: how often the ball is among the first 1 / 4 / 16 / 32 candidates;
   for the verifier seeing the first 16 or all 32 candidates and for its thresholds, recall (the ball among the kept top-4 within two radii, as in
   ``rt2 eval detector``), outlier rate (kept candidates off the ball / all kept), median centre error
   and false alarms on the same frames with the balls painted out.

Training runs on one CPU thread (numpy, OpenCV, torch) and is seeded: the same seed gives the same
figures. ``python -m harness.experiments.detector.shape_study --data DIR --train-range 0:58
--test-range 58: --seed 0``.
"""

from __future__ import annotations

import argparse
import json
import sys

import cv2
import numpy as np

from harness.experiments.detector.ballfree import mask_balls
from harness.experiments.detector.coco import read_coco
from harness.experiments.detector.subsets import parse_range, take_range
from harness.experiments.detector.train import load_image
from tracker.detection.verifier import CandidateVerifier

__all__ = ["run_study"]

BOXES_PX = ((3, 7), (5, 11), (7, 15), (11, 23))  #: (inner, outer) box sides at the small scale
THRESHOLDS = (0.5, 0.9, 0.95, 0.98)
VERIFIED = (16, 32)  #: the verifier sees the first 16, or all 32, candidates


def _features(image, scale: float) -> np.ndarray:
    """(h, w, 24) float32 box features of an (H, W, 3) uint8 image downscaled by ``scale``."""
    small = cv2.resize(image, None, fx=1.0 / scale, fy=1.0 / scale, interpolation=cv2.INTER_AREA)
    x = np.log(small.astype(np.float32) + np.float32(8.0))
    out = []
    for c in range(3):
        ch = np.ascontiguousarray(x[:, :, c])
        for di, do in BOXES_PX:
            a = cv2.boxFilter(ch, -1, (di, di), normalize=False, borderType=cv2.BORDER_REFLECT_101)
            b = cv2.boxFilter(ch, -1, (do, do), normalize=False, borderType=cv2.BORDER_REFLECT_101)
            inner = a / (di * di)
            out += [inner, inner - (b - a) / (do * do - di * di)]
    return np.stack(out, -1)


def _quadratic(z):
    import torch

    iu = torch.triu_indices(z.shape[1], z.shape[1])
    return torch.cat([z, (z[:, :, None] * z[:, None, :])[:, iu[0], iu[1]]], 1)


class _Proposer:
    def __init__(self, scale: float, nms_px: int):
        self.scale, self.nms_px = scale, nms_px

    def response(self, feats):
        import torch

        h, w, nf = feats.shape
        z = torch.as_tensor(((feats.reshape(-1, nf) - self.mu) / self.sd).astype(np.float32))
        with torch.no_grad():
            return (_quadratic(z) @ self.w + self.b).numpy().reshape(h, w).astype(np.float32)

    def maxima(self, feats, k: int):
        """(k, 2) candidate centres at the small scale (column, row) and their responses, best first."""
        r = self.response(feats)
        ys, xs = np.nonzero(r >= cv2.dilate(r, np.ones((self.nms_px, self.nms_px), np.uint8)))
        order = np.argsort(-r[ys, xs], kind="stable")[:k]
        return np.stack([xs[order], ys[order]], 1).astype(np.float64), r[ys, xs][order]

    def fit(self, feats, centers, sizes, rng, n_negatives: int = 3000):
        nf = feats[0].shape[2]
        xs, ys = [], []
        for f, c, s in zip(feats, centers, sizes):
            h, w = f.shape[:2]
            yy, xx = np.mgrid[:h, :w]
            dist = np.hypot(xx - c[0], yy - c[1]).ravel()
            pos = np.flatnonzero(dist <= max(1.5, 0.15 * s))
            far = np.flatnonzero(dist > 0.6 * s)
            neg = rng.choice(far, min(n_negatives, len(far)), replace=False)
            xs += [f.reshape(-1, nf)[pos], f.reshape(-1, nf)[neg]]
            ys += [np.ones(len(pos)), np.zeros(len(neg))]
        x0, y0 = np.concatenate(xs).astype(np.float32), np.concatenate(ys).astype(np.float32)
        self.mu, self.sd = x0.mean(0), x0.std(0) + 1e-6
        self._lbfgs(x0, y0)
        hard = []  # second round: the first round's strong maxima away from the ball
        for f, c, s in zip(feats, centers, sizes):
            p, _ = self.maxima(f, 64)
            far = np.hypot(*(p - c).T) > 0.6 * s
            hard.append(f[p[far, 1].astype(int), p[far, 0].astype(int)])
        hard = np.concatenate(hard).astype(np.float32)
        self._lbfgs(np.concatenate([x0, hard]), np.concatenate([y0, np.zeros(len(hard), np.float32)]))
        return self

    def _lbfgs(self, x, y):
        import torch

        z = _quadratic(torch.as_tensor((x - self.mu) / self.sd))
        yt = torch.as_tensor(y)
        w = torch.zeros(z.shape[1], requires_grad=True)
        b = torch.zeros(1, requires_grad=True)
        pos_weight = torch.tensor(float((y == 0).sum() / max((y == 1).sum(), 1)))
        opt = torch.optim.LBFGS([w, b], max_iter=300)

        def closure():
            opt.zero_grad()
            loss = torch.nn.functional.binary_cross_entropy_with_logits(z @ w + b, yt, pos_weight=pos_weight) + 1e-3 * (w * w).sum()
            loss.backward()
            return loss

        opt.step(closure)
        self.w, self.b = w.detach(), b.detach()


def run_study(data, train_range: str = "0:58", test_range: str = "58:", *, seed: int = 0, scale: float = 4.0,
              nms_px: int = 9, n_candidates: int = max(VERIFIED), crop_side_px: float = 80.0, epochs: int = 150) -> dict:
    """The figures of the module docstring as a dict (JSON-ready). ``data``: a COCO file or folder."""
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    labelled = read_coco(data)
    train, test = take_range(labelled, train_range, "--train-range"), take_range(labelled, test_range, "--test-range")
    for name, part in (("--train-range", train), ("--test-range", test)):
        if not part or any(len(li.boxes_xywh) != 1 for li in part):
            raise ValueError(f"{name}: need frames with exactly one labelled ball each, got {len(part)} frames")
    images = [load_image(li) for li in train + test]
    free = [mask_balls(im, li.boxes_xywh) for im, li in zip(images, train + test)]
    centers = np.array([li.centers_px[0] for li in train + test])
    sizes = np.array([li.boxes_xywh[0, 2:].max() for li in train + test])
    small_c = (centers + 0.5) / scale - 0.5
    feats = [_features(im, scale) for im in images]
    n_tr = len(train)
    prop = _Proposer(scale, nms_px).fit(feats[:n_tr], small_c[:n_tr], sizes[:n_tr] / scale, rng)

    def candidates(f):
        p, _ = prop.maxima(f, n_candidates)
        return (p + 0.5) * scale - 0.5

    cands = [candidates(f) for f in feats]
    cands_free = [candidates(_features(im, scale)) for im in free]
    ranks = []
    for p, c, s in zip(cands[n_tr:], centers[n_tr:], sizes[n_tr:]):
        hit = np.flatnonzero(np.hypot(*(p - c).T) < s / 2)
        ranks.append(int(hit[0]) if len(hit) else None)

    crop = CandidateVerifier(np.zeros((768, 1)), np.zeros(1), np.zeros((1, 3)), np.zeros(3), crop_px=16)

    def crops(image, pts):
        return crop.features(image, pts, np.full(len(pts), crop_side_px))

    xp, op, xn = [], [], []
    for i in range(n_tr):
        jit = rng.uniform(-0.12, 0.12, (30, 2)) * crop_side_px
        sides = crop_side_px * np.exp(rng.uniform(-0.15, 0.15, 30))
        xp.append(crop.features(images[i], centers[i] + jit, sides))
        op.append(-jit / sides[:, None])
        far = np.hypot(*(cands[i] - centers[i]).T) > 0.6 * sizes[i]
        xn += [crops(images[i], cands[i][far]), crops(free[i], cands_free[i])]
    xp, op, xn = np.concatenate(xp), np.concatenate(op), np.concatenate(xn)
    x = torch.as_tensor(np.concatenate([xp, xn]), dtype=torch.float32)
    y = torch.as_tensor(np.r_[np.ones(len(xp)), np.zeros(len(xn))], dtype=torch.float32)
    off = torch.as_tensor(np.concatenate([op, np.zeros((len(xn), 2))]), dtype=torch.float32)
    net = torch.nn.Sequential(torch.nn.Dropout(0.2), torch.nn.Linear(768, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3))
    opt = torch.optim.Adam(net.parameters(), 1e-3, weight_decay=1e-2)
    pos_weight = torch.tensor(len(xn) / len(xp))
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        perm = torch.randperm(len(x), generator=gen)
        for k in range(0, len(x), 256):
            idx = perm[k : k + 256]
            out = net(x[idx])
            loss = torch.nn.functional.binary_cross_entropy_with_logits(out[:, 0], y[idx], pos_weight=pos_weight)
            loss = loss + 20 * (((out[:, 1:] - off[idx]) ** 2).sum(1) * y[idx]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    net.eval()

    def verify(image, pts):
        with torch.no_grad():
            o = net(torch.as_tensor(crops(image, pts), dtype=torch.float32)).numpy().astype(np.float64)
        prob = 1.0 / (1.0 + np.exp(-o[:, 0]))
        order = np.argsort(-prob, kind="stable")[:4]
        return prob[order], (pts + o[:, 1:] * crop_side_px)[order]

    rows = []
    for n_verified in VERIFIED:  # the verifier sees the first n_verified candidates
        kept = [verify(images[i], cands[i][:n_verified]) for i in range(n_tr, len(images))]
        alarms = [verify(free[i], cands_free[i][:n_verified])[0].max() for i in range(n_tr, len(images))]
        for th in THRESHOLDS:
            n_det = n_off = n_hit = 0
            errors = []
            for (prob, uv), c, s in zip(kept, centers[n_tr:], sizes[n_tr:]):
                d = np.hypot(*(uv[prob >= th] - c).T)
                n_det += len(d)
                n_off += int((d >= s).sum())
                if (d < s).any():
                    n_hit += 1
                    errors.append(float(d[d < s].min()))
            rows.append(dict(verified=n_verified, threshold=th, recall=n_hit / len(kept), outlier_rate=n_off / max(n_det, 1),
                             median_center_error_px=float(np.median(errors)) if errors else float("nan"),
                             ball_free_alarm_rate=float(np.mean(np.array(alarms) >= th))))
    n = len(ranks)
    reach = {str(k): sum(r is not None and r < k for r in ranks) / n for k in (1, 4, 16, n_candidates)}
    return dict(data=str(data), train_range=train_range, test_range=test_range, seed=seed, n_train=n_tr, n_test=n,
                candidate_reach=reach, candidate_ranks=ranks, verifier=rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.experiments.detector.shape_study", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, help="COCO file or folder (one labelled ball per frame)")
    parser.add_argument("--train-range", default="0:58", help="time-ordered frames to train on (START:STOP)")
    parser.add_argument("--test-range", default="58:", help="time-ordered frames held out (START:STOP)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    try:
        parse_range(args.train_range, "--train-range")
        parse_range(args.test_range, "--test-range")
        res = run_study(args.data, args.train_range, args.test_range, seed=args.seed)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    reach = "  ".join(f"top-{k} {100 * v:.0f}%" for k, v in res["candidate_reach"].items())
    print(f"{res['n_train']} training frames, {res['n_test']} held out; ball among the proposer's candidates: {reach}")
    print(f"{'verified':>8} {'threshold':>9} {'recall':>7} {'outliers':>9} {'median px':>10} {'ball-free alarms':>17}")
    for r in res["verifier"]:
        print(f"{r['verified']:8d} {r['threshold']:9.2f} {100 * r['recall']:6.0f}% {100 * r['outlier_rate']:8.0f}% {r['median_center_error_px']:10.2f} "
              f"{100 * r['ball_free_alarm_rate']:16.0f}%")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

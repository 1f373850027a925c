"""A study of the white ball on real frames: the ball-scale proposer of ``shape_study`` trained on far
more varied (drawn) balls, and a small CNN crop verifier with a centre-offset head (not a shipped detector).

1. **Training data we make.** Real backgrounds: the training frames with their ball painted out
   (``ballfree.mask_balls``) and frames of ball-free videos (``--backgrounds``, e.g. the caliscope
   cameras). Into every background ``--synthetic-per-frame`` white balls are drawn
   (``white_balls``: cream/peach tint, shading, highlight, motion blur into capsules, defocus, noise;
   exact centres), one per copy, and ``--synthetic-crops`` more into random windows of them for the
   verifier.
2. **Proposer**: ``shape_study``'s box features + quadratic logistic regression at 1/``scale`` (its
   response evaluated as a numpy quadratic form), trained on the real training frames, the drawn frames
   and the backgrounds (``--proposer-data all``: 300 random negatives per frame, hard negatives in a
   second round) or, as ``shape_study``, on the real training frames alone (``real``: 3000 per frame).
3. **Verifier**: a CNN on ``crop_px`` x ``crop_px`` crops of side ``crop_side_px`` around each
   candidate (``log(p + 8)`` per channel minus the crop's channel means): three 3x3 conv + ReLU + 2x2
   max-pool layers, a hidden layer and three outputs (ball logit, centre offset in units of the crop
   side). Trained with torch; inference is numpy (:func:`cnn_forward`; a test checks it against
   torch). The centre is refined by ``refine_steps`` re-crops at the predicted centre.
4. **Figures** on the held-out frames and the same frames with the ball painted out, as
   ``rt2 eval detector`` defines them (a detection is on the ball within two radii, radius = half the
   box's shorter side): for every threshold, ``top1`` (the best kept candidate) and ``top4`` (every
   kept candidate among the first four): recall, outlier rate, median centre error and the
   fraction of ball-free frames with an alarm.

Seeded (numpy rng, torch generator; one thread). ``python -m harness.experiments.detector.white_study
--data DIR --train-range 0:58 --test-range 58: --backgrounds VIDEO ... --seed 0``.
"""

from __future__ import annotations

import argparse
import json
import sys

import cv2
import numpy as np

from harness.experiments.detector.backgrounds import read_backgrounds
from harness.experiments.detector.ballfree import mask_balls
from harness.experiments.detector.coco import read_coco
from harness.experiments.detector.shape_study import _features, _Proposer
from harness.experiments.detector.subsets import parse_range, take_range
from harness.experiments.detector.train import load_image
from harness.experiments.detector.white_balls import draw_white_ball, random_ball

__all__ = ["cnn_forward", "crop_features", "run_white_study"]

THRESHOLDS = (0.5, 0.8, 0.9, 0.95, 0.98)
CHANNELS = (8, 16, 32)  #: conv layers' output channels
HIDDEN = 32
_LUT = np.log(np.arange(256, dtype=np.float32) + np.float32(8.0))


def crop_features(image, centers_px, side_px: float, crop_px: int) -> np.ndarray:
    """(n, crop_px, crop_px, 3) float32: log crops of side ``side_px`` around (n, 2) centres, channel means removed."""
    centers = np.asarray(centers_px, np.float64).reshape(-1, 2)
    side = int(round(side_px))
    out = np.empty((len(centers), crop_px, crop_px, 3), np.uint8)
    for i, (u, v) in enumerate(centers):
        patch = cv2.getRectSubPix(image, (side, side), (float(u), float(v)))
        out[i] = cv2.resize(patch, (crop_px, crop_px), interpolation=cv2.INTER_AREA)
    x = _LUT[out]
    return x - x.mean(axis=(1, 2), keepdims=True)


def _conv3x3_relu_pool(x, w, b):
    """NHWC 3x3 'same' convolution (torch weight (Cout, Cin, 3, 3)), ReLU, 2x2 max-pool."""
    n, h, wd, c = x.shape
    xp = np.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)))
    cols = np.lib.stride_tricks.sliding_window_view(xp, (3, 3), axis=(1, 2)).reshape(n * h * wd, c * 9)
    y = np.maximum(cols @ w.reshape(len(w), -1).T + b, 0.0).reshape(n, h, wd, -1)
    return y.reshape(n, h // 2, 2, wd // 2, 2, -1).max(axis=(2, 4))


def cnn_forward(params: dict, x: np.ndarray) -> np.ndarray:
    """(n, 3) outputs (ball logit, offset u, offset v) of (n, crop, crop, 3) float32 crop features, numpy only."""
    for k in range(len(CHANNELS)):
        x = _conv3x3_relu_pool(x, params[f"conv{k}_w"], params[f"conv{k}_b"])
    x = x.transpose(0, 3, 1, 2).reshape(len(x), -1)  # torch's (C, H, W) flattening
    x = np.maximum(x @ params["fc0_w"].T + params["fc0_b"], 0.0)
    return x @ params["fc1_w"].T + params["fc1_b"]


def _torch_cnn(crop_px: int):
    import torch

    layers, c_in = [], 3
    for c in CHANNELS:
        layers += [torch.nn.Conv2d(c_in, c, 3, padding=1), torch.nn.ReLU(), torch.nn.MaxPool2d(2)]
        c_in = c
    side = crop_px // 2 ** len(CHANNELS)
    layers += [torch.nn.Flatten(), torch.nn.Linear(c_in * side * side, HIDDEN), torch.nn.ReLU(), torch.nn.Linear(HIDDEN, 3)]
    return torch.nn.Sequential(*layers)


def _params(net) -> dict:
    convs = [m for m in net if m.__class__.__name__ == "Conv2d"]
    fcs = [m for m in net if m.__class__.__name__ == "Linear"]
    out = {}
    for k, m in enumerate(convs):
        out[f"conv{k}_w"], out[f"conv{k}_b"] = m.weight.detach().numpy().copy(), m.bias.detach().numpy().copy()
    for k, m in enumerate(fcs):
        out[f"fc{k}_w"], out[f"fc{k}_b"] = m.weight.detach().numpy().copy(), m.bias.detach().numpy().copy()
    return out


class _NumpyProposer(_Proposer):
    """``shape_study``'s proposer with its response as a numpy quadratic form ``z . wl + z^T A z + b``
    (the same numbers as the torch expansion into products, without the (n, 24, 24) tensor)."""

    def response(self, feats):
        h, w, nf = feats.shape
        wt = self.w.numpy().astype(np.float64)
        a = np.zeros((nf, nf))
        a[np.triu_indices(nf)] = wt[nf:]
        z = (feats.reshape(-1, nf) - self.mu) / self.sd
        r = z @ wt[:nf].astype(np.float32) + ((z @ a.astype(np.float32)) * z).sum(1) + float(self.b)
        return r.reshape(h, w).astype(np.float32)


class _LazyFeatures:
    """The proposer's features of a list of images, computed when read (hundreds of frames' features do not fit in memory)."""

    def __init__(self, images, scale: float):
        self.images, self.scale = images, scale

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, i):
        return _features(self.images[i], self.scale)

    def __iter__(self):
        return (_features(im, self.scale) for im in self.images)


def _hits(uv, center, box):
    """(k,) distances of candidates to the ball and the hit radius (the box's shorter side = two radii)."""
    return np.hypot(*(np.asarray(uv).reshape(-1, 2) - center).T), float(min(box[2], box[3]))


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run_white_study(data, train_range: str = "0:58", test_range: str = "58:", *, backgrounds=(), background_frames: int = 8,
                    seed: int = 0, synthetic_per_frame: int = 2, synthetic_crops: int = 3000, scale: float = 4.0,
                    nms_px: int = 9, n_candidates: int = 32, crop_side_px: float = 80.0, crop_px: int = 32,
                    epochs: int = 12, refine_steps: int = 2, proposer_data: str = "all") -> dict:
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
    tr_img = [load_image(li) for li in train]
    te_img = [load_image(li) for li in test]
    tr_box = np.array([li.boxes_xywh[0] for li in train])
    te_box = np.array([li.boxes_xywh[0] for li in test])
    tr_c = np.array([li.centers_px[0] for li in train])
    te_c = np.array([li.centers_px[0] for li in test])
    tr_free = [mask_balls(im, li.boxes_xywh) for im, li in zip(tr_img, train)]
    te_free = [mask_balls(im, li.boxes_xywh) for im, li in zip(te_img, test)]
    bgs = tr_free + [im for im, _ in read_backgrounds(backgrounds, background_frames, load_image=load_image)]

    # -- drawn balls in real backgrounds ---------------------------------------------------------------
    syn_img, syn_c, syn_box = [], [], []
    for bg in bgs:
        h, w = bg.shape[:2]
        for _ in range(synthetic_per_frame):
            c = rng.uniform([40, 40], [w - 40, h - 40])
            im, box = draw_white_ball(bg, random_ball(rng, c), rng)
            syn_img.append(im), syn_c.append(c), syn_box.append(box)
    syn_c, syn_box = np.array(syn_c), np.array(syn_box)

    _log(f"{len(syn_img)} drawn frames; fitting the proposer")
    # -- proposer ------------------------------------------------------------------------------------
    prop = _NumpyProposer(scale, nms_px)
    far = np.array([-1e4, -1e4])
    fit_imgs = tr_img + syn_img + bgs
    fit_c = np.concatenate([tr_c, syn_c, np.tile(far, (len(bgs), 1))])
    fit_s = np.concatenate([tr_box[:, 2:].max(1), syn_box[:, 2:].max(1), np.ones(len(bgs))])
    if proposer_data == "all":  # the real training frames, the drawn frames and the backgrounds
        prop.fit(_LazyFeatures(fit_imgs, scale), (fit_c + 0.5) / scale - 0.5, fit_s / scale, rng, n_negatives=300)
    else:  # the real training frames only (as shape_study)
        prop.fit(_LazyFeatures(tr_img, scale), (tr_c + 0.5) / scale - 0.5, tr_box[:, 2:].max(1) / scale, rng, n_negatives=3000)

    def candidates(im):
        p, _ = prop.maxima(_features(im, scale), n_candidates)
        return (p + 0.5) * scale - 0.5

    fit_cands = [candidates(im) for im in fit_imgs]
    te_cands = [candidates(im) for im in te_img]
    te_free_cands = [candidates(im) for im in te_free]

    _log("candidates found; building the verifier's crops")
    # -- verifier training set -----------------------------------------------------------------------
    S = crop_side_px
    xp, op, xn = [], [], []
    ball_c = np.concatenate([tr_c, syn_c])
    ball_box = np.concatenate([tr_box, syn_box])
    for k, (im, c, box) in enumerate(zip(tr_img + syn_img, ball_c, ball_box)):
        n_jit = 24 if k < len(tr_img) else 8
        jit = rng.uniform(-0.12, 0.12, (n_jit, 2)) * S
        xp.append(crop_features(im, c + jit, S, crop_px))
        op.append(-jit / S)
    for _ in range(synthetic_crops):  # more drawn balls, each in a window of a random background
        bg = bgs[rng.integers(len(bgs))]
        h, w = bg.shape[:2]
        u0, v0 = int(rng.integers(0, w - 160)), int(rng.integers(0, h - 160))
        win = np.ascontiguousarray(bg[v0 : v0 + 160, u0 : u0 + 160])
        c = np.array([80.0, 80.0]) + rng.uniform(-0.12, 0.12, 2) * S
        im, _ = draw_white_ball(win, random_ball(rng, c), rng)
        xp.append(crop_features(im, [[80.0, 80.0]], S, crop_px))
        op.append(((c - 80.0) / S)[None])
    for k, (im, cand) in enumerate(zip(fit_imgs, fit_cands)):
        if k < len(ball_c):
            d, hit = _hits(cand, ball_c[k], ball_box[k])
            cand = cand[d > max(hit, 0.35 * S)]
        xn.append(crop_features(im, cand, S, crop_px))
    xp, op, xn = np.concatenate(xp), np.concatenate(op), np.concatenate(xn)

    x = np.concatenate([xp, xn])
    off = np.concatenate([op, np.zeros((len(xn), 2))])
    y = np.r_[np.ones(len(xp)), np.zeros(len(xn))]
    xt = torch.as_tensor(np.ascontiguousarray(x.transpose(0, 3, 1, 2)), dtype=torch.float32)
    yt, ot = torch.as_tensor(y, dtype=torch.float32), torch.as_tensor(off, dtype=torch.float32)
    _log(f"training the CNN on {len(xp)} ball and {len(xn)} other crops")
    net = _torch_cnn(crop_px)
    opt = torch.optim.Adam(net.parameters(), 2e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    pos_weight = torch.tensor(float((y == 0).sum() / max((y == 1).sum(), 1)))
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        perm = torch.randperm(len(xt), generator=gen)
        for k in range(0, len(xt), 128):
            idx = perm[k : k + 128]
            xb, ob = xt[idx], ot[idx]
            if torch.rand(1, generator=gen).item() < 0.5:  # a left-right flip (the offset's u flips with it)
                xb, ob = xb.flip(3), ob * torch.tensor([-1.0, 1.0])
            out = net(xb)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(out[:, 0], yt[idx], pos_weight=pos_weight)
            loss = loss + 50 * (((out[:, 1:] - ob) ** 2).sum(1) * yt[idx]).sum() / yt[idx].sum().clamp(min=1)
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    net.eval()
    params = _params(net)

    def verify(im, pts):
        """Probabilities and refined centres of the candidates, best first, duplicates merged."""
        pts = np.asarray(pts, np.float64)
        o = cnn_forward(params, crop_features(im, pts, S, crop_px))
        prob = 1.0 / (1.0 + np.exp(-o[:, 0].astype(np.float64)))
        uv = pts + o[:, 1:] * S
        for _ in range(refine_steps):
            uv = uv + cnn_forward(params, crop_features(im, uv, S, crop_px))[:, 1:] * S
        order = np.argsort(-prob, kind="stable")
        keep = []
        for i in order:  # one candidate per ball: drop those a better one already holds
            if all(np.hypot(*(uv[i] - uv[j])) > 0.25 * S for j in keep):
                keep.append(i)
        keep = np.array(keep[:4], int)
        return prob[keep], uv[keep]

    kept = [verify(im, p) for im, p in zip(te_img, te_cands)]
    alarms = np.array([verify(im, p)[0].max() for im, p in zip(te_free, te_free_cands)])
    rows = []
    for th in THRESHOLDS:
        for top in (1, 4):
            n_det = n_off = n_hit = 0
            errors = []
            for (prob, uv), c, box in zip(kept, te_c, te_box):
                d, hit = _hits(uv[:top][prob[:top] >= th], c, box)
                n_det += len(d)
                n_off += int((d >= hit).sum())
                if (d < hit).any():
                    n_hit += 1
                    errors.append(float(d[d < hit].min()))
            rows.append(dict(threshold=th, top=top, recall=n_hit / len(kept), outlier_rate=n_off / max(n_det, 1),
                             median_center_error_px=float(np.median(errors)) if errors else None,
                             ball_free_alarm_rate=float(np.mean(alarms >= th))))
    ranks = []
    for p, c, box in zip(te_cands, te_c, te_box):
        d, hit = _hits(p, c, box)
        ranks.append(int(np.flatnonzero(d < hit)[0]) if (d < hit).any() else None)
    n = len(ranks)
    reach = {str(k): sum(r is not None and r < k for r in ranks) / n for k in (1, 4, 16, n_candidates)}
    return dict(data=str(data), train_range=train_range, test_range=test_range, seed=seed, proposer_data=proposer_data,
                n_train=len(train), n_test=n,
                n_backgrounds=len(bgs), n_synthetic_frames=len(syn_img), n_positive_crops=int(len(xp)), n_negative_crops=int(len(xn)),
                candidate_reach=reach, candidate_ranks=ranks, verifier=rows, params=params)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.experiments.detector.white_study", description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, help="COCO file or folder (one labelled ball per frame)")
    parser.add_argument("--train-range", default="0:58", help="time-ordered frames to train on (START:STOP)")
    parser.add_argument("--test-range", default="58:", help="time-ordered frames held out (START:STOP)")
    parser.add_argument("--backgrounds", nargs="*", default=[], help="ball-free videos / COCO sets / image folders")
    parser.add_argument("--background-frames", type=int, default=8, help="frames per background video")
    parser.add_argument("--synthetic-per-frame", type=int, default=2, help="drawn-ball copies of every background")
    parser.add_argument("--synthetic-crops", type=int, default=3000, help="more drawn balls for the verifier")
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument("--proposer-data", choices=("all", "real"), default="all",
                        help="train the proposer on the real training frames, drawn frames and backgrounds (all), or the real frames only")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--save-params", help="write the verifier's weights to this .npz")
    args = parser.parse_args(argv)
    try:
        parse_range(args.train_range, "--train-range")
        parse_range(args.test_range, "--test-range")
        res = run_white_study(args.data, args.train_range, args.test_range, backgrounds=args.backgrounds,
                              background_frames=args.background_frames, seed=args.seed, synthetic_per_frame=args.synthetic_per_frame,
                              synthetic_crops=args.synthetic_crops, epochs=args.epochs,
                              proposer_data=args.proposer_data)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    params = res.pop("params")
    reach = "  ".join(f"top-{k} {100 * v:.0f}%" for k, v in res["candidate_reach"].items())
    print(f"{res['n_train']} training frames, {res['n_backgrounds']} backgrounds, {res['n_synthetic_frames']} drawn frames, "
          f"{res['n_positive_crops']} / {res['n_negative_crops']} ball / other crops; {res['n_test']} held out")
    print(f"ball among the proposer's candidates: {reach}")
    print(f"{'threshold':>9} {'top':>4} {'recall':>7} {'outliers':>9} {'median px':>10} {'ball-free alarms':>17}")
    for r in res["verifier"]:
        med = "-" if r["median_center_error_px"] is None else f"{r['median_center_error_px']:.2f}"
        print(f"{r['threshold']:9.2f} {r['top']:4d} {100 * r['recall']:6.0f}% {100 * r['outlier_rate']:8.0f}% {med:>10} "
              f"{100 * r['ball_free_alarm_rate']:16.0f}%")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)
    if args.save_params:
        np.savez(args.save_params, **params)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

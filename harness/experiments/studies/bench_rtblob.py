"""``rt2 bench rtblob``: milliseconds per VGA frame of the RTBlob baseline, one thread.

Rows (all in one process, same images; medians over ``--repeats`` runs after a warm-up):

* ``likelihood`` — Eq. (1) through the look-up tables, and its plain float64 formula (reference);
* ``detect <method>`` — Eq. (1)-(3) per camera image: likelihood + disk correlation + arg-max, for
  every correlation method (``numpy`` FFT is the reference the ratios are taken against);
* ``process 4 cams`` — :meth:`RTBlobTracker.process` on a 4-camera frame set with default options
  (four detections, two pair triangulations, covariance): ms per frame set and frame sets per second.

The scene: four 640x480 cameras around the table looking at a ball 2.8-3 m away, textured grey
background (seeded). Run on a loaded machine the numbers are noisy: compare ratios from one run.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from tracker.rtblob import CORRELATION_METHODS, likelihood_reference
from tracker.camera import Camera
from tracker.detection.synthetic import draw_disk
from tracker.observation import FrameSet
from tracker.rig import Rig
from tracker.rtblob import RTBlobDetector, RTBlobOptions, RTBlobTracker

__all__ = ["add_arguments", "bench", "bench_scene", "run"]

BALL_M = np.array([0.5, 0.1, 1.0])


def _medians_ms(fns: dict, repeats: int, warmup: int = 5) -> dict:
    """Median ms of each callable, timed round-robin so that load changes hit every row alike."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times = {k: np.empty(repeats) for k in fns}
    for i in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k][i] = time.perf_counter() - t0
    return {k: float(np.median(t) * 1e3) for k, t in times.items()}


def bench_scene(seed: int) -> tuple[Rig, tuple]:
    """Four VGA cameras 2.6 m up, two per long side of the table, and one frame set with a ball."""
    rng = np.random.default_rng(seed)
    cams = []
    for i, c in enumerate([(-0.4, 1.9, 2.6), (0.9, 1.9, 2.6), (-0.4, -1.9, 2.6), (0.9, -1.9, 2.6)]):
        z = np.array([0.3, 0.0, 0.95]) - c
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        K = [[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]]
        cams.append(Camera(f"cam{i}", K, [-0.12, 0.06, 0.0, 0.0, 0.0], R, -R @ np.asarray(c), (640, 480)))
    rig = Rig(cams)
    images = []
    for cam in rig:
        img = np.clip(rng.normal(110, 25, (480, 640, 1)) + rng.normal(0, 6, (480, 640, 3)), 0, 255).astype(np.uint8)
        draw_disk(img, cam.project(BALL_M), 2 * cam.K[0, 0] * 0.02 / cam.depth(BALL_M)[0], (235, 120, 25))
        images.append(img)
    return rig, tuple(images)


def bench(rig: Rig, images: tuple, *, radii_px=(4.0, 8.0), repeats: int = 50) -> list[dict]:
    """Rows: dicts with stage, method, radius_px, median_ms (and ratio_vs_numpy for detect rows)."""
    cv2.setNumThreads(1)
    img = images[0]
    W, H = rig[0].image_size
    opts = RTBlobOptions()
    det = RTBlobDetector((W, H), radii_px[0], opts)
    ms = _medians_ms({"lut": lambda: det.likelihood(img), "float64 reference": lambda: likelihood_reference(img, opts)}, repeats)
    rows = [dict(stage="likelihood", method=k, radius_px=None, median_ms=v) for k, v in ms.items()]
    for r in radii_px:
        dets = {}
        for method in CORRELATION_METHODS:
            d = RTBlobDetector((W, H), r, RTBlobOptions(correlation=method))
            dets[f"auto ({d.correlation})" if method == "auto" else method] = d
        ms = _medians_ms({k: (lambda d=d: d.detect(img)) for k, d in dets.items()}, repeats)
        rows += [dict(stage="detect", method=k, radius_px=float(r), median_ms=v, ratio_vs_numpy=v / ms["numpy"])
                 for k, v in ms.items()]
    tracker = RTBlobTracker(rig, opts)
    fs = FrameSet(0.0, images)
    obs = tracker.process(fs)
    if not obs.has_position or np.linalg.norm(obs.position_m - BALL_M) > 0.02:
        raise ValueError("the benchmark scene's ball was not found: the RTBlob options do not fit the scene")
    ms = _medians_ms({"process": lambda: tracker.process(fs)}, repeats)
    rows.append(dict(stage="process", method=f"{len(rig)} cams, default options", radius_px=float(tracker.radius_px[0]),
                     median_ms=ms["process"]))
    return rows


def add_arguments(parser) -> None:
    parser.add_argument("--repeats", type=int, default=50, help="timed runs per row (default 50)")
    parser.add_argument("--radius-px", type=float, nargs="+", default=[4.0, 8.0], help="disk radii to time (default 4 8)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic background")
    parser.add_argument("--json", default=None, help="also write the rows as JSON to this path")


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the benchmark, not after
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    if min(args.radius_px) < 1:
        raise ValueError(f"--radius-px must be >= 1, got {args.radius_px}")
    rig, images = bench_scene(args.seed)
    rows = bench(rig, images, radii_px=tuple(args.radius_px), repeats=args.repeats)
    print(f"RTBlob baseline, one thread, 640x480 frames (synthetic, seed {args.seed}); medians of {args.repeats} runs")
    print(f"{'stage':<11} {'method':<28} {'r px':>5} {'median ms':>10} {'vs numpy':>9}")
    for r in rows:
        rad = "" if r["radius_px"] is None else f"{r['radius_px']:g}"
        ratio = f"{r['ratio_vs_numpy']:.2f}x" if "ratio_vs_numpy" in r else ""
        print(f"{r['stage']:<11} {r['method']:<28} {rad:>5} {r['median_ms']:10.3f} {ratio:>9}")
    proc = rows[-1]["median_ms"]
    print(f"process: {1e3 / proc:.0f} frame sets per second (4 cameras, one thread)")
    if args.json:
        atomic_write_json(args.json, rows, "--json")
    return 0

"""``rt2 bench detector``: milliseconds per VGA frame of the ball detector on one core.

Rows (all in one process, one thread each, same image, same weights):

* ``full / cv2`` — the production path: ``BallDetector.detect`` on the whole frame (the logits in one
  compiled pass: the input transform's lookup and the 5x5x3 correlation, ``tracker/detection/_correlate.py``;
  Algorithm 1 with top-K candidates, numba flood fill). The row keeps its name for the scripts that read it.
* ``full / cv2 every pixel`` — the same with the logits of every pixel computed (``DetectorOptions.coarse_full_frame``
  off): the full-frame search before its coarse pass, the ratio's baseline; a breakdown row times the coarse pass alone.
* ``roi / cv2`` — the same in a window of side ``2 * roi_half_size_px`` around a predicted pixel.
* ``full / cv2 without verifier``, ``roi / cv2 without verifier`` (models with a candidate verifier
  only) — the same detector with the filter alone, so the verifier's cost is the difference; a
  breakdown row times the verifier on the frame's candidates.
* ``full / learned``, ``roi / learned`` (models with a learned stage, :mod:`tracker.detection.learned`) — what
  ``rt2`` detects with: the heatmap network (ONNX Runtime, one thread) on the whole frame (in two passes when
  the stage has a coarse pass) and on the window with its context; the ``cv2`` rows are then the same model's
  filter and Algorithm 1 (what ``rt2-paper`` runs), and a breakdown row times one full-scale pass over the frame;
  where the stage has a confirmation network (:mod:`tracker.detection.confirm`), a breakdown row times the whole
  frame without it (its cost is the difference).
* ``full / torch``, ``roi / torch`` — the same model as ``torch.nn.Conv2d`` (reflect padding) +
  sigmoid + argmax in torch (Algorithm 1 line 1 only, no flood fill), from the same uint8 image.

Breakdown rows (printed, not in ``--json``) split the cv2 path into its logits and Algorithm 1, and
time the same logits as three ``cv2.filter2D`` passes summed (the path before the compiled pass, kept
here as the baseline it is measured against).
Timings are medians over ``--repeats`` rounds after a warm-up; each round calls every row once
(round-robin), so the ratio torch / cv2 comes from the same run under the same load.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["add_arguments", "bench", "filter2d_logits", "run"]

VGA_HW = (480, 640)


def _median_ms(fns: dict, repeats: int, warmup: int = 20) -> dict:
    """Median milliseconds of each function, timed round-robin (one call of each per round), so load
    changes on a shared machine hit every row alike and the ratios stay fair."""
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


def _bench_image(data, seed: int, colour: str = "orange", finds=None):
    """A VGA frame with a ball: the first labelled image with a ball in ``data``, else a lab4_vga frame
    rendered from a seeded random scene (ball, person, robot, distractors) whose ball (of the model's
    ``colour``, "orange" or "white") camera 0 sees and, given ``finds(image, centre) -> bool``, the detector
    finds in its window (a window search is timed as it runs when it finds the ball)."""
    if data:
        from harness.experiments.detector.coco import read_coco
        from harness.experiments.detector.train import load_image

        for li in read_coco(data):
            if li.n_balls:
                return load_image(li), li.centers_px[0], str(li.path)
        raise ValueError(f"--data {data}: no image with a ball box")
    from harness.sim.render.renderer import Renderer
    from harness.sim.render.scenes import SceneOptions, random_scene
    from tracker import Rig

    rig = Rig.load(Path(__file__).resolve().parents[3] / "data" / "rigs" / "lab4_vga.yaml")
    renderer = Renderer(rig, seed=seed)
    options = SceneOptions(p_no_ball=0.0, p_white=1.0 if colour == "white" else 0.0)
    for i in range(100):
        scene = random_scene(np.random.default_rng([seed, i]), options=options, frame_index=i)
        images, truths = renderer.render_labelled(scene)
        if truths[0][0].visible and truths[0][0].diameter_px >= 8 and (finds is None or finds(images[0], truths[0][0].center_px)):
            return images[0], truths[0][0].center_px, f"rendered lab4_vga cam0 frame, {colour} ball (seed {seed}, scene {i})"
    raise ValueError(f"no rendered scene of seed {seed} shows camera 0 a ball the model finds")


def _torch_path(model, torch):
    """``(image, window) -> flat argmax`` with the model as a torch Conv2d + sigmoid + argmax."""
    conv = torch.nn.Conv2d(3, 1, 5, padding=2, padding_mode="reflect", bias=True)
    with torch.no_grad():
        conv.weight.copy_(torch.from_numpy(model.kernel_rgb_uint8.transpose(2, 0, 1)[None].copy()))
        conv.bias.fill_(model.bias_uint8)
    conv.eval()

    def detect(image, window=None):
        if window is not None:
            x0, y0, x1, y1 = window
            image = image[max(y0 - 2, 0) : y1 + 2, max(x0 - 2, 0) : x1 + 2]
        with torch.no_grad():
            x = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float()
            p = torch.sigmoid(conv(x))
            return int(torch.argmax(p))

    return detect


def blob_arguments(det) -> tuple[float, float, dict]:
    """``(t_high logit, t_low logit, keyword arguments)`` with which ``find_blobs`` runs Algorithm 1 as the
    full-frame search of ``det`` (a :class:`tracker.BallDetector`, method "ours") does, read from its public
    settings; a test holds the two to the same candidates."""
    from tracker.detection.model import logit

    if det.options.method != "ours":
        raise ValueError(f"the Algorithm 1 breakdown times the method 'ours', got {det.options.method!r}")
    o = det.options
    kw = dict(max_blobs=o.max_seeds if det.verifier is not None else o.max_candidates, max_seeds=o.max_seeds,
              min_area_px=det.area_range_px[0], max_area_px=det.area_range_px[1], min_fill_ratio=o.min_fill_ratio,
              max_aspect=o.max_aspect, backend=o.backend)
    return logit(det.t_high), logit(det.t_low), kw


def filter2d_logits(model, image):
    """The model's logits as three ``cv2.filter2D`` passes over the transformed channels, summed (the
    detector's path before its compiled pass): the baseline of the logits breakdown row. Equal to
    ``model.logits`` up to float32 rounding (the sums run in another order)."""
    import cv2

    from tracker.detection.model import transform_lut

    lut = transform_lut(model.input_transform, model.log_offset_dn)
    out = None
    for c, chan in enumerate(cv2.split(image)):
        x = cv2.LUT(chan, lut)
        r = cv2.filter2D(x, -1, model.kernel_rgb_uint8[:, :, c], borderType=cv2.BORDER_REFLECT_101)
        out = r if out is None else cv2.add(out, r)
    out += np.float32(model.bias_uint8)
    return out


def _window_detector(model, roi_half_size_px: int):
    """The detector whose window search is timed: the learned stage as a tracker runs it (at its tracking
    threshold, where the file has one), else the filter."""
    from tracker import BallDetector, DetectorOptions

    if model.learned is None:
        return BallDetector(model, DetectorOptions(roi_half_size_px=roi_half_size_px, learned=False))
    return BallDetector(model, DetectorOptions(roi_half_size_px=roi_half_size_px, learned_threshold=model.learned.track_threshold))


def _window(image, center_px, half: int) -> tuple:
    cu, cv = (int(round(v)) for v in center_px)
    h, w = image.shape[:2]
    return max(cu - half, 0), max(cv - half, 0), min(cu + half, w), min(cv + half, h)


def bench(model, image, roi_center_px, *, repeats: int = 300, roi_half_size_px: int = 32):
    """Return (rows for --json, breakdown rows): dicts with mode, backend, median_ms."""
    import cv2
    import torch  # the comparison baseline only; the detector never imports it

    from tracker import BallDetector, DetectorOptions
    from tracker.detection.blobs import find_blobs
    from tracker.detection.model import LogitWorkspace

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    det = BallDetector(model, DetectorOptions(roi_half_size_px=roi_half_size_px, learned=False))
    every = BallDetector(model, DetectorOptions(roi_half_size_px=roi_half_size_px, learned=False, coarse_full_frame=False))
    work = LogitWorkspace()
    learned = _window_detector(model, roi_half_size_px) if model.learned is not None else None
    window = _window(image, roi_center_px, roi_half_size_px)
    if len((learned or det).detect(image, window)) == 0:
        raise ValueError("the benchmark frame's ball is not found in its window: the model does not fit this image")
    if learned is not None:
        import dataclasses

        one_pass = dataclasses.replace(model.learned, coarse_side_px=0)
        extra_learned_full = {("full", "learned"): lambda: learned.detect(image)}
        if model.learned.coarse_side_px:
            extra_learned_full[("full", "learned: one pass at full scale")] = lambda: one_pass.candidates(image)
        extra_learned_roi = {("roi", "learned"): lambda: learned.detect(image, window)}
        if model.learned.scale_of(*image.shape[:2]) == 1.0:  # the network alone, on the very input the stage gives it
            net_full, net_roi = (model.learned.network_input(image, win, 1.0)[0] for win in (None, window))
            extra_learned_full[("full", "learned: network alone (ONNX Runtime)")] = lambda: model.learned.run(net_full)
            extra_learned_roi[("roi", "learned: network alone (ONNX Runtime)")] = lambda: model.learned.run(net_roi)
        if model.learned.confirm is not None:  # the second look at a whole frame's candidates: what it costs
            no_confirm = BallDetector(model, dataclasses.replace(learned.options, confirm=False))
            extra_learned_full[("full", "learned without the confirmation")] = lambda: no_confirm.detect(image)
        if not model.learned.filter_refines:  # the stage's centres from the ball's edge: what the edge fit costs
            no_edge = BallDetector(model, dataclasses.replace(learned.options, refine_edges=False))
            extra_learned_roi[("roi", "learned without the edge fit")] = lambda: no_edge.detect(image, window)
    else:
        extra_learned_full, extra_learned_roi = {}, {}
    tdet = _torch_path(model, torch)
    lg = model.logits(image)
    th, tl, blob_kw = blob_arguments(det)
    extra_full, extra_roi = {}, {}
    if model.verifier is not None:  # the same detector with the filter alone, and the verifier's own share
        plain = BallDetector(model, DetectorOptions(roi_half_size_px=roi_half_size_px, verify=False))
        cand = BallDetector(model, DetectorOptions(roi_half_size_px=roi_half_size_px, verify=False, max_candidates=det.options.max_seeds)).detect(image)
        sides = cand.boxes_xywh[:, 2:].max(axis=1)
        extra_full = {
            ("full", "cv2 without verifier"): lambda: plain.detect(image),
            ("full", f"cv2: verifier on {len(cand)} candidates' crops"): lambda: model.verifier.verify(image, cand.uv_px, sides),
        }
        extra_roi = {("roi", "cv2 without verifier"): lambda: plain.detect(image, window)}
    full = _median_ms(
        {
            **extra_learned_full,
            **extra_full,
            ("full", "cv2"): lambda: det.detect(image),
            ("full", "cv2 every pixel"): lambda: every.detect(image),
            ("full", "torch"): lambda: tdet(image),
            ("full", "cv2: logits only (LUT + one compiled 5x5x3 pass)"): lambda: model.logits(image),
            ("full", "cv2: logits as 3 x filter2D, summed (baseline)"): lambda: filter2d_logits(model, image),
            ("full", "cv2: Algorithm 1 top-K on given logits"): lambda: find_blobs(lg, th, tl, **blob_kw),
            ("full", "cv2: coarse pass only (every other pixel, 3x3)"): lambda: model.logits_coarse_trusted(image, work),
        },
        repeats,
    )
    roi = _median_ms({**extra_learned_roi, ("roi", "cv2"): lambda: det.detect(image, window), ("roi", "torch"): lambda: tdet(image, window), **extra_roi},
                     repeats * 10)
    timed = {**full, **roi}
    main = ([("full", "learned"), ("roi", "learned")] if learned is not None else []) + [("full", "cv2"), ("roi", "cv2"), ("full", "torch"), ("roi", "torch"),
                                                                                      ("full", "cv2 every pixel")]
    if model.verifier is not None:
        main += [("full", "cv2 without verifier"), ("roi", "cv2 without verifier")]
    rows = [dict(mode=m, backend=b, median_ms=timed[m, b]) for m, b in main]
    breakdown = [dict(mode=m, backend=b, median_ms=t) for (m, b), t in timed.items() if (m, b) not in main]
    return rows, breakdown


def add_arguments(parser) -> None:
    from harness.experiments.studies.eval_detector import DEFAULT_MODEL

    parser.add_argument("--model", default=str(DEFAULT_MODEL), help="weights file (.npz; default: the shipped model)")
    parser.add_argument("--data", default=None, help="COCO set to take the frame from (default: a rendered lab4_vga frame)")
    parser.add_argument("--repeats", type=int, default=300, help="timed runs per full-frame row (ROI rows: 10x)")
    parser.add_argument("--roi-half-size-px", type=int, default=32, help="half side of the ROI window (default 32: 64x64)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the rendered scene")
    parser.add_argument("--json", default=None, help="also write the rows as JSON to this path")


def run(args) -> int:
    from tracker import BallSegmentationModel
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the benchmark, not after

    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    if args.roi_half_size_px < 1:
        raise ValueError(f"--roi-half-size-px must be >= 1, got {args.roi_half_size_px}")
    model = BallSegmentationModel.load(args.model)
    image, center, what = _bench_image(args.data, args.seed, "white" if model.ball_colour == "white" else "orange",
                                       finds=lambda im, c: len(_window_detector(model, args.roi_half_size_px).detect(im, _window(im, c, args.roi_half_size_px))) > 0)
    side = 2 * args.roi_half_size_px
    if side >= min(image.shape[:2]):  # the window would be the whole frame: the ROI rows would time the full frame again
        raise ValueError(f"--roi-half-size-px {args.roi_half_size_px}: a {side}x{side} window is not smaller than the "
                         f"{image.shape[1]}x{image.shape[0]} frame ({what}); give less than {min(image.shape[:2]) // 2}")
    rows, breakdown = bench(model, image, center, repeats=args.repeats, roi_half_size_px=args.roi_half_size_px)
    print(f"ball detector, one thread, {image.shape[1]}x{image.shape[0]} frame ({what}); ROI {side}x{side}; medians of {args.repeats} (ROI: {10 * args.repeats}) runs")
    print(f"{'mode':<5} {'backend':<40} {'median ms':>10}")
    for r in rows + breakdown:
        print(f"{r['mode']:<5} {r['backend']:<40} {r['median_ms']:10.3f}")
    by = {(r["mode"], r["backend"]): r["median_ms"] for r in rows}
    for mode in ("full", "roi"):
        print(f"{mode}: torch / cv2 = {by[(mode, 'torch')] / by[(mode, 'cv2')]:.2f}x")
    print(f"full: every pixel / coarse to fine = {by[('full', 'cv2 every pixel')] / by[('full', 'cv2')]:.2f}x")
    if model.verifier is not None:
        for mode in ("full", "roi"):
            print(f"{mode}: with verifier / without = {by[(mode, 'cv2')] / by[(mode, 'cv2 without verifier')]:.2f}x")
    if model.learned is not None:
        for mode in ("full", "roi"):
            print(f"{mode}: learned / cv2 = {by[(mode, 'learned')] / by[(mode, 'cv2')]:.2f}x")
        print("goals: with the learned stage, full frame <= 6 ms, ROI <= 0.3 ms")
    else:
        print("goals: full frame <= 2 ms, ROI <= 0.2 ms (cv2 path)")
    if args.json:
        atomic_write_json(args.json, rows, "--json")
    return 0

"""``rt2 eval detector``: recall, outlier rate and centre error of the ball detector on labelled images.

Definitions (per image, truth = the labelled balls, radius = half the ball's diameter in px; the
diameter is the shorter side of its COCO box, which motion blur does not stretch):

* a *detection* is an **inlier** if it lies within two radii (one diameter) of some labelled ball,
  else an **outlier** (every detection in an image without a labelled ball is an outlier);
* a ball of at least ``min_diameter_px`` is **recalled** if some detection is within two radii;
  its **centre error** is the distance from its exact centre to the nearest such detection.

``recall`` = recalled / balls of at least ``min_diameter_px``; ``outlier_rate`` = outliers / all
detections reported; centre errors are over recalled balls (median and 95th percentile, px).

Methods: ``paper`` = Algorithm 1 (argmax + flood fill, one detection); ``ours`` = the first
candidate of the top-K detector (shape test applied); ``topk`` = all its K candidates, so a ball
counts as recalled if any candidate hits it and *every* extra candidate that is not on the ball
counts as an outlier (these are what the robust estimator has to reject).

With a motion cue (``--motion-cue``, fixed cameras' sequences) the images of each camera are searched in their time
order, as a live camera's frames are: per camera a background (``tracker.motion.MotionCue``) and only the candidates
of ``ours`` and ``topk`` on cells that moved are kept (the tracker's ``rt2-motion-gate``), except where the frame gives no
cue (a camera's first image, after a gap or a change of the whole scene) or its still-ball search is due.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from harness.experiments.detector.scores import operating_points, score_detections, truth_of
from harness.experiments.detector.subsets import camera_sequences, frames_before, image_camera, select_cameras, sequence_key

__all__ = ["DEFAULT_MODEL", "EVAL_METHODS", "add_arguments", "evaluate", "format_cameras", "run"]

DEFAULT_MODEL = Path(__file__).resolve().parents[3] / "data" / "models" / "ball_seg_default.npz"
EVAL_METHODS = ("paper", "ours", "topk")
BALL_FREE_MARGIN_PX = 4.0  #: --ball-free grows each box by this before inpainting
GOALS = {"recall": 0.99, "outlier_rate": 0.01, "median_center_error_px": 0.5}


def evaluate(model, labelled, *, methods=EVAL_METHODS, max_candidates: int = 4, min_diameter_px: float = 6.0, t_high=None, t_low=None, progress=True,
             ball_free_margin_px: float | None = None, area_px=None, learned_threshold: float | None = None, motion_cue=None,
             cue_warmup=()):
    """Run each method on every labelled image; returns a list of :class:`~harness.experiments.detector.scores.DetectorScores`.

    model : ``BallSegmentationModel``; labelled : list of ``harness.experiments.detector.coco.LabelledImage``
    t_high, t_low : Algorithm 1's thresholds as probabilities (None = the model's recommended ones)
    ball_free_margin_px : when set, every labelled ball is inpainted out first (boxes grown by this
        margin, :mod:`harness.experiments.detector.ballfree`) and the images count as ball-free:
        every detection is a false alarm
    area_px : (min, max) accepted blob area of ``ours``, pixels (None = the model's ``area_range_px``;
        :func:`area_from_diameters` turns a ball diameter range into one)
    learned_threshold : the learned stage's heat threshold of ``ours`` and ``topk``, a probability (None = the stage's
        single-image one)
    motion_cue : ``tracker.motion.MotionOptions`` for the fixed cameras' motion cue (module docstring; None: single images);
        the images are searched per camera in time order (:func:`~harness.experiments.detector.subsets.camera_sequences`)
        and ``ours`` and ``topk`` get a ``motion_cue`` entry: the sequences, the images searched without the cue and the
        candidates it dropped
    cue_warmup : ``LabelledImage`` s each camera's cue is shown, in order, before its first scored image (not scored: the
        frames before a ``--time-range``, as a live camera's stream would have shown them)
    Images naming two or more cameras (:func:`~harness.experiments.detector.subsets.image_camera`) give each score
    its ``per_camera`` figures.
    """
    from harness.common.progress import progress_bar

    from harness.experiments.detector.ballfree import without_balls
    from tracker import BallDetector, DetectorOptions

    for m in methods:
        if m not in EVAL_METHODS:
            raise ValueError(f"unknown method {m!r}; valid: {EVAL_METHODS}")
    paper = BallDetector(model, DetectorOptions(method="paper", t_high=t_high, t_low=t_low))
    ours = BallDetector(model, _ours_options(max_candidates, t_high, t_low, learned_threshold, area_px))
    if motion_cue is not None:  # each camera's images in time order; the scores do not depend on the order
        labelled = [labelled[i] for seq in camera_sequences(labelled) for i in seq]
    cues = None if motion_cue is None else _CameraCues(motion_cue, cue_warmup, ball_free_margin_px)
    found = {m: [] for m in methods}
    first_scores = []  # the score of ours' detection per image (nan: none): its operating points
    centers, diameters = [], []
    for li in progress_bar(labelled, desc="eval detector", unit="img", disable=not progress, leave=False):
        image = _evaluated_image(li, ball_free_margin_px)
        gate = None if cues is None else cues.observe(li, image)
        if ball_free_margin_px is not None:
            li = without_balls(li)
        c, d = truth_of(li)
        centers.append(c)
        diameters.append(d)
        if "paper" in methods:
            found["paper"].append(paper.detect(image).uv_px)
        if "ours" in methods or "topk" in methods:
            det = ours.detect(image)
            uv, sc = (det.uv_px, det.scores) if gate is None else cues.moving(gate, det)
            if "ours" in methods:
                found["ours"].append(uv[:1])
                first_scores.append(float(sc[0]) if len(sc) else float("nan"))
            if "topk" in methods:
                found["topk"].append(uv)
    scores = [score_detections(m, centers, diameters, found[m], min_diameter_px=min_diameter_px) for m in methods]
    if "ours" in methods:
        points = operating_points(centers, diameters, found["ours"], first_scores, min_diameter_px=min_diameter_px)
        scores = [replace(s, operating_points=points) if s.method == "ours" else s for s in scores]
    if cues is not None:
        scores = [replace(s, motion_cue=cues.summary()) if s.method in ("ours", "topk") else s for s in scores]
    cameras = [image_camera(li) for li in labelled]
    if not all(cameras) or len(set(cameras)) < 2:
        return scores
    split = {}
    for name in sorted(set(cameras)):
        idx = [i for i, c in enumerate(cameras) if c == name]
        split[name] = [score_detections(m, [centers[i] for i in idx], [diameters[i] for i in idx], [found[m][i] for i in idx],
                                        min_diameter_px=min_diameter_px) for m in methods]
    return [replace(s, per_camera={name: split[name][k] for name in split}) for k, s in enumerate(scores)]


class _CameraCues:
    """The cues of an evaluated set's cameras (:func:`evaluate`'s ``motion_cue``: ``tracker.motion.CameraCues`` keyed by
    :func:`~harness.experiments.detector.subsets.sequence_key`), each shown its warm-up frames first, and their counts."""

    def __init__(self, options, warmup, ball_free_margin_px):
        from tracker.motion import CameraCues

        self.cues, self.ball_free_margin_px = CameraCues(options), ball_free_margin_px
        self.warmup: dict = {}
        for li in warmup:
            self.warmup.setdefault(sequence_key(li), []).append(li)
        self.without_cue = self.dropped = 0

    def observe(self, li, image):
        """Show ``image`` (of ``li``) to its camera's cue; the cue where it gates this image's candidates, else None."""
        key = sequence_key(li)
        if key not in self.cues:
            for w in self.warmup.get(key, ()):
                self.cues.warm(key, _evaluated_image(w, self.ball_free_margin_px), _time_of(w))
        cue = self.cues.observe(key, image, _time_of(li))
        self.without_cue += cue is None
        return cue

    def moving(self, cue, det) -> tuple[np.ndarray, np.ndarray]:
        """The centres and scores of ``det``'s candidates on cells ``cue`` saw move (best first)."""
        keep = cue.moved(det.uv_px, det.boxes_xywh[:, 2:].max(axis=1)) if len(det) else np.zeros(0, bool)
        self.dropped += int((~keep).sum())
        return det.uv_px[keep], det.scores[keep]

    def summary(self) -> dict:
        return {"sequences": len(self.cues), "images_without_cue": self.without_cue, "candidates_dropped": self.dropped}


def _time_of(li) -> float:
    return math.nan if li.time_s is None else li.time_s


def area_from_diameters(model, diameter_px) -> tuple[int, int]:
    """(min, max) accepted blob area, pixels, for balls of ``diameter_px`` (lo, hi) across: the rule the
    tracker applies to a rig's ball sizes (:func:`tracker.ball_size.size_limits`, which widens the model's
    own range and never narrows it), for images whose rig is not known."""
    from tracker.ball_size import size_limits

    lo, hi = (float(v) for v in diameter_px)
    if not (0 < lo <= hi and np.isfinite(hi)):
        raise ValueError(f"--ball-diameter-px must be LO:HI with 0 < LO <= HI, got {diameter_px!r}")
    lim = size_limits([[lo, hi]], model.area_range_px, 32, edge_loss_px=model.edge_loss_px)
    return int(math.floor(lim.area_px[0, 0])), int(math.ceil(lim.area_px[0, 1]))


def too_large(model, labelled, min_diameter_px: float, area_px=None) -> tuple[int, int, float]:
    """(labelled balls >= ``min_diameter_px`` whose disk is larger than the accepted blob area, such balls, that largest
    area in pixels): a ball imaged larger than the model was trained for is rejected by the shape test whatever its colour.
    A model with a learned stage (whose candidates are the network's, not the filter's blobs): (balls wider than the
    sizes the stage was trained on, at each image's scale, such balls, 0.0)."""
    if model.learned is not None:
        st = model.learned
        big = [float(d) * st.scale_of(li.height, li.width) > st.diameter_range_px[1]
               for li in labelled for d in np.minimum(li.boxes_xywh[:, 2], li.boxes_xywh[:, 3]) if d >= min_diameter_px]
        return int(sum(big)), len(big), 0.0
    max_area = float(model.area_range_px[1] if area_px is None else area_px[1])
    d = np.concatenate([np.minimum(li.boxes_xywh[:, 2], li.boxes_xywh[:, 3]) for li in labelled] or [np.zeros(0)])
    d = d[d >= min_diameter_px]
    return int((math.pi / 4 * (d - model.edge_loss_px) ** 2 > max_area).sum()), len(d), max_area


def format_cameras(scores, methods=("ours", "topk")) -> str:
    """``methods``' figures per camera (:func:`~harness.experiments.detector.subsets.image_camera`), a row per camera
    and method, or "" when the images do not name two or more cameras."""
    split = [s for s in scores if s.method in methods and s.per_camera]
    if not split:
        return ""
    width = max(8, *(len(n) for n in split[0].per_camera))
    head = f"{'camera':<{width}} {'method':<7} {'recall':>8} {'outliers':>9} {'median px':>10} {'balls':>6} {'dets':>6} {'images':>7}"
    lines = ["per camera:", head, "-" * len(head)]
    for name in split[0].per_camera:
        for s in split:
            c = s.per_camera[name]
            recall = "n/a" if not c.n_balls else f"{100 * c.recall:.2f}%"
            lines.append(f"{name:<{width}} {s.method:<7} {recall:>8} {100 * c.outlier_rate:8.2f}% {c.median_center_error_px:10.3f} "
                         f"{c.n_balls:6d} {c.n_detections:6d} {c.n_images:7d}")
    return "\n".join(lines)


def format_operating_points(scores, option: str) -> str | None:
    """One line: ``ours``' best recall at each outlier bound of its operating points (thresholds at or above the one
    scored) and the threshold (``option``) that gives it; None without them."""
    s = next((s for s in scores if s.method == "ours" and s.operating_points), None)
    if s is None:
        return None
    parts = []
    for bound, p in sorted(s.operating_points.items(), key=lambda kv: -kv[0]):
        if p["threshold"] is None:
            parts.append(f"<= {100 * bound:g} % outliers: no ball")
        else:
            which = "this run's threshold" if p["n_detections"] == s.n_detections else f"{option} {p['threshold']:g}"
            parts.append(f"<= {100 * bound:g} % outliers: recall {100 * p['recall']:.2f} % at {100 * p['outlier_rate']:.2f} % ({which})")
    return "ours at a stricter threshold (the best candidate kept where it scores at least it): " + "; ".join(parts)


def learned_threshold_of(model, text) -> float | None:
    """``--learned-threshold``: None (the stage's single-image threshold), ``track`` (its tracking threshold) or a
    probability; ValueError naming the value, or a model without a learned stage."""
    if text is None:
        return None
    if model.learned is None:
        raise ValueError(f"--learned-threshold {text}: the model has no learned stage (its 5x5 filter's thresholds are --t-high / --t-low)")
    if text == "track":
        return model.learned.threshold if model.learned.track_threshold is None else model.learned.track_threshold
    try:
        p = float(text)
    except ValueError:
        p = float("nan")
    if not 0.0 < p < 1.0:
        raise ValueError(f"--learned-threshold must be a probability in (0, 1) or 'track', got {text!r}")
    return p


def format_table(scores) -> str:
    """The figures as a text table; the last two columns split the outliers by where they happen."""
    head = (
        f"{'method':<7} {'recall':>8} {'outliers':>9} {'median px':>10} {'p95 px':>8} {'balls':>6} {'dets':>6} {'images':>7}"
        f" {'outliers in ball images':>24} {'false alarms in no-ball images':>31}"
    )
    lines = [head, "-" * len(head)]
    for s in scores:
        alarms = f"{s.n_false_alarm_images}/{s.n_images_without_ball}"
        lines.append(
            f"{s.method:<7} {100 * s.recall:7.2f}% {100 * s.outlier_rate:8.2f}% {s.median_center_error_px:10.3f} "
            f"{s.p95_center_error_px:8.3f} {s.n_balls:6d} {s.n_detections:6d} {s.n_images:7d} {s.n_outliers_with_ball:24d} {alarms:>31}"
        )
    return "\n".join(lines)


def _evaluated_image(li, ball_free_margin_px):
    """The image of ``li`` as :func:`evaluate` searched it (its balls painted out when ``ball_free_margin_px`` is set)."""
    from harness.experiments.detector.train import load_image

    image = load_image(li)
    if ball_free_margin_px is None:
        return image
    from harness.experiments.detector.ballfree import ball_free

    return ball_free(image, li, ball_free_margin_px)[0]


def _ours_options(max_candidates: int, t_high, t_low, learned_threshold, area_px):
    """The ``ours`` detector options of :func:`evaluate` (the figures draw what the table scored)."""
    from tracker import DetectorOptions

    area = {} if area_px is None else dict(min_area_px=int(area_px[0]), max_area_px=int(area_px[1]))
    return DetectorOptions(method="ours", max_candidates=max_candidates, t_high=t_high, t_low=t_low, learned_threshold=learned_threshold, **area)


def probability_figure(model, labelled, path, *, n: int = 3, half_hw=(60, 80), t_high=None, t_low=None, learned_threshold=None,
                       area_px=None, ball_free_margin_px: float | None = None) -> Path:
    """Write the paper's probability-image figure: per row an image crop around a ball, the
    probability image ``B`` (black 0, white 1) and the crop with our detection's box (green; the
    paper method's in red where it differs) and the label's (blue). Uses the first ``n`` images with a
    ball >= 8 px. Each column has a title, the figure a legend, and a crop where a method found
    nothing says "no detection" (ours, or the paper's) instead of showing no box at all. The detectors and the
    images are :func:`evaluate`'s with the same arguments (with ``ball_free_margin_px`` the crops show where the ball
    was painted out, and any detection there is a false alarm).
    """
    import cv2

    from tracker import BallDetector, DetectorOptions

    ours = BallDetector(model, _ours_options(1, t_high, t_low, learned_threshold, area_px))
    paper = BallDetector(model, DetectorOptions(method="paper", t_high=t_high, t_low=t_low))
    hh, hw = half_hw
    rows, empty = [], []
    for li in labelled:
        if len(rows) == n:
            break
        big = np.flatnonzero(np.minimum(li.boxes_xywh[:, 2], li.boxes_xywh[:, 3]) >= 8)
        if not len(big):
            continue
        image = _evaluated_image(li, ball_free_margin_px)
        u, v = np.rint(li.centers_px[big[0]]).astype(int)
        pad = cv2.copyMakeBorder(image, hh, hh, hw, hw, cv2.BORDER_CONSTANT)
        crop = pad[v : v + 2 * hh, u : u + 2 * hw].copy()
        prob = cv2.copyMakeBorder((255 * model.probability(image)).astype(np.uint8), hh, hh, hw, hw, cv2.BORDER_CONSTANT)
        prob = cv2.cvtColor(prob[v : v + 2 * hh, u : u + 2 * hw], cv2.COLOR_GRAY2RGB)
        boxed = crop.copy()
        x, y, w, h = np.rint(li.boxes_xywh[big[0]]).astype(int)
        cv2.rectangle(boxed, (x - u + hw - 1, y - v + hh - 1), (x - u + hw + w, y - v + hh + h), (60, 140, 255), 1)
        missing = []
        for name, det, colour in (("paper", paper.detect(image), (255, 0, 0)), ("ours", ours.detect(image), (0, 255, 0))):
            if not len(det.boxes_xywh):
                missing.append(name)
            for bx, by, bw, bh in det.boxes_xywh[:1].astype(int):
                x0, y0 = bx - u + hw, by - v + hh
                cv2.rectangle(boxed, (x0 - 1, y0 - 1), (x0 + bw, y0 + bh), colour, 1)
        rows.append(np.hstack([crop, prob, boxed]))
        empty.append(missing)
    if not rows:
        raise ValueError("no labelled ball of at least 8 px to draw")
    titles = FIGURE_TITLES if ball_free_margin_px is None else ("image (the labelled ball painted out)", *FIGURE_TITLES[1:])
    fig = _titled(cv2.resize(np.vstack(rows), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST), empty, 4 * hw, 4 * hh, titles)
    from harness.common.outputs import atomic_path

    path = Path(path)
    with atomic_path(path, "--figure") as tmp:  # never a half-written figure
        if not cv2.imwrite(str(tmp), cv2.cvtColor(fig, cv2.COLOR_RGB2BGR)):
            raise ValueError(f"cannot write the figure to {str(path)!r} (use .png; or the disk is full)")
    return path


#: the probability figure's column titles and legend
FIGURE_TITLES = ("image (crop around a labelled ball)", "probability B (black 0, white 1)", "detection")
FIGURE_LEGEND = "blue: label   green: ours (first candidate)   red: the paper's method   'no detection': the method found nothing"


def _titled(fig: np.ndarray, empty: list, col_w: int, row_h: int, titles=FIGURE_TITLES) -> np.ndarray:
    """``fig`` (rows of 3 columns ``col_w`` x ``row_h`` px) with column titles above, a legend below and "no detection"
    written into the detection column of each row where a method found nothing (``empty``: per row the methods' names)."""
    import cv2

    font, black = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0)
    title_h, legend_h = 28, 26
    width = max(fig.shape[1], 820)
    out = np.full((title_h + fig.shape[0] + legend_h, width, 3), 255, np.uint8)
    out[title_h : title_h + fig.shape[0], : fig.shape[1]] = fig
    for k, title in enumerate(titles):
        cv2.putText(out, title, (k * col_w + 6, 19), font, 0.45, black, 1, cv2.LINE_AA)
    for r, missing in enumerate(empty):
        for j, name in enumerate(missing):
            at = (2 * col_w + 8, title_h + r * row_h + 22 + 22 * j)
            text = f"no detection ({name})"
            cv2.putText(out, text, at, font, 0.6, (0, 0, 0), 3, cv2.LINE_AA)  # a dark outline: readable on any crop
            cv2.putText(out, text, at, font, 0.6, (255, 255, 0), 1, cv2.LINE_AA)
    cv2.putText(out, FIGURE_LEGEND, (6, title_h + fig.shape[0] + 18), font, 0.42, black, 1, cv2.LINE_AA)
    return out


def failure_sheet(model, labelled, path, *, max_candidates: int = 4, min_diameter_px: float = 6.0, t_high=None, t_low=None,
                  learned_threshold=None, area_px=None, ball_free_margin_px: float | None = None):
    """Write the contact sheet of misses and false alarms (harness/experiments/detector/failures.py) of the
    top-K detector on ``labelled`` to ``path``, with :func:`evaluate`'s detector and images for the same arguments
    (with ``ball_free_margin_px`` the balls painted out: no ball to miss, every detection a false alarm); returns
    (path, misses, false alarms)."""
    from harness.experiments.detector.failures import contact_sheet
    from tracker import BallDetector

    ours = BallDetector(model, _ours_options(max_candidates, t_high, t_low, learned_threshold, area_px))
    dets = [ours.detect(_evaluated_image(li, ball_free_margin_px)) for li in labelled]
    shown, load = labelled, None
    if ball_free_margin_px is not None:
        from harness.experiments.detector.ballfree import without_balls

        shown = [without_balls(li) for li in labelled]  # no ball left to miss
        load = lambda k: _evaluated_image(labelled[k], ball_free_margin_px)  # noqa: E731 - the painted frame
    return contact_sheet(shown, [d.uv_px for d in dets], [d.boxes_xywh for d in dets], path, min_diameter_px=min_diameter_px, load=load)


def add_arguments(parser) -> None:
    from harness.experiments.detector.labels import LABEL_FORMATS

    parser.add_argument("--data", nargs="+", required=True, help="labelled sets (any --label-format): held-out COCO folders or JSON files, YOLO data.yaml, labelme, CVAT XML, Label Studio JSON")
    parser.add_argument("--label-format", choices=("auto", *LABEL_FORMATS), default="auto",
                        help="format of the --data labels (default auto: found from the files; README 'Label formats')")
    parser.add_argument("--model", default=str(DEFAULT_MODEL), help="weights file (.npz; default: the shipped model)")
    parser.add_argument("--json", default=None, help="also write the figures as JSON to this path")
    parser.add_argument("--max-candidates", type=int, default=4, help="K of the top-K detector (default 4)")
    parser.add_argument("--min-diameter-px", type=float, default=6.0, help="recall is over balls at least this wide (default 6)")
    parser.add_argument("--ball-colour", choices=("model", "any", "orange", "white"), default="model",
                        help="score only balls of this colour; detections on the others count as outliers "
                             "(default: the colour the model was trained for; 'any' scores every ball)")
    parser.add_argument("--t-high", type=float, default=None, help="Algorithm 1's T_h, a probability (default: the model's recommended one)")
    parser.add_argument("--t-low", type=float, default=None, help="Algorithm 1's T_l, a probability (default: the model's recommended one)")
    parser.add_argument("--learned-threshold", default=None, metavar="P|track",
                        help="a model with a learned stage: its heat threshold for ours and topk, a probability, or 'track' = the "
                             "stage's tracking threshold (the one a rig's cameras report candidates down to); default: its "
                             "single-image threshold")
    parser.add_argument("--max-images", type=int, default=None, help="evaluate only the first N images")
    parser.add_argument("--figure", default=None, help="also draw the probability-image figure (image, B, detection) to this PNG, "
                                                        "and the contact sheet of misses and false alarms beside it (NAME_failures.png)")
    parser.add_argument("--time-range", default=None,
                        help="evaluate only images START:STOP in time order (file names sorted as frame numbers), e.g. 58: for a "
                             "video's later frames that training did not see")
    parser.add_argument("--camera", nargs="+", default=None, metavar="NAME",
                        help="score only the images of these rig cameras (the COCO image field 'camera', as rt2 sim dataset and "
                             "rt2 label --auto write it); without it, images that name two or more cameras get a row per camera too")
    parser.add_argument("--motion-cue", action="store_true",
                        help="fixed cameras' sequences: search each camera's images in time order (their file names; the COCO "
                             "image field 'time_s' for gaps) and drop the candidates of ours and topk where nothing moved against "
                             "the camera's background, as rt2 track --motion-cue does on full frames; with --time-range the "
                             "frame before the range starts each camera's background")
    parser.add_argument("--no-confirm", action="store_true",
                        help="rank a whole frame's candidates by the learned stage's heat alone, without its confirmation network "
                             "(if it has one), at the heat's own threshold")
    parser.add_argument("--coarse-side", type=int, default=None, metavar="PX",
                        help="a model with a learned stage: search whole frames first at this longer side, its best peaks again at "
                             "full scale (0: one pass at the stage's full scale); default: the model's own")
    parser.add_argument("--coarse-context", type=int, default=None, metavar="PX",
                        help="a model with a learned stage: network pixels of context around each coarse peak's window at full "
                             "scale, before the second look; default: the model's own")
    parser.add_argument("--no-verifier", action="store_true",
                        help="run 'ours' and 'topk' with the model's 5x5 filter alone, without its candidate verifier (if it has one)")
    parser.add_argument("--ball-diameter-px", default=None, metavar="LO:HI",
                        help="the balls' diameter range on these images, pixels, when no rig says it: the accepted blob area "
                             "follows from it (widening the model's own range, as the tracker does from a rig's ball sizes); "
                             "default: the model's own area range")
    parser.add_argument("--ball-free", action="store_true",
                        help="paint every labelled ball out first (OpenCV inpainting of its box + 4 px) and count every detection "
                             "as a false alarm: false alarms on real scenes without ball-free frames")


def run(args) -> int:
    from harness.experiments.detector.labels import read_labels
    from harness.experiments.detector.train import colour_note, select_ball_colour
    from tracker import BallSegmentationModel

    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")  # before the evaluation, not after
    check_output_file(args.figure, "--figure")
    sheet = None if args.figure is None else str(Path(args.figure).with_name(Path(args.figure).stem + "_failures.png"))
    check_output_file(sheet, "--figure")
    model = BallSegmentationModel.load(args.model)
    if getattr(args, "no_verifier", False) and model.verifier is not None:
        model = replace(model, verifier=None)
    if getattr(args, "no_confirm", False) and model.learned is not None and model.learned.confirm is not None:
        model = replace(model, learned=replace(model.learned, confirm=None))
    from harness.experiments.detector.shipped import coarse_context_problem, coarse_side_problem

    # the stage's whole-frame passes as the options say: (option, value, its problem or None, the stage's field)
    for option, value, check, name in (
            ("--coarse-side", getattr(args, "coarse_side", None), lambda v, st: coarse_side_problem(v, st.max_side_px, f"the stage's full scale ({st.max_side_px} px)"), "coarse_side_px"),
            ("--coarse-context", getattr(args, "coarse_context", None), lambda v, st: coarse_context_problem(v), "coarse_context_px")):
        if value is None:
            continue
        if model.learned is None:
            raise ValueError(f"{option} {value}: the model has no learned stage (its whole frames are searched by its 5x5 filter)")
        problem = check(value, model.learned)
        if problem:
            raise ValueError(problem)
        model = replace(model, learned=replace(model.learned, **{name: value}))
    # the options' values before any image is read (reading and sorting the balls by colour takes a while)
    if args.max_images is not None and args.max_images < 1:
        raise ValueError(f"--max-images must be a positive number of images, got {args.max_images}")
    if args.max_candidates < 1:
        raise ValueError(f"--max-candidates must be a positive number of candidates, got {args.max_candidates}")
    for name in ("t_high", "t_low"):
        v = getattr(args, name)
        if v is not None and not 0.0 < v < 1.0:
            raise ValueError(f"--{name.replace('_', '-')} must be a probability in (0, 1), got {v}")
    t_high = model.t_high if args.t_high is None else args.t_high
    t_low = model.t_low if args.t_low is None else args.t_low
    if not t_low < t_high:
        raise ValueError(f"need T_l < T_h, got T_l={t_low:g} and T_h={t_high:g} (--t-low/--t-high and the model's defaults combined)")
    ball_free_margin = BALL_FREE_MARGIN_PX if getattr(args, "ball_free", False) else None
    area_px = None
    if getattr(args, "ball_diameter_px", None) is not None:
        text = str(args.ball_diameter_px)
        try:
            lo, hi = (float(t) for t in text.split(":"))
        except ValueError:
            raise ValueError(f"--ball-diameter-px must be LO:HI in pixels (e.g. 20:60), got {text!r}") from None
        area_px = area_from_diameters(model, (lo, hi))
    learned_threshold = learned_threshold_of(model, getattr(args, "learned_threshold", None))
    labelled = [li for path in args.data for li in read_labels(path, args.label_format)]
    if getattr(args, "camera", None):  # before --time-range: the time order is one camera's
        labelled = select_cameras(labelled, args.camera)
    every = labelled
    motion_cue = None
    if getattr(args, "motion_cue", False):
        from tracker.motion import MotionOptions

        if args.figure:
            raise ValueError("--figure draws single images, without the motion cue: leave out --motion-cue or --figure")
        motion_cue = MotionOptions(regions=False)  # the whole frame searched, the still candidates dropped
    if getattr(args, "time_range", None) is not None:
        from harness.experiments.detector.subsets import take_range

        labelled = take_range(labelled, args.time_range)
    if args.max_images is not None:
        labelled = labelled[: args.max_images]
    if not labelled:
        raise ValueError(f"--data {args.data}: no images")
    warmup = frames_before(every, labelled) if motion_cue is not None else []
    colour = model.ball_colour if args.ball_colour == "model" else args.ball_colour
    chosen = select_ball_colour(labelled, colour, progress=True)
    note = colour_note(labelled, chosen, colour, "they are not counted, and a detection on one is an outlier")
    labelled = chosen
    scores = evaluate(model, labelled, max_candidates=args.max_candidates, min_diameter_px=args.min_diameter_px, t_high=args.t_high, t_low=args.t_low,
                      ball_free_margin_px=ball_free_margin, area_px=area_px, learned_threshold=learned_threshold, motion_cue=motion_cue,
                      cue_warmup=warmup)
    print(
        f"model {args.model}{' (with its candidate verifier)' if model.verifier is not None else ''}: T_h={t_high:g}, T_l={t_low:g}; {len(labelled)} images; "
        f"{colour} balls >= {args.min_diameter_px:g} px"
        + (f" (the model's own colour; --ball-colour any scores every ball)" if args.ball_colour == "model" and colour != "any" else "")
    )
    if note:
        print(f"note: {note}")
    if model.learned is not None:
        confirm = model.learned.confirm
        own = model.learned.threshold if confirm is None else confirm.threshold
        print(f"learned stage: {'heat' if confirm is None else 'confirmed (sqrt(confirmation x heat))'} threshold "
              f"{own if learned_threshold is None else learned_threshold:g}"
              + (" (the single image's)" if learned_threshold is None else f" (--learned-threshold {args.learned_threshold})")
              + ("" if confirm is None else f"; the confirmation network looks at the heat's best {confirm.candidates} of each image"))
    if area_px is not None:
        print(f"accepted blob area {area_px[0]}-{area_px[1]} px (--ball-diameter-px {args.ball_diameter_px}; the model's own: "
              f"{model.area_range_px[0]:.0f}-{model.area_range_px[1]:.0f} px)")
    n_big, n_scored, max_area = too_large(model, labelled, args.min_diameter_px, area_px) if ball_free_margin is None else (0, 0, 0.0)
    if n_big and model.learned is not None:
        print(f"warning: {n_big} of {n_scored} labelled balls are wider than the learned stage was trained on "
              f"({model.learned.diameter_range_px[1]:g} network pixels, frames shrunk to a longer side of {model.learned.max_side_px} px): "
              "it may miss them")
    elif n_big:
        print(f"warning: {n_big} of {n_scored} labelled balls are larger than the accepted blob area (max {max_area:.0f} px, a ball "
              f"~{2 * math.sqrt(max_area / math.pi) + model.edge_loss_px:.0f} px across): 'ours' rejects them whatever their colour; "
              "pass --ball-diameter-px LO:HI (the balls' sizes on these images)")
    if ball_free_margin is not None:
        print(f"ball-free: every labelled ball painted out (box + {ball_free_margin:g} px); every detection is a false alarm")
    cue = next((sc.motion_cue for sc in scores if sc.motion_cue is not None), None)
    if cue is not None:
        print(f"motion cue: {cue['sequences']} camera sequence(s) searched in time order ({len(warmup)} earlier frame(s) shown first); "
              f"{cue['candidates_dropped']} candidates of ours/topk dropped where nothing moved; {cue['images_without_cue']} "
              "image(s) searched without the cue (a camera's first, after a gap or a change of the whole scene, a still ball's turn)")
    print(format_table(scores))
    if format_cameras(scores):
        print(format_cameras(scores))
    line = format_operating_points(scores, "--learned-threshold" if model.learned is not None else "--t-high")
    if line and ball_free_margin is None:
        print(line)
    goals = f"goals: recall >= {100 * GOALS['recall']:.0f}%, outliers <= {100 * GOALS['outlier_rate']:.0f}%, median error <= {GOALS['median_center_error_px']} px"
    print(goals + " (topk's outlier rate counts every extra candidate; the robust estimator rejects them)")
    if args.json:
        atomic_write_json(args.json, [s.as_json() for s in scores], "--json")
    if args.figure:
        same = dict(t_high=args.t_high, t_low=args.t_low, learned_threshold=learned_threshold, area_px=area_px,
                    ball_free_margin_px=ball_free_margin)  # the figures draw what the table scored
        print(f"wrote {probability_figure(model, labelled, args.figure, **same)}")
        path, n_miss, n_alarm = failure_sheet(model, labelled, sheet, max_candidates=args.max_candidates,
                                              min_diameter_px=args.min_diameter_px, **same)
        print(f"wrote {path}: contact sheet of {n_miss} misses and {n_alarm} false alarms")
    return 0

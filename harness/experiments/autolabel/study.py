"""``rt2 eval autolabel``: how good are the labels ``rt2 label --auto`` makes, against the truth.

Two scenes with a known ball, read as a recording would be (frame sets in time order, flights):

* ``lab``: the simulated lab as ``rt2 track --source sim`` renders it (:class:`~harness.live.sources.sim.LauncherFlights`
  of ``--seed``, the lab rig ``lab4_vga``), frame set k at ``k / rate_hz``, rendered offline so that a busy
  machine drops none;
* ``caliscope``: semi-real flights (:mod:`harness.sim.semireal`): a ball of known flight drawn into the real
  frames of the real 4-camera caliscope session with its real calibration; flights of ``--flight-frames``
  frame sets at ``--rate-hz``, a second apart.

Figures (the goals in brackets): of the frame sets where the ball is visible (``BallTruth.visible``) in >= 3
cameras and lies inside the rig's workspace (grown by the consensus's margin: outside it the consensus accepts no
position, by the rig's definition; those frame sets are counted apart), the share kept (>= 95 %); of the labels on a visible ball, the share whose centre is within 1.5 px of
the truth (>= 95 %); wrong labels, a label where the ball is not visible or whose centre is off the ball
(farther than its radius) (< 1 %); the same split by whether the camera's detector had found it (hard
positives). Same seed, same figures (a test says so).

``--train-held-out CAM`` then asks whether the labels teach the detector: the kept labels of every camera
but ``CAM`` (images written losslessly to a temporary folder) train a model as ``rt2 train`` would (fine-tuned
from the model the labels started from, 3 augmented copies, its guard that keeps the base unless fine-tuning
beats it), and both models are scored by ``rt2 eval detector``'s rule (method ``ours``) on ``CAM``'s frames where
the truth shows the ball: recall up and outliers not up is the goal.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from harness.common.outputs import finite_or_none
from harness.experiments.autolabel.consensus import AutoOptions, auto_label
from harness.experiments.autolabel.framesets import RecordedSet

__all__ = ["GOALS", "SCENES", "format_report", "score_labels", "smear_ratio", "study"]

SCENES = ("lab", "caliscope")
GOALS = {"kept": 0.95, "within_1_5px": 0.95, "wrong": 0.01}


def _lab(frames: int, seed: int, rate_hz: float):
    from harness.live.sources.sim import LauncherFlights
    from harness.sim.render import Renderer
    from tracker.rig_files import resolve_rig

    rig = resolve_rig("lab4_vga")
    renderer, flights = Renderer(rig, seed=seed), LauncherFlights(seed)

    def sets():
        for k in range(frames):
            scene = flights(k / rate_hz)
            images, truths = renderer.render_labelled(scene)
            centre = np.asarray(scene.balls[0].position_m, float) if scene.balls else None
            yield RecordedSet(k, k, k / rate_hz, tuple(images)), [t[0] if t else None for t in truths], centre

    return rig, sets


def _caliscope(frames: int, seed: int, rate_hz: float, flight_frames: int, ball: dict | None = None):
    from harness.sim.semireal import SemiRealOptions, SemiRealSession

    session = SemiRealSession(options=SemiRealOptions(**(ball or {})), seed=seed)

    def sets():
        k = 0
        for n in range(math.ceil(frames / flight_frames)):
            flight = session.flight(n, flight_frames, rate_hz)
            for j in range(flight_frames):
                if k == frames:
                    return
                images, truths, centre, _ = session.flight_frameset(n, j, flight)
                yield RecordedSet(k, k, n * (flight_frames / rate_hz + 1.0) + j / rate_hz, tuple(images)), [t[0] for t in truths], centre[0]
                k += 1

    return session.rig, sets


def score_labels(kept, truths: list, centres=None, workspace_m=None) -> dict:
    """The figures (module docstring) of ``kept`` (FrameSetLabels) against ``truths`` (per frame set, per camera a BallTruth or None).

    centres : per frame set the ball's true centre (3,) or None; workspace_m : the rig's (2, 3) workspace box, grown by the
    consensus's margin (``RobustOptions.workspace_margin_m``): a frame set whose ball lies outside it is not eligible (the
    consensus accepts no position there, by the rig's definition), counted in ``outside_workspace``
    """
    visible = np.array([[t is not None and t.visible for t in row] for row in truths], bool).reshape(len(truths), -1)
    seen3 = visible.sum(axis=1) >= 3
    inside = np.ones(len(truths), bool)
    if workspace_m is not None and centres is not None:
        from tracker.robust import RobustOptions

        lo, hi = np.asarray(workspace_m, float) + [[-RobustOptions.workspace_margin_m], [RobustOptions.workspace_margin_m]]
        inside = np.array([c is None or bool(((np.asarray(c) >= lo) & (np.asarray(c) <= hi)).all()) for c in centres], bool)
    eligible = seen3 & inside
    kept_idx = {fs.index for fs in kept}
    n_eligible = int(eligible.sum())
    kept_eligible = sum(1 for i in np.flatnonzero(eligible) if int(i) in kept_idx)
    errors, wrong, labels = {True: [], False: []}, {True: 0, False: 0}, {True: 0, False: 0}
    sized = []  # per visible label: (error px, true diameter px, smear / diameter)
    for fs in kept:
        for j, t in enumerate(truths[fs.index]):
            if not np.isfinite(fs.diameter_px[j]):
                continue
            det = bool(fs.inliers[j])
            labels[det] += 1
            if t is None or not t.visible:
                wrong[det] += 1
                continue
            e = float(np.linalg.norm(fs.center_px[j] - t.center_px))
            errors[det].append(e)
            sized.append((e, float(t.diameter_px), smear_ratio(t)))
            wrong[det] += int(e > t.diameter_px / 2)
    all_err = np.array(errors[True] + errors[False])
    n_labels = labels[True] + labels[False]

    def share(x, n):
        return None if n == 0 else x / n

    return {
        "frame_sets": len(truths), "eligible": n_eligible, "outside_workspace": int(np.sum(seen3 & ~inside)), "kept": len(kept), "kept_eligible": kept_eligible,
        "kept_share": share(kept_eligible, n_eligible), "kept_not_eligible": len(kept_idx) - kept_eligible,
        "labels": n_labels, "hard_positives": labels[False],
        "within_1_5px": share(int(np.sum(all_err <= 1.5)), n_labels),
        "median_error_px": float(np.median(all_err)) if len(all_err) else None,
        "p95_error_px": float(np.percentile(all_err, 95)) if len(all_err) else None,
        "wrong": share(wrong[True] + wrong[False], n_labels), "wrong_labels": wrong[True] + wrong[False],
        "hard_positive_within_1_5px": share(int(np.sum(np.array(errors[False]) <= 1.5)), labels[False]),
        "hard_positive_wrong": share(wrong[False], labels[False]),
        **_by_ball(np.array(sized, float).reshape(-1, 3)),
    }


SIZE_BANDS_PX = (20.0, 40.0, 60.0)  #: the report's diameter bands: < 20, 20-40, 40-60, >= 60 px
SMEARED = 0.5  #: a ball smeared over at least this share of its diameter counts as smeared


def smear_ratio(truth) -> float:
    """A visible ball's smear over the exposure as a share of its diameter: its box's longer side, less the
    diameter, over the diameter (0 for a still ball; the box clipped by the image's border shortens it)."""
    d = float(truth.diameter_px)
    return max(float(max(truth.box_xywh[2], truth.box_xywh[3])) - d, 0.0) / d if d > 0 else float("nan")


def _by_ball(sized: np.ndarray) -> dict:
    """The labels' precision split by the ball's diameter and smear (``sized``: (n, 3) error px, diameter px,
    smear / diameter): the 1.5 px goal is tighter for a larger ball, and a smeared ball's centre (the middle of its
    path over the exposure) is harder to find than a round one's."""
    e, d, sm = sized.T

    def band(mask) -> dict:
        n = int(mask.sum())
        return {"labels": n, "within_1_5px": None if n == 0 else float(np.mean(e[mask] <= 1.5))}

    edges = (0.0,) + SIZE_BANDS_PX + (math.inf,)
    sizes = {f"{lo:g}-{hi:g}px" if math.isfinite(hi) else f">={lo:g}px": band((d >= lo) & (d < hi)) for lo, hi in zip(edges, edges[1:])}
    return {"by_diameter": sizes,
            "by_smear": {"round": band(sm < SMEARED), "smeared": band(sm >= SMEARED)},
            "median_error_of_diameter": float(np.median(e / d)) if len(e) else None}


def _scene_rig_names(scene: str) -> list:
    if scene == "lab":
        from tracker.rig_files import resolve_rig

        return list(resolve_rig("lab4_vga").names)
    from harness.sim.semireal import session_rig

    return list(session_rig().names)


def _scene(scene, frames, seed, rate_hz, flight_frames, ball=None):
    return _lab(frames, seed, rate_hz) if scene == "lab" else _caliscope(frames, seed, rate_hz, flight_frames, ball)


def ball_options(scene: str, ball: str | None, crops=None, crop_frames: str | None = None) -> dict:
    """``--ball`` / ``--ball-crops`` / ``--crop-frames`` -> the caliscope scene's :class:`~harness.sim.semireal.SemiRealOptions`
    fields (:func:`harness.sim.semireal.ball_options`); the lab scene has its renderer's ball and takes none of them."""
    from harness.sim import semireal

    if scene != "caliscope":
        for name, value in (("--ball", ball), ("--ball-crops", crops), ("--crop-frames", crop_frames)):
            if value is not None:
                raise ValueError(f"{name} applies to --scene caliscope (the lab's ball is its renderer's), got --scene {scene}")
    return semireal.ball_options(ball, crops, crop_frames)


def _label_sets(rig, sets, kept, root, *, held_out: int | None = None) -> tuple[list, list]:
    """``(training labels, held-out balls)`` as ``LabelledImage`` lists with their images saved under ``root``: the
    ``kept`` auto labels of every camera but ``held_out``, and ``held_out``'s true balls (none without one)."""
    import cv2

    from harness.experiments.detector.coco import LabelledImage

    by_index = {fs.index: fs for fs in kept}
    train_set, test_set = [], []

    def save(img, name):
        path = root / f"{name}.png"
        cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return path

    for rs, truth, _ in sets():  # the same frame sets again (they depend only on the seed)
        if held_out is not None:
            t = truth[held_out]
            if t is not None and t.visible:
                box = np.array([t.box_xywh], float)
                test_set.append(LabelledImage(save(rs.images[held_out], f"test_{rs.index:06d}"), *rig[held_out].image_size, box, t.center_px[None, :]))
        fs = by_index.get(rs.index)
        for j, cam in enumerate(rig):
            if fs is None or j == held_out or not np.isfinite(fs.diameter_px[j]):
                continue
            w, hh = cam.image_size
            b = fs.box_xywh(j)
            x0, y0 = max(0.0, b[0]), max(0.0, b[1])
            box = np.array([[x0, y0, min(float(w), b[0] + b[2]) - x0, min(float(hh), b[1] + b[3]) - y0]])
            train_set.append(LabelledImage(save(rs.images[j], f"f{rs.index:06d}_{cam.name}"), w, hh, box, fs.center_px[j][None, :],
                                           camera=cam.name))  # as rt2 label --auto writes it: rt2 train's folds go by camera
    return train_set, test_set


def _train_on(train_set, base, seed: int, epochs: int | None, what: str):
    """``rt2 train``'s defaults on ``train_set`` from ``base`` (--learned auto: a model with a learned stage keeps
    training it, not dropping it); ``(model, info)``; a training that finds no ball is one line naming ``what``."""
    from harness.experiments.detector.train import NoBallFoundError, TrainOptions, train

    opts = TrainOptions(seed=seed, ball_colour="any", augment_copies=3, learned="auto", workers=None,  # as rt2 train: by the fits' length
                        **({} if epochs is None else {"epochs": epochs}))
    try:
        return train(train_set, opts, base=base, progress=False, log=lambda *a, **k: None)
    except NoBallFoundError as exc:  # one line naming what failed, not a model that finds nothing
        raise NoBallFoundError(f"{what}: {exc}") from exc


def trained_on_all(scene: str, frames: int, seed: int, kept, out, *, rate_hz: float = 100.0, flight_frames: int = 20,
                   model=None, epochs: int | None = None, ball: dict | None = None) -> dict:
    """Train on the ``kept`` labels of every camera (``rt2 label --auto`` then ``rt2 train``) and write the model to
    ``out``; what it was trained on."""
    import tempfile
    from pathlib import Path

    from harness.common.outputs import atomic_path
    from tracker.pipeline import load_model

    base = load_model(model)
    rig, sets = _scene(scene, frames, seed, rate_hz, flight_frames, ball)
    with tempfile.TemporaryDirectory(prefix="rt2-autolabel-") as tmp:
        train_set, _ = _label_sets(rig, sets, kept, Path(tmp))
        if not train_set:
            raise ValueError(f"--train-out {out}: no frame set was kept, no label to train on")
        trained, info = _train_on(train_set, base, seed, epochs, f"--train-out {out}: the training on {len(train_set)} auto labels")
        with atomic_path(Path(out), "--train-out") as tmp_out:
            trained.save(tmp_out)
    stage = info.get("learned")
    return {"out": str(out), "train_images": len(train_set), "kept_base": bool(info.get("kept_base")),
            "learned_stage": None if stage is None else stage["chosen"].name}


def held_out_training(scene: str, frames: int, seed: int, held_out: str, kept, *, rate_hz: float = 100.0, flight_frames: int = 20,
                      model=None, epochs: int | None = None, ball: dict | None = None) -> dict:
    """Train on the ``kept`` labels of every camera but ``held_out``; score base and trained on ``held_out``'s true balls."""
    import tempfile
    from pathlib import Path

    from harness.experiments.studies.eval_detector import evaluate
    from tracker.pipeline import load_model

    base = load_model(model)
    rig, sets = _scene(scene, frames, seed, rate_hz, flight_frames, ball)
    if held_out not in rig.names:
        raise ValueError(f"--train-held-out {held_out!r}: the {scene} rig's cameras are {list(rig.names)}")
    h = rig.names.index(held_out)
    with tempfile.TemporaryDirectory(prefix="rt2-autolabel-") as tmp:
        train_set, test_set = _label_sets(rig, sets, kept, Path(tmp), held_out=h)
        if not train_set or not test_set:
            raise ValueError(f"--train-held-out {held_out}: {len(train_set)} training labels, {len(test_set)} held-out balls: nothing to compare")
        trained, info = _train_on(train_set, base, seed, epochs, f"--train-held-out {held_out}: the training on {len(train_set)} auto labels of the other cameras")
        before = {s.method: s for s in evaluate(base, test_set, methods=("ours",), progress=False)}["ours"]
        after = {s.method: s for s in evaluate(trained, test_set, methods=("ours",), progress=False)}["ours"]
    stage = info.get("learned")  # the learned stage's cross-validated choice (rt2 train's log says the same)
    return {"held_out": held_out, "train_images": len(train_set), "held_out_balls": len(test_set), "kept_base": bool(info.get("kept_base")),
            "base": {"recall": before.recall, "outlier_rate": before.outlier_rate},
            "trained": {"recall": after.recall, "outlier_rate": after.outlier_rate},
            "learned_stage": None if stage is None else {"chosen": stage["chosen"].name,
                                                          "threshold": stage["chosen"].threshold if stage["chosen"].name != "none" else None,
                                                          "single_threshold": finite_or_none(stage.get("single_threshold")), "folds_by": stage.get("folds_by"),
                                                          "choices": [c.line() for c in stage["choices"]], "mining": stage.get("mining")}}


def study(scene: str, frames: int, seed: int, *, rate_hz: float = 100.0, flight_frames: int = 20, model=None,
          options: AutoOptions = AutoOptions(), kept_out: list | None = None, ball: dict | None = None) -> tuple[dict, dict]:
    """Run ``rt2 label --auto``'s consensus over ``frames`` frame sets of ``scene``; returns (figures, consensus counts).
    ball : the caliscope scene's ball (:func:`ball_options`; None = the drawn orange ball)"""
    from tracker.pipeline import load_model

    if scene not in SCENES:
        raise ValueError(f"unknown --scene {scene!r}; valid: {list(SCENES)}")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"--frames must be a positive integer, got {frames!r}")
    if not (math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
        raise ValueError(f"--rate-hz must be in (0, 1000], got {rate_hz!r}")
    if isinstance(flight_frames, bool) or not isinstance(flight_frames, int) or flight_frames < 3:
        raise ValueError(f"--flight-frames must be an integer >= 3, got {flight_frames!r}")
    model = load_model(model)
    rig, sets = _scene(scene, frames, seed, rate_hz, flight_frames, ball)
    truths, centres = [], []

    def recorded():
        for rs, truth, centre in sets():
            truths.append(truth)
            centres.append(centre)
            yield rs

    kept, counts = auto_label(recorded(), rig, model, options)
    if kept_out is not None:
        kept_out.extend(kept)
    return score_labels(kept, truths, centres, rig.workspace_m), counts


def format_report(scene: str, fig: dict, counts: dict) -> str:
    def pct(x):
        return "n/a" if x is None else f"{100 * x:.1f}%"

    def px(x):
        return "n/a" if x is None else f"{x:.2f} px"

    met = lambda ok: "met" if ok else "NOT met"  # noqa: E731
    k, w, e = fig["kept_share"], fig["within_1_5px"], fig["wrong"]
    return "\n".join([
        f"rt2 eval autolabel --scene {scene}: {fig['frame_sets']} frame sets, {fig['eligible']} with the ball visible in >= 3 cameras "
        f"inside the rig's workspace ({fig['outside_workspace']} more outside it, where the consensus accepts no position); "
        f"consensus: {counts['agreed']} agreed ({counts['second_look']} by the second look"
        + (f", {counts['recentred_agreement']} on re-centred centres" if counts.get("recentred_agreement") else "")
        + f"), {counts['kept']} kept after the flight test"
        + (f" ({counts['smoothed']} positions smoothed along their flight)" if "smoothed" in counts else ""),
        f"  kept {fig['kept_eligible']} of {fig['eligible']} ({pct(k)}; goal >= {100 * GOALS['kept']:.0f}%: {met(k is not None and k >= GOALS['kept'])}); "
        f"{fig['kept_not_eligible']} kept where fewer than 3 cameras see the ball",
        f"  {fig['labels']} labels ({fig['hard_positives']} hard positives, the detector had missed them): centre within 1.5 px "
        f"{pct(w)} (goal >= {100 * GOALS['within_1_5px']:.0f}%: {met(w is not None and w >= GOALS['within_1_5px'])}), "
        f"median {px(fig['median_error_px'])}, p95 {px(fig['p95_error_px'])}",
        "  within 1.5 px by the ball's diameter: " + ", ".join(f"{k} {pct(v['within_1_5px'])} of {v['labels']}" for k, v in fig["by_diameter"].items())
        + f"; round balls (smear < {SMEARED:g} diameter) {pct(fig['by_smear']['round']['within_1_5px'])} of {fig['by_smear']['round']['labels']}, "
        f"smeared {pct(fig['by_smear']['smeared']['within_1_5px'])} of {fig['by_smear']['smeared']['labels']}; median error "
        f"{pct(fig['median_error_of_diameter'])} of the diameter",
        f"  wrong labels (ball not visible there, or centre off the ball) {fig['wrong_labels']} = {pct(e)} "
        f"(goal < {100 * GOALS['wrong']:.0f}%: {met(e is not None and e < GOALS['wrong'])}); hard positives: within 1.5 px "
        f"{pct(fig['hard_positive_within_1_5px'])}, wrong {pct(fig['hard_positive_wrong'])}",
    ])


# -- command line ----------------------------------------------------------------------------------
def add_arguments(parser) -> None:
    parser.add_argument("--scene", choices=SCENES, default="lab",
                        help="lab: the simulated lab's launcher flights (as rt2 track --source sim renders them); caliscope: semi-real "
                             "flights drawn into the real caliscope session")
    parser.add_argument("--frames", type=int, default=200, help="frame sets (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="the scene's seed (default 0)")
    parser.add_argument("--rate-hz", type=float, default=100.0, help="frame rate of the flights (default 100)")
    parser.add_argument("--flight-frames", type=int, default=20, help="caliscope: frame sets per flight (default 20)")
    parser.add_argument("--model", default=None, help="the detector's weights (default: the shipped model)")
    parser.add_argument("--ball", choices=("orange", "white"), default=None,
                        help="--scene caliscope: orange = the drawn orange ball (the default); white = real white balls cut from the "
                             "real rally frames and pasted along the flight (use a white model: --model data/models/ball_seg_white.npz)")
    parser.add_argument("--ball-crops", default=None,
                        help="--ball white: the COCO set whose balls are cut (default ../shared/data/real/phone_rally)")
    parser.add_argument("--crop-frames", default=None,
                        help="--ball white: START:STOP of the crops' time order whose balls are used (e.g. 58: = the rally frames "
                             "the shipped white model never saw; default all)")
    parser.add_argument("--flight-window", type=int, default=AutoOptions.flight_window, help="as rt2 label --auto (default 3)")
    parser.add_argument("--smooth-window", type=int, default=AutoOptions.smooth_window, metavar="N",
                        help=f"as rt2 label --auto: smooth each position along its flight over N frame sets on each side "
                             f"(default {AutoOptions.smooth_window}; 0 = off)")
    parser.add_argument("--max-size-ratio", type=float, default=None,
                        help=f"as rt2 label --auto: the 3D size test's threshold (default {AutoOptions.max_size_ratio:g})")
    parser.add_argument("--trim", type=float, default=None, metavar="PX",
                        help=f"as rt2 label --auto: drop agreeing cameras farther than this from the ball (default {AutoOptions.trim_px:g})")
    parser.add_argument("--recentre", action=argparse.BooleanOptionalAction, default=True,
                        help="as rt2 label --auto: re-measure each camera's ball where the 3D ball projects (default on)")
    parser.add_argument("--second-look", action=argparse.BooleanOptionalAction, default=True,
                        help="as rt2 label --auto: search the frame sets without an agreement again where the flight puts the ball (default on)")
    parser.add_argument("--train-held-out", default=None, metavar="CAM",
                        help="also train on the labels of the other cameras and score the base and the trained model on CAM's true balls")
    parser.add_argument("--train-out", default=None, metavar="M.npz",
                        help="also train on the labels of every camera as rt2 train does (from --model) and write the model here "
                             "(then: rt2 eval framesets --scene ... --seed OTHER --model M.npz)")
    parser.add_argument("--epochs", type=int, default=None, help="--train-held-out, --train-out: rt2 train's epochs (default its own)")
    parser.add_argument("--json", default=None, help="also write the figures as JSON to this path")


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file

    check_output_file(args.json, "--json")
    if args.train_out is not None:
        check_output_file(args.train_out, "--train-out", suffix=".npz")
    given = {"max_size_ratio": args.max_size_ratio, "trim_px": args.trim}
    options = AutoOptions.from_flags(flight_window=args.flight_window, second_look=args.second_look, recentre=args.recentre,
                                     smooth_window=args.smooth_window, **{k: v for k, v in given.items() if v is not None})
    ball = ball_options(args.scene, args.ball, args.ball_crops, args.crop_frames)
    if args.train_held_out is not None:  # checked before the consensus pass, not after it
        names = _scene_rig_names(args.scene)
        if args.train_held_out not in names:
            raise ValueError(f"--train-held-out {args.train_held_out!r}: the {args.scene} rig's cameras are {names}")
    kept: list = []
    fig, counts = study(args.scene, args.frames, args.seed, rate_hz=args.rate_hz, flight_frames=args.flight_frames, model=args.model,
                        options=options, kept_out=kept, ball=ball)
    print(format_report(args.scene, fig, counts))
    result = {"scene": args.scene, "seed": args.seed, "frames": args.frames, "ball": args.ball or ("orange" if args.scene == "caliscope" else None),
              "crop_frames": args.crop_frames, "figures": fig, "counts": counts}
    if args.train_held_out is not None:
        t = held_out_training(args.scene, args.frames, args.seed, args.train_held_out, kept, rate_hz=args.rate_hz,
                              flight_frames=args.flight_frames, model=args.model, epochs=args.epochs, ball=ball)
        b, a = t["base"], t["trained"]
        up = (a["recall"] > b["recall"] or b["recall"] == 1.0 == a["recall"]) and a["outlier_rate"] <= b["outlier_rate"]
        print(f"  trained on {t['train_images']} auto labels of the other cameras, scored on {t['held_out_balls']} true balls of "
              f"{t['held_out']}: recall {100 * b['recall']:.1f}% -> {100 * a['recall']:.1f}%, outliers {100 * b['outlier_rate']:.1f}% -> "
              f"{100 * a['outlier_rate']:.1f}%{' (the guard kept the base)' if t['kept_base'] else ''}: goal (recall up or already 100%, outliers not up) "
              f"{'met' if up else 'NOT met'}")
        if t["learned_stage"] is not None:
            ls = t["learned_stage"]
            single = ls.get("single_threshold")
            folds = f", folds by {ls['folds_by']}" if ls.get("folds_by") else ""
            print(f"  its learned stage: {ls['chosen']} by cross-validation{folds} ({'; '.join(ls['choices'])})"
                  + ("" if single is None else f"; single images at threshold {single:g}"))
            m = ls.get("mining")
            if m and m["with"] is None:
                print("  its single images were often off the ball, but its network had no false alarm in the labelled frames to mine")
            elif m:
                print(f"  its fits continued with its {m['false_alarms']} false alarms mined (its single images were often off the ball): "
                      f"{m['with']}; the one {'with' if m['kept'] else 'without'} them kept")
        result["held_out_training"] = t
    if args.train_out is not None:
        t = trained_on_all(args.scene, args.frames, args.seed, kept, args.train_out, rate_hz=args.rate_hz,
                           flight_frames=args.flight_frames, model=args.model, epochs=args.epochs, ball=ball)
        print(f"  trained on {t['train_images']} auto labels of every camera"
              + (" (the guard kept the base's filter)" if t["kept_base"] else "")
              + (f", its learned stage: {t['learned_stage']}" if t["learned_stage"] else "") + f"; wrote {t['out']}")
        result["train_out"] = t
    if args.json:
        atomic_write_json(args.json, result, "--json")
    return 0

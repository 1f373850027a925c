"""The shipped detector models with a learned stage (``data/models/ball_seg_white.npz``, ``ball_seg_orange.npz``):
the recipe that trains it for transfer to cameras it never saw, as one command.

``rt2 train-shipped --colour white|orange --out M.npz --seed 0 [--steps N] [--base M0.npz]``

The 5x5 filter of the file is the base model's (``--base``; the shipped orange filter by default, which the
paper's method ``rt2-paper`` keeps using); the learned stage is trained here on (seeded, every source in the
model's description):

* **real frames**: the real rally frames (``../shared/data/real/phone_rally``, white ball) of the training part
  of their time order only (``--rally-range``, default ``0:58``; ``58:`` stays held out), weight 2;
* **balls drawn into real frames** (:mod:`harness.experiments.detector.drawn`): the caliscope session's cameras
  0 and 1 (cameras 2 and 3 stay held out) and the rally frames of the training part with their ball painted
  out, VGA, balls of ``--diameter-px`` (log-uniform), motion blur, highlights, Bayer and camera randomisation
  (white balance, exposure, gamma, lamp tint, blur, noise, JPEG), a quarter of the frames ball-free;
* **real ball crops pasted into real frames** (:mod:`harness.sim.render.ball_crops` when present): the rally's
  own ball, cut from the training frames with its matte, at random scale and blur; for orange its colour made
  orange (per-channel gains ``ORANGE_GAIN``: a real ball's shading, highlight and smear, an orange ball's colour;
  ``../shared`` holds no real orange ball);
* **semi-real frames**: the caliscope session's cameras 0 and 1 with balls flown through the rig in 3D
  (:class:`harness.sim.semireal.SemiRealSession`, as ``rt2 eval framesets --scene caliscope`` makes them on every
  camera): white, the rally's real balls of the training part; orange, the drawn ball of ``rt2 eval framesets``;
  exact centres and apparent diameters (what teaches the diameter head the ball's true size and gives the 3D size
  test's ratio), the flight's smear, the frame's own light (``--semireal-sets``);
* **renders** of the simulated lab (``--renders DIR``: an ``rt2 sim dataset`` set; none by default: in trials
  the renders' look crowded out the real frames', and the stage missed balls in held-out real frames).

The stage's threshold (recall - outliers, top-K candidates) is chosen on the real training frames where there
are any (white: the rally's training part), else on a validation set of balls drawn into other frames with other
seeds; never on held-out data.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

from harness.experiments.detector.learned_train import ARCHS, TRACK_THRESHOLD, WINDOW_CONTEXT_PX

__all__ = ["add_arguments", "build", "run"]

ROOT = Path(__file__).resolve().parents[3]
REAL = ROOT.parent / "shared" / "data" / "real"
RALLY = REAL / "phone_rally" / "annotations.json"
CALISCOPE_VIDEOS = [REAL / "caliscope_4cam" / "calibration" / "extrinsic" / f"cam_{i}.mp4" for i in (0, 1)]
DEFAULT_BASE = ROOT / "data" / "models" / "ball_seg_default.npz"


def coarse_side_of(max_side: int) -> int:
    """A new stage's coarse pass over a whole frame: its longer side, two thirds of ``max_side`` (640 px of 960).
    Half of it (480 px) shrank a 1080p frame four times, its balls of 21-49 px to 5-12: the pass missed 12 of the rally's 58
    training balls and 3 of its 25 held-out ones, which a full-scale window then never searched (README Results)."""
    return 2 * int(max_side) // 3


#: the smallest coarse side an option may ask for (a coarse pass of fewer pixels holds no ball's peak)
MIN_COARSE_SIDE_PX = 64
#: the smallest ``--max-side-px``: its default coarse pass (:func:`coarse_side_of`) no smaller than ``MIN_COARSE_SIDE_PX``
MIN_MAX_SIDE_PX = 3 * MIN_COARSE_SIDE_PX // 2


def coarse_side_problem(value: int, max_side: int, bound: str) -> str | None:
    """None when ``value`` is a coarse side a stage of ``max_side`` can search with (0: one pass), else the option's
    one-line error; ``bound`` names the upper bound as the user gave it (``--max-side-px``, the kept stage's side)."""
    if value == 0 or MIN_COARSE_SIDE_PX <= value < max_side:
        return None
    return f"--coarse-side must be 0 (one pass) or a side of {MIN_COARSE_SIDE_PX} px up to below {bound}, got {value}"


#: a new stage's coarse peaks' windows: network pixels of context around each at full scale
#: (``LearnedStage.coarse_context_px``; a tracker's windows keep ``WINDOW_CONTEXT_PX``). With the windows' 8 px a large
#: or smeared ball's heat at full scale fell to 0.2-0.4 where one pass over the frame gave 0.5-0.7 (README Results,
#: "The coarse peaks' context")
COARSE_CONTEXT_PX = 24
#: the most context an option may ask for around a coarse peak's window (network pixels; beyond the network's receptive field)
MAX_COARSE_CONTEXT_PX = 256


def coarse_context_problem(value: int) -> str | None:
    """None when ``value`` is a context a coarse peak's window can be searched with, else the option's one-line error."""
    if 0 <= value <= MAX_COARSE_CONTEXT_PX:
        return None
    return f"--coarse-context must be 0 to {MAX_COARSE_CONTEXT_PX} network pixels around a coarse peak's window, got {value}"


def _drawn(sources, n_per_video: int, seed: int, colour: str, diameter_px, log):
    from harness.experiments.detector.backgrounds import read_backgrounds
    from harness.experiments.detector.drawn import DrawnOptions, draw_frame
    from harness.experiments.detector.train import load_image

    frames = read_backgrounds(sources, n_per_video, load_image=load_image)
    opts = DrawnOptions(size=(640, 480), diameter_px=tuple(diameter_px), colour=colour, p_empty=0.25, max_blur_diameters=1.4)
    out = [draw_frame(im, f"drawn/{seed}/{i:05d}.png", np.random.default_rng([seed, i]), opts) for i, (im, _) in enumerate(frames)]
    log(f"{len(out)} frames with {colour} balls drawn in ({', '.join(Path(str(s)).name for s in sources)})")
    return out


#: where the description of a stage kept by ``--stage-from`` ends and what was added to it begins
STAGE_FROM_MARK = "; then `rt2 train-shipped --colour "
#: relative sampling weights of the sources (the real frames count most)
WEIGHTS = {"real": 4.0, "pasted": 1.0, "renders": 1.0, "semireal": 1.0}
#: the drawn balls' weight per ball colour: white, least (their look is ours, real frames exist); orange, as much as
#: the rest (no real frame of an orange ball exists)
DRAWN_WEIGHT = {"white": 0.3, "orange": 1.0}
#: the semi-real source's cameras (the caliscope session's; 2 and 3 stay held out for evaluation)
SEMIREAL_CAMERAS = (0, 1)
#: the recipe's frames by default (``build``, the command's options, and the description's command, which gives an
#: option only where it differs): the rally's training part, background frames per video, semi-real frame sets, the
#: network's longer side
RALLY_RANGE, FRAMES_PER_VIDEO, SEMIREAL_SETS, MAX_SIDE_PX = "0:58", 64, 160, 960
#: an orange ball from a real white one: per-channel gains (sRGB levels) drawn between these (orange to yellow-orange)
ORANGE_GAIN = ((0.92, 0.32, 0.04), (1.05, 0.62, 0.25))


def build(colour: str, seed: int, *, steps: int, base_path=DEFAULT_BASE, rally_range: str = RALLY_RANGE, renders=None,
          diameter_px=(5.0, 48.0), frames_per_video: int = FRAMES_PER_VIDEO, max_side: int = MAX_SIDE_PX, semireal_sets: int = SEMIREAL_SETS, arch: str | None = None, hard_pastes: float = 0.0, lights: float = 0.0, mined: float = 0.0, ema: float = 0.0, faded: float = 0.0, log=print,
          progress: bool = True, confirm_steps: int = 3000, stage_from=None, confirm_lights: float = 0.5, confirm_context=None,
          coarse_side=None, coarse_context=None, confirm_lookalikes: float = 0.0, confirm_skin: float = 0.0, confirm_ema: float = 0.0):
    """The model (base filter + trained learned stage and its confirmation network) and a dict of what it was trained
    on and its validation figures. ``stage_from``: a model file whose learned stage is kept as it is (its heatmap
    network, size ratio and description; not trained again): only its confirmation network is trained, or with
    ``confirm_steps`` 0 its own kept too (only the thresholds chosen again).
    ``confirm_context``: the confirmation's crop side in candidate diameters, or two (a second crop; None:
    ``confirm_train.CONTEXT``). ``coarse_side``: a whole frame's coarse pass, its longer side in pixels (0: one pass at
    ``max_side``; None: :func:`coarse_side_of` for a new stage, a kept stage's own); ``coarse_context``: network pixels of
    context around each coarse peak's window at full scale (None: ``COARSE_CONTEXT_PX`` for a new stage, a kept stage's own);
    ``confirm_lookalikes``: the share of the confirmation's training frames searched again with look-alikes of the
    ball's colour drawn in (:func:`harness.experiments.detector.confirm_train.draw_lookalike`); ``confirm_skin``: the share
    searched again with bare skin and coloured glints drawn in (:func:`harness.experiments.detector.confirm_train.with_skin`);
    ``ema``, ``faded``, ``confirm_ema``: the learned stage's and the confirmation network's moving averages of their
    weights, the learned stage's faded balls (:class:`harness.experiments.detector.learned_train.LearnedTrainOptions`)."""
    from harness.experiments.detector.labels import read_labels
    from harness.experiments.detector.learned_train import (LearnedTrainOptions, _best_threshold, fit_learned, items_at_scale)
    from harness.experiments.detector.scores import truth_of
    from harness.experiments.detector.subsets import take_range
    from harness.experiments.detector.train import load_image
    from tracker import BallSegmentationModel
    from tracker.detection.learned import LearnedStage

    from harness.experiments.detector.confirm_train import CONTEXT, LIT

    heat_options = {"lights": lights, "mined": mined, "ema": ema, "faded": faded}  # what only the heat network's training uses
    given = [name for name, v in heat_options.items() if v] + (["arch"] if arch is not None else [])
    if stage_from is not None and given:  # before any frame is read: a kept stage is not trained, its description must not claim them
        raise ValueError(f"--{given[0]} is the learned stage's training: a --stage-from stage is kept as it is, not trained again")
    if stage_from is not None and not confirm_steps and hard_pastes:  # nothing is trained: no frame is pasted
        raise ValueError("--hard-pastes shapes the training frames: with --stage-from and --confirm-steps 0 nothing is trained")

    base = BallSegmentationModel.load(base_path)
    contexts = [CONTEXT] if confirm_context is None else [float(c) for c in np.atleast_1d(confirm_context)]
    weight = {**WEIGHTS, "drawn": DRAWN_WEIGHT[colour]}
    pairs, weights, sources, semi = [], [], [], []
    rally_train = take_range(read_labels(RALLY, "auto"), rally_range) if RALLY.is_file() else []
    if colour == "white":
        if not rally_train:
            raise ValueError(f"the real rally frames are missing ({RALLY}): the white model's real frames")
        pairs += [(load_image(li), li) for li in rally_train]
        weights += [weight["real"]] * len(rally_train)
        sources.append(f"{len(rally_train)} real rally frames ({rally_range})")
    # a kept stage and its kept confirmation network train nothing: only their thresholds are chosen again
    trains = stage_from is None or confirm_steps > 0
    bg = [str(p) for p in CALISCOPE_VIDEOS if p.is_file()] + ([f"{RALLY}@{rally_range}"] if rally_train else [])
    drawn = _drawn(bg, frames_per_video, seed, colour, diameter_px, log) if trains else []
    pairs += drawn
    weights += [weight["drawn"]] * len(drawn)
    if drawn:
        sources.append(f"{len(drawn)} frames with drawn {colour} balls (caliscope cameras 0-1, rally {rally_range} painted out)")
    if rally_train and trains:
        pasted = _pasted(rally_range, bg, seed, frames_per_video, diameter_px, log, hard_share=hard_pastes, colour=colour)
        if pasted:
            pairs += pasted
            weights += [weight["pasted"]] * len(pasted)
            sources.append(f"{len(pasted)} frames with the rally's real ball crops" + (f" made {colour}" if colour != "white" else "") + " pasted in"
                           + (f" ({100 * hard_pastes:g} % of them long-smeared or partly hidden)" if hard_pastes else ""))
    if semireal_sets and trains:
        semi = _semireal(rally_range, semireal_sets, seed, log, colour)
        pairs += semi
        weights += [weight["semireal"]] * len(semi)
        sources.append(f"{len(semi)} semi-real frames (caliscope cameras 0-1, " + (f"the rally's real balls {rally_range}" if colour == "white" else f"drawn {colour} balls") + " flown in 3D)")
    if renders and trains:
        r = read_labels(renders, "auto")
        pairs += [(load_image(li), li) for li in r]
        weights += [weight["renders"]] * len(r)
        sources.append(f"{len(r)} renders ({renders})")
    opts = LearnedTrainOptions(iterations=steps, max_side_px=max_side, diameter_range_px=(4.0, 48.0), p_light=lights, p_mined=mined, ema=ema, p_faded=faded,
                               **({} if arch is None else {"arch": arch}))
    if lights:
        sources.append(f"light sources drawn into {100 * lights:g} % of the patches")
    if mined:
        sources.append(f"{100 * mined:g} % of the patches near its own false alarms in these frames, mined every {opts.mine_every} steps")
    if faded:
        sources.append(f"the balls of {100 * faded:g} % of the patches with balls faded into their surroundings")
    if ema:
        sources.append(f"the weights' moving average kept (decay {ema:g} per step)")
    if stage_from is None:
        items = []
        for (im, li), w in zip(pairs, weights):
            items += items_at_scale([(im, li)], max_side, weight=w)
        _, onnx = fit_learned(items, opts, seed, log=log, progress=progress)
        # the file keeps the base's filter (of orange balls, trained on renders): it never refines the stage's centres, the
        # ball's edge does (for orange too: docs/detector.md, "The shipped models")
        stage = LearnedStage(onnx, max_side_px=max_side, threshold=0.5, diameter_range_px=opts.diameter_range_px,
                             coarse_side_px=coarse_side_of(max_side) if coarse_side is None else coarse_side,
                             coarse_context_px=COARSE_CONTEXT_PX if coarse_context is None else coarse_context,
                             context_px=WINDOW_CONTEXT_PX, filter_refines=False)
    else:
        kept = BallSegmentationModel.load(stage_from).learned
        if kept is None:
            raise ValueError(f"--stage-from {stage_from}: the model has no learned stage to keep")
        stage = dataclasses.replace(kept, confirm=kept.confirm if not confirm_steps else None,
                                    **({} if coarse_side is None else dict(coarse_side_px=coarse_side)),
                                    **({} if coarse_context is None else dict(coarse_context_px=coarse_context)))
        log(f"the learned stage of {stage_from} kept (not trained again)" + _passes_note(coarse_side, coarse_context, ", "))
    if confirm_steps:
        from harness.experiments.detector.confirm_train import build_confirm_net
        from harness.experiments.detector.drawn import BALL_REFLECTANCE

        confirm = build_confirm_net(stage, pairs, steps=confirm_steps, seed=seed, log=log, progress=progress,
                                    lit=confirm_lights, lookalikes=confirm_lookalikes, skin=confirm_skin, ema=confirm_ema, reflectance=BALL_REFLECTANCE[colour], context=contexts[0], context2=contexts[1] if len(contexts) > 1 else None,
                                    description=f"the candidates of the stage on its training frames ({'; '.join(sources)})")
        stage = dataclasses.replace(stage, confirm=confirm)
        sources.append(f"a confirmation network ({confirm_steps} steps) on the stage's candidates in these frames")
    # the threshold: on the real training frames where there are any (white: the rally's training part, never its
    # held-out frames), else on a validation set made like the drawn training frames from other frames and seeds
    if colour == "white":
        val = [(im, li) for im, li in pairs[: len(rally_train)]]
        val_what = f"the {len(val)} real rally training frames ({rally_range})"
    else:
        val = _drawn([str(p) for p in CALISCOPE_VIDEOS if p.is_file()], 24, seed + 1000, colour, diameter_px, log)
        val_what = f"{len(val)} validation frames (drawn balls, other frames and seeds)"
    truth = ([truth_of(li)[0] for _, li in val], [truth_of(li)[1] for _, li in val])
    if stage_from is None:  # the heat's threshold (windows; whole frames without the second look)
        cands = [stage.candidates(im, None, k=16, threshold=0.05, confirm=False)[:2] for im, _ in val]
        th, s = _best_threshold(truth, cands, 4, 6.0)
        stage = dataclasses.replace(stage, threshold=th, track_threshold=min(th, TRACK_THRESHOLD))
    if stage.confirm is not None:  # the single image's threshold of the confirmed scores
        cands = [stage.candidates(im, None, k=16, threshold=0.05)[:2] for im, _ in val]
        th_c, s = _best_threshold(truth, cands, 4, 6.0)
        stage = dataclasses.replace(stage, confirm=dataclasses.replace(stage.confirm, threshold=th_c))
    th = stage.threshold if stage.confirm is None else stage.confirm.threshold
    size_note = ""
    if semi and stage_from is None:  # the 3D size test's threshold its diameters need, from its own semi-real frames (a kept stage keeps its own)
        ratio, n, median = size_ratio_of(stage, semi)
        if ratio is not None:
            stage = dataclasses.replace(stage, size_ratio=ratio)
            size_note = f"; size ratio {ratio:g} (99th percentile of its diameter / the true one, {n} semi-real training balls)"
            log(f"size ratio {ratio:g}: the 99th percentile of the stage's diameter / the true diameter of {n} semi-real training balls "
                f"(median {median:.2f})")
    chosen = (f"tracking threshold {stage.track_threshold:g}; threshold {th:g} chosen on {val_what}"
              + (f" with the confirmation network (the heat's alone: {stage.threshold:g})" if stage.confirm is not None else "")
              + f": recall {100 * np.nan_to_num(s.recall):.1f}%, outliers {100 * s.outlier_rate:.1f}%")
    # the command as it was given: a context other than the default is part of it (the shipped files' descriptions unchanged)
    # the frames' options where not the defaults (the shipped files' descriptions unchanged): the rally's range always
    # (the threshold's frames), the others where frames are made (a new stage's --max-side-px: a kept stage keeps its own)
    # (--hard-pastes shapes a kept stage's new confirmation network's frames too; the heat's options and --arch were
    # refused above for a kept stage); --base, the file whose filter the new file keeps, where it is not the default
    cmd_extra = ("" if rally_range == RALLY_RANGE else f" --rally-range {rally_range}") \
        + ("" if Path(base_path).resolve() == DEFAULT_BASE.resolve() else f" --base {Path(base_path).name}") \
        + ("" if frames_per_video == FRAMES_PER_VIDEO or not trains else f" --frames-per-video {frames_per_video}") \
        + ("" if semireal_sets == SEMIREAL_SETS or not trains else f" --semireal-sets {semireal_sets}") \
        + ("" if not renders or not trains else f" --renders {Path(renders).name}") \
        + ("" if max_side == MAX_SIDE_PX or stage_from is not None else f" --max-side-px {max_side}") \
        + ("" if arch is None else f" --arch {arch}") \
        + "".join(f" --{flag} {v:g}" for flag, v in {"hard-pastes": hard_pastes, **heat_options}.items() if v) \
        + ((" --confirm-context " + " ".join(f"{c:g}" for c in contexts)) if confirm_steps and contexts != [CONTEXT] else "") \
        + (f" --confirm-lights {confirm_lights:g}" if confirm_steps and confirm_lights != LIT else "") \
        + (f" --confirm-lookalikes {confirm_lookalikes:g}" if confirm_steps and confirm_lookalikes else "") \
        + (f" --confirm-skin {confirm_skin:g}" if confirm_steps and confirm_skin else "") \
        + (f" --confirm-ema {confirm_ema:g}" if confirm_steps and confirm_ema else "") \
        + ("" if coarse_side is None else f" --coarse-side {coarse_side}") + ("" if coarse_context is None else f" --coarse-context {coarse_context}")
    if stage_from is None:
        description = (f"{colour} balls; trained by `rt2 train-shipped --colour {colour} --seed {seed} --steps {steps} --confirm-steps {confirm_steps}{cmd_extra}` on "
                       + "; ".join(sources) + f"; network layout {opts.arch}, {steps} steps of {opts.batch} patches of {opts.patch_px} px; frames shrunk to "
                       f"{max_side} px, " + (f"coarse pass at {stage.coarse_side_px} px, its peaks' windows with {stage.coarse_context_px} px of context" if stage.coarse_side_px else "one pass") + f", windows with {WINDOW_CONTEXT_PX} px of context; " + chosen + size_note)
    else:
        # a file made so before: its stage's own description, where a new confirmation network replaces the kept one's; a
        # kept confirmation network keeps the history of how it was made
        before = kept.description.split(STAGE_FROM_MARK)[0] if confirm_steps or stage.confirm is None else kept.description
        description = (f"{before}{STAGE_FROM_MARK}{colour} --seed {seed} --confirm-steps {confirm_steps}{cmd_extra} --stage-from "
                       f"{Path(stage_from).name}` kept that stage"
                       + _passes_note(coarse_side, coarse_context, " (", ")")
                       + (f" and added a confirmation network: {stage.confirm.description}" if confirm_steps
                          else " and its confirmation network" if stage.confirm is not None else " and added nothing")
                       + "; " + chosen)
    stage = dataclasses.replace(stage, description=description)
    log(f"threshold {th:g} on {val_what}: recall {100 * np.nan_to_num(s.recall):.1f}%, outliers {100 * s.outlier_rate:.1f}%, "
        f"median {s.median_center_error_px:.2f} px")
    # a base with a learned stage of its own (--base a white file) gives its filter's part: the stage is this one
    from harness.experiments.detector.train import LEARNED_MARK

    filter_part = base.description.split(LEARNED_MARK, 1)[0]
    model = dataclasses.replace(base, learned=stage, ball_colour=colour if colour == "white" else base.ball_colour,
                                description=filter_part + LEARNED_MARK + stage.description)
    return model, dict(validation=s, threshold=th, sources=sources)


def _passes_note(coarse_side, coarse_context, before: str, after: str = "") -> str:
    """What ``--coarse-side`` and ``--coarse-context`` changed of a kept stage's whole-frame passes, for its log and description."""
    parts = ([] if coarse_side is None else [f"its coarse pass over whole frames at {coarse_side} px" if coarse_side else "whole frames in one pass"]) \
        + ([] if coarse_context is None else [f"its coarse peaks' windows with {coarse_context} px of context"])
    return f"{before}{', '.join(parts)}{after}" if parts else ""


def size_ratio_of(stage, frames) -> tuple[float | None, int, float]:
    """The 3D size test's threshold ``stage``'s diameters need (``LearnedStage.size_ratio``): the 99th percentile of
    its diameter / the true one over the balls of ``frames`` ((image, LabelledImage) pairs with exact square boxes:
    the semi-real frames) that its best candidate within half a diameter finds at the tracking threshold, rounded up
    to a hundredth; returns ``(ratio, n balls, median ratio)``, the ratio None with fewer than 50 such balls."""
    ratios = []
    for im, li in frames:
        if len(li.centers_px) != 1:
            continue
        c, d_true = li.centers_px[0], float(li.boxes_xywh[0][2])
        uv, _, d = stage.candidates(im, None, k=4, threshold=stage.track_threshold)
        if len(uv):
            dist = np.hypot(uv[:, 0] - c[0], uv[:, 1] - c[1])
            j = int(np.argmin(dist))
            if dist[j] <= 0.5 * d_true:
                ratios.append(float(d[j]) / d_true)
    median = float(np.median(ratios)) if ratios else math.nan
    if len(ratios) < 50:
        return None, len(ratios), median
    return max(1.0, math.ceil(100.0 * float(np.percentile(ratios, 99)) - 1e-9) / 100.0), len(ratios), median


def _semireal(rally_range: str, n_sets: int, seed: int, log, colour: str = "white"):
    """Frames of the caliscope session's training cameras (``SEMIREAL_CAMERAS``) with a ball of ``colour`` flown
    through the rig (white: the rally's real balls of ``rally_range``, as ``rt2 eval framesets --scene caliscope --ball
    white`` flies them; orange: the drawn ball of ``rt2 eval framesets --scene caliscope``)
    (:class:`harness.sim.semireal.SemiRealSession`: projected centre and apparent diameter exact, the flight's
    smear, the frame's light and sharpness); labels: the exact centre and a square of the apparent diameter.
    A ball less than half inside a camera's image leaves that frame out (neither ball nor background)."""
    from harness.experiments.detector.coco import LabelledImage
    from harness.sim.semireal import DEFAULT_RALLY, DEFAULT_SESSION, SemiRealOptions, SemiRealSession

    if not (DEFAULT_SESSION.is_dir() and (colour != "white" or DEFAULT_RALLY.is_dir())):
        return []
    real = dict(real_balls=DEFAULT_RALLY, crop_frames=rally_range) if colour == "white" else {}  # no real orange ball: drawn
    session = SemiRealSession(DEFAULT_SESSION, SemiRealOptions(ball_colour=colour, backgrounds=48, moving_backgrounds=False, **real),
                              seed=seed + 7000)
    out = []
    for f in range(n_sets):
        images, truths, _, k = session.frameset(f)
        for c in SEMIREAL_CAMERAS:
            t, im = truths[c][0], images[c]
            h, w = im.shape[:2]
            if t.visibility >= 0.5 and np.isfinite(t.center_px).all():
                d = float(t.diameter_px)
                boxes, centers = [[t.center_px[0] + 0.5 - d / 2, t.center_px[1] + 0.5 - d / 2, d, d]], [t.center_px]
            elif t.visibility > 0:
                continue
            else:
                boxes, centers = [], []
            out.append((im, LabelledImage(f"semireal/{seed}/{f:05d}_cam{c}.png", w, h, np.array(boxes, float).reshape(-1, 4),
                                          np.array(centers, float).reshape(-1, 2))))
    balls = f"{len(session.real.crops)} real ball crops of {rally_range}" if colour == "white" else f"drawn {colour} balls"
    log(f"{len(out)} semi-real frames (caliscope cameras {', '.join(map(str, SEMIREAL_CAMERAS))}, {n_sets} frame sets, {balls})")
    return out


def _occlude(im: np.ndarray, c, d: float, rng) -> np.ndarray:
    """``im`` with the ball at ``c`` (diameter ``d``) 20-56 % hidden behind an object: a region bounded by a line
    across the ball at a random angle, out to 1-2 diameters, filled with another part of the frame (its texture) or
    a flat bat-red, dark or skin colour with noise, its edge softened."""
    import cv2

    h, w = im.shape[:2]
    a = rng.uniform(0, 2 * math.pi)
    n = np.array([math.cos(a), math.sin(a)])
    off = d / 2 * rng.uniform(-0.1, 0.5)  # the line's distance from the centre: 56-20 % of the disc behind it
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    rel_u, rel_v = xx - c[0], yy - c[1]
    side = rel_u * n[0] + rel_v * n[1] - off  # > 0: behind the object
    reach = d * rng.uniform(1.0, 2.0)
    mask = ((side > 0) & (np.hypot(rel_u, rel_v) < reach)).astype(np.float32)
    mask = cv2.GaussianBlur(mask, (0, 0), float(rng.uniform(0.5, 1.5)))[..., None]
    if rng.random() < 0.5:  # another part of the frame, moved over the ball
        du, dv = int(rng.integers(-w // 3, w // 3 + 1)), int(rng.integers(-h // 3, h // 3 + 1))
        fill = np.roll(im, (dv, du), axis=(0, 1)).astype(np.float32)
    else:
        colour = [(200, 40, 40), (30, 30, 30), (210, 160, 130), (120, 80, 60)][int(rng.integers(4))]
        fill = np.empty_like(im, np.float32)
        fill[:] = np.asarray(colour, np.float32) * rng.uniform(0.7, 1.2)
        fill += rng.normal(0, 4, fill.shape).astype(np.float32)
    return np.clip(im * (1 - mask) + fill * mask, 0, 255).astype(np.uint8)


def _pasted(rally_range: str, bg_sources, seed: int, n_per_video: int, diameter_px, log, *, hard_share: float = 0.0, colour: str = "white"):
    """Frames of the background sources (VGA) with the rally's real ball crops (its training part, clean mattes only)
    pasted in at random size, place, motion blur and defocus; a fifth of them stay ball-free. ``hard_share`` of the
    balls are hard: half flown 1-3 diameters over the exposure, half partly hidden (:func:`_occlude`). ``colour``
    other than white: each ball given that colour by per-channel gains (``ORANGE_GAIN``) on its real shading."""
    import cv2

    from harness.experiments.detector.backgrounds import read_backgrounds
    from harness.experiments.detector.coco import LabelledImage
    from harness.experiments.detector.train import load_image
    from harness.sim.render.ball_crops import MIN_FIT, cut_ball_crops, paste_ball

    crops = [c for c in cut_ball_crops(RALLY, rally_range) if c.fit >= MIN_FIT]
    if not crops:
        return []
    frames = read_backgrounds(bg_sources, n_per_video, load_image=load_image)
    out = []
    for i, (im, _) in enumerate(frames):
        rng = np.random.default_rng([seed, 7, i])
        h, w = im.shape[:2]
        s = 640 / max(h, w)
        im = cv2.resize(im, (int(round(w * s)), int(round(h * s))), interpolation=cv2.INTER_AREA)
        h, w = im.shape[:2]
        boxes, centers = [], []
        if rng.random() > 0.2:
            d = float(math.exp(rng.uniform(math.log(diameter_px[0]), math.log(diameter_px[1]))))
            c = rng.uniform([d, d], [w - 1 - d, h - 1 - d])
            hard = hard_share > 0 and rng.random() < hard_share  # (no draw without: the shipped recipe's frames unchanged)
            smear = hard and rng.random() < 0.5
            if smear:  # a long smear: the ball flown 1-3 diameters over the exposure
                a = rng.uniform(0, 2 * math.pi)
                blur = d * rng.uniform(1.0, 3.0) * np.array([math.cos(a), math.sin(a)])
            else:
                blur = rng.normal(0, 0.35 * d, 2) if rng.random() < 0.5 else (0.0, 0.0)
            gain = None if colour == "white" else rng.uniform(*ORANGE_GAIN)  # a white ball's shading and smear, an orange ball's colour
            r = paste_ball(im, crops[int(rng.integers(len(crops)))], c, d, rng, blur_px=blur, defocus_px=float(rng.uniform(0, 1.2)), colour_gain=gain)
            im = r.image
            if hard and not smear:  # partly hidden: a bat, fingers, an edge in front of it
                im = _occlude(im, c, d, rng)
            boxes.append(r.box_xywh)
            centers.append(r.center_px)
        out.append((im, LabelledImage(f"pasted/{seed}/{i:05d}.png", w, h, np.array(boxes, float).reshape(-1, 4), np.array(centers, float).reshape(-1, 2))))
    log(f"{len(out)} frames with the rally's real ball crops ({len(crops)} clean ones of {rally_range}) pasted in")
    return out


def add_arguments(parser) -> None:
    parser.add_argument("--colour", choices=("white", "orange"), required=True, help="the ball colour of the model")
    parser.add_argument("--out", required=True, help="weights file to write (.npz)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=3000, help="optimiser steps of the learned stage (default 3000, as shipped)")
    parser.add_argument("--base", default=str(DEFAULT_BASE), help="the model whose 5x5 filter the file keeps (default: the shipped orange model)")
    parser.add_argument("--rally-range", default=RALLY_RANGE, help=f"the rally frames trained on, in time order (default {RALLY_RANGE}; the rest stays held out)")
    parser.add_argument("--renders", default=None, help="an rt2 sim dataset folder of renders added to training (default none)")
    parser.add_argument("--frames-per-video", type=int, default=FRAMES_PER_VIDEO, help=f"background frames taken from each video (default {FRAMES_PER_VIDEO})")
    parser.add_argument("--arch", default=None, choices=ARCHS, help="the network's layout (default: the training default)")
    parser.add_argument("--semireal-sets", type=int, default=SEMIREAL_SETS,
                        help="semi-real frame sets (caliscope cameras 0-1, the rally's training balls or, orange, a drawn ball "
                             f"flown in 3D) added to training (default {SEMIREAL_SETS}; 0 = none)")
    parser.add_argument("--hard-pastes", type=float, default=0.0,
                        help="the share of pasted real balls made hard, half flown 1-3 diameters over the exposure, half "
                             "partly hidden behind an object (default 0)")
    parser.add_argument("--lights", type=float, default=0.0,
                        help="the share of training patches with a light source drawn in away from their balls: a lamp's "
                             "saturated core and glow, a white ball's detector's false alarm (default 0)")
    parser.add_argument("--mined", type=float, default=0.0,
                        help="the share of training patches centred on the network's own false alarms in its training frames, "
                             "mined every 1000 steps (bootstrapping; default 0)")
    parser.add_argument("--ema", type=float, default=0.0, metavar="DECAY",
                        help="keep the exponential moving average of the network's weights over the steps, with this decay "
                             "per step (e.g. 0.999; default 0: the last step's weights)")
    parser.add_argument("--faded", type=float, default=0.0, metavar="SHARE",
                        help="the share of training patches with balls whose balls are faded into their surroundings "
                             "(their contrast cut to 25-70 %%: dim, grey and smeared balls; default 0)")
    parser.add_argument("--confirm-steps", type=int, default=3000,
                        help="optimiser steps of the confirmation network, the second look at a whole frame's best candidates "
                             "(default 3000, as shipped; 0 = none, or with --stage-from the kept file's own)")
    parser.add_argument("--confirm-lights", type=float, default=0.5,
                        help="the share of the training frames the confirmation network's examples are also taken from with "
                             "light sources drawn in (lamps: a white ball's detector's false alarms; default 0.5)")
    parser.add_argument("--confirm-lookalikes", type=float, default=0.0,
                        help="the share of the training frames the confirmation network's examples are also taken from with "
                             "things of the ball's colour that are no ball drawn in (boxes, cloths, signs; default 0)")
    parser.add_argument("--confirm-skin", type=float, default=0.0,
                        help="the share of the training frames the confirmation network's examples are also taken from with "
                             "bare skin (elbows, foreheads, knuckles with a highlight) and coloured glints (LEDs) drawn in: a "
                             "white ball's detector's false alarms (default 0)")
    parser.add_argument("--confirm-ema", type=float, default=0.0, metavar="DECAY",
                        help="keep the exponential moving average of the confirmation network's weights over its steps, with "
                             "this decay per step (e.g. 0.999; default 0: the last step's weights)")
    parser.add_argument("--confirm-context", type=float, nargs="+", default=None, metavar="DIAMETERS",
                        help="the confirmation network's crop: its side in candidate diameters (at least 48 px; default 6, as "
                             "shipped); two values: each candidate cut out at both, a network on each crop, their "
                             "probabilities averaged (the white file: 6 2)")
    parser.add_argument("--stage-from", default=None,
                        help="a model file whose learned stage is kept as it is (not trained again): only the confirmation network "
                             "is trained, on its candidates, and the thresholds chosen again; with --confirm-steps 0 its "
                             "confirmation network is kept too (with --coarse-side or --coarse-context: the file's passes "
                             "changed, nothing trained)")
    parser.add_argument("--coarse-side", type=int, default=None, metavar="PX",
                        help="a whole frame's first, coarse pass: its longer side in pixels, whose best peaks are searched "
                             "again at full scale (0: one pass at --max-side-px; default two thirds of --max-side-px for a new "
                             "stage, a --stage-from stage's own)")
    parser.add_argument("--coarse-context", type=int, default=None, metavar="PX",
                        help="network pixels of context around each coarse peak's window at full scale, before the second "
                             f"look (single images, proposals, rt2 label --auto; default {COARSE_CONTEXT_PX} for a new stage, a "
                             f"--stage-from stage's own; a tracker's cameras search with the windows' {WINDOW_CONTEXT_PX})")
    parser.add_argument("--max-side-px", type=int, default=MAX_SIDE_PX,
                        help=f"frames with a longer side are shrunk to it before the network (default {MAX_SIDE_PX}: VGA frames as they are)")


def run(args) -> int:
    from harness.common.outputs import atomic_path, check_output_file
    from harness.experiments.detector.learned_train import ema_problem

    out = Path(args.out)
    check_output_file(out, "--out", suffix=".npz")
    if args.confirm_steps < 0:
        raise ValueError(f"--confirm-steps must be 0 (none) or more, got {args.confirm_steps}")
    # the frames' and the heat network's options before any frame is read (making the frames takes minutes)
    if args.stage_from is None and args.steps < 1:
        raise ValueError(f"--steps must be a positive number of optimiser steps, got {args.steps}")
    if args.semireal_sets < 0:
        raise ValueError(f"--semireal-sets must be 0 (none) or more, got {args.semireal_sets}")
    if args.frames_per_video < 1:
        raise ValueError(f"--frames-per-video must be a positive number of frames, got {args.frames_per_video}")
    if args.stage_from is None and args.max_side_px < MIN_MAX_SIDE_PX:  # a kept stage keeps its own side
        raise ValueError(f"--max-side-px must be at least {MIN_MAX_SIDE_PX} px (a whole frame's coarse pass, two thirds of it, "
                         f"needs {MIN_COARSE_SIDE_PX}), got {args.max_side_px}")
    if args.renders is not None and not Path(args.renders).exists():
        raise ValueError(f"--renders {args.renders}: no such folder or label file")
    if args.stage_from is not None and not Path(args.stage_from).is_file():
        raise ValueError(f"--stage-from {args.stage_from}: no such model file")
    max_side, side_of = args.max_side_px, f"--max-side-px ({args.max_side_px})"
    if args.stage_from is not None:  # before any frame is read
        from tracker import BallSegmentationModel

        kept = BallSegmentationModel.load(args.stage_from).learned
        if kept is None:
            raise ValueError(f"--stage-from {args.stage_from}: the model has no learned stage to keep")
        max_side, side_of = kept.max_side_px, f"the kept stage's side ({kept.max_side_px})"
    if args.confirm_context is not None and (len(args.confirm_context) > 2 or not all(1.0 <= c <= 32.0 for c in args.confirm_context)):
        raise ValueError("--confirm-context must be one or two numbers of diameters between 1 and 32, got "
                         + " ".join(f"{c:g}" for c in args.confirm_context))
    if args.confirm_context is not None and not args.confirm_steps:
        raise ValueError("--confirm-context is the confirmation network's crop: it needs --confirm-steps 1 or more")
    for name in ("confirm_lookalikes", "confirm_skin", "confirm_ema"):
        if getattr(args, name) and not args.confirm_steps:
            raise ValueError(f"--{name.replace('_', '-')} is the confirmation network's training: it needs --confirm-steps 1 or more")
    problem = None if args.coarse_side is None else coarse_side_problem(args.coarse_side, max_side, side_of)
    if problem:
        raise ValueError(problem)
    problem = None if args.coarse_context is None else coarse_context_problem(args.coarse_context)
    if problem:
        raise ValueError(problem)
    for name in ("hard_pastes", "lights", "mined", "faded", "confirm_lights", "confirm_lookalikes", "confirm_skin"):
        v = getattr(args, name)
        if not (0.0 <= v <= 1.0):
            raise ValueError(f"--{name.replace('_', '-')} must be a share between 0 and 1, got {v!r}")
    for name in ("ema", "confirm_ema"):
        if ema_problem(getattr(args, name)):
            raise ValueError(f"--{name.replace('_', '-')} {ema_problem(getattr(args, name))}")
    model, info = build(args.colour, args.seed, steps=args.steps, base_path=args.base, rally_range=args.rally_range,
                        renders=args.renders, frames_per_video=args.frames_per_video, max_side=args.max_side_px,
                        semireal_sets=args.semireal_sets, arch=args.arch, hard_pastes=args.hard_pastes, lights=args.lights, mined=args.mined,
                        ema=args.ema, faded=args.faded, confirm_steps=args.confirm_steps, stage_from=args.stage_from, confirm_lights=args.confirm_lights, confirm_lookalikes=args.confirm_lookalikes,
                        confirm_skin=args.confirm_skin, confirm_ema=args.confirm_ema,
                        confirm_context=args.confirm_context, coarse_side=args.coarse_side, coarse_context=args.coarse_context)
    with atomic_path(out, "--out") as tmp:
        model.save(tmp)
    print(f"wrote {out}: learned stage threshold {info['threshold']:g}")
    return 0


if __name__ == "__main__":
    import argparse

    p = argparse.ArgumentParser(prog="rt2 train-shipped")
    add_arguments(p)
    sys.exit(run(p.parse_args()))

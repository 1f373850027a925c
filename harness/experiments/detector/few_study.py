"""Few labels on one camera, scored on another: does fine-tuning beat the base model it starts from?

``python -m harness.experiments.detector.few_study --train A --camera cam0 --frames 16 --eval B
--eval-camera cam1 cam2 cam3 --ball-colour orange --seeds 0 1 2``: ``--frames`` frames spread evenly
over camera ``--camera``'s frames of set A (time order, ball or not: what a user labelling a
recording gets) fine-tune the base model (``rt2 train --from``) once per seed, exactly as
:func:`harness.experiments.detector.train.train` does with the given options; each model and the base
are scored by ``rt2 eval detector``'s :func:`evaluate` on the ``--eval-camera`` images of set B (balls of
the other colour are not labels there). Prints one row per seed and the base's row; ``--json`` writes
them. The same options give the same figures (docs/detector.md, "Few labels: when fine-tuning loses").
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

__all__ = ["camera_frames", "main", "run_study", "spread_frames"]


def camera_frames(labelled, camera: str) -> list:
    """The images of ``camera`` (:func:`~harness.experiments.detector.subsets.image_camera`) in time order; ValueError
    naming the cameras the set has when there is none."""
    from harness.experiments.detector.subsets import select_cameras, time_order

    return time_order(select_cameras(labelled, [camera]))


def spread_frames(frames: list, n: int) -> list:
    """``n`` frames spread evenly over ``frames`` (first and last included); ValueError when there are fewer."""
    if n > len(frames):
        raise ValueError(f"--frames {n}: the camera has only {len(frames)} frames")
    return [frames[i] for i in np.linspace(0, len(frames) - 1, n).round().astype(int)]


def run_study(train_set, eval_set, base, opts_list, *, log=print) -> dict:
    """``train_set``: the labelled frames to fine-tune on; ``eval_set``: held-out images; ``opts_list``: one
    ``TrainOptions`` per training. Returns ``{"base": row, "runs": [row, ...]}`` (rows: ours and topk scores)."""
    from harness.experiments.detector.train import train
    from harness.experiments.studies.eval_detector import evaluate

    def row(model):
        ours, topk = evaluate(model, eval_set, methods=("ours", "topk"), progress=False)
        return {"ours": ours.as_json(), "topk": topk.as_json(), "n_balls": ours.n_balls}

    def line(name, r):
        o, k = r["ours"], r["topk"]
        return (f"{name:>14}: ours recall {100 * o['recall']:.1f}% outliers {100 * o['outlier_rate']:.1f}% median "
                f"{o['median_center_error_px'] if o['median_center_error_px'] is not None else float('nan'):.3f} px | "
                f"top-K recall {100 * k['recall']:.1f}% outliers {100 * k['outlier_rate']:.1f}%")

    out = {"base": row(base), "runs": []}
    log(line("base as it is", out["base"]) + f" ({out['base']['n_balls']} balls)")
    for opts in opts_list:
        model, info = train(train_set, opts, base=base, progress=False, log=lambda s: None)
        r = {"seed": opts.seed, "kept_base": bool(info["kept_base"]), **row(model)}
        out["runs"].append(r)
        log(line(f"seed {opts.seed}", r) + ("  (base kept)" if r["kept_base"] else ""))
    return out


def main(argv=None) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file
    from harness.experiments.detector.labels import read_labels
    from harness.experiments.detector.train import KEEP_BASE_CHOICES, TrainOptions, resolve_base, select_ball_colour
    from tracker.detection.model import BALL_COLOURS

    p = argparse.ArgumentParser(prog="python -m harness.experiments.detector.few_study", description=__doc__.split("\n")[0])
    p.add_argument("--train", required=True, help="labelled set to take the few frames from (rt2 sim dataset output, COCO)")
    p.add_argument("--camera", required=True, help="camera of --train whose frames are labelled (e.g. cam0)")
    p.add_argument("--frames", type=int, default=16, help="frames spread over that camera's recording (default 16)")
    p.add_argument("--eval", required=True, help="labelled set to score on (another seed's renders, say)")
    p.add_argument("--eval-camera", nargs="+", required=True, help="cameras of --eval scored (e.g. cam1 cam2 cam3)")
    p.add_argument("--ball-colour", choices=BALL_COLOURS, default="orange")
    p.add_argument("--from", dest="from_model", default="shipped", help="as rt2 train --from (default shipped)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--epochs", type=int, default=3)
    p.add_argument("--augment", type=int, default=3)
    p.add_argument("--finetune-l2", type=float, default=TrainOptions.finetune_l2)
    p.add_argument("--hard-negatives", type=int, default=TrainOptions.hard_negatives_per_image, help="hard negatives per image and epoch")
    p.add_argument("--keep-base", choices=KEEP_BASE_CHOICES, default="auto")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    try:
        if args.frames < 2:
            raise ValueError(f"--frames must be >= 2, got {args.frames}")
        if args.json:
            check_output_file(args.json, "--json")
        opts_list = [TrainOptions(epochs=args.epochs, seed=s, ball_colour=args.ball_colour, augment_copies=args.augment,
                                  finetune_l2=args.finetune_l2, hard_negatives_per_image=args.hard_negatives, keep_base=args.keep_base)
                     for s in args.seeds]
        base, origin = resolve_base(args.from_model, args.ball_colour)
        if base is None:
            raise ValueError(f"--from {args.from_model}: no base model ({origin}); this study compares fine-tuning with its base")
        few = spread_frames(camera_frames(read_labels(args.train), args.camera), args.frames)
        held = read_labels(args.eval)
        eval_set = select_ball_colour([li for c in args.eval_camera for li in camera_frames(held, c)], args.ball_colour)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"fine-tuning {origin} on {len(few)} frames of {args.train} {args.camera} ({sum(li.n_balls > 0 for li in few)} with a ball); "
          f"scored on {len(eval_set)} images of {args.eval} {' '.join(args.eval_camera)} ({args.ball_colour} balls)")
    result = run_study(few, eval_set, base, opts_list)
    result["options"] = {k: v for k, v in vars(args).items() if k != "json"}  # the figures, not where they went
    result["train_frames"] = [str(li.path.name) for li in few]
    if args.json:
        atomic_write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())

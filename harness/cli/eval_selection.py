"""``rt2 eval selection``: do the frames ``rt2 label`` suggests train a better detector than consecutive ones?

The study is :mod:`harness.label.selection` (its docstring states the protocol); this module parses and prints.
"""

from __future__ import annotations

from harness.experiments.studies.eval_detector import DEFAULT_MODEL
from harness.label.selection import SelectionOptions

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    from harness.experiments.detector.train import KEEP_BASE_CHOICES, THRESHOLD_CHOICES
    from tracker.detection.model import BALL_COLOURS

    parser.add_argument("--data", required=True, help="labelled frames of one or more cameras (folder with annotations.json, or the JSON file); "
                                                     "each camera (f000123_cam2 / cam2_s000123 in the file names) is one recording")
    parser.add_argument("--camera", nargs="+", default=(), help="study only these cameras (e.g. cam0 cam1; default: every camera of the set)")
    parser.add_argument("--model", default=str(DEFAULT_MODEL), help="weights that propose the ball for the page's rule (default: the shipped model)")
    parser.add_argument("--chosen", type=int, default=SelectionOptions.n_chosen, help="frames the page's rule chooses (default 10)")
    parser.add_argument("--consecutive", type=int, default=SelectionOptions.n_consecutive, help="consecutive frames of the other arm (default 20)")
    parser.add_argument("--pool-fraction", type=float, default=SelectionOptions.pool_fraction,
                        help="earlier share of each camera's frames to pick from; the later rest is held out (default 0.6)")
    parser.add_argument("--gap", type=int, default=SelectionOptions.gap_frames,
                        help=f"frames skipped between the pool and the held-out frames (default {SelectionOptions.gap_frames})")
    parser.add_argument("--repeats", type=int, default=SelectionOptions.repeats, help="trainings per arm and camera, seeds SEED.. (default 3)")
    parser.add_argument("--epochs", type=int, default=SelectionOptions.epochs, help="rt2 train epochs per training (default: rt2 train's)")
    parser.add_argument("--from", dest="from_model", default=SelectionOptions.from_model,
                        help="as rt2 train --from: 'shipped' (default: fine-tune the shipped model of --ball-colour), 'none' (scratch) or a .npz")
    parser.add_argument("--augment", type=int, default=None, help="as rt2 train --augment (default: 3 when fine-tuning, 0 from scratch)")
    parser.add_argument("--thresholds", choices=THRESHOLD_CHOICES, default=SelectionOptions.threshold_choice, help="as rt2 train --thresholds (default auto)")
    parser.add_argument("--ball-colour", choices=BALL_COLOURS, default=SelectionOptions.ball_colour, help="as rt2 train --ball-colour (default any)")
    parser.add_argument("--keep-base", choices=KEEP_BASE_CHOICES, default=SelectionOptions.keep_base,
                        help="as rt2 train --keep-base (default auto: an arm keeps the base model when fine-tuning does not beat it on its "
                             "own labelled frames; 'never' always fine-tunes)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (consecutive starts and training)")
    parser.add_argument("--json", default=None, help="also write the figures as JSON to this path")


def _pct(v) -> str:
    return "   -" if v is None else f"{100 * v:5.1f}%"


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file
    from harness.experiments.detector.coco import read_coco
    from harness.label.selection import run_selection
    from tracker import BallSegmentationModel

    check_output_file(args.json, "--json")  # before the trainings, not after
    opts = SelectionOptions(pool_fraction=args.pool_fraction, n_chosen=args.chosen, n_consecutive=args.consecutive,
                            repeats=args.repeats, epochs=args.epochs, seed=args.seed, gap_frames=args.gap, from_model=args.from_model,
                            augment=args.augment, threshold_choice=args.thresholds, ball_colour=args.ball_colour, cameras=tuple(args.camera),
                            keep_base=args.keep_base)
    model = BallSegmentationModel.load(args.model)
    result = run_selection(read_coco(args.data), model, opts)
    n_runs = opts.repeats * len(result["recordings"])
    print(f"\nheld-out detection on the later {result['n_held_out']} frames of {len(result['recordings'])} recording(s), "
          f"{n_runs} runs per arm (seeds {opts.seed}-{opts.seed + opts.repeats - 1}); median [worst - best]:")
    print(f"{'arm':<24} {'recall ours':>23} {'recall top-K':>23} {'outliers ours (median)':>23}")
    for arm, n in (("chosen", opts.n_chosen), ("consecutive", opts.n_consecutive)):
        med, lo, hi = (result[s][arm] for s in ("median", "min", "max"))
        print(f"{f'{arm} ({n} frames)':<24} " + " ".join(f"{_pct(med[k])} [{_pct(lo[k])} -{_pct(hi[k])}]" for k in ("ours_recall", "topk_recall"))
              + f" {_pct(med['ours_outlier_rate']):>23}")
    for rec in result["recordings"]:
        if rec["base"] is not None:
            o, k = rec["base"]["ours"], rec["base"]["topk"]
            print(f"{'no labels: ' + result['trained_from'].removeprefix('the shipped model ') + (' ' + rec['camera'] if rec['camera'] else ''):<24} "
                  f"{_pct(o['recall'])}{'':>17} {_pct(k['recall'])}{'':>17} {_pct(o['outlier_rate']):>23}")
    verdict = result["verdict"]
    if verdict["met"] is None:
        print(f"goal: cannot tell: {verdict['reason']} (rt2 train learns no detector for this ball from these frames), "
              "so the frames chosen make no difference here")
    else:
        print(f"goal: {opts.n_chosen} chosen frames train a model {'at least as good as' if verdict['met'] else 'NOT as good as'} "
              f"{opts.n_consecutive} consecutive ones (held-out recall ours and top-K, median and worst run): {'met' if verdict['met'] else 'not met'}")
    if args.json:
        atomic_write_json(args.json, result, "--json", allow_nan=False)
    return 0

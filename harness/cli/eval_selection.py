"""``rt2 eval selection``: do the frames ``rt2 label`` suggests train a better detector than consecutive ones?

The study is :mod:`harness.label.selection` (its docstring states the protocol); this module parses and prints.
"""

from __future__ import annotations

from harness.experiments.studies.eval_detector import DEFAULT_MODEL
from harness.label.selection import SelectionOptions

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("--data", required=True, help="one recording's COCO labels (folder with annotations.json, or the JSON file)")
    parser.add_argument("--model", default=str(DEFAULT_MODEL), help="weights that propose the ball for the page's rule (default: the shipped model)")
    parser.add_argument("--chosen", type=int, default=SelectionOptions.n_chosen, help="frames the page's rule chooses (default 10)")
    parser.add_argument("--consecutive", type=int, default=SelectionOptions.n_consecutive, help="consecutive frames of the other arm (default 20)")
    parser.add_argument("--pool-fraction", type=float, default=SelectionOptions.pool_fraction,
                        help="earlier share of the frames to pick from; the later rest is held out (default 0.6)")
    parser.add_argument("--repeats", type=int, default=SelectionOptions.repeats, help="trainings per arm, seeds SEED.. (default 3)")
    parser.add_argument("--epochs", type=int, default=SelectionOptions.epochs, help="rt2 train epochs per training (default: rt2 train's)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (consecutive start and training)")
    parser.add_argument("--json", default=None, help="also write the figures as JSON to this path")


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file
    from harness.experiments.detector.coco import read_coco
    from harness.label.selection import run_selection
    from tracker import BallSegmentationModel

    check_output_file(args.json, "--json")  # before the trainings, not after
    opts = SelectionOptions(pool_fraction=args.pool_fraction, n_chosen=args.chosen, n_consecutive=args.consecutive,
                            repeats=args.repeats, epochs=args.epochs, seed=args.seed)
    model = BallSegmentationModel.load(args.model)
    result = run_selection(read_coco(args.data), model, opts)
    print(f"\nheld-out detection on the later {result['n_held_out']} frames (median of {opts.repeats} seeds from {opts.seed}):")
    print(f"{'arm':<24} {'recall ours':>11} {'recall top-K':>12} {'outliers ours':>13} {'median err px':>13}")
    for arm, n in (("chosen", opts.n_chosen), ("consecutive", opts.n_consecutive)):
        m = {k: float("nan") if v is None else v for k, v in result["median"][arm].items()}
        print(f"{f'{arm} ({n} frames)':<24} {100 * m['ours_recall']:>10.1f}% {100 * m['topk_recall']:>11.1f}% "
              f"{100 * m['ours_outlier_rate']:>12.1f}% {m['ours_median_center_error_px']:>13.2f}")
    c, k = ({key: 0.0 if v is None else v for key, v in result["median"][arm].items()} for arm in ("chosen", "consecutive"))
    if max(c["topk_recall"], k["topk_recall"]) == 0.0:
        print(f"goal: cannot tell: neither arm's model finds a ball in the held-out frames (rt2 train learns no detector for "
              f"this ball from {opts.n_consecutive} frames or fewer), so the frames chosen make no difference here")
    else:
        verdict = "at least as good as" if c["topk_recall"] >= k["topk_recall"] and c["ours_recall"] >= k["ours_recall"] else "NOT as good as"
        print(f"goal: {opts.n_chosen} chosen frames train a model {verdict} {opts.n_consecutive} consecutive ones (held-out recall): "
              f"{'met' if verdict.startswith('at least') else 'not met'}")
    if args.json:
        atomic_write_json(args.json, result, "--json", allow_nan=False)
    return 0

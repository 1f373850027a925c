"""``rt2 reevaluate LOG.mcap``: re-run a tracker on a recorded session and get its figures again, no robot needed.

The log's ``session`` metadata says what kind of session it is; :data:`REEVALUATORS` maps the kind to
the function that re-evaluates it (``accuracy``: :func:`harness.experiments.accuracy.reevaluate_accuracy.reevaluate_accuracy`,
printed by ``_accuracy``; ``play``: :func:`harness.experiments.play.reevaluate_play.run_reevaluate`; ``track`` (``rt2 track``
logs): :func:`harness.live.reevaluate_track.run_reevaluate`). Unknown kinds raise
and list the known ones.

    rt2 reevaluate out/accuracy/session.mcap                       # every tracker, same settings
    rt2 reevaluate run.mcap --tracker rt2 --eps-px 3 --json r.json --plot r.png
    rt2 reevaluate run.mcap --from detections                      # estimator only, even if images were logged
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from harness.common.outputs import atomic_write_json, check_output_file
from harness.logs.reader import MAX_DECODE_WORKERS

__all__ = ["REEVALUATORS", "add_arguments", "run"]

_TRACKERS = ("rt2", "rt2-paper", "rtblob")
_SOURCES = ("auto", "images", "detections")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG.mcap", help="a session log written by an rt2 experiment")
    parser.add_argument("--tracker", action="append", choices=_TRACKERS, default=None,
                        help="tracker to re-run (repeat for several; default: every tracker of the session)")
    parser.add_argument("--eps-px", type=float, default=None, metavar="E", help="rt2 estimators' consistency threshold, px")
    parser.add_argument("--from", dest="source", default="auto", choices=_SOURCES,
                        help="re-run on the logged images (all frame sets needed) or the logged detections (default: images when all were logged)")
    parser.add_argument("--json", metavar="PATH", help="write the figures in the live run's --json form")
    parser.add_argument("--plot", metavar="PATH", help="write the error histogram (.png or .pdf)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--decode-workers", type=int, default=None, metavar="N",
                        help="threads decoding the logged images ahead of the trackers (default: one per core; 0 = in the "
                             "trackers' thread). The figures are the same whatever N")


def run(args) -> int:
    import warnings

    from harness.logs import LogError, SessionLogReader

    path = Path(args.log)
    if not path.is_file():
        raise FileNotFoundError(f"log {str(path)!r}: no such file")
    if args.eps_px is not None and not args.eps_px > 0:
        raise ValueError(f"--eps-px must be a positive number of pixels, got {args.eps_px}")
    if args.decode_workers is None:
        args.decode_workers = os.cpu_count() or 1
    if not 0 <= args.decode_workers <= MAX_DECODE_WORKERS:
        raise ValueError(f"--decode-workers must be in [0, {MAX_DECODE_WORKERS}], got {args.decode_workers}")
    check_output_file(args.json, "--json")  # before the re-run, not after
    check_output_file(args.plot, "--plot")
    with warnings.catch_warnings(record=True) as caught, SessionLogReader(path) as reader:
        warnings.simplefilter("always")
        try:
            kind = reader.metadata("session").get("kind")
        except LogError:
            kind = None
        if kind not in REEVALUATORS:
            raise ValueError(f"{path}: cannot re-evaluate a session of kind {kind!r}; known kinds: {sorted(REEVALUATORS)}")
        code = REEVALUATORS[kind](reader, args)
    for w in caught:
        print(f"warning: {w.message}")
    return code


def _accuracy(reader, args) -> int:
    from harness.cli.accuracy import format_report
    from harness.experiments.accuracy.figure import plot_histogram
    from harness.experiments.accuracy.reevaluate_accuracy import reevaluate_accuracy

    r = reevaluate_accuracy(reader, trackers=args.tracker, eps_px=args.eps_px, source=args.source,
                            progress=not args.no_progress, decode_workers=args.decode_workers)
    cfg = r.config
    head = [f"rt2 reevaluate {reader.path}: accuracy session, seed {cfg.seed}, {cfg.n_frames} frame sets; "
            f"from the logged {r.source}" + (f", eps_px {cfg.eps_px:g}" if cfg.eps_px is not None else "")]
    head += [f"  {k}: {how}" for k, how in r.how.items()]
    head += [f"note: {n}" for n in r.notes]
    print(format_report(r.figures, r.rows, header="\n".join(head)))
    if r.live_rows is not None:
        print("\nlive run's figures: " + ("reproduced exactly" if r.identical else "differ:"))
        if not r.identical:
            from harness.experiments.accuracy.stats import format_table

            print(format_table(r.live_rows))
    if args.json:
        atomic_write_json(args.json, r.rows, "--json")
        print(f"wrote {args.json}")
    if args.plot:
        plot_histogram(r.errors, [args.plot], title=f"re-evaluated: {reader.path.name}")
        print(f"wrote {args.plot}")
    return 0


def _play(reader, args) -> int:
    from harness.experiments.play.reevaluate_play import run_reevaluate

    return run_reevaluate(reader, args)


def _track(reader, args) -> int:
    from harness.live.reevaluate_track import run_reevaluate

    return run_reevaluate(reader, args)


#: session kind -> the function that re-evaluates and prints it
REEVALUATORS = {"accuracy": _accuracy, "play": _play, "track": _track}

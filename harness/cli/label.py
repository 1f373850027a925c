"""``rt2 label SOURCE --out DIR``: label ball frames in a browser page served on 127.0.0.1 (docs/label.md).

``rt2 label --auto --source SPEC --rig RIG --out DIR``: no page; the cameras label each other where three or
more agree on the ball (:mod:`harness.experiments.autolabel`), the labels are written to ``DIR`` and counted
per camera; ``rt2 label DIR/images --out DIR`` then reviews them as proposals.

SOURCE is a folder of images, a video file, or a session log (``.mcap``, ``--camera`` for one camera).
The model (``--model``) proposes the ball; labels go to ``DIR/annotations.json`` (COCO, what ``rt2 train
--data DIR`` reads) after every change, and a restart with the same ``--out`` continues from it.
Prints one JSON line on stdout when the page is served (``url``, ``port``, ``pid``, ``frames``), then
serves until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from pathlib import Path

from harness.experiments.studies.eval_detector import DEFAULT_MODEL

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("source", nargs="?", default=None,
                        help="a folder of images, a video file (anything OpenCV opens) or a session log (.mcap); not with --auto")
    parser.add_argument("--out", required=True, help="data set folder: annotations.json and images/ are written here (resumed when present)")
    parser.add_argument("--camera", default=None, help="session logs: label this camera's images only (default: every camera's)")
    parser.add_argument("--every", type=int, default=1, help="videos and logs: take every N-th frame (per camera; default 1)")
    parser.add_argument("--max-frames", type=int, default=500, help="videos and logs: at most this many frames (default 500)")
    parser.add_argument("--model", default=str(DEFAULT_MODEL), help="weights (.npz) that propose the ball (default: the shipped model)")
    parser.add_argument("--port", type=int, default=8765, help="port on 127.0.0.1 (default 8765; 0 = any free port)")
    parser.add_argument("--suggestions", type=int, default=10, help="frames listed as 'label next' (default 10)")
    parser.add_argument("--min-train", type=int, default=8, help="labelled frames before the page offers training (default 8)")
    parser.add_argument("--train-epochs", type=int, default=None, help="epochs of the page's `rt2 train` run (default: rt2 train's)")
    parser.add_argument("--train-seed", type=int, default=0, help="seed of the page's `rt2 train` run (default 0)")
    parser.add_argument("--train-learned-steps", type=int, default=None,
                        help="optimiser steps of a learned stage from scratch in the page's `rt2 train` run (its --learned-steps; "
                             "default: rt2 train's; fewer train faster and learn less)")
    parser.add_argument("--ball-colour", choices=("any", "orange", "white"), default=None,
                        help="the ball colour the page's training uses (rt2 train --ball-colour; default: the page asks)")
    parser.add_argument("--confirm-below", type=float, default=0.9,
                        help="accepting a proposal scored below this takes a second key press (default 0.9; 0 = never)")
    parser.add_argument("--motion-cue", action="store_true",
                        help="the frames are a fixed camera's recording (a video, a session log, a folder of one camera's frames, "
                             "in time order): each frame's candidates that moved against the camera's background are proposed first, "
                             "the still ones (a lamp, a shelf) after them")
    parser.add_argument("--verbose", action="store_true", help="print every HTTP request on stderr")
    auto = parser.add_argument_group("self-labelling (--auto): the cameras label each other")
    auto.add_argument("--auto", action="store_true",
                      help="label a multi-camera recording from the cameras' consensus (>= 3 agreeing cameras), write DIR and exit")
    auto.add_argument("--source", dest="source_spec", nargs="+", default=None, metavar="SPEC",
                      help="--auto: the recording, as rt2 track --source: 'replay LOG.mcap' or 'video DIR'")
    auto.add_argument("--rig", default=None, metavar="RIG", help="--auto: the recording's calibrated rig (file or name in data/rigs)")
    auto.add_argument("--min-support", type=int, default=3, help="--auto: cameras that must agree (default 3)")
    auto.add_argument("--max-reprojection", type=float, default=3.0, metavar="PX",
                      help="--auto: every agreeing camera within this of the 3D ball, px (default 3)")
    auto.add_argument("--flight-window", type=int, default=3,
                      help="--auto: neighbouring frame sets on each side whose flight must predict the ball (default 3; 0 = off)")
    auto.add_argument("--smooth-window", type=int, default=8, metavar="N",
                      help="--auto: each kept ball's position is taken from a parabola fitted in time to the kept positions of up "
                           "to N frame sets on each side, where they fit one (default 8; 0 = off)")
    auto.add_argument("--max-flight-residual", type=float, default=0.03, metavar="M",
                      help="--auto: the flight test's tolerance, metres (default 0.03)")
    auto.add_argument("--max-size-ratio", type=float, default=1.6,
                      help="--auto: the 3D size test's threshold: the agreeing cameras' candidates at most this many times as wide as "
                           "a ball at that depth, by their median (default 1.6)")
    auto.add_argument("--trim", type=float, default=2.0, metavar="PX",
                      help="--auto: an agreeing camera farther than this from the 3D ball is dropped and the ball triangulated again "
                           "from the others, while more than --min-support remain (default 2)")
    auto.add_argument("--recentre", action=argparse.BooleanOptionalAction, default=True,
                      help="--auto: measure each camera's ball again where the 3D ball projects (the model's own centring) and "
                           "triangulate from those centres (default on)")
    auto.add_argument("--second-look", action=argparse.BooleanOptionalAction, default=True,
                      help="--auto: search the frame sets without an agreement again, in windows where the flight of their "
                           "neighbours puts the ball, at half the detector's thresholds (default on; needs --flight-window > 0)")


def run(args) -> int:
    if args.auto:
        return run_auto(args)
    if args.source is None:
        raise ValueError("give the SOURCE to label (a folder, a video or a session log), or --auto --source SPEC --rig RIG")
    for flag, value in (("--source", args.source_spec), ("--rig", args.rig)):
        if value is not None:
            raise ValueError(f"{flag} is for --auto (the page takes its SOURCE as the first argument)")
    from tqdm import tqdm

    from harness.common.outputs import check_output_dir
    from harness.label.frames import open_frames
    from harness.label.server import LabelServer
    from harness.label.session import LabelOptions, LabelSession
    from harness.label.store import lock_folder
    from tracker import BallSegmentationModel

    if args.train_epochs is not None and args.train_epochs < 1:
        raise ValueError(f"--train-epochs must be >= 1, got {args.train_epochs}")
    if args.train_learned_steps is not None and args.train_learned_steps < 1:
        raise ValueError(f"--train-learned-steps must be >= 1, got {args.train_learned_steps}")
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be in [0, 65535], got {args.port}")
    if args.suggestions < 1:
        raise ValueError(f"--suggestions must be >= 1, got {args.suggestions}")
    if args.min_train < 3:
        raise ValueError(f"--min-train must be >= 3 (rt2 train holds out frames for validation), got {args.min_train}")
    train_args = (["--seed", str(args.train_seed)] + ([] if args.train_epochs is None else ["--epochs", str(args.train_epochs)])
                  + ([] if args.train_learned_steps is None else ["--learned-steps", str(args.train_learned_steps)]))
    options = LabelOptions(n_suggestions=args.suggestions, min_train_labels=args.min_train, train_args=tuple(train_args),
                           confirm_below=args.confirm_below, ball_colour=args.ball_colour, motion_cue=args.motion_cue)
    model = BallSegmentationModel.load(args.model)
    out = check_output_dir(args.out, "--out")
    lock = lock_folder(out)  # one writer per folder, before a frame is extracted into it
    bars: dict = {}

    def progress_of(what):
        def progress(done, total):  # a bar once there is something to show (none for a source refused at once)
            if what not in bars:
                bars[what] = tqdm(desc=what, unit="frame", file=sys.stderr, leave=False)
            bar = bars[what]
            bar.total = total
            bar.update(done - bar.n)
        return progress

    try:
        frames = open_frames(args.source, out, camera=args.camera, every=args.every, max_frames=args.max_frames, progress=progress_of("frames"))
        session = LabelSession(frames, out, model, args.model, options, progress=progress_of("proposals"), lock=lock)
    except BaseException:
        lock.close()
        raise
    finally:
        for bar in bars.values():
            bar.close()
    try:
        server = LabelServer(session, args.port, verbose=args.verbose)
    except BaseException:
        session.close()
        raise

    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()
        threading.Thread(target=server.httpd.shutdown, daemon=True).start()

    signal.signal(signal.SIGTERM, on_signal)
    c = session.store.counts()
    print(json.dumps({"url": server.url, "port": server.port, "pid": os.getpid(), "frames": len(frames),
                      "annotations": str(session.store.json_path), "labelled": c["labelled"], "auto": c["auto"],
                      "skipped": [name for name, _ in frames.skipped]}), flush=True)
    print(f"rt2 label: {len(frames)} frames of {frames.kind} {args.source}; {c['labelled']} already labelled in "
          f"{session.store.json_path}; open {server.url} (Ctrl-C to stop)", file=sys.stderr, flush=True)
    for name, why in frames.skipped:
        print(f"rt2 label: skipped {name}: {why}", file=sys.stderr, flush=True)
    if session.store.backup is not None:
        print(f"rt2 label: {session.store.json_path} was written by another tool; continuing it (its fields kept), the original "
              f"copied to {session.store.backup}", file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.httpd.server_close()
        session.close()
    c = session.store.counts()
    print(f"rt2 label: stopped; {c['labelled']} frames labelled ({c['with_ball']} with a ball) in {session.store.json_path}", file=sys.stderr)
    return 0


def run_auto(args) -> int:
    """``rt2 label --auto``: the consensus pass, then (only when something was kept) the images and the COCO file."""
    from harness.common.outputs import check_output_dir
    from harness.common.progress import progress_bar
    from harness.experiments.autolabel.consensus import AutoOptions, auto_label
    from harness.experiments.autolabel.framesets import check_cameras, read_framesets
    from harness.experiments.autolabel.output import per_camera_counts, write_auto_labels
    from harness.label.store import lock_folder
    from tracker import BallSegmentationModel
    from tracker.rig_files import resolve_rig

    if args.source is not None:
        raise ValueError(f"--auto takes the recording as --source SPEC, not as a first argument ({args.source!r})")
    if args.source_spec is None or args.rig is None:
        raise ValueError("--auto needs --source SPEC (replay LOG.mcap, video DIR) and --rig RIG (the recording's calibration)")
    if args.every < 1 or args.max_frames < 1:
        raise ValueError(f"--every and --max-frames must be positive integers, got {args.every}, {args.max_frames}")
    options = AutoOptions.from_flags(min_support=args.min_support, max_reprojection_px=args.max_reprojection, flight_window=args.flight_window,
                                     max_flight_residual_m=args.max_flight_residual, max_size_ratio=args.max_size_ratio, trim_px=args.trim,
                                     second_look=args.second_look, recentre=args.recentre, smooth_window=args.smooth_window)
    out = Path(args.out)
    if (out / "annotations.json").exists():
        raise ValueError(f"--out {args.out!r} already holds annotations.json: --auto writes a new data set folder")
    parent = next(p for p in [out, *out.parents] if p.exists())  # checked now, created only when there are labels to write
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise ValueError(f"--out {args.out!r}: {str(parent)!r} is not a folder this user can write in")
    rig = resolve_rig(args.rig)
    model = BallSegmentationModel.load(args.model)
    spec = list(args.source_spec)
    kind = spec[0]
    check_cameras(spec, rig)  # before any progress line
    with progress_bar(desc="consensus", unit="frame set", leave=False) as bar:
        kept, counts = auto_label(read_framesets(spec, rig, every=args.every, max_sets=args.max_frames), rig, model, options,
                                  progress=lambda n: bar.update(n - bar.n))
    source = " ".join(spec)
    if counts["frame_sets"] == 0:
        raise ValueError(f"--source {source}: no frame set with an image from every camera of --rig {args.rig}")
    if not kept:
        raise ValueError(f"--source {source}: none of its {counts['frame_sets']} frame sets has {options.min_support} or more cameras "
                         f"agreeing on a ball ({counts['agreed']} agreed, none in a consistent flight); nothing written "
                         "(is --rig this recording's calibration, --model one that sees this ball?)")
    lock = lock_folder(check_output_dir(out, "--out"))
    try:
        info = {"source": source, "rig": str(args.rig), "model": str(args.model), "command": "rt2 label --auto",
                "options": {k: getattr(options, k) for k in options.__dataclass_fields__}, "counts": counts}
        path = write_auto_labels(out, kind, rig, kept, read_framesets(spec, rig, every=args.every, max_sets=args.max_frames), info)
    finally:
        lock.close()
    per_cam = per_camera_counts(rig, kept)
    print(f"rt2 label --auto: {counts['kept']} of {counts['frame_sets']} frame sets kept ({counts['agreed']} with >= "
          f"{options.min_support} agreeing cameras, {counts['second_look']} of them at the second look, "
          f"{counts['recentred_agreement']} on re-centred centres; flight window "
          f"{options.flight_window}; {counts['smoothed']} positions smoothed along their flight); wrote {path}")
    for name, c in per_cam.items():
        print(f"  {name}: {c['labels']} labels ({c['hard_positives']} where its detector missed the ball), {c['hard_negatives']} hard negatives")
    print(f"review: rt2 label {out / 'images'} --out {out}   train: rt2 train --data {out} --out {out / 'model.npz'}")
    return 0

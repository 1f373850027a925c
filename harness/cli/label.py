"""``rt2 label SOURCE --out DIR``: label ball frames in a browser page served on 127.0.0.1 (docs/label.md).

SOURCE is a folder of images, a video file, or a session log (``.mcap``, ``--camera`` for one camera).
The model (``--model``) proposes the ball; labels go to ``DIR/annotations.json`` (COCO, what ``rt2 train
--data DIR`` reads) after every change, and a restart with the same ``--out`` continues from it.
Prints one JSON line on stdout when the page is served (``url``, ``port``, ``pid``, ``frames``), then
serves until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading

from harness.experiments.studies.eval_detector import DEFAULT_MODEL

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    parser.add_argument("source", help="a folder of images, a video file (anything OpenCV opens) or a session log (.mcap)")
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
    parser.add_argument("--ball-colour", choices=("any", "orange", "white"), default=None,
                        help="the ball colour the page's training uses (rt2 train --ball-colour; default: the page asks)")
    parser.add_argument("--confirm-below", type=float, default=0.9,
                        help="accepting a proposal scored below this takes a second key press (default 0.9; 0 = never)")
    parser.add_argument("--verbose", action="store_true", help="print every HTTP request on stderr")


def run(args) -> int:
    from tqdm import tqdm

    from harness.common.outputs import check_output_dir
    from harness.label.frames import open_frames
    from harness.label.server import LabelServer
    from harness.label.session import LabelOptions, LabelSession
    from harness.label.store import lock_folder
    from tracker import BallSegmentationModel

    if args.train_epochs is not None and args.train_epochs < 1:
        raise ValueError(f"--train-epochs must be >= 1, got {args.train_epochs}")
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be in [0, 65535], got {args.port}")
    train_args = ["--seed", str(args.train_seed)] + ([] if args.train_epochs is None else ["--epochs", str(args.train_epochs)])
    options = LabelOptions(n_suggestions=args.suggestions, min_train_labels=args.min_train, train_args=tuple(train_args),
                           confirm_below=args.confirm_below, ball_colour=args.ball_colour)
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

"""``rt2 track``: the tracker as a real-time service (docs/live.md).

    rt2 track --duration 5                                  # the simulated lab as four live cameras
    rt2 track --source replay out/demo/session.mcap --log out/track.mcap --json out/track.json
    rt2 track --source opencv 0 1 2 3 --rig data/rigs/my_lab.yaml --foxglove

The options become a :class:`~harness.live.config.TrackConfig` (:func:`track_config`; its errors are
shown with these flags, :data:`FLAGS`). Cameras (``--source``) -> frame-set assembly ->
:class:`~harness.live.service.TrackingService` (built by :func:`harness.live.run.open_service`)
-> the tennicam-compatible ZeroMQ stream (port 7660), rt2's own stream (the next port), an
optional Foxglove live view and an optional session log. A status line every second; a summary
at the end (``--json`` writes it). SIGINT / SIGTERM stop the run and finish the log.

Bad input (unknown rig, source or driver, an address that cannot be bound, a port in use, a
camera count that does not match the rig, a log file that exists) ends with one line and exit 2
before anything is written.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

from contextlib import contextmanager

from harness.live.config import DEFAULT_MAX_BACKLOG, NEXT_PORT, SIM_RENDER, ConfigError, TrackConfig, check_output_path
from harness.live.run import open_service
from harness.live.stats import format_budget

__all__ = ["FLAGS", "add_arguments", "add_source_arguments", "flag_errors", "lab_truth_scene", "run", "track_config"]

DEFAULT_RIG = "lab4_vga"  # data/rigs/lab4_vga.yaml, found from any working directory
_TRACKERS = ("rt2", "rt2-paper", "rtblob")  # for --help only; the kind is checked against tracker.TRACKER_KINDS
CLOSE_BY_S = 1.0  #: after SIGINT / SIGTERM, what is not closed this long after the signal is left to the exit (2 s in all)

#: the flag of each TrackConfig field (errors below the command line name fields; shown with these)
FLAGS = {"rig": "--rig", "source": "--source", "rate_hz": "--rate-hz", "seed": "--seed", "prerender_s": "--prerender",
         "truth_stream": "--truth-stream", "scene": "--scene", "max_behind_s": "--max-behind", "sim_rig": "--sim-rig",
         "sim_render": "--sim-render", "sim_render_nice": "--sim-render-nice", "sim_ball": "--sim-ball", "queue_s": "--queue-s", "max_backlog": "--max-backlog", "tracker": "--tracker",
         "model_path": "--model", "workers": "--workers", "full_frame_pyramid": "--full-frame-pyramid", "defer_full_frame": "--defer-full-frame", "motion_cue": "--motion-cue", "publish": "--publish", "publish_rt2": "--publish-rt2",
         "foxglove_port": "--foxglove", "foxglove_host": "--foxglove-host", "log_path": "--log", "log_overwrite": "--log-overwrite",
         "log_images": "--log-images", "log_image_format": "--log-image-format", "duration_s": "--duration",
         "status_period_s": "--status-period", "json": "--json"}


@contextmanager
def flag_errors():
    """Show a :class:`ConfigError` raised inside with this command's flags (one line, exit 2)."""
    try:
        yield
    except ConfigError as exc:
        raise ValueError(exc.render(FLAGS)) from None


def _off(value):
    return None if value is not None and str(value).lower() == "none" else value


def track_config(args, **fields) -> TrackConfig:
    """The :class:`TrackConfig` of ``rt2 track``'s (or ``rt2 bench live``'s) parsed options; ``fields``
    override single fields (``rt2 bench live``: its streams and duration). Errors name the flags."""
    with flag_errors():
        mine = dict(
            rig=str(args.rig), source=tuple(args.source), rate_hz=args.rate_hz, seed=args.seed, prerender_s=args.prerender,
            truth_stream=args.truth_stream, scene=args.scene, max_behind_s=args.max_behind, sim_rig=args.sim_rig,
            sim_render=args.sim_render, sim_render_nice=args.sim_render_nice, sim_ball=args.sim_ball, queue_s=args.queue_s, max_backlog=args.max_backlog, tracker=args.tracker,
            model_path=args.model, workers=args.workers, full_frame_pyramid=args.full_frame_pyramid, defer_full_frame=args.defer_full_frame, motion_cue=args.motion_cue,
        )
        if hasattr(args, "publish"):  # rt2 track's own options (rt2 bench live sets its streams itself)
            mine.update(
                publish=_off(args.publish), publish_rt2=NEXT_PORT if args.publish_rt2 is None else _off(args.publish_rt2),
                foxglove_port=args.foxglove, foxglove_host=args.foxglove_host, log_path=args.log, log_overwrite=args.log_overwrite,
                log_images=args.log_images, log_image_format=args.log_image_format, duration_s=args.duration,
                status_period_s=args.status_period,
            )
        return TrackConfig(**{**mine, **fields})


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rig", default=DEFAULT_RIG, metavar="RIG",
                        help=f"rig file or name in data/rigs (default {DEFAULT_RIG}: the simulated lab's four VGA cameras)")
    parser.add_argument("--source", nargs="+", default=["sim"], metavar="SPEC",
                        help="sim (default: the simulated lab), replay LOG.mcap, video DIR, opencv 0,1,2,3, "
                             "pylon [SERIALS], genicam [PRODUCER.cti [SERIALS]] (docs/live.md)")
    parser.add_argument("--rate-hz", type=float, default=200.0, metavar="HZ", help="frame rate of sim/replay sources and the assembler (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sim source's scene and noise (default 0)")
    parser.add_argument("--prerender", type=float, default=None, metavar="S",
                        help="sim only: render S seconds of the scene up front and loop them, so rendering takes no CPU "
                             "while tracking (benchmarks; memory 3.7 MB per frame set of 4 VGA cameras)")
    parser.add_argument("--tracker", default="rt2", metavar="KIND", help=f"tracker kind: {', '.join(_TRACKERS)} (default rt2)")
    parser.add_argument("--model", default=None, metavar="MODEL.npz",
                        help="rt2 kinds: the ball segmentation model (default: the shipped data/models/ball_seg_default.npz); "
                             "one you trained with `rt2 train` on your own labels")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="rt2 kinds: threads running the detector on the cameras of one frame set (default 2: a "
                             "full-frame search, a new ball or a lost one, runs two cameras at a time when a second core "
                             "is free; rt2 bench live); 1 = the tracking thread only (rtblob: always 1)")
    parser.add_argument("--full-frame-pyramid", action=argparse.BooleanOptionalAction, default=True,
                        help="rt2: a camera whose ball is large (>= 11 px across the workspace: high-resolution cameras) searches its "
                             "full frame at a reduced resolution, each candidate then found again at full resolution (default on; "
                             "VGA cameras are searched at full resolution either way; docs/pipeline.md)")
    parser.add_argument("--defer-full-frame", action=argparse.BooleanOptionalAction, default=None,
                        help="rt2: when the windows lose the ball (or a new one comes), report the frame set at once without a "
                             "position and search the full frames while the next frames arrive; their ball places the next "
                             "frame set's windows (a new ball is reported a frame set later, and no frame set waits for eight full "
                             "frames). Default: on for a model without a learned stage, off with one (docs/pipeline.md)")
    parser.add_argument("--motion-cue", action=argparse.BooleanOptionalAction, default=False,
                        help="rt2, fixed cameras: a full-frame search (a new ball, a lost one) keeps only the candidates where the "
                             "frame moved against the camera's own background (lamps, shelves and white objects do not move; a "
                             "ball already followed is kept when it stops). Default off (docs/pipeline.md, 'The motion cue')")
    parser.add_argument("--truth-stream", default=None, metavar="ADDR",
                        help="sim only: render the lab from a lab truth stream (e.g. rt2 robot serve --sim --truth-stream ADDR): "
                             "each frame is exposed on the host clock, rendered once the truth at that instant has arrived, "
                             "and stamped with its exposure time (docs/live.md, 'Lab truth')")
    parser.add_argument("--scene", default="accuracy", metavar="SCENE",
                        help="with --truth-stream: accuracy (default: the accuracy experiment's lab, the ball on the arm), "
                             "accuracy-clean, accuracy-harsh, or play (the arm and the stream's free balls)")
    parser.add_argument("--max-behind", type=float, default=0.1, metavar="S",
                        help="with --truth-stream: when a frame's exposure is more than S seconds past as its turn to render "
                             "comes, the cameras skip to the present (default 0.1: stay near real time); a larger S renders "
                             "every frame until they are S behind (the accuracy experiment's cameras)")
    parser.add_argument("--sim-rig", default=None, metavar="RIG",
                        help="sim only: the rig the simulated cameras render with (default: --rig); e.g. the true lab when "
                             "--rig is an estimated calibration")
    parser.add_argument("--sim-render", default="auto", choices=SIM_RENDER,
                        help="sim only: where the cameras are rendered: process (a child process on the other core, never "
                             "holding the tracker's interpreter lock, as a camera driver's threads; ~1 s per camera to start), "
                             "thread (in the service's process), auto (default: process, thread with --prerender or "
                             "--truth-stream)")
    parser.add_argument("--sim-render-nice", type=int, default=None, metavar="N",
                        help="sim only: the render process's CPU priority below the tracker's (os.nice, 0-19; default 10): the "
                             "tracker gets the cores first, as with cameras that render on their own hardware; frame sets the "
                             "renderer cannot make in time are skipped and counted. 0 on a machine busy with other work")
    parser.add_argument("--sim-ball", default="orange", metavar="COLOUR",
                        help="sim only: the ball of the sim source's own scene, orange (default) or white (to run a "
                             "white-ball model, e.g. --model data/models/ball_seg_white.npz)")
    parser.add_argument("--queue-s", type=float, default=0.25, metavar="S",
                        help="frames buffered per camera before the oldest is dropped, in seconds of the frame rate "
                             "(default 0.25: a hiccup of the machine that long costs latency, not frames)")
    parser.add_argument("--max-backlog", type=int, default=DEFAULT_MAX_BACKLOG, metavar="N",
                        help=f"frame sets that may wait for the tracker (default {DEFAULT_MAX_BACKLOG}): when a newer set comes, the oldest "
                             "waiting one is skipped and counted, so positions are never more than N frame periods stale "
                             "(a robot gains nothing from a stale position)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from harness.logs import add_log_arguments

    add_source_arguments(parser)
    parser.add_argument("--publish", default="tcp://127.0.0.1:7660", metavar="ADDR",
                        help="tennicam-compatible ZeroMQ PUB address (default tcp://127.0.0.1:7660; '*' for every interface); 'none' = off")
    parser.add_argument("--publish-rt2", default=None, metavar="ADDR",
                        help="rt2's own stream (default: the --publish port + 1); 'none' = off")
    parser.add_argument("--foxglove", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                        help="live view for Foxglove / Lichtblick on ws://HOST:PORT (default port 8765)")
    parser.add_argument("--foxglove-host", default="127.0.0.1", metavar="HOST", help="where the live view listens (default 127.0.0.1)")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: until Ctrl-C or the source ends)")
    parser.add_argument("--json", metavar="STATS", help="write the end-of-run figures to this JSON file")
    parser.add_argument("--status-period", type=float, default=1.0, metavar="S", help="seconds between status lines (0 = none)")
    parser.add_argument("--ready-json", action="store_true",
                        help="print the start line as JSON (the bound stream addresses; for scripts and tests)")
    add_log_arguments(parser)
    parser.set_defaults(log_images="20")
    for action in parser._actions:  # the shared option, with this command's default
        if action.dest == "log_images":
            action.help = ("images to record: N = every N-th frame set (default 20: JPEG-encoding every image of "
                           "4 VGA cameras at 200 Hz takes ~0.85 of a core, rt2 bench log), all, or none")


def lab_truth_scene(address: str, scene: str, *, seed: int):
    """The sim source's scene provider for ``--truth-stream`` (the accuracy experiment's lab)."""
    from harness.experiments.accuracy.truth_scene import LabTruthScene

    return LabTruthScene(address, scene, seed=seed)


def _print_summary(s: dict) -> None:
    lat = s["latency_ms"]
    print(f"rt2 track: {s['frame_sets']} frame sets in {s['duration_s']:.1f} s ({s['rate_hz']:.1f}/s), tracker {s['tracker']}")
    print(f"  latency (first frame's arrival -> message sent): p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms")
    print(f"  status: " + ", ".join(f"{k} {v}" for k, v in sorted(s["status"].items())))
    print(f"  frame sets without a camera's frame: " + ", ".join(f"{k} {v}" for k, v in s["missing_frames"].items()))
    a = s.get("assembly")
    if isinstance(a, dict) and "dropped_framesets" in a:
        print(f"  assembly: {a.get('complete')} complete, {a.get('incomplete')} incomplete, "
              f"{a.get('dropped_framesets')} frame sets skipped (the tracker had not taken them before "
              f"{a.get('backlog')} newer ones came: --max-backlog), "
              f"frames dropped per camera {list(a.get('dropped', ()))}, late {list(a.get('late', ()))}")
        for e in a.get("errors", ()) or ():
            if e:
                print(f"  camera failed (not restarted): {e}")
    if "latency_budget_ms" in s:
        print("\n".join("  " + line for line in format_budget(s["latency_budget_ms"], "whole run")))
    slow = s.get("slowest_frame_sets") or []
    if slow:
        w = slow[0]
        stages = ", ".join(f"{k} {v:.2f}" for k, v in (w.get("stages_ms") or {}).items() if v is not None)
        print(f"  slowest frame set: frame id {w['frame_id']}, {w['latency_ms']:.2f} ms ({stages or 'stages not kept'}), "
              f"{w['status']}" + (f"; {'; '.join(w['notes'])}" if w["notes"] else "") + " (JSON slowest_frame_sets: the 5 slowest)")
    if "published" in s:
        print(f"  published: {s['published']} on {s['addresses']}")
    if "log" in s:
        print(f"  log: {s['log']['path']}" + (f" (dropped by the writer: {s['log']['dropped']})" if s["log"]["dropped"] else ""))


def run(args) -> int:
    from harness.logs.codecs import to_json_value

    stop = threading.Event()
    got = {}

    def on_signal(signum, frame):
        got.setdefault("signal", signal.Signals(signum).name)
        got.setdefault("t_s", time.monotonic())
        stop.set()

    config = track_config(args)
    with flag_errors():
        if args.json:
            check_output_path("json", args.json)
        live = open_service(config, status=lambda line: print(line, flush=True), truth_scene=lab_truth_scene)
    with live:
        service = live.service
        where = [f"{k} stream on {v}" for k, v in (service.publisher.addresses if service.publisher else {}).items()]
        if service.view is not None:
            where.append(f"live view on ws://{config.foxglove_host}:{service.view.port}")
        if service.log is not None:
            where.append(f"log {service.log.path}")
        if args.ready_json:
            ready = {"streams": dict(service.publisher.addresses if service.publisher else {}),
                     "tracker": config.tracker, "rig": config.rig, "pid": os.getpid()}
            if service.view is not None:
                ready["live_view"] = f"ws://{config.foxglove_host}:{service.view.port}"
            print(json.dumps(ready), flush=True)
        else:
            print(f"rt2 track: {config.tracker} on {' '.join(config.source)} ({len(service.rig)} cameras, rig {config.rig}): "
                  + ("; ".join(where) or "nothing published"), flush=True)
        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            live.assembler.start()
            summary = service.run(live.assembler, stop=stop, duration_s=config.duration_s)
            if "t_s" in got:  # run() has finished the log on its way out
                summary["stop_to_log_closed_s"] = time.monotonic() - got["t_s"]
        finally:
            for s, h in old.items():
                signal.signal(s, h)
        if "signal" in got:  # the log is finished; the rest (threads, cameras, sockets) gets what is left of 2 s
            live.close(timeout_s=max(0.2, CLOSE_BY_S - (time.monotonic() - got["t_s"])))
    errors = (summary.get("assembly") or {}).get("errors") or ()
    if summary["frame_sets"] == 0 and errors and all(errors):  # no camera ever delivered: nothing to keep
        if args.log:
            Path(args.log).unlink(missing_ok=True)
        raise ValueError("no camera delivered a frame: " + "; ".join(str(e) for e in errors))
    if "signal" in got:
        summary["stopped_by"] = got["signal"]
        print(f"rt2 track: stopped by {got['signal']}" + (f"; log finished {summary['stop_to_log_closed_s']:.2f} s later"
                                                        if args.log and "stop_to_log_closed_s" in summary else ""), file=sys.stderr)
    _print_summary(summary)
    log_error = (summary.get("log") or {}).get("error")
    if log_error:
        print(f"rt2 track: error: the session log {args.log} failed ({log_error}); tracking and publishing went on", file=sys.stderr)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(to_json_value(summary, "track summary", lenient=True), indent=1) + "\n")
        print(f"wrote {args.json}")
    code = 1 if log_error else 0
    if "signal" in got:  # stopped, everything written: leave without the interpreter's slow teardown
        from harness.common.fast_exit import exit_at_once_when_done

        exit_at_once_when_done(code)
    return code

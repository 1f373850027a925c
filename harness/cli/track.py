"""``rt2 track``: the tracker as a real-time service (docs/live.md).

    rt2 track --duration 5                                  # the simulated lab as four live cameras
    rt2 track --source replay out/demo/session.mcap --log out/track.mcap --json out/track.json
    rt2 track --source opencv 0 1 2 3 --rig data/rigs/my_lab.yaml --foxglove

Cameras (``--source``) -> frame-set assembly -> :class:`~harness.live.service.TrackingService`
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
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

__all__ = ["add_arguments", "run", "open_service"]

DEFAULT_RIG = "lab4_vga"  # data/rigs/lab4_vga.yaml, found from any working directory
_TRACKERS = ("rt2", "rt2-paper", "rtblob")


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
    parser.add_argument("--tracker", default="rt2", choices=_TRACKERS, help="tracker kind (default rt2)")
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
    parser.add_argument("--queue-s", type=float, default=0.25, metavar="S",
                        help="frames and frame sets buffered before anything is dropped, in seconds of the frame rate "
                             "(default 0.25: a hiccup of the machine that long costs latency, not frame sets)")


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


def _addresses(args) -> tuple[str | None, str | None]:
    from harness.live.publish import TENNICAM_PORT, parse_address

    pub = None if str(args.publish).lower() == "none" else parse_address(args.publish, default_port=TENNICAM_PORT)
    if args.publish_rt2 is not None and str(args.publish_rt2).lower() == "none":
        return pub, None
    if args.publish_rt2 is not None:
        return pub, parse_address(args.publish_rt2, default_port=TENNICAM_PORT + 1)
    if pub is None:
        return None, None
    host, port = pub.rsplit(":", 1)
    return pub, (f"{host}:0" if port == "0" else f"{host}:{int(port) + 1}")


def check_output_paths(args) -> None:
    """Refuse, before anything starts, a log that exists (without --log-overwrite) or an output path
    that is a folder or lies under a file; missing folders are created when the file is written."""
    for flag, value in (("--log", args.log), ("--json", getattr(args, "json", None))):
        if not value:
            continue
        p = Path(value)
        if p.is_dir():
            raise ValueError(f"{flag} {value!r} is a folder; give a file name")
        parent = next((q for q in p.parents if q.exists()), None)
        if parent is not None and not parent.is_dir():
            raise ValueError(f"{flag} {value!r}: {str(parent)!r} is a file, not a folder")
    if args.log and Path(args.log).exists() and not args.log_overwrite:
        raise ValueError(f"--log {args.log!r} exists; pass --log-overwrite to replace it")


def open_frames(args, rig):
    """Open the cameras of ``--source`` and the frame-set assembler; returns (assembler, description)."""
    from harness.live.assembly import AssemblyOptions, FrameSetAssembler
    from harness.live.sources import open_sources, parse_source_spec

    spec = parse_source_spec(args.source)
    if not (isinstance(args.rate_hz, (int, float)) and math.isfinite(args.rate_hz) and args.rate_hz > 0):
        raise ValueError(f"--rate-hz must be a positive number, got {args.rate_hz}")
    extra = {}
    if getattr(args, "prerender", None) is not None:
        if spec.kind != "sim":
            raise ValueError(f"--prerender applies to the sim source only, got --source {' '.join(args.source)}")
        if not (math.isfinite(args.prerender) and 0 < args.prerender <= 10):
            raise ValueError(f"--prerender must be in (0, 10] seconds, got {args.prerender}")
        extra["prerender_s"] = float(args.prerender)
    queue_s = getattr(args, "queue_s", 0.25)
    if not (math.isfinite(queue_s) and 0 < queue_s <= 10):
        raise ValueError(f"--queue-s must be in (0, 10] seconds, got {queue_s}")
    n_queue = max(8, math.ceil(queue_s * args.rate_hz))
    render_rig, clock, provider = rig, "host", None
    if spec.kind != "sim" and (getattr(args, "truth_stream", None) or getattr(args, "sim_rig", None)):
        raise ValueError(f"--truth-stream and --sim-rig apply to the sim source only, got --source {' '.join(args.source)}")
    if getattr(args, "sim_rig", None):
        from harness.sim.rigs import resolve_rig

        render_rig = resolve_rig(args.sim_rig)
        if render_rig.names != rig.names:
            raise ValueError(f"--sim-rig {args.sim_rig!r} has cameras {list(render_rig.names)}, --rig {args.rig!r} has "
                             f"{list(rig.names)}: they must be the same cameras")
    if getattr(args, "truth_stream", None):
        from harness.experiments.accuracy.truth_scene import LabTruthScene

        if "prerender_s" in extra:
            raise ValueError("--prerender cannot go with --truth-stream (the lab is rendered as the truth arrives)")
        provider = LabTruthScene(args.truth_stream, args.scene, seed=args.seed)
        if not (math.isfinite(args.max_behind) and 0 < args.max_behind <= 3600):
            raise ValueError(f"--max-behind must be in (0, 3600] seconds, got {args.max_behind}")
        extra["clock"], clock = "host", "device"  # exposure stamped on the host clock: take it as it is
        extra["max_behind_s"] = float(args.max_behind)
    sources = open_sources(spec, render_rig, rate_hz=args.rate_hz, seed=args.seed, queue_len=n_queue,
                           scene_provider=provider, **extra)
    try:
        if len(sources) != len(rig):
            raise ValueError(f"--source {' '.join(args.source)} gives {len(sources)} camera(s) but rig {args.rig!r} has {len(rig)}")
        assembler = FrameSetAssembler(sources, AssemblyOptions(rate_hz=args.rate_hz, queue_len=n_queue, output_len=n_queue,
                                                               clock=clock))
    except BaseException:
        for s in sources:
            s.close()
        raise
    return assembler, " ".join(args.source)


def open_service(args, *, status=print, tracker_overrides: dict | None = None):
    """Everything ``rt2 track`` runs, opened in an order that leaves nothing behind on bad input:
    checks, rig, tracker, sockets, live view, cameras, and the log last. Returns (service, assembler, closers).

    tracker_overrides : options of the tracker (``roi=False`` for full-frame search, ...)"""
    from harness.live.publish import Publisher
    from harness.live.service import ServiceOptions, TrackingService, warm_up
    from harness.sim.rigs import resolve_rig
    from tracker import Tracker

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not (math.isfinite(args.status_period) and args.status_period >= 0):
        raise ValueError(f"--status-period must be >= 0 seconds, got {args.status_period}")
    check_output_paths(args)
    tennicam_addr, rich_addr = _addresses(args)
    rig = resolve_rig(args.rig)
    closers = []
    try:
        tracker = Tracker(rig, args.tracker, **(tracker_overrides or {}))
        closers.append(tracker.close)
        warm_up(tracker, rig)
        publisher = None
        if tennicam_addr is not None or rich_addr is not None:
            publisher = Publisher(tennicam_addr, rich_addr)
            closers.append(publisher.close)
        view = None
        if args.foxglove is not None:
            from harness.live.foxglove_view import LiveView, ViewOptions

            view = LiveView(rig, args.tracker, ViewOptions(host=args.foxglove_host, port=args.foxglove))
            closers.append(view.close)
        assembler, described = open_frames(args, rig)
        closers.append(assembler.close)
        log = None
        if args.log:
            from harness.live.session_log import LiveLog

            Path(args.log).parent.mkdir(parents=True, exist_ok=True)
            log = LiveLog(args.log, rig, tracker, source=described, seed=args.seed, log_images=args.log_images,
                          image_format=args.log_image_format, overwrite=args.log_overwrite,
                          config={"rig": str(args.rig), "source": list(args.source), "rate_hz": args.rate_hz,
                                  "tracker": args.tracker, "publish": tennicam_addr, "publish_rt2": rich_addr})
        try:
            service = TrackingService(rig, tracker, publisher=publisher, log=log, view=view,
                                      options=ServiceOptions(status_period_s=args.status_period), status=status)
        except BaseException:
            if log is not None:  # nothing tracked yet: leave no half-written log behind
                log.close(error="not started")
                Path(args.log).unlink(missing_ok=True)
            raise
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    return service, assembler, closers


def _print_summary(s: dict) -> None:
    lat = s["latency_ms"]
    print(f"rt2 track: {s['frame_sets']} frame sets in {s['duration_s']:.1f} s ({s['rate_hz']:.1f}/s), tracker {s['tracker']}")
    print(f"  latency (first frame's arrival -> message sent): p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms")
    print(f"  status: " + ", ".join(f"{k} {v}" for k, v in sorted(s["status"].items())))
    print(f"  frame sets without a camera's frame: " + ", ".join(f"{k} {v}" for k, v in s["missing_frames"].items()))
    a = s.get("assembly")
    if isinstance(a, dict) and "dropped_framesets" in a:
        print(f"  assembly: {a.get('complete')} complete, {a.get('incomplete')} incomplete, "
              f"{a.get('dropped_framesets')} frame sets dropped before the tracker (it did not take them in time), "
              f"frames dropped per camera {list(a.get('dropped', ()))}, late {list(a.get('late', ()))}")
        for e in a.get("errors", ()) or ():
            if e:
                print(f"  camera failed (not restarted): {e}")
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

    service, assembler, closers = open_service(args, status=lambda line: print(line, flush=True))
    where = [f"{k} stream on {v}" for k, v in (service.publisher.addresses if service.publisher else {}).items()]
    if service.view is not None:
        where.append(f"live view on ws://{args.foxglove_host}:{service.view.port}")
    if service.log is not None:
        where.append(f"log {service.log.path}")
    if getattr(args, "ready_json", False):
        print(json.dumps({"streams": dict(service.publisher.addresses if service.publisher else {}),
                          "tracker": args.tracker, "rig": str(args.rig), "pid": os.getpid()}), flush=True)
    else:
        print(f"rt2 track: {args.tracker} on {' '.join(args.source)} ({len(service.rig)} cameras, rig {args.rig}): "
              + ("; ".join(where) or "nothing published"), flush=True)
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        assembler.start()
        summary = service.run(assembler, stop=stop, duration_s=args.duration)
        if "t_s" in got:  # run() has finished the log on its way out
            summary["stop_to_log_closed_s"] = time.monotonic() - got["t_s"]
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        service.finish()
        for close in reversed(closers):
            close()
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
    return 1 if log_error else 0

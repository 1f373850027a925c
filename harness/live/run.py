"""Build ``rt2 track``'s live service from its options: cameras, assembler, tracker, streams, live view, log.

    service, assembler, closers = open_service(args, status=print)
    assembler.start()
    summary = service.run(assembler, duration_s=5.0)
    service.finish()
    for close in reversed(closers):
        close()

``args`` holds the options of ``rt2 track`` (``harness.cli.track.add_arguments``); ``rt2 track`` and
``rt2 bench live`` (:mod:`harness.live.bench`) build their service here, and the live experiments run
``rt2 track`` itself (:mod:`harness.live.spawn`). Everything is checked before anything is opened, and
what was opened is closed again when a later step fails, so bad input leaves no socket, camera or log behind.
"""

from __future__ import annotations

import math
from pathlib import Path

__all__ = ["DEFAULT_MAX_BACKLOG", "SIM_RENDER", "check_output_paths", "open_frames", "open_service", "stream_addresses"]

#: frame sets that may wait for the tracker before the oldest is skipped (``--max-backlog``); chosen with
#: ``rt2 bench live --max-backlog 1`` and ``3`` against the default (README, "Latency first")
DEFAULT_MAX_BACKLOG = 1
#: where the sim source renders (``--sim-render``): auto = a child process unless --prerender or --truth-stream
SIM_RENDER = ("auto", "process", "thread")


def stream_addresses(args) -> tuple[str | None, str | None]:
    """(tennicam address, rt2 address) of ``--publish`` / ``--publish-rt2``; None = off. rt2's stream
    defaults to the next port after the tennicam one (port 0 stays 0: a free port each)."""
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


def open_frames(args, rig, *, truth_scene=None):
    """Open the cameras of ``--source`` and the frame-set assembler; returns (assembler, description).

    args : ``rt2 track``'s options (see :func:`open_service`); rig : the tracker's rig
    truth_scene : ``truth_scene(address, scene, seed=)`` -> the sim source's scene provider, needed with
    ``--truth-stream`` (``rt2 track`` passes the accuracy experiment's ``LabTruthScene``)"""
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
    backlog = getattr(args, "max_backlog", DEFAULT_MAX_BACKLOG)
    if isinstance(backlog, bool) or not isinstance(backlog, int) or not 1 <= backlog <= n_queue:
        raise ValueError(f"--max-backlog must be a whole number of frame sets in [1, {n_queue}] (--queue-s x --rate-hz), "
                         f"got {backlog!r}")
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
        if "prerender_s" in extra:
            raise ValueError("--prerender cannot go with --truth-stream (the lab is rendered as the truth arrives)")
        if truth_scene is None:
            raise ValueError("--truth-stream needs a lab truth scene: pass truth_scene= (e.g. "
                             "harness.experiments.accuracy.truth_scene.LabTruthScene)")
        provider = truth_scene(args.truth_stream, args.scene, seed=args.seed)
        if not (math.isfinite(args.max_behind) and 0 < args.max_behind <= 3600):
            raise ValueError(f"--max-behind must be in (0, 3600] seconds, got {args.max_behind}")
        extra["clock"], clock = "host", "device"  # exposure stamped on the host clock: take it as it is
        extra["max_behind_s"] = float(args.max_behind)
    render = getattr(args, "sim_render", "auto")
    if render not in SIM_RENDER:
        raise ValueError(f"--sim-render must be one of {SIM_RENDER}, got {render!r}")
    if render != "auto" and spec.kind != "sim":
        raise ValueError(f"--sim-render applies to the sim source only, got --source {' '.join(args.source)}")
    if render == "process" and ("prerender_s" in extra or provider is not None):
        raise ValueError("--sim-render process cannot go with --prerender or --truth-stream (those render in the service's process)")
    nice = getattr(args, "sim_render_nice", None)
    if nice is not None and (isinstance(nice, bool) or not isinstance(nice, int) or not 0 <= nice <= 19):
        raise ValueError(f"--sim-render-nice must be a whole number in [0, 19], got {nice!r}")
    if nice is not None and spec.kind != "sim":
        raise ValueError(f"--sim-render-nice applies to the sim source only, got --source {' '.join(args.source)}")
    if spec.kind == "sim" and "prerender_s" not in extra and provider is None:
        extra["render_process"] = render != "thread"  # "auto": a child process, as a camera driver's own threads
        if nice is not None:
            extra["render_nice"] = nice
    sources = open_sources(spec, render_rig, rate_hz=args.rate_hz, seed=args.seed, queue_len=n_queue,
                           scene_provider=provider, **extra)
    try:
        if len(sources) != len(rig):
            raise ValueError(f"--source {' '.join(args.source)} gives {len(sources)} camera(s) but rig {args.rig!r} has {len(rig)}")
        assembler = FrameSetAssembler(sources, AssemblyOptions(rate_hz=args.rate_hz, queue_len=n_queue, output_len=backlog,
                                                               clock=clock))
    except BaseException:
        for s in sources:
            s.close()
        raise
    return assembler, " ".join(args.source)


def open_service(args, *, status=print, tracker_overrides: dict | None = None, truth_scene=None):
    """Everything ``rt2 track`` runs, opened in an order that leaves nothing behind on bad input:
    checks, rig, tracker, sockets, live view, cameras, and the log last. Returns (service, assembler, closers).

    args : ``rt2 track``'s options as its parser gives them (``harness.cli.track.add_arguments``; an
    ``argparse.Namespace`` with the same fields works from Python); errors name the option (``--rate-hz``, ...)
    tracker_overrides : options of the tracker (``roi=False`` for full-frame search, ...)
    truth_scene : the scene provider's builder for ``--truth-stream`` (:func:`open_frames`)"""
    from harness.live.publish import Publisher
    from harness.live.service import ServiceOptions, TrackingService, warm_up
    from harness.sim.rigs import resolve_rig
    from tracker import Tracker

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not (math.isfinite(args.status_period) and args.status_period >= 0):
        raise ValueError(f"--status-period must be >= 0 seconds, got {args.status_period}")
    check_output_paths(args)
    tennicam_addr, rich_addr = stream_addresses(args)
    rig = resolve_rig(args.rig)
    closers = []
    try:
        workers = getattr(args, "workers", 1)
        if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 64:
            raise ValueError(f"--workers must be a whole number in [1, 64], got {workers!r}")
        model = getattr(args, "model", None)
        if model is not None and args.tracker == "rtblob":
            raise ValueError("--model applies to the rt2 kinds only (rtblob matches a colour and a template, it has no model)")
        if model is not None and not Path(model).is_file():
            raise ValueError(f"--model {str(model)!r}: no such file (train one with `rt2 train --out MODEL.npz`)")
        kw = {"model": model} if model is not None else {}
        tracker = Tracker(rig, args.tracker, **kw, **({"workers": workers} if workers != 1 else {}), **(tracker_overrides or {}))
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
        assembler, described = open_frames(args, rig, truth_scene=truth_scene)
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

"""Build ``rt2 track``'s live service from a :class:`~harness.live.config.TrackConfig`: cameras, assembler,
tracker, streams, live view, log.

    with open_service(config, status=print) as live:
        live.assembler.start()
        summary = live.service.run(live.assembler, duration_s=config.duration_s)

``rt2 track`` and ``rt2 bench live`` (:mod:`harness.live.bench`) build their service here, and the live
experiments run ``rt2 track`` itself (:mod:`harness.live.spawn_track`). The config was checked when it was made;
what needs the file system is checked before anything is opened, and what was opened is closed again when a
later step fails, so bad input leaves no socket, camera or log behind. Errors name the config's fields
(:class:`~harness.live.config.ConfigError`).
"""

from __future__ import annotations

import threading
from pathlib import Path

from harness.live.config import DEFAULT_MAX_BACKLOG, NEXT_PORT, SIM_RENDER, ConfigError, TrackConfig

__all__ = ["DEFAULT_MAX_BACKLOG", "DEFERRED_WAIT_PERIODS", "SIM_RENDER", "LiveService", "open_frames", "open_service",
           "stream_addresses"]

#: with the deferred full-frame search: how long (frame periods) a frame set that comes while it runs waits for it
#: (``TrackerOptions.deferred_wait_s``): on eight VGA cameras 6-11 frame sets in 15 s came just before it ended
DEFERRED_WAIT_PERIODS = 0.4


def stream_addresses(config: TrackConfig) -> tuple[str | None, str | None]:
    """(tennicam address, rt2 address) of ``publish`` / ``publish_rt2``; None = off. rt2's stream
    defaults (:data:`NEXT_PORT`) to the next port after the tennicam one (port 0 stays 0: a free port each)."""
    from harness.live.publish import TENNICAM_PORT, parse_address

    pub = None if config.publish is None else parse_address(config.publish, default_port=TENNICAM_PORT)
    if config.publish_rt2 is None:
        return pub, None
    if config.publish_rt2 != NEXT_PORT:
        return pub, parse_address(config.publish_rt2, default_port=TENNICAM_PORT + 1)
    if pub is None:
        return None, None
    host, port = pub.rsplit(":", 1)
    return pub, (f"{host}:0" if port == "0" else f"{host}:{int(port) + 1}")


def open_frames(config: TrackConfig, rig, *, truth_scene=None):
    """Open the cameras of ``config.source`` and the frame-set assembler; returns (assembler, description).

    rig : the tracker's rig; truth_scene : ``truth_scene(address, scene, seed=)`` -> the sim source's scene
    provider, needed with ``truth_stream`` (``rt2 track`` passes the accuracy experiment's ``LabTruthScene``)"""
    from harness.live.assembly import AssemblyOptions, FrameSetAssembler
    from harness.live.sources import open_sources, parse_source_spec

    spec = parse_source_spec(list(config.source))
    extra = {}
    if config.prerender_s is not None:
        extra["prerender_s"] = float(config.prerender_s)
    render_rig, clock, provider = rig, "host", None
    if config.sim_rig:
        from tracker.rig_files import resolve_rig

        render_rig = resolve_rig(config.sim_rig)
        if render_rig.names != rig.names:
            raise ConfigError("sim_rig", f"{{sim_rig}} {config.sim_rig!r} has cameras {list(render_rig.names)}, {{rig}} {config.rig!r} has "
                                         f"{list(rig.names)}: they must be the same cameras")
    if config.truth_stream:
        if truth_scene is None:
            raise ConfigError("truth_stream", "{truth_stream} needs a lab truth scene: pass truth_scene= (e.g. "
                                              "harness.experiments.accuracy.truth_scene.LabTruthScene)")
        provider = truth_scene(config.truth_stream, config.scene, seed=config.seed)
        extra["clock"], clock = "host", "device"  # exposure stamped on the host clock: take it as it is
        extra["max_behind_s"] = float(config.max_behind_s)
    if spec.kind == "sim" and "prerender_s" not in extra and provider is None:
        extra["render_process"] = config.sim_render != "thread"  # "auto": a child process, as a camera driver's own threads
        if config.sim_render_nice is not None:
            extra["render_nice"] = config.sim_render_nice
    if spec.kind == "sim":
        extra["ball_colour"] = config.sim_ball
    n_queue = config.queue_len
    sources = open_sources(spec, render_rig, rate_hz=config.rate_hz, seed=config.seed, queue_len=n_queue,
                           scene_provider=provider, **extra)
    try:
        if len(sources) != len(rig):
            raise ConfigError("source", f"{{source}} {' '.join(config.source)} gives {len(sources)} camera(s) but {{rig}} "
                                        f"{config.rig!r} has {len(rig)}")
        assembler = FrameSetAssembler(sources, AssemblyOptions(rate_hz=config.rate_hz, queue_len=n_queue, output_len=config.max_backlog,
                                                               clock=clock))
    except BaseException:
        for s in sources:
            s.close()
        raise
    return assembler, " ".join(config.source)


class LiveService:
    """What :func:`open_service` opened: ``service`` (:class:`~harness.live.service.TrackingService`, with its
    ``tracker``, ``publisher``, ``log``, ``view``), ``assembler`` and ``config``. A context manager:
    leaving it (or :meth:`close`) finishes the service (its log) and closes everything in reverse order."""

    def __init__(self, config: TrackConfig, service, assembler, closers: list):
        self.config, self.service, self.assembler = config, service, assembler
        self._closers = closers

    def close(self, timeout_s: float | None = None) -> bool:
        """Finish the service (its log: always, whatever it takes) and close what was opened, newest first (once).
        With ``timeout_s`` (a run stopped by a signal, which has 2 s to exit) the closing runs in a daemon thread
        and is waited for that long: a camera driver or a thread that is slow to stop is left to the process's
        exit. Returns whether everything was closed."""
        closers, self._closers = self._closers, []
        if not closers:
            return True

        def close_all():
            for close in reversed(closers):
                close()

        try:
            self.service.finish()
        finally:  # the closers run also when finishing failed; its error then goes on to the caller
            if timeout_s is None:
                close_all()
                done = True
            else:
                t = threading.Thread(target=close_all, name="rt2-live-close", daemon=True)
                t.start()
                t.join(timeout_s)
                done = not t.is_alive()
        return done

    def __enter__(self) -> "LiveService":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_service(config: TrackConfig, *, status=print, truth_scene=None) -> LiveService:
    """Everything ``rt2 track`` runs, opened in an order that leaves nothing behind on bad input:
    path checks, rig, tracker, sockets, live view, cameras, and the log last. Returns a :class:`LiveService`.

    config : :class:`TrackConfig`; status : callable taking one line of text (None = quiet)
    truth_scene : the scene provider's builder for ``truth_stream`` (:func:`open_frames`)"""
    from harness.live._memory import keep_freed_memory
    from harness.live.publish import Publisher
    from harness.live.service import ServiceOptions, TrackingService, warm_up
    from tracker.rig_files import resolve_rig
    from tracker import Tracker

    if not isinstance(config, TrackConfig):
        raise ValueError(f"open_service takes a harness.live.config.TrackConfig, got {type(config).__name__}")
    config.check_paths()
    keep_freed_memory()  # frames freed per set are reused, not mapped anew (page faults per set)
    tennicam_addr, rich_addr = stream_addresses(config)
    rig = resolve_rig(config.rig)
    closers = []
    try:
        kw = {"model": config.model_path} if config.model_path is not None else {}
        if config.tracker_workers != 1:
            kw["workers"] = config.tracker_workers
        if config.roi is not None:
            kw["roi"] = config.roi
        if config.motion_cue:
            from tracker import MotionOptions

            kw["motion_cue"] = MotionOptions()
        defer = config.defer_full_frame
        if defer is None:  # auto: on for the filter alone, off with a learned stage (its windows fall back often: see TrackConfig)
            from tracker.pipeline import load_model

            if config.tracker != "rtblob":
                kw["model"] = load_model(config.model_path)
            defer = config.tracker != "rtblob" and kw["model"].learned is None
        if defer:  # a frame set that comes while the search runs waits for it 0.4 of a period (TrackerOptions.deferred_wait_s)
            kw["deferred_wait_s"] = DEFERRED_WAIT_PERIODS / config.rate_hz
        tracker = Tracker(rig, config.tracker, full_frame_pyramid=config.full_frame_pyramid, defer_full_frame=defer, **kw)
        closers.append(tracker.close)
        warm_up(tracker, rig)
        publisher = None
        if tennicam_addr is not None or rich_addr is not None:
            publisher = Publisher(tennicam_addr, rich_addr)
            closers.append(publisher.close)
        view = None
        if config.foxglove_port is not None:
            from harness.live.foxglove_view import LiveView, ViewOptions

            view = LiveView(rig, config.tracker, ViewOptions(host=config.foxglove_host, port=config.foxglove_port))
            closers.append(view.close)
        assembler, described = open_frames(config, rig, truth_scene=truth_scene)
        closers.append(assembler.close)
        log = None
        if config.log_path:
            from harness.live.session_log import LiveLog

            Path(config.log_path).parent.mkdir(parents=True, exist_ok=True)
            log = LiveLog(config.log_path, rig, tracker, source=described, seed=config.seed, log_images=config.log_images,
                          image_format=config.log_image_format, overwrite=config.log_overwrite, model_path=config.model_path,
                          config={"rig": str(config.rig), "source": list(config.source), "rate_hz": config.rate_hz,
                                  "tracker": config.tracker, "publish": tennicam_addr, "publish_rt2": rich_addr})
        try:
            service = TrackingService(rig, tracker, publisher=publisher, log=log, view=view,
                                      options=ServiceOptions(status_period_s=config.status_period_s), status=status)
        except BaseException:
            if log is not None:  # nothing tracked yet: leave no half-written log behind
                log.close(error="not started")
                Path(config.log_path).unlink(missing_ok=True)
            raise
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    return LiveService(config, service, assembler, closers)

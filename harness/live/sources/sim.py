"""``sim``: the simulated lab seen as live cameras.

The renderer (:mod:`harness.sim.render`, docs/renderer.md) draws frame set k of the scene at
``t = k / rate_hz`` (``scene_provider(t) -> Scene``); a background thread renders up to
``render_ahead`` frame sets ahead of the clock and the :class:`~._feed.PacedFeed` emits them at the
rate with host stamps. The device stamp is the scene time ``k / rate_hz`` (a camera clock starting at
0, as if the cameras were hardware-triggered from one clock); all cameras share frame id k.

Honest about speed: one process renders ~470 busy VGA images/s and ~3400/s with one flying ball
(docs/renderer.md), so four VGA cameras of launcher flights at 200 Hz (800 images/s) fit in one
core, a busy ``scene_provider`` may not. The clock is fixed (frame set k is due at ``t0 + k /
rate_hz``): a frame set rendered after its due time is emitted at once and counted in ``late`` (a
render process does not start a frame set more than a period after its due time: it answers it skipped,
counted in ``skipped``, so a renderer starved of CPU spends its time on frame sets it can still deliver,
at most a render's time late, rather than on a queue of stale ones delivered in a burst);
when the renderer finds its next frame set already due it skips ahead to the next one not yet due
(counted in ``skipped``; the frame ids jump, as with a camera that loses frames), so host and device
stamps stay consistent and the run stays real time. ``prerender_s`` renders a clip up front and
loops it instead (memory: 0.92 MB per VGA image). The renderer shares the GIL with the tracker
when both run in one process.

The default scene is seeded launcher ball flights (:class:`LauncherFlights`); any callable
``t_s -> Scene`` may replace it (e.g. the ball on the WAM's end effector driven by live joint states).
Scene time ``t_s`` is host time ``feed.origin_s + t_s`` (``sources[i].feed``); a provider that
follows live state should run with ``render_ahead=1``, so that what it returns is drawn at most about
a period before the frame is stamped.

``clock="host"`` is for a lab driven by other processes (the simulated WAM behind its bridge): frame set
k is *exposed* at host time ``origin + k / rate_hz``, rendered after that instant from
``scene_provider(t_host_s, k)`` (:class:`harness.experiments.accuracy.truth_scene.LabTruthScene` waits for the lab truth stream's
sample at that instant), and stamped with the exposure time on the host clock as its device stamp; it
arrives later by the wait and the render time, as a frame from a camera with hardware timestamps does.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from harness.common.disk_cache import cached
from harness.live.sources._feed import FeedItem, PacedFeed
from harness.sim.render import Ball, Exposure, Renderer, RenderOptions, Scene
from harness.sim.render.scenes import BALL_COLOURS  # the default scene's ball colours (``SimOptions.ball_colour``)

__all__ = ["BALL_COLOURS", "LauncherFlights", "SimOptions", "open_sim"]


@dataclass(frozen=True)
class SimOptions:
    """Options of the ``sim`` source.

    rate_hz : frame sets per second (scene time step ``1 / rate_hz``)
    seed : fixes the default scene (launcher flights) and the sensor noise: same seed, same images
    render_ahead : frame sets rendered ahead of the clock by the background thread
    prerender_s : None = render while running; else render this many seconds up front and loop them
    duration_s : None = run until closed; else stop (sources ``exhausted``) after this much scene time
    speed : 1.0 real time, None = as fast as rendering allows (for benchmarks and tests)
    queue_len : frames buffered per camera before the oldest is dropped (counted)
    exposure : the cameras' exposure (constant)
    render_process : render in a child process (another core, never holding the tracker's interpreter
        lock; the scene provider must be picklable; ~1 s per VGA camera to start) instead of a thread
    clock : "scene" (frame set k shows scene time k / rate_hz, rendered ahead, device stamp k / rate_hz) or
        "host": frame set k is exposed at host time ``origin + k / rate_hz`` (CLOCK_MONOTONIC, ``origin`` when
        the feed starts), rendered only once that instant has passed by ``scene_provider(t_host_s, k)``
        (which may wait for the lab's truth at it, e.g. :class:`harness.experiments.accuracy.truth_scene.LabTruthScene`), and stamped
        with the exposure time as its device stamp while it arrives later -- a camera with hardware
        timestamps on the host clock (assemble with ``clock="device"``)
    render_nice : with ``render_process``: the child's CPU priority below the tracker's (``os.nice``, 0-19;
        default 10): on a busy machine the tracker gets the cores first, as with cameras that render on
        their own hardware; frame sets the renderer cannot make in time are skipped and counted
    max_behind_s : "host" clock: when frame set k's exposure is further than this in the past as its turn
        comes, the renderer skips to the present (counted in ``skipped``): a renderer slower than real time
        falls behind by up to this much, renders every frame meanwhile, then catches up at once
    ball_colour : the default scene's ball, one of :data:`BALL_COLOURS` (a white ball for a white-ball model)
    """

    rate_hz: float = 200.0
    seed: int = 0
    render_ahead: int = 16
    prerender_s: float | None = None
    duration_s: float | None = None
    speed: float | None = 1.0
    queue_len: int = 8
    exposure: Exposure = Exposure(exposure_s=0.002, gain=1.0, light_level=1.0)
    render_process: bool = False
    render_nice: int = 10
    clock: str = "scene"
    max_behind_s: float = 0.1
    ball_colour: str = "orange"

    def __post_init__(self):
        if self.ball_colour not in BALL_COLOURS:
            raise ValueError(f"SimOptions.ball_colour must be one of {BALL_COLOURS}, got {self.ball_colour!r}")
        if self.clock not in ("scene", "host"):
            raise ValueError(f"SimOptions.clock must be 'scene' or 'host', got {self.clock!r}")
        if self.clock == "host" and (self.prerender_s is not None or self.render_process):
            raise ValueError("SimOptions.clock='host' renders each frame after its exposure: it cannot go with "
                             "prerender_s or render_process")
        if not (np.isfinite(self.max_behind_s) and self.max_behind_s > 0):
            raise ValueError(f"SimOptions.max_behind_s must be > 0 s, got {self.max_behind_s!r}")
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"SimOptions.rate_hz must be > 0, got {self.rate_hz!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"SimOptions.seed must be an integer >= 0, got {self.seed!r}")
        for name in ("prerender_s", "duration_s"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"SimOptions.{name} must be None or > 0 seconds, got {v!r}")
        if isinstance(self.render_nice, bool) or not isinstance(self.render_nice, int) or not 0 <= self.render_nice <= 19:
            raise ValueError(f"SimOptions.render_nice must be a whole number in [0, 19], got {self.render_nice!r}")
        if self.render_ahead < 1:
            raise ValueError(f"SimOptions.render_ahead must be >= 1, got {self.render_ahead!r}")


class LauncherFlights:
    """Seeded launcher serves one after another: ``flights(t_s) -> Scene`` with the ball at ``t_s``.

    Each serve (:class:`harness.sim.launcher.BallLauncher`) flies until it reaches the floor or
    ``max_flight_s``; then the lab is empty for ``gap_s`` before the next serve. ``n_serves`` serves
    (~0.3 s each to draw) are drawn up front and repeat in a cycle, so nothing slow happens while
    the clock runs; the scene at a time depends only on the seed. Drawn flights are kept on disk
    (harness/common/disk_cache.py): the next process with the same seed reads them back.
    """

    def __init__(self, seed: int, *, n_serves: int = 8, gap_s: float = 0.3, max_flight_s: float = 1.5,
                 exposure: Exposure = SimOptions.exposure, colour: str = "orange"):
        self.gap_s = float(gap_s)
        self.max_flight_s = float(max_flight_s)
        self.exposure = exposure
        if colour not in BALL_COLOURS:
            raise ValueError(f"LauncherFlights.colour must be one of {BALL_COLOURS}, got {colour!r}")
        self.colour = colour
        if isinstance(n_serves, bool) or int(n_serves) < 1:
            raise ValueError(f"LauncherFlights.n_serves must be >= 1, got {n_serves!r}")
        drawn = _flights_on_disk(int(seed), int(n_serves), self.gap_s, self.max_flight_s)
        self._starts = [float(t) for t in drawn["starts"]]  # scene time at which flight i starts
        self._flights = [(drawn[f"times_{i}"], drawn[f"states_{i}"]) for i in range(len(self._starts))]  # (K,), (K, 9)
        self.cycle_s = self._starts[-1] + self._flights[-1][0][-1] + self.gap_s

    def ball_state(self, t_s: float) -> np.ndarray | None:
        """(9,) [p, v, w] of the ball at scene time ``t_s``, or None between flights."""
        t_s = float(t_s) % self.cycle_s
        i = int(np.searchsorted(self._starts, t_s, side="right")) - 1
        times, states = self._flights[i]
        local = t_s - self._starts[i]
        if local > times[-1]:
            return None
        k = min(int(np.searchsorted(times, local, side="right")) - 1, len(times) - 2)
        a = (local - times[k]) / (times[k + 1] - times[k])
        return (1 - a) * states[k] + a * states[k + 1]

    def __call__(self, t_s: float) -> Scene:
        s = self.ball_state(t_s)
        balls = () if s is None else (Ball(s[:3], velocity_mps=s[3:6], colour=self.colour),)
        return Scene(balls=balls, exposure=self.exposure)


def _draw_flights(seed: int, n_serves: int, gap_s: float, max_flight_s: float) -> dict:
    """``n_serves`` seeded serves flown until the floor or ``max_flight_s``: ``starts`` (n,) and flight i's
    ``times_i`` (K,) and ``states_i`` (K, 9)."""
    from harness.sim.launcher import BallLauncher  # only when flights are drawn, not read back
    from harness.sim.physics import BallWorld

    launcher = BallLauncher(seed=seed)
    starts: list[float] = []
    flights: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(n_serves):
        serve = launcher.serve()
        world = BallWorld(launcher.params, launcher.world)
        world.reset(serve.state)
        times, states = world.run(max_flight_s)
        starts.append(starts[-1] + flights[-1][0][-1] + gap_s if flights else 0.0)
        flights.append((times, states))
    drawn = {"starts": np.asarray(starts, np.float64)}
    for i, (times, states) in enumerate(flights):
        drawn[f"times_{i}"], drawn[f"states_{i}"] = np.asarray(times), np.asarray(states)
    return drawn


def _flights_key(seed: int, n_serves: int, gap_s: float, max_flight_s: float) -> bytes:
    """What the drawn flights depend on besides the code: the arguments, the fitted ball parameters the launcher
    loads (data/ball_params.yaml) and scipy's version (the launcher aims with its least-squares solver)."""
    import pickle

    from importlib.metadata import version

    from policies.ball_model import BallParams

    params = BallParams.load()
    return pickle.dumps((seed, n_serves, gap_s, max_flight_s, version("scipy"), dataclasses.astuple(params)), protocol=4)


#: :func:`_draw_flights` kept on disk (harness/common/disk_cache.py): ~1-2 s per seed, once per machine. The code by
#: name: the launcher is imported only where flights are drawn, not where they are read back
_flights_on_disk = cached("sim-launcher-flights", _draw_flights, key_of=_flights_key,
                          code_of=(__name__, "harness.sim.launcher", "harness.sim.physics", "harness.common.seeding",
                                   "policies.ball_model", "policies._ball_integrate"))


def open_sim(rig, options: SimOptions = SimOptions(), *, scene_provider: Callable[[float], Scene] | None = None,
             render_options: RenderOptions = RenderOptions()):
    """One :class:`~._feed.FeedCamera` per rig camera, rendering ``scene_provider`` (default:
    :class:`LauncherFlights` with ``options.seed``). Returns ``(sources, feed)``; ``feed.stats()``
    counts late frame sets and drops."""
    if scene_provider is not None and not callable(scene_provider):
        raise ValueError(f"scene_provider must be a callable t_s -> Scene, got {type(scene_provider).__name__}")
    process = None
    if options.render_process and options.prerender_s is None:
        from harness.live.sources._render_process import RenderProcess

        # started first: the child ray-casts the lab while this process draws the flights
        process = RenderProcess(rig, render_options, options.seed, slots=options.render_ahead, nice=options.render_nice)
    provider = scene_provider
    try:
        if provider is None:
            provider = LauncherFlights(options.seed, exposure=options.exposure, colour=options.ball_colour)
            if options.clock == "host":
                flights, period_s = provider, 1.0 / options.rate_hz
                provider = lambda t_host_s, k: flights(k * period_s)  # noqa: E731 - scene time of frame set k
        if process is not None:
            process.start(provider)
    except BaseException:
        if process is not None:
            process.close()
        raise
    n = len(rig.cameras)
    period = 1.0 / options.rate_hz
    n_total = None if options.duration_s is None else int(round(options.duration_s * options.rate_hz))
    if process is not None:
        renderer = None
    else:
        renderer = Renderer(rig, render_options, seed=options.seed)  # ray-casts the static lab (~1 s per VGA camera)

    def render(k: int) -> tuple:
        scene = provider(k * period)
        if not isinstance(scene, Scene):
            raise ValueError(f"scene_provider({k * period:.4f}) returned {type(scene).__name__}, not a Scene")
        return tuple(renderer.render(dataclasses.replace(scene, frame_index=k)))

    clip = None
    if options.prerender_s is not None:
        clip = [render(k) for k in range(max(1, int(round(options.prerender_s * options.rate_hz))))]

    def next_index(k: int) -> int:
        """k, or the first frame set not yet due when k already is (counted in ``skipped``)."""
        now = feed.schedule_now()
        if now is not None and clip is None and k * period < now:
            k_next = int(now / period) + 1
            feed.skipped += k_next - k
            return k_next
        return k

    def produce():
        k = 0
        while n_total is None or k < n_total:
            k = next_index(k)
            if n_total is not None and k >= n_total:
                break
            images = clip[k % len(clip)] if clip is not None else render(k)
            t = k * period
            yield FeedItem((k,) * n, t, (t,) * n, images)
            k += 1

    def produce_in_process():
        free, asked, k = list(range(process.slots)), 0, 0
        while True:
            # one request until the first emission fixes the schedule (its deadlines), then render ahead
            while free and (n_total is None or k < n_total) and (not asked or feed.origin_s is not None
                                                                  or feed.speed is None):
                k = next_index(k)
                if n_total is not None and k >= n_total:
                    break
                origin = feed.origin_s  # None before the first emission: render whatever it costs
                drop_after = math.nan if origin is None or feed.speed is None else origin + (k + 1) * period / feed.speed
                process.request(k, free.pop(), k * period, drop_after)
                asked += 1
                k += 1
            if not asked:
                return
            got = None
            while got is None:
                if feed.closing():
                    return
                got = process.result(0.1)
            k_done, slot, rendered = got
            asked -= 1
            if not rendered:  # the child would have started it after its deadline: skipped, counted
                free.append(slot)
                feed.skipped += 1
                continue
            images = process.images(slot)
            free.append(slot)
            t = k_done * period
            yield FeedItem((k_done,) * n, t, (t,) * n, images)

    def produce_on_host_clock():
        """Frame set k: wait for its exposure instant, render what the provider says is there, stamp it."""
        warm = getattr(provider, "warm_up_scene", None)
        if warm is not None:  # compile the renderer's kernels for this scene before the clock starts
            renderer.render(warm())
        if hasattr(provider, "open"):  # e.g. LabTruthScene: connect and wait for the first truth sample first
            provider.open()
        origin = time.monotonic() + 2 * period
        k = 0
        while n_total is None or k < n_total:
            now = time.monotonic()
            if now - (origin + k * period) > options.max_behind_s:  # too far behind: skip to the present
                k_next = int(np.ceil((now - origin) / period))
                feed.skipped += k_next - k
                k = k_next
                if n_total is not None and k >= n_total:
                    break
            t_exp = origin + k * period
            if t_exp > now and feed.wait_closing(t_exp - now):
                return
            scene = provider(t_exp, k)
            if not isinstance(scene, Scene):
                raise ValueError(f"scene_provider({t_exp:.4f}, {k}) returned {type(scene).__name__}, not a Scene")
            images = tuple(renderer.render(dataclasses.replace(scene, frame_index=k)))
            yield FeedItem((k,) * n, k * period, (t_exp,) * n, images)
            k += 1

    if options.clock == "host":
        producer = produce_on_host_clock
    else:
        producer = produce_in_process if process is not None else produce
    feed = PacedFeed("sim", range(n), rig.names, producer,
                     speed=options.speed, queue_len=options.queue_len,
                     prefetch=0 if clip is not None or process is not None or options.clock == "host"
                     else options.render_ahead,
                     late_tolerance_s=period if options.clock == "scene" else options.max_behind_s, slide=False)
    if process is not None:
        feed.add_closer(process.close)
    if hasattr(provider, "close"):  # e.g. a LabTruthScene's subscriber
        feed.add_closer(provider.close)
    return feed.views(), feed

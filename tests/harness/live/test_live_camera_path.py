"""The path of a simulated camera's frames to the tracker: a paced feed hands each frame set to the
assembler in the thread that stamped it (no reader threads), the sim renderer process runs at a lower
CPU priority, and frame sets it cannot start in time are skipped and counted, never delivered in a burst.
Same seed, same images whichever path they take."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from harness.live.assembly import AssemblyOptions, FrameSetAssembler
from harness.live.sources import open_sources
from harness.live.sources._feed import FeedItem, PacedFeed
from harness.live.sources.sim import LauncherFlights, SimOptions
from harness.sim.lab import preview_rig
from tests.harness.live._live_frames import drain


@pytest.fixture(scope="module")
def rig():
    return preview_rig(80, 60)


class SlowFlights:
    """A picklable scene provider that takes ``delay_s`` per frame set (a renderer that cannot keep up)."""

    def __init__(self, delay_s: float):
        self.delay_s = delay_s
        self.flights = LauncherFlights(0, n_serves=1)

    def __call__(self, t_s: float):
        time.sleep(self.delay_s)
        return self.flights(t_s)


def _reader_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("read ")]


def test_a_real_time_sim_feed_pushes_whole_sets_without_reader_threads(rig):
    flights = LauncherFlights(0, n_serves=1)
    sources = open_sources(["sim"], rig, rate_hz=100.0, seed=5, scene_provider=flights, duration_s=0.3,
                           render_process=True)
    before = set(_reader_threads())
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=100.0, output_len=64)) as asm:
        assert asm.pushed_by_feed == [True, True]
        assert set(_reader_threads()) == before  # no reader thread was started for the pushed cameras
        sets = drain(asm, 30, 20.0)
        assert asm.get(2.0) is None and asm.finished  # the feed's end reached the assembler
        st = asm.stats()
    feed = sources[0].feed
    assert len(sets) + feed.stats().skipped == 30, (len(sets), feed.stats())
    assert st.complete == len(sets) and st.dropped == (0, 0) and st.ended == (True, True)
    # assembled in the thread that stamped the frames: no hand-over between the stamp and the output queue
    lag_ms = np.array([(s.t_assembled_s - np.nanmin(s.t_host_s)) * 1e3 for s in sets])
    assert np.median(lag_ms) < 1.0, lag_ms
    # the same images as rendered without the child process, as fast as possible (same seed, same frame id)
    ref = open_sources(["sim"], rig, rate_hz=100.0, seed=5, speed=None, scene_provider=flights, duration_s=0.3)
    with FrameSetAssembler(ref, AssemblyOptions(rate_hz=100.0, output_len=64, lossless=True)) as asm_ref:
        assert asm_ref.pushed_by_feed == [False, False]  # lossless: the readers pace the recording
        by_id = {s.frame_id: s for s in drain(asm_ref, 30, 20.0)}
    assert len(by_id) == 30
    for s in sets:
        assert all(np.array_equal(x, y) for x, y in zip(s.frameset.images, by_id[s.frame_id].frameset.images))


def test_the_renderer_process_runs_below_the_tracker_s_priority(rig):
    from harness.live.sources._render_process import RenderProcess
    from harness.sim.render import RenderOptions

    mine = os.getpriority(os.PRIO_PROCESS, 0)
    proc = RenderProcess(rig, RenderOptions(), 0, LauncherFlights(0, n_serves=1), slots=2, nice=0)
    try:
        assert os.getpriority(os.PRIO_PROCESS, proc.proc.pid) == mine  # nice 0: the tracker's own priority
    finally:
        proc.close()
    # the sim source's renderer at its default, 10 below (one renderer process started for both: each start is seconds)
    assert SimOptions().render_nice == 10
    before = set(_renderer_processes())
    sources = open_sources(["sim"], rig, rate_hz=100.0, scene_provider=LauncherFlights(0, n_serves=1),
                           render_process=True)
    try:
        (pid,) = set(_renderer_processes()) - before
        assert os.getpriority(os.PRIO_PROCESS, pid) == min(mine + 10, 19)
    finally:
        for s in sources:
            s.close()


class RecordingFlights(LauncherFlights):
    """The default scene, noting which sim renderer children of this process run while it is drawn."""

    seen: list = []

    def __init__(self, *a, **kw):
        RecordingFlights.seen.append(_renderer_processes())
        super().__init__(*a, **kw)


class BrokenScene:
    """A picklable scene provider that fails in the child (its first frame set, before "ready")."""

    def __call__(self, t_s: float):
        raise RuntimeError("no scene here")


def test_the_renderer_child_ray_casts_the_lab_while_the_flights_are_drawn(rig, monkeypatch):
    """The sim source starts its renderer process before it draws the default scene's flights (each start takes
    seconds: the two overlap), and the child renders them as before."""
    import harness.live.sources.sim as sim

    monkeypatch.setattr(sim, "LauncherFlights", RecordingFlights)
    RecordingFlights.seen.clear()
    before = set(_renderer_processes())
    sources = open_sources(["sim"], rig, rate_hz=100.0, seed=5, speed=None, duration_s=0.05, render_process=True)
    try:
        (during,) = RecordingFlights.seen
        assert len(set(during) - before) == 1  # the child was already running while the flights were drawn
        with FrameSetAssembler(sources, AssemblyOptions(rate_hz=100.0, output_len=64, lossless=True)) as asm:
            sets = drain(asm, 5, 20.0)
        assert [s.frame_id for s in sets] == list(range(5))
    finally:
        for s in sources:
            s.close()


def test_a_scene_that_fails_in_the_renderer_child_is_one_error_and_no_child_left(rig):
    from harness.live.sources._render_process import RenderProcess
    from harness.sim.render import RenderOptions

    before = set(_renderer_processes())
    proc = RenderProcess(rig, RenderOptions(), 0, slots=2, nice=0)  # started: ray-casts the lab, waits for the scene
    with pytest.raises(ValueError, match="failed to start: RuntimeError: no scene here"):
        proc.start(BrokenScene(), start_timeout_s=60.0)
    assert proc.proc is None and set(_renderer_processes()) == before
    proc = RenderProcess(rig, RenderOptions(), 0, slots=2, nice=0)
    with pytest.raises(ValueError, match="picklable scene_provider"):
        proc.start(lambda t: None)
    assert proc.proc is None and set(_renderer_processes()) == before
    with pytest.raises(ValueError, match="failed to start: RuntimeError: no scene here"):  # given at once: the same
        RenderProcess(rig, RenderOptions(), 0, BrokenScene(), slots=2, nice=0)
    assert set(_renderer_processes()) == before


def _renderer_processes() -> list[int]:
    """This process's children that run the sim renderer (harness.live.sources._render_process), from /proc."""
    from pathlib import Path

    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat, cmdline = (d / "stat").read_text(), (d / "cmdline").read_bytes()
            except OSError:
                continue
            ppid = int(stat[stat.rindex(")") + 2:].split()[1])
            if ppid == os.getpid() and b"harness.live.sources._render_process" in cmdline:
                out.append(int(d.name))
    return out


def test_the_renderer_skips_a_request_it_could_not_deliver_in_time_without_rendering_it(rig):
    from harness.live.sources._render_process import RenderProcess
    from harness.sim.render import RenderOptions

    proc = RenderProcess(rig, RenderOptions(), 0, SlowFlights(0.5), slots=2)
    try:
        t0 = time.monotonic()
        proc.request(3, 0, 0.015, time.monotonic() - 1.0)  # already too late to start
        assert proc.result(5.0) == (3, 0, False)
        assert time.monotonic() - t0 < 0.4  # answered without asking the 0.5 s scene provider
        proc.request(4, 1, 0.02)  # no deadline: rendered, whatever it costs
        assert proc.result(10.0) == (4, 1, True)
        assert proc.views[1][0].any()
    finally:
        proc.close()


@pytest.mark.parametrize("nice", [-1, 20, 1.5, True, "10", None])
def test_bad_renderer_priority(rig, nice):
    with pytest.raises(ValueError, match="render_nice"):
        SimOptions(render_process=True, render_nice=nice)
    from harness.live.sources._render_process import RenderProcess
    from harness.sim.render import RenderOptions

    with pytest.raises(ValueError, match="nice"):
        RenderProcess(rig, RenderOptions(), 0, LauncherFlights(0, n_serves=1), slots=2, nice=nice)


def test_frame_sets_the_renderer_cannot_start_in_time_are_skipped_and_counted_never_a_stale_burst(rig):
    # 25 ms per frame set at 100 Hz: the renderer makes at most 2 in 5; the rest are skipped, counted
    sources = open_sources(["sim"], rig, rate_hz=100.0, seed=2, scene_provider=SlowFlights(0.025), duration_s=1.0,
                           render_process=True)
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=100.0, output_len=200)) as asm:
        sets = drain(asm, 100, 30.0)
        st = asm.stats()
    feed = sources[0].feed.stats()
    assert 0 < len(sets) < 60 and feed.skipped > 40
    assert len(sets) + feed.skipped == 100  # every frame set of the second is either delivered or counted
    assert st.dropped_framesets == 0 and st.late == (0, 0)  # nothing for rt2 to skip: the source dropped them
    # what is delivered is at most a render late, never a burst of stale sets
    t = np.array([np.nanmin(s.t_host_s) for s in sets])
    k = np.array([s.frame_id for s in sets])
    lag = (t - t[0]) - (k - k[0]) * 0.01
    # a period plus a render plus the scheduling slack of a loaded machine; rendering every request in turn,
    # it would grow to ~0.4 s (16 sets in flight, 25 ms each)
    assert lag.max() < 0.15, lag


def test_a_pushing_feed_s_failure_reaches_the_assembler_as_a_failed_camera():
    def produce():
        img = np.zeros((4, 4, 3), np.uint8)
        for k in range(3):
            yield FeedItem((k, k), k * 0.005, (None, None), (img, img))
        raise OSError("the device went away")

    feed = PacedFeed("fake", range(2), ("a", "b"), produce, late_tolerance_s=1.0)
    with FrameSetAssembler(feed.views(), AssemblyOptions(rate_hz=200.0, output_len=8)) as asm:
        assert asm.pushed_by_feed == [True, True]
        sets = drain(asm, 10, 5.0)
        st = asm.stats()
    assert [s.frame_id for s in sets] == [0, 1, 2]
    assert st.ended == (True, True)
    assert st.errors == ("fake: camera a: OSError: the device went away", "fake: camera b: OSError: the device went away")


def test_a_feed_with_a_camera_outside_the_assembler_keeps_its_readers():
    def produce():
        img = np.zeros((4, 4, 3), np.uint8)
        for k in range(4):
            yield FeedItem((k, k), k * 0.005, (None, None), (img, img))

    feed = PacedFeed("fake", range(2), ("a", "b"), produce)
    views = feed.views()
    with FrameSetAssembler(views[:1], AssemblyOptions(rate_hz=200.0, output_len=8)) as asm:
        assert asm.pushed_by_feed == [False]  # camera b is read by nobody here: no push
        sets = drain(asm, 10, 5.0)
    assert [s.frame_id for s in sets] == [0, 1, 2, 3]
    views[1].close()


@pytest.mark.parametrize("args, message", [
    (["--sim-render-nice", "-1"], "--sim-render-nice must be a whole number in [0, 19], got -1"),
    (["--sim-render-nice", "20"], "--sim-render-nice must be a whole number in [0, 19], got 20"),
    (["--sim-render-nice", "5", "--source", "replay", "x.mcap"], "--sim-render-nice applies to the sim source only"),
    # found by the sim source or the log writer once the service opened, under their own field names, before
    (["--seed", "-1"], "--seed must be >= 0, got -1"),
    (["--log-images", "-1"], "--log-images must be 'all', 'none' or a positive integer N (every N-th frame set), got '-1'"),
])
def test_bad_renderer_priority_on_the_command_line_is_one_line(capsys, tmp_path, args, message):
    from tests.harness.live import test_live_cli as cli_tests

    assert message in cli_tests._bad(capsys, tmp_path, "--publish", "none", *args)


def test_the_command_line_priority_reaches_the_renderer(rig, monkeypatch):
    import argparse

    from harness.cli.track import add_arguments, track_config
    from harness.live import run
    from harness.live.sources import sim

    seen = []
    monkeypatch.setattr(sim, "open_sim", lambda rig, options, **kw: seen.append(options.render_nice) or ([], None))
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    for extra, expect in (([], SimOptions().render_nice), (["--sim-render-nice", "0"], 0), (["--sim-render-nice", "7"], 7)):
        with pytest.raises(ValueError, match="opened 0 camera"):  # the stand-in opened no camera: stop there
            run.open_frames(track_config(parser.parse_args(["--publish", "none", *extra])), rig)
    assert seen == [10, 0, 7]

"""Frame-set assembly with real threads: scripted cameras release frames at set times (some lost,
some late, one that stops, one that fails) and the counters must come out exact."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from harness.live.assembly import AssemblyOptions, FrameSetAssembler
from harness.live.frames import Frame, FrameSource, SourceError
from harness.live.sources.clock import ClockOffsetEstimator
from tests.harness.live._live_frames import drain


class _Start:
    """A start time shared by the scripted cameras of one test (set by the first start())."""

    def __init__(self):
        self.t0 = None
        self.lock = threading.Lock()

    def begin(self) -> float:
        with self.lock:
            if self.t0 is None:
                self.t0 = time.monotonic() + 0.05
            return self.t0


# Timing tests use long per-camera queues: on a loaded machine the assembler thread can be starved
# for longer than 8 frames, and drop-oldest (tested on its own below) would then be right to drop.


class ScriptedCamera:
    """A FrameSource releasing ``script`` = [(release_s, frame_id, t_device_s | None)] in order.

    After the script: ``ends=True`` -> exhausted; False -> silent forever (a stalled camera);
    ``fail_after`` -> read raises SourceError after that many frames.
    """

    def __init__(self, camera, script, start: _Start, *, ends=True, fail_after=None, shape=(6, 8, 3), handover_s=None):
        self.handover_s = dict(handover_s or {})  # script index -> extra seconds before the reader gets it (starved)
        self.camera, self.name = camera, f"scripted{camera}"
        self.script, self.start_clock, self.ends, self.fail_after = list(script), start, ends, fail_after
        self.shape = shape
        self.i = 0
        self.t0 = None
        self.closed = False

    def start(self):
        self.t0 = self.start_clock.begin()

    def read(self, timeout_s):
        if self.fail_after is not None and self.i >= self.fail_after:
            raise SourceError(f"{self.name}: cable pulled")
        if self.i >= len(self.script):
            if not self.ends:
                time.sleep(timeout_s)
            return None
        release_s, frame_id, t_dev = self.script[self.i]
        wait = self.t0 + release_s - time.monotonic()
        if wait > timeout_s:
            time.sleep(timeout_s)
            return None
        if wait > 0:
            time.sleep(wait)
        time.sleep(self.handover_s.get(self.i, 0.0))
        self.i += 1
        img = np.full(self.shape, frame_id % 256, np.uint8)
        # stamped at its scheduled arrival, as a driver stamps a frame when it arrives: a reader thread starved by
        # a loaded machine (seen: 40-100 ms) hands the frame over late but does not move its stamp
        return Frame(self.camera, frame_id, t_dev, self.t0 + release_s, img)

    @property
    def exhausted(self):
        return self.ends and self.i >= len(self.script)

    def close(self):
        self.closed = True


def test_scripted_camera_is_a_frame_source():
    assert isinstance(ScriptedCamera(0, [], _Start()), FrameSource)


def test_lost_and_late_frames_counted_exactly():
    period = 0.02
    start = _Start()
    ids = range(40)
    cam0 = [(k * period, k, None) for k in ids]
    cam1 = [(k * period, k, None) for k in ids if k not in (5, 30)]  # frames 5 and 30 lost
    # cam2: silent from frame 10 on; frames 10-12 arrive at 0.40 s, long after their sets timed out
    # (at ~0.26 s); 13-18 are lost; from 19 on on time.
    cam2 = [(k * period, k, None) for k in range(10)] + [(0.40, k, None) for k in (10, 11, 12)] \
        + [(k * period, k, None) for k in range(19, 40)]
    sources = [ScriptedCamera(0, cam0, start), ScriptedCamera(1, cam1, start), ScriptedCamera(2, cam2, start)]
    opts = AssemblyOptions(rate_hz=1 / period, max_wait_s=0.06, stall_s=1.0, output_len=64, queue_len=64)
    with FrameSetAssembler(sources, opts) as asm:
        sets = drain(asm, 100)
        st = asm.stats()
    assert [s.frame_id for s in sets] == list(ids)
    assert st.framesets == 40 and st.delivered == 40 and st.dropped_framesets == 0
    assert st.incomplete == 2 + 9 and st.complete == 40 - 11
    assert st.missing == (0, 2, 9)
    assert st.late == (0, 0, 3)
    assert st.frames == (40, 38, 34)
    assert st.dropped == (0, 0, 0)
    by_id = {s.frame_id: s for s in sets}
    assert by_id[5].frameset.images[1] is None and "camera 1" in by_id[5].notes[0] and "lost" in by_id[5].notes[0]
    assert by_id[10].frameset.images[2] is None and "no frame in time" in by_id[10].notes[0]
    assert np.isnan(by_id[10].t_host_s[2]) and np.isfinite(by_id[10].t_host_s[:2]).all()
    assert all(by_id[k].notes == () for k in (0, 9, 19, 39))
    assert by_id[7].frameset.images[0][0, 0, 0] == 7  # images are the frames of that id
    t = [s.frameset.t_s for s in sets]
    assert np.all(np.diff(t) > 0)  # capture order, strictly increasing (clamped where jitter says otherwise)
    assert st.clamped_times <= 5
    assert all(src.closed for src in sources)


def test_camera_that_stops_becomes_none_with_a_note_and_assembly_goes_on():
    period = 0.02
    start = _Start()
    full = [(k * period, k, None) for k in range(30)]
    sources = [ScriptedCamera(0, full, start), ScriptedCamera(1, full, start),
               ScriptedCamera(2, full[:10], start, ends=False)]  # stops after frame 9, never says so
    opts = AssemblyOptions(rate_hz=1 / period, max_wait_s=0.08, stall_s=0.2, output_len=32, queue_len=64)
    with FrameSetAssembler(sources, opts) as asm:
        sets = drain(asm, 30)
        st = asm.stats()
    assert [s.frame_id for s in sets] == list(range(30)), st
    assert all(s.frameset.images[2] is None for s in sets[10:])
    assert all(s.frameset.images[2] is not None for s in sets[:10])
    assert st.missing == (0, 0, 20) and st.incomplete == 20
    notes = [s.notes[0] for s in sets[10:]]
    assert all(n.startswith("camera 2 (scripted2): ") for n in notes)
    assert any("stalled" in n for n in notes)  # once silent for stall_s it is no longer waited for


def test_failed_camera_is_reported_and_the_rest_goes_on():
    period = 0.02
    start = _Start()
    full = [(k * period, k, None) for k in range(20)]
    sources = [ScriptedCamera(0, full, start), ScriptedCamera(1, full, start, fail_after=5)]
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=1 / period, max_wait_s=0.08, queue_len=64)) as asm:
        sets = drain(asm, 20)
        st = asm.stats()
        assert asm.finished
    assert len(sets) == 20 and st.missing == (0, 15)
    assert st.ended == (True, True) and "cable pulled" in st.errors[1] and st.errors[0] is None
    assert "failed" in sets[-1].notes[0] and "cable pulled" in sets[-1].notes[0]


def test_slow_consumer_drops_oldest_sets_and_counts_them():
    period = 0.005
    start = _Start()
    script = [(k * period, k, None) for k in range(50)]
    sources = [ScriptedCamera(0, script, start), ScriptedCamera(1, script, start)]
    opts = AssemblyOptions(rate_hz=1 / period, output_len=4, queue_len=64)
    with FrameSetAssembler(sources, opts) as asm:
        deadline = time.monotonic() + 60.0  # only ends a hang: the 50 sets take 0.25 s, more on a loaded machine
        while not (asm.stats().ended == (True, True) and asm.stats().framesets == 50) and time.monotonic() < deadline:
            time.sleep(0.05)  # the consumer is busy elsewhere
        sets = drain(asm, 10)
        st = asm.stats()
    assert [s.frame_id for s in sets] == [46, 47, 48, 49]  # the newest survive
    assert st.framesets == 50 and st.dropped_framesets == 46 and st.delivered == 4


def test_lossless_assembly_makes_a_fast_recording_wait_for_a_slow_consumer():
    start = _Start()
    burst = [(0.0, k, None) for k in range(50)]  # a recording replayed as fast as possible
    sources = [ScriptedCamera(0, burst, start), ScriptedCamera(1, burst[:20] + burst[21:], start)]
    opts = AssemblyOptions(rate_hz=200.0, queue_len=2, output_len=2, lossless=True)
    with FrameSetAssembler(sources, opts) as asm:
        sets = []
        while not asm.finished:
            s = asm.get(0.5)
            if s is not None:
                sets.append(s)
                time.sleep(0.005)  # a slow consumer
        st = asm.stats()
    assert [s.frame_id for s in sets] == list(range(50))
    assert st.dropped == (0, 0) and st.dropped_framesets == 0 and st.missing == (0, 1)
    assert "lost" in sets[20].notes[0]


def test_per_camera_queue_drops_oldest_when_the_assembler_lags():
    # queue_len=1 and a camera bursting 20 frames at once: the assembler sees only the newest. The output
    # holds every set (output_len 20): a test thread slow to drain on a loaded machine must not make the
    # output's own drop-oldest (another test's subject) skip one of them.
    start = _Start()
    burst = [(0.0, k, None) for k in range(20)]
    sources = [ScriptedCamera(0, burst, start)]
    opts = AssemblyOptions(rate_hz=100.0, queue_len=1, output_len=20)
    with FrameSetAssembler(sources, opts) as asm:
        sets = drain(asm, 20)
        st = asm.stats()
    assert st.frames[0] + st.dropped[0] == 20 and st.framesets == len(sets) == st.frames[0]
    assert sets[-1].frame_id == 19


@pytest.mark.parametrize("starved", [{}, {4: 0.08, 5: 0.08, 6: 0.08}], ids=["on_time", "reader_starved_80ms"])
def test_match_by_time_with_unrelated_frame_ids_and_device_stamps(starved):
    period = 0.05
    start = _Start()
    # Two free-running cameras: different frame counters, device clocks with different offsets;
    # camera 1 is triggered 3 ms after camera 0 (within half a period). "reader_starved": camera 1's frames 4-6
    # reach its reader 80 ms late (more than half a period), stamped on arrival: they still join their sets.
    cam0 = [(k * period, 1000 + k, 5.0 + k * period) for k in range(25)]
    cam1 = [(k * period + 0.003, k, 80.0 + k * period + 0.003) for k in range(25) if k != 12]
    sources = [ScriptedCamera(0, cam0, start), ScriptedCamera(1, cam1, start, handover_s=starved)]
    # a set waits for a camera until that camera's next frame shows the frame lost (set 12), or 2 s: a reader thread
    # starved on a loaded machine must not make a set incomplete here (time-outs are the lost/late test's subject)
    opts = AssemblyOptions(rate_hz=1 / period, match="time", max_wait_s=2.0, stall_s=1.0, queue_len=64)
    with FrameSetAssembler(sources, opts) as asm:
        sets = drain(asm, 25, timeout_s=60.0)  # returns when the 25 sets are out (1.3 s unloaded)
        st = asm.stats()
        offsets = asm.clock_offsets()
    assert len(sets) == 25 and st.incomplete == 1 and st.missing == (0, 1)
    assert [s.frame_id for s in sets] == list(range(25))
    pairs = [(s.t_device_s[0] - 5.0, s.t_device_s[1] - 80.0) for s in sets if s.frameset.images[1] is not None]
    assert all(abs(a - b) < 0.004 for a, b in pairs)  # each set holds the frames of one trigger
    assert sets[12].frameset.images[1] is None
    # host - device = (t0 - 5) and (t0 - 80): offsets differ by 75 s; the arrival stamps have no jitter here
    assert abs((offsets[0].offset_s - offsets[1].offset_s) - 75.0) < 1e-6
    assert 0 <= offsets[0].spread_s < 1e-6


def test_clock_offset_estimator_is_robust_and_resets():
    rng = np.random.default_rng(0)
    est = ClockOffsetEstimator(window=200)
    t_dev = np.arange(300) * 0.005
    latency = 0.0008 + rng.exponential(0.0005, 300)
    latency[50] = 0.2  # one frame stuck in a buffer
    for td, lat in zip(t_dev, latency):
        est.add(1234.5 + td + lat, td)
    e = est.estimate()
    assert abs(e.offset_s - (1234.5 + 0.0008)) < 0.0002 and e.n_samples == 200
    assert 0 < e.spread_s < 0.003
    assert abs(est.to_host(1.0) - (1.0 + e.offset_s)) < 1e-12
    est.add(2000.001, 0.0)  # device clock restarted
    assert est.estimate() is None and est.to_host(1.0) is None
    for k in range(10):
        est.add(2000.0 + k * 0.005 + 0.001, k * 0.005)
    assert est.estimate().resets == 1 and abs(est.estimate().offset_s - 2000.001) < 1e-9


@pytest.mark.parametrize("kwargs, match", [
    ({"rate_hz": 0.0}, "rate_hz"), ({"match": "id"}, "match"), ({"max_wait_s": -1.0}, "max_wait_s"),
    ({"output_len": 0}, "output_len"),
])
def test_bad_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AssemblyOptions(**kwargs)


def test_bad_use():
    with pytest.raises(ValueError, match="at least one source"):
        FrameSetAssembler([])
    asm = FrameSetAssembler([ScriptedCamera(0, [], _Start())])
    with pytest.raises(RuntimeError, match="before start"):
        asm.get(0.0)
    with pytest.raises(ValueError, match="window"):
        ClockOffsetEstimator(window=1)


@pytest.mark.parametrize("backlog", [1, 2])
def test_slow_consumer_never_sees_a_set_older_than_the_backlog_and_skips_add_up(backlog):
    # Cameras at 200 Hz, a consumer that takes ~3 periods per set: the newest sets win, every set it gets
    # is at most `backlog` sets behind the newest assembled one, and framesets = delivered + skipped + waiting.
    period = 0.005
    start = _Start()
    script = [(k * period, k, None) for k in range(120)]
    sources = [ScriptedCamera(0, script, start), ScriptedCamera(1, script, start)]
    opts = AssemblyOptions(rate_hz=1 / period, output_len=backlog, queue_len=64)
    got = []
    with FrameSetAssembler(sources, opts) as asm:
        while not asm.finished:
            before = asm.stats()  # framesets can only grow between this and the get
            s = asm.get(0.5)
            if s is None:
                continue
            assert s.frameset.index >= before.framesets - backlog, (s.frameset.index, before.framesets)
            got.append(s.frame_id)
            st = asm.stats()
            assert st.framesets == st.delivered + st.dropped_framesets + st.waiting
            assert st.waiting <= backlog and st.backlog == backlog
            time.sleep(3 * period)
        st = asm.stats()
    assert got == sorted(got) and got[-1] == 119  # capture order kept, the newest delivered
    assert st.framesets == 120 and st.waiting == 0
    assert st.delivered == len(got) and st.dropped_framesets == 120 - len(got) > 0

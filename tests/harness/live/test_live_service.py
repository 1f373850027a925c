"""The tracking service on rendered frame sets of the simulated lab: one message per frame set on both
streams, a camera that stops mid-run, the session log and its re-evaluation, and figures."""

from __future__ import annotations

import dataclasses
import json
import threading

import numpy as np
import pytest
import zmq

from harness.cli import main as rt2
from harness.live.publish import Publisher
from harness.live.service import ServiceOptions, TrackingService
from harness.live.session_log import LiveLog
from harness.logs import SessionLogReader
from tests.harness.live._live_frames import assembled, lab_rig, rendered_images
from tracker import Status, Tracker


@pytest.fixture(scope="module")
def rig():
    rendered_images()  # render once for the module (a few seconds)
    return lab_rig()


def _collect(addr: str, out: list, ready: threading.Event, stop: threading.Event):
    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.SUB)
    s.connect(addr)
    s.setsockopt(zmq.SUBSCRIBE, b"")
    ready.set()
    while not stop.is_set() or s.poll(200):
        if s.poll(50):
            out.append(json.loads(s.recv()))
    s.close(linger=0)


def _wait_joined(pub: Publisher, got: list, timeout_s: float = 10.0):
    """PUB/SUB joins asynchronously: send probes until the subscriber saw one, then forget them."""
    import time

    t_end = time.monotonic() + timeout_s
    while not got and time.monotonic() < t_end:
        pub.publish({"num": -1, "time": 0, "proc_time": 0.0, "obs": None},
                    {"num": -1, "t_first_host_s": 0.0, "t_publish_s": 0.0})
        time.sleep(0.02)
    time.sleep(0.1)
    got.clear()


def test_every_frame_set_is_published_and_a_stopped_camera_is_reported(rig):
    tennicam, rich = [], []
    stop = threading.Event()
    with Publisher("tcp://127.0.0.1:0", "tcp://127.0.0.1:0") as pub, Tracker(rig, "rt2") as tr:
        threads = []
        for addr, out in ((pub.addresses["tennicam"], tennicam), (pub.addresses["rt2"], rich)):
            ready = threading.Event()
            th = threading.Thread(target=_collect, args=(addr, out, ready, stop))
            th.start()
            ready.wait()
            threads.append(th)
            _wait_joined(pub, out)
        probes = dict(pub.sent)
        service = TrackingService(rig, tr, publisher=pub, options=ServiceOptions(status_period_s=0))
        summary = service.run(assembled(240, drop_camera=2, drop_from=120))
        summary["published"] = {k: v - probes[k] for k, v in summary["published"].items()}
        stop.set()
        for th in threads:
            th.join()
    tennicam = [m for m in tennicam if m["num"] >= 0]  # the join probes out
    rich = [m for m in rich if m["num"] >= 0]
    assert summary["frame_sets"] == 240 and summary["published"] == {"tennicam": 240, "rt2": 240}
    assert [m["num"] for m in tennicam] == list(range(240))  # nothing lost between rt2 and a reader
    assert [m["num"] for m in rich] == list(range(240))
    assert summary["missing_frames"] == {"cam0": 0, "cam1": 0, "cam2": 120, "cam3": 0}
    # tracking goes on from the other three cameras, and each message says camera 2 is missing
    after = rich[120:]
    assert all(m["status"] == "ok" and m["support"] == 3 and not m["inliers"][2] for m in after)
    assert all(any("camera 2: no frame in time" in n for n in m["notes"]) for m in after)
    assert all(m["obs"] is not None for m in tennicam[120:])
    # the tennicam position is rt2's position; time is the capture time in ns on CLOCK_MONOTONIC
    for t, r in zip(tennicam, rich):
        assert t["obs"] == r["position_m"]
        assert t["time"] == round(r["t_s"] * 1e9)
        assert r["t_first_host_s"] <= r["t_publish_s"] and r["latency_s"] == pytest.approx(r["t_publish_s"] - r["t_first_host_s"])
        assert t["proc_time"] == r["latency_s"]  # one publication stamp: both streams give the same latency
        assert (r["t_host_s"][2] is None) == (r["num"] >= 120)  # NaN stamps travel as null
    assert summary["latency_ms"]["p50"] > 0 and summary["status"] == {"ok": 240}


def test_session_log_is_the_experiments_format_and_reevaluates_exactly(rig, tmp_path, capsys):
    path = tmp_path / "track.mcap"
    with Tracker(rig, "rt2") as tr:
        log = LiveLog(path, rig, tr, source="test", seed=0, log_images="all", image_format="png",
                      max_pending_images=1000)  # offline: PNG is slow, keep every image
        service = TrackingService(rig, tr, log=log, options=ServiceOptions(status_period_s=0))
        # 40 frame sets (a third fewer PNG images to write and track again than before, the same code): cam1 stops at 20,
        # before the rendered clip restarts (set 24), so a new ball is searched for without it
        summary = service.run(assembled(40, drop_camera=1, drop_from=20, pace=True, due_stamps=True))  # 200 Hz times, whatever the load
    # the tracker's counters over the run (rt2 track's JSON): every frame set, the 20 without cam1's frame
    st = summary["tracker_stats"]
    assert st["frames"] == 40 and st["missing_frames"] == 20 and st["ok"] == summary["status"].get("ok", 0)
    assert st["full_frame_searches"] >= 1 and st["roi_searches"] > 0
    with SessionLogReader(path) as r:
        assert r.finished_cleanly
        assert r.metadata("session")["kind"] == "track"
        s = r.summary()
        counts = {t: st.count for t, st in s.topics.items()}
        assert counts["/tracker/rt2/ball"] == 40
        assert counts["/camera/cam0/image"] == 40 and counts["/camera/cam1/image"] == 20
        assert counts["/camera/cam0/detections"] == 40 and counts["/scene/static"] == 1
        assert r.figures()["track"]["frame_sets"] == 40
    assert summary["log"]["dropped"] == {}
    for source in ("detections", "images"):
        assert rt2(["reevaluate", str(path), "--from", source, "--json", str(tmp_path / f"{source}.json")]) == 0
        out = capsys.readouterr().out
        assert "identical observations (status and position): 40 of 40" in out, out
        assert json.loads((tmp_path / f"{source}.json").read_text())["identical"] == 40
    # the same log replayed as live cameras through rt2 track: the run ends by itself with the recording
    stats = tmp_path / "replay.json"
    assert rt2(["track", "--source", "replay", str(path), "--publish", "127.0.0.1:0", "--status-period", "0",
                "--json", str(stats)]) == 0
    s = json.loads(stats.read_text())
    assert s["frame_sets"] + s["assembly"]["dropped_framesets"] == 40 and "stopped_by" not in s
    # every frame set without cam1 was assembled as such; the tracker saw those it did not skip (latency first)
    assert s["assembly"]["missing"][1] >= 20 and s["assembly"]["missing"][0] == 0
    assert s["missing_frames"]["cam1"] >= 20 - s["skipped_framesets"] and s["missing_frames"]["cam0"] == 0


def test_service_stops_on_request_and_closes_its_log(rig, tmp_path):
    path = tmp_path / "stop.mcap"
    stop = threading.Event()

    def frames():
        for k, afs in enumerate(assembled(10_000)):
            if k == 30:
                stop.set()
            yield afs

    with Tracker(rig, "rt2") as tr:
        log = LiveLog(path, rig, tr, source="test", log_images="none")
        summary = TrackingService(rig, tr, log=log, options=ServiceOptions(status_period_s=0)).run(frames(), stop=stop)
    assert summary["frame_sets"] == 30
    with SessionLogReader(path) as r:
        assert r.finished_cleanly and r.figures()["track"]["frame_sets"] == 30


def test_service_rejects_other_inputs(rig):
    with Tracker(rig, "rt2") as tr:
        service = TrackingService(rig, tr)
        with pytest.raises(ValueError, match="AssembledFrameSet"):
            service.step("not a frame set")
        with pytest.raises(ValueError, match="duration_s"):
            service.run([], duration_s=-1)
    with pytest.raises(ValueError, match="status_period_s"):
        ServiceOptions(status_period_s=-1)


def test_status_line_and_summary(rig):
    lines = []
    with Tracker(rig, "rt2") as tr:
        service = TrackingService(rig, tr, options=ServiceOptions(status_period_s=0.05), status=lines.append)
        summary = service.run(assembled(40, pace=True, rate_hz=200))
    assert lines and "frame sets" in lines[0] and "latency p50" in lines[0] and "cam3:0" in lines[0]
    assert summary["frame_sets"] == 40 and 10 < summary["rate_hz"] < 300  # paced at 200 Hz; a loaded machine is slower
    assert set(summary["latency_ms"]) >= {"p50", "p99", "max"}
    use = summary["process_per_set"]  # what a frame set cost the process: CPU, page faults, switches
    assert set(use) == {"cpu_ms", "page_faults", "context_switches"}
    assert 0 < use["cpu_ms"] < 1000 and use["page_faults"] >= 0 and use["context_switches"] >= 0


def test_process_per_set_divides_the_readings():
    from types import SimpleNamespace as U

    from harness.live.stats import process_per_set

    a = U(ru_utime=1.0, ru_stime=0.5, ru_minflt=100, ru_nvcsw=10, ru_nivcsw=2)
    b = U(ru_utime=1.2, ru_stime=0.6, ru_minflt=140, ru_nvcsw=30, ru_nivcsw=2)
    got = process_per_set(a, b, 10)
    assert got == pytest.approx({"cpu_ms": 30.0, "page_faults": 4.0, "context_switches": 2.0})
    assert process_per_set(a, b, 0)["cpu_ms"] == pytest.approx(300.0)  # no set: per one, never a division by zero


def test_latency_budget_stages_add_up_to_the_latency_and_the_collector_is_frozen_only_while_running(rig):
    import gc

    from harness.live.stats import STAGES

    frozen = []

    class Counting:
        def __iter__(self):  # a camera's times at 200 Hz: what the tracker does with them does not depend on the load
            for afs in assembled(30, pace=True, due_stamps=True):
                frozen.append(gc.get_freeze_count())
                yield afs

    with Tracker(rig, "rt2") as tr:
        service = TrackingService(rig, tr)
        summary = service.run(Counting())
        stages = service.stats.stages_s()
        lat = service.stats.latencies_s()
    assert min(frozen) > 0 and gc.get_freeze_count() == 0
    assert stages.shape == (30, len(STAGES)) and np.isfinite(stages).all() and (stages >= 0).all()
    # assembly + backlog + tracker + publish = first frame's arrival -> messages sent, per frame set
    np.testing.assert_allclose(stages[:, :4].sum(axis=1), lat, atol=1e-9)
    budget = summary["latency_budget_ms"]
    assert budget["total"]["n"] == 30 and budget["tracker"]["max"] <= budget["total"]["max"] + 1e-9
    # the first frame set searched every full frame (no prediction yet), the later ones windows: the former's own rows
    assert tr.stats.full_frame_searches > 0 and tr.stats.roi_searches > 0
    assert 1 <= budget["tracker_full"]["n"] == budget["total_full"]["n"] < 30
    assert budget["tracker_full"]["max"] <= budget["tracker"]["max"] and budget["total_full"]["max"] <= budget["total"]["max"]


def test_the_budget_splits_out_the_full_frame_sets_only_where_both_kinds_ran():
    from types import SimpleNamespace

    from harness.live.stats import LiveStats, format_budget

    def run(flags):
        st = LiveStats(["a"])
        afs = SimpleNamespace(frameset=SimpleNamespace(images=[np.zeros(1)]), notes=(), frame_id=0)
        for k, full in enumerate(flags):
            afs.frame_id = k
            obs = SimpleNamespace(latency_s=0.001 * (1 + 4 * full), status="ok", position_m=None, notes=())
            st.add(afs, obs, 0.002 * (1 + 4 * full), float(k), (0.0005, 0.0, 0.001 * (1 + 4 * full), 0.0005, 0.0), full_frame=full)
        return st.budget_ms()

    mixed = run([True] + [False] * 9 + [True])
    assert mixed["tracker_full"] == {"n": 2, "p50": pytest.approx(5.0), "p99": pytest.approx(5.0), "max": pytest.approx(5.0)}
    assert mixed["total_full"]["max"] == pytest.approx(10.0) and mixed["total"]["p50"] == pytest.approx(2.0)
    assert any("sets with a full-frame search" in line for line in format_budget(mixed))
    assert "tracker_full" not in run([False] * 5) and "tracker_full" not in run([True] * 5)  # one kind: nothing to split


def test_the_summary_keeps_the_slowest_frame_sets_with_their_stages_and_notes(capsys):
    from types import SimpleNamespace

    from harness.cli.track import _print_summary
    from harness.live.stats import SLOWEST_KEPT, LiveStats

    st = LiveStats(["a"], keep=8)  # a short ring: the oldest slow set's stages are gone by the end
    lat = [0.002] * 20
    lat[1], lat[12], lat[15] = 0.050, 0.009, 0.030  # the three slowest, and many alike below them
    for k, x in enumerate(lat):
        afs = SimpleNamespace(frameset=SimpleNamespace(images=[np.zeros(1)]), notes=(f"assembly note {k}",) if k == 15 else (), frame_id=100 + k)
        obs = SimpleNamespace(latency_s=x / 2, status="ok" if k != 12 else "too_few_observations", position_m=None,
                              notes=("not searched: the full-frame search after ... still runs",) if k == 12 else ())
        st.add(afs, obs, x, float(k), (0.0001, 0.0, x / 2, 0.0002, 0.0))
    slow = st.slowest()
    assert len(slow) == SLOWEST_KEPT and [r["frame_id"] for r in slow[:3]] == [101, 115, 112]
    assert [r["latency_ms"] for r in slow[:3]] == pytest.approx([50.0, 30.0, 9.0])
    assert "stages_ms" not in slow[0]  # frame 101 left the 8-set ring
    assert slow[1]["stages_ms"]["tracker"] == pytest.approx(15.0) and slow[1]["notes"] == ["assembly note 15"]
    assert slow[2]["status"] == "too_few_observations" and slow[2]["notes"][0].startswith("not searched")
    summary = st.summary()
    assert summary["slowest_frame_sets"] == slow
    _print_summary({**summary, "tracker": "rt2"})
    line = [x for x in capsys.readouterr().out.splitlines() if "slowest frame set" in x]
    assert line == ["  slowest frame set: frame id 101, 50.00 ms (stages not kept), ok (JSON slowest_frame_sets: the 5 slowest)"]
    assert LiveStats(["a"]).summary()["slowest_frame_sets"] == []


def test_a_failing_log_never_stops_tracking_or_publishing(rig, tmp_path):
    """The log's file fails mid-run (as a full disk would): the service says so once and goes on."""
    lines = []
    with Tracker(rig, "rt2") as tr, Publisher("tcp://127.0.0.1:0", None) as pub:
        log = LiveLog(tmp_path / "fails.mcap", rig, tr, source="test", log_images="none")
        service = TrackingService(rig, tr, publisher=pub, log=log, options=ServiceOptions(status_period_s=0),
                                  status=lines.append)

        def frames():
            for k, afs in enumerate(assembled(80, pace=True, rate_hz=50)):  # 1.6 s: the writer flushes on its timer
                if k == 20:
                    log.bg.writer._file.close()  # the disk goes away under the writer
                yield afs

        summary = service.run(frames())
    assert summary["frame_sets"] == 80 and summary["published"]["tennicam"] == 80
    assert summary["log"]["error"] and "log writer failed" in summary["log"]["error"]
    assert sum("the session log failed" in ln for ln in lines) == 1


def test_a_log_that_fails_only_when_closed_is_reported_not_raised(rig, tmp_path):
    with Tracker(rig, "rt2") as tr:
        log = LiveLog(tmp_path / "fails_late.mcap", rig, tr, source="test", log_images="none")
        service = TrackingService(rig, tr, log=log, options=ServiceOptions(status_period_s=0))

        def frames():
            for k, afs in enumerate(assembled(30)):
                if k == 29:
                    log.bg.writer._file.close()
                yield afs

        summary = service.run(frames())
    assert summary["frame_sets"] == 30 and summary["log"]["error"]


def _two_cameras_lose_the_ball(n_sets: int, lost: range):
    """The rendered flight through the service's input, cameras 2 and 3 showing another frame's image during
    ``lost``: their windows hold no ball while cameras 0 and 1 agree (a two-camera position in time)."""
    images = rendered_images()
    for afs in assembled(n_sets):
        k = afs.frame_id
        if k in lost:
            imgs = list(afs.frameset.images)
            imgs[2] = imgs[3] = images[(k + len(images) // 2) % len(images)][2]
            afs = dataclasses.replace(afs, frameset=dataclasses.replace(afs.frameset, images=tuple(imgs)))
        yield afs


def test_a_log_of_deferred_full_frame_searches_reevaluates_exactly(rig, tmp_path, capsys):
    # live, the full frames of a frame set without a confirmed ball are searched after it is reported
    # (defer_full_frame): that frame set has no position although its windows' candidates (logged) held one, and
    # the frame sets that come during the search are not searched. Both re-runs reproduce every frame set.
    path = tmp_path / "deferred.mcap"
    with Tracker(rig, "rt2", defer_full_frame=True) as tr:
        log = LiveLog(path, rig, tr, source="test", seed=0, log_images="all", image_format="png", max_pending_images=1000)
        TrackingService(rig, tr, log=log, options=ServiceOptions(status_period_s=0)).run(
            _two_cameras_lose_the_ball(40, range(14, 17)))
    with SessionLogReader(path) as r:
        obs = [m.data for m in r.messages(["/tracker/rt2/ball"])]
        assert r.metadata("session")["defer_full_frame"] is True
    deferred = [o for o in obs if o.full_frames_deferred]
    assert any("window search gave low_support" in n for o in deferred for n in o.notes), [o.notes for o in obs]
    assert all(o.position_m is None and o.status is Status.NO_CONSENSUS for o in deferred if "window search gave low_support" in o.notes[-1])
    for source in ("detections", "images"):
        assert rt2(["reevaluate", str(path), "--from", source, "--json", str(tmp_path / f"{source}.json")]) == 0
        out = capsys.readouterr().out
        assert "identical observations (status and position): 40 of 40" in out, out
        doc = json.loads((tmp_path / f"{source}.json").read_text())
        assert doc["deferred_live"] == len(deferred) and doc["not_searched_live"] == sum(o.not_searched for o in obs)
        assert f"{len(deferred)} frame set(s) had their full frames searched after they were reported" in out


def test_a_log_whose_writer_dropped_images_reevaluates_on_the_detections_and_says_why(rig, tmp_path, capsys, monkeypatch):
    # an encoder that cannot keep up (stalled until the run ends): images dropped and counted in session_end; the
    # auto re-run takes the detections (every frame set has them) and reproduces every observation, and --from images
    # says that its frame sets lost images
    from harness.logs import SessionLogWriter

    gate = threading.Event()
    real = SessionLogWriter.write_image
    monkeypatch.setattr(SessionLogWriter, "write_image", lambda self, *a, **k: (gate.wait(10), real(self, *a, **k))[1])
    path = tmp_path / "dropped.mcap"
    with Tracker(rig, "rt2") as tr:
        log = LiveLog(path, rig, tr, source="test", seed=0, log_images="all", image_format="png", max_pending_images=2)
        service = TrackingService(rig, tr, log=log, options=ServiceOptions(status_period_s=0))
        with pytest.warns(RuntimeWarning, match="dropping image"):
            threading.Timer(2.0, gate.set).start()
            summary = service.run(assembled(30))
    dropped = summary["log"]["dropped"]["image"]
    assert dropped > 0
    assert rt2(["reevaluate", str(path), "--json", str(tmp_path / "auto.json")]) == 0
    out = capsys.readouterr().out
    assert f"note: the writer dropped {dropped} images" in out and "re-running the estimator on the logged detections" in out
    assert "identical observations (status and position): 30 of 30" in out
    assert json.loads((tmp_path / "auto.json").read_text())["source"] == "detections"
    assert rt2(["reevaluate", str(path), "--from", "images"]) == 0
    out = capsys.readouterr().out
    assert f"note: the writer dropped {dropped} images" in out and "re-run without them" in out

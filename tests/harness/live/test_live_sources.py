"""Camera sources: spec parsing, sim (rendered lab), replay of a real session log, video files and
image folders, opencv (through cv2.VideoCapture), and the messages of missing drivers."""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np
import pytest

from harness.sim.lab import preview_rig
from harness.live.assembly import AssemblyOptions, FrameSetAssembler
from harness.live.frames import FrameSource
from harness.live.sources import (SourceSpec, SourceUnavailable, open_sources, parse_source_spec,
                                  require_driver)
from harness.sim.render import Ball, Scene
from tests.harness.live._live_frames import drain


@pytest.fixture(scope="module")
def rig():
    return preview_rig(80, 60)


def _ball_scene(t_s: float) -> Scene:
    return Scene(balls=(Ball([-1.2 + 0.5 * t_s, 0.0, 1.2], velocity_mps=[0.5, 0.0, 0.0]),))


def _collect(sources, n, rate_hz, **opts):
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=rate_hz, output_len=1000, **opts)) as asm:
        return drain(asm, n, 20.0), asm.stats()


# -- spec ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("tokens, spec", [
    (["sim"], SourceSpec("sim")),
    (["replay", "run.mcap"], SourceSpec("replay", "run.mcap")),
    ("video /data/clip", SourceSpec("video", "/data/clip")),
    (["opencv", "0,1,2,3"], SourceSpec("opencv", None, (0, 1, 2, 3))),
    (["opencv", "/dev/video0,rtsp://10.0.0.2/s"], SourceSpec("opencv", None, ("/dev/video0", "rtsp://10.0.0.2/s"))),
    (["pylon"], SourceSpec("pylon")),
    (["pylon", "02301,2302"], SourceSpec("pylon", None, ("02301", "2302"))),  # serials stay text
    (["genicam"], SourceSpec("genicam")),
    (["genicam", "p.cti", "a,b"], SourceSpec("genicam", "p.cti", ("a", "b"))),
    (["genicam", "a", "b"], SourceSpec("genicam", None, ("a", "b"))),
    (["opencv", "0", "1"], SourceSpec("opencv", None, (0, 1))),
    (["pylon", "40012", "40013,40014"], SourceSpec("pylon", None, ("40012", "40013", "40014"))),
])
def test_parse_source_spec(tokens, spec):
    assert parse_source_spec(tokens) == spec


@pytest.mark.parametrize("tokens, match", [
    ([], "empty"), (["webcam"], "unknown camera source 'webcam'"), (["replay"], "replay LOG"),
    (["sim", "x"], "'sim x'"), (["opencv", "0,,1"], "comma-separated"), (["opencv"], "opencv IDS"),
    (["video", "a", "b"], "'video a b'"),
])
def test_parse_source_spec_bad(tokens, match):
    with pytest.raises(ValueError, match=match):
        parse_source_spec(tokens)


def test_camera_count_must_match_the_rig(rig):
    with pytest.raises(ValueError, match="lists 3 camera.*rig has 2"):
        open_sources(["opencv", "0,1,2"], rig)
    with pytest.raises(ValueError, match="rate_hz"):
        open_sources(["sim"], rig, rate_hz=0)


# -- sim -------------------------------------------------------------------------------------------
def test_sim_frames_ids_stamps_and_same_seed_same_images(rig):
    runs = []
    for _ in range(2):
        sources = open_sources(["sim"], rig, rate_hz=100.0, seed=3, speed=None, scene_provider=_ball_scene,
                               duration_s=0.1)
        assert all(isinstance(s, FrameSource) for s in sources) and [s.camera for s in sources] == [0, 1]
        sets, st = _collect(sources, 20, 100.0, lossless=True)  # as fast as possible: wait for every frame
        assert [s.frame_id for s in sets] == list(range(10)) and st.complete == 10 and st.late == (0, 0), st
        assert np.allclose(sets[4].t_device_s, 0.04)
        assert st.sources[0].emitted == 10 and st.sources[1] == st.sources[0]  # the shared feed's counters
        assert sets[0].frameset.images[0].shape == (60, 80, 3) and sets[0].frameset.images[0].dtype == np.uint8
        runs.append(sets)
    for a, b in zip(*runs):
        for x, y in zip(a.frameset.images, b.frameset.images):
            assert np.array_equal(x, y)
    other = open_sources(["sim"], rig, rate_hz=100.0, seed=4, speed=None, scene_provider=_ball_scene, duration_s=0.02)
    sets, _ = _collect(other, 2, 100.0)
    assert not np.array_equal(sets[0].frameset.images[0], runs[0][0].frameset.images[0])  # noise follows the seed


def test_sim_real_time_rate_and_host_stamps(rig):
    # long queues: a loaded machine may starve the reader threads for longer than 8 frames
    sources = open_sources(["sim"], rig, rate_hz=50.0, seed=0, scene_provider=_ball_scene, duration_s=0.5,
                           queue_len=64)
    sets, st = _collect(sources, 25, 50.0, queue_len=64)
    assert len(sets) + sources[0].stats().skipped == 25
    t = np.array([s.t_host_s[0] for s in sets])
    k = np.array([s.frame_id for s in sets])
    # host stamps follow the fixed 20 ms schedule (a late frame set is late, never early)
    lag = (t - t[0]) - (k - k[0]) * 0.02
    assert np.median(np.abs(lag)) < 0.005 and lag.min() > -0.002
    off = st.clock_offsets[0]
    assert off is not None and off.spread_s < 0.05


def test_sim_prerendered_clip_loops(rig):
    sources = open_sources(["sim"], rig, rate_hz=100.0, seed=1, speed=None, scene_provider=_ball_scene,
                           prerender_s=0.05, duration_s=0.12)
    sets, st = _collect(sources, 20, 100.0, lossless=True)
    assert [s.frame_id for s in sets] == list(range(12)) and st.complete == 12
    assert np.array_equal(sets[7].frameset.images[1], sets[2].frameset.images[1])  # 5 frame sets, looped
    assert not np.array_equal(sets[3].frameset.images[1], sets[2].frameset.images[1])


def test_sim_render_process_gives_the_thread_s_images(rig):
    from harness.live.sources.sim import LauncherFlights

    flights = LauncherFlights(0, n_serves=1)  # picklable: goes to the child process
    runs = []
    for in_process in (False, True):
        sources = open_sources(["sim"], rig, rate_hz=100.0, seed=5, speed=None, scene_provider=flights,
                               duration_s=0.08, render_process=in_process)
        feed = sources[0].feed
        sets, st = _collect(sources, 20, 100.0, lossless=True)
        assert [s.frame_id for s in sets] == list(range(8)) and st.complete == 8
        runs.append(sets)
    for a, b in zip(*runs):
        assert all(np.array_equal(x, y) for x, y in zip(a.frameset.images, b.frameset.images))
    assert feed._closers == []  # closing the sources ended the child process and freed the shared memory
    with pytest.raises(ValueError, match="picklable scene_provider"):
        open_sources(["sim"], rig, scene_provider=lambda t: _ball_scene(t), render_process=True)


def test_close_stops_an_endless_sim_promptly(rig):
    import threading

    before = threading.active_count()
    sources = open_sources(["sim"], rig, rate_hz=100.0, scene_provider=_ball_scene)
    asm = FrameSetAssembler(sources, AssemblyOptions(rate_hz=100.0)).start()
    assert asm.get(5.0) is not None
    t0 = time.monotonic()
    asm.close()
    assert time.monotonic() - t0 < 2.0
    deadline = time.monotonic() + 2.0
    while threading.active_count() > before and time.monotonic() < deadline:
        time.sleep(0.02)
    assert threading.active_count() <= before  # reader, assembler, pacer and render threads all ended


def test_sim_default_scene_is_seeded_launcher_flights():
    from harness.live.sources.sim import LauncherFlights

    a, b = LauncherFlights(5, n_serves=1), LauncherFlights(5, n_serves=1)
    s = a.ball_state(0.3)
    assert s.shape == (9,) and np.array_equal(s, b.ball_state(0.3))
    assert s[0] < 1.9 and s[3] < 0  # flying toward the robot (-x)
    assert a.ball_state(a.cycle_s - 0.01) is None  # the gap between serves: no ball
    assert np.allclose(a.ball_state(0.3 + a.cycle_s), s, atol=1e-9)  # the serves repeat
    assert len(a(0.3).balls) == 1


def test_sim_bad_scene_provider(rig):
    sources = open_sources(["sim"], rig, rate_hz=100.0, speed=None, scene_provider=lambda t: "no scene",
                           duration_s=0.05)
    sets, st = _collect(sources, 5, 100.0)
    assert sets == [] and all(st.ended) and "not a Scene" in st.errors[0]


# -- replay ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_log(tmp_path_factory, rig):
    from harness.logs import SessionLogWriter
    from harness.sim.render import Renderer

    path = tmp_path_factory.mktemp("replay") / "run.mcap"
    renderer = Renderer(rig, seed=1)
    images = []
    with SessionLogWriter(path, metadata={"kind": "test", "seed": 1}, image_format="png") as log:
        log.attach_rig(rig)
        for k in range(12):
            imgs = renderer.render(Scene(balls=_ball_scene(k * 0.02).balls, frame_index=k))
            images.append(imgs)
            for name, img in zip(rig.names, imgs):
                if not (name == "cam1" and k == 7):  # camera 1 lost frame 7 in this recording
                    log.write_image(1.0 + k * 0.02, name, img, k)
    return path, images


def test_replay_as_fast_as_possible_is_exact(rig, small_log):
    path, images = small_log
    sets, st = _collect(open_sources(["replay", str(path)], rig, speed=None), 20, 50.0, lossless=True)
    assert [s.frame_id for s in sets] == list(range(12))
    assert st.missing == (0, 1) and sets[7].frameset.images[1] is None
    for s, imgs in zip(sets, images):
        assert np.array_equal(s.frameset.images[0], imgs[0])  # png: lossless
        assert np.isclose(s.t_device_s[0], 1.0 + s.frame_id * 0.02)


def test_replay_at_recorded_timing(rig, small_log):
    path, _ = small_log
    sets, _ = _collect(open_sources(["replay", str(path)], rig, speed=1.0), 20, 50.0)
    t = np.array([s.t_host_s[0] for s in sets])
    assert len(sets) == 12 and 0.20 < t[-1] - t[0] < 0.30  # 11 intervals of 20 ms


def test_replay_errors(rig, small_log, tmp_path):
    with pytest.raises(FileNotFoundError, match="no session log"):
        open_sources(["replay", str(tmp_path / "missing.mcap")], rig)
    from tracker import Rig

    data = rig.to_dict()
    data["cameras"][0]["name"] = "camX"
    renamed = Rig.from_dict(data)
    with pytest.raises(ValueError, match=r"no images of rig camera\(s\) \['camX'\]"):
        open_sources(["replay", str(small_log[0])], renamed)


# -- missing drivers -------------------------------------------------------------------------------
def test_missing_driver_names_the_extra(monkeypatch):
    for name in ("pypylon", "pypylon.pylon"):
        monkeypatch.setitem(sys.modules, name, None)  # what an environment without the package does
    with pytest.raises(SourceUnavailable, match=r"pip install 'rt2\[cameras\]'") as info:
        require_driver("pypylon.pylon", "pylon")
    assert isinstance(info.value, ValueError) and "pypylon" in str(info.value)


# -- video -----------------------------------------------------------------------------------------
def _frames(rig, n):
    """Smooth frames (lossy codecs keep them close): a colour gradient and a block that moves by 8 px a frame."""
    w, h = rig.cameras[0].image_size
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([200 * xx / w, 200 * yy / h, np.full((h, w), 60.0)], axis=-1).astype(np.uint8)
    out = []
    for k in range(n):
        row = []
        for j in range(len(rig.cameras)):
            img = base.copy()
            x0 = (8 * k + 16 * j) % (w - 16)
            img[20:40, x0:x0 + 16] = (250, 40, 10)  # orange-red block: a BGR mix-up shows as blue
            row.append(img)
        out.append(row)
    return out


def test_video_image_folders_with_timestamps(rig, tmp_path):
    frames = _frames(rig, 6)
    for j, name in enumerate(rig.names):
        (tmp_path / name).mkdir()
        for k in range(6):
            cv2.imwrite(str(tmp_path / name / f"img{k:03d}.png"), cv2.cvtColor(frames[k][j], cv2.COLOR_RGB2BGR))
    rows = "\n".join(f"{100 + k},{5.0 + 0.01 * k:.3f}" for k in range(6))
    (tmp_path / "cam0.csv").write_text("frame_id,t_s\n" + rows + "\n")
    (tmp_path / "cam1" / "timestamps.csv").write_text("frame_id,t_s\n" + rows + "\n")
    sets, st = _collect(open_sources(["video", str(tmp_path)], rig, speed=None), 10, 100.0, lossless=True)
    assert [s.frame_id for s in sets] == [100 + k for k in range(6)] and st.complete == 6
    assert np.allclose(sets[2].t_device_s, 5.02)
    for s, fr in zip(sets, frames):
        assert all(np.array_equal(a, b) for a, b in zip(s.frameset.images, fr))


@pytest.mark.parametrize("suffix, fourcc", [(".avi", "MJPG"), (".mp4", "mp4v")])
def test_video_files(rig, tmp_path, suffix, fourcc):
    frames = _frames(rig, 8)
    w, h = rig.cameras[0].image_size
    for j, name in enumerate(rig.names):
        out = cv2.VideoWriter(str(tmp_path / f"{name}{suffix}"), cv2.VideoWriter_fourcc(*fourcc), 30.0, (w, h))
        assert out.isOpened()
        for k in range(8):
            out.write(cv2.cvtColor(frames[k][j], cv2.COLOR_RGB2BGR))
        out.release()
    sets, st = _collect(open_sources(["video", str(tmp_path)], rig, rate_hz=100.0), 10, 100.0)
    assert [s.frame_id for s in sets] == list(range(8)) and st.complete == 8
    assert np.isnan(sets[0].t_device_s).all()  # no timestamps file: no device stamps
    t = np.array([s.t_host_s[0] for s in sets])
    assert 0.05 < t[-1] - t[0] < 0.2  # played at rate_hz: 7 intervals of 10 ms
    for s, fr in zip(sets, frames):  # lossy codecs: close, and not another frame
        err = [np.abs(a.astype(int) - b).mean() for a, b in zip(s.frameset.images, fr)]
        other = np.abs(s.frameset.images[0].astype(int) - frames[(s.frame_id + 3) % 8][0]).mean()
        assert max(err) < 0.5 * other


def test_video_errors(rig, tmp_path):
    with pytest.raises(FileNotFoundError, match="no folder"):
        open_sources(["video", str(tmp_path / "none")], rig)
    (tmp_path / "cam0").mkdir()
    with pytest.raises(ValueError, match="for rig camera cam1"):
        open_sources(["video", str(tmp_path)], rig)
    (tmp_path / "cam1").mkdir()
    (tmp_path / "cam1.csv").write_text("frame,time\n0,0.0\n")
    with pytest.raises(ValueError, match=r"cam1.csv: the first row must be the header 'frame_id,t_s'"):
        open_sources(["video", str(tmp_path)], rig)


# -- opencv ----------------------------------------------------------------------------------------
def test_opencv_device_that_does_not_open_is_named(rig):
    with pytest.raises(SourceUnavailable, match="opencv camera 63 .rig camera cam0. does not open"):
        open_sources(["opencv", "63,62"], rig)


def test_opencv_reads_through_videocapture(rig, tmp_path):
    frames = _frames(rig, 5)
    w, h = rig.cameras[0].image_size
    paths = []
    for j, name in enumerate(rig.names):
        paths.append(str(tmp_path / f"{name}.avi"))
        out = cv2.VideoWriter(paths[-1], cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (w, h))
        for k in range(5):
            out.write(cv2.cvtColor(frames[k][j], cv2.COLOR_RGB2BGR))
        out.release()
    sources = open_sources(["opencv", ",".join(paths)], rig)
    cam = sources[1]
    cam.start()
    got = []
    while (f := cam.read(1.0)) is not None:
        got.append(f)
    assert cam.exhausted and [f.frame_id for f in got] == list(range(5)) and all(f.camera == 1 for f in got)
    for f, fr in zip(got, frames):
        assert np.abs(f.image.astype(int) - fr[1]).mean() < 5  # RGB, not BGR: the block is orange-red
        assert np.abs(f.image[..., ::-1].astype(int) - fr[1]).mean() > 20
    assert got[0].t_host_s <= got[-1].t_host_s
    for s in sources:
        s.close()


@pytest.mark.slow  # the lab rig's renderer set-up takes 4 s idle, ~20 s on a loaded machine
def test_sim_launcher_flights_tracked_on_the_lab_rig():
    """The default demo path: launcher flights rendered on lab4_vga, assembled, tracked in 3D."""
    from harness.live.sources.sim import LauncherFlights
    from tracker.rig_files import resolve_rig
    from tracker import Tracker

    lab = resolve_rig("lab4_vga")
    flights = LauncherFlights(2, n_serves=1)
    sources = open_sources(["sim"], lab, rate_hz=200.0, seed=2, speed=None, scene_provider=flights,
                           duration_s=0.5)
    tracker = Tracker(lab, "rt2")
    sets, st = _collect(sources, 100, 200.0, lossless=True)
    assert len(sets) == 100 and st.complete == 100
    errors = []
    for s in sets[::5]:
        obs = tracker.process(s.frameset)
        truth = flights.ball_state(s.frame_id / 200.0)[:3]
        if obs.status == "ok":
            errors.append(np.linalg.norm(obs.position_m - truth))
    # a served ball flies through the view of 3-4 cameras: most frame sets give a position, within
    # the tracker's centimetre-level error on moving, motion-blurred rendered balls
    assert len(errors) >= 10 and np.median(errors) < 0.01


# -- a real recording ------------------------------------------------------------------------------
def test_video_of_a_real_four_webcam_session_matched_by_time(real_data, tmp_path):
    """caliscope's four-webcam session (real mp4s, per-camera frame times on one PC clock; see
    ../shared/data/real/caliscope_4cam/README.md): grouping the frames by time must reproduce the
    recording's own synchronisation (sync_index) exactly."""
    import csv
    from collections import defaultdict

    from tracker import Rig

    src = real_data / "caliscope_4cam" / "calibration" / "extrinsic"
    rows = list(csv.DictReader(open(src / "timestamps.csv")))
    per_cam = defaultdict(list)
    for r in rows:
        per_cam[int(r["cam_id"])].append((float(r["frame_time"]), int(r["sync_index"])))
    for c in range(4):
        (tmp_path / f"cam_{c}.mp4").symlink_to(src / f"cam_{c}.mp4")
        lines = [f"{sync},{t!r}" for t, sync in sorted(per_cam[c])]
        (tmp_path / f"cam_{c}.csv").write_text("frame_id,t_s\n" + "\n".join(lines) + "\n")
    from tracker.rig_files import resolve_rig

    data = resolve_rig("lab4_vga").to_dict()  # only names and sizes matter to the source
    for c, cam in enumerate(data["cameras"]):
        cam["name"], cam["image_size"] = f"cam_{c}", [1280, 720]
    rig4 = Rig.from_dict(data)
    sources = open_sources(["video", str(tmp_path)], rig4, speed=None)
    sets, st = _collect(sources, 100, 6.0, match="time", clock="device", lossless=True)
    sync_of = {(c, t): s for c in range(4) for t, s in per_cam[c]}
    assert len(sets) == 48 and st.complete == 48 and st.late == (0, 0, 0, 0)
    for s in sets:
        syncs = {sync_of[(c, float(t))] for c, t in enumerate(s.t_device_s)}
        assert len(syncs) == 1  # the four frames of one synchronised instant
        assert s.frameset.images[0].shape == (720, 1280, 3)


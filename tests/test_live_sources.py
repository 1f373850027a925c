"""Camera sources: spec parsing, sim (rendered lab), replay of a real session log, video files and
image folders, opencv (through cv2.VideoCapture), and the messages of missing drivers."""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np
import pytest

from harness.lab import preview_rig
from harness.live.assembly import AssemblyOptions, FrameSetAssembler
from harness.live.frames import FrameSource
from harness.live.sources import (SourceSpec, SourceUnavailable, open_sources, parse_source_spec,
                                  require_driver)
from harness.render import Ball, Scene


@pytest.fixture(scope="module")
def rig():
    return preview_rig(80, 60)


def _ball_scene(t_s: float) -> Scene:
    return Scene(balls=(Ball([-1.2 + 0.5 * t_s, 0.0, 1.2], velocity_mps=[0.5, 0.0, 0.0]),))


def _collect(sources, n, rate_hz, **opts):
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=rate_hz, output_len=1000, **opts)) as asm:
        out = []
        deadline = time.monotonic() + 20.0
        while len(out) < n and time.monotonic() < deadline:
            fs = asm.get(0.2)
            if fs is None and asm.finished:
                break
            if fs is not None:
                out.append(fs)
        return out, asm.stats()


# -- spec ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("tokens, spec", [
    (["sim"], SourceSpec("sim")),
    (["replay", "run.mcap"], SourceSpec("replay", "run.mcap")),
    ("video /data/clip", SourceSpec("video", "/data/clip")),
    (["opencv", "0,1,2,3"], SourceSpec("opencv", None, (0, 1, 2, 3))),
    (["opencv", "/dev/video0,rtsp://10.0.0.2/s"], SourceSpec("opencv", None, ("/dev/video0", "rtsp://10.0.0.2/s"))),
    (["pylon"], SourceSpec("pylon")),
    (["pylon", "2301,2302"], SourceSpec("pylon", None, (2301, 2302))),
    (["genicam"], SourceSpec("genicam")),
    (["genicam", "p.cti", "a,b"], SourceSpec("genicam", "p.cti", ("a", "b"))),
])
def test_parse_source_spec(tokens, spec):
    assert parse_source_spec(tokens) == spec


@pytest.mark.parametrize("tokens, match", [
    ([], "empty"), (["webcam"], "unknown camera source 'webcam'"), (["replay"], "replay LOG"),
    (["sim", "x"], "'sim x'"), (["opencv", "0,,1"], "comma-separated"), (["pylon", "a", "b"], "pylon"),
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
        sets, st = _collect(sources, 20, 100.0, max_wait_s=1.0)  # as fast as possible: wait for every frame
        assert [s.frame_id for s in sets] == list(range(10)) and st.complete == 10 and st.late == (0, 0), st
        assert np.allclose(sets[4].t_device_s, 0.04)
        assert sets[0].frameset.images[0].shape == (60, 80, 3) and sets[0].frameset.images[0].dtype == np.uint8
        runs.append(sets)
    for a, b in zip(*runs):
        for x, y in zip(a.frameset.images, b.frameset.images):
            assert np.array_equal(x, y)
    other = open_sources(["sim"], rig, rate_hz=100.0, seed=4, speed=None, scene_provider=_ball_scene, duration_s=0.02)
    sets, _ = _collect(other, 2, 100.0)
    assert not np.array_equal(sets[0].frameset.images[0], runs[0][0].frameset.images[0])  # noise follows the seed


def test_sim_real_time_rate_and_host_stamps(rig):
    sources = open_sources(["sim"], rig, rate_hz=50.0, seed=0, scene_provider=_ball_scene, duration_s=0.5)
    sets, st = _collect(sources, 25, 50.0)
    assert len(sets) + sources[0].stats().skipped == 25
    t = np.array([s.t_host_s[0] for s in sets])
    k = np.array([s.frame_id for s in sets])
    # host stamps follow the fixed 20 ms schedule (a late frame set is late, never early)
    lag = (t - t[0]) - (k - k[0]) * 0.02
    assert np.median(np.abs(lag)) < 0.005 and lag.min() > -0.002
    off = st.clock_offsets[0]
    assert off is not None and off.spread_s < 0.05


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
    from harness.render import Renderer

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
    sets, st = _collect(open_sources(["replay", str(path)], rig, speed=None), 20, 50.0, max_wait_s=1.0)
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

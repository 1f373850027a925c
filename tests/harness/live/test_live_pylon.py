"""The pylon source end to end through Basler's camera emulator (pypylon, PYLON_CAMEMU=4):
rendered frames of the lab rig streamed by four emulated cameras, assembled, tracked to 3D."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

pylon = pytest.importorskip("pypylon.pylon", reason="pypylon is not installed (pip install 'rt2[cameras]')")

from harness.live.assembly import AssemblyOptions, FrameSetAssembler  # noqa: E402
from harness.live.sources import SourceUnavailable, open_sources  # noqa: E402
from harness.sim.render import Ball, Renderer, Scene  # noqa: E402
from tracker.rig_files import resolve_rig  # noqa: E402

BALL_M = np.array([-1.0, 0.05, 1.25])  # over the robot's half, seen by all four lab cameras


@pytest.fixture(scope="module")
def emulated(tmp_path_factory):
    os.environ["PYLON_CAMEMU"] = "4"  # read by pylon at each device enumeration
    rig = resolve_rig("lab4_vga")
    images = Renderer(rig, seed=0).render(Scene(balls=(Ball(BALL_M),), frame_index=0))
    dirs = []
    for name, img in zip(rig.names, images):
        d = tmp_path_factory.mktemp(f"emu_{name}")
        cv2.imwrite(str(d / "frame.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))  # PNG: lossless
        dirs.append(d)
    return rig, images, dirs


def test_emulated_cameras_to_a_3d_position(emulated):
    from tracker import Tracker

    rig, images, dirs = emulated
    sources = open_sources(["pylon"], rig, rate_hz=20.0, trigger="software", emulator_images=dirs)
    assert [s.camera for s in sources] == [0, 1, 2, 3]
    assert [s.serial for s in sources] == sorted(s.serial for s in sources)  # documented order rule
    tracker = Tracker(rig, "rt2")
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=20.0, max_wait_s=0.2, output_len=16)) as asm:
        sets = [asm.get(2.0) for _ in range(6)]
        st = asm.stats()
    assert all(s is not None for s in sets)
    assert [s.frame_id for s in sets] == list(range(sets[0].frame_id, sets[0].frame_id + 6))  # one trigger, one id
    assert st.complete == st.framesets and st.late == (0, 0, 0, 0)
    assert all(s["grab_errors"] == 0 for s in st.sources)
    # emulated cameras report device time 0: no device stamps, the host stamps carry the time
    assert all(np.isnan(s.t_device_s).all() and np.isfinite(s.t_host_s).all() for s in sets)
    assert st.clock_offsets == (None, None, None, None)
    for s in sets:
        for got, sent in zip(s.frameset.images, images):
            assert np.array_equal(got, sent)  # RGB order and every pixel survive the driver path
    obs = [tracker.process(s.frameset) for s in sets]
    # The ball is 7-9 px across in these cameras; the tracker's rendered-frame error on this rig is
    # ~1-2 mm (docs/accuracy.md). 5 mm is a few times that and far below what a camera mix-up or a
    # channel swap would give (no consensus, or centimetres off).
    for o in obs:
        assert o.status == "ok" and o.support == 4
        assert np.linalg.norm(o.position_m - BALL_M) < 0.005


def test_free_run_and_explicit_serials(emulated):
    rig, _, dirs = emulated
    serials = [d.GetSerialNumber() for d in pylon.TlFactory.GetInstance().EnumerateDevices()]
    order = serials[::-1]  # explicit list: rig camera i is the i-th serial given
    sources = open_sources(["pylon", ",".join(order)], rig, rate_hz=50.0, emulator_images=dirs)
    assert [s.serial for s in sources] == order
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=50.0, match="time", max_wait_s=0.1)) as asm:
        s = asm.get(3.0)
    assert s is not None and sum(img is not None for img in s.frameset.images) >= 1


def test_serial_and_count_errors(emulated):
    rig, _, _ = emulated
    with pytest.raises(SourceUnavailable, match="no camera with serial number or user id 'nope'"):
        open_sources(["pylon", "nope,a,b,c"], rig)
    two = rig.subset(rig.names[:2])
    with pytest.raises(ValueError, match=r"found 4 camera\(s\).*rig has 2"):
        open_sources(["pylon"], two)
    with pytest.raises(ValueError, match="trigger must be one of"):
        open_sources(["pylon"], rig, trigger="line")


def test_missing_pypylon_names_the_extra(monkeypatch, emulated):
    import sys

    rig, _, _ = emulated
    monkeypatch.setitem(sys.modules, "pypylon.pylon", None)
    with pytest.raises(SourceUnavailable, match=r"pypylon.*pip install 'rt2\[cameras\]'"):
        open_sources(["pylon"], rig)

"""The genicam source through harvesters and the reference GenTL producer shipped in the genicam
package (three simulated 400x400 devices: red, green, blue test images)."""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest

pytest.importorskip("harvesters.core", reason="harvesters is not installed (pip install 'rt2[cameras]')")

from harness.live.assembly import AssemblyOptions, FrameSetAssembler  # noqa: E402
from harness.live.sources import SourceUnavailable, open_sources  # noqa: E402
from harness.live.sources.genicam import default_producers  # noqa: E402
from tracker.rig_files import resolve_rig  # noqa: E402
from tracker import Rig  # noqa: E402


@pytest.fixture(scope="module")
def producer():
    found = [p for p in default_producers() if p.endswith(".cti")]
    if not found:
        pytest.skip("no GenTL producer: the genicam package ships none on this platform")
    return found[0]


@pytest.fixture(scope="module")
def rig3():
    """Three lab cameras at the simulated devices' 400x400 size."""
    data = resolve_rig("lab4_vga").to_dict()
    data["cameras"] = data["cameras"][:3]
    for cam in data["cameras"]:
        cam["image_size"] = [400, 400]
    return Rig.from_dict(data)


def test_reference_producer_frames_assembled_by_time(producer, rig3):
    sources = open_sources(["genicam", producer], rig3, rate_hz=20.0)
    assert [s.serial for s in sources] == sorted(s.serial for s in sources)
    with FrameSetAssembler(sources, AssemblyOptions(rate_hz=20.0, match="time", max_wait_s=0.2, output_len=32)) as asm:
        sets, full = [], []
        deadline = time.monotonic() + 10.0
        while len(full) < 3 and time.monotonic() < deadline:  # the devices start one after the other
            s = asm.get(1.0)
            if s is not None:
                sets.append(s)
                if all(img is not None for img in s.frameset.images):
                    full.append(s)
        st = asm.stats()
    assert len(full) == 3, f"complete frame sets: {len(full)} of {len(sets)}; {st}"
    assert st.errors == (None, None, None)
    for img in full[0].frameset.images:
        assert img.shape == (400, 400, 3) and img.dtype == np.uint8 and img.any()
    assert np.isnan(full[0].t_device_s).all()  # this producer gives no timestamps: host stamps carry
    ids = [s.frame_id for s in sets]
    assert ids == sorted(ids)


def test_device_errors(producer, rig3):
    two = rig3.subset(rig3.names[:2])
    with pytest.raises(ValueError, match=r"found 3 device\(s\).*rig has 2"):
        open_sources(["genicam", producer], two)
    with pytest.raises(SourceUnavailable, match="no device with serial number or id 'x'"):
        open_sources(["genicam", producer, "x,y,z"], rig3)
    with pytest.raises(FileNotFoundError, match="no GenTL producer file"):
        open_sources(["genicam", "/nonexistent/producer.cti"], rig3)


def test_missing_harvesters_names_the_extra(monkeypatch, rig3):
    monkeypatch.setitem(sys.modules, "harvesters.core", None)
    with pytest.raises(SourceUnavailable, match=r"harvesters.*pip install 'rt2\[cameras\]'"):
        open_sources(["genicam"], rig3)

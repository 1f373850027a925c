"""harness.live._memory: freed frame memory is reused (no page faults per frame set), in a separate process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_PROBE = r"""
import json, resource, sys
import numpy as np
from harness.live._memory import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "keep" else None
again = keep_freed_memory() if sys.argv[1] == "keep" else None
src = np.full((480, 640, 3), 7, np.uint8)
for _ in range(20):  # warm up (the dynamic threshold of glibc adapts at first)
    a = [src.copy() for _ in range(4)]
    del a
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(200):  # four VGA frames copied and freed per "frame set", with a trim-sized gap between
    a = [src.copy() for _ in range(4)]
    big = np.ones(3 * 1024 * 1024, np.uint8)
    del a, big
print(json.dumps({"applied": applied, "again": again, "faults_per_set": (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 200}))
"""


def _probe(mode):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, timeout=120, env=env, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator settings")
def test_freed_frames_are_reused_without_page_faults():
    keep = _probe("keep")
    assert keep["applied"] is True and keep["again"] is True  # once per process, idempotent
    assert keep["faults_per_set"] < 5
    plain = _probe("plain")
    assert plain["faults_per_set"] > 10 * max(keep["faults_per_set"], 1.0)  # what it saves

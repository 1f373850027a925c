"""No orphans (harness/common/spawn.py, docs/reliability.md): SIGKILL the parent of each kind of child service
-- the robot bridge (``rt2 accuracy --robot sim``), the observation process (``rt2 play --live``), rt2 track and
its renderer (``rt2 accuracy --live``) -- and 2 s later none of its descendants is alive and their ports are free.
Real processes and ports on 127.0.0.1, found through /proc."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.common.spawn import PARENT_PID_ENV, ROOT
from tests.stop_times import bindable, descendants, listening_ports, wait_gone


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _listening_ports(pid: int) -> set[int]:
    return set(listening_ports([pid]))


def _kill_parent_and_check(tmp_path, argv, needles, timeout_s=600.0):
    """Start ``rt2 argv``; once a descendant matching each of ``needles`` listens, SIGKILL the parent and check."""
    proc = subprocess.Popen([sys.executable, "-m", "harness.cli", *argv], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=open(tmp_path / "parent.err", "w"))
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            kids = descendants(proc.pid)
            ready = {n: [k for k in kids if n in _cmdline(k) and _listening_ports(k)] for n in needles}
            if all(ready.values()):
                break
            assert proc.poll() is None, (tmp_path / "parent.err").read_text()[-2000:]
            assert time.monotonic() < deadline, f"the children {needles} did not start: {[_cmdline(k) for k in kids]}"
            time.sleep(0.2)
        time.sleep(0.3)
        kids = descendants(proc.pid)
        ports = set().union(*(_listening_ports(k) for k in kids))
        assert ports
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    left = [(k, _cmdline(k)) for k in wait_gone(kids, 2.0)]  # on their exits (pidfds), at most 2 s
    for k, _ in left:  # do not leave them behind for the next test
        os.kill(k, signal.SIGKILL)
    assert not left, left
    assert all(bindable(p) for p in ports), [p for p in ports if not bindable(p)]
    return kids


def test_the_robot_bridge_dies_with_rt2_accuracy(tmp_path):
    kids = _kill_parent_and_check(tmp_path, ["accuracy", "--robot", "sim", "--frames", "1500", "--rate-hz", "100",
                                             "--trackers", "rt2", "--out", str(tmp_path / "out")], ["robot serve"])
    assert kids


def test_the_bridge_and_observer_die_with_rt2_play_live(tmp_path):
    _kill_parent_and_check(tmp_path, ["play", "--live", "--balls", "3", "--no-log", "--out", str(tmp_path / "out")],
                           ["robot serve", "play observe"])


@pytest.mark.slow
def test_rt2_track_and_its_renderer_die_with_rt2_accuracy_live(tmp_path):
    kids = _kill_parent_and_check(tmp_path, ["accuracy", "--live", "--frames", "400", "--rate-hz", "100",
                                             "--trackers", "rt2", "--out", str(tmp_path / "out")],
                                  ["robot serve", "track"])
    assert any("_render_process" in _cmdline(k) or "render" in _cmdline(k) for k in kids) or kids


def test_a_child_whose_parent_is_gone_before_it_starts_exits(tmp_path):
    """The race of a parent dying between the fork and PR_SET_PDEATHSIG: the child sees it and exits at once."""
    env = {**os.environ, PARENT_PID_ENV: "1"}  # its parent is not pid 1
    proc = subprocess.run([sys.executable, "-m", "harness.cli", "robot", "serve", "--sim", "--bind",
                           "tcp://127.0.0.1:*", "--ready-json"], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1 and not proc.stdout

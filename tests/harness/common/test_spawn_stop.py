"""Children stopped side by side, and never waited for past a deadline (harness/common/spawn.py
``stop_together``): what keeps a parent stopped by a signal within its 2 s (docs/reliability.md, "Child services
stop fast") when it has two child services, or one that does not leave on SIGTERM."""

from __future__ import annotations

import subprocess
import sys
import time
from dataclasses import dataclass

from harness.common.spawn import STOP_GRACE_S, stop_together

#: a child that, on SIGTERM, takes LEAVE_S to leave (a service finishing its work), or ignores it (a hung one)
_CHILD = """
import signal, sys, time
mode = sys.argv[1]
if mode == "ignore":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
else:
    def leave(*_):
        time.sleep(float(mode))
        sys.exit(0)
    signal.signal(signal.SIGTERM, leave)
print("ready", flush=True)
time.sleep(120)
"""


@dataclass
class Child:
    proc: subprocess.Popen
    stop_timeout_s: float = 30.0


def _start(mode: str) -> Child:
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, mode], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "ready\n"  # its handler is installed
    return Child(proc)


def test_two_children_stop_side_by_side_not_one_after_the_other():
    leave_s = 1.5
    children = [_start(str(leave_s)), _start(str(leave_s))]
    t0 = time.monotonic()
    stop_together(children)
    took = time.monotonic() - t0
    assert all(c.proc.returncode == 0 for c in children)  # each left on its own, none killed
    # one after the other takes >= 2 x 1.5 s; side by side 1.5 s plus the start of the handlers (0.01-0.3 s on the
    # loaded 2-core machine): 2.7 s leaves room for load and still fails the sequential stop
    assert leave_s <= took < 2 * leave_s - 0.3, took


def test_a_child_that_ignores_sigterm_is_killed_at_the_deadline():
    children = [_start("ignore"), _start("0")]
    t0 = time.monotonic()
    stop_together(children, STOP_GRACE_S)
    took = time.monotonic() - t0
    assert children[0].proc.returncode == -9 and children[1].proc.returncode == 0
    # it waited the grace, not the children's own 30 s stop_timeout_s (1 s slack for SIGKILL and reaping under load)
    assert STOP_GRACE_S <= took < STOP_GRACE_S + 1.0, took


def test_children_already_gone_and_the_default_deadline():
    gone = _start("0")
    gone.proc.terminate()
    gone.proc.wait()
    hung = _start("ignore")
    gone.stop_timeout_s, hung.stop_timeout_s = 0.1, 0.3  # the default deadline is the largest stop_timeout_s
    t0 = time.monotonic()
    stop_together([gone, hung])
    assert hung.proc.returncode == -9 and 0.3 <= time.monotonic() - t0 < 1.3
    stop_together([])  # nothing to stop

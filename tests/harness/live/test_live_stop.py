"""``rt2 track`` after SIGINT / SIGTERM (harness/live/run.py ``LiveService.close(timeout_s)``): its log is finished
whatever that takes, and what is still closing after the deadline (a camera driver or a thread slow to stop) is
left to the process's exit, so the service leaves within its 2 s (docs/reliability.md, "Stop times")."""

from __future__ import annotations

import threading
import time

import pytest

from harness.live.run import LiveService


class _Service:
    def __init__(self, finish_s: float = 0.0):
        self.finished = 0
        self.finish_s = finish_s

    def finish(self):
        time.sleep(self.finish_s)  # a log closed on a loaded machine
        self.finished += 1


def test_close_with_a_deadline_finishes_the_log_and_leaves_a_hung_closer_behind():
    hang, closed = threading.Event(), []
    service = _Service(finish_s=0.5)
    live = LiveService(config=None, service=service, assembler=None,
                       closers=[lambda: closed.append("tracker"), lambda: hang.wait(30.0), lambda: closed.append("log?")])
    t0 = time.monotonic()
    assert live.close(timeout_s=0.3) is False  # the hung closer is still running
    took = time.monotonic() - t0
    assert service.finished == 1  # the log: always, and not counted against the deadline
    assert 0.8 <= took < 0.8 + 1.0, took  # 0.5 s finish + 0.3 s; 1 s slack for a loaded machine (not the 30 s hang)
    assert closed == ["log?"]  # newest first: the ones before the hung one ran, the one after waits behind it
    hang.set()
    assert live.close(timeout_s=0.3) is True and service.finished == 1  # once


@pytest.mark.parametrize("timeout_s", [None, 1.0])
def test_a_failing_finish_still_closes_everything_and_is_raised(timeout_s):
    class _Broken(_Service):
        def finish(self):
            raise OSError("disk full")

    closed = []
    live = LiveService(config=None, service=_Broken(), assembler=None, closers=[lambda: closed.append(1), lambda: closed.append(2)])
    with pytest.raises(OSError, match="disk full"):
        live.close(timeout_s=timeout_s)
    assert closed == [2, 1]


def test_close_without_a_deadline_closes_everything_in_order():
    closed = []
    live = LiveService(config=None, service=_Service(), assembler=None,
                       closers=[lambda: closed.append(1), lambda: closed.append(2)])
    with live:
        pass
    assert closed == [2, 1]
    assert live.close(timeout_s=0.1) is True and closed == [2, 1]

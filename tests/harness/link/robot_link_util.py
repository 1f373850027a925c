"""The robot-link tests start `rt2 robot serve --sim` as a separate process on free 127.0.0.1 ports."""

from __future__ import annotations

from harness.common.spawn import ROOT
from harness.link.spawn_bridge import SimBridgeProcess

__all__ = ["BridgeProcess", "ROOT", "STARVED_OK"]

#: WamClient link-loss limits for the tests that are not about losing the link: the client's defaults (no state for
#: 0.25 s, no reply for 0.4 s = link lost) suit a robot streaming at 500 Hz on its own machine, but on the loaded
#: 2-core test machine a bridge process goes without CPU for 0.5-1 s at times (a log close took 0.74 s at a load
#: average of 40, make stop-times), and the test then failed on a "lost" link it was not about. Loss itself is
#: tested with its own limits (test_robot_link_loss.py, test_live_accuracy.py, rt2 robot check)
STARVED_OK = {"timeout_s": 2.0, "request_timeout_s": 2.0}


def BridgeProcess(*extra: str, **kwargs) -> SimBridgeProcess:
    """A bridge process; it wakes every 4 ticks (``--batch 4``: the same stamps, less CPU on the shared test
    machine, where a bridge starved of CPU for 0.25 s would look like a lost link)."""
    return SimBridgeProcess(*extra, *(() if "--batch" in extra else ("--batch", "4")), **kwargs)

"""The robot-link tests start `rt2 robot serve --sim` as a separate process on free 127.0.0.1 ports."""

from __future__ import annotations

from harness.common.spawn import ROOT
from harness.link.spawn_bridge import SimBridgeProcess

__all__ = ["BridgeProcess", "ROOT"]


def BridgeProcess(*extra: str, **kwargs) -> SimBridgeProcess:
    """A bridge process; it wakes every 4 ticks (``--batch 4``: the same stamps, less CPU on the shared test
    machine, where a bridge starved of CPU for 0.25 s would look like a lost link)."""
    return SimBridgeProcess(*extra, *(() if "--batch" in extra else ("--batch", "4")), **kwargs)

"""The robot-link tests start `rt2 robot serve --sim` as a separate process on free 127.0.0.1 ports."""

from __future__ import annotations

from harness.robot.link.spawn import ROOT, SimBridgeProcess

BridgeProcess = SimBridgeProcess

__all__ = ["BridgeProcess", "ROOT"]

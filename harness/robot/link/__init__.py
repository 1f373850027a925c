"""The robot link: the WAM over the network (ZeroMQ + msgpack), the way the harness talks to a real robot.

``protocol`` (message schema, validation), ``bridge_sim`` (the robot side for the simulated WAM:
``rt2 robot serve --sim``), ``client`` (``WamClient``: the WAM interface over the link), ``clock``
(clock-offset estimates). Protocol and the bridge a lab writes for its controller: docs/robot_link.md.
"""

from harness.robot.link.bridge_sim import BridgeOptions, SimBridge
from harness.robot.link.client import LinkLostError, WamClient
from harness.robot.link.clock import ClockEstimate, RoundTripClock, pair_joint_states
from harness.robot.link.protocol import VERSION, ProtocolError

__all__ = ["BridgeOptions", "ClockEstimate", "LinkLostError", "ProtocolError", "RoundTripClock", "SimBridge", "VERSION",
           "WamClient", "pair_joint_states"]

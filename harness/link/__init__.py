"""The robot link: the WAM over the network (ZeroMQ + msgpack), the way the harness talks to a real robot.

``protocol`` (message schema, validation), ``bridge_core`` (what every bridge does: requests, checks,
watchdog), ``bridge_sim`` (the robot side for the simulated WAM: ``rt2 robot serve --sim``),
``bridge_ros`` (the robot side for ROS ``wam_node``, run under the system Python with rospy), ``client``
(``WamClient``: the WAM interface over the link), ``clock`` (clock-offset estimates). Protocol and the
bridge a lab writes for its controller: docs/robot_link.md.

Names are loaded on first use (PEP 562), so that ``python3 -m harness.link.bridge_ros``, which runs this
file first, imports under a Python that has neither the simulator nor the client's dependencies.
"""

from checks.lazy import lazy_attributes

_WHERE = {
    "BridgeOptions": "bridge_sim", "SimBridge": "bridge_sim", "LinkLostError": "client", "WamClient": "client",
    "ClockEstimate": "clock", "RoundTripClock": "clock", "pair_joint_states": "clock",
    "VERSION": "protocol", "ProtocolError": "protocol",
}

__all__ = sorted(_WHERE)
__getattr__, __dir__ = lazy_attributes("harness.link", globals(), _WHERE)

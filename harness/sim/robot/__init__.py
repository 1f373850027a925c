"""The simulated WAM (``SimulatedWam``): 500 Hz tracking loop, limits, encoders, zero-offset bias.

The interface contract (``WamInterface``, ``JointState``, ``JointTrajectory``, ``check_joint_trajectory``)
lives in robot_models/robot_interface.py, where policies can see it; docs/robot.md describes the
simulator's error model and docs/robot_link.md the network protocol.

The simulator's names are loaded on first use (PEP 562), so that the robot link's ROS bridge
(``python3 -m harness.link.bridge_ros``, a system Python without numba) can import this package.
"""

from harness.common.lazy import lazy_attributes

_WHERE = {"PiecewiseReference": "_reference", "SimSamples": "sim_wam", "SimWamOptions": "sim_wam",
          "SimulatedWam": "sim_wam"}

__all__ = sorted(_WHERE)
__getattr__, __dir__ = lazy_attributes("harness.sim.robot", globals(), _WHERE)

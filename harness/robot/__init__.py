"""The robot side of the harness: the simulated WAM, the robot link (``harness.robot.link``) and robot CLI commands.

The interface contract (``WamInterface``, ``JointState``, ``JointTrajectory``, ``check_joint_trajectory``)
lives in robot_models/robot_interface.py, where policies can see it; docs/robot.md describes the
simulator's error model and docs/robot_link.md the network protocol.
"""

from harness.robot.sim_wam import SimSamples, SimulatedWam, SimWamOptions

__all__ = ["SimSamples", "SimWamOptions", "SimulatedWam"]
